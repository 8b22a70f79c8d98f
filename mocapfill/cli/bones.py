"""`mocapfill estimate-bones IN [-o bones.json]`: the rigid marker pairs of a capture, as an editable file."""

from __future__ import annotations

import re
import sys

import click
import numpy as np
from rich import box
from rich.table import Table

from ..errors import MocapfillError
from . import cli
from .common import ReadOptions, input_options, console, quiet_option, read_input

_LENGTH = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(mm|cm|m)?\s*$")


def parse_length(text: str | None, units: str, option: str) -> float | None:
    """A length option: a bare number is in the file's ``units``; "6mm", "0.6cm", "0.006m" are converted."""
    from ..units import length_factor

    if text is None:
        return None
    match = _LENGTH.match(str(text))
    if not match:
        raise MocapfillError(f"{option}: not a length: {text!r} (a number, optionally followed by mm, cm or m)")
    value = float(match.group(1))
    if match.group(2):
        value *= length_factor(match.group(2), units)
    return value


def _show(bones, labels, units: str, n_markers: int, min_partners: int, path: str, quiet: bool,
          breaks=None) -> None:
    out = console(quiet)
    table = Table(title=f"[bold]{path}[/bold]: {len(bones)} bones", title_justify="left", box=box.SIMPLE_HEAD,
                  pad_edge=False)
    table.add_column("marker a", no_wrap=True)
    table.add_column("marker b", no_wrap=True)
    table.add_column(f"length ({units})", justify="right", no_wrap=True)
    table.add_column(f"spread ({units})", justify="right", no_wrap=True)
    table.add_column("spread %", justify="right", no_wrap=True)
    table.add_column("frames", justify="right", no_wrap=True)
    for (i, j), length, spread, frames in zip(bones.pairs, bones.lengths, bones.spread, bones.n_frames):
        table.add_row(labels[i], labels[j], f"{length:.4g}", f"{spread:.3g}", f"{100 * spread / length:.2f}",
                      str(frames))
    table.caption = ("spread: robust standard deviation of the distance, (95th - 5th percentile) / 3.29, over the "
                     "frames where both markers are observed")
    table.caption_justify = "left"
    out.print(table)
    degree = bones.partners(n_markers)
    loose = [f"{labels[m]} ({degree[m]})" for m in range(n_markers) if degree[m] < min_partners]
    if loose:
        out.print(f"held by fewer than {min_partners} bones: " + ", ".join(loose), markup=False)
    let_go = [] if breaks is None else [k for k in np.argsort(-breaks, kind="stable") if breaks[k] >= 5e-4]
    if let_go:
        shown = [f"{labels[bones.pairs[k][0]]} - {labels[bones.pairs[k][1]]} ({100 * breaks[k]:.1f} %)"
                 for k in let_go[:10]]
        more = f", and {len(let_go) - 10} more" if len(let_go) > 10 else ""
        out.print("bones that did not hold at some frames (their share of the frames with both markers seen; the "
                  "default fill leaves such a bone out where its predictions say it broke): " + ", ".join(shown) + more,
                  markup=False)


@cli.command("estimate-bones")
@click.argument("input_path", metavar="IN", type=str)
@click.option("-o", "--output", type=str, default=None,
              help='Where to write the bones (default "-": stdout).')
@click.option("--format", "fmt", type=click.Choice(["json", "csv"]), default=None,
              help="Output format (default: from the output's extension, else json).")
@click.option("--max-rel-spread", type=float, default=None, show_default=False,
              help="Largest spread relative to the length (default 0.04).")
@click.option("--max-abs-spread", type=str, default=None,
              help='Largest spread, e.g. "6mm" or "0.006m"; a bare number is in the file\'s units (default 6 mm).')
@click.option("--min-frames", type=int, default=None,
              help="Fewest frames both markers must be observed together (default min(100, frames/2), >= 10).")
@click.option("--min-partners", type=int, default=None,
              help="Give every marker at least this many bones where the data allows (default 3).")
@input_options
@quiet_option
def estimate_bones_command(input_path: str, output: str | None, fmt: str | None, max_rel_spread: float | None,
                           max_abs_spread: str | None, min_frames: int | None, min_partners: int | None,
                           reading: ReadOptions, quiet: bool) -> None:
    """Find the marker pairs of IN that behave like rigid bones ("-" reads stdin).

    A pair is a bone when the spread of its distance, over the frames where both markers are observed, is small
    both relative to its length and in absolute terms; markers held by fewer than --min-partners bones get their
    most rigid remaining pairs if those are nearly as rigid.  The output (JSON, or CSV) lists per bone the two
    labels, the length (median distance), the spread and the frames used; edit it and pass it back with
    `mocapfill fill --bones FILE`.  A table goes to stderr, with the bones that did not hold at some of those frames
    (a hand that lets go of what it holds, a marker that slides).
    """
    from ..bones.boneset import (DEFAULT_MAX_REL_SPREAD, DEFAULT_MIN_PARTNERS, bones_to_csv, bones_to_dict,
                         estimate_bones, save_bones)
    from ..io.atomic import check_output_path
    import json

    output = output or "-"
    check_output_path(output, input_path)
    if fmt is None:
        fmt = "csv" if output.lower().endswith(".csv") else "json"
    data = read_input(input_path, reading, quiet=quiet)
    min_partners = DEFAULT_MIN_PARTNERS if min_partners is None else min_partners
    for name, value in (("--min-frames", min_frames), ("--min-partners", min_partners)):
        if value is not None and value < 0:
            raise MocapfillError(f"{name} must be >= 0, got {value}")
    if max_rel_spread is not None and not max_rel_spread > 0:
        raise MocapfillError(f"--max-rel-spread must be positive, got {max_rel_spread}")
    abs_spread = parse_length(max_abs_spread, data.units, "--max-abs-spread")
    if abs_spread is not None and not abs_spread > 0:
        raise MocapfillError(f"--max-abs-spread must be positive, got {max_abs_spread}")
    bones = estimate_bones(data.positions, units=data.units, labels=data.labels,
                           max_rel_spread=DEFAULT_MAX_REL_SPREAD if max_rel_spread is None else max_rel_spread,
                           max_abs_spread=abs_spread, min_frames=min_frames, min_partners=min_partners)
    if output == "-":
        if fmt == "csv":
            text = bones_to_csv(bones, labels=data.labels, units=data.units)
        else:
            text = json.dumps(bones_to_dict(bones, labels=data.labels, units=data.units), indent=2) + "\n"
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        save_bones(bones, output, labels=data.labels, units=data.units, format=fmt)
    # The data is written before the table: a reader of stderr that goes away must not cost the output.
    breaks = None
    if not quiet and len(bones):
        from ..methods.auto import bone_break_rates
        from ..methods.auto_config import DEFAULT_CONFIG
        from ..units import length_factor

        breaks = bone_break_rates(data.positions, bones, DEFAULT_CONFIG, length_factor("mm", data.units))
    _show(bones, data.labels, data.units, data.n_markers, min_partners, data.path or input_path, quiet, breaks)
    if output != "-":
        console(quiet).print(f"wrote {len(bones)} bones to {output}", markup=False)
