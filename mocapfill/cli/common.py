"""Options and helpers shared by the commands: one decorator per shared option, one stderr console."""

from __future__ import annotations

import dataclasses
import functools
import os
import warnings
from typing import Callable, NamedTuple

import click
from rich.console import Console, ConsoleDimensions

from ..errors import ConvergenceWarning, DataWarning, MethodError, warning_line

from ..io import READ_FORMATS, WRITE_FORMATS

#: output formats (``--format``); what ``--input-format`` accepts is ``READ_FORMATS``.
FORMATS = WRITE_FORMATS


def quiet_option(func: Callable) -> Callable:
    """``--quiet/-q``: nothing on stderr but errors."""
    return click.option("-q", "--quiet", is_flag=True, help="Print nothing on stderr but errors.")(func)


class ReadOptions(NamedTuple):
    """How to read an input: ``--input-format``, ``--rate`` and ``--override-rate``."""

    format: str | None = None
    rate: float | None = None
    override_rate: bool = False


def input_options(func: Callable) -> Callable:
    """``--input-format``, ``--rate`` and ``--override-rate``, handed to the command as one ``reading: ReadOptions``."""

    @functools.wraps(func)
    def wrapper(*args, input_format=None, rate=None, override_rate=False, **kwargs):
        return func(*args, reading=ReadOptions(input_format, rate, override_rate), **kwargs)

    wrapper = click.option("--override-rate", is_flag=True,
                           help="Use --rate even where the file states another rate.")(wrapper)
    wrapper = click.option("--rate", type=click.FloatRange(min=0, min_open=True), default=None, metavar="HZ",
                           help="Frame rate for a file that carries none (a bare CSV).")(wrapper)
    wrapper = click.option("--input-format", type=click.Choice(READ_FORMATS), default=None,
                           help="Format of the input (default: from its extension; needed for stdin).")(wrapper)
    return wrapper


def format_options(func: Callable) -> Callable:
    """``--format`` (output) and the input options: needed when a path is "-" or has an unusual extension."""
    func = input_options(func)
    func = click.option("-f", "--format", "output_format", type=click.Choice(FORMATS), default=None,
                        help="Format of the output (default: from its extension, else the input's).")(func)
    return func


def fill_options(func: Callable) -> Callable:
    """``--method`` and every fill option (``--hidden`` ... ``--smooth-order``), shared by ``fill`` and ``batch``.

    The command receives them as one ``fill_settings: FillSettings``; an option that needs a step that is off
    (``--delta`` without ``--reject-outliers``) is a usage error.
    """
    from ..methods import DEFAULT_METHOD, METHODS
    from ..pipeline import FillSettings

    names = [field.name for field in dataclasses.fields(FillSettings)]

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        settings = FillSettings(**{name: kwargs.pop(name) for name in names})
        option_name = lambda field: "--" + field.replace("_", "-")  # noqa: E731
        try:
            settings.check_values(name=option_name)
        except MethodError as exc:  # a malformed value: one line
            raise click.ClickException(str(exc)) from None
        try:
            settings.check(name=option_name)
        except MethodError as exc:
            raise click.UsageError(str(exc)) from None
        return func(*args, fill_settings=settings, **kwargs)

    options = [
        click.option("-m", "--method", type=click.Choice(list(METHODS)), default=DEFAULT_METHOD, show_default=True,
                     help="Fill method (listed below; 'auto' is the most accurate measured)."),
        click.option("--hidden", type=click.IntRange(min=1), default=None,
                     help="Hidden dimension of the dynamical models (dynammo, bolero-*; default 16); at most 3 x the "
                          "observed markers (a larger value is capped there, with a warning)."),
        click.option("--max-iter", type=click.IntRange(min=0), default=None,
                     help="Iteration cap of iterative methods."),
        click.option("--tol", type=click.FloatRange(min=0), default=None,
                     help="Convergence tolerance (relative change) of iterative methods."),
        click.option("--seed", type=int, default=None, help="Random seed (results are reproducible with it)."),
        click.option("--bones", "bones", type=str, default=None,
                     help="Bones file (from `mocapfill estimate-bones`) for bone-aware methods; default: estimated "
                          "from the observed frames."),
        click.option("--reject-outliers", is_flag=True, help="Remove samples that break inter-marker distance "
                     "ranges (Holden's rule) before filling; they become gaps and are filled."),
        click.option("--delta", type=click.FloatRange(min=0), default=None,
                     help="Outlier margin as a fraction of each pair's distance range (default 0.1)."),
        click.option("--reference", "reference", type=str, multiple=True,
                     help="A reference take of the same marker set (repeatable: the static trial, other takes of the "
                          "session): its frames train the fill's body model, weighted by how well its body fits; a "
                          "moving one also gives --reject-outliers its distance ranges (default: the file itself)."),
        click.option("--model", "model", type=str, default=None,
                     help="A denoiser model of this marker layout (from `mocapfill train`): for --method learned and "
                          "--denoise."),
        click.option("--denoise", is_flag=True,
                     help="Observed samples the --model judges displaced or swapped become gaps and are refilled "
                          "(reported as repaired)."),
        click.option("--keep-held", is_flag=True,
                     help="Keep held and frozen samples (a marker repeating its exact position while the body moves, "
                          "a coordinate stuck at exactly 0) as observed; by default they become gaps and are filled."),
        click.option("--smooth", is_flag=True,
                     help="Savitzky-Golay smoothing of the output (off by default: it changes observed samples)."),
        click.option("--smooth-window", type=click.IntRange(min=1), default=None,
                     help="Smoothing window in frames, odd (default about 1/15 s)."),
        click.option("--smooth-order", type=click.IntRange(min=0), default=None,
                     help="Smoothing polynomial order (3)."),
        click.option("--max-gap", "max_gap", type=str, default=None, metavar="DURATION",
                     help="Leave gaps longer than this missing: frames (40) or seconds (0.5s). The reports list "
                          "them as left missing."),
        click.option("--edges", type=click.Choice(["fill", "leave"]), default="fill", show_default=True,
                     help="Fill or leave the gaps that touch the first or last frame."),
        click.option("--min-fragment", type=click.IntRange(min=1), default=None, metavar="FRAMES",
                     help="Observed stretches shorter than this between two gaps join the gap around them and are "
                          "filled with it (changes observed samples; the report counts them)."),
        click.option("--markers", type=str, default=None, metavar="PATTERNS",
                     help="Fill only these markers: labels or shell patterns, comma-separated (L*,R*), matched "
                          "after a Subject: prefix; every marker still informs the fill."),
        click.option("--exclude", type=str, default=None, metavar="PATTERNS",
                     help="Do not fill these markers (same forms as --markers)."),
        click.option("--ik-model", "ik_model", type=str, default=None, metavar="MODEL.osim",
                     help="Scaled OpenSim model whose markers carry the capture's labels, for --method opensim-ik "
                          "(the kinematic fill; needs the extra mocapfill[opensim])."),
        click.option("--donors", multiple=True, metavar="[MARKER=]D1,D2,...",
                     callback=lambda ctx, param, value: ";".join(value) if value else None,
                     help="Donor markers of --method pattern / rigid, by label: MARKER=D1,D2 for one marker "
                          "(repeatable), D1,D2 for every marker (default: per gap, the markers whose distance to "
                          "the gapped one varies least)."),
        click.option("--lowpass", type=str, default=None, metavar="HZ|auto|auto-marker",
                     help="Zero-lag 4th-order Butterworth low-pass after the fill (gain 0.5 at HZ), each continuous "
                          "stretch alone; 'auto' picks the cutoff by Winter's residual analysis for the take, "
                          "'auto-marker' per marker.  Changes observed samples; the report gives the cutoff."),
    ]
    for option in reversed(options):
        wrapper = option(wrapper)
    return wrapper


#: the width a console writing to a file or a pipe lays its tables out in: wide enough that no cell is cut.
UNBOUNDED_WIDTH = 10_000


class _StderrConsole(Console):
    """A rich console whose width, when its stream is not a terminal, is :data:`UNBOUNDED_WIDTH`.

    rich lays out a file's or a pipe's output in 80 columns (or the width of whichever standard stream is a
    terminal, or ``COLUMNS``), cutting table cells with an ellipsis; a log or a CI's output has no width to fit.
    Decided at each print, since the stream may be replaced (click's test runner); a terminal keeps rich's width.
    """

    @property
    def size(self) -> ConsoleDimensions:
        size = super().size
        if not self.is_terminal:
            return ConsoleDimensions(UNBOUNDED_WIDTH, size.height)
        return size

    @size.setter
    def size(self, new_size: tuple[int, int]) -> None:
        Console.size.fset(self, new_size)


@functools.lru_cache(maxsize=2)
def console(quiet: bool = False) -> Console:
    """The stderr console for people: tables, progress, warnings.  Plain and uncut when stderr is not a terminal."""
    return _StderrConsole(stderr=True, quiet=quiet, highlight=False)


class StderrProgress:
    """A transient rich progress bar on stderr, shown on terminals only and never with --quiet.

    ``columns()`` builds the rich columns (called only when the bar shows, so rich.progress loads lazily);
    ``fields`` are the task's initial custom fields.  The bar starts at its first update: one that is never updated
    (a method that reports no progress) starts no refresh thread, so the work it wraps may fork
    (:func:`mocapfill.runtime.executor.can_fork`).
    """

    def __init__(self, quiet: bool, columns: Callable[[], tuple], **fields) -> None:
        out = console(quiet)
        self.enabled = not quiet and out.is_terminal
        self._bar = None
        if self.enabled:
            from rich.progress import Progress

            self._bar = Progress(*columns(), console=out, transient=True)
            self._task = self._bar.add_task("", total=None, **fields)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        if self._bar is not None and self._bar.live.is_started:
            self._bar.stop()

    def update(self, **changes) -> None:
        if self._bar is not None:
            if not self._bar.live.is_started:
                self._bar.start()
            self._bar.update(self._task, **changes)


def read_input(path: str, reading: ReadOptions = ReadOptions(), *, quiet: bool = False, show_notes: bool = True):
    """Read a capture for a command, with the user's ``--input-format`` / ``--rate`` (``reading``).

    What the reader repaired (renamed duplicate labels, a truncated file, ...) is kept in ``data.notes``; it is shown
    here as one line each on stderr (``show_notes``), never as a Python warning with a source line.
    """
    from ..io import read

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        data = read(path, format=reading.format, rate=reading.rate, override_rate=reading.override_rate)
    if show_notes:
        for note in grouped_notes(data.notes):
            console(quiet).print(f"note: {path}: {note}", markup=False, highlight=False, soft_wrap=True)
    return data


def grouped_notes(notes: list[str], shown: int = 3) -> list[str]:
    """The reader's notes, the renamed duplicate labels as one line (a file that writes every label three times
    would otherwise print a line per copy): "48 duplicate labels renamed: 'A' -> 'A_2', ... (all in the report)"."""
    from ..io.labels import RENAMED_NOTE

    renamed = [n for n in notes if n.startswith(RENAMED_NOTE)]
    if len(renamed) <= shown:
        return list(notes)
    pairs = [n[len(RENAMED_NOTE):].replace(" renamed ", " -> ") for n in renamed[:shown]]
    line = f"{len(renamed)} duplicate labels renamed: {', '.join(pairs)}, ... (all in the report)"
    return [line] + [n for n in notes if not n.startswith(RENAMED_NOTE)]


def copies_text(copies: list[dict], shown: int = 4) -> str:
    """The first ``shown`` of the ``copies`` records (``info["copies"]``, ``summary["copies"]``): "B = A, D = C, ..."."""
    return ", ".join(f"{c['marker']} = {c['copy_of']}" for c in copies[:shown]) + (", ..." if len(copies) > shown
                                                                                  else "")


_PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _ours(item: warnings.WarningMessage) -> bool:
    """Warnings meant for the user: mocapfill's own categories, or any warning raised from mocapfill's code."""
    if issubclass(item.category, (ConvergenceWarning, DataWarning)):
        return True
    return issubclass(item.category, UserWarning) and _PACKAGE_DIR in os.path.abspath(item.filename or "")


def show_warnings(caught: list[warnings.WarningMessage], quiet: bool) -> None:
    """Each distinct warning once, as one line on stderr (no traceback, no source line)."""
    out = console(quiet)
    seen: set[str] = set()
    for item in caught:
        if not _ours(item):
            continue
        text = warning_line(item)
        if text in seen:
            continue
        seen.add(text)
        out.print(f"[yellow]warning[/yellow] {text}", markup=True, highlight=False, soft_wrap=True)
