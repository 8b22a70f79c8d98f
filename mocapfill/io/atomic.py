"""Safe output: write to a temporary file beside the target and rename it into place at the end.

A failure part-way (an exception in the caller, a full disk) therefore never leaves a half-written file behind, and
the previous content of the target, if any, survives.  ``"-"`` means stdout and is written directly.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path
from typing import IO, Iterator

from ..errors import InputError

__all__ = ["atomic_write", "check_output_path", "is_std_stream"]


def is_std_stream(path) -> bool:
    """True when ``path`` is ``"-"`` (stdin / stdout)."""
    return isinstance(path, str) and path == "-"


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


@contextlib.contextmanager
def atomic_write(path, mode: str = "wb", *, encoding: str | None = "utf-8", newline: str | None = None
                 ) -> Iterator[IO]:
    """Open ``path`` for writing through a temporary file that replaces it only on success.

    Parameters
    ----------
    path : str or os.PathLike
        Target file; ``"-"`` writes straight to stdout (binary modes use ``sys.stdout.buffer``).
    mode : str
        ``"wb"`` (default) or ``"w"`` (text, ``encoding``/``newline`` as for :func:`open`).

    Yields
    ------
    The open file object.  On normal exit it is flushed, fsynced and renamed onto ``path`` (keeping the target's
    permissions when it existed); on an exception the temporary file is removed and the exception propagates.

    Raises
    ------
    InputError
        The directory does not exist or is not writable, the target is a directory, or the rename fails; the message
        names ``path``.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write mode must be 'w' or 'wb', not {mode!r}")
    binary = "b" in mode
    if is_std_stream(path):
        stream = sys.stdout.buffer if binary else sys.stdout
        yield stream
        stream.flush()
        return

    target = Path(os.fspath(path))
    directory = target.parent if str(target.parent) else Path(".")
    if target.is_dir():
        raise InputError(f"{path}: is a directory, cannot write a file there")
    if not directory.is_dir():
        why = "is not a directory" if directory.exists() else "does not exist"
        raise InputError(f"{path}: cannot write: {str(directory)!r} {why}")
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=directory)
    except OSError as exc:
        raise InputError(f"{path}: cannot write: {_reason(exc)}") from None
    tmp = Path(tmp_name)
    try:
        kwargs = {} if binary else {"encoding": encoding, "newline": newline}
        with os.fdopen(fd, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        if target.exists():
            try:
                os.chmod(tmp, target.stat().st_mode & 0o7777)
            except OSError:
                pass  # keeping the old permissions is a courtesy, not a requirement
        else:
            # mkstemp creates 0600; give a new file the usual umask-based permissions instead.
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        try:
            os.replace(tmp, target)
        except OSError as exc:
            raise InputError(f"{path}: cannot write: {_reason(exc)}") from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def check_output_path(output, *inputs) -> None:
    """Refuse an output path that names the same file as one of the inputs.

    ``"-"`` (stdout / stdin) never clashes, nor does ``None``.  Paths are compared after resolving symlinks and
    ``..``; existing files are compared by device and inode (so hard links count as the same file).

    Raises
    ------
    InputError
        ``"<output>: output is the same file as the input <input>; choose another output path"``.
    """
    if output is None or is_std_stream(output):
        return
    out = Path(os.fspath(output))
    for inp in inputs:
        if inp is None or is_std_stream(inp):
            continue
        if _same_file(out, Path(os.fspath(inp))):
            raise InputError(f"{output}: output is the same file as the input {inp}; choose another output path")
