"""The default fill (``--method auto``): the most accurate combination measured, and still fast.

Pipeline (each step chosen by measurement with the ``marker`` and ``limb`` protocols on the repository's real clips,
see ``benchmarks/bench_default.py`` and the README's figures):

1. **Local-frame weighted PCA** (:mod:`.hybrid_local`).  Gløersen & Federolf's distance-weighted PCA, computed in
   the frame of each missing marker's observed neighbourhood (weighted Kabsch alignment per frame), so that turns,
   jumps and flips no longer break its linear model; the number of components is chosen by leave-one-block-out
   cross-validation instead of the 99 % rule; three weight widths (150, 200, 300 mm) are averaged by their inverse
   cross-validated variance; a k-nearest-pose residual correction adds what the linear map misses; the residual at
   the frames just outside a gap is carried into it (Ornstein-Uhlenbeck bridge), so fills meet the observations.
2. **Bone refinement** (:mod:`.hybrid_bones`).  Bones are estimated from the observed frames of the input (never
   from anything hidden) unless given; each frame's filled markers move to the most probable positions given the
   PCA estimate (weighted by its uncertainty) and the bone lengths (weighted by their spread).  This keeps a limb
   rigid where the reconstruction drifts, which is where two-marker limb gaps lose.
3. **Fallback**: a stretch with fewer than three usable neighbours or ten training frames (whole-body blackouts,
   mostly) is filled by a cubic spline through the marker's own observations when it is at most 0.5 s long
   (blackout protocol, 10 trials: median RMSE 8 mm on the CMU clip and 4 mm on the tennis serve, against 39 and
   25 mm for straight lines), and by linear interpolation beyond (a cubic runs away over long stretches: median
   624 mm on the 10-50 % one-marker gaps of the CMU clip); edges hold the nearest observed value.  These samples
   carry no uncertainty (NaN) and are not moved by the bone refinement.

Candidates measured and left out (``benchmarks/bench_default.py``, 20 trials per clip and protocol, median RMSE in
mm on the CMU clip / tennis serve; the default: 11.6 / 3.7 one-marker, 15.3 / 5.8 limb): the published PCA alone
(29.7 / 5.4, 42.3 / 8.3) and its joint-marker strategy (no better); bone refinement with one global weight
(BoLeRO-SC style on top of the local PCA: helped the CMU clip, hurt the tennis serve); DynaMMo (135 / 35,
138 / 149) and averaging with it by inverse variance (on three CMU limb trials its predictive std was 3-8x smaller
than its error, so it would dominate the average and drag it down); BoLeRO-SC (48 / 20, 49 / 33, 0.5-0.8 s per
fill).

``info["gap_methods"]`` lists, for every gap (run of missing frames of one marker), which method filled it and why.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..errors import MethodError
from ..gaps import find_gaps
from .base import FillResult, finish
from ..blas import single_blas_thread
from .hybrid_bones import refine_bones
from .hybrid_local import DEFAULT_ALIGN_MM, DEFAULT_SCALES_MM, reconstruct_local
from .pca import DEFAULT_SCALE_MM, unit_scale

#: The PCA uncertainty is multiplied by this before the bone refinement weighs it against the bones' spread
#: (measured: trusting the reconstruction twice as much as its cross-validated error says was the best balance).
BONE_TRUST = 0.5
#: Smallest bone spread used in the refinement, in mm (a bone is never an exact constraint).
SPREAD_FLOOR_MM = 1.0
#: Longest fallback stretch filled by a cubic spline instead of a straight line, in seconds (frames without a rate).
SPLINE_SECONDS = 0.5
SPLINE_FRAMES = 60


def _resolve_bones(positions: np.ndarray, bones: Any, units: str, labels: Sequence[str] | None):
    """The BoneSet to use: ``bones`` converted to ``units``, or estimated from the observed frames when None."""
    from ..bones import BoneSet, estimate_bones

    if bones is None:
        return estimate_bones(positions, units=units, labels=list(labels) if labels is not None else None)
    if bones is False:
        return None
    if not isinstance(bones, BoneSet):
        raise MethodError(f"bones must be a BoneSet or None, got {type(bones).__name__}")
    if len(bones) and bones.pairs.max() >= positions.shape[1]:
        raise MethodError(f"bones refer to marker {int(bones.pairs.max())} but the data has "
                          f"{positions.shape[1]} markers")
    return bones.to_units(units)


def fill_auto(
    positions: np.ndarray,
    *,
    seed: int | None = None,
    units: str = "mm",
    labels: Sequence[str] | None = None,
    rate: float | None = None,
    bones: Any = None,
    knn: int = 10,
    refine: bool = True,
) -> FillResult:
    """Fill gaps with the default pipeline (see the module docstring).

    Parameters
    ----------
    positions : ndarray (n_frames, n_markers, 3), NaN = missing
    seed : ignored (the pipeline is deterministic); accepted for a uniform signature.
    units : "mm", "cm" or "m"; converts every length default.
    labels : marker labels (n_markers,), used to name markers in ``info["gap_methods"]``.
    rate : frame rate (Hz); converts the 0.5 s limit of the spline fallback (60 frames without it).
    bones : BoneSet, None (estimate from the observed frames) or False (no bone refinement).
    knn : neighbours of the nearest-pose residual correction (0 disables it).
    refine : apply the bone refinement (same as ``bones=False`` when False).

    Returns
    -------
    FillResult
        ``std`` (n_frames, n_markers): per-coordinate RMS uncertainty of each filled sample (cross-validated, grown
        with the frame's leverage, shrunk next to observations; the bone refinement does not change it).
        ``info``: ``gap_methods`` (one dict per gap: ``marker`` (label or index), ``marker_index``, ``start``,
        ``length``, ``method``, ``reason``), ``bones`` (number used), ``bone_refinement`` (frames refined, mean
        |bone error| before/after), ``fallback`` (marker indices filled by interpolation).
    """
    del seed
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise MethodError(f"positions must have shape (n_frames, n_markers, 3), got {positions.shape}")
    if labels is not None and len(labels) != positions.shape[1]:
        raise MethodError(f"{len(labels)} labels for {positions.shape[1]} markers")
    with single_blas_thread():  # thousands of small decompositions: BLAS threads only add contention
        return _fill_auto(positions, units=units, labels=labels, rate=rate, bones=bones, knn=knn, refine=refine)


def _fill_auto(positions: np.ndarray, *, units: str, labels, rate, bones, knn: int, refine: bool) -> FillResult:
    """The body of :func:`fill_auto` (positions (n_frames, n_markers, 3), already validated)."""
    mm = unit_scale(units, None) / DEFAULT_SCALE_MM  # data units per millimetre
    missing = np.isnan(positions).any(axis=2)
    estimate, std, local_info = reconstruct_local(positions, scales=tuple(DEFAULT_SCALES_MM * mm),
                                                  align_scale=DEFAULT_ALIGN_MM * mm, knn=knn)
    spline_max = int(round(SPLINE_SECONDS * rate)) if rate else SPLINE_FRAMES
    estimate, splined = _spline_short_fallbacks(positions, estimate, missing & np.isnan(std), spline_max)
    info: dict[str, Any] = {"pipeline": "local-frame weighted PCA + bone refinement",
                            "fallback": local_info["fallback"], "spline_max_frames": spline_max}
    boneset = _resolve_bones(positions, bones if refine else False, units, labels)
    if boneset is not None and len(boneset):
        estimate, binfo = refine_bones(estimate, positions, std * BONE_TRUST, boneset.pairs, boneset.lengths,
                                       boneset.spread, spread_floor=SPREAD_FLOOR_MM * mm)
        info["bone_refinement"] = binfo
    info["bones"] = 0 if boneset is None else int(len(boneset))
    info["gap_methods"] = _gap_methods(missing, std, local_info, boneset, labels, units, splined, spline_max)
    return finish(positions, estimate, std=std, info=info)


def _spline_short_fallbacks(positions: np.ndarray, estimate: np.ndarray, fallback: np.ndarray, longest: int
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Replace the fallback (linear) fill of every interior stretch of at most ``longest`` frames by a cubic spline.

    positions / estimate (n_frames, n_markers, 3); fallback (n_frames, n_markers) bool: samples the PCA could not
    fill.  Returns the new estimate and the (n_frames, n_markers) mask of splined samples.
    """
    from ..gaps import runs
    from .interp import fill_spline

    splined = np.zeros_like(fallback)
    if not fallback.any() or longest < 1:
        return estimate, splined
    n_frames = positions.shape[0]
    spline = None
    for m in np.flatnonzero(fallback.any(axis=0)):
        for start, length in runs(fallback[:, m]):
            interior = start > 0 and start + length < n_frames
            if length <= longest and interior:
                if spline is None:
                    spline = fill_spline(positions).positions
                splined[start:start + length, m] = True
    if spline is not None:
        estimate = estimate.copy()
        estimate[splined] = spline[splined]
    return estimate, splined


def _gap_methods(missing: np.ndarray, std: np.ndarray, local_info: dict, boneset, labels, units: str,
                 splined: np.ndarray, spline_max: int) -> list[dict]:
    """One record per gap: which method filled it and why (JSON-ready)."""
    cv = {}
    for g in local_info["groups"]:
        cv.setdefault(g["marker"], []).append(g)
    bone_count = np.zeros(missing.shape[1], dtype=int)
    if boneset is not None and len(boneset):
        bone_count = np.bincount(boneset.pairs.ravel(), minlength=missing.shape[1])
    out = []
    for gap in find_gaps(missing):
        m = gap.marker
        name = labels[m] if labels is not None else m
        rec = {"marker": name, "marker_index": int(m), "start": int(gap.start), "length": int(gap.length)}
        seg = std[gap.start:gap.stop, m]
        if missing[:, m].all():
            rec.update(method="none", reason="marker missing in every frame: nothing to learn from")
        elif not np.isfinite(seg).all():
            why = "fewer than 3 observed neighbours or 10 training frames for PCA"
            if splined[gap.start:gap.stop, m].all():
                rec.update(method="spline", reason=f"{why}; short (<= {spline_max} frames): cubic spline")
            elif np.isfinite(seg).any():
                rec.update(method="local-pca+interpolation",
                           reason=f"{why} in part of the gap: that part interpolated (spline when short)")
            else:
                rec.update(method="linear", reason=f"{why}; too long for a spline or at the clip's edge: "
                                                   f"linear interpolation, edges held")
        else:
            groups = cv.get(m, [])
            rms = [r for g in groups for r in g["cv_rms"] if np.isfinite(r)]
            why = "local-frame weighted PCA: the marker's observed neighbours predict it"
            if rms:
                why += f" (cross-validated error {min(rms):.3g} {units})"
            method = "local-pca"
            if bone_count[m]:
                method = "local-pca+bones"
                why += f"; refined with {int(bone_count[m])} bone(s) to keep its segment rigid"
            rec.update(method=method, reason=why)
        out.append(rec)
    return out
