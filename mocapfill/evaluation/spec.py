"""Occlusion spec files: an exact list of trials to replay, independent of any one clip.

Layout (JSON; ``docs/occlusions.md`` has the full description and an example)::

    {
      "format": "mocapfill-occlusions/1",
      "units": "mm",                       # optional: units of the shift offsets (default: the clip's)
      "trials": [
        {"occlusions": [{"markers": ["RKNE", "RSHN"], "first_frame": 25, "length": 66}],
         "shifts": [{"marker": "LELB", "first_frame": 100, "length": 5, "offset": [120.0, 0.0, -40.0]}]},
        {"occlusions": [{"markers": "*", "start": 300, "length": 12}]}
      ]
    }

- ``markers``: a list of labels, one label, or ``"*"`` (every marker).  A label matches a clip's label exactly or,
  failing that, by its name after the subject prefix (``RKNE`` matches ``Male:RKNE``) when that is unambiguous.
- ``first_frame`` is in the clip's own numbering (C3D counts from its header's first frame, usually 1); ``start``
  is a 0-based index from the clip's first frame instead.  ``length`` is in frames.
- ``shifts`` (optional) displace a marker by ``offset`` (x, y, z) over a stretch; used by the ``random`` protocol.
- A bare list of trials is accepted too; unknown keys (``source``, ``description``) are ignored.
"""

from __future__ import annotations

import json
import os
from typing import Any

from ..errors import InputError, MocapfillError
from ..units import MM_PER_UNIT, length_factor
from .occlusions import Occlusion, Shift, Trial

SPEC_FORMAT = "mocapfill-occlusions/1"


def resolve_label(label: str, labels: list[str], *, where: str) -> int:
    """Index of ``label`` in ``labels``: exact match, else the unique match of the name after any ``Subject:`` prefix."""
    if label in labels:
        return labels.index(label)
    base = str(label).rsplit(":", 1)[-1]
    hits = [i for i, lab in enumerate(labels) if lab.rsplit(":", 1)[-1] == base]
    if len(hits) == 1:
        return hits[0]
    if hits:
        raise MocapfillError(f"{where}: marker {label!r} is ambiguous ({', '.join(labels[i] for i in hits)})")
    raise MocapfillError(f"{where}: no marker called {label!r} in the clip")


def _start(rec: dict, first_frame: int, where: str) -> int:
    if "first_frame" in rec:
        value = rec["first_frame"]
        offset = first_frame
    elif "start" in rec:
        value = rec["start"]
        offset = 0
    else:
        raise MocapfillError(f"{where}: needs 'first_frame' (clip numbering) or 'start' (0-based)")
    if not isinstance(value, int) or isinstance(value, bool):
        raise MocapfillError(f"{where}: first frame {value!r} is not a whole number")
    return value - offset


def _length(rec: dict, where: str) -> int:
    value = rec.get("length")
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise MocapfillError(f"{where}: 'length' must be a whole number of frames >= 1, got {value!r}")
    return value


def _check_span(start: int, length: int, n_frames: int, first_frame: int, where: str) -> None:
    if start < 0 or start + length > n_frames:
        raise MocapfillError(f"{where}: frames {start + first_frame}-{start + first_frame + length - 1} fall outside "
                             f"the clip's frames {first_frame}-{first_frame + n_frames - 1}")


def trials_from_spec(spec: Any, data, *, name: str = "occlusion spec") -> list[Trial]:
    """Trials of a parsed spec (dict or list, see the module docstring) resolved against ``data``'s labels/frames.

    ``data`` : MarkerData, positions (n_frames, n_markers, 3).  Raises MocapfillError naming ``name``, the trial and
    the field at fault.
    """
    if isinstance(spec, dict):
        fmt = spec.get("format", SPEC_FORMAT)
        if fmt != SPEC_FORMAT:
            raise MocapfillError(f"{name}: format {fmt!r} is not {SPEC_FORMAT!r}")
        trials_raw = spec.get("trials")
        units = spec.get("units")
    else:
        trials_raw, units = spec, None
    if not isinstance(trials_raw, list) or not trials_raw:
        raise MocapfillError(f"{name}: expected a non-empty list 'trials'")
    scale = 1.0
    if units is not None:
        if units not in MM_PER_UNIT or str(data.units) not in MM_PER_UNIT:
            raise MocapfillError(f"{name}: cannot convert shift offsets from {units!r} to {data.units!r}")
        scale = length_factor(units, str(data.units))
    labels = list(data.labels)
    n_frames, first = data.n_frames, int(data.first_frame)
    out = []
    for t, raw in enumerate(trials_raw, start=1):
        where = f"{name}: trial {t}"
        if not isinstance(raw, dict):
            raise MocapfillError(f"{where}: expected an object with 'occlusions'")
        occs_raw = raw.get("occlusions", [])
        shifts_raw = raw.get("shifts", [])
        if not isinstance(occs_raw, list) or not isinstance(shifts_raw, list):
            raise MocapfillError(f"{where}: 'occlusions' and 'shifts' must be lists")
        if not occs_raw and not shifts_raw:
            raise MocapfillError(f"{where}: hides nothing")
        occs = []
        for k, rec in enumerate(occs_raw, start=1):
            w = f"{where}, occlusion {k}"
            if not isinstance(rec, dict):
                raise MocapfillError(f"{w}: expected an object")
            markers = rec.get("markers", rec.get("marker"))
            if markers == "*":
                idx = tuple(range(len(labels)))
            elif isinstance(markers, str):
                idx = (resolve_label(markers, labels, where=w),)
            elif isinstance(markers, list) and markers and all(isinstance(m, str) for m in markers):
                idx = tuple(sorted({resolve_label(m, labels, where=w) for m in markers}))
            else:
                raise MocapfillError(f"{w}: 'markers' must be a label, a list of labels or \"*\"")
            start, length = _start(rec, first, w), _length(rec, w)
            _check_span(start, length, n_frames, first, w)
            occs.append(Occlusion(idx, start, length))
        shifts = []
        for k, rec in enumerate(shifts_raw, start=1):
            w = f"{where}, shift {k}"
            if not isinstance(rec, dict) or not isinstance(rec.get("marker"), str):
                raise MocapfillError(f"{w}: expected an object with a 'marker' label")
            offset = rec.get("offset")
            if (not isinstance(offset, list) or len(offset) != 3
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in offset)):
                raise MocapfillError(f"{w}: 'offset' must be three numbers")
            start, length = _start(rec, first, w), _length(rec, w)
            _check_span(start, length, n_frames, first, w)
            shifts.append(Shift(resolve_label(rec["marker"], labels, where=w), start, length,
                                tuple(float(v) * scale for v in offset)))
        out.append(Trial(tuple(occs), tuple(shifts)))
    return out


def load_spec(path: str | os.PathLike, data) -> list[Trial]:
    """Read the spec file at ``path`` and resolve it against ``data`` (see :func:`trials_from_spec`)."""
    name = os.fspath(path)
    try:
        with open(name, encoding="utf-8") as handle:
            spec = json.load(handle)
    except FileNotFoundError:
        raise InputError(f"{name}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{name}: is a directory, not a file") from None
    except UnicodeDecodeError:
        raise MocapfillError(f"{name}: not a UTF-8 JSON file") from None
    except json.JSONDecodeError as exc:
        raise MocapfillError(f"{name}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    return trials_from_spec(spec, data, name=name)


def spec_of(trials: list[Trial], data, *, source: dict | None = None) -> dict:
    """The JSON-ready spec of ``trials`` on ``data`` (labels, frames in the clip's numbering, offsets in its units)."""
    labels = list(data.labels)
    first = int(data.first_frame)
    n_markers = len(labels)
    out_trials = []
    for trial in trials:
        occs = []
        for occ in trial.occlusions:
            markers: Any = "*" if len(occ.markers) == n_markers and n_markers > 1 else [labels[m] for m in occ.markers]
            occs.append({"markers": markers, "first_frame": first + occ.start, "length": occ.length})
        rec: dict[str, Any] = {"occlusions": occs}
        if trial.shifts:
            rec["shifts"] = [{"marker": labels[s.marker], "first_frame": first + s.start, "length": s.length,
                              "offset": [float(v) for v in s.offset]} for s in trial.shifts]
        out_trials.append(rec)
    spec: dict[str, Any] = {"format": SPEC_FORMAT, "units": str(data.units)}
    if source:
        spec["source"] = source
    spec["trials"] = out_trials
    return spec


def save_spec(trials: list[Trial], data, path: str | os.PathLike, *, source: dict | None = None) -> None:
    """Write ``trials`` as a spec file (atomically) that :func:`load_spec` replays exactly on ``data``."""
    from ..io.atomic import atomic_write

    text = json.dumps(spec_of(trials, data, source=source), indent=1) + "\n"
    with atomic_write(path, "w", encoding="utf-8") as handle:
        handle.write(text)
