"""`mocapfill batch INPUT... --out-dir DIR`: fill every capture of a session or a database, resumably.

A thin door over :func:`mocapfill.batching.batch`: the same fill options as `fill` (one shared decorator), a rich
progress bar and a summary on stderr, exit status 1 when any file failed.
"""

from __future__ import annotations

import click

from ..pipeline import FillSettings
from . import cli
from .common import ReadOptions, StderrProgress, console, fill_options, format_options, quiet_option
from .fill import FILL_EPILOG


class _BatchProgress(StderrProgress):
    """Files done / failed / skipped and the time left, on stderr (terminals only)."""

    def __init__(self, quiet: bool) -> None:
        self.counts = {"filled": 0, "skipped": 0, "failed": 0}

        def columns():
            from rich.progress import (BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn,
                                       TimeRemainingColumn)

            return (TextColumn("batch"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("[green]{task.fields[filled]} filled[/] [dim]{task.fields[skipped]} skipped[/] "
                               "[red]{task.fields[failed]} failed[/]"),
                    TimeElapsedColumn(), TextColumn("left"), TimeRemainingColumn())

        super().__init__(quiet, columns, **self.counts)

    def __call__(self, done: int, total: int, row) -> None:
        if row is not None:
            self.counts[row.status] = self.counts.get(row.status, 0) + 1
        self.update(completed=done, total=total, **self.counts)


@cli.command("batch", epilog=FILL_EPILOG)
@click.argument("inputs", metavar="INPUT...", nargs=-1, required=True)
@click.option("-o", "--out-dir", required=True, type=str, metavar="DIR",
              help="Folder for the outputs (created), the results table mocapfill-batch.csv and index.html.")
@fill_options
@click.option("--report", type=click.Choice(["html", "json"]), default=None,
              help="A report per file (<output>.report.html|json) and DIR/index.html, a sortable table of all.")
@click.option("--status", "status", is_flag=True,
              help="Write <output>.status.csv per file: what became of every sample (as fill --status).")
@format_options
@click.option("-j", "--jobs", type=click.IntRange(min=0), default=1, show_default=True,
              help="Local worker processes (0 = every core).")
@click.option("--scheduler", metavar="tcp://HOST:PORT", default=None,
              help="Run each file as a task on this Dask scheduler (pip install 'mocapfill[dask]'); inputs and "
                   "DIR must be on a file system the workers share.")
@click.option("--force", is_flag=True, help="Redo inputs already filled with the same content and settings.")
@quiet_option
def batch_command(inputs: tuple[str, ...], out_dir: str, fill_settings: FillSettings, report: str | None,
                  status: bool, output_format: str | None, reading: ReadOptions, jobs: int, scheduler: str | None,
                  force: bool, quiet: bool) -> None:
    """Fill every INPUT (files, folders searched recursively, globs) into DIR.

    Each output keeps its input's path relative to its folder.  Results go to DIR/mocapfill-batch.csv as files
    finish (input, output, status, frames, markers, missing_samples, filled_samples, method, seconds, error,
    left_samples: samples left missing by --max-gap, --edges leave, --markers / --exclude; references: each
    --reference's weight against the file, "not used" where its body differs).  A re-run skips inputs
    whose output exists and whose content and settings are unchanged (--force redoes them).
    A bad file gives a `failed` row and the others go on; the exit status is 1 if any file failed.
    """
    import dataclasses

    from ..batching import RESULTS_NAME, batch

    if scheduler is not None and jobs != 1:
        raise click.UsageError("--jobs applies to local processes; with --scheduler the cluster decides")
    options = dataclasses.asdict(fill_settings)
    method = options.pop("method")
    with _BatchProgress(quiet) as bar:
        rows = batch(list(inputs), out_dir, method=method, jobs=jobs, scheduler=scheduler, format=output_format,
                     input_format=reading.format, rate=reading.rate, override_rate=reading.override_rate,
                     report=report, status=status, force=force, progress=bar, **options)

    out = console(quiet)
    for row in rows:  # the readers' and fills' warnings (each names its file), as `fill` prints them
        for text in row.warnings:
            if not text.startswith("note: "):  # (the notes restate them for the per-file report)
                out.print(f"[yellow]warning[/yellow] {text}", markup=True, highlight=False, soft_wrap=True)
    failed = [row for row in rows if row.status == "failed"]
    errors = console(False)  # a failed file is an error: said under --quiet too
    for row in failed:
        errors.print(f"[red]failed[/red] {row.error}", highlight=False, soft_wrap=True)
    for line in unused_references(rows):
        out.print(line, highlight=False, markup=False, soft_wrap=True)
    seconds = sum(row.seconds for row in rows)
    out.print(", ".join(f"{n} {status}" for status, n in bar.counts.items()) +
              f" ({seconds:.1f} s of work); results in {out_dir}/{RESULTS_NAME}", highlight=False, markup=False,
              soft_wrap=True)
    if failed:
        raise SystemExit(1)


def unused_references(rows) -> list[str]:
    """One line per reference take some filled file left out (its body differs) or the method left out (it takes
    none), naming how many files (``BatchRow.references``, :func:`mocapfill.references.weights_text`)."""
    from ..references import NOT_USED, NOT_USED_BY_METHOD, NOT_USED_OWN

    filled = [row for row in rows if row.status == "filled" and row.references]
    unused: dict[tuple[str, str], int] = {}
    for row in filled:
        for entry in row.references.split("; "):
            for suffix in (NOT_USED_OWN, NOT_USED_BY_METHOD, NOT_USED):
                if entry.endswith(suffix):
                    name = entry[:-len(suffix)].rsplit(" ", 1)[0]
                    unused[name, suffix] = unused.get((name, suffix), 0) + 1
                    break
    why = {NOT_USED: "its body differs from theirs", NOT_USED_BY_METHOD: "the method takes no reference frames",
           NOT_USED_OWN: "it is the file itself, or holds its frames"}
    return [f"reference {name}: not used for {n} of {len(filled)} files ({why[suffix]}; the references column says "
            "per file)" for (name, suffix), n in unused.items()]
