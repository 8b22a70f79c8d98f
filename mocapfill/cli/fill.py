"""`mocapfill fill IN OUT`: fill the gaps of a capture and write it back (``-`` = stdin / stdout).

The command is a thin door: read with :func:`mocapfill.io.read`, optionally reject outliers
(:func:`mocapfill.guards.outliers.reject_outliers`), fill with :func:`mocapfill.api.fill`, optionally smooth
(:func:`mocapfill.guards.smooth.savgol_smooth`), write with :func:`mocapfill.io.write`, optionally write a report
(:mod:`mocapfill.report`).  stdout carries data only; progress, warnings and the summary go to stderr.
"""

from __future__ import annotations

import dataclasses
import os
import warnings

import click
import numpy as np

from ..methods import METHODS
from ..methods.base import records_mask
from ..pipeline import FillSettings
from . import cli
from .common import (ReadOptions, StderrProgress, console, copies_text, fill_options, format_options, quiet_option,
                     read_input, show_warnings)


class _ProgressBar(StderrProgress):
    """A rich progress bar for a method's ``progress(iteration, n_max, objective)`` callback (stderr, terminals)."""

    def __init__(self, method: str, quiet: bool) -> None:
        def columns():
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

            return (TextColumn(f"{method}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("objective {task.fields[objective]}"), TimeElapsedColumn())

        super().__init__(quiet, columns, objective="-")

    def __call__(self, iteration: int, n_max: int, objective: float) -> None:
        self.update(completed=iteration, total=n_max, objective=f"{objective:.6g}")


FILL_EPILOG = "\b\nMethods:\n" + "\n".join(f"  {spec.name:<10} {spec.summary}" for spec in METHODS.values())


@cli.command("fill", epilog=FILL_EPILOG)
@click.argument("input_path", metavar="IN", type=str)
@click.argument("output_path", metavar="OUT", type=str)
@fill_options
@click.option("--report", "report_path", type=str, default=None,
              help="Write a report of the fill: FILE.json or FILE.html (self-contained page with plots).")
@click.option("--status", "status_path", type=str, default=None, metavar="FILE.csv",
              help="Write what became of every sample (frame, marker, status: observed, filled, left missing "
                   "and why, rejected and why, smoothed, ...) as CSV.")
@format_options
@quiet_option
@click.option("--force", is_flag=True, help="Allow OUT to be the same file as IN (it is replaced atomically).")
@click.option("-j", "--jobs", type=click.IntRange(min=0), default=0, show_default=True,
              help="Worker processes (0 = every core): a long take's windows, the default method's per-marker "
                   "models, an HTML report's plots; the output does not depend on it.")
def fill_command(input_path: str, output_path: str, fill_settings: FillSettings, report_path: str | None,
                 status_path: str | None, output_format: str | None, reading: ReadOptions, quiet: bool,
                 force: bool, jobs: int) -> None:
    """Fill the gaps of IN and write the result to OUT ("-" = stdin / stdout).

    Observed samples are written back unchanged, except under --smooth, --reject-outliers and --min-fragment
    (the summary says which changed them).  Progress, warnings and a summary go to stderr; stdout carries data
    only, so `mocapfill fill - - --format csv < in.csv > out.csv` works in a pipe.
    """
    from ..io import write
    from ..io.atomic import check_output_path, check_writable, removed_on_failure
    from ..pipeline import fill_capture, write_fill_report, write_status_csv

    settings = fill_settings
    method = settings.method
    if not force:
        check_output_path(output_path, input_path)
    if report_path is not None:
        if not report_path.lower().endswith((".json", ".html", ".htm")):
            raise click.BadParameter("must end in .json or .html", param_hint="--report")
        check_output_path(report_path, input_path, output_path)
    if status_path is not None:
        check_output_path(status_path, input_path, output_path, report_path)
        if status_path == "-" and output_path == "-":
            raise click.BadParameter("stdout carries the output; write the status to a file", param_hint="--status")
    if input_path == "-" and "-" in fill_settings.reference:
        raise click.BadParameter("standard input carries the capture (IN is '-'); give the reference as a file",
                                 param_hint="--reference")
    for path in (output_path, report_path, status_path):  # a bad path found now, not after the fill
        check_writable(path)
    mismatch = _format_mismatch(output_path, output_format)
    if mismatch is not None:  # written as asked (the user chose the format), but said now, before the fill
        console(quiet).print(f"[yellow]warning[/yellow] {mismatch}", markup=True, highlight=False, soft_wrap=True)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        data = read_input(input_path, reading, quiet=quiet)
        reference = []
        for path in settings.reference:
            check_output_path(output_path, path)
            reference.append(read_input(path, reading._replace(format=None, override_rate=True), quiet=quiet))

        with _ProgressBar(method, quiet) as bar:
            outcome = fill_capture(data, settings, reference=reference, progress=bar if bar.enabled else None,
                                   jobs=jobs)

        out_data = outcome.output
        if force:
            # The writer refuses the path the data came from; --force says the user wants exactly that.
            out_data = dataclasses.replace(out_data, path=None)
        stored = outcome.observed_stored(output_path, output_format)  # what the format does to them: TSV's 0.001 mm
        # The output last: a report or status that fails leaves it (under --force, the input) untouched, and one
        # that fails to write takes the report and status already written with it.
        with removed_on_failure() as written:
            if report_path is not None:
                write_fill_report(outcome, report_path, method=method, input_path=input_path,
                                  output_path=output_path, smoothed=settings.smooth or settings.lowpass is not None,
                                  jobs=jobs, stored=stored)
                written.append(report_path)
            if status_path is not None:
                write_status_csv(outcome, status_path)
                written.append(status_path)
            write(out_data, output_path, format=output_format)

    show_warnings(caught, quiet)
    _references(outcome.references, data.units, quiet)
    _summary(outcome, method, report_path, status_path, quiet, stored)
    _found(outcome, quiet)


def _format_mismatch(output_path: str, output_format: str | None) -> str | None:
    """The warning when ``--format`` disagrees with OUT's extension (``-f c3d`` into ``out.csv``), else None.

    Only an extension that names another format counts; readers go by the extension where the content allows, so
    the file would not read back as it was written."""
    from ..errors import FormatError
    from ..io import detect_format

    if output_format is None or output_path == "-":
        return None
    try:
        by_extension = detect_format(output_path)
    except FormatError:  # no extension, or one of no format: nothing to disagree with
        return None
    if by_extension == output_format:
        return None
    suffix = os.path.splitext(output_path)[1]
    return (f"{output_path}: --format {output_format} writes {output_format.upper()} into a {suffix} file; "
            f"reading it back will need --input-format {output_format}")


def _found(outcome, quiet: bool) -> None:
    """One line each on what the reader and the held-sample guard found (only when there is something)."""
    from ..pipeline import held_report, points_line

    out = console(quiet)
    if any(kind != "marker" for kind in outcome.data.kinds):
        out.print(f"points: {points_line(outcome.data)}", markup=False, highlight=False)
    if outcome.held_summary is not None:
        line = held_report(outcome.held_summary, kept=outcome.held is None)["line"]
        if line != "none":
            out.print(f"held samples: {line}" + ("" if outcome.held is None else " (made gaps and filled)"),
                      markup=False, highlight=False)


def _references(references, units: str, quiet: bool) -> None:
    """One line per reference take on stderr: frames, weight, and what each stage did with it."""
    out = console(quiet)
    for ref in references:
        stages = "; ".join(f"{stage}: {text}" for stage, text in ref.stages.items())
        kind = "static trial, " if ref.static else ""
        frames = "1 frame" if ref.n_frames == 1 else f"{ref.n_frames} frames"
        fit = (f"its pair lengths {ref.shape_difference:.3g} {units} off the capture's (median)"
               if np.isfinite(ref.shape_difference) else "no pair lengths to compare")
        out.print(f"reference {ref.name} ({kind}{frames}, {fit}, weight {ref.weight:.2f}): {stages}",
                  markup=False, highlight=False, soft_wrap=True)


def _summary(outcome, method: str, report_path, status_path, quiet: bool, stored: str | None = None) -> None:
    """A few lines on stderr: method, filled samples, gaps left (and why), time, convergence, what changed observed
    samples (or, when nothing did, how the output format stores them: ``stored``, None = exactly)."""
    from ..gaps import all_missing_markers, find_gaps
    from ..guards.limits import left_records
    from ..report.json_report import observed_words

    data, result = outcome.data, outcome.result
    # counts of the points that went to the fill (markers), not of the model points / unlabelled kept aside
    columns = np.arange(data.n_markers) if outcome.columns is None else np.asarray(outcome.columns)
    labels = [data.labels[c] for c in columns]
    missing = outcome.work.missing[:, columns]
    filled = result.filled[:, columns]
    n_gaps = len(find_gaps(missing))
    n_left = len(find_gaps(np.isnan(result.positions[:, columns]).any(axis=2)))
    out = console(quiet)
    shown = result.info.get("method", method)
    parts = [f"[bold]{method}[/bold]" + (f" ({shown})" if shown != method else ""),
             f"filled {int(filled.sum())} of {int(missing.sum())} missing samples in {n_gaps} gaps",
             f"{n_left} gaps left", f"{outcome.seconds:.2f} s"]
    if result.n_iter:
        parts.append(f"{result.n_iter} iterations" + ("" if result.converged else " (not converged)"))
    if outcome.rejected is not None:
        parts.append(f"{int(outcome.rejected.sum())} outlier samples rejected")
    if outcome.repaired is not None:
        parts.append(f"{int(outcome.repaired[:, columns].sum())} displaced samples repaired by the denoiser")
    fragments = outcome.settings.get("min_fragment")
    if fragments is not None:
        parts.append(f"{fragments['fragments']} fragments ({fragments['samples']} samples) shorter than "
                     f"{fragments['frames']} frames filled over")
    if "smooth" in outcome.settings:
        parts.append("output smoothed")
    lowpass = outcome.settings.get("lowpass")
    if lowpass:
        parts.append(f"low-passed at {lowpass['used']}")
    if report_path:
        parts.append(f"report {report_path}")
    if status_path:
        parts.append(f"status {status_path}")
    out.print(", ".join(parts), highlight=False, soft_wrap=True)
    if outcome.left is not None and outcome.left[:, columns].any():
        by_reason: dict[str, list[str]] = {}
        for rec in left_records(outcome.left[:, columns]):
            first = data.first_frame + rec["start"]
            by_reason.setdefault(rec["reason"], []).append(
                f"{labels[rec['marker']]} {first}-{first + rec['length'] - 1}")
        for reason, items in by_reason.items():
            shown_items = ", ".join(items[:8]) + (f", ... {len(items) - 8} more" if len(items) > 8 else "")
            out.print(f"{reason}: {len(items)} gaps (marker frames): {shown_items}", markup=False,
                      highlight=False, soft_wrap=True)
    edges = outcome.settings.get("edges", "fill")
    edge_filled = [g for g in find_gaps(missing) if (g.at_start or g.at_end) and filled[g.start, g.marker]]
    if edges == "leave" or edge_filled:
        out.print(f"edges: {edges}; {len(edge_filled)} gaps at the first or last frame filled", markup=False,
                  highlight=False, soft_wrap=True)
    out.print("observed samples " + observed_words(outcome.observed_changed(), stored), markup=False,
              highlight=False, soft_wrap=True)
    declined = result.info.get("declined") or []
    if declined:
        shown_gaps = ", ".join(f"{rec['marker']} at frame {data.first_frame + rec['start']} ({rec['length']} frames: "
                               f"{rec['reason']})" for rec in declined[:5])
        more = f" and {len(declined) - 5} more (see --report)" if len(declined) > 5 else ""
        gaps = f"{len(declined)} gap" + ("s" if len(declined) != 1 else "")
        out.print(f"{method} declined {gaps}, left missing: {shown_gaps}{more}", markup=False, highlight=False,
                  soft_wrap=True)
    copies = result.info.get("copies") or []
    if copies:
        out.print(f"{len(copies)} markers are exact copies of another, filled once and copied: "
                  f"{copies_text(copies)}", markup=False, highlight=False, soft_wrap=True)
    lent = [rec for rec in result.info.get("gap_methods") or []
            if isinstance(rec, dict) and rec.get("method") == "copy"]
    if lent:  # samples one copy missed and another kept
        shown = ", ".join(f"{rec['marker']} {data.first_frame + rec['start']}-"
                          f"{data.first_frame + rec['start'] + rec['length'] - 1}" for rec in lent[:5])
        more = f", ... {len(lent) - 5} more (see --report)" if len(lent) > 5 else ""
        out.print(f"{sum(rec['length'] for rec in lent)} samples taken from an exact copy observed there: "
                  f"{shown}{more}", markup=False, highlight=False, soft_wrap=True)
    copied = {c["marker_index"] for c in copies}  # a copy's gaps are its original's: listed once

    def has_fill(rec: dict) -> bool:
        """Whether the record's gap got a filled sample (one left missing has nothing to check: listed above; a
        record without a run of its own is kept)."""
        covered = records_mask([rec], result.filled.shape)
        return not covered.any() or bool((covered & result.filled).any())

    review = [rec for rec in result.info.get("gap_methods") or [] if isinstance(rec, dict) and rec.get("review")
              and rec.get("marker_index") not in copied and has_fill(rec)]
    if review:  # the gaps the method itself is unsure of: what a technician checks first
        shown_gaps = ", ".join(f"{rec['marker']} {data.first_frame + rec['start']}-"
                               f"{data.first_frame + rec['start'] + rec['length'] - 1}" for rec in review[:8])
        more = f", ... {len(review) - 8} more (see --report)" if len(review) > 8 else ""
        out.print(f"review {len(review)} gap{'s' if len(review) != 1 else ''} (marker frames; the fill is unsure "
                  f"there): {shown_gaps}{more}", markup=False, highlight=False, soft_wrap=True)
    dead = [labels[m] for m in all_missing_markers(missing) if not filled[:, m].any()]  # (a --reference fills some)
    if dead:
        out.print(f"never observed, left empty: {', '.join(dead)}", markup=False, highlight=False)

