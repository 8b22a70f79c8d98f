"""Fill a whole capture database: :func:`batch`, one task per file, serial, on local processes or on a Dask cluster.

- **Inputs**: files, folders (searched recursively for the extensions :func:`mocapfill.io.detect_format` knows) and
  globs.  Each output keeps its input's path relative to the folder (or a glob's fixed part) under ``out_dir``.
- **One task per file** (:func:`run_task`): hash, read, fill (:func:`mocapfill.pipeline.fill_capture`), write
  atomically, report.  It never raises: a bad file gives a ``failed`` :class:`BatchRow` with a one-line error.
- **Results table** ``out_dir/mocapfill-batch.csv`` (:data:`COLUMNS`), one row per input, appended as files finish.
- **Resumable**: ``out_dir/.mocapfill-batch.jsonl`` records, per finished output, the SHA-256 of its input's content
  and of the settings; a re-run skips an input whose output exists and whose two hashes are unchanged.
- **Local processes** (``jobs`` > 1) or **Dask** (``scheduler``): :mod:`mocapfill.runtime.workers` runs the tasks; a local
  worker that dies (killed, out of memory) fails only the file it was filling.  On Dask the file is read inside the
  task (inputs and ``out_dir`` must be on a file system the workers share).

No click, no rich, no printing: callers watch progress through ``progress(done, total, row)``.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import glob
import hashlib
import json
import mmap
import os
import re
import signal
import socket
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .errors import FormatError, InputError, MocapfillError
from .pipeline import FillSettings

__all__ = ["batch", "BatchRow", "COLUMNS", "RESULTS_NAME", "STATE_NAME", "INDEX_NAME", "find_inputs", "run_task",
           "FileTask"]

#: Columns of the results table, in order.
COLUMNS = ("input", "output", "status", "frames", "markers", "missing_samples", "filled_samples", "method",
           "seconds", "error", "left_samples")
#: The results table, the resume record and the index page inside ``out_dir``.
RESULTS_NAME = "mocapfill-batch.csv"
STATE_NAME = ".mocapfill-batch.jsonl"
INDEX_NAME = "index.html"
REPORT_KINDS = ("html", "json")


@dataclass
class BatchRow:
    """The outcome of one input; the first ten fields and ``left_samples`` are the results table's :data:`COLUMNS`.

    ``status`` is ``"filled"``, ``"skipped"`` (done before with the same content and settings) or ``"failed"``
    (``error`` says why, on one line).  ``frames`` ... ``filled_samples`` are None where the file could not be read.
    ``report`` is the per-file report's path ("" without one), ``warnings`` the reader's notes and the fill's
    warnings, ``worker`` the ``host:pid`` that ran the task and ``peak_rss_mb`` that process's peak resident memory
    so far (None where unknown), ``input_sha256`` the hash of the content the task read.  How the task used its
    thread (None where unknown; what ``bench_batch.py`` compares across runners): ``started`` (wall clock, seconds
    since the epoch), ``cpu_seconds`` (user + kernel), ``kernel_seconds`` and ``page_faults`` (minor).
    ``left_samples``: missing samples left missing on request (``max_gap``, ``edges="leave"``, markers not chosen);
    ``status_csv``: the per-sample status CSV's path ("" without one).
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


# --------------------------------------------------------------------------------------------------------- inputs

def _readable(path: Path) -> bool:
    from .io import detect_format

    try:
        detect_format(path)
    except FormatError:
        return False
    return True


def _inside(path: Path, folder: Path | None) -> bool:
    if folder is None:
        return False
    try:
        path.resolve().relative_to(folder)
    except ValueError:
        return False
    return True


def _search(folder: Path, exclude: Path | None) -> list[Path]:
    """Readable files below ``folder``, sorted; hidden files and folders skipped, and ``exclude`` (the output
    folder) when it lies inside ``folder``."""
    if _inside(folder, exclude):
        exclude = None
    found = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not _inside(Path(root, d), exclude))
        for name in sorted(files):
            path = Path(root, name)
            if not name.startswith(".") and _readable(path):
                found.append(path)
    return found


def _glob_base(pattern: str) -> Path:
    """The folder part of ``pattern`` before its first wildcard: outputs keep their path relative to it."""
    parts = Path(pattern).parts
    fixed = []
    for part in parts[:-1]:
        if glob.has_magic(part):
            break
        fixed.append(part)
    return Path(*fixed) if fixed else Path(".")


def find_inputs(inputs: Iterable[str | os.PathLike], *, exclude: str | os.PathLike | None = None
                ) -> list[tuple[Path, Path]]:
    """Expand files, folders and globs into ``(path, relative path)`` pairs, in a stable order, without duplicates.

    A folder is searched recursively for the extensions :func:`mocapfill.io.detect_format` knows; a glob's
    matching folders likewise.  A plain path that does not exist is kept (its task fails with the reader's error).
    Files a search or glob finds inside ``exclude`` (the output folder) are left out, unless the searched folder
    itself lies inside it.

    Raises
    ------
    InputError
        A glob matches nothing, or nothing at all was found.
    """
    ex = Path(exclude).resolve() if exclude is not None else None
    pairs: list[tuple[Path, Path]] = []
    seen: set[Path] = set()

    def add(path: Path, base: Path | None) -> None:
        key = path.resolve()
        if key in seen:
            return
        seen.add(key)
        pairs.append((path, Path(os.path.relpath(path, base)) if base is not None else Path(path.name)))

    for item in inputs:
        text = os.fspath(item)
        if glob.has_magic(text):
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                raise InputError(f"{text}: no file matches")
            base = _glob_base(text)
            skip = None if _inside(base, ex) else ex  # a glob reaching into the output folder must not eat outputs
            for match in map(Path, matches):
                if match.is_dir():
                    for path in _search(match, skip):
                        add(path, base)
                elif not _inside(match, skip):
                    add(match, base)
        elif Path(text).is_dir():
            for path in _search(Path(text), ex):
                add(path, Path(text))
        else:
            add(Path(text), None)
    if not pairs:
        raise InputError(f"no capture files found in {', '.join(map(os.fspath, inputs))}")
    return pairs


# ------------------------------------------------------------------------------------------------------- hashing

def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's content (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _settings_digest(task: FileTask) -> str:
    """SHA-256 of everything that shapes an output but the input's content (files named by settings included).

    The same for every task of a batch: it names the report's kind, not its path.
    """
    from . import __version__

    report = None if task.report is None else Path(task.report).suffix
    doc: dict[str, Any] = {"mocapfill": __version__, "fill": task.settings.as_dict(), "report": report,
                           "status": task.status is not None,
                           "reading": [task.input_format, task.rate, task.override_rate],
                           "format": task.output_format}
    for name in ("bones", "reference"):
        path = getattr(task.settings, name)
        if path is not None:
            try:
                doc[f"{name}_sha256"] = file_digest(path)
            except OSError:
                doc[f"{name}_sha256"] = None  # the task will fail and say why
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


# ------------------------------------------------------------------------------------------------- one file task

def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _process_facts() -> tuple[str, float | None]:
    worker = f"{socket.gethostname()}:{os.getpid()}"
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Windows
        return worker, None
    # ru_maxrss is in KiB on Linux.
    return worker, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _thread_usage() -> tuple[float, float, int] | None:
    """(user + kernel seconds, kernel seconds, minor page faults) of the calling thread so far, None if unknown."""
    try:
        import resource

        usage = resource.getrusage(resource.RUSAGE_THREAD)
    except (ImportError, AttributeError, OSError):  # pragma: no cover - not on Linux
        return None
    return usage.ru_utime + usage.ru_stime, usage.ru_stime, usage.ru_minflt


def run_task(task: FileTask) -> BatchRow:
    """Fill one file: read it, fill it, write the output (atomically) and the report.  Never raises an Exception.

    The row's ``seconds`` is the wall time of the whole task (read to report); a failure becomes
    ``status="failed"`` with a one-line ``error``.  Runs under :func:`mocapfill.runtime.malloc.roomy_malloc` (a Dask
    worker's fixed malloc thresholds cost a fill a fifth of its time in page faults).
    """
    from .runtime.malloc import roomy_malloc

    row = BatchRow(task.input, task.output, method=task.settings.method, started=time.time())
    before = _thread_usage()
    with roomy_malloc():
        _fill_file(task, row)
    after = _thread_usage()
    if before is not None and after is not None:
        row.cpu_seconds, row.kernel_seconds = after[0] - before[0], after[1] - before[1]
        row.page_faults = after[2] - before[2]
    row.worker, row.peak_rss_mb = _process_facts()
    return row


def _fill_file(task: FileTask, row: BatchRow) -> None:
    """The body of :func:`run_task`: fills in ``row`` (status, counts, error, warnings, seconds)."""
    from .io import read, write
    from .pipeline import fill_capture, write_fill_report

    started = time.perf_counter()
    notes: list[str] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                row.input_sha256 = file_digest(task.input)
                data = read(task.input, format=task.input_format, rate=task.rate, override_rate=task.override_rate)
                notes += [f"note: {note}" for note in data.notes]
                row.frames, row.markers = data.n_frames, data.n_markers
                reference = None
                if task.settings.reject_outliers and task.settings.reference is not None:
                    reference = read(task.settings.reference, rate=task.rate, override_rate=task.override_rate)
                outcome = fill_capture(data, task.settings, reference=reference)
                row.missing_samples = int(outcome.work.missing.sum())  # rejected outliers count as gaps
                row.filled_samples = int(outcome.result.filled.sum())
                Path(task.output).parent.mkdir(parents=True, exist_ok=True)
                write(outcome.output, task.output, format=task.output_format)
                if task.report is not None:
                    write_fill_report(outcome, task.report, method=task.settings.method, input_path=task.input,
                                      output_path=task.output, smoothed=task.settings.smooth)
                    row.report = task.report
                if task.status is not None:
                    from .pipeline import write_status_csv

                    write_status_csv(outcome, task.status)
                    row.status_csv = task.status
                row.left_samples = 0 if outcome.left is None else int((outcome.left != 0).sum())
                row.status = "filled"
            finally:
                notes += [f"{item.category.__name__}: {_one_line(item.message)}" for item in caught]
    except MocapfillError as exc:
        row.error = _one_line(exc)
    except MemoryError:
        row.error = f"{task.input}: out of memory"
    except OSError as exc:
        where = exc.filename or task.input
        row.error = _one_line(f"{where}: {exc.strerror or exc}")
    except Exception as exc:  # a bug of ours on one file must not stop the others
        row.error = _one_line(f"{task.input}: {type(exc).__name__}: {exc}")
    row.warnings = tuple(dict.fromkeys(notes))
    row.seconds = time.perf_counter() - started


def _remove_temporaries(task: FileTask) -> None:
    """Remove the temporary files :func:`mocapfill.io.atomic.atomic_write` leaves when its process is killed."""
    for target in (task.output, task.report, task.status):
        if target is None:
            continue
        path = Path(target)
        for tmp in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
            with contextlib.suppress(OSError):
                tmp.unlink()


def _died(task: FileTask, exitcode: int | None, where: str = "worker process") -> BatchRow:
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        how = f"killed by {name}" + (", out of memory?" if name == "SIGKILL" else "")
    else:
        how = f"exit status {exitcode}"
    _remove_temporaries(task)
    return BatchRow(task.input, task.output, method=task.settings.method,
                    error=f"{task.input}: the {where} died while filling this file ({how})")


# ------------------------------------------------------------------------------------------------------ runners

def _absolute(task: FileTask) -> FileTask:
    """The task with absolute paths: a Dask worker's working folder is not ours."""
    def absolute(path):
        return None if path is None else os.path.abspath(path)

    settings = dataclasses.replace(task.settings, bones=absolute(task.settings.bones),
                                   reference=absolute(task.settings.reference))
    return dataclasses.replace(task, input=absolute(task.input), output=absolute(task.output),
                               report=absolute(task.report), settings=settings)


def _dask_failed(task: FileTask, exc: BaseException) -> BatchRow:
    """The row of a task Dask could not finish: KilledWorker (its worker died on it, repeatedly), lost connection."""
    _remove_temporaries(task)
    if type(exc).__name__ == "KilledWorker":
        error = (f"{task.input}: the Dask worker died while filling this file (KilledWorker: "
                 "distributed.scheduler.allowed-failures exceeded; out of memory?)")
    else:
        error = _one_line(f"{task.input}: Dask: {type(exc).__name__}: {exc}")
    return BatchRow(task.input, task.output, method=task.settings.method, error=error)


def _run(tasks: Sequence[FileTask], jobs: int, scheduler: Any, on_row: Callable[[BatchRow], None]) -> None:
    """Run :func:`run_task` on every task (in process, on local workers or on Dask), ``on_row`` as each ends."""
    from .runtime.workers import SchedulerUnreachable, run_dask, run_local

    if scheduler is None:
        run_local(run_task, tasks, jobs, on_row, on_death=_died)
        return
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise InputError("a Dask scheduler needs the distributed package: pip install 'mocapfill[dask]'") from None

    def done(task: FileTask, row: BatchRow) -> None:
        row.input, row.output, row.report = task.input, task.output, row.report and (task.report or "")
        on_row(row)

    try:
        run_dask(run_task, tasks, scheduler, done, on_error=_dask_failed, prepare=_absolute, name="mocapfill-batch")
    except SchedulerUnreachable as exc:
        raise InputError(f"{scheduler}: cannot reach the Dask scheduler: {exc}") from None


# ------------------------------------------------------------------------------------------------ resume record

def _load_state(path: Path) -> dict[str, dict[str, Any]]:
    """Entries by output key; a torn last line (an interrupted append) is ignored."""
    state: dict[str, dict[str, Any]] = {}
    if not path.is_file():
        return state
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            entry = json.loads(line)
            state[entry["output"]] = entry
        except (ValueError, KeyError, TypeError):
            continue
    return state


def _row_from_state(entry: dict[str, Any], task: FileTask, seconds: float) -> BatchRow | None:
    try:
        known = {k: entry["row"][k] for k in ("frames", "markers", "missing_samples", "filled_samples")}
    except (KeyError, TypeError):
        return None
    return BatchRow(task.input, task.output, "skipped", method=task.settings.method, seconds=seconds,
                    report=task.report or "", left_samples=entry["row"].get("left_samples"),
                    status_csv=task.status or "", **known)


# ------------------------------------------------------------------------------------------------------ the API

def _output_paths(rel: Path, out_dir: Path, output_format: str | None, report: str | None
                  ) -> tuple[Path, Path | None]:
    out = out_dir / rel
    if output_format is not None:
        out = out.with_suffix("." + output_format)
    return out, (out.with_name(f"{out.name}.report.{report}") if report else None)


def _jobs(jobs: int, n_tasks: int) -> int:
    if jobs <= 0:
        try:
            jobs = len(os.sched_getaffinity(0))
        except AttributeError:  # pragma: no cover - not on Linux
            jobs = os.cpu_count() or 1
    return max(1, min(jobs, n_tasks))


def batch(inputs: str | os.PathLike | Iterable[str | os.PathLike], out_dir: str | os.PathLike, *,
          method: str = "auto", jobs: int = 1, scheduler: Any = None, format: str | None = None,
          input_format: str | None = None, rate: float | None = None, override_rate: bool = False,
          report: str | None = None, status: bool = False, force: bool = False,
          progress: Callable[[int, int, BatchRow | None], None] | None = None, **options: Any) -> list[BatchRow]:
    """Fill every input file into ``out_dir``; return one :class:`BatchRow` per input, in input order.

    Parameters
    ----------
    inputs : path, glob or folder, or a list of them
        Folders are searched recursively for the formats :func:`mocapfill.read` reads.
    out_dir : path
        Created if needed.  Outputs keep each input's path relative to its folder (or glob's fixed part).
    method : str
        A method of :data:`mocapfill.methods.METHODS`.
    jobs : int
        Local worker processes; 1 = in this process, 0 = every core.  Workers are started with ``spawn``: a script
        that calls ``batch(jobs=...)`` needs the usual ``if __name__ == "__main__":`` guard.
    scheduler : str, distributed.Client or None
        A Dask scheduler address (``"tcp://host:8786"``) or client: each file becomes one task on that cluster.
    format : {"c3d", "csv", "trc"} or None
        Output format (default: the input's extension).
    input_format, rate, override_rate :
        How to read the inputs (as :func:`mocapfill.read`).
    report : {"html", "json"} or None
        Write ``<output>.report.<kind>`` per file and ``out_dir/index.html`` linking them.
    status : bool
        Write ``<output>.status.csv`` per file: what became of every sample (see ``fill --status``).
    force : bool
        Redo inputs that a previous run finished with the same content and settings.
    progress : callable or None
        ``progress(done, total, row)``, called once with ``(0, total, None)`` and after every file.
    **options
        The fill options of :class:`mocapfill.pipeline.FillSettings` (``hidden``, ``max_iter``, ``tol``, ``seed``,
        ``bones``, ``reject_outliers``, ``delta``, ``reference``, ``smooth``, ``smooth_window``, ``smooth_order``,
        ``max_gap``, ``edges``, ``min_fragment``, ``markers``, ``exclude``).

    Returns
    -------
    list of BatchRow
        Also written to ``out_dir/mocapfill-batch.csv`` as the files finish.

    Raises
    ------
    MocapfillError
        Bad settings, no inputs, two inputs that would write the same output, an unreachable scheduler.  Problems
        with single files never raise: they give ``failed`` rows.  KeyboardInterrupt propagates after the workers
        have stopped; finished outputs and rows are kept, no half-written output is left.
    """
    known = {f.name for f in dataclasses.fields(FillSettings)} - {"method"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise MocapfillError(f"batch: unknown option(s) {', '.join(unknown)} (expected {', '.join(sorted(known))})")
    settings = FillSettings(method=method, **options).check()
    from .io import WRITE_FORMATS

    if format is not None and format not in WRITE_FORMATS:
        raise MocapfillError(f"batch: cannot write format {format!r} (expected one of {', '.join(WRITE_FORMATS)})")
    if report is not None and report not in REPORT_KINDS:
        raise MocapfillError(f"batch: report must be one of {', '.join(REPORT_KINDS)}, not {report!r}")
    if scheduler is not None and jobs != 1:
        raise MocapfillError("batch: jobs applies to local processes; a Dask scheduler runs as many as it has")
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    out = Path(out_dir)
    pairs = find_inputs(list(inputs), exclude=out)

    tasks: list[FileTask] = []
    owners: dict[Path, Path] = {}
    for path, rel in pairs:
        output, report_path = _output_paths(rel, out, format, report)
        key = output.resolve()
        if key in owners:
            raise InputError(f"{owners[key]} and {path} would both be written to {output}; "
                             "batch them separately or give another --format")
        if key == path.resolve():
            raise InputError(f"{output}: output is the same file as the input {path}; choose another --out-dir")
        owners[key] = path
        tasks.append(FileTask(str(path), str(output), None if report_path is None else str(report_path), settings,
                              input_format, rate, override_rate, format,
                              str(output.with_name(f"{output.name}.status.csv")) if status else None))

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out}: cannot create the output folder: {exc.strerror or exc}") from None
    state_path = out / STATE_NAME
    state = _load_state(state_path)
    settings_digest = _settings_digest(tasks[0])
    rows: dict[str, BatchRow] = {}
    total = len(tasks)

    def key_of(task: FileTask) -> str:
        return Path(os.path.relpath(task.output, out)).as_posix()

    with open(out / RESULTS_NAME, "w", newline="", encoding="utf-8") as table, \
            open(state_path, "a", encoding="utf-8") as record:
        writer = csv.DictWriter(table, fieldnames=COLUMNS)
        writer.writeheader()
        table.flush()

        def on_row(row: BatchRow) -> None:
            rows[row.input] = row
            writer.writerow({k: ("" if v is None else round(v, 4) if isinstance(v, float) else v)
                             for k, v in row.table_row().items()})
            table.flush()
            if row.status == "filled":
                task = by_input[row.input]
                entry = {"output": key_of(task), "input": task.input, "settings_sha256": settings_digest,
                         "input_sha256": row.input_sha256, "row": row.table_row()}
                state[entry["output"]] = entry
                record.write(json.dumps(entry) + "\n")
                record.flush()
            if progress is not None:
                progress(len(rows), total, row)

        by_input = {task.input: task for task in tasks}
        if progress is not None:
            progress(0, total, None)
        to_run = []
        for task in tasks:
            entry = None if force else state.get(key_of(task))
            started = time.perf_counter()
            skipped = None
            if entry is not None and entry.get("settings_sha256") == settings_digest \
                    and Path(task.output).is_file() and (task.report is None or Path(task.report).is_file()) \
                    and (task.status is None or Path(task.status).is_file()):
                with contextlib.suppress(OSError):
                    if file_digest(task.input) == entry.get("input_sha256"):
                        skipped = _row_from_state(entry, task, time.perf_counter() - started)
            if skipped is not None:
                on_row(skipped)
            else:
                to_run.append(task)
        # Longest expected first: the last tasks to finish are then short ones, and the workers end together.
        # Dask runs tasks submitted with one priority in submission order.
        to_run = _longest_first(to_run)
        try:
            if to_run:
                _run(to_run, _jobs(jobs, len(to_run)), scheduler, on_row)
        finally:
            if report is not None:
                from .report.batch_index import write_batch_index

                done = [rows[t.input] for t in tasks if t.input in rows]
                with contextlib.suppress(MocapfillError, OSError):
                    write_batch_index(done, out / INDEX_NAME, out_dir=out)
    _compact_state(state_path, state)
    return [rows[task.input] for task in tasks]


#: Bytes per sample (one marker in one frame) of a text capture: what :func:`_samples_hint` divides a CSV's size by.
_TEXT_BYTES_PER_SAMPLE = 25


def _samples_hint(path: str) -> int:
    """Frames x markers of a capture from its header alone (C3D header block, TRC header lines), else its size over
    :data:`_TEXT_BYTES_PER_SAMPLE`; 0 when unreadable.  :func:`_longest_first`'s samples for text files, and its
    fallback when the scan cannot tell.  Only orders the tasks: a wrong hint never changes an output.

    Bytes alone order badly: analog channels fill a C3D without adding fill work (measured: the costliest of the
    benchmark's 20 files, 4.6 s of 20 s, was the 15th largest, and ran last while the other worker idled).
    """
    try:
        if not os.path.isfile(path):  # a FIFO or device would block here: its task reads it
            return 0
        with open(path, "rb") as handle:
            head = handle.read(2 * 512)
        size = os.path.getsize(path)
    except OSError:
        return 0
    hint = None
    if len(head) >= 1024 and head[1] == 0x50:  # C3D: points and first / last frame in the header's 16-bit words
        pstart = ((head[0] or 2) - 1) * 512
        order = ">" if pstart + 3 < len(head) and head[pstart + 3] == 86 else "<"  # 86: MIPS, big-endian
        points, first, last = (int.from_bytes(head[2 * k:2 * k + 2], "big" if order == ">" else "little")
                               for k in (1, 3, 4))
        hint = points * (last - first + 1) if last >= first else None
    elif head[:12].lower() == b"pathfiletype":  # TRC: the values under NumFrames and NumMarkers
        lines = head.decode("latin-1").splitlines()
        if len(lines) >= 3:
            sep = "\t" if "\t" in lines[1] else ","
            meta = dict(zip((k.strip() for k in lines[1].split(sep)), (v.strip() for v in lines[2].split(sep))))
            with contextlib.suppress(KeyError, ValueError):
                hint = int(meta["NumFrames"]) * int(meta["NumMarkers"])
    return hint if hint is not None and hint > 0 else size // _TEXT_BYTES_PER_SAMPLE


#: Expected cost of an observed sample relative to a missing one.  Fill time grows with the missing samples far more
#: than with the file's size (bench_batch's 20 files: 7,661 of 14,850 samples missing took 12 s, 160 of 46,492 took
#: 0.3 s); the small term keeps big, fully observed files from running last.
_OBSERVED_WEIGHT = 0.02
#: The scan reads at most this many frames of a C3D (evenly spaced) and this many bytes of a text file (in
#: :data:`_TEXT_CHUNKS` spread chunks): a few milliseconds per file, whatever its size.
_SCAN_FRAMES = 1000
_SCAN_BYTES = 1 << 18
_TEXT_CHUNKS = 64
#: Scanning stops after this many seconds in all (a database of thousands of files); the files left are costed from
#: their headers with the mean missing fraction of those scanned.  With that many files the order of the tail
#: hardly matters: a worker idles at most one file's time at the end.
_SCAN_SECONDS = 2.0
#: A text field that counts as a missing coordinate (what the text readers read as NaN); QTM's TSV also writes
#: missing samples as zeros (:mod:`mocapfill.io.tsv`).
_MISSING_FIELD = re.compile(rb"(?<=[\t,])[ ]*(?:nan|-nan|null|na|n/a)?[ ]*(?=[\t,\r\n])", re.IGNORECASE)
_MISSING_OR_ZERO_FIELD = re.compile(rb"(?<=[\t,])[ ]*(?:nan|-nan|null|na|n/a|-?0(?:\.0*)?)?[ ]*(?=[\t,\r\n])",
                                    re.IGNORECASE)
_FIELD_SEPARATORS = re.compile(rb"[\t,]")


def _longest_first(tasks: list[FileTask]) -> list[FileTask]:
    """``tasks`` sorted by expected fill time, longest first: samples x (missing fraction + :data:`_OBSERVED_WEIGHT`),
    from :func:`_scan_missing`.  Only orders the tasks: a wrong estimate never changes an output.
    """
    deadline = time.perf_counter() + _SCAN_SECONDS
    scans = [_scan_missing(t.input) if time.perf_counter() < deadline else None for t in tasks]
    known = [scan[0] for scan in scans if scan is not None]
    typical = sum(known) / len(known) if known else 0.0
    cost = [(scan[1] * (scan[0] + _OBSERVED_WEIGHT)) if scan is not None
            else _samples_hint(t.input) * (typical + _OBSERVED_WEIGHT) for t, scan in zip(tasks, scans)]
    order = sorted(range(len(tasks)), key=lambda i: -cost[i])
    return [tasks[i] for i in order]


def _scan_missing(path: str) -> tuple[float, int] | None:
    """(fraction of missing samples, frames x markers) of a capture from a bounded scan (:data:`_SCAN_FRAMES`,
    :data:`_SCAN_BYTES`); None when it cannot tell (not a regular file, unreadable, corrupt, no data).  Never raises.

    C3D: the point words of evenly spaced frames, missing as :mod:`mocapfill.io.c3d` reads them (negative residual,
    non-finite or all-zero coordinates); only the header, the parameters and those frames' point words are read.  Text (TRC, CSV, TSV): the share of fields that are empty or a NaN token (or zero, in a TSV) in
    chunks spread over the file, and :func:`_samples_hint`'s samples.
    """
    try:
        if not os.path.isfile(path):  # a FIFO or device would block here: its task reads it
            return None
        with open(path, "rb") as handle:
            head = handle.read(2)
            size = os.fstat(handle.fileno()).st_size
            if size == 0:
                return None
            if len(head) == 2 and head[1] == 0x50:
                return _c3d_missing(handle, path)
            fraction = _text_missing_fraction(handle, size, path.lower().endswith(".tsv"))
        return None if fraction is None else (fraction, _samples_hint(path))
    except Exception:  # noqa: BLE001 - only a hint: whatever went wrong, the file's own task reports it
        return None


def _c3d_missing(handle, path: str) -> tuple[float, int] | None:
    from .io.c3d import decode_points
    from .io.c3dfile import parse

    # parse reads the header and the parameters through the map (and the data section only when nothing else gives
    # the frame count); the sampled frames' point words are then read one by one, not through the map, whose
    # fault-around would bring in most of a big file.
    with mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as raw:
        if hasattr(raw, "madvise"):
            raw.madvise(mmap.MADV_RANDOM)
        f = parse(raw, path)
    if f.n_frames == 0 or f.n_points == 0:
        return None
    row = 4 * f.n_points * f.word_size
    words = bytearray()
    for frame in range(0, f.n_frames, -(-f.n_frames // _SCAN_FRAMES)):
        handle.seek(f.data_offset + frame * f.frame_bytes)
        words += handle.read(row)
    sampled = dataclasses.replace(f, raw=bytes(words), n_frames=len(words) // row, data_offset=0, analog_words=0)
    positions, _ = decode_points(sampled, sampled.point_block())
    return float(np.isnan(positions[:, :, 0]).mean()), f.n_frames * f.n_points


def _text_missing_fraction(handle, size: int, zeros_missing: bool) -> float | None:
    # Every line is about as likely to fall in a chunk whatever its length; many small chunks follow the gaps along
    # the capture (they come in stretches) better than a few big ones.
    chunk = _SCAN_BYTES // _TEXT_CHUNKS
    starts = [0] if size <= _SCAN_BYTES else [k * (size - chunk) // (_TEXT_CHUNKS - 1) for k in range(_TEXT_CHUNKS)]
    pattern = _MISSING_OR_ZERO_FIELD if zeros_missing else _MISSING_FIELD
    missing = fields = 0
    for start in starts:
        handle.seek(start)
        text = handle.read(size if len(starts) == 1 else chunk)
        missing += len(pattern.findall(text))
        fields += len(_FIELD_SEPARATORS.findall(text))
    return missing / fields if fields else None


def _compact_state(path: Path, state: dict[str, dict[str, Any]]) -> None:
    """Rewrite the resume record with one line per output (re-runs append; this keeps it from growing)."""
    from .io.atomic import atomic_write

    with contextlib.suppress(MocapfillError, OSError):
        with atomic_write(path, "w") as handle:
            for entry in state.values():
                handle.write(json.dumps(entry) + "\n")
