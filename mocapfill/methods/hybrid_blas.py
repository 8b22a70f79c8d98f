"""Run NumPy's BLAS on one thread for the duration of a fill made of many small matrix operations.

The PCA fills (:mod:`.pca`, :mod:`.hybrid_local`, :mod:`.auto`) do thousands of eigendecompositions and products of
matrices at most 3 x n_markers wide.  A multi-threaded OpenBLAS gains nothing on such sizes, and on a busy machine
its threads wait for cores: on the shared 2-core development machine the default fill of a 1,500-frame clip with
gaps in 37 markers took 17.8 s with 2 BLAS threads and 2.7 s with one (``benchmarks/bench_default.py``).

:func:`one_blas_thread` does what ``threadpoolctl.threadpool_limits(1)`` does, for NumPy's bundled OpenBLAS only,
and only while the fill runs: it uses threadpoolctl when installed, else calls the bundled library's own
``*_set_num_threads`` through ctypes; when neither is available it does nothing.  It never raises.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
from typing import Callable, Iterator

import numpy as np

_SETTERS = (
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)
_cached: tuple[Callable[[], int], Callable[[int], None]] | None | bool = False


def _bundled_openblas() -> tuple[Callable[[], int], Callable[[int], None]] | None:
    """(get, set) thread-count functions of the OpenBLAS bundled with NumPy, or None."""
    global _cached
    if _cached is not False:
        return _cached  # type: ignore[return-value]
    _cached = None
    root = os.path.dirname(os.path.dirname(np.__file__))
    patterns = [os.path.join(root, "numpy.libs", "*openblas*"), os.path.join(os.path.dirname(np.__file__), ".dylibs",
                                                                              "*openblas*")]
    for pattern in patterns:
        for path in sorted(glob.glob(pattern)):
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                continue
            for get_name, set_name in _SETTERS:
                get, put = getattr(lib, get_name, None), getattr(lib, set_name, None)
                if get is not None and put is not None:
                    get.restype = ctypes.c_int
                    put.argtypes = [ctypes.c_int]
                    _cached = (get, put)
                    return _cached
    return None


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Limit NumPy's BLAS to one thread inside the ``with`` block, restoring the previous count after."""
    try:
        from threadpoolctl import threadpool_limits  # optional
    except ImportError:
        threadpool_limits = None
    if threadpool_limits is not None:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
        return
    funcs = None
    try:
        funcs = _bundled_openblas()
    except Exception:  # pragma: no cover - a foreign BLAS layout must never break a fill
        funcs = None
    if funcs is None:
        yield
        return
    get, put = funcs
    before = int(get())
    put(1)
    try:
        yield
    finally:
        put(before)
