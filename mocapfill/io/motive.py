"""OptiTrack Motive CSV export (read; format name ``motive-csv``).

Layout (Motive's "Data Export: CSV", format versions 1.1x to 1.2x)::

    Format Version,1.23,Take Name,...,Export Frame Rate,120.000000,...,Length Units,Millimeters,...
    <blank line>
    ,Type,Rigid Body,...,Rigid Body Marker,...,Marker,Marker,Marker
    ,Name,Hand,...,Hand:Marker1,...,Unlabeled 1000,...
    ,ID,1,...
    ,Parent,...                       (recent versions only)
    ,,Rotation,...,Position,Position,Position,Marker Quality,...
    Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,...
    0,0.000000,...

- The first line is ``key,value`` pairs: the rate is ``Export Frame Rate`` (else ``Capture Frame Rate``, else the
  time column), the units ``Length Units``.  Older exports (1.21) leave the ``Type``/``Name``/``ID`` cells of the
  header rows empty and call the time column ``Time``; the rows are then taken in that order.
- Every ``Position`` X/Y/Z triplet of a column whose type names a marker (``Marker``, ``Rigid Body Marker``, skeleton
  ``Bone Marker`` ...) becomes one marker, labelled by its ``Name`` row; rigid-body and bone centres, rotations,
  qualities and errors are skipped.  Empty cells (occlusions) are missing samples.
- The first frame is the ``Frame`` column's first value (Motive counts from 0).
"""

from __future__ import annotations

import numpy as np

from ..errors import FormatError
from ..markers import MarkerData
from .csv import check_width, csv_rows, frame_number, parse_numbers
from .labels import make_unique, normalise_units, point_kinds, rename_notes, unit_name
from .timing import rate_from_times

__all__ = ["read_motive"]

_ROW_NAMES = ("type", "name", "id", "parent")


def read_motive(text: str, name: str) -> MarkerData:
    """Parse Motive CSV text into MarkerData (positions (n_frames, n_markers, 3) in the file's units, NaN = missing).

    Raises FormatError naming the file for a damaged export or one without marker positions.
    """
    rows = csv_rows(text, name)
    if not rows or not rows[0] or rows[0][0].lstrip("\ufeff").strip().lower() != "format version":
        raise FormatError(f"{name}: not an OptiTrack Motive CSV (the first line should start with 'Format Version')")
    first = [c.strip() for c in rows[0]]
    meta = {first[i]: first[i + 1] for i in range(0, len(first) - 1, 2)}
    axis_at = next((i for i, r in enumerate(rows) if r and r[0].strip().lower() == "frame"), None)
    if axis_at is None:
        raise FormatError(f"{name}: Motive CSV without its 'Frame,Time,X,Y,Z,...' row (export with the header)")
    header = [r for r in rows[1:axis_at] if any(c.strip() for c in r)]
    if len(header) < 2:
        raise FormatError(f"{name}: Motive CSV header lacks its Type / Name / Position rows")
    named = {r[1].strip().lower(): r for r in header if len(r) > 1 and r[1].strip().lower() in _ROW_NAMES}
    types = named.get("type", header[0])
    names = named.get("name", header[1] if len(header) > 2 else header[0])
    components = header[-1]
    axes = [c.strip().upper() for c in rows[axis_at]]
    width = len(axes)
    while width > 2 and not axes[width - 1]:
        width -= 1

    cell = lambda row, j: row[j].strip() if j < len(row) else ""  # noqa: E731
    labels, columns = [], []
    j = 2
    while j + 2 < width:
        kind, comp = cell(types, j).lower(), cell(components, j).lower()
        if (kind.endswith("marker") and comp == "position" and axes[j:j + 3] == ["X", "Y", "Z"]
                and cell(names, j) == cell(names, j + 2)):
            labels.append(cell(names, j) or f"M{len(labels) + 1:03d}")
            columns.append([j, j + 1, j + 2])
            j += 3
        else:
            j += 1
    if not labels:
        raise FormatError(f"{name}: Motive CSV without marker positions (export the markers)")
    notes: list[str] = []
    labels, renamed = make_unique(labels)
    notes.extend(rename_notes(renamed))

    data_rows = [r for r in rows[axis_at + 1:] if any(c.strip() for c in r)]
    data_rows = check_width(data_rows, width, name, axis_at + 2)
    cols = np.array(columns, dtype=int)
    header_names = [f"{lab}_{a}" for lab in labels for a in "xyz"]
    values = parse_numbers([[r[k] for k in cols.reshape(-1)] for r in data_rows], name, axis_at + 2, header_names)
    positions = values.reshape(len(data_rows), len(labels), 3).copy()
    if np.isinf(positions).any():
        raise FormatError(f"{name}: infinite coordinate values")
    positions[np.isnan(positions).any(axis=2)] = np.nan
    clock = parse_numbers([r[:2] for r in data_rows], name, axis_at + 2, ["Frame", "Time"])

    rate, rate_range = _rate(meta, clock[:, 1], [r[1] for r in data_rows], name)
    first_frame = frame_number(clock[0, 0], name) if len(clock) else 0
    units = unit_name(meta.get("Length Units", ""))
    if units is None:
        units, note = normalise_units(meta.get("Length Units", ""), positions)
        notes.append(note)
    return MarkerData(positions, labels, rate, units, first_frame, "motive-csv", None, name, notes,
                      point_kinds(labels), rate_range)


def _rate(meta: dict, times: np.ndarray, cells: list[str], name: str) -> tuple[float, tuple[float, float] | None]:
    """The rate and the range the times agree with (:attr:`MarkerData.rate_range`): the header's rate (no range),
    else the time column's (:func:`rate_from_times`), else NaN."""
    for key in ("Export Frame Rate", "Capture Frame Rate"):
        if meta.get(key):
            try:
                rate = float(meta[key])
            except ValueError:
                raise FormatError(f"{name}: {key} {meta[key][:30]!r} is not a number") from None
            if not np.isfinite(rate) or rate <= 0:
                raise FormatError(f"{name}: {key} {rate:g} is not a positive frame rate")
            return rate, None
    if np.isfinite(times).sum() >= 2:
        timed = rate_from_times(times, name, cells)
        return timed.rate, (timed.low, timed.high)
    return float("nan"), None
