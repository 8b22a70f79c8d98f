"""The order a batch runs its files in: longest expected first, so that the last files to finish are short ones
and the workers end together (Dask runs tasks submitted with one priority in submission order).  Only orders the
tasks: a wrong estimate never changes an output."""

from __future__ import annotations

import time
from typing import Sequence, TypeVar

from ..io.peek import peek

#: Expected cost of an observed sample relative to a missing one.  Fill time grows with the missing samples far more
#: than with the file's size (bench_batch's 20 files: 7,661 of 14,850 samples missing took 12 s, 160 of 46,492 took
#: 0.3 s); the small term keeps big, fully observed files from running last.
OBSERVED_WEIGHT = 0.02
#: Scanning stops after this many seconds in all (a database of thousands of files); the files left are costed from
#: their headers with the mean missing fraction of those scanned.  With that many files the order of the tail
#: hardly matters: a worker idles at most one file's time at the end.
SCAN_SECONDS = 2.0

T = TypeVar("T")


def longest_first(tasks: Sequence[T], paths: Sequence[str]) -> list[T]:
    """``tasks`` sorted by expected fill time, longest first: samples x (missing fraction + :data:`OBSERVED_WEIGHT`),
    from :func:`mocapfill.io.peek.peek` of each task's input ``paths[i]``; past :data:`SCAN_SECONDS`, the header's
    samples x the mean fraction of the files scanned."""
    deadline = time.perf_counter() + SCAN_SECONDS
    peeks = [peek(p, scan=time.perf_counter() < deadline) for p in paths]
    known = [p.missing for p in peeks if p.missing is not None]
    typical = sum(known) / len(known) if known else 0.0
    cost = [(p.samples or 0) * ((typical if p.missing is None else p.missing) + OBSERVED_WEIGHT) for p in peeks]
    order = sorted(range(len(tasks)), key=lambda i: -cost[i])
    return [tasks[i] for i in order]
