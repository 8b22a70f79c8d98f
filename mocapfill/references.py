"""Reference takes: other captures of the same marker set that the stages of a fill can learn from.

A lab never has one capture: it has the subject's static trial, the other takes of the session, and earlier clean
takes of the same marker set.  ``fill --reference A.c3d --reference B.c3d`` (``reference=`` in Python) hands them to
every stage that can use them, each where it fits:

- the fill's body model (the default's local PCA, ``pca``): a reference's frames train it beside the capture's own,
  each reference weighted by how well its body fits the capture (:func:`weigh`), so that a take of another subject
  is used little or not at all;
- ``--reject-outliers``: the distance ranges come from the *moving* references only.  A static trial (a nearly
  motionless take, :func:`is_static`) has exact ranges that would reject normal joint motion, so it gives the body's
  shape to the fill and nothing to the outlier ranges.

Matching (:func:`match_reference`): by label, exactly or with a ``Subject:`` prefix aside, in any order; the markers
the two share are used, a capture marker the reference lacks is NaN in its frames; the reference's units are
converted to the capture's (:func:`mocapfill.units.length_factor`).  Fewer than :data:`MIN_SHARED` shared markers is
an error naming the reference; a partial match is a warning naming the markers it lacks (a label it carries but
never shows counts as lacking).

Everything here is pure NumPy on arrays of shape (n_frames, n_markers, 3) in the capture's units and marker order.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .bones.distances import pair_distances
from .errors import DataWarning, MocapfillError
from .units import length_factor

#: A reference sharing fewer markers than this with the capture cannot teach it anything (a local frame needs 3).
MIN_SHARED = 3
#: A take is static (a standing trial) when the median over its markers of each marker's RMS distance from its mean
#: position is below this (mm): a static trial sways by a few mm, the slowest CMU take (77_02, standing) moves its
#: markers by 60 mm and more.
STATIC_MM = 25.0
#: Body-shape fit: each marker's SHAPE_PAIRS most rigid partners in the capture form the pairs whose median lengths
#: are compared; they carry the subject's proportions and marker placement, not the pose.
SHAPE_PAIRS = 3
#: Weight of a reference = exp(-(shape difference / SHAPE_SCALE_MM)^2 / 2): the median over those pairs of the
#: absolute difference of their median lengths.  A median, not an RMS: a few pairs rigid in the capture alone (the
#: two feet of a subject standing through the take) can differ by 100-600 mm from a static trial and made the RMS.
#: Over every ordered pair of 14 CMU clips of the 41-marker set (``benchmarks/bench_references.py --shapes``), a take
#: of the same subject differs by 1.1-2.1 mm whole and 1.4-5.2 mm as a one-frame static trial, another subject's by
#: 10.6-42.0 mm: weight 0.43-0.96 for the first, at most 0.03 (left out) for the second.  (The RMS left 8 of the 40
#: same-subject static trials out.)
SHAPE_SCALE_MM = 4.0
#: A method that takes ``reference_frames`` but no weights gets only the references weighted at least this much.
FULL_WEIGHT = 0.5
#: References weighted below this are left out of the fill altogether (they would only cost time).
MIN_WEIGHT = 0.05
#: Frames read per take for the shape statistics (evenly spaced): enough for medians, bounded on long takes.
STAT_FRAMES = 1000
#: Frames one reference gives the fill at most (evenly spaced): every local model trains on all of them, so a
#: long take would cost time in every model and outweigh the capture; 2,000 frames (17 s at 120 Hz) cover a motion.
MAX_FILL_FRAMES = 2000


class ReferenceError(MocapfillError):
    """A reference take cannot be matched to the capture (too few shared marker labels)."""


@dataclass
class Reference:
    """One reference take, matched to a capture.

    Attributes
    ----------
    name : str
        Where it came from (its path, or ``reference N``), for messages and reports.
    positions : ndarray (n_ref_frames, n_markers, 3)
        In the capture's units and marker order; NaN where the reference lacks a marker or a sample.
    shared, lacking : list of str
        Capture labels the reference carries / lacks.
    static : bool
        A nearly motionless take (:func:`is_static`): shape for the fill, no outlier ranges.
    weight : float
        How much the fill uses it, in [0, 1] relative to one frame of the capture (:func:`weigh`); NaN until weighed.
    shape_difference : float
        Median absolute difference (capture units) of the median lengths of near-rigid marker pairs between the
        reference and the capture (:func:`shape_difference`); NaN until weighed.
    stages : dict
        Which stage used it and how: ``{"fill": "...", "reject_outliers": "..."}``.
    own_frames : bool
        It holds the capture's own frames (:func:`holds_frames_of`: the capture itself, or the take it was cut from,
        as a session's glob hands every take to itself): weight 0, left out (in the fill's cross-validation the
        capture's held-out frames would be in training, and its sd would shrink).
    """

    name: str
    positions: np.ndarray
    shared: list[str]
    lacking: list[str]
    static: bool
    weight: float = float("nan")
    shape_difference: float = float("nan")
    stages: dict[str, str] = field(default_factory=dict)
    own_frames: bool = False

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    def record(self, units: str) -> dict[str, Any]:
        """What a report says about it (JSON-ready)."""
        return {"name": self.name, "frames": self.n_frames, "static": bool(self.static),
                "shared_markers": len(self.shared), "lacking": list(self.lacking),
                "weight": None if not np.isfinite(self.weight) else round(float(self.weight), 4),
                "shape_difference": (None if not np.isfinite(self.shape_difference)
                                     else round(float(self.shape_difference), 3)),
                "units": units, "stages": dict(self.stages)}


def bare_label(label: str) -> str:
    """A marker label without its ``Subject:`` prefix (``"Male:LKNE"`` -> ``"LKNE"``)."""
    return str(label).rsplit(":", 1)[-1].strip()


def match_reference(labels: Sequence[str], units: str, ref_positions: np.ndarray, ref_labels: Sequence[str],
                    ref_units: str, *, name: str = "reference") -> Reference:
    """Match one reference take to a capture's ``labels`` and ``units``.

    ref_positions (n_ref_frames, n_ref_markers, 3) in ``ref_units``.  Returns a :class:`Reference` with positions
    (n_ref_frames, len(labels), 3) in ``units``.  Raises :class:`ReferenceError` when fewer than
    :data:`MIN_SHARED` markers match; warns (:class:`~mocapfill.errors.DataWarning`) naming the capture's markers
    the reference lacks.
    """
    ref_positions = np.asarray(ref_positions, dtype=np.float64)
    if ref_positions.ndim != 3 or ref_positions.shape[2] != 3 or ref_positions.shape[1] != len(ref_labels):
        raise ReferenceError(f"{name}: positions must have shape (n_frames, {len(ref_labels)}, 3), "
                             f"got {ref_positions.shape}")
    exact = {str(label): k for k, label in enumerate(ref_labels)}
    bare: dict[str, list[int]] = {}
    for k, label in enumerate(ref_labels):
        bare.setdefault(bare_label(label), []).append(k)
    factor = length_factor(ref_units, units)
    out = np.full((ref_positions.shape[0], len(labels), 3), np.nan)
    shared, lacking, labelled = [], [], 0
    for m, label in enumerate(labels):
        k = exact.get(str(label))
        if k is None:
            hits = bare.get(bare_label(label), [])
            k = hits[0] if len(hits) == 1 else None
        if k is None:
            lacking.append(str(label))
            continue
        labelled += 1
        if np.isnan(ref_positions[:, k]).any(axis=1).all():  # a label it never shows: it lacks the marker
            lacking.append(str(label))
            continue
        out[:, m] = ref_positions[:, k] * factor
        shared.append(str(label))
    if labelled < MIN_SHARED:
        sample = ", ".join(bare_label(x) for x in list(labels)[:5])
        raise ReferenceError(f"{name}: shares {labelled} marker label(s) with the capture (which has {sample}, "
                             f"...); a reference needs at least {MIN_SHARED} of the same marker set")
    if lacking:
        shown = ", ".join(lacking[:12]) + (f" and {len(lacking) - 12} more" if len(lacking) > 12 else "")
        use = f"it is used for the {len(shared)} it shares" if shared else "it shows none of them"
        warnings.warn(f"{name}: lacks {len(lacking)} of the capture's markers ({shown}); {use}", DataWarning,
                      stacklevel=2)
    out[np.isnan(out).any(axis=2)] = np.nan
    return Reference(name, out, shared, lacking, is_static(out, units))


def _sample(positions: np.ndarray) -> np.ndarray:
    """At most :data:`STAT_FRAMES` evenly spaced frames of positions (n_frames, n_markers, 3)."""
    n = positions.shape[0]
    if n <= STAT_FRAMES:
        return positions
    return positions[np.linspace(0, n - 1, STAT_FRAMES).round().astype(int)]


def is_static(positions: np.ndarray, units: str) -> bool:
    """Whether a take (n_frames, n_markers, 3) is nearly motionless (a static trial): see :data:`STATIC_MM`."""
    x = _sample(positions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(x, axis=0, keepdims=True)
        spread = np.sqrt(np.nanmean(((x - mean) ** 2).sum(axis=2), axis=0))  # (n_markers,)
    spread = spread[np.isfinite(spread)]
    if spread.size == 0:
        return False
    return bool(np.median(spread) < STATIC_MM * length_factor("mm", units))


def _median_lengths(positions: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    x = _sample(positions)
    d = pair_distances(x, pairs)  # (n, P)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(d, axis=0)


def pair_length_differences(positions: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Median length in the capture minus median length in the reference, per compared pair (n_pairs,).

    positions and reference (n, n_markers, 3) alike, NaN = missing.  The pairs: each marker with its
    :data:`SHAPE_PAIRS` most rigid partners in the capture (smallest spread, 10th to 90th percentile, of their
    distance over the frames where both are observed), among markers both takes carry: their lengths are the
    subject's proportions and marker placement, not the pose.  Empty when no pair can be compared.
    """
    n_markers = positions.shape[1]
    iu, ju = np.triu_indices(n_markers, 1)
    x = _sample(positions)
    d = pair_distances(x, np.stack([iu, ju], axis=1))  # (n, P)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, hi = np.nanpercentile(d, [10, 90], axis=0)
    spread = np.full((n_markers, n_markers), np.inf)
    ok = np.isfinite(hi - lo) & (np.isfinite(d).sum(axis=0) >= 10)
    spread[iu[ok], ju[ok]] = (hi - lo)[ok]
    spread[ju[ok], iu[ok]] = (hi - lo)[ok]
    has_ref = ~np.isnan(reference).any(axis=2).all(axis=0)
    spread[:, ~has_ref] = np.inf
    chosen = set()
    for m in np.flatnonzero(has_ref):
        for k in np.argsort(spread[m])[:SHAPE_PAIRS]:
            if np.isfinite(spread[m, k]):
                chosen.add((min(m, k), max(m, k)))
    if not chosen:
        return np.empty(0)
    pairs = np.array(sorted(chosen))
    diff = _median_lengths(positions, pairs) - _median_lengths(reference, pairs)
    return diff[np.isfinite(diff)]


def shape_difference(positions: np.ndarray, reference: np.ndarray) -> float:
    """How far a reference's body lies from the capture's: the median over :func:`pair_length_differences` of
    their absolute value (capture units; both arrays (n, n_markers, 3)).

    A median, as a few pairs can be rigid in this capture alone (feet planted through a standing take) and not in
    the body.  NaN when no pair can be compared.
    """
    diff = pair_length_differences(positions, reference)
    return float(np.median(np.abs(diff))) if diff.size else float("nan")


def weigh(positions: np.ndarray, references: Sequence[Reference], units: str) -> None:
    """Set each reference's ``shape_difference`` and ``weight`` from how well its body fits the capture's.

    positions (n_frames, n_markers, 3), NaN = missing (only observed samples are used).  The weight is
    exp(-(difference / :data:`SHAPE_SCALE_MM`)^2 / 2): near 1 for another take of the same subject and marker
    placement, near 0 for another body; one that holds the capture's own frames weighs 0 (``own_frames``).  The
    fill's own cross-validation then decides, per model, whether the weighted references help at all
    (:mod:`mocapfill.engines.local_pca`).
    """
    scale = SHAPE_SCALE_MM * length_factor("mm", units)
    for ref in references:
        diff = shape_difference(positions, ref.positions)
        ref.shape_difference = diff
        ref.weight = float(np.exp(-0.5 * (diff / scale) ** 2)) if np.isfinite(diff) else 0.0
        if holds_frames_of(positions, ref.positions, units):  # (the capture itself: weight 0, see Reference)
            ref.own_frames, ref.weight = True, 0.0


#: Capture frames :func:`holds_frames_of` looks for in a reference (evenly spaced), and the share that must be found.
SAMPLED_FRAMES, FOUND_SHARE = 20, 0.5


def holds_frames_of(positions: np.ndarray, frames: np.ndarray, units: str) -> bool:
    """Whether reference ``frames`` (n_ref, n_markers, 3), matched to the capture (its units and marker order), hold
    frames of the capture ``positions`` (n_frames, n_markers, 3), NaN = missing: of up to :data:`SAMPLED_FRAMES`
    evenly spaced capture frames with 3 or more markers seen, at least :data:`FOUND_SHARE` are in it, every marker
    both see within 0.05 mm (the capture itself, or the take it was cut from; a take of the same session never
    repeats a frame to that precision)."""
    tol = 0.05 * length_factor("mm", units)
    seen = ~np.isnan(positions).any(axis=2)
    sampled = np.flatnonzero(seen.sum(axis=1) >= 3)
    sampled = sampled[np.unique(np.linspace(0, len(sampled) - 1, min(SAMPLED_FRAMES, len(sampled))).round()
                                .astype(int))]
    found = 0
    for t in sampled:
        markers = np.flatnonzero(seen[t] & ~np.isnan(frames).any(axis=2).all(axis=0))
        if len(markers) < 3:
            continue
        first = markers[0]  # the few reference frames where one marker agrees, then every marker
        near = np.flatnonzero((np.abs(frames[:, first] - positions[t, first]) <= tol).all(axis=1))
        for r in near:
            both = markers[~np.isnan(frames[r, markers]).any(axis=1)]
            if len(both) >= 3 and np.max(np.abs(frames[r, both] - positions[t, both])) <= tol:
                found += 1
                break
    return bool(len(sampled)) and found >= FOUND_SHARE * len(sampled)


def completed_frames(positions: np.ndarray, frames: np.ndarray, scale: float) -> np.ndarray:
    """Reference ``frames`` (n, n_markers, 3) with their missing samples estimated (NaN where none can be).

    The estimate is the weighted PCA (:func:`mocapfill.engines.weighted_pca.reconstruct`, Gaussian width ``scale`` in
    data units) of the capture (``positions`` (n_frames, n_markers, 3), NaN = missing) and the frames together: a
    session's takes have gaps, and a model whose predictors are every near marker learns nothing from a frame that
    lacks one, nor from a reference that lacks a marker altogether, unless it is completed as the capture is.
    Observed samples come back unchanged; which are observed is the caller's to keep (a completed sample is a
    predictor, never a target).
    """
    from .engines.weighted_pca import reconstruct

    both = np.concatenate([positions, frames])
    estimate = reconstruct(both, scale=scale, uncertainty=False)[0][len(positions):]
    return np.where(np.isnan(frames), estimate, frames)  # (the reconstruction moves the rest by round-off)


def training_frames(references: Sequence[Reference]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The fill's reference frames and their weights: ``(frames (n, n_markers, 3), weights (n,))``.

    References weighted below :data:`MIN_WEIGHT` are left out (and their ``stages["fill"]`` says so); (None, None)
    when none is left.  Frames without any observed marker are dropped; a longer reference gives
    :data:`MAX_FILL_FRAMES` evenly spaced frames.
    """
    frames, weights = [], []
    for ref in references:
        if ref.own_frames:
            ref.stages["fill"] = OWN_FRAMES_TEXT
            continue
        if not np.isfinite(ref.shape_difference):
            ref.stages["fill"] = "not used: no marker pair to compare its body with the capture's by"
            continue
        if not np.isfinite(ref.weight) or ref.weight < MIN_WEIGHT:
            ref.stages["fill"] = "not used: its body differs from the capture's"
            continue
        rows = np.flatnonzero(~np.isnan(ref.positions).any(axis=2).all(axis=1))
        if len(rows) > MAX_FILL_FRAMES:
            rows = rows[np.linspace(0, len(rows) - 1, MAX_FILL_FRAMES).round().astype(int)]
        frames.append(ref.positions[rows])
        weights.append(np.full(len(rows), ref.weight))
        trains = "1 frame trains" if len(rows) == 1 else f"{len(rows)} frames train"
        ref.stages["fill"] = f"{trains} the body model, weight {ref.weight:.2f}"
    if not frames:
        return None, None
    return np.concatenate(frames), np.concatenate(weights)


#: :func:`weights_text`'s words after a reference's weight where its body differs / the method takes no references.
NOT_USED, NOT_USED_BY_METHOD = " not used", " not used by the method"
#: A results table's suffix, and a stage's words, for a reference that holds the capture's own frames.
NOT_USED_OWN = " not used: the file itself"
OWN_FRAMES_TEXT = "not used: it holds the capture's own frames (the capture itself, or the take it was cut from)"


def weights_text(references: Sequence[Reference]) -> str:
    """One line for a results table: each reference's name and weight, :data:`NOT_USED` after it where its body
    differs and :data:`NOT_USED_BY_METHOD` where the fill method takes no reference frames
    (``"static.c3d 0.82; other.c3d 0.00 not used"``); "" without references."""
    def words(ref: Reference) -> str:
        if ref.own_frames:
            return NOT_USED_OWN
        if not ref.weight >= MIN_WEIGHT:
            return NOT_USED
        return NOT_USED_BY_METHOD if ref.stages.get("fill", "").startswith("not used") else ""

    return "; ".join(f"{ref.name} {ref.weight:.2f}{words(ref)}" for ref in references)


def method_options(references: Sequence[Reference], method: str, accepted: set[str]) -> dict[str, np.ndarray]:
    """The keyword options that hand the references to a fill method: ``reference_frames`` / ``reference_weights``
    when the method takes them (its parameter names ``accepted``) and some reference is weighted in; else none, and
    each reference's ``stages["fill"]`` says why."""
    if "reference_frames" not in accepted:
        for ref in references:
            ref.stages["fill"] = f"not used: method {method!r} takes no reference frames"
        return {}
    frames, weights = training_frames(references)
    if frames is None:
        return {}
    if "reference_weights" not in accepted:  # a method without weights gets only the references weighted near 1
        keep = weights >= FULL_WEIGHT
        for ref in references:
            if ref.stages.get("fill", "").endswith(f"weight {ref.weight:.2f}") and ref.weight < FULL_WEIGHT:
                ref.stages["fill"] = f"not used: method {method!r} takes no weights, and its weight is {ref.weight:.2f}"
        return {"reference_frames": frames[keep]} if keep.any() else {}
    return {"reference_frames": frames, "reference_weights": weights}


def outlier_frames(references: Sequence[Reference]) -> np.ndarray | None:
    """Frames (n, n_markers, 3) of the moving references for ``--reject-outliers``'s distance ranges, or None.

    A static reference gives none (its exact ranges would reject normal joint motion), nor does one whose body
    differs from the capture's (weight below :data:`MIN_WEIGHT`: its pair lengths are another body's); their
    ``stages`` say so.
    """
    frames = []
    for ref in references:
        if ref.own_frames:
            ref.stages["reject_outliers"] = OWN_FRAMES_TEXT
            continue
        if ref.static:
            ref.stages["reject_outliers"] = "not used: a static trial's distance ranges would reject joint motion"
            continue
        if np.isfinite(ref.weight) and ref.weight < MIN_WEIGHT:
            ref.stages["reject_outliers"] = "not used: its body differs from the capture's"
            continue
        frames.append(ref.positions)
        ref.stages["reject_outliers"] = f"{ref.n_frames} frames give the distance ranges"
    return np.concatenate(frames) if frames else None


def prepare(data: Any, references: Sequence[Any], *, rate: float | None = None) -> list[Reference]:
    """Match and weigh references for a capture ``data`` (:class:`~mocapfill.markers.MarkerData`).

    Each item of ``references`` is a MarkerData, a path (read with :func:`mocapfill.io.read`; ``rate`` for a file
    that carries none, the capture's by default) or a :class:`Reference` already matched.  Returns the matched
    references with their weights set.
    """
    out = []
    for k, item in enumerate(references):
        if isinstance(item, Reference):
            out.append(item)
            continue
        if isinstance(item, (str,)) or hasattr(item, "__fspath__"):
            from .io import read

            name = str(item)
            item = read(item, rate=rate if rate is not None else data.rate, override_rate=True)
        else:
            name = getattr(item, "path", None) or f"reference {k + 1}"
        out.append(match_reference(list(data.labels), data.units, item.positions, list(item.labels), item.units,
                                   name=name))
    weigh(data.positions, out, data.units)
    return out
