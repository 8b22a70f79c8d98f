"""Marker I/O: C3D, CSV (plain wide, Vicon Nexus, header-only wide), TRC, Qualisys TSV and OptiTrack Motive CSV, one
module per format.

- :func:`read` turns a file (or ``"-"`` = stdin, or an open binary stream) into one :class:`MarkerData`.
- :func:`write` writes one back, atomically (temporary file + rename, see :mod:`mocapfill.io.atomic`).
- :func:`storage_change` says whether the written file holds the samples exactly (CSV, TRC: always; TSV: mm on its
  0.001 mm grid; C3D: words kept from the original, or float32 values), else how it stores them.

The format comes from ``format=`` when given; else a file's extension, refined by its content among the text formats
(TRC ``PathFileType``, QTM ``NO_OF_FRAMES``, Motive ``Format Version,``: a Motive export saved as ``.csv`` is read as
Motive) and replaced by it when the extension is unknown; on stdin and streams the content alone (C3D
parameter-block byte or the text signatures; CSV when nothing matches).  Writing to stdout without a format uses
the format the data was read from (our plain CSV for formats we only read).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
from typing import BinaryIO, Union

from ..errors import FormatError, InputError
from ..markers import MarkerData
from .atomic import atomic_write, check_output_path, is_std_stream

__all__ = ["read", "write", "storage_change", "atomic_write", "check_output_path", "detect_format", "sniff_format",
           "READ_FORMATS", "WRITE_FORMATS"]

PathOrStream = Union[str, os.PathLike, BinaryIO]

#: formats :func:`read` accepts ("csv" auto-detects plain, Vicon and header-only wide layouts).
READ_FORMATS = ("c3d", "csv", "vicon-csv", "trc", "tsv", "motive-csv")
#: formats :func:`write` produces.
WRITE_FORMATS = ("c3d", "csv", "trc", "tsv")
_EXTENSIONS = {".c3d": "c3d", ".csv": "csv", ".trc": "trc", ".tsv": "tsv"}
#: what a format read but not written is written back as (to stdout without a format).
_WRITTEN_AS = {"vicon-csv": "csv", "motive-csv": "csv"}


def _name_of(path_or_stream) -> str:
    if isinstance(path_or_stream, (str, os.PathLike)):
        return os.fspath(path_or_stream)
    return getattr(path_or_stream, "name", None) or "<stream>"


def detect_format(path, format: str | None = None) -> str:
    """The format to use for ``path``: ``format`` when given, else from the extension (case-insensitive).

    Raises FormatError naming the path for an unknown extension.
    """
    if format is not None:
        fmt = format.lower()
        if fmt not in READ_FORMATS:
            raise FormatError(f"{path}: unknown format {format!r} (expected one of {', '.join(READ_FORMATS)})")
        return fmt
    suffix = Path(os.fspath(path)).suffix.lower()
    try:
        return _EXTENSIONS[suffix]
    except KeyError:
        what = f"unknown file extension {suffix!r}" if suffix else "no file extension"
        raise FormatError(f"{path}: {what}; expected .c3d, .csv, .trc or .tsv (or give the format explicitly)"
                          ) from None


def sniff_format(raw: bytes) -> str | None:
    """The format content announces by its signature, or None (plain CSV has none)."""
    if len(raw) >= 512 and raw[1] == 0x50 and 1 <= raw[0] < 32:  # byte 0: a block number, never text
        return "c3d"
    head = raw[:64].lstrip(b"\xef\xbb\xbf \t\r\n")
    lower = head.lower()
    if lower.startswith(b"pathfiletype"):
        return "trc"
    if head.startswith((b"NO_OF_FRAMES", b"FILE_VERSION")):
        return "tsv"
    if lower.startswith(b"format version,"):
        return "motive-csv"
    return None


def _content_or_extension(raw: bytes, name: str, stream: bool) -> str:
    """The format of ``raw``: streams by content alone (CSV when nothing matches); files by extension, refined by the
    content among the text formats (a Motive export saved as .csv, a TSV saved as .txt), by content alone when the
    extension is unknown.  A binary file with a text extension stays with its extension (and is reported as binary)."""
    sniffed = sniff_format(raw)
    if stream:
        return sniffed or "csv"
    suffix = Path(os.fspath(name)).suffix.lower()
    by_extension = _EXTENSIONS.get(suffix)
    if by_extension is None:
        return sniffed or detect_format(name)
    if sniffed is not None and sniffed != "c3d" and by_extension != "c3d":
        return sniffed
    return by_extension


def _read_bytes(path_or_stream, name: str) -> bytes:
    if is_std_stream(path_or_stream):
        return sys.stdin.buffer.read()
    if not isinstance(path_or_stream, (str, os.PathLike)):
        raw = path_or_stream.read()
        return raw.encode("utf-8") if isinstance(raw, str) else raw
    if not os.fspath(path_or_stream):  # ("" would be read as the current folder)
        raise InputError("an empty path names no file")
    path = Path(os.fspath(path_or_stream))
    if not path.exists():
        raise InputError(f"{name}: no such file")
    if path.is_dir():
        raise InputError(f"{name}: is a directory, not a file")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(f"{name}: cannot read: {exc.strerror or exc}") from None


def read(path_or_stream: PathOrStream, format: str | None = None, *, rate: float | None = None,
         override_rate: bool = False) -> MarkerData:
    """Read marker trajectories from a file, ``"-"`` (stdin) or a binary stream.

    Parameters
    ----------
    path_or_stream : str, os.PathLike or binary file object
        The input; ``"-"`` reads stdin (into memory first: the C3D reader seeks).
    format : {"c3d", "csv", "vicon-csv", "trc", "tsv", "motive-csv"} or None
        Overrides the content and the extension; a stream whose content has no signature is read as CSV.
    rate : float or None
        Frame rate in Hz for a file that carries none (a bare CSV, the BoLeRO authors' CSV).  For a file that has
        its own rate it must agree with it (to 1e-6 relative, or within the precision of the time column it came
        from: :attr:`MarkerData.rate_range`) unless ``override_rate`` says to replace the file's.
    override_rate : bool
        Use ``rate`` even where the file says otherwise (the user knows the file is wrong).

    Returns
    -------
    MarkerData with ``positions`` (n_frames, n_markers, 3) float64, NaN = missing, and ``extra`` holding what the
    writer needs to write the same file back.

    Raises
    ------
    InputError (missing or unreadable file), FormatError (unknown extension, corrupt content, no rate in the file
    and none given, a ``rate`` that contradicts the file's); all name the file.
    """
    name = _name_of(path_or_stream)
    rate = _check_rate(rate, name)
    stream = is_std_stream(path_or_stream) or not isinstance(path_or_stream, (str, os.PathLike))
    if format is not None:
        fmt = detect_format(name, format)
    raw = _read_bytes(path_or_stream, name)
    if format is None:
        fmt = _content_or_extension(raw, name, stream)
    if fmt == "c3d":
        from .c3d import read_c3d
        data = read_c3d(raw, name)
    elif fmt in ("csv", "vicon-csv"):
        from .csv import read_csv
        data = read_csv(_decode(raw, name), name, layout="vicon" if fmt == "vicon-csv" else None)
    elif fmt == "tsv":
        from .tsv import read_tsv
        data = read_tsv(_decode(raw, name), name)
    elif fmt == "motive-csv":
        from .motive import read_motive
        data = read_motive(_decode(raw, name), name)
    else:
        from .trc import read_trc
        data = read_trc(_decode(raw, name), name)
    data.path = name
    _apply_rate(data, rate, override_rate, name)
    return data


def _check_rate(rate, name: str) -> float | None:
    if rate is None:
        return None
    try:
        value = float(rate)
    except (TypeError, ValueError):
        raise InputError(f"{name}: --rate {rate!r} is not a number") from None
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"{name}: --rate {value:g} is not a positive frame rate in Hz")
    return value


def _apply_rate(data: MarkerData, rate: float | None, override: bool, name: str) -> None:
    """The file's rate, else the caller's; a caller's rate that contradicts the file's is an error unless overridden.

    Readers give NaN where the file carries no rate.
    """
    has_own = np.isfinite(data.rate) and data.rate > 0
    if rate is None:
        if not has_own:
            raise FormatError(f"{name}: the file has no frame rate; give it with --rate HZ (rate= in Python)")
        return
    # A rate inferred from a time column is known only to the times' written precision: any rate within it agrees.
    within = data.rate_range is not None and data.rate_range[0] <= rate <= data.rate_range[1]
    if has_own and abs(data.rate - rate) > 1e-6 * data.rate and not within and not override:
        raise FormatError(f"{name}: --rate {rate:g} contradicts the file's rate of {data.rate:g} Hz "
                          f"(add --override-rate to use {rate:g} Hz anyway)")
    if has_own and data.rate != rate and not within and override:
        data.notes.append(f"frame rate {data.rate:g} Hz in the file replaced by {rate:g} Hz (--override-rate)")
        data.rate_range = None
    data.rate = rate


def _decode(raw: bytes, name: str) -> str:
    for encoding in ("utf-8-sig", "latin-1"):
        try:
            text = raw.decode(encoding)
        except UnicodeDecodeError:
            continue
        if "\x00" in text:
            raise FormatError(f"{name}: binary content where text was expected (is it really a text file?)")
        return text
    raise FormatError(f"{name}: cannot decode as text")  # pragma: no cover - latin-1 decodes everything


def _write_format(data: MarkerData, path_or_stream: PathOrStream, format: str | None) -> tuple[str, str, bool]:
    """(name, format, whether a stream) of a :func:`write`: ``format``, else the path's extension, else (stdout and
    streams) the format the data was read from."""
    name = _name_of(path_or_stream)
    stream = is_std_stream(path_or_stream) or not isinstance(path_or_stream, (str, os.PathLike))
    if format is not None or not stream:
        fmt = detect_format(name, format)
    else:
        fmt = _WRITTEN_AS.get(data.source_format or "", data.source_format) or "csv"
    if fmt == "vicon-csv":
        fmt = "csv"  # "the CSV layout" when asked to write what was read
    if fmt not in WRITE_FORMATS:
        raise FormatError(f"{name}: cannot write format {fmt!r} (expected one of {', '.join(WRITE_FORMATS)})")
    return name, fmt, stream


def storage_change(data: MarkerData, path_or_stream: PathOrStream, format: str | None = None, *,
                   samples: np.ndarray | None = None) -> str | None:
    """How :func:`write` of ``data`` to ``path_or_stream`` changes the numbers of ``samples`` ((n_frames, n_markers)
    bool, default every observed sample): None when the file holds them exactly as they are (CSV and TRC always:
    the shortest text that reads back to the same float64); else how the format stores them ("rounded to the TSV's
    0.001 mm", "stored as float32 by C3D", ...).  Arguments as :func:`write`."""
    _, fmt, _ = _write_format(data, path_or_stream, format)
    mask = ~data.missing if samples is None else np.asarray(samples, dtype=bool) & ~data.missing
    if fmt == "tsv":
        from .tsv import tsv_storage
        return tsv_storage(data, mask)
    if fmt == "c3d":
        from .c3d import c3d_storage
        return c3d_storage(data, mask)
    return None


def write(data: MarkerData, path_or_stream: PathOrStream, format: str | None = None) -> None:
    """Write ``data`` to a file (atomically), ``"-"`` (stdout) or a binary stream.

    Parameters
    ----------
    data : MarkerData
        ``positions`` (n_frames, n_markers, 3); for C3D output, ``data.extra`` from a C3D read lets the writer keep
        every parameter, analog channel, event and model output of the original (observed samples keep their
        residuals, newly filled samples get residual 0, NaN samples residual -1).
    path_or_stream : str, os.PathLike or binary file object
    format : {"c3d", "csv", "trc", "tsv"} or None
        Overrides the extension; for ``"-"`` / streams the default is the format the data was read from.

    Raises
    ------
    InputError (unwritable directory, the path of the file ``data`` was read from, ...), FormatError (unknown
    extension, data the format cannot hold).
    """
    name, fmt, stream = _write_format(data, path_or_stream, format)
    if not stream:
        check_output_path(path_or_stream, data.path)  # never overwrite the file the data came from
    if fmt == "c3d":
        from .c3d import c3d_bytes
        payload = c3d_bytes(data, name)
    elif fmt == "csv":
        from .csv import csv_text
        payload = csv_text(data).encode("utf-8")
    elif fmt == "tsv":
        from .tsv import tsv_text
        payload = tsv_text(data, name).encode("utf-8")
    else:
        from .trc import trc_text
        payload = trc_text(data, name).encode("utf-8")
    if stream and not is_std_stream(path_or_stream):
        path_or_stream.write(payload)
        return
    with atomic_write(path_or_stream, "wb") as handle:
        handle.write(payload)
