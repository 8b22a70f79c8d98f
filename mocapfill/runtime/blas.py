"""Keep BLAS to one thread where many small LAPACK calls run.

The EM loops and the per-window solves are made of many small (H x H, k x k) LAPACK calls and tall-skinny
products; OpenBLAS threads gain nothing there and, on a machine whose cores are busy, make them 10-40x slower
(measured: a 16 x 16 triangular solve went from 2 us to 12 ms).
"""

from __future__ import annotations

import contextlib
import os
from typing import Iterator


@contextlib.contextmanager
def single_blas_thread() -> Iterator[None]:
    """Run the enclosed code with every loaded BLAS library limited to one thread, then restore them."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


#: The variables that size the BLAS libraries' thread pools in a process about to start.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def one_blas_thread_environment() -> Iterator[None]:
    """The :data:`BLAS_THREAD_VARIABLES` the caller left unset at 1 within the block, then unset again: for a worker
    process started in it (a spawned process takes the environment as it is at its start, before its BLAS is
    loaded), where the workers are the parallelism; without it each worker started one BLAS thread per core, and a
    long take's windows on two workers took twice the time of one process, their threads fighting over the cores."""
    added = [name for name in BLAS_THREAD_VARIABLES if name not in os.environ]
    for name in added:
        os.environ[name] = "1"
    try:
        yield
    finally:
        for name in added:
            os.environ.pop(name, None)
