"""Running a batch's tasks on the executor the caller chose (:mod:`mocapfill.runtime.executor`)."""

from __future__ import annotations

import dataclasses
import os
from typing import Callable, Sequence

from ..errors import InputError
from ..runtime.executor import Executor, SchedulerUnreachable
from .task import BatchRow, FileTask, failed_row, run_task


def _absolute(task: FileTask) -> FileTask:
    """The task with absolute paths: a Dask worker's working folder is not ours."""
    def absolute(path):
        return None if path is None else os.path.abspath(path)

    settings = dataclasses.replace(task.settings, bones=absolute(task.settings.bones),
                                   reference=tuple(absolute(p) for p in task.settings.reference),
                                   model=absolute(task.settings.model))
    return dataclasses.replace(task, input=absolute(task.input), output=absolute(task.output),
                               report=absolute(task.report), settings=settings)


def run_tasks(tasks: Sequence[FileTask], executor: Executor, on_row: Callable[[BatchRow], None]) -> None:
    """Run :func:`run_task` on every task, ``on_row(row)`` as each ends; rows keep the paths as the caller gave them
    (a cluster's tasks get absolute ones: a Dask worker's working folder is not ours)."""
    def done(task: FileTask, row: BatchRow) -> None:
        original = originals[id(task)]
        row.input, row.output = original.input, original.output
        row.report = row.report and (original.report or "")
        on_row(row)

    sent = [_absolute(t) if executor.remote else t for t in tasks]
    originals = {id(s): t for s, t in zip(sent, tasks)}
    try:
        executor.run(run_task, sent, done, on_failure=lambda task, exc: failed_row(originals[id(task)], exc))
    except SchedulerUnreachable as exc:
        raise InputError(f"{getattr(executor, 'scheduler', '')}: cannot reach the Dask scheduler: {exc}") from None
