"""Bones: marker pairs whose distance stays (nearly) constant, chosen from the observed frames of a capture.

A *bone* here is the BoLeRO paper's bone-length constraint ``<i, j, d_ij>`` (Definition 1): two markers on the same
rigid segment and the distance between them.  :func:`estimate_bones` picks them from inter-marker distance
statistics (:mod:`mocapfill.bones.distances`) computed **only over frames where both markers are observed**, so a bone
length never sees a filled or hidden sample.

Choice of pairs
---------------
For every pair observed together in at least ``min_frames`` frames:

- ``length`` is the median distance (robust to a few mislabelled frames);
- ``spread`` is a robust standard deviation of the distance: the 5-95 % inter-percentile range divided by 3.29
  (for normally distributed distances this is the standard deviation; up to 5 % wild frames on either side leave it
  unchanged);
- the pair's *score* is ``max(spread / length / max_rel_spread, spread / max_abs_spread)``: it is a bone when the
  score is <= 1, i.e. its spread is small both relative to its length (short pairs across a joint, e.g. a finger
  to a wrist) AND in absolute terms (long pairs across a joint whose angle changes little in the clip, e.g. pelvis
  to head).

Then every marker with fewer than ``min_partners`` bones gets its lowest-score remaining pairs, as long as their
score stays <= ``relax`` (default 1.25, i.e. thresholds loosened by a quarter): a marker is held by something
where the data allows it, but never by a pair that visibly stretches (a thigh marker has only the knee as a rigid
partner; pelvis pairs cross the hip and stay out).

Defaults (set on the CMU 41-marker clip 85_02 and checked on the tennis serve (metres), a Vicon upper-body trial,
an OptiTrack lower-leg cluster walk and a wheelchair-basketball clip with 39 % missing): ``max_rel_spread`` 0.04,
``max_abs_spread`` 6 mm (converted to the data's units), ``min_partners`` 3, ``relax`` 1.25, ``min_frames``
``max(10, min(100, n_frames // 2))``.  On 85_02, same-segment pairs have robust spreads of 0.9-2.4 mm (head,
wrist, LTHI-LKNE, RKNE-RSHN, LBWT-RBWT) up to 5-7 mm (pelvis, shank, RTHI-RKNE) and relative spreads of 0.4-3.6 %;
pairs across a joint have 5-10 % relative (RSHO-RUPA 5.2 %, LWRB-LFIN 6.2 %) or, when long, 9-25 mm absolute at
2-3 % relative (pelvis-head, knee-heel, pelvis-knee), which is why both thresholds are needed.  With relax 1.5 the
fallback let in RSHO-RUPA, RELB-RFIN and RSHN-RHEE; with 1.25 it does not.  Result on 85_02: 51 bones, every marker
held except LFIN (the left hand's only marker; its pairs stretch 5-10 %).

JSON format (:func:`save_bones` / :func:`load_bones`), meant to be edited by hand::

    {
      "format": "mocapfill-bones", "version": 1, "units": "mm",
      "spread": "robust standard deviation of the distance: (95th - 5th percentile) / 3.29",
      "bones": [ {"a": "RKNE", "b": "RSHN", "length": 93.51, "spread": 2.17, "frames": 810}, ... ]
    }

Only ``a``, ``b`` and ``length`` are required per bone (``spread`` and ``frames`` default to NaN and 0).  When the
file's ``units`` differ from the data's (``units=`` of :func:`load_bones`), lengths and spreads are **converted**
explicitly (mm / cm / m are exact factors) and the returned :class:`BoneSet` records the data's units.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .distances import pair_distance_stats, pair_distances
from ..errors import FormatError, InputError, MethodError, MocapfillError
from ..units import MM_PER_UNIT, length_factor

#: Default thresholds (see the module docstring for the evidence).
DEFAULT_MAX_REL_SPREAD = 0.04
DEFAULT_MAX_ABS_SPREAD_MM = 6.0
DEFAULT_MIN_PARTNERS = 3
DEFAULT_RELAX = 1.25

#: The robust spread: (p95 - p5) / this equals the standard deviation of a normal distribution.
P5_P95_TO_STD = 3.2897072539029457

SPREAD_DEFINITION = "robust standard deviation of the distance: (95th - 5th percentile) / 3.29"


@dataclass
class BoneSet:
    """Bone-length constraints: marker pairs and their lengths.

    Attributes
    ----------
    pairs : ndarray int, shape (B, 2)
        Marker indices (into the data's labels), smaller index first.
    lengths : ndarray float64, shape (B,)
        Bone length in ``units``: the median distance over the frames both markers were observed.
    spread : ndarray float64, shape (B,)
        Robust standard deviation of that distance ((p95 - p5) / 3.29) in ``units``; NaN when unknown (hand-written
        bones).
    n_frames : ndarray int, shape (B,)
        Frames in which both markers were observed (0 when unknown).
    units : str or None
        Length unit of ``lengths`` and ``spread``.
    """

    pairs: np.ndarray
    lengths: np.ndarray
    spread: np.ndarray
    n_frames: np.ndarray
    units: str | None = None

    def __post_init__(self) -> None:
        pairs = np.asarray(self.pairs, dtype=np.intp).reshape(-1, 2)
        pairs = np.sort(pairs, axis=1)
        self.pairs = pairs
        b = len(pairs)
        self.lengths = np.asarray(self.lengths, dtype=np.float64).reshape(b)
        self.spread = np.asarray(self.spread, dtype=np.float64).reshape(b)
        self.n_frames = np.asarray(self.n_frames, dtype=np.intp).reshape(b)
        if b and (pairs[:, 0] == pairs[:, 1]).any():
            raise MocapfillError("a bone joins a marker to itself")

    def __len__(self) -> int:
        return len(self.pairs)

    def subset(self, keep: np.ndarray) -> "BoneSet":
        """The bones selected by ``keep`` (bool mask shape (B,) or index array)."""
        return BoneSet(self.pairs[keep], self.lengths[keep], self.spread[keep], self.n_frames[keep], self.units)

    def partners(self, n_markers: int) -> np.ndarray:
        """Number of bones touching each marker, shape (n_markers,) int."""
        return np.bincount(self.pairs.ravel(), minlength=n_markers)[:n_markers]

    def touching(self, markers: np.ndarray) -> np.ndarray:
        """Bool mask (B,) of bones with at least one end in ``markers`` (bool mask (n_markers,) or indices)."""
        markers = np.asarray(markers)
        if markers.dtype == bool:
            return markers[self.pairs].any(axis=1)
        return np.isin(self.pairs, markers).any(axis=1)

    def violation(self, positions: np.ndarray) -> np.ndarray:
        """Distance minus bone length per frame and bone, shape (n_frames, B); NaN where a marker is missing.

        ``positions`` (n_frames, n_markers, 3) in the bones' units.
        """
        return pair_distances(positions, self.pairs) - self.lengths[None, :]

    def to_units(self, units: str) -> "BoneSet":
        """The same bones with lengths and spreads converted to ``units`` (no-op when already there / unknown)."""
        if self.units is None or self.units == units:
            return BoneSet(self.pairs, self.lengths, self.spread, self.n_frames, units)
        k = length_factor(self.units, units)
        return BoneSet(self.pairs, self.lengths * k, self.spread * k, self.n_frames, units)


def resolve_bones(positions: np.ndarray, bones: "BoneSet | None", *, units: str = "mm",
                  labels: Sequence[str] | None = None) -> BoneSet:
    """The bones a bone-aware fill uses: ``bones`` checked against the data and converted to ``units``, or, when
    None, estimated from the observed samples of ``positions`` (n_frames, n_markers, 3) only, so hidden data never
    leaks into them.  Bones without a finite positive length are dropped.
    """
    if bones is None:
        return estimate_bones(positions, units=units, labels=list(labels) if labels is not None else None)
    if not isinstance(bones, BoneSet):
        raise MethodError(f"bones must be a BoneSet or None, got {type(bones).__name__}")
    n_markers = positions.shape[1]
    if len(bones) and (bones.pairs.min() < 0 or bones.pairs.max() >= n_markers):
        raise MethodError(f"bones refer to marker {int(bones.pairs.max())} but the data has {n_markers} markers "
                          f"(index out of range 0..{n_markers - 1})")
    bones = bones.to_units(units)
    return bones.subset(np.isfinite(bones.lengths) & (bones.lengths > 0))


def default_min_frames(n_frames: int) -> int:
    """Default ``min_frames`` for a clip of ``n_frames``: ``max(10, min(100, n_frames // 2))``."""
    return max(10, min(100, n_frames // 2))


def _empty(units: str | None) -> BoneSet:
    return BoneSet(np.zeros((0, 2), np.intp), np.zeros(0), np.zeros(0), np.zeros(0, np.intp), units)


def pair_scores(positions: np.ndarray, *, units: str = "mm", max_rel_spread: float = DEFAULT_MAX_REL_SPREAD,
                max_abs_spread: float | None = None, min_frames: int | None = None, pairs: np.ndarray | None = None,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Candidate statistics for every pair: ``(pairs (P, 2), lengths, spread, n_frames, score)``, each (P,).

    ``score`` is ``max(spread / length / max_rel_spread, spread / max_abs_spread)``: <= 1 means rigid enough;
    +inf for pairs observed together in fewer than ``min_frames`` frames or with no positive length.
    ``positions`` (n_frames, n_markers, 3); ``max_abs_spread`` in ``units`` (default 6 mm converted).
    """
    positions = np.asarray(positions, dtype=np.float64)
    if max_abs_spread is None:
        max_abs_spread = DEFAULT_MAX_ABS_SPREAD_MM * length_factor("mm", units)
    if min_frames is None:
        min_frames = default_min_frames(positions.shape[0])
    if not (max_rel_spread > 0 and max_abs_spread > 0):
        raise MocapfillError(f"spread thresholds must be positive (got relative {max_rel_spread}, "
                             f"absolute {max_abs_spread})")
    stats = pair_distance_stats(positions, pairs, percentiles=(5.0, 50.0, 95.0))
    lengths = stats.percentiles[:, 1]
    spread = (stats.percentiles[:, 2] - stats.percentiles[:, 0]) / P5_P95_TO_STD
    with np.errstate(divide="ignore", invalid="ignore"):
        score = np.maximum(spread / lengths / max_rel_spread, spread / max_abs_spread)
    usable = (stats.count >= max(int(min_frames), 2)) & (lengths > 0) & np.isfinite(score)
    score = np.where(usable, score, np.inf)
    return stats.pairs, lengths, spread, stats.count, score


def estimate_bones(positions: np.ndarray, *, units: str = "mm", labels: Sequence[str] | None = None,
                   max_rel_spread: float = DEFAULT_MAX_REL_SPREAD, max_abs_spread: float | None = None,
                   min_frames: int | None = None, min_partners: int = DEFAULT_MIN_PARTNERS,
                   relax: float = DEFAULT_RELAX) -> BoneSet:
    """Choose the marker pairs that behave like rigid bones, from the observed frames only.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing; missing samples never contribute.
    units : str
        Units of ``positions``; scales the default ``max_abs_spread`` (6 mm).
    labels : sequence of str, optional
        Marker labels, only used to name a marker in error messages.
    max_rel_spread : float
        Largest robust spread relative to the length (default 0.04).
    max_abs_spread : float, optional
        Largest robust spread in ``units`` (default 6 mm converted to ``units``).
    min_frames : int, optional
        Fewest frames the two markers must be observed together (default ``max(10, min(100, n_frames // 2))``).
    min_partners : int
        Markers with fewer bones get their most rigid remaining pairs whose score stays <= ``relax``.
    relax : float
        Loosening factor of both thresholds for those extra pairs (1 = none).

    Returns
    -------
    BoneSet
        Sorted by (first marker, second marker); ``units`` set to ``units``.
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise MocapfillError(f"positions must have shape (n_frames, n_markers, 3), got {positions.shape}")
    if labels is not None and len(labels) != positions.shape[1]:
        raise MocapfillError(f"{len(labels)} labels for {positions.shape[1]} markers")
    if min_partners < 0 or relax < 1:
        raise MocapfillError(f"min_partners must be >= 0 and relax >= 1 (got {min_partners}, {relax})")
    n_markers = positions.shape[1]
    if n_markers < 2:
        return _empty(units)
    pairs, lengths, spread, count, score = pair_scores(
        positions, units=units, max_rel_spread=max_rel_spread, max_abs_spread=max_abs_spread,
        min_frames=min_frames)
    chosen = score <= 1.0
    if min_partners > 0:
        degree = np.bincount(pairs[chosen].ravel(), minlength=n_markers)
        # greedy over the remaining candidates, most rigid first: a pair joins when it helps an under-held marker
        order = np.argsort(score, kind="stable")
        for k in order:
            if score[k] > relax:
                break
            if chosen[k]:
                continue
            i, j = pairs[k]
            if degree[i] < min_partners or degree[j] < min_partners:
                chosen[k] = True
                degree[i] += 1
                degree[j] += 1
    idx = np.flatnonzero(chosen)
    return BoneSet(pairs[idx], lengths[idx], spread[idx], count[idx], units)


# ---------------------------------------------------------------------------------------------------------------
# The editable file


def bones_to_dict(bones: BoneSet, *, labels: Sequence[str], units: str | None = None) -> dict:
    """The JSON-ready dict of :func:`save_bones` (see the module docstring for the format)."""
    units = units or bones.units or "mm"
    if bones.units is not None and bones.units != units:
        bones = bones.to_units(units)
    rows = []
    for (i, j), length, spread, frames in zip(bones.pairs, bones.lengths, bones.spread, bones.n_frames):
        rows.append({"a": labels[i], "b": labels[j], "length": _round(length),
                     "spread": _round(spread) if math.isfinite(spread) else None, "frames": int(frames)})
    return {"format": "mocapfill-bones", "version": 1, "units": units, "spread": SPREAD_DEFINITION, "bones": rows}


def _round(x: float) -> float:
    # six significant digits: plenty for a length, and readable when edited by hand
    return float(f"{float(x):.6g}")


def bones_to_csv(bones: BoneSet, *, labels: Sequence[str], units: str | None = None) -> str:
    """CSV text: header ``marker_a,marker_b,length_<units>,spread_<units>,frames`` then one row per bone."""
    d = bones_to_dict(bones, labels=labels, units=units)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["marker_a", "marker_b", f"length_{d['units']}", f"spread_{d['units']}", "frames"])
    for row in d["bones"]:
        writer.writerow([row["a"], row["b"], row["length"], "" if row["spread"] is None else row["spread"],
                         row["frames"]])
    return out.getvalue()


def save_bones(bones: BoneSet, path, *, labels: Sequence[str], units: str | None = None, format: str | None = None
               ) -> None:
    """Write ``bones`` as the editable JSON (or CSV: ``format="csv"`` or a ``.csv`` path); ``"-"`` = stdout.

    ``units`` defaults to ``bones.units``; written atomically (temporary file + rename).
    """
    from ..io.atomic import atomic_write

    fmt = format or ("csv" if str(path).lower().endswith(".csv") else "json")
    if fmt == "csv":
        text = bones_to_csv(bones, labels=labels, units=units)
    elif fmt == "json":
        text = json.dumps(bones_to_dict(bones, labels=labels, units=units), indent=2) + "\n"
    else:
        raise MocapfillError(f"unknown bones format {fmt!r} (expected json or csv)")
    with atomic_write(path, "w") as handle:
        handle.write(text)


def _label_index(labels: Sequence[str]):
    exact = {label: k for k, label in enumerate(labels)}
    short: dict[str, list[int]] = {}
    for k, label in enumerate(labels):
        short.setdefault(label.rsplit(":", 1)[-1], []).append(k)

    def find(name: str) -> int | list[int] | None:
        """The index of ``name``; a list of candidates when only ambiguous prefix-free matches exist; else None."""
        if name in exact:
            return exact[name]
        # "Male:RKNE" in the file and "RKNE" (or "Derrick:RKNE") in the data: match on the name without its
        # subject prefix when that is unambiguous
        hits = short.get(str(name).rsplit(":", 1)[-1], [])
        if len(hits) == 1:
            return hits[0]
        return hits or None

    return find


def _parse_rows(path: str, text: str) -> tuple[str | None, list[dict]]:
    if str(path).lower().endswith(".csv"):
        reader = csv.reader(io.StringIO(text))
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise FormatError(f"{path}: empty bones file") from None
        if len(header) < 3 or header[0] != "marker_a" or header[1] != "marker_b" or not header[2].startswith("length"):
            raise FormatError(f"{path}: expected a header marker_a,marker_b,length_<units>,... got {','.join(header)}")
        units = header[2].split("_", 1)[1] if "_" in header[2] else None
        rows = []
        for n, rec in enumerate(reader, start=2):
            if not rec or not "".join(rec).strip():
                continue
            rec = rec + [""] * (5 - len(rec))
            rows.append({"a": rec[0].strip(), "b": rec[1].strip(), "length": rec[2].strip() or None,
                         "spread": rec[3].strip() or None, "frames": rec[4].strip() or None, "_where": f"line {n}"})
        return units, rows
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if isinstance(doc, list):
        doc = {"bones": doc}
    if not isinstance(doc, dict) or not isinstance(doc.get("bones"), list):
        raise FormatError(f"{path}: expected an object with a \"bones\" list")
    rows = []
    for n, row in enumerate(doc["bones"], start=1):
        if not isinstance(row, dict):
            raise FormatError(f"{path}: bone {n} is not an object")
        rows.append({**row, "_where": f"bone {n}"})
    return doc.get("units"), rows


def load_bones(path, labels: Sequence[str], *, units: str | None = None) -> BoneSet:
    """Read bones written by :func:`save_bones` (JSON, or CSV by extension) and map labels to marker indices.

    Parameters
    ----------
    path : str or os.PathLike
        The bones file.
    labels : sequence of str, length n_markers
        The data's marker labels.  A label is matched exactly, else by its name without a ``Subject:`` prefix
        when that is unique.
    units : str, optional
        The data's units: lengths are converted from the file's units to these (and the result says ``units``).

    Raises
    ------
    InputError
        The file cannot be read.
    FormatError
        Malformed content, an unknown label, a bad length, or a marker paired with itself; one line naming the
        file and the bone.
    """
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as handle:
            text = handle.read()
    except OSError as exc:
        raise InputError(f"{path}: cannot read bones file: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a text file") from None
    file_units, rows = _parse_rows(path, text)
    if file_units is not None and file_units not in MM_PER_UNIT:
        raise FormatError(f"{path}: unknown units {file_units!r} (expected mm, cm or m)")
    find = _label_index(list(labels))
    pairs, lengths, spreads, frames = [], [], [], []
    seen: dict[tuple[int, int], str] = {}
    for row in rows:
        where = row["_where"]
        ends = []
        for key in ("a", "b"):
            name = row.get(key)
            if not isinstance(name, str) or not name:
                raise FormatError(f"{path}: {where} has no marker {key!r}")
            k = find(name)
            if k is None:
                raise FormatError(f"{path}: {where}: unknown marker {name!r} (not among the data's "
                                  f"{len(labels)} labels)")
            if isinstance(k, list):
                raise FormatError(f"{path}: {where}: ambiguous marker {name!r} (matches "
                                  f"{', '.join(labels[i] for i in k)}); write the full label")
            ends.append(k)
        if ends[0] == ends[1]:
            raise FormatError(f"{path}: {where} joins marker {labels[ends[0]]!r} to itself")
        length = _number(path, where, "length", row.get("length"), required=True)
        if not (length > 0):
            raise FormatError(f"{path}: {where}: length must be positive, got {row.get('length')!r}")
        key = (min(ends), max(ends))
        if key in seen:
            raise FormatError(f"{path}: {where} repeats the bone {labels[key[0]]}-{labels[key[1]]} of {seen[key]}")
        seen[key] = where
        pairs.append(key)
        lengths.append(length)
        spreads.append(_number(path, where, "spread", row.get("spread"), required=False))
        nf = _number(path, where, "frames", row.get("frames"), required=False)
        frames.append(int(nf) if math.isfinite(nf) else 0)
    bones = BoneSet(np.array(pairs, dtype=np.intp).reshape(-1, 2), lengths, spreads, frames, file_units or units)
    if units is not None and file_units is not None and file_units != units:
        bones = bones.to_units(units)
    return bones


def _number(path: str, where: str, key: str, value, *, required: bool) -> float:
    if value is None or value == "":
        if required:
            raise FormatError(f"{path}: {where} has no {key}")
        return float("nan")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise FormatError(f"{path}: {where}: {key} is not a number: {value!r}") from None
    if not math.isfinite(x) and required:
        raise FormatError(f"{path}: {where}: {key} is not finite: {value!r}")
    return x
