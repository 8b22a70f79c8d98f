"""CSV marker files: our plain wide layout (read and write), Vicon Nexus exports and header-only wide CSVs (read).

Plain wide layout (what :func:`csv_text` writes)::

    # mocapfill csv: units=mm rate=120 first_frame=1
    frame,time,LFHD_x,LFHD_y,LFHD_z,RFHD_x,RFHD_y,RFHD_z
    1,0.0,123.25,-10.5,1701.0,,,
    2,0.008333333333333333,123.5,-10.25,1702.0,130.0,-12.0,1700.5

- The first line is a comment carrying the units, the rate and the number of the first frame.  It is optional on
  reading: without it the rate comes from the ``time`` column, the first frame from the ``frame`` column and the
  units are guessed from the size of the coordinates (and a note says so).
- Then one header row: optional ``frame`` and ``time`` columns, then three columns per marker named
  ``<label>_x``, ``<label>_y``, ``<label>_z`` (the separator may also be ``-``, ``.`` or a space, any case).
- An empty cell (or ``nan``) is a missing coordinate; a marker sample is missing when any coordinate is.
- Numbers are written with the shortest representation that reads back to the same float64, so a round trip is
  exact.

Header-only wide CSVs from other tools (``time,male:LKNE-x,male:LKNE-y,...``) are the same layout without our
comment line; there a ``subject:`` prefix is stripped when the stripped labels stay unique (not from an unlabelled
trajectory's name such as Motive's ``Unlabeled:108``).

Vicon Nexus "Trajectories" export: a ``Trajectories`` line, the rate, a row of ``subject:label`` names (one per
x/y/z triplet), ``Frame,Sub Frame,X,Y,Z,...``, a units row, then the data.  Labels are kept as Vicon writes them
(with the subject prefix, as in the matching C3D).
"""

from __future__ import annotations

import csv as _csv
import io
import re
import warnings

import numpy as np

from ..errors import DataWarning, FormatError
from ..markers import MarkerData
from .labels import (UNLABELLED_NAME, make_unique, match_label_row, named_by_place, normalise_units, point_kinds,
                     rename_notes, unit_name)
from .timing import rate_from_times

__all__ = ["read_csv", "csv_text", "csv_rows", "frame_number", "parse_numbers"]

_AXIS = re.compile(r"^(?P<label>.*?)[ _\-.]?(?P<axis>[xyzXYZ])$")
_FRAME_NAMES = {"frame", "frame#", "frames", "frame_number", "frame number"}
_TIME_NAMES = {"time", "time (s)", "time_s", "t", "seconds"}
_IGNORED_NAMES = {"sub frame", "subframe", "sub_frame"}
_VICON_SECTIONS = {"trajectories", "devices", "model outputs", "joints", "segments"}
_MISSING_TOKENS = {"", "nan", "NaN", "NAN", "-nan", "null", "NULL", "NA", "N/A"}


def parse_numbers(rows: list[list[str]], name: str, first_line: int, columns: list[str]) -> np.ndarray:
    """Cells (n_rows, n_cols) of text as float64 with NaN for empty / nan cells.

    Raises FormatError naming the file, line and column of the first cell that is not a number.
    """
    if not rows:
        return np.zeros((0, len(columns)))
    nan = float("nan")
    try:
        # Fast path: float() takes surrounding spaces and "nan"; empty cells are missing.
        return np.array([[float(c) if c else nan for c in row] for row in rows], dtype=np.float64)
    except ValueError:
        pass
    try:
        return np.array([[nan if c.strip() in _MISSING_TOKENS else float(c) for c in row] for row in rows],
                        dtype=np.float64)
    except ValueError:
        pass
    for i, row in enumerate(rows):
        for j, cell in enumerate(row):
            text = cell.strip()
            if text in _MISSING_TOKENS:
                continue
            try:
                float(text)
            except ValueError:
                col = columns[j] if j < len(columns) else f"#{j + 1}"
                raise FormatError(f"{name}: line {first_line + i}: {text[:30]!r} in column {col!r} is not a "
                                  "number") from None
    raise FormatError(f"{name}: content that is not numbers")  # pragma: no cover


def frame_number(value, name: str, what: str = "first frame") -> int:
    """An integer frame number from text or a parsed cell; FormatError naming the file when it is not one."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise FormatError(f"{name}: {what} {str(value)[:30]!r} is not a number") from None
    if not np.isfinite(number) or abs(number) >= 2 ** 31:
        raise FormatError(f"{name}: {what} {number:g} is not a frame number")
    return int(number)


def csv_rows(text: str, name: str) -> list[list[str]]:
    """All rows of CSV text.  A lone carriage return ends a line (old Mac files); anything else the ``csv`` module
    rejects (an oversized field, ...) is a FormatError naming the file."""
    try:
        return list(_csv.reader(io.StringIO(text, newline="")))
    except _csv.Error as exc:
        raise FormatError(f"{name}: malformed CSV: {exc}") from None


def check_width(rows: list[list[str]], width: int, name: str, first_line: int, pad_short: bool = False
                 ) -> list[list[str]]:
    """Rows trimmed of trailing empty fields beyond ``width``; FormatError for a row of another width."""
    out = []
    for i, row in enumerate(rows):
        if len(row) > width and not any(c.strip() for c in row[width:]):
            row = row[:width]
        if len(row) < width and pad_short:
            row = row + [""] * (width - len(row))
        if len(row) != width:
            raise FormatError(f"{name}: line {first_line + i} has {len(row)} fields, the header has {width} "
                              "(ragged CSV)")
        out.append(row)
    return out


def _finish(values: np.ndarray, name: str) -> np.ndarray:
    """(n_rows, 3 * n_markers) values -> positions (n_rows, n_markers, 3) with whole samples NaN when any is."""
    positions = values.reshape(values.shape[0], values.shape[1] // 3, 3).copy()
    missing = np.isnan(positions).any(axis=2)
    positions[missing] = np.nan
    if np.isinf(positions).any():
        raise FormatError(f"{name}: infinite coordinate values")
    return positions


def read_csv(text: str, name: str, layout: str | None = None) -> MarkerData:
    """Parse CSV text (plain wide, header-only wide or Vicon; ``layout="vicon"`` forces Vicon).

    Returns MarkerData with positions (n_frames, n_markers, 3), NaN = missing.
    """
    rows = csv_rows(text, name)
    first = next((i for i, r in enumerate(rows) if any(c.strip() for c in r)), None)
    if first is None:
        raise FormatError(f"{name}: empty CSV file")
    head = rows[first][0].strip().lower()
    if layout == "vicon" or head in _VICON_SECTIONS:
        return _read_vicon(rows, name)
    return _read_wide(rows, name)


def _meta_comment(line: list[str]) -> dict[str, str]:
    text = ",".join(line).lstrip("#").strip()
    if text.lower().startswith("mocapfill csv"):
        text = text.split(":", 1)[1] if ":" in text else ""
    meta = {}
    for part in re.split(r"[\s,;]+", text):
        if "=" in part:
            key, value = part.split("=", 1)
            meta[key.strip().lower()] = value.strip()
    return meta


def _read_wide(rows: list[list[str]], name: str) -> MarkerData:
    notes: list[str] = []
    meta: dict[str, str] = {}
    ours = False
    i = 0
    while i < len(rows) and (not any(c.strip() for c in rows[i]) or rows[i][0].lstrip().startswith("#")):
        if rows[i] and rows[i][0].lstrip().startswith("#"):
            ours = ours or "mocapfill" in rows[i][0].lower()
            meta.update(_meta_comment(rows[i]))
        i += 1
    if i >= len(rows):
        raise FormatError(f"{name}: no header row")
    header = [c.strip() for c in rows[i]]
    while header and header[-1] == "":
        header.pop()
    header_line = i + 1

    frame_col = time_col = None
    markers: list[tuple[str, dict[str, int]]] = []
    for j, col in enumerate(header):
        low = col.lower()
        if low in _FRAME_NAMES and frame_col is None:
            frame_col = j
            continue
        if low in _TIME_NAMES and time_col is None:
            time_col = j
            continue
        if low in _IGNORED_NAMES:
            continue
        match = _AXIS.match(col)
        if not match or not match.group("label").strip():
            raise FormatError(f"{name}: column {col!r} is neither frame, time nor <label>_x / _y / _z")
        label, axis = match.group("label").strip(), match.group("axis").lower()
        if markers and markers[-1][0] == label and axis not in markers[-1][1]:
            markers[-1][1][axis] = j
        else:
            markers.append((label, {axis: j}))
    for label, axes in markers:
        if set(axes) != {"x", "y", "z"}:
            seen = [c for c in header if _AXIS.match(c) and _AXIS.match(c).group("label").strip() == label]
            dup = [c for c in set(seen) if seen.count(c) > 1]
            if dup:
                raise FormatError(f"{name}: column {dup[0]!r} appears more than once and cannot be matched to one "
                                  "x, y, z triplet")
            lacking = ", ".join(sorted({"x", "y", "z"} - set(axes)))
            raise FormatError(f"{name}: marker {label!r} has no {lacking} column next to its others")
    if not markers:
        raise FormatError(f"{name}: no marker columns (<label>_x, <label>_y, <label>_z) in the header")

    data_rows = [r for r in rows[i + 1:] if any(c.strip() for c in r)]
    data_rows = check_width(data_rows, len(header), name, header_line + 1)
    values = parse_numbers(data_rows, name, header_line + 1, header)
    order = [axes[a] for _, axes in markers for a in "xyz"]
    positions = _finish(values[:, order], name) if values.size else np.zeros((0, len(markers), 3))

    labels = [label for label, _ in markers]
    if not ours:
        # Motive's "Unlabeled:108" has no subject prefix: its colon is part of the name.
        prefixed = [":" in lab and not UNLABELLED_NAME.match(lab) for lab in labels]
        stripped = [lab.split(":", 1)[1] if cut else lab for lab, cut in zip(labels, prefixed)]
        if stripped != labels and len(set(stripped)) == len(stripped) and all(stripped):
            prefixes = sorted({lab.split(":", 1)[0] for lab, cut in zip(labels, prefixed) if cut})
            notes.append(f"subject prefix {', '.join(repr(p + ':') for p in prefixes)} removed from the labels")
            labels = stripped
    labels, renamed = make_unique(labels)
    notes.extend(rename_notes(renamed))
    if renamed:
        warnings.warn(f"{name}: {len(renamed)} duplicate marker label(s) renamed (e.g. {renamed[0][1]!r})",
                      DataWarning, stacklevel=3)

    rate, rate_range = None, None
    if "rate" in meta:
        try:
            rate = float(meta["rate"])
        except ValueError:
            raise FormatError(f"{name}: rate {meta['rate']!r} in the comment line is not a number") from None
    elif time_col is not None and len(values) >= 2:
        timed = rate_from_times(values[:, time_col], name, [r[time_col] for r in data_rows])
        rate, rate_range = timed.rate, (timed.low, timed.high)
    if rate is None:
        # No rate in the file: the caller's (``--rate``); NaN tells io.read that the file had none.
        rate = float("nan")
    elif not np.isfinite(rate) or rate <= 0:
        raise FormatError(f"{name}: frame rate {rate:g} in the file is not a positive number")

    first_frame = 1
    if "first_frame" in meta:
        first_frame = frame_number(meta["first_frame"], name)
    elif frame_col is not None and len(values):
        first_frame = frame_number(values[0, frame_col], name)
    if "units" in meta and unit_name(meta["units"]):
        units = unit_name(meta["units"])
    else:
        units, note = normalise_units(meta.get("units", ""), positions)
        if note:
            notes.append(note)
    return MarkerData(positions, labels, rate, units, first_frame, "csv", None, name, notes, point_kinds(labels),
                      rate_range)


def _read_vicon(rows: list[list[str]], name: str) -> MarkerData:
    notes: list[str] = []
    start = next((i for i, r in enumerate(rows) if r and r[0].strip().lower() == "trajectories"), None)
    if start is None:
        raise FormatError(f"{name}: Vicon CSV without a 'Trajectories' section (export the trajectories)")
    try:
        rate = float(rows[start + 1][0])
        label_row, axis_row, unit_row = rows[start + 2], rows[start + 3], rows[start + 4]
    except (IndexError, ValueError):
        raise FormatError(f"{name}: Vicon CSV 'Trajectories' section lacks its rate / label / unit rows") from None
    if not axis_row or axis_row[0].strip().lower() != "frame":
        raise FormatError(f"{name}: Vicon CSV: expected 'Frame,Sub Frame,X,Y,Z,...' on line {start + 4}")
    width = len(axis_row)
    while width > 2 and not axis_row[width - 1].strip():
        width -= 1
    n_markers = (width - 2) // 3
    if (width - 2) % 3:
        raise FormatError(f"{name}: Vicon CSV: {width - 2} coordinate columns is not a multiple of 3")
    labels, label_note, matched = match_label_row(label_row[2:width], n_markers, f"the label row (line {start + 3})")
    if label_note:
        notes.append(label_note)
    if not matched:
        warnings.warn(f"{name}: {label_note}", DataWarning, stacklevel=3)
    labels = named_by_place(labels[:n_markers])
    data_rows = []
    for r in rows[start + 5:]:
        if not any(c.strip() for c in r):
            break  # a blank line ends the section
        data_rows.append(r)
    data_rows = check_width(data_rows, width, name, start + 6)
    header = ["Frame", "Sub Frame"] + [f"{lab}_{a}" for lab in labels for a in "xyz"]
    values = parse_numbers(data_rows, name, start + 6, header)
    positions = _finish(values[:, 2:], name) if values.size else np.zeros((0, n_markers, 3))
    units_text = next((c for c in unit_row[2:] if c.strip()), "")
    units, note = normalise_units(units_text, positions)
    if note:
        notes.append(note)
    labels, renamed = make_unique(labels)
    notes.extend(rename_notes(renamed))
    first_frame = frame_number(values[0, 0], name) if values.size else 1
    return MarkerData(positions, labels, rate, units, first_frame, "vicon-csv", None, name, notes, point_kinds(labels))


def _fmt(values: np.ndarray) -> list[str]:
    """Shortest round-tripping text of each float64; "" for NaN."""
    return ["" if v != v else repr(v) for v in values.tolist()]


def csv_text(data: MarkerData) -> str:
    """The plain wide CSV text of ``data`` (see the module docstring), exact for float64 positions."""
    out = io.StringIO()
    out.write(f"# mocapfill csv: units={data.units} rate={float(data.rate)!r} first_frame={int(data.first_frame)}\n")
    writer = _csv.writer(out, lineterminator="\n")
    labels = named_by_place(data.labels)  # (an empty one would write "_x", a column no reader takes)
    writer.writerow(["frame", "time"] + [f"{lab}_{a}" for lab in labels for a in "xyz"])
    flat = data.positions.reshape(data.n_frames, 3 * data.n_markers)
    times = data.times
    for t in range(data.n_frames):
        out.write(f"{data.first_frame + t},{float(times[t])!r},")
        out.write(",".join(_fmt(flat[t])))
        out.write("\n")
    return out.getvalue()
