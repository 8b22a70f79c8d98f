"""Safe output: write to a temporary file beside the target and rename it into place at the end.

A failure part-way (an exception in the caller, a full disk) therefore never leaves a half-written file behind, and
the previous content of the target, if any, survives.  ``"-"`` means stdout and is written directly; so is an
existing target that is not a regular file (a FIFO, a device such as ``/dev/null``, a socket), where a rename would
replace it with a file.  A symlink is followed: the file it points to is replaced, the link stays.
"""

from __future__ import annotations

import contextlib
import os
import stat
import sys
import tempfile
from pathlib import Path
from typing import IO, Iterator

from ..errors import InputError

__all__ = ["atomic_write", "check_output_path", "check_writable", "is_std_stream", "removed_on_failure"]


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
    permissions when it existed); on an exception the temporary file is removed and the exception propagates.  A
    symlink at ``path`` is followed (its target is replaced); an existing FIFO, device or socket (after following
    links) is opened and written directly.

    Raises
    ------
    InputError
        The directory does not exist or is not writable, the target is a directory, the rename fails, or a FIFO /
        device cannot be opened or refuses the data; the message names ``path``.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write mode must be 'w' or 'wb', not {mode!r}")
    binary = "b" in mode
    kwargs = {} if binary else {"encoding": encoding, "newline": newline}
    if is_std_stream(path):
        stream = sys.stdout.buffer if binary else sys.stdout
        yield stream
        stream.flush()
        return

    target = _target(path)
    if target is None:
        # A FIFO, device or socket: a rename would put a file in its place, and atomicity means nothing there.
        yield from _write_directly(path, mode, kwargs)
        return
    directory = target.parent
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=directory)
    except OSError as exc:
        raise InputError(f"{path}: cannot write: {_reason(exc)}") from None
    tmp = Path(tmp_name)
    try:
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


def check_writable(path, *, parents: bool = False) -> None:
    """Raise the error :func:`atomic_write` would raise on ``path`` before it writes anything, so a command can check
    every output before its work starts.  ``"-"`` and ``None`` pass.

    ``parents``: a missing directory passes where the nearest existing one above it is a directory (the caller
    creates it before writing).

    Raises
    ------
    InputError
        The target is a directory, or its directory does not exist or is not a directory; the message names
        ``path``.
    """
    if path is not None and not is_std_stream(path):
        _target(path, parents=parents)


def _target(path, *, parents: bool = False) -> Path | None:
    """Where :func:`atomic_write` renames its temporary file for ``path``: ``path`` itself, or the file a symlink
    there names (the link stays); None for an existing FIFO, device or socket (written directly)."""
    target = Path(os.fspath(path))
    kind = _existing_kind(target)
    if kind is not None and stat.S_ISDIR(kind):
        raise InputError(f"{path}: is a directory, cannot write a file there")
    if kind is not None and not stat.S_ISREG(kind):
        return None
    if target.is_symlink():
        target = Path(os.path.realpath(target))  # replace the file the link names, not the link
    directory = target.parent if str(target.parent) else Path(".")
    if parents and not directory.exists():
        directory = next(above for above in directory.parents if above.exists())  # "." and "/" exist
    if not directory.is_dir():
        why = "is not a directory" if directory.exists() else "does not exist"
        raise InputError(f"{path}: cannot write: {str(directory)!r} {why}")
    return target


@contextlib.contextmanager
def removed_on_failure() -> Iterator[list]:
    """Collect the outputs a command writes (append each path once written); if the block then fails, remove them,
    so a command that fails leaves none of its outputs behind.  Only regular files are removed (a symlink's target,
    not the link): stdout, a FIFO or a device keeps what it was sent."""
    written: list = []
    try:
        yield written
    except BaseException:
        for path in written:
            if path is None or is_std_stream(path):
                continue
            real = os.path.realpath(os.fspath(path))
            with contextlib.suppress(OSError):
                if stat.S_ISREG(os.stat(real).st_mode):
                    os.unlink(real)
        raise


def _existing_kind(target: Path) -> int | None:
    """``st_mode`` of what ``target`` names after following symlinks, None where nothing exists (a new path, a
    dangling link) or it cannot be looked at (the directory checks then say why)."""
    try:
        return os.stat(target).st_mode
    except OSError:
        return None


def _write_directly(path, mode: str, kwargs: dict) -> Iterator[IO]:
    """Open ``path`` (not a regular file) and stream to it: no temporary file, no rename, no fsync."""
    try:
        handle = open(os.fspath(path), mode, **kwargs)
    except OSError as exc:
        raise InputError(f"{path}: cannot write: {_reason(exc)}") from None
    try:
        yield handle
        handle.flush()
    except OSError as exc:
        # What a device refuses (/dev/full: no space left) shows at a write or the flush, without a file name; a
        # reader that went away stays a BrokenPipeError (the CLI ends quietly on it).
        if isinstance(exc, BrokenPipeError) or exc.filename is not None:
            raise
        raise InputError(f"{path}: cannot write: {_reason(exc)}") from None
    finally:
        with contextlib.suppress(OSError):
            handle.close()


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
