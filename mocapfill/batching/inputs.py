"""Which files a batch fills: files, folders searched recursively, globs; and where each output goes."""

from __future__ import annotations

import glob
import os
from pathlib import Path
from typing import Iterable

from ..errors import FormatError, InputError
from .resume import STATE_NAME

#: The results table and the index page a batch writes into its output folder (the resume record is
#: :data:`STATE_NAME`); named here, where a search skips them.
RESULTS_NAME = "mocapfill-batch.csv"
INDEX_NAME = "index.html"
#: What a batch appends to an output's name for its per-sample status CSV.
STATUS_SUFFIX = ".status.csv"
#: The per-file reports a batch writes, ``<output>.report.<kind>``.
REPORT_KINDS = ("html", "json")


def _bookkeeping(path: Path) -> bool:
    """A file a batch wrote for itself, not a capture: its results table, resume record or index page, or an
    output's status CSV or report (``<output>.status.csv``, ``<output>.report.json|html`` beside ``<output>``)."""
    name = path.name
    if name in (RESULTS_NAME, STATE_NAME, INDEX_NAME):
        return True
    return any(name.endswith(suffix) and path.with_name(name[:-len(suffix)]).is_file()
               for suffix in beside_suffixes())


def report_suffix(kind: str) -> str:
    """What a batch appends to an output's name for its report of ``kind`` (one of :data:`REPORT_KINDS`)."""
    return f".report.{kind}"


def beside_suffixes() -> tuple[str, ...]:
    """What a batch appends to an output's name for the files it writes beside it: its reports and status CSV."""
    return (*(report_suffix(kind) for kind in REPORT_KINDS), STATUS_SUFFIX)


def _batch_output(folder: Path) -> bool:
    """An earlier batch's output folder (it holds the results table or the resume record): its files are outputs."""
    return (folder / RESULTS_NAME).is_file() or (folder / STATE_NAME).is_file()


def _in_batch_output(path: Path, base: Path) -> bool:
    """Whether ``path`` (a glob's match) is, or lies in, an earlier batch's output folder below ``base`` (the glob's
    fixed part: a folder the user named is searched even when it is one)."""
    top = base.resolve()
    for folder in ([path] if path.is_dir() else []) + list(path.parents):
        if folder.resolve() == top or top not in folder.resolve().parents:
            return False
        if _batch_output(folder):
            return True
    return False


def _readable(path: Path) -> bool:
    from ..io import detect_format

    try:
        detect_format(path)
    except FormatError:
        return False
    return True


def _inside(path: Path, folder: Path | None) -> bool:
    if folder is None:
        return False
    try:
        path.resolve().relative_to(folder)
    except ValueError:
        return False
    return True


def _search(folder: Path, exclude: Path | None) -> list[Path]:
    """Readable files below ``folder``, sorted; hidden files and folders skipped, and ``exclude`` (the output
    folder) when it lies inside ``folder``; so are a batch's own files and earlier batches' output folders below
    ``folder`` (``folder`` itself is searched: the user named it)."""
    if _inside(folder, exclude):
        exclude = None
    found = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not _inside(Path(root, d), exclude)
                         and not _batch_output(Path(root, d)))
        for name in sorted(files):
            path = Path(root, name)
            if not name.startswith(".") and not _bookkeeping(path) and _readable(path):
                found.append(path)
    return found


def _glob_base(pattern: str) -> Path:
    """The folder part of ``pattern`` before its first wildcard: outputs keep their path relative to it."""
    parts = Path(pattern).parts
    fixed = []
    for part in parts[:-1]:
        if glob.has_magic(part):
            break
        fixed.append(part)
    return Path(*fixed) if fixed else Path(".")


def find_inputs(inputs: Iterable[str | os.PathLike], *, exclude: str | os.PathLike | None = None
                ) -> list[tuple[Path, Path]]:
    """Expand files, folders and globs into ``(path, relative path)`` pairs, in a stable order, without duplicates.

    A folder is searched recursively for the extensions :func:`mocapfill.io.detect_format` knows; a glob's
    matching folders likewise.  A plain path that does not exist is kept (its task fails with the reader's error).
    Files a search or glob finds inside ``exclude`` (the output folder) are left out, unless the searched folder
    itself lies inside it; so are a batch's own files (results table, resume record, index page, status CSVs) and
    everything in an earlier batch's output folder below a named folder or a glob's fixed part.  Files named
    explicitly are kept as they are.

    Raises
    ------
    InputError
        A glob matches nothing, or nothing at all was found.
    """
    ex = Path(exclude).resolve() if exclude is not None else None
    pairs: list[tuple[Path, Path]] = []
    seen: set[Path] = set()

    def add(path: Path, base: Path | None) -> None:
        key = path.resolve()
        if key in seen:
            return
        seen.add(key)
        pairs.append((path, Path(os.path.relpath(path, base)) if base is not None else Path(path.name)))

    for item in inputs:
        text = os.fspath(item)
        if glob.has_magic(text):
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                raise InputError(f"{text}: no file matches")
            base = _glob_base(text)
            skip = None if _inside(base, ex) else ex  # a glob reaching into the output folder must not eat outputs
            for match in map(Path, matches):
                if match.is_dir() and _in_batch_output(match, base):
                    continue
                if match.is_dir():
                    for path in _search(match, skip):
                        add(path, base)
                elif not _inside(match, skip) and not _bookkeeping(match) and not _in_batch_output(match, base):
                    add(match, base)
        elif Path(text).is_dir():
            for path in _search(Path(text), ex):
                add(path, Path(text))
        else:
            add(Path(text), None)
    if not pairs:
        raise InputError(f"no capture files found in {', '.join(map(os.fspath, inputs))}")
    return pairs



def output_paths(rel: Path, out_dir: Path, output_format: str | None, report: str | None
                 ) -> tuple[Path, Path | None]:
    """The output path of an input at ``rel`` below the folder it was found in, and its report's (or None)."""
    out = out_dir / rel
    if output_format is not None:
        out = out.with_suffix("." + output_format)
    return out, (out.with_name(out.name + report_suffix(report)) if report else None)
