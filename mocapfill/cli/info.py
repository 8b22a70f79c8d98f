"""`mocapfill info FILE`: what is in a capture and where its gaps are (rich tables on stderr, or JSON on stdout)."""

from __future__ import annotations

import json
import sys

import click
from rich import box
from rich.table import Table

from . import cli
from .common import ReadOptions, copies_text, grouped_notes, input_options, console, quiet_option, read_input


def _frames(n: int, rate: float) -> str:
    return f"{n} frames ({n / rate:.2f} s)" if rate > 0 else f"{n} frames"


def _ranges(ranges: list[dict], limit: int = 8) -> str:
    shown = [f"{r['first_frame']}" if r["length"] == 1 else f"{r['first_frame']}-{r['last_frame']}"
             for r in ranges[:limit]]
    more = f" and {len(ranges) - limit} more" if len(ranges) > limit else ""
    return ", ".join(shown) + more


def _show(summary: dict, quiet: bool) -> None:
    out = console(quiet)
    rate = summary["rate"]
    overview = Table(show_header=False, box=None, pad_edge=False, title=f"[bold]{summary['path']}[/bold]",
                     title_justify="left")
    overview.add_column(style="bold")
    overview.add_column()
    overview.add_row("format", str(summary["format"]))
    overview.add_row("frames", f"{summary['n_frames']} (first frame {summary['first_frame']})")
    overview.add_row("rate", f"{rate:g} Hz")
    overview.add_row("duration", f"{summary['duration_seconds']:.3f} s")
    overview.add_row("units", summary["units"])
    overview.add_row("markers", f"{summary['n_markers']} ({summary['markers_complete']} complete)")
    overview.add_row("missing", f"{summary['percent_missing']:.2f} % of marker samples "
                                f"({summary['n_missing']} samples, {summary['n_gaps']} gaps)")
    overview.add_row("longest gap", _frames(summary["longest_gap_frames"], rate) if summary["n_gaps"] else "none")
    throughout = summary["markers_missing_throughout"]
    overview.add_row("missing throughout", ", ".join(throughout) if throughout else "none")
    blackouts = summary["blackouts"]
    overview.add_row("blackout frames", f"{summary['blackout_frames']}: {_ranges(blackouts)}" if blackouts
                     else "none")
    aside = [f"{len(summary['model_points'])} model points" if summary["model_points"] else "",
             f"{len(summary['unlabelled'])} unlabelled trajectories" if summary["unlabelled"] else ""]
    if any(aside):
        overview.add_row("kept aside", " and ".join(a for a in aside if a) + " (not filled, not counted above)")
    from ..guards.held import held_line

    overview.add_row("held samples", held_line(summary["held"]))
    copies = summary.get("copies") or []
    if copies:
        overview.add_row("copies", f"{len(copies)} markers repeat another's samples exactly (the default fills them "
                                   f"once): {copies_text(copies)}")
    c3d = summary.get("c3d")
    if c3d:
        overview.add_row("C3D", f"{c3d['processor']} {c3d['storage']} storage, {c3d['analog_channels']} analog "
                                f"channels, {len(c3d['model_outputs'])} model outputs (not markers)")
    out.print(overview)

    table = Table(title="markers", title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
    widest = max((len(m["label"]) + (21 if m["missing_throughout"] else 0) for m in summary["markers"]), default=6)
    table.add_column("marker", no_wrap=True, min_width=min(widest, 48))
    table.add_column("missing %", justify="right", no_wrap=True)
    table.add_column("gaps", justify="right", no_wrap=True)
    table.add_column("longest gap", justify="right", no_wrap=True)
    table.add_column("start", justify="center", no_wrap=True)
    table.add_column("end", justify="center", no_wrap=True)
    for m in summary["markers"]:
        style = "red" if m["missing_throughout"] else ("yellow" if m["n_gaps"] else None)
        longest = (f"{m['longest_gap_frames']} ({m['longest_gap_seconds']:.2f} s)" if m["n_gaps"] else "")
        table.add_row(m["label"] + (" (missing throughout)" if m["missing_throughout"] else ""),
                      f"{m['percent_missing']:.1f}", str(m["n_gaps"]), longest,
                      "yes" if m["gap_at_start"] else "", "yes" if m["gap_at_end"] else "", style=style)
    table.caption = "longest gap in frames (seconds); start / end: a gap touches the first / last frame"
    table.caption_justify = "left"
    out.print(table)
    for kind, names in (("model points", summary["model_points"]), ("unlabelled", summary["unlabelled"])):
        if names:
            out.print(f"{kind}: {', '.join(names[:40])}" + (f" and {len(names) - 40} more" if len(names) > 40 else ""),
                      markup=False)
    for note in grouped_notes(summary["notes"]):
        out.print(f"note: {note}", markup=False)


@cli.command("info")
@click.argument("file", type=str)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout instead of tables.")
@click.option("--report", "report_path", type=str, default=None,
              help="Also write FILE.html: a self-contained page with a 3-D player of the raw capture and its gaps.")
@input_options
@quiet_option
def info(file: str, as_json: bool, report_path: str | None, reading: ReadOptions, quiet: bool) -> None:
    """Show frames, rate, units, markers and the gaps of FILE ("-" reads stdin).

    Per marker: percent missing, number of gaps, the longest gap (frames and seconds), gaps touching the start or
    the end, markers missing throughout; and the blackout frames (every marker missing).  With --report take.html,
    also a page to look at the raw capture in 3-D before repairing it.
    """
    from ..summary import summarize

    if report_path is not None:
        from ..io.atomic import check_output_path

        if not report_path.lower().endswith((".html", ".htm")):
            raise click.BadParameter("must end in .html", param_hint="--report")
        check_output_path(report_path, file)
    data = read_input(file, reading, show_notes=False)  # the notes are part of the table below
    summary = summarize(data)
    if report_path is not None:
        from ..report.capture_html import write_capture_report

        write_capture_report(data, summary, report_path)
    if as_json:
        sys.stdout.write(json.dumps(summary, indent=2, allow_nan=False) + "\n")
        sys.stdout.flush()
        return
    _show(summary, quiet)
