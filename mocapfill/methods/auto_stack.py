"""The default fill (``--method auto``): the most accurate combination measured, and still fast.

Pipeline (each step chosen by measurement with the ``marker`` and ``limb`` protocols on the repository's real clips,
see ``benchmarks/bench_default.py`` and the README's figures):

1. **Local-frame weighted PCA** (:mod:`.local_pca`).  Gløersen & Federolf's distance-weighted PCA, computed in
   the frame of each missing marker's observed neighbourhood (weighted Kabsch alignment per frame), so that turns,
   jumps and flips no longer break its linear model; the number of components is chosen by leave-one-block-out
   cross-validation instead of the 99 % rule; three weight widths (150, 200, 300 mm) are averaged by their inverse
   cross-validated variance; a k-nearest-pose residual correction adds what the linear map misses; the residual at
   the frames just outside a gap is carried into it (Ornstein-Uhlenbeck bridge), so fills meet the observations.
   When many markers are missing at once (issue 9: 20-30 % of the samples in 0.25-2 s gaps leave 0-2 % of the
   frames complete) each model conditions only on the markers observed where it predicts and keeps the nearest of
   them that still leave 100 training frames: it learns from incomplete frames (CMU 85_02 at 20 % missing: median
   / RMSE 169 / 331 mm on the issue's clips before, 9.6 / 26 mm now; ``benchmarks/bench_messy.py``).
2. **Bone refinement** (:mod:`.bone_refinement`).  Bones are estimated from the observed frames of the input (never
   from anything hidden) unless given; each frame's filled markers move to the most probable positions given the
   PCA estimate (weighted by its uncertainty) and the bone lengths (weighted by their spread).  This keeps a limb
   rigid where the reconstruction drifts, which is where two-marker limb gaps lose.
3. **Fallback**: a stretch with fewer than three usable neighbours or ten training frames (whole-body blackouts,
   mostly) is filled by a cubic spline through the marker's own observations when it is at most 0.5 s long
   (blackout protocol, 10 trials: median RMSE 8 mm on the CMU clip and 4 mm on the tennis serve, against 39 and
   25 mm for straight lines).  Beyond that, when some untrusted stretch (step 4) is longer than 0.5 s (a messy
   capture: on the dense protocol at 20-30 % missing; rarely at 5-10 %, never on one-marker or limb gaps), or when
   short gaps are everywhere (fewer than 10 % of the frames complete and more than 7 % of the samples missing:
   Holden's random protocol, :data:`GUIDE_COMPLETE`), a dynamics guide is fitted (:func:`dynamics_guide`): BoLeRO-SC (:mod:`.bolero`, DynaMMo with the bones as soft
   constraints, which learns from every frame, complete or not), or DynaMMo alone where no bones are known.  The
   fallback follows the guide, shifted linearly to meet the known samples at the stretch's ends (a straight line
   there missed a tennis player's hand by a metre); otherwise linear interpolation; edges hold the nearest
   observed value.  These samples carry no uncertainty of their own (NaN) and are not moved by the bone
   refinement.
4. **Trust check and smooth blend** (:func:`pca_trust`, :func:`limit_trust_changes`).  With few neighbours left
   (a subject walking out of the volume) the local frame rests on a few far points and the PCA jumped by up to
   700 mm between frames (VER4C3D's toe).  Each PCA sample gets a trust in [0, 1]: lowered by its uncertainty
   (50-150 mm) and by its step to the neighbouring frames (1.5-3x the larger of the marker's largest observed step
   and the body's largest step at that frame).  (A cap for frames defined by only three neighbours was dropped in
   issue 9: on dense gaps the nearest three often define it well, and the cap blended good estimates into
   interpolation, tennis serve at 30 %: 12 / 63 mm with it, 8 / 29 without; the step checks keep the walk-outs
   calm.)  The fallback path then runs through the observations and the fully trusted samples; trust is lowered
   further so that it changes by at most half a largest observed step per frame, and each filled sample is
   trust x PCA + (1 - trust) x fallback.  A guard distrusts an ever wider stretch around any filled step still
   above 3x the reference step.
5. **Mixing by uncertainty** (:func:`mix_by_uncertainty`, only when BoLeRO-SC guided): every filled sample becomes
   the inverse-variance average of this pipeline's estimate and BoLeRO-SC's (a fallback sample, which has no
   uncertainty, takes BoLeRO-SC's; a short splined run keeps its spline).  Dense protocol, pooled RMSE at 20 / 30 %
   missing: 26.1 / 38.5 mm with the guide alone, 20.4 / 32.5 with the mixing (BoLeRO-SC alone 27.4 / 37.4).
6. **Plausibility** (:func:`guide_where_implausible`, :func:`.plausibility.project_plausible`).  A gap run that
   holds a sample beyond 1.1x the body's observed extent or a step beyond 3x the reference takes the guide instead,
   where the guide is plausible there (uncertainty growing towards the middle like a Brownian bridge).  Then every
   filled run is moved to the nearest path (least squares) that stays within 1.1x the body's observed extent and
   steps at most 1.5x the larger of the marker's largest observed step and the body's largest step at that frame;
   its uncertainty grows by the distance moved.  Only where the observations themselves make that impossible (the
   marker reappears farther away than those steps reach) is the calmest path kept and the gap reported as forced.
   The bound is not the marker's own largest step alone: the hidden truth of the dense trials breaks that by up to
   4.4x (85_02's flips hide the knees while they move fastest), and holding it cost 11.8 -> 73 mm RMSE at 5 %
   missing; the body's bound is never broken by the truth there.  ``benchmarks/bench_messy.py`` reports the extent
   and speed ratios on every capture with real gaps; ``tests/test_plausibility.py`` guards the committed ones.

Long takes: :func:`_fill_auto_stack` is one call on the whole array; a windowed fill (``methods/windows.py``, issue 9's
long-take part) wraps exactly that call (see the comment at its end).

Candidates measured and left out (``benchmarks/bench_default.py``, 20 trials per clip and protocol, median RMSE in
mm on the CMU clip / tennis serve; the default: 11.6 / 3.7 one-marker, 15.3 / 5.8 limb): the published PCA alone
(29.7 / 5.4, 42.3 / 8.3) and its joint-marker strategy (no better); bone refinement with one global weight
(BoLeRO-SC style on top of the local PCA: helped the CMU clip, hurt the tennis serve); DynaMMo (135 / 35,
138 / 149) and averaging with it by inverse variance (on three CMU limb trials its predictive std was 3-8x smaller
than its error, so it would dominate the average and drag it down); BoLeRO-SC (48 / 20, 49 / 33, 0.5-0.8 s per
fill).

``info["gap_methods"]`` lists, for every gap (run of missing frames of one marker), which method filled it and why
(``+fallback`` when part of it was blended into the fallback, with the count of frames per reason).
"""

from __future__ import annotations

import warnings
from functools import partial
from typing import Any, Sequence

import numpy as np

from ..errors import ConvergenceWarning, MethodError
from ..gaps import find_gaps
from .base import FillResult, finish
from ..runtime.blas import single_blas_thread
from ..bones.boneset import resolve_bones
from ..bones.refinement import refine_bones
from ..guards.plausibility import implausible, observed_speed, project_plausible
from ..engines.local_pca import DEFAULT_ALIGN_MM, DEFAULT_SCALES_MM, reconstruct_local
from ..guards.windows import DEFAULT_WINDOW, fill_in_windows
from ..units import length_factor

#: The PCA uncertainty is multiplied by this before the bone refinement weighs it against the bones' spread
#: (measured: trusting the reconstruction twice as much as its cross-validated error says was the best balance).
BONE_TRUST = 0.5
#: Smallest bone spread used in the refinement, in mm (a bone is never an exact constraint).
SPREAD_FLOOR_MM = 1.0
#: Longest fallback stretch filled by a cubic spline instead of a straight line, in seconds (frames without a rate).
SPLINE_SECONDS = 0.5
SPLINE_FRAMES = 60
#: Trust in a local PCA sample falls from 1 to 0 as its uncertainty grows from the first to the second value (mm):
#: the default's median errors are 4-15 mm, and a PCA that doubts itself by decimetres is no better than a guess.
TRUST_STD_MM = 50.0
DISTRUST_STD_MM = 150.0
#: ... and as its step to a neighbouring frame grows from FAST to STEP_BOUND times the reference step (the larger of
#: the marker's largest observed step and the body's largest step at that frame); STEP_BOUND is also the final
#: guard: no filled step longer than it keeps any PCA trust.
FAST = 1.5
STEP_BOUND = 3.0
#: Blending moves a fill by at most this fraction of the marker's largest observed step per frame (a ramp, not a
#: switch, between the PCA and the fallback).
BLEND_STEP = 0.5
#: Below this trust a sample is the fallback's (no uncertainty, not moved by the bones).
MIN_ALPHA = 0.05
#: Slowest speed limit (mm per frame); passes of the final guard.
MIN_SPEED_MM = 1.0
JUMP_PASSES = 6
#: The guide also runs, however short the gaps, when fewer than GUIDE_COMPLETE of the frames are complete and more
#: than GUIDE_MISSING of the samples (of markers seen somewhere) are missing.  Holden's random protocol (0.05-0.5 s
#: gaps and rejected shifted stretches: 1-7 % of the frames complete, 7.6-12.3 % of the samples missing) never
#: leaves an untrusted stretch longer than 0.5 s, yet there the local PCA alone had a median RMSE of 34.6 / 20.3 mm
#: (85_02 / tennis serve, perfect detector, 6 trials each) and with the guide 19.5 / 10.0 (BoLeRO-SC alone 25.3 /
#: 12.3).  At 5 % missing (the dense protocol, 7-29 % of the frames complete) the local model alone is best: there
#: the guide changed the pooled median / RMSE from 3.7 / 10.4 to 3.8 / 10.1 mm at three times the time, and the
#: 5,000-frame windows of a take with 5 % missing hold 4.2-6.3 % (a 6 % bound ran the guide in three of sixteen,
#: 52 -> 70 s).  One-marker and limb gaps leave >= 50 % of the frames complete.
GUIDE_COMPLETE = 0.10
GUIDE_MISSING = 0.07
#: ... and only in captures longer than this many spline lengths (4 x 0.5 s = 2 s): on CMU 127_07 (1.2 s) the guide
#: is learned from too little (BoLeRO-SC alone: median 76.9 mm on the random protocol with a perfect detector), and
#: mixing it in took the default from 12.5 to 23.4 mm there.
GUIDE_MIN_SPLINES = 4

#: Where reference takes trained the local PCA (:mod:`mocapfill.references`) its uncertainty bounds of trust are this
#: many times wider: its model has seen the body in many more poses, and a fallback through a long gap (spline,
#: line, a dynamics guide learnt from the gappy capture alone) is far worse than a PCA doubting itself by 5-15 cm.
REFERENCE_STD_SCALE = 4.0
#: ... and no dynamics guide runs, when at least this fraction of the local models kept the references: the guide
#: learns from the gappy capture alone (CMU 07_12 with 07_01 as reference, segment / dense 30 %: 57 -> 22, 70 -> 27,
#: 111 -> 35 mm RMSE without it).
REFERENCE_MODELS = 0.5

GUIDE_NAMES = {"dynammo": "DynaMMo", "bolero-sc": "BoLeRO-SC"}


def fill_auto_stack(
    positions: np.ndarray,
    *,
    seed: int | None = None,
    units: str = "mm",
    labels: Sequence[str] | None = None,
    rate: float | None = None,
    bones: Any = None,
    knn: int = 10,
    refine: bool = True,
    jobs: int = 1,
    reference_frames: np.ndarray | None = None,
    reference_weights: np.ndarray | None = None,
) -> FillResult:
    """Fill gaps with the default pipeline (see the module docstring).

    A take longer than :data:`windows.DEFAULT_WINDOW` frames is filled in overlapping windows
    (:func:`windows.fill_in_windows`), so time grows linearly with its length and memory stays bounded.

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
    reference_frames, reference_weights : frames (n_ref_frames, n_markers, 3) of reference takes of the same marker
        set in this capture's units and marker order (NaN where a reference lacks a marker), and their weights
        (n_ref_frames,) in [0, 1]; they train the local PCA beside the capture's frames
        (:func:`~mocapfill.engines.local_pca.reconstruct_local`).  ``mocapfill.fill(..., reference=[...])`` builds
        them (:mod:`mocapfill.references`).
    jobs : local worker processes for the windows of a long take (1, the default: here; 0: every core); the output
        does not depend on it.  Workers are spawned: a script needs the ``if __name__ == "__main__":`` guard.

    Returns
    -------
    FillResult
        ``std`` (n_frames, n_markers): per-coordinate RMS uncertainty of each filled sample (cross-validated, grown
        with the frame's leverage, shrunk next to observations, divided by the trust given to the PCA there; NaN
        where the fallback filled the sample; the bone refinement does not change it).
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
    core = partial(_fill_auto_stack, units=units, labels=labels, rate=rate, bones=bones, knn=knn, refine=refine,
                   reference_frames=reference_frames, reference_weights=reference_weights)
    with single_blas_thread():  # thousands of small decompositions: BLAS threads only add contention
        if positions.shape[0] > DEFAULT_WINDOW:  # long takes: overlapping windows, time linear in frames
            return fill_in_windows(positions, core, jobs=jobs)
        return core(positions)


def _fill_auto_stack(positions: np.ndarray, *, units: str, labels, rate, bones, knn: int, refine: bool,
               reference_frames: np.ndarray | None = None, reference_weights: np.ndarray | None = None
               ) -> FillResult:
    """The body of :func:`fill_auto_stack` (positions (n_frames, n_markers, 3), already validated)."""
    mm = length_factor("mm", units)  # data units per millimetre
    missing = np.isnan(positions).any(axis=2)
    pca, pca_std, local_info = reconstruct_local(positions, scales=tuple(DEFAULT_SCALES_MM * mm),
                                                 align_scale=DEFAULT_ALIGN_MM * mm, knn=knn,
                                                 reference_frames=reference_frames,
                                                 reference_weights=reference_weights)
    spline_max = int(round(SPLINE_SECONDS * rate)) if rate else SPLINE_FRAMES
    info: dict[str, Any] = {"pipeline": "local-frame weighted PCA + bone refinement, checked against a "
                                        "smooth fallback",
                            "fallback": local_info["fallback"], "spline_max_frames": spline_max}
    if "references" in local_info:
        info["references"] = local_info["references"]
    use_bones = refine and bones is not False  # False: no bone refinement
    boneset = resolve_bones(positions, bones, units=units, labels=labels) if use_bones else None
    if boneset is not None and len(boneset):
        # samples without a PCA estimate (NaN std) stay fixed here; the blend below decides what they become
        pca, binfo = refine_bones(pca, positions, pca_std * BONE_TRUST, boneset.pairs, boneset.lengths,
                                  boneset.spread, spread_floor=SPREAD_FLOOR_MM * mm)
        info["bone_refinement"] = binfo
    info["bones"] = 0 if boneset is None else int(len(boneset))
    speed = observed_speed(positions, missing, floor=MIN_SPEED_MM * mm)
    limit = step_reference(positions, missing, speed)
    refs = local_info.get("references", {})
    with_refs = refs.get("used", 0) >= REFERENCE_MODELS * max(refs.get("models", 0), 1)
    trust, why = pca_trust(positions, pca, pca_std, limit, mm, REFERENCE_STD_SCALE if with_refs else 1.0)
    gap = missing & ~missing.all(axis=0)
    if with_refs:  # the local model learnt the body from the references: a guide from the gappy capture only hurts
        guide, guide_std, guide_name = None, None, "none"
    else:
        guide, guide_std, guide_name = dynamics_guide(positions, trust, gap, spline_max, boneset=boneset,
                                                      units=units, labels=labels)
    info["fallback_guide"] = guide_name
    for attempt in range(JUMP_PASSES):
        fallback, splined = fallback_path(positions, pca, trust >= 1.0, spline_max, guide)
        alpha = limit_trust_changes(trust, np.linalg.norm(np.nan_to_num(pca - fallback), axis=2),
                                    BLEND_STEP * speed, gap)
        estimate, std = blend(positions, pca, pca_std, fallback, alpha)
        # last guard: a filled step beyond the bound drops the PCA's trust within 2^attempt frames of it (a step
        # inside the fallback means the trusted estimates it bridges disagree with each other or with the
        # observations: distrust a wider stretch each pass, so the fallback bridges from farther away)
        jump = jumps(estimate, gap, limit * STEP_BOUND)
        if not jump.any():
            break
        jump = _dilate(jump, 2 ** attempt) & gap & (trust > 0)
        if not jump.any():
            break
        trust[jump] = 0.0
        why["jump"] |= jump
    mixed = np.zeros_like(gap)
    if guide_name == "bolero-sc":
        # short stretches without a PCA estimate (whole-body blackouts of <= 0.5 s) keep their spline, as measured;
        # a splined run between doubtful PCA estimates does not (85_02, 30 % missing: a toe 771 mm off)
        spline_only = splined & (alpha == 0) & (local_info["anchors"] == 0)
        estimate, std, mixed = mix_by_uncertainty(positions, estimate, std, guide,
                                                  np.where(spline_only, np.nan, guide_std))
    calm = np.zeros_like(gap)
    if guide is not None:
        estimate, std, calm = guide_where_implausible(positions, estimate, std, gap, speed, limit, guide)
    alpha[calm] = 0.0
    why["implausible"], why["mixed"] = calm, mixed
    # the final bounds: within 1.1x the body's observed extent, no step beyond 1.5x the larger of the marker's largest
    # observed step and the body's largest then (the hidden truth of every dense trial keeps this; it broke a bound of
    # 1.5x the marker's own largest by up to 4.4x on 85_02's flips, and holding that cost 11.8 -> 73 mm RMSE at 5 %)
    before = estimate
    estimate, moved, forced = project_plausible(estimate, positions, limit)
    # the model put the sample elsewhere: its uncertainty grows by the distance the bounds moved it
    shift = np.linalg.norm(np.nan_to_num(estimate - before), axis=2)
    std = np.where(moved, np.sqrt(std ** 2 + shift ** 2 / 3.0), std)
    why["bounded"], why["forced"] = moved, forced
    splined &= (alpha == 0) & ~calm
    info["gap_methods"] = _gap_methods(missing, std, local_info, boneset, labels, units, splined, spline_max,
                                       alpha, why, guided=guide_name)
    return finish(positions, estimate, std=std, info=info)


def guide_where_implausible(positions: np.ndarray, estimate: np.ndarray, std: np.ndarray, gap: np.ndarray,
                            speed: np.ndarray, limit: np.ndarray, guide: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Replace every gap run that holds an implausible sample by the dynamics guide, where the guide is plausible.

    positions / estimate / guide (n_frames, n_markers, 3); std / gap (n_frames, n_markers); speed (n_markers,) the
    largest observed steps; limit (n_frames - 1, n_markers) the step reference (:func:`step_reference`).  A run is
    implausible when a sample leaves 1.1x the body's observed extent or steps beyond ``STEP_BOUND`` times the
    reference.  The guide (it learnt from every frame and, as BoLeRO-SC, keeps the bones) is shifted linearly to meet
    the observations at the run's ends; its uncertainty grows like a Brownian bridge whose step is the marker's
    largest observed one.  Runs where the guide breaks the bounds too are left to :func:`.plausibility.
    project_plausible`.  (A straight line through the ends was the calm choice here before; with the guide and the
    projection the dense protocol's pooled RMSE fell from 38.5 to 32.5 mm at 30 % missing, 26.1 to 20.4 at 20 %.)
    Returns estimate, std and the (n_frames, n_markers) mask of replaced samples.
    """
    from ..gaps import runs
    from ..engines.weighted_pca import linear_fallback

    bad = implausible(estimate, positions, limit, factor=STEP_BOUND)
    replaced = np.zeros_like(gap)
    if not bad.any():
        return estimate, std, replaced
    missing = np.isnan(positions).any(axis=2)
    todo = [(m, start, length) for m in np.flatnonzero(bad.any(axis=0)) for start, length in runs(gap[:, m])
            if bad[start:start + length, m].any()]
    candidate = estimate.copy()
    shifted = {}
    for m, start, length in todo:
        if m not in shifted:
            shifted[m] = guide[:, m] + linear_fallback(positions[:, m] - guide[:, m], missing[:, m])
        candidate[start:start + length, m] = shifted[m][start:start + length]
    still = implausible(candidate, positions, limit, factor=STEP_BOUND)
    estimate, std = estimate.copy(), std.copy()
    for m, start, length in todo:
        sl = slice(start, start + length)
        if still[sl, m].any():
            continue
        estimate[sl, m] = candidate[sl, m]
        d = np.arange(1, length + 1, dtype=float)
        std[sl, m] = speed[m] * np.sqrt(d * (length + 1 - d) / (length + 1)) / np.sqrt(3.0)
        replaced[sl, m] = True
    return estimate, std, replaced


def mix_by_uncertainty(positions: np.ndarray, estimate: np.ndarray, std: np.ndarray, other: np.ndarray,
                       other_std: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every filled sample as the inverse-variance average of this pipeline's estimate and another method's.

    positions / estimate / other (n_frames, n_markers, 3); std / other_std (n_frames, n_markers) per-coordinate
    uncertainties (NaN: none).  Weight w = (1/std^2) / (1/std^2 + 1/other_std^2); a sample without an uncertainty
    of its own (the fallback's) takes the other's (w = 0), and one the other cannot fill keeps its own.  The
    combined uncertainty is (1/std^2 + 1/other_std^2)^-1/2.  Returns estimate, std and the mask of mixed samples.
    """
    missing = np.isnan(positions).any(axis=2)
    theirs = missing & np.isfinite(other).all(axis=2) & np.isfinite(other_std) & (other_std > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        mine = np.where(np.isfinite(std) & (std > 0), 1.0 / std ** 2, 0.0)
        their = np.where(theirs, 1.0 / other_std ** 2, 0.0)
        w = np.where(theirs, mine / (mine + their), 1.0)
        combined = np.where(theirs, 1.0 / np.sqrt(mine + their), std)
    out = np.where(theirs[..., None], w[..., None] * np.nan_to_num(estimate) + (1 - w[..., None]) * other, estimate)
    return out, np.where(missing, combined, std), theirs


def step_reference(positions: np.ndarray, missing: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """The step each filled sample is judged against: (n_frames - 1, n_markers), data units per frame.

    The larger of the marker's largest observed step (``speed`` (n_markers,)) and the largest step any marker
    observed in both frames makes there: a marker hidden during the fastest movement (a hand in a flip) may move
    faster than it was ever seen to, but not much faster than the rest of the body does at that moment.
    positions (n_frames, n_markers, 3), missing (n_frames, n_markers).
    """
    both = ~missing[1:] & ~missing[:-1]
    step = np.where(both, np.linalg.norm(np.nan_to_num(np.diff(positions, axis=0)), axis=2), 0.0)
    body = step.max(axis=1) if step.shape[1] else np.zeros(len(step))
    return np.maximum(speed[None, :], body[:, None])


def dynamics_guide(positions: np.ndarray, trust: np.ndarray, gap: np.ndarray, longest: int, *, boneset=None,
                   units: str = "mm", labels=None) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """The dynamics guide: (fill (n_frames, n_markers, 3), its std (n_frames, n_markers) or None, name), or
    (None, None, "none") when no untrusted stretch is longer than ``longest`` and the capture is not gappy
    everywhere (:data:`GUIDE_COMPLETE`, :data:`GUIDE_MISSING`).

    BoLeRO-SC with ``boneset`` (a :class:`~mocapfill.bones.boneset.BoneSet`) when it holds bones, else DynaMMo.
    positions (n_frames, n_markers, 3); trust / gap (n_frames, n_markers).  When many markers are missing at once
    (20-30 % of the samples in 0.25-2 s gaps) some markers lose every near neighbour and the local PCA doubts
    itself over whole seconds; a straight line there missed a tennis player's hand by up to a metre.  The linear
    dynamical system learns from every frame, complete or not, and follows the motion through such stretches.
    """
    from ..gaps import runs
    from .dynammo import run_dynammo

    complete = float((~gap.any(axis=1)).mean()) if len(gap) else 1.0  # frames where every seen marker is observed
    seen = gap.shape[0] * int((~np.isnan(positions).any(axis=2)).any(axis=0).sum())  # samples of seen markers
    untrusted = gap & (trust < 1.0)
    gappy = complete < GUIDE_COMPLETE and gap.sum() > GUIDE_MISSING * seen and len(gap) > GUIDE_MIN_SPLINES * longest
    if not gappy and \
            not any(length > longest for m in np.flatnonzero(untrusted.any(axis=0))
                    for _, length in runs(untrusted[:, m])):
        return None, None, "none"
    with warnings.catch_warnings():  # a guide needs no convergence to the last digit; say nothing
        warnings.simplefilter("ignore", ConvergenceWarning)
        if boneset is not None and len(boneset):
            from .bolero import fill_bolero_sc
            # The inverse-variance mix below was measured with the model's own std ("model"), not the
            # second-opinion one a user of bolero-sc gets.
            res = fill_bolero_sc(positions, bones=boneset, units=units, labels=labels, seed=0, uncertainty="model")
            return res.positions, res.std, "bolero-sc"
        return run_dynammo(positions, seed=0, uncertainty=False).positions, None, "dynammo"


def fallback_path(positions: np.ndarray, pca: np.ndarray, trusted: np.ndarray, longest: int,
                  guide: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The bounded, smooth fill every untrusted PCA sample is blended towards.

    It passes through the observations and the fully trusted PCA samples (``trusted`` (n_frames, n_markers) bool,
    estimates in ``pca`` (n_frames, n_markers, 3)) and bridges each run of other missing samples: a cubic spline
    when the run is interior and at most ``longest`` frames, linear interpolation otherwise, the nearest value held
    beyond the clip's edges.  positions (n_frames, n_markers, 3), NaN = missing.  Returns the path (n_frames,
    n_markers, 3) (NaN for never-observed markers) and the (n_frames, n_markers) mask of splined samples.
    """
    from ..gaps import runs
    from .interp import fill_spline
    from ..engines.weighted_pca import linear_fallback

    missing = np.isnan(positions).any(axis=2)
    known = ~missing | (trusted & missing & np.isfinite(pca).all(axis=2))
    series = np.where(known[..., None], np.where(missing[..., None], pca, positions), np.nan)
    out = series.copy()
    splined = np.zeros_like(missing)
    n_frames = positions.shape[0]
    todo = np.flatnonzero((~known).any(axis=0) & known.any(axis=0))
    for m in todo:
        if guide is None:
            out[:, m] = linear_fallback(series[:, m], ~known[:, m])
        else:  # interior runs: the guide, shifted linearly to meet the known samples at the run's ends
            out[:, m] = linear_fallback(series[:, m], ~known[:, m])
            shifted = guide[:, m] + linear_fallback(series[:, m] - guide[:, m], ~known[:, m])
            seen = np.flatnonzero(known[:, m])
            out[seen[0]:seen[-1], m] = shifted[seen[0]:seen[-1]]
        for start, length in runs(~known[:, m]):
            if length <= longest and start > 0 and start + length < n_frames:
                splined[start:start + length, m] = True
    if splined.any():
        spline = fill_spline(series[:, todo]).positions
        sub = splined[:, todo]
        part = out[:, todo]
        part[sub] = spline[sub]
        out[:, todo] = part
    return out, splined


def pca_trust(positions: np.ndarray, pca: np.ndarray, std: np.ndarray, limit: np.ndarray,
              mm: float, std_scale: float = 1.0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Per-sample trust in the local PCA estimate, in [0, 1], and the reasons it is lowered.

    positions / pca (n_frames, n_markers, 3); std (n_frames, n_markers) the PCA's uncertainty (NaN where it made
    no estimate); limit
    (n_frames - 1, n_markers) the reference step (:func:`step_reference`); mm data units per millimetre.  Trust
    falls linearly from 1 to 0 as the uncertainty grows from ``TRUST_STD_MM`` to ``DISTRUST_STD_MM`` and as the
    estimate's step to the next or previous frame grows from ``FAST`` to ``STEP_BOUND`` times the reference step.
    Returns trust (n_frames, n_markers) (1 on observed samples, 0 where there is no estimate) and masks
    ``uncertain``, ``fast`` and ``jump`` (filled by the caller's final check).  ``std_scale`` multiplies both
    uncertainty bounds (:data:`REFERENCE_STD_SCALE` where reference takes trained the PCA).
    """
    missing = np.isnan(positions).any(axis=2)
    est = missing & np.isfinite(std)
    trust = np.where(missing, 0.0, 1.0)
    lo, hi = TRUST_STD_MM * mm * std_scale, DISTRUST_STD_MM * mm * std_scale
    by_std = np.clip((hi - np.nan_to_num(std, nan=np.inf)) / (hi - lo), 0.0, 1.0)
    # the PCA path: observations where observed, the estimate where it exists
    path = np.where(est[..., None], pca, positions)
    step = np.linalg.norm(np.diff(path, axis=0), axis=2)  # (n_frames - 1, n_markers), NaN next to holes
    step = np.nan_to_num(step, nan=0.0) / limit
    ratio = np.zeros_like(trust)
    ratio[1:] = step
    ratio[:-1] = np.maximum(ratio[:-1], step)
    by_speed = np.clip((STEP_BOUND - ratio) / (STEP_BOUND - FAST), 0.0, 1.0)
    trust[est] = np.minimum(by_std, by_speed)[est]
    why = {"uncertain": est & (by_std < 1), "fast": est & (by_speed < 1),
           "jump": np.zeros_like(est)}
    return trust, why


def limit_trust_changes(trust: np.ndarray, gap_size: np.ndarray, max_step: np.ndarray, gap: np.ndarray
                        ) -> np.ndarray:
    """Lower trust (never raise it) so that blending moves the fill by at most ``max_step`` per frame.

    trust (n_frames, n_markers) in [0, 1]; gap_size (n_frames, n_markers) distance between the PCA estimate and the
    fallback; max_step (n_markers,); gap (n_frames, n_markers) the samples being filled (trust is left alone on the
    others).  The blend's step gains |change of trust| x gap_size, so trust may change by at most
    max_step / gap_size per frame: a forward and a backward pass of a = min(a, neighbour + allowed) give the largest
    such trust below the given one (a ramp instead of a switch).
    """
    alpha = np.where(gap, trust, 1.0)
    allowed = max_step[None, :] / np.maximum(gap_size, 1e-12)
    for t in range(1, len(alpha)):
        np.minimum(alpha[t], alpha[t - 1] + allowed[t], out=alpha[t])
    for t in range(len(alpha) - 2, -1, -1):
        np.minimum(alpha[t], alpha[t + 1] + allowed[t], out=alpha[t])
    return np.where(gap, alpha, 0.0)


def blend(positions: np.ndarray, pca: np.ndarray, pca_std: np.ndarray, fallback: np.ndarray, alpha: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    """alpha x PCA + (1 - alpha) x fallback on the filled samples, with the uncertainty it carries.

    positions / pca / fallback (n_frames, n_markers, 3); pca_std / alpha (n_frames, n_markers).  The uncertainty
    is the PCA's divided by alpha (a less trusted estimate weighs less against the bones) and NaN where alpha is
    below ``MIN_ALPHA`` (such samples are the fallback's: no uncertainty, not moved by the bone refinement).
    """
    missing = np.isnan(positions).any(axis=2)
    a = alpha[..., None]
    mixed = np.where(a > 0, a * np.nan_to_num(pca) + (1 - a) * fallback, fallback)
    estimate = np.where(missing[..., None], mixed, positions)
    std = np.where(missing, np.nan, 0.0)
    ok = missing & (alpha >= MIN_ALPHA)
    std[ok] = pca_std[ok] / alpha[ok]
    return estimate, std


def _dilate(mask: np.ndarray, width: int) -> np.ndarray:
    """mask (n_frames, n_markers) grown by ``width`` frames each way along the frames."""
    out = mask.copy()
    for d in range(1, width + 1):
        out[d:] |= mask[:-d]
        out[:-d] |= mask[d:]
    return out


def jumps(estimate: np.ndarray, gap: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """Filled samples (n_frames, n_markers) at either end of a frame-to-frame step longer than ``bound``
    (n_frames - 1, n_markers).

    estimate (n_frames, n_markers, 3); gap (n_frames, n_markers) the filled samples.
    """
    step = np.nan_to_num(np.linalg.norm(np.diff(estimate, axis=0), axis=2), nan=0.0)
    big = step > bound
    out = np.zeros_like(gap)
    out[1:] |= big
    out[:-1] |= big
    return out & gap


def _gap_methods(missing: np.ndarray, std: np.ndarray, local_info: dict, boneset, labels, units: str,
                 splined: np.ndarray, spline_max: int, alpha: np.ndarray, why: dict, guided: str = "none"
                 ) -> list[dict]:
    """One record per gap: which method filled it and why (JSON-ready).

    missing / std / splined / alpha (n_frames, n_markers): the final uncertainty, splined fallback samples and the
    trust given to the PCA; ``why``: masks from :func:`pca_trust` (plus ``jump``).
    """
    cv = {}
    for g in local_info["groups"]:
        cv.setdefault(g["marker"], []).append(g)
    bone_count = np.zeros(missing.shape[1], dtype=int)
    if boneset is not None and len(boneset):
        bone_count = np.bincount(boneset.pairs.ravel(), minlength=missing.shape[1])
    no_pca = local_info["anchors"] == 0
    out = []
    for gap in find_gaps(missing):
        m = gap.marker
        sl = slice(gap.start, gap.stop)
        name = labels[m] if labels is not None else m
        rec = {"marker": name, "marker_index": int(m), "start": int(gap.start), "length": int(gap.length)}
        trusted = alpha[sl, m]
        if missing[:, m].all():
            rec.update(method="none", reason="marker missing in every frame: nothing to learn from")
            out.append(rec)
            continue
        if why["implausible"][sl, m].any():
            rec.update(method=guided, reason=f"plausibility guard: the fill left the body's observed extent or "
                                             f"stepped beyond {STEP_BOUND:g}x the largest observed (its own or the "
                                             f"body's then); {GUIDE_NAMES[guided]}'s fill instead, shifted to meet "
                                             f"the observations, its uncertainty growing towards the middle")
            out.append(rec)
            continue
        if no_pca[sl, m].all():
            why_not = "fewer than 3 observed neighbours or 10 training frames for PCA"
            if splined[sl, m].all():
                rec.update(method="spline", reason=f"{why_not}; short (<= {spline_max} frames): cubic spline")
            elif guided != "none":
                rec.update(method=guided, reason=f"{why_not}; {GUIDE_NAMES[guided]}'s fill, which learns from every "
                                                 f"frame, complete or not")
            else:
                rec.update(method="linear", reason=f"{why_not}; too long for a spline or at the clip's edge: "
                                                   f"linear interpolation, edges held")
            out.append(rec)
            continue
        groups = cv.get(m, [])
        rms = [r for g in groups for r in g["cv_rms"] if np.isfinite(r)]
        reason = "local-frame weighted PCA: the marker's observed neighbours predict it"
        if rms:
            reason += f" (cross-validated error {min(rms):.3g} {units})"
        method = "local-pca"
        if bone_count[m] and np.isfinite(std[sl, m]).any():
            method = "local-pca+bones"
            reason += f"; refined with {int(bone_count[m])} bone(s) to keep its segment rigid"
        if (trusted < 1).any() and not no_pca[sl, m].all():
            method += "+fallback"
            parts = []
            if no_pca[sl, m].any():
                parts.append(f"{int(no_pca[sl, m].sum())} frame(s) without 3 observed neighbours or 10 training "
                             f"frames")
            labels_why = {"uncertain": f"uncertainty above {TRUST_STD_MM:g} mm",
                          "fast": f"steps above {FAST:g}x the largest observed (its own or the body's then)",
                          "jump": f"a filled step above {STEP_BOUND:g}x the largest observed (its own or the "
                                  f"body's then) or beyond the body's extent / 1.5x its own largest observed step"}
            for key, text in labels_why.items():
                count = int(why[key][sl, m].sum())
                if count:
                    parts.append(f"{count} frame(s) with {text}")
            kind = ("spline" if splined[sl, m].any() else
                    f"{GUIDE_NAMES[guided]}'s fill, shifted to meet the trusted samples" if guided != "none" else
                    "linear interpolation / hold")
            reason += (f"; PCA not trusted in {int((trusted < 1).sum())} of {gap.length} frames ("
                       + ", ".join(parts) + f"): blended smoothly into the {kind} there")
        rec.update(method=method, reason=reason)
        out.append(rec)
    for gap, rec in zip(find_gaps(missing), out):
        sl, m = slice(gap.start, gap.stop), gap.marker
        if rec["method"] == "none":
            continue
        if why["mixed"][sl, m].any() and not rec["method"].startswith(guided):
            rec["method"] += f"+{guided}"
            rec["reason"] += (f"; averaged with {GUIDE_NAMES[guided]}'s fill, each weighted by the inverse of its "
                              f"uncertainty (the capture is too gappy for the local model alone)")
        if why["forced"][sl, m].any():
            rec["method"] += "+bounded"
            rec["reason"] += ("; the observations at the gap's ends are farther apart than 1.5x the largest observed "
                              "step allows (or the body's extent cannot hold with it): the straight line through "
                              "them, the calmest path there is")
        elif why["bounded"][sl, m].any():
            rec["method"] += "+bounded"
            rec["reason"] += (f"; {int(why['bounded'][sl, m].sum())} frame(s) moved to the nearest path within 1.1x "
                              f"the body's observed extent and 1.5x the largest observed step (the marker's own or "
                              f"the body's then), its uncertainty grown by the distance moved")
    return out
