"""Give a fill glibc's roomy malloc thresholds where its process was started with small fixed ones (Dask workers).

Dask's nanny starts every worker with ``MALLOC_TRIM_THRESHOLD_=65536`` (``distributed.nanny.pre-spawn-environ``)
so that freed memory goes back to the OS.  Setting any malloc threshold also turns off glibc's dynamic mmap
threshold: it stays at 128 KiB, so every temporary array above 128 KiB is a fresh ``mmap`` whose pages are faulted
in and zeroed one by one, and the heap is trimmed after nearly every ``free``.  Measured on ``bench_batch.py``'s 20
files: 3.7 M page faults instead of 0.1 M and 4 s of kernel time on 20 s of fills (+20 % per file).

:func:`roomy_malloc` raises the two thresholds to what glibc's dynamic rule reaches on its own (mmap 32 MiB, trim
64 MiB) for the duration of a task, then puts the process's own settings back and trims (:c:func:`malloc_trim`), so
the worker still hands the memory back between tasks.  It does nothing where malloc runs with glibc's defaults or
where there is no glibc, or when ``MOCAPFILL_KEEP_MALLOC=1`` (keep the cluster's thresholds; ``bench_batch.py
--without-malloc-fix`` measures the difference).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import platform
import threading
from typing import Iterator

__all__ = ["roomy_malloc", "fixed_thresholds", "KEEP_ENV"]

# mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: glibc's defaults (128 KiB each) and the largest mmap threshold its dynamic rule reaches on 64-bit (32 MiB).
_DEFAULT = 128 * 1024
_ROOMY_MMAP = 32 * 1024 * 1024
_ROOMY_TRIM = 2 * _ROOMY_MMAP
_ENV = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_")
#: Set to 1 to keep the process's own malloc thresholds.
KEEP_ENV = "MOCAPFILL_KEEP_MALLOC"

_lock = threading.Lock()
_active = 0  # tasks inside roomy_malloc (a Dask worker may run several threads)


def fixed_thresholds() -> dict[str, int]:
    """The malloc thresholds this process's environment fixes (``MALLOC_TRIM_THRESHOLD_``,
    ``MALLOC_MMAP_THRESHOLD_``), by name; empty where glibc chooses them itself."""
    fixed = {}
    for name in _ENV:
        with contextlib.suppress(KeyError, ValueError):
            fixed[name] = int(os.environ[name])
    return fixed


def _libc():
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    try:
        libc = ctypes.CDLL(None)
        return libc if hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None
    except OSError:  # pragma: no cover
        return None


@contextlib.contextmanager
def roomy_malloc() -> Iterator[None]:
    """Run the enclosed code with glibc's roomy malloc thresholds if the environment fixed small ones; then restore
    them (the environment's values, glibc's defaults for the other) and return free memory to the OS."""
    global _active
    fixed = fixed_thresholds()
    libc = _libc() if fixed and os.environ.get(KEEP_ENV, "") in ("", "0") else None
    if libc is None:
        yield
        return
    with _lock:
        if _active == 0:
            libc.mallopt(_M_MMAP_THRESHOLD, _ROOMY_MMAP)
            libc.mallopt(_M_TRIM_THRESHOLD, _ROOMY_TRIM)
        _active += 1
    try:
        yield
    finally:
        with _lock:
            _active -= 1
            if _active == 0:
                libc.mallopt(_M_MMAP_THRESHOLD, fixed.get("MALLOC_MMAP_THRESHOLD_", _DEFAULT))
                libc.mallopt(_M_TRIM_THRESHOLD, fixed.get("MALLOC_TRIM_THRESHOLD_", _DEFAULT))
                libc.malloc_trim(0)
