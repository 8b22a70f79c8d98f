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
from .labels import make_unique, match_label_row, named_by_place, normalise_units, point_kinds, rename_notes

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
    n_axis = sum(1 for c in axis_row[2:] if c[:1].upper() == "X")
    declared = _int(meta.get("NumMarkers"))
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
    in_rows = -(-(longest - 2) // 3) if longest > 2 else 0
    n_header = n_axis or len(_label_fields(label_row))
    if in_rows > max(n_header, declared or 0):
        # Rows that stop early (their last markers missing) end on a whole marker; a longer row whose values end
        # inside a triplet is shifted, not extra markers.
        number, n = next(((number, len(r)) for number, r in raw_rows if len(r) > 2 + 3 * n_header
                          and (len(r) - 2) % 3), (None, 0))
        if number is not None:
            raise FormatError(f"{name}: line {number} has {n} fields, the header has {2 + 3 * n_header} and the "
                              "values end inside a marker's x, y, z (ragged TRC)")
    labels, kinds, label_notes = trc_labels(label_row, n_axis, in_rows, name)
    notes.extend(label_notes)
    if declared is not None and declared != len(labels) and declared != n_header:
        notes.append(f"header says {declared} markers, the label row names {n_header}")
    n_markers = len(labels)
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
    return MarkerData(positions, labels, rate, units, first_frame, "trc", None, name, notes, kinds)


def _label_fields(label_row: list[str]) -> list[tuple[int, str]]:
    """The non-empty names of a TRC label row after ``Frame#`` and ``Time``, with their field index (from 0)."""
    return [(j, c) for j, c in enumerate(label_row[2:]) if c]


def trc_labels(label_row: list[str], n_axis: int, in_rows: int, name: str
               ) -> tuple[list[str], list[str], list[str]]:
    """Labels, kinds and notes of the markers of a TRC, from its label row (line 4) as split fields.

    The label row's non-empty names are read in order when they stand every third field (the layout) or when
    their number matches the marker count (the ``X1 Y1 Z1`` row says how many; else the widest data row),
    whatever the spacing.  A row that matches neither gives every marker a placeholder ``M###`` name and a
    :class:`DataWarning` naming the line, never a name that may belong to another marker.  Columns the rows hold
    beyond the named markers (an exporter's unnamed trajectories) are placeholder-named and of kind
    ``"unlabelled"``; the kinds of named markers come from :func:`mocapfill.io.labels.point_kinds`.
    """
    n_expected = n_axis or in_rows or len(_label_fields(label_row))
    labels, message, matched = match_label_row(label_row[2:], n_expected, "the label row (line 4)")
    notes: list[str] = [message] if message else []
    if not matched:
        warnings.warn(f"{name}: {message}", DataWarning, stacklevel=4)
    aligned = matched and message is None
    n_named = len(labels)
    unnamed = [k for k, lab in enumerate(labels) if not lab]
    if unnamed and aligned:
        notes.append(f"{len(unnamed)} marker(s) without a label named M###")
    labels = named_by_place(labels)
    kinds = point_kinds(labels)
    if in_rows > n_named:
        extra = in_rows - n_named
        message = (f"the rows hold {in_rows} markers, the label row names {n_named}; the other {extra} "
                   f"({_placeholder_range(n_named, in_rows)}) are kept as unlabelled trajectories")
        notes.append(message)
        warnings.warn(f"{name}: {message}", DataWarning, stacklevel=4)
        labels += [f"M{k + 1:03d}" for k in range(n_named, in_rows)]
        kinds += ["unlabelled"] * extra
    labels, renamed = make_unique(labels)
    notes.extend(rename_notes(renamed))
    return labels, kinds, notes


def _placeholder_range(start: int, stop: int) -> str:
    return f"M{start + 1:03d}" if stop - start == 1 else f"M{start + 1:03d}-M{stop:03d}"


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
