"""Options and helpers shared by the commands: one decorator per shared option, one stderr console."""

from __future__ import annotations

import functools
import os
import warnings
from typing import Callable, NamedTuple

import click
from rich.console import Console

from ..errors import ConvergenceWarning, DataWarning

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


@functools.lru_cache(maxsize=2)
def console(quiet: bool = False) -> Console:
    """The stderr console for people: tables, progress, warnings.  Plain when stderr is not a terminal."""
    return Console(stderr=True, quiet=quiet, highlight=False)


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
        for note in data.notes:
            console(quiet).print(f"note: {path}: {note}", markup=False, highlight=False, soft_wrap=True)
    return data


_PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _one_line(message: object) -> str:
    return " ".join(str(message).split())


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
        text = f"{item.category.__name__}: {_one_line(item.message)}"
        if text in seen:
            continue
        seen.add(text)
        out.print(f"[yellow]warning[/yellow] {text}", markup=True, highlight=False, soft_wrap=True)
