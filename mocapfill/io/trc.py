"""TRC (OpenSim / Motion Analysis track row column) read and write.

Layout: five header lines (``PathFileType``; the names ``DataRate CameraRate NumFrames NumMarkers Units
OrigDataRate OrigDataStartFrame OrigNumFrames``; their values; ``Frame# Time`` + one label per x/y/z triplet;
``X1 Y1 Z1 ...``), an optional blank line, then one row per frame.  Fields are tab-separated (some tools use
commas; both are read).  An empty field is a missing coordinate; rows may stop early when their last markers are
missing.  A file holding fewer rows than its ``NumFrames`` (a truncated export) is read as far as it goes, with a
:class:`DataWarning` and a note.  Unlike C3D, a point at exactly (0, 0, 0) is kept: text formats mark missing
samples with empty fields, and a marker at the origin is sometimes real (a reference point).
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from ..errors import DataWarning, FormatError
from ..markers import MarkerData
from .csv import frame_number, parse_numbers
from .labels import make_unique, normalise_units

__all__ = ["read_trc", "trc_text"]

_HEADER_KEYS = ("DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
                "OrigDataStartFrame", "OrigNumFrames")


def read_trc(text: str, name: str) -> MarkerData:
    """Parse TRC text into MarkerData (positions (n_frames, n_markers, 3), NaN = missing)."""
    lines = text.splitlines()
    if len(lines) < 5 or not lines[0].lstrip().lower().startswith("pathfiletype"):
        raise FormatError(f"{name}: not a TRC file (the first line should start with 'PathFileType')")
    delim = "\t" if "\t" in lines[1] else ","
    split = lambda line: [c.strip() for c in line.rstrip("\r\n").split(delim)]  # noqa: E731
    keys, values = split(lines[1]), split(lines[2])
    meta = {k: v for k, v in zip(keys, values) if k}
    notes: list[str] = []
    try:
        rate = float(meta.get("DataRate") or meta.get("CameraRate"))
    except (TypeError, ValueError):
        raise FormatError(f"{name}: TRC header has no valid DataRate") from None
    if not np.isfinite(rate) or rate <= 0:
        raise FormatError(f"{name}: TRC DataRate {rate:g} is not a positive number")

    label_row, axis_row = split(lines[3]), split(lines[4])
    n_label = max(((len(label_row) - 2) + 2) // 3, 0)
    n_axis = sum(1 for c in axis_row[2:] if c[:1].upper() == "X")
    labels = [label_row[2 + 3 * k] if 2 + 3 * k < len(label_row) else "" for k in range(max(n_label, n_axis))]
    while labels and not labels[-1] and len(labels) > n_axis:
        labels.pop()
    n_markers = len(labels)
    declared = _int(meta.get("NumMarkers"))
    if declared is not None and declared != n_markers:
        notes.append(f"header says {declared} markers, the label row names {n_markers}")
    unnamed = [k for k, lab in enumerate(labels) if not lab]
    labels = [lab or f"M{k + 1:03d}" for k, lab in enumerate(labels)]
    if unnamed:
        notes.append(f"{len(unnamed)} marker(s) without a label named M###")
    labels, renamed = make_unique(labels)
    for old, new in renamed:
        notes.append(f"duplicate label {old!r} renamed {new!r}")

    raw_rows: list[tuple[int, list[str]]] = []
    for number, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        row = split(line)
        if not any(row):
            continue  # the blank line after the header, written with delimiters by comma-separated exporters
        while len(row) > 2 and not row[-1]:
            row.pop()  # rows stop early (or carry trailing tabs) when their last markers are missing
        raw_rows.append((number, row))
    longest = max((len(r) for _, r in raw_rows), default=0)
    header_width = 2 + 3 * n_markers
    long_rows = [(number, len(r)) for number, r in raw_rows if len(r) > header_width]
    if len({n for _, n in long_rows}) > 1:
        # Rows longer than the header are only believable as unnamed extra markers when they all agree.
        number, n = long_rows[0]
        raise FormatError(f"{name}: line {number} has {n} fields, the header has {header_width} and other rows "
                          "differ again (ragged TRC)")
    in_rows = -(-(longest - 2) // 3) if longest > 2 else 0
    if in_rows > n_markers:
        # Some exporters name fewer markers than the rows hold; keep the extra columns as unnamed markers.
        notes.append(f"the rows hold {in_rows} markers, the label row names {n_markers}; the others are named M###")
        warnings.warn(f"{name}: the rows hold {in_rows} markers but the label row names {n_markers}",
                      DataWarning, stacklevel=3)
        labels, _ = make_unique(labels + [f"M{k + 1:03d}" for k in range(n_markers, in_rows)])
        n_markers = in_rows
    width = 2 + 3 * n_markers
    rows = [row + [""] * (width - len(row)) for _, row in raw_rows]
    first_line = raw_rows[0][0] if raw_rows else None
    columns = ["Frame#", "Time"] + [f"{lab}_{a}" for lab in labels for a in "xyz"]
    table = parse_numbers(rows, name, first_line or 6, columns)
    positions = table[:, 2:].reshape(len(rows), n_markers, 3).copy()
    positions[np.isnan(positions).any(axis=2)] = np.nan

    expected = _int(meta.get("NumFrames"))
    if expected is not None and expected != len(rows):
        what = "truncated" if len(rows) < expected else "longer than its header says"
        notes.append(f"header says {expected} frames, the file holds {len(rows)} ({what}); read what is there")
        warnings.warn(f"{name}: header says {expected} frames, the file holds {len(rows)}; read what is there",
                      DataWarning, stacklevel=3)
    units, note = normalise_units(meta.get("Units", ""), positions)
    if note:
        notes.append(note)
    first_frame = frame_number(table[0, 0], name) if len(rows) and np.isfinite(table[0, 0]) else 1
    return MarkerData(positions, labels, rate, units, first_frame, "trc", None, name, notes)


def _int(text) -> int | None:
    try:
        return int(float(text))
    except (TypeError, ValueError, OverflowError):  # "inf" overflows
        return None


def _num(value: float) -> str:
    return "" if value != value else repr(float(value))


def trc_text(data: MarkerData, name: str = "out.trc") -> str:
    """TRC text of ``data`` (tab-separated, shortest exact numbers, empty fields for missing samples; a row whose last
    marker is missing ends with an extra tab, so that OpenSim counts its columns right)."""
    for label in data.labels:
        if "\t" in label or "\n" in label:
            raise FormatError(f"{name}: label {label!r} contains a tab or newline, which TRC cannot hold")
    n, m = data.n_frames, data.n_markers
    rate = _num(data.rate)
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{os.path.basename(str(name))}",
        "\t".join(_HEADER_KEYS),
        "\t".join([rate, rate, str(n), str(m), data.units, rate, str(data.first_frame), str(n)]),
        "\t".join(["Frame#", "Time"] + [f"{lab}\t\t" for lab in data.labels]).rstrip("\t"),
        "\t".join(["", ""] + [f"X{k}\tY{k}\tZ{k}" for k in range(1, m + 1)]),
        "",
    ]
    flat = data.positions.reshape(n, 3 * m).tolist()
    times = data.times.tolist()
    for t in range(n):
        cells = ["" if v != v else repr(v) for v in flat[t]]
        row = "\t".join([str(data.first_frame + t), repr(times[t])] + cells)
        # OpenSim's reader drops the empty field after a row's last tab and then finds a column short: a row whose
        # last marker is missing ends with one more tab (our reader, and OpenSim's, ignore trailing empty fields)
        lines.append(row + "\t" if cells and not cells[-1] else row)
    return "\n".join(lines) + "\n"
