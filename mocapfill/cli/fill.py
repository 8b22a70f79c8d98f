"""`mocapfill fill IN OUT`: fill the gaps of a capture and write it back (``-`` = stdin / stdout).

The command is a thin door: read with :func:`mocapfill.io.read`, optionally reject outliers
(:func:`mocapfill.outliers.reject_outliers`), fill with :func:`mocapfill.api.fill`, optionally smooth
(:func:`mocapfill.smooth.savgol_smooth`), write with :func:`mocapfill.io.write`, optionally write a report
(:mod:`mocapfill.report`).  stdout carries data only; progress, warnings and the summary go to stderr.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from typing import Any

import click
import numpy as np

from ..methods import DEFAULT_METHOD, METHODS, get_method
from . import cli
from .common import ReadOptions, console, format_options, quiet_option, read_input, show_warnings


class _ProgressBar:
    """A rich progress bar for a method's ``progress(iteration, n_max, objective)`` callback (stderr, terminals)."""

    def __init__(self, method: str, quiet: bool) -> None:
        out = console(quiet)
        self.enabled = not quiet and out.is_terminal
        self._bar = None
        self._task = None
        if self.enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self._bar = Progress(TextColumn(f"{method}"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("objective {task.fields[objective]}"), TimeElapsedColumn(),
                                 console=out, transient=True)
            self._task = self._bar.add_task(method, total=None, objective="-")

    def __enter__(self) -> "_ProgressBar":
        if self._bar is not None:
            self._bar.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.stop()

    def __call__(self, iteration: int, n_max: int, objective: float) -> None:
        if self._bar is not None:
            self._bar.update(self._task, completed=iteration, total=n_max, objective=f"{objective:.6g}")


_EPILOG = "\b\nMethods:\n" + "\n".join(f"  {spec.name:<10} {spec.summary}" for spec in METHODS.values())


@cli.command("fill", epilog=_EPILOG)
@click.argument("input_path", metavar="IN", type=str)
@click.argument("output_path", metavar="OUT", type=str)
@click.option("-m", "--method", type=click.Choice(list(METHODS)), default=DEFAULT_METHOD, show_default=True,
              help="Fill method (listed below; 'auto' is the most accurate measured).")
@click.option("--hidden", type=click.IntRange(min=1), default=None,
              help="Hidden dimension of the dynamical models (dynammo, bolero-*; default 16).")
@click.option("--max-iter", type=click.IntRange(min=0), default=None, help="Iteration cap of iterative methods.")
@click.option("--tol", type=click.FloatRange(min=0), default=None,
              help="Convergence tolerance (relative change) of iterative methods.")
@click.option("--seed", type=int, default=None, help="Random seed (results are reproducible with it).")
@click.option("--report", "report_path", type=str, default=None,
              help="Write a report of the fill: FILE.json or FILE.html (self-contained page with plots).")
@click.option("--bones", "bones_path", type=str, default=None,
              help="Bones file (from `mocapfill estimate-bones`) for bone-aware methods; default: estimated from "
                   "the observed frames.")
@click.option("--reject-outliers", is_flag=True, help="Remove samples that break inter-marker distance ranges "
              "(Holden's rule) before filling; they become gaps and are filled.")
@click.option("--delta", type=click.FloatRange(min=0), default=None,
              help="Outlier margin as a fraction of each pair's distance range (default 0.1).")
@click.option("--reference", "reference_path", type=str, default=None,
              help="A clean capture of the same marker set giving the distance ranges for --reject-outliers "
                   "(default: the file itself).")
@click.option("--smooth", is_flag=True,
              help="Savitzky-Golay smoothing of the output (off by default: it changes observed samples).")
@click.option("--smooth-window", type=click.IntRange(min=1), default=None,
              help="Smoothing window in frames, odd (default about 1/15 s).")
@click.option("--smooth-order", type=click.IntRange(min=0), default=None, help="Smoothing polynomial order (3).")
@format_options
@quiet_option
@click.option("--force", is_flag=True, help="Allow OUT to be the same file as IN (it is replaced atomically).")
def fill_command(input_path: str, output_path: str, method: str, hidden: int | None, max_iter: int | None,
                 tol: float | None, seed: int | None, report_path: str | None, bones_path: str | None,
                 reject_outliers: bool, delta: float | None, reference_path: str | None, smooth: bool,
                 smooth_window: int | None, smooth_order: int | None, output_format: str | None,
                 reading: ReadOptions, quiet: bool, force: bool) -> None:
    """Fill the gaps of IN and write the result to OUT ("-" = stdin / stdout).

    Observed samples are written back unchanged (unless --smooth).  Progress, warnings and a summary go to
    stderr; stdout carries data only, so `mocapfill fill - - --format csv < in.csv > out.csv` works in a pipe.
    """
    from ..io import write
    from ..io.atomic import check_output_path

    if (delta is not None or reference_path is not None) and not reject_outliers:
        raise click.UsageError("--delta and --reference only apply with --reject-outliers")
    if (smooth_window is not None or smooth_order is not None) and not smooth:
        raise click.UsageError("--smooth-window and --smooth-order only apply with --smooth")
    if not force:
        check_output_path(output_path, input_path)
    if report_path is not None:
        if not report_path.lower().endswith((".json", ".html", ".htm")):
            raise click.BadParameter("must end in .json or .html", param_hint="--report")
        check_output_path(report_path, input_path, output_path)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        data = read_input(input_path, reading, quiet=quiet)
        work = data

        rejected = None
        settings: dict[str, Any] = {}
        if reject_outliers:
            from ..outliers import reject_outliers as reject

            options: dict[str, Any] = {"units": data.units, "labels": list(data.labels),
                                       "rate": data.rate}
            if delta is not None:
                options["delta"] = delta
            if reference_path is not None:
                check_output_path(output_path, reference_path)
                ref = read_input(reference_path, reading._replace(format=None), quiet=quiet)
                options.update(reference=ref.positions, reference_labels=list(ref.labels),
                               reference_units=ref.units)
            outcome = reject(data.positions, **options)
            rejected = np.asarray(outcome.rejected, dtype=bool)
            work = data.with_positions(outcome.positions)
            settings["reject_outliers"] = {"delta": 0.1 if delta is None else delta,
                                           "reference": reference_path, "rejected": int(rejected.sum())}

        bones = None
        if bones_path is not None:
            from ..bones import load_bones

            bones = load_bones(bones_path, data.labels, units=data.units)

        spec = get_method(method)
        accepted = spec.parameters()
        options = {key: value for key, value in (("hidden", hidden), ("max_iter", max_iter), ("tol", tol),
                                                  ("seed", seed), ("bones", bones)) if value is not None}
        settings.update({k: v for k, v in options.items() if k != "bones"})
        if bones_path is not None:
            settings["bones"] = bones_path

        from ..api import fill

        started = time.perf_counter()
        with _ProgressBar(method, quiet) as bar:
            if bar.enabled and "progress" in accepted:
                options["progress"] = bar
            result = fill(work, method, **options)
        seconds = time.perf_counter() - started

        positions = result.positions
        if smooth:
            from ..smooth import savgol_smooth

            smooth_options: dict[str, Any] = {"rate": data.rate}
            if smooth_window is not None:
                smooth_options["window"] = smooth_window
            if smooth_order is not None:
                smooth_options["order"] = smooth_order
            positions = savgol_smooth(positions, **smooth_options)
            settings["smooth"] = {"window": smooth_window, "order": smooth_order}

        out_data = data.with_positions(positions)
        if rejected is not None:  # a rejected sample filled again is written as filled, not with its old residual
            from ..io.c3d import mark_refilled

            out_data = mark_refilled(out_data, rejected)
        if force:
            # The writer refuses the path the data came from; --force says the user wants exactly that.
            out_data = dataclasses.replace(out_data, path=None)
        write(out_data, output_path, format=output_format)

        if report_path is not None:
            from ..report import build_fill_report, write_report

            report_bones = bones
            if report_bones is None:
                # The report's bone-length checks need bones: estimate them from the observed frames of the input
                # (as the bone-aware methods do), never from filled samples.
                from ..bones import estimate_bones

                report_bones = estimate_bones(work.positions, units=data.units, labels=data.labels)
                if len(report_bones) == 0:
                    report_bones = None
            report = build_fill_report(data, result, method=method, settings=settings, seconds=seconds,
                                       input_path=input_path, output_path=output_path, bones=report_bones,
                                       rejected=rejected, smoothed=smooth)
            write_report(report, report_path, data=data, result=result, bones=report_bones)

    show_warnings(caught, quiet)
    _summary(data, work, result, method, seconds, rejected, smooth, report_path, quiet)


def _summary(data, work, result, method: str, seconds: float, rejected, smoothed: bool, report_path, quiet: bool
             ) -> None:
    """A few lines on stderr: method, filled samples, gaps left, time, convergence."""
    from ..gaps import all_missing_markers, find_gaps

    out = console(quiet)
    missing = work.missing
    left = np.isnan(result.positions).any(axis=2)
    n_gaps = len(find_gaps(missing))
    n_left = len(find_gaps(left))
    shown = result.info.get("method", method)
    parts = [f"[bold]{method}[/bold]" + (f" ({shown})" if shown != method else ""),
             f"filled {int(result.filled.sum())} of {int(missing.sum())} missing samples in {n_gaps} gaps",
             f"{n_left} gaps left", f"{seconds:.2f} s"]
    if result.n_iter:
        parts.append(f"{result.n_iter} iterations" + ("" if result.converged else " (not converged)"))
    if rejected is not None:
        parts.append(f"{int(rejected.sum())} outlier samples rejected")
    if smoothed:
        parts.append("output smoothed")
    if report_path:
        parts.append(f"report {report_path}")
    out.print(", ".join(parts), highlight=False, soft_wrap=True)
    dead = [data.labels[m] for m in all_missing_markers(missing)]
    if dead:
        out.print(f"never observed, left empty: {', '.join(dead)}", markup=False, highlight=False)
