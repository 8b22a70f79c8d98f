"""Exceptions and warnings raised by mocapfill.

Library code raises :class:`MocapfillError` (or a subclass) with a message that names the file, the marker or the
value at fault.  The CLI turns every one of them into a one-line ``Error: ...`` and exit status 1, in one place
(:mod:`mocapfill.cli`).
"""

from __future__ import annotations

import warnings


class MocapfillError(Exception):
    """Base class of every error mocapfill raises on purpose."""


class InputError(MocapfillError):
    """A file cannot be read or written: missing, unreadable, same as the input, unwritable directory."""


class FormatError(MocapfillError):
    """A file is readable but its content is not valid for its format (truncated C3D, ragged CSV, ...)."""


class MethodError(MocapfillError):
    """A fill method was asked for something it cannot do (unknown method, bad option value)."""


class ConvergenceWarning(UserWarning):
    """An iterative method stopped at its iteration cap before meeting its tolerance."""


class DataWarning(UserWarning):
    """Something in the input was repaired or ignored on reading (duplicate labels, truncated rows, ...)."""


def one_line(problem: BaseException | object, where: str | None = None) -> str | None:
    """The user's one-line message for ``problem``: the one place that words an error, for the CLI and ``batch``.

    A :class:`MocapfillError` says it all itself; an ``OSError`` becomes ``FILE: reason``; ``MemoryError`` becomes
    ``out of memory`` (prefixed by ``where``, the file at hand, when given); any other exception (a bug of ours)
    becomes ``where: TypeName: message``.  Text is folded onto one line.  Returns None for an exception that is not
    an error of the input (``KeyboardInterrupt``, ``SystemExit``): those propagate.
    """
    prefix = f"{where}: " if where else ""
    if isinstance(problem, (KeyboardInterrupt, SystemExit, GeneratorExit)):
        return None
    if isinstance(problem, MocapfillError):
        text = str(problem)
    elif isinstance(problem, MemoryError):
        text = f"{prefix}out of memory"
    elif isinstance(problem, OSError):
        filename = getattr(problem, "filename", None) or where
        text = f"{filename}: {problem.strerror or problem}" if filename else str(problem.strerror or problem)
    elif isinstance(problem, BaseException):
        text = f"{prefix}{type(problem).__name__}: {problem}"
    else:
        text = str(problem)
    return " ".join(text.split())


def warning_line(item: warnings.WarningMessage) -> str:
    """The user's one-line text for a caught warning: its category, then its message (the message is the warning
    object, whose :func:`one_line` would name the category again)."""
    return f"{item.category.__name__}: {one_line(str(item.message))}"
