"""Keep BLAS to one thread where many small LAPACK calls run.

The EM loops and the per-window solves are made of many small (H x H, k x k) LAPACK calls and tall-skinny
products; OpenBLAS threads gain nothing there and, on a machine whose cores are busy, make them 10-40x slower
(measured: a 16 x 16 triangular solve went from 2 us to 12 ms).
"""

from __future__ import annotations

import contextlib
from typing import Iterator


@contextlib.contextmanager
def single_blas_thread() -> Iterator[None]:
    """Run the enclosed code with every loaded BLAS library limited to one thread, then restore them."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
