"""Exceptions and warnings raised by mocapfill.

Library code raises :class:`MocapfillError` (or a subclass) with a message that names the file, the marker or the
value at fault.  The CLI turns every one of them into a one-line ``Error: ...`` and exit status 1, in one place
(:mod:`mocapfill.cli`).
"""

from __future__ import annotations


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
