"""The ``mocapfill`` command line: a thin door over :mod:`mocapfill.io` and the NumPy core.

This module owns the click group and the one place where library errors become ``click.ClickException``
(``Error: <message>``, exit status 1, no traceback).  Each command lives in its own module and registers itself on
:data:`cli` when imported below.
"""

from __future__ import annotations

import sys

import click

from .. import __version__
from ..errors import MocapfillError


class _Group(click.Group):
    """A click group that turns library errors into one-line messages."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except MocapfillError as exc:
            raise click.ClickException(str(exc)) from None
        except BrokenPipeError:
            # The reader of our stdout went away (``| head``): not an error of ours.
            sys.stderr.close()
            raise SystemExit(0) from None
        except OSError as exc:
            where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
            raise click.ClickException(f"{where}{exc.strerror or exc}") from None
        except MemoryError:
            raise click.ClickException("out of memory") from None


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
