"""One file, one task: :class:`FileTask` in, :class:`BatchRow` out (:func:`run_task` never raises)."""

from __future__ import annotations

import contextlib
import glob
import os
import socket
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import one_line, warning_line
from ..pipeline import FillSettings
from ..references import ReferenceError as UnmatchedReference
from .resume import file_digest

#: Columns of the results table, in order.
COLUMNS = ("input", "output", "status", "frames", "markers", "missing_samples", "filled_samples", "method",
           "seconds", "error", "left_samples", "references")
@dataclass
class BatchRow:
    """The outcome of one input; the first ten fields, ``left_samples`` and ``references`` are the results table's
    :data:`COLUMNS`.

    ``status`` is ``"filled"``, ``"skipped"`` (done before with the same content and settings) or ``"failed"``
    (``error`` says why, on one line).  ``frames`` ... ``filled_samples`` are None where the file could not be read.
    ``report`` is the per-file report's path ("" without one), ``warnings`` the reader's notes and the fill's
    warnings, ``worker`` the ``host:pid`` that ran the task and ``peak_rss_mb`` that process's peak resident memory
    so far (None where unknown), ``input_sha256`` the hash of the content the task read.  How the task used its
    thread (None where unknown; what ``bench_batch.py`` compares across runners): ``started`` (wall clock, seconds
    since the epoch), ``cpu_seconds`` (user + kernel), ``kernel_seconds`` and ``page_faults`` (minor).
    ``left_samples``: missing samples left missing on request (``max_gap``, ``edges="leave"``, markers not chosen);
    ``status_csv``: the per-sample status CSV's path ("" without one).  ``references``: each reference take's weight
    against this file, "not used" where its body differs (:func:`mocapfill.references.weights_text`; "" without).
    """

    input: str
    output: str
    status: str = "failed"
    frames: int | None = None
    markers: int | None = None
    missing_samples: int | None = None
    filled_samples: int | None = None
    method: str = ""
    seconds: float = 0.0
    error: str = ""
    report: str = ""
    warnings: tuple[str, ...] = ()
    worker: str = ""
    peak_rss_mb: float | None = None
    input_sha256: str = ""
    started: float | None = None
    cpu_seconds: float | None = None
    kernel_seconds: float | None = None
    page_faults: int | None = None
    left_samples: int | None = None
    status_csv: str = ""
    references: str = ""

    def table_row(self) -> dict[str, Any]:
        """The row as the results table holds it (:data:`COLUMNS` only)."""
        return {name: getattr(self, name) for name in COLUMNS}


@dataclass(frozen=True)
class FileTask:
    """Everything a worker needs to fill one file (small and picklable: the file is read by the worker)."""

    input: str
    output: str
    report: str | None
    settings: FillSettings
    input_format: str | None = None
    rate: float | None = None
    override_rate: bool = False
    output_format: str | None = None
    status: str | None = None  # where to write the per-sample status CSV, or None


def _process_facts() -> tuple[str, float | None]:
    worker = f"{socket.gethostname()}:{os.getpid()}"
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Windows
        return worker, None
    # ru_maxrss is in KiB on Linux.
    return worker, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _thread_usage() -> tuple[float, float, int] | None:
    """(user seconds, kernel seconds, minor page faults) of the calling thread so far, None if unknown."""
    try:
        import resource

        usage = resource.getrusage(resource.RUSAGE_THREAD)
    except (ImportError, AttributeError, OSError):  # pragma: no cover - not on Linux
        return None
    return usage.ru_utime, usage.ru_stime, usage.ru_minflt


def run_task(task: FileTask) -> BatchRow:
    """Fill one file: read it, fill it, write the output (atomically) and the report.  Never raises an Exception.

    The row's ``seconds`` is the wall time of the whole task (read to report); a failure becomes
    ``status="failed"`` with a one-line ``error``.  Runs under :func:`mocapfill.runtime.malloc.roomy_malloc` (a Dask
    worker's fixed malloc thresholds cost a fill a fifth of its time in page faults).
    """
    from ..runtime.malloc import roomy_malloc

    row = BatchRow(task.input, task.output, method=task.settings.method, started=time.time())
    before = _thread_usage()
    with roomy_malloc():
        _fill_file(task, row)
    after = _thread_usage()
    if before is not None and after is not None:
        # user and kernel apart, then summed: (u1 + s1) - (u0 + s0) could round below s1 - s0 when no user time passed
        row.kernel_seconds = after[1] - before[1]
        row.cpu_seconds = (after[0] - before[0]) + row.kernel_seconds
        row.page_faults = after[2] - before[2]
    row.worker, row.peak_rss_mb = _process_facts()
    return row


def _fill_file(task: FileTask, row: BatchRow) -> None:
    """The body of :func:`run_task`: fills in ``row`` (status, counts, error, warnings, seconds)."""
    from ..io import read, write
    from ..io.atomic import check_writable, removed_on_failure
    from ..pipeline import fill_capture, write_fill_report

    started = time.perf_counter()
    notes: list[str] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                for path in (task.output, task.report, task.status):  # a bad path found now, not after the fill
                    check_writable(path, parents=True)
                row.input_sha256 = file_digest(task.input)
                data = read(task.input, format=task.input_format, rate=task.rate, override_rate=task.override_rate)
                notes += [f"note: {note}" for note in data.notes]
                row.frames, row.markers = data.n_frames, data.n_markers
                reference = [read(path, rate=task.rate if task.rate else data.rate, override_rate=True)
                             for path in task.settings.reference]
                try:
                    outcome = fill_capture(data, task.settings, reference=reference)
                except UnmatchedReference as exc:  # it names the reference; the row's reader needs the input too
                    raise UnmatchedReference(f"{task.input}: reference {exc}") from None
                columns = outcome.columns  # the markers filled: model points and unlabelled ones are not counted
                row.markers = int(columns.size)
                row.missing_samples = int(outcome.work.missing[:, columns].sum())  # rejected samples count as gaps
                row.filled_samples = int(outcome.result.filled[:, columns].sum())
                if outcome.held is not None and outcome.held.any():
                    notes.append(f"note: {int(outcome.held.sum())} held sample(s) made gaps and filled")
                Path(task.output).parent.mkdir(parents=True, exist_ok=True)
                with removed_on_failure() as written:  # a failed report or status takes the output with it
                    write(outcome.output, task.output, format=task.output_format)
                    written.append(task.output)
                    if task.report is not None:
                        write_fill_report(outcome, task.report, method=task.settings.method, input_path=task.input,
                                          output_path=task.output,
                                          smoothed=task.settings.smooth or task.settings.lowpass is not None,
                                          stored=outcome.observed_stored(task.output, task.output_format))
                        written.append(task.report)
                    if task.status is not None:
                        from ..pipeline import write_status_csv

                        write_status_csv(outcome, task.status)
                row.report, row.status_csv = task.report or "", task.status or ""
                row.left_samples = 0 if outcome.left is None else int((outcome.left != 0).sum())
                if outcome.references:
                    from ..references import weights_text

                    row.references = weights_text(outcome.references)
                row.status = "filled"
            finally:
                notes += [warning_line(item) for item in caught]
    except Exception as exc:  # MemoryError included; a bug of ours on one file must not stop the others
        row.error = one_line(exc, where=task.input)
    row.warnings = tuple(dict.fromkeys(notes))
    row.seconds = time.perf_counter() - started


def remove_temporaries(task: FileTask) -> None:
    """Remove the temporary files :func:`mocapfill.io.atomic.atomic_write` leaves when its process is killed."""
    for target in (task.output, task.report, task.status):
        if target is None:
            continue
        path = Path(target)
        for tmp in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
            with contextlib.suppress(OSError):
                tmp.unlink()


def failed_row(task: FileTask, exc: BaseException) -> BatchRow:
    """The row of a task whose worker was lost: a local worker that died (``WorkerLost``), a Dask task the cluster
    could not finish (``KilledWorker``: its worker died on it more often than allowed; a lost connection)."""
    remove_temporaries(task)
    kind = type(exc).__name__
    if kind == "WorkerLost":
        error = f"{task.input}: the worker process died while filling this file ({exc})"
    elif kind == "KilledWorker":
        error = (f"{task.input}: the Dask worker died while filling this file (KilledWorker: "
                 "distributed.scheduler.allowed-failures exceeded; out of memory?)")
    else:
        error = one_line(f"{task.input}: Dask: {kind}: {exc}")
    return BatchRow(task.input, task.output, method=task.settings.method, error=error)


