"""Qualisys QTM TSV export of 3-D marker data (read and write).

Layout (QTM's "Motion data (.tsv)", 3D)::

    NO_OF_FRAMES	2000
    NO_OF_CAMERAS	10
    NO_OF_MARKERS	15
    FREQUENCY	100
    NO_OF_ANALOG	0
    ANALOG_FREQUENCY	0
    DESCRIPTION	--
    TIME_STAMP	2026-01-19, 10:19:43.755	2063631.96175450
    DATA_INCLUDED	3D
    MARKER_NAMES	LHEE	RHEE	...
    TRAJECTORY_TYPES	Measured	Mixed	...
    Frame	Time	LHEE X	LHEE Y	LHEE Z	RHEE X	...
    1	0.00000	819.834	277.770	22.421	...

- Header lines are ``KEY<tab>value...`` (upper-case keys; ``EVENT`` lines repeat; ``FILE_VERSION`` from QTM 2.0 on;
  ``TRAJECTORY_TYPES`` in recent versions).  The rate is ``FREQUENCY`` (``EXT`` = external timebase: no rate in the
  file, give it with ``--rate``), the labels ``MARKER_NAMES``, the units always millimetres.
- The column-name row (``Frame Time <label> X ...``) is optional (older exports write data only, with or without
  the frame and time columns); per-frame ``<label> Type`` columns are skipped.  The first frame is the ``Frame``
  column's first value (QTM counts from 1).
- A missing sample is written by QTM as ``0.000 0.000 0.000``; empty cells and ``NaN`` are read as missing too.
  A sample at exactly (0, 0, 0) is therefore always missing in this format (the writer does the same).
- The writer emits QTM's header keys (those of the file the data was read from, when it was a TSV with the same
  markers: a rewrite of QTM's file gives back its lines character for character, line ends aside), coordinates in
  millimetres with three decimals (QTM's precision; data in other units are converted, as the format has no unit
  field), times with five decimals counted from frame 1, ``\n`` line ends.  2-D and 6DOF TSV exports are refused with a message.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import DataWarning, FormatError
from ..markers import MarkerData
from ..units import length_factor
from .csv import frame_number, parse_numbers
from .labels import make_unique, named_by_place, point_kinds, rename_notes

__all__ = ["read_tsv", "tsv_text", "tsv_storage", "looks_like_tsv", "TSVExtra"]

_KEY = re.compile(r"^[A-Z][A-Z0-9_]*$")
#: header keys the writer always computes itself (the rest are copied from a TSV source).
_COMPUTED = ("NO_OF_FRAMES", "NO_OF_MARKERS", "FREQUENCY", "DATA_INCLUDED", "MARKER_NAMES", "TRAJECTORY_TYPES")
#: QTM's order of the header keys.
_ORDER = ("FILE_VERSION", "NO_OF_FRAMES", "NO_OF_CAMERAS", "NO_OF_MARKERS", "FREQUENCY", "NO_OF_ANALOG",
          "ANALOG_FREQUENCY", "DESCRIPTION", "TIME_STAMP", "DATA_INCLUDED", "EVENT", "MARKER_NAMES",
          "TRAJECTORY_TYPES")


@dataclass
class TSVExtra:
    """What a TSV rewrite keeps from the file read: the header lines as ``(key, fields)``, the labels and the
    missing-sample mask ``(n_frames, n_markers)`` (a marker whose gaps were filled is then typed ``Mixed``)."""

    header: list[tuple[str, list[str]]] = field(default_factory=list)
    labels: list[str] = field(default_factory=list)
    missing: np.ndarray | None = None


def looks_like_tsv(head: str) -> bool:
    """True when text starts like a QTM TSV export (its first header key)."""
    first = head.lstrip("\ufeff").lstrip().split("\t", 1)[0].split("\n", 1)[0].strip()
    return first in ("NO_OF_FRAMES", "FILE_VERSION")


def _header(lines: list[str]) -> tuple[list[tuple[str, list[str]]], int]:
    """The ``KEY<tab>values`` lines at the top and the index of the first line after them."""
    header: list[tuple[str, list[str]]] = []
    i = 0
    for i, line in enumerate(lines):
        fields = line.rstrip("\r\n").split("\t")
        key = fields[0].strip()
        if not key and not any(f.strip() for f in fields):
            continue  # blank line
        if not _KEY.match(key):
            return header, i
        header.append((key, [f.strip() for f in fields[1:]]))
    return header, len(lines)


def read_tsv(text: str, name: str) -> MarkerData:
    """Parse QTM TSV text (3-D marker data) into MarkerData (positions (n_frames, n_markers, 3) in mm, NaN = missing).

    Raises FormatError naming the file for a TSV that is not QTM's 3-D export or is damaged.
    """
    lines = text.splitlines()
    header, start = _header(lines)
    if not header or not looks_like_tsv(lines[0] if lines else ""):
        raise FormatError(f"{name}: not a QTM TSV export (the first line should be 'NO_OF_FRAMES<tab>n'; "
                          "export with 'Include TSV header')")
    meta = {}
    for key, values in header:
        meta.setdefault(key, values)
    included = (meta.get("DATA_INCLUDED") or ["3D"])[0].upper()
    if included != "3D" or "MARKER_NAMES" not in meta:
        what = included if included != "3D" else "no MARKER_NAMES line"
        raise FormatError(f"{name}: QTM TSV with {what}; only 3-D marker data exports can be read")
    notes: list[str] = []
    raw_labels = list(meta["MARKER_NAMES"])
    while raw_labels and not raw_labels[-1]:
        raw_labels.pop()
    n_markers = len(raw_labels)
    declared = _int(meta.get("NO_OF_MARKERS"))
    if declared is not None and declared != n_markers:
        notes.append(f"header says {declared} markers, MARKER_NAMES lists {n_markers}")
    labels = named_by_place(raw_labels)
    labels, renamed = make_unique(labels)
    notes.extend(rename_notes(renamed))

    rate = _rate(meta.get("FREQUENCY"), name)
    rows = [line.rstrip("\r\n").split("\t") for line in lines[start:]]
    # A trailing empty field (a tab at the end of the line) is common; blank lines end nothing and are skipped.
    first_line = start + 1
    columns = None
    if rows and rows[0] and rows[0][0].strip().lower() == "frame":
        columns = [c.strip() for c in rows[0]]
        rows, first_line = rows[1:], first_line + 1
    keep = [(i, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    xyz, frame_col = _layout(columns, raw_labels, keep[0][1] if keep else None, name)
    width = max(xyz.max() + 1, frame_col + 1 if frame_col is not None else 0) if xyz.size else 0
    cells = []
    for i, r in keep:
        if len(r) < width:
            raise FormatError(f"{name}: line {first_line + i} has {len(r)} fields, expected at least {width} "
                              "(a truncated or ragged TSV)")
        cells.append(r)
    names = [f"{lab} {a}" for lab in labels for a in "XYZ"]
    flat = xyz.reshape(-1)
    if cells:
        values = parse_numbers([[r[j] for j in flat] for r in cells], name, first_line, names)
    else:
        values = np.zeros((0, flat.size))
    positions = values.reshape(len(cells), n_markers, 3)
    if np.isinf(positions).any():
        raise FormatError(f"{name}: infinite coordinate values")
    missing = np.isnan(positions).any(axis=2) | (positions == 0).all(axis=2)
    positions[missing] = np.nan

    first_frame = 1
    if frame_col is not None and cells:
        frames = parse_numbers([[r[frame_col]] for r in cells[:1]], name, first_line, ["Frame"])
        first_frame = frame_number(frames[0, 0], name)
    n_declared = _int(meta.get("NO_OF_FRAMES"))
    if n_declared is not None and n_declared != len(cells):
        notes.append(f"header says {n_declared} frames, the file holds {len(cells)}")
        if n_declared > len(cells):
            warnings.warn(f"{name}: header says {n_declared} frames, the file holds {len(cells)} (truncated?)",
                          DataWarning, stacklevel=3)
    extra = TSVExtra([(k, v) for k, v in header], list(labels), missing.copy())
    # A trajectory QTM lists without a name was never identified.
    kinds = [kind if raw else "unlabelled" for kind, raw in zip(point_kinds(labels), raw_labels)]
    return MarkerData(positions, labels, rate, "mm", first_frame, "tsv", extra, name, notes, kinds)


def _int(values) -> int | None:
    try:
        return int(values[0])
    except (TypeError, ValueError, IndexError):
        return None


def _rate(values, name: str) -> float:
    text = (values or [""])[0]
    if not text or text.upper() == "EXT":
        return float("nan")  # external timebase: no rate in the file (the caller's --rate)
    try:
        rate = float(text)
    except ValueError:
        raise FormatError(f"{name}: FREQUENCY {text[:30]!r} is not a number") from None
    if not np.isfinite(rate) or rate <= 0:
        raise FormatError(f"{name}: FREQUENCY {rate:g} is not a positive frame rate")
    return rate


def _layout(columns: list[str] | None, labels: list[str], first_row: list[str] | None, name: str):
    """Column indices ``(n_markers, 3)`` of the coordinates, and of the frame column (or None)."""
    n = len(labels)
    if columns is not None:
        index = {}
        for j, c in enumerate(columns):
            index.setdefault(c, j)
        frame_col = index.get("Frame")
        xyz = []
        for lab in labels:
            cols = [index.get(f"{lab} {a}") for a in "XYZ"]
            if None in cols:
                raise FormatError(f"{name}: no '{lab} X/Y/Z' columns for marker {lab!r} in the column-name row")
            xyz.append(cols)
        return np.array(xyz, dtype=int).reshape(n, 3), frame_col
    # No column names: data only, with or without the frame and time columns.
    width = len(first_row) if first_row is not None else 3 * n
    while first_row is not None and width > 0 and not first_row[width - 1].strip():
        width -= 1
    if width == 3 * n + 2 or first_row is None:
        return np.arange(2, 3 * n + 2).reshape(n, 3), 0
    if width == 3 * n:
        return np.arange(3 * n).reshape(n, 3), None
    raise FormatError(f"{name}: {width} data columns do not fit {n} markers (expected {3 * n} or {3 * n + 2})")


def _rate_text(rate: float) -> str:
    if not np.isfinite(rate):
        return "EXT"
    return str(int(rate)) if float(rate).is_integer() else repr(float(rate))


def tsv_storage(data: MarkerData, samples: np.ndarray) -> str | None:
    """None when :func:`tsv_text` writes the ``samples`` ((n_frames, n_markers) bool) of ``data`` exactly; else how it
    changes them (converted to mm, rounded to 0.001 mm)."""
    if data.units != "mm":
        return f"converted from {data.units} to mm and rounded to the TSV's 0.001 mm"
    values = data.positions[samples]
    # a value on the 0.001 grid (the nearest float64 to k / 1000, as a TSV read gives) prints and reads back as itself
    return None if np.array_equal(np.round(values, 3), values) else "rounded to the TSV's 0.001 mm"


def tsv_text(data: MarkerData, name: str = "<tsv>") -> str:
    """QTM TSV text of ``data`` (positions (n_frames, n_markers, 3), written in mm, missing = 0.000 triplets)."""
    labels = list(data.labels)
    for lab in labels:
        if "\t" in lab or "\n" in lab or "\r" in lab:
            raise FormatError(f"{name}: marker label {lab!r} holds a tab or line break; TSV cannot hold it")
    source = data.extra if isinstance(data.extra, TSVExtra) and data.extra.labels == labels else None
    labels = named_by_place(labels)
    kept = {}
    events = []
    if source is not None:
        for key, values in source.header:
            if key == "EVENT":
                events.append(values)
            elif key not in _COMPUTED:
                kept.setdefault(key, values)
    types = ["Measured"] * len(labels)
    if source is not None:
        original = dict(source.header).get("TRAJECTORY_TYPES")
        if original and len(original) >= len(labels):
            types = list(original[:len(labels)])
        if source.missing is not None and source.missing.shape == data.missing.shape:
            filled = (source.missing & ~data.missing).any(axis=0)
            types = ["Mixed" if f and t == "Measured" else t for t, f in zip(types, filled)]
    values = {
        "NO_OF_FRAMES": [str(data.n_frames)], "NO_OF_CAMERAS": kept.get("NO_OF_CAMERAS", ["0"]),
        "NO_OF_MARKERS": [str(data.n_markers)], "FREQUENCY": [_rate_text(data.rate)],
        "NO_OF_ANALOG": kept.get("NO_OF_ANALOG", ["0"]), "ANALOG_FREQUENCY": kept.get("ANALOG_FREQUENCY", ["0"]),
        "DESCRIPTION": kept.get("DESCRIPTION", ["--"]), "TIME_STAMP": kept.get("TIME_STAMP", ["--"]),
        "DATA_INCLUDED": ["3D"], "MARKER_NAMES": labels, "TRAJECTORY_TYPES": types,
    }
    if "FILE_VERSION" in kept:
        values["FILE_VERSION"] = kept["FILE_VERSION"]
    if source is not None and "TRAJECTORY_TYPES" not in dict(source.header):
        del values["TRAJECTORY_TYPES"]  # an older QTM's layout stays that layout
    out = []
    for key in _ORDER:
        if key == "EVENT":
            out.extend("\t".join(["EVENT"] + ev) for ev in events)
        elif key in values:
            out.append("\t".join([key] + list(values[key])))
    out.append("\t".join(["Frame", "Time"] + [f"{lab} {a}" for lab in labels for a in "XYZ"]) + "\t")  # as QTM
    factor = length_factor(data.units, "mm")
    flat = (data.positions * factor).reshape(data.n_frames, 3 * data.n_markers)
    flat = np.where(np.isnan(flat), 0.0, flat)
    # QTM's Time counts from frame 1 of the capture (a file trimmed to start at frame 12 starts at 0.11 s at 100 Hz)
    start = max(int(data.first_frame) - 1, 0)
    times = (start + np.arange(data.n_frames)) / data.rate if data.rate > 0 else np.zeros(data.n_frames)
    body = [f"{data.first_frame + t}\t{times[t]:.5f}\t" + "\t".join(f"{v:.3f}" for v in flat[t])
            for t in range(data.n_frames)]
    return "\n".join(out + body) + "\n"
