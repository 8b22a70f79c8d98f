"""The ``mocapfill`` command line: a thin door over :mod:`mocapfill.io` and the NumPy core.

This module owns the click group and the one place where library errors become ``click.ClickException``
(``Error: <message>``, exit status 1, no traceback).  Each command lives in its own module and registers itself on
:data:`cli` when imported below.
"""

from __future__ import annotations

import sys

import click

from .. import __version__
from ..errors import MocapfillError, one_line


class _Group(click.Group):
    """A click group that turns library errors into one-line messages."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except BrokenPipeError:
            # The reader of our stdout went away (``| head``): not an error of ours.
            sys.stderr.close()
            raise SystemExit(0) from None
        except (MocapfillError, OSError, MemoryError) as exc:
            raise click.ClickException(one_line(exc)) from None


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mocapfill")
def cli() -> None:
    """Repair optical motion-capture marker data.

    Read C3D, CSV (plain, Vicon or Motive), TRC and QTM TSV; fill gaps with bone-length-aware methods; reject
    swapped or ghost markers; score methods on your own data.  "-" as a path means stdin / stdout.
    """


# Commands register themselves on `cli` at import; imported here so `mocapfill --help` lists them all.
from . import info, fill, bones, evaluate, batch, train  # noqa: E402,F401


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="mocapfill")
