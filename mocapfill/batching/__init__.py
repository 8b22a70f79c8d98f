"""Fill a whole capture database: :func:`batch`, one task per file, serial, on local processes or on a Dask cluster.

- **Inputs**: files, folders (searched recursively for the extensions :func:`mocapfill.io.detect_format` knows) and
  globs.  Each output keeps its input's path relative to the folder (or a glob's fixed part) under ``out_dir``.
- **One task per file** (:func:`run_task`): hash, read, fill (:func:`mocapfill.pipeline.fill_capture`), write
  atomically, report.  It never raises: a bad file gives a ``failed`` :class:`BatchRow` with a one-line error.
- **Results table** ``out_dir/mocapfill-batch.csv`` (:data:`COLUMNS`), one row per input, appended as files finish.
- **Resumable**: ``out_dir/.mocapfill-batch.jsonl`` records, per finished output, the SHA-256 of its input's content
  and of the settings; a re-run skips an input whose output exists and whose two hashes are unchanged.
- **Local processes** (``jobs`` > 1) or **Dask** (``scheduler``): :mod:`mocapfill.runtime.executor` runs the tasks; a local
  worker that dies (killed, out of memory) fails only the file it was filling.  On Dask the file is read inside the
  task (inputs and ``out_dir`` must be on a file system the workers share).

No click, no rich, no printing: callers watch progress through ``progress(done, total, row)``.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import os
import time
import warnings
from pathlib import Path
from typing import Any, Callable, Iterable

from ..errors import InputError, MocapfillError
from ..pipeline import FillSettings
from .inputs import (INDEX_NAME, REPORT_KINDS, RESULTS_NAME, STATUS_SUFFIX, beside_suffixes, find_inputs,
                     output_paths)
from .order import longest_first
from .resume import STATE_NAME, compact_state, file_digest, load_state, row_from_state, settings_digest
from .task import COLUMNS, BatchRow, FileTask, run_task

__all__ = ["batch", "BatchRow", "COLUMNS", "RESULTS_NAME", "STATE_NAME", "INDEX_NAME", "find_inputs", "run_task",
           "FileTask"]



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
        ``bones``, ``reject_outliers``, ``delta``, ``reference`` (paths of reference takes), ``model``,
        ``denoise``, ``smooth``, ``smooth_window``, ``smooth_order``, ``max_gap``, ``edges``, ``min_fragment``,
        ``markers``, ``exclude``, ``donors``,
        ``lowpass``).

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
    if isinstance(options.get("reference"), (str, os.PathLike)):
        options["reference"] = (os.fspath(options["reference"]),)
    elif options.get("reference") is not None:
        options["reference"] = tuple(os.fspath(p) for p in options["reference"])
    else:
        options.pop("reference", None)
    settings = FillSettings(method=method, **options).check()
    from ..io import WRITE_FORMATS

    if format is not None and format not in WRITE_FORMATS:
        raise MocapfillError(f"batch: cannot write format {format!r} (expected one of {', '.join(WRITE_FORMATS)})")
    if report is not None and report not in REPORT_KINDS:
        raise MocapfillError(f"batch: report must be one of {', '.join(REPORT_KINDS)}, not {report!r}")
    if scheduler is not None and jobs != 1:
        raise MocapfillError("batch: jobs applies to local processes; a Dask scheduler runs as many as it has")
    if scheduler is None:  # (a cluster's workers may see other paths than this process: they say so per file)
        check_shared_files(settings, rate)
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    out = Path(out_dir)
    pairs = find_inputs(list(inputs), exclude=out)

    tasks: list[FileTask] = []
    owners: dict[Path, Path] = {}
    for path, rel in pairs:
        output, report_path = output_paths(rel, out, format, report)
        key = output.resolve()
        if key in owners:
            raise InputError(f"{owners[key]} and {path} would both be written to {output}; "
                             "batch them separately or give another --format")
        if key == path.resolve():
            raise InputError(f"{output}: output is the same file as the input {path}; choose another --out-dir")
        owners[key] = path
        tasks.append(FileTask(str(path), str(output), None if report_path is None else str(report_path), settings,
                              input_format, rate, override_rate, format,
                              str(output.with_name(output.name + STATUS_SUFFIX)) if status else None))

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out}: cannot create the output folder: {exc.strerror or exc}") from None
    state_path = out / STATE_NAME
    state = load_state(state_path)
    digest = settings_digest(tasks[0])
    rows: dict[str, BatchRow] = {}
    total = len(tasks)

    def key_of(task: FileTask) -> str:
        return Path(os.path.relpath(task.output, out)).as_posix()

    with open(out / RESULTS_NAME, "w", newline="", encoding="utf-8") as table, \
            open(state_path, "a", encoding="utf-8") as record:
        writer = csv.DictWriter(table, fieldnames=COLUMNS)
        writer.writeheader()
        table.flush()

        def stale(entry: dict | None, row: BatchRow) -> bool:
            """Whether an earlier run's entry is of other settings or other content than this failed row's (a
            failure on the same content and settings, a lost worker under --force, keeps its still valid output)."""
            return entry is not None and (entry.get("settings_sha256") != digest
                                          or entry.get("input_sha256") != row.input_sha256)

        def on_row(row: BatchRow) -> None:
            rows[row.input] = row
            writer.writerow({k: ("" if v is None else round(v, 4) if isinstance(v, float) else v)
                             for k, v in row.table_row().items()})
            table.flush()
            task = by_input[row.input]
            key = key_of(task)
            if row.status == "filled":
                entry = {"output": key, "input": task.input, "settings_sha256": digest,
                         "input_sha256": row.input_sha256, "row": row.table_row()}
                state[key] = entry
                record.write(json.dumps(entry) + "\n")
                record.flush()
            elif row.status == "failed" and stale(state.get(key), row):
                # an earlier run filled this input from content or settings that no longer hold
                del state[key]
                gone = remove_earlier_outputs(Path(task.output))
                if gone:
                    row.warnings += (f"{row.input}: the earlier run's {', '.join(gone)} removed (of content or "
                                     "settings that no longer hold: this run failed on it)",)
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
            if entry is not None and entry.get("settings_sha256") == digest \
                    and Path(task.output).is_file() and (task.report is None or Path(task.report).is_file()) \
                    and (task.status is None or Path(task.status).is_file()):
                with contextlib.suppress(OSError):
                    if file_digest(task.input) == entry.get("input_sha256"):
                        skipped = row_from_state(entry, task, time.perf_counter() - started)
            if skipped is not None:
                on_row(skipped)
            else:
                to_run.append(task)
        # Longest expected first: the last tasks to finish are then short ones, and the workers end together.
        # Dask runs tasks submitted with one priority in submission order.
        to_run = longest_first(to_run, [t.input for t in to_run])
        try:
            if to_run:
                run_tasks(to_run, executor_for(jobs, scheduler, len(to_run)), on_row)
        finally:
            if report is not None:
                from ..report.batch_index import write_batch_index

                done = [rows[t.input] for t in tasks if t.input in rows]
                with contextlib.suppress(MocapfillError, OSError):
                    write_batch_index(done, out / INDEX_NAME, out_dir=out)
    compact_state(state_path, state)
    return [rows[task.input] for task in tasks]




def executor_for(jobs: int, scheduler: Any, n_tasks: int):
    """The executor for ``jobs`` local processes or a Dask ``scheduler`` (one line naming the extra without it)."""
    from ..runtime.executor import make_executor

    try:
        return make_executor(jobs, scheduler, n_tasks=n_tasks, name="mocapfill-batch")
    except ImportError:
        raise InputError("a Dask scheduler needs the distributed package: pip install 'mocapfill[dask]'") from None


from .runners import run_tasks  # noqa: E402  (runners imports task, which imports this package's siblings only)


def check_shared_files(settings: FillSettings, rate: float | None) -> None:
    """The files every input's fill reads (``--bones``, ``--model``, ``--ik-model``, each ``--reference``): one that
    is missing or unreadable is the batch's error, said once before anything runs, not a failed row per input.  A
    reference is read as a fill reads it (at ``rate``, or any rate where neither it nor the batch gives one: only its
    readability is checked here)."""
    from ..io import read

    for option, value in (("--bones", settings.bones), ("--model", settings.model),
                          ("--ik-model", settings.ik_model)):
        if isinstance(value, (str, os.PathLike)) and not os.path.isfile(value):
            raise InputError(f"{value}: no such file ({option}, given to every input)")
    for path in settings.reference:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                read(path, rate=rate or 100.0, override_rate=True)  # as each task reads it
        except MocapfillError as exc:
            raise InputError(f"{exc} (--reference, given to every input)") from None


def remove_earlier_outputs(output: Path) -> list[str]:
    """Remove what an earlier run wrote for one input (its output, per-file reports and status CSV, by the names
    :func:`~.inputs.output_paths` gives them) where this run failed on it; returns the names removed."""
    gone = []
    for path in [output] + [output.with_name(output.name + suffix) for suffix in beside_suffixes()]:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            gone.append(path.name)
    return gone
