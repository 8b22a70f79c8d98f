"""``auto``, the default fill: one model, a spatial prediction and a motion prior, joined by one smoother.

The model (equations in ``ARCHITECTURE.md``, "The default's model"), each stage a pure function with its own test:

1. :func:`spatial_stage`: every missing sample gets a prediction and its standard deviation from the local,
   rotation-aligned, distance-weighted PCA (:func:`mocapfill.engines.local_pca.reconstruct_local`), which learns
   from incomplete frames (each model conditions on the markers observed where it predicts).  The same model's
   reconstruction at the observed frames next to each gap is kept: the smoother learns the prediction's error there.
   Frames of other takes of the same marker set (``reference_frames``) join the training frames, each weighted by
   how well its take fits the capture (``reference_weights``, :mod:`mocapfill.references`); each local model keeps
   them only where they lower its cross-validated error on the capture's own frames; their gaps are completed first
   (:func:`mocapfill.references.completed_frames`, :attr:`ModelConfig.reference_pca_mm`), as predictors only, so a
   frame lacking a marker still trains the models that predict from it.  With a learned denoiser
   (``model``), :func:`prior_stage` fuses its estimate with the spatial prediction as a second measurement.
   :func:`body_stage`: a missing sample the local PCA could not predict (its neighbourhood vanished with it)
   rides rigidly on its nearest markers seen at that frame, its scatter relative to them as the standard deviation
   (:func:`mocapfill.engines.local_pca.rigid_prediction`).
   :func:`global_stage`: a missing sample still without a prediction (a marker seen in too few frames to train a
   local model) takes the global distance-weighted PCA's (:func:`global_prediction`, the ``pca`` method; only where
   it stays inside the body) with sd :attr:`ModelConfig.global_sd_mm`, so it moves with the body rather than being
   bridged by the motion alone.
   :func:`anchor_stage`: a missing sample still without a prediction takes the body anchor's
   (:func:`mocapfill.engines.body_anchor.body_anchor`: the markers seen with it, by their mean offsets, no
   rotation) as a weak white measurement, so a gap at a take's end comes to rest inside the body instead of
   flying off on its last velocity.
2. :func:`bone_stage` (optional): each frame's predictions move to the most probable positions given their
   standard deviations and the bone lengths' spread (:func:`mocapfill.bones.refinement.refine_bones`); a bone the
   predictions say broke at a frame (a hand let go of what it held) is left out there (:func:`bone_breaks`).
3. :func:`temporal_stage`: per marker, a damped white-jerk state-space model with the spatial prediction's
   correlated error in its state (:mod:`mocapfill.engines.motion_smoother`); the observations and the spatial
   predictions are its measurements; one Rauch-Tung-Striebel smoother gives the fill (posterior mean) and its
   standard deviation (posterior sd).  The jerk density is learnt from the capture's observed third differences,
   scaled at each frame by how fast the body moves then.  The correlated error is one model's: it is drawn anew where
   a marker's predictions pass to another kind of model (:attr:`ModelConfig.bias_per_model`).  Samples of observed
   fragments of 1-2 frames between gaps count as noisy measurements (the output keeps them), and so does an
   observed run between two gaps that lies farther off the spatial model than its sd explains
   (:func:`displaced_runs`: a swapped or ghost marker outlier rejection cannot see; it is reported).  Where the
   spatial model has nothing, the dynamics bridge the gap and the standard deviation grows.  (Optionally,
   ``reweight_passes``: predictions far off the smoothed path are down-weighted and the smoother runs again; off by
   default, as measured.)
4. :func:`impute_stage` (EM-style): the spatial model is fitted again on the take completed by step 3 (every frame
   where the marker is observed is a training frame, its neighbours taken from the completed take, their posterior
   variance propagated into the prediction's; a neighbour filled with an sd above ``impute_trust_mm`` during the
   marker's gaps is no predictor), and step 3 runs again on its predictions.  (The first pass then only
   seeds it: one weight width, no nearest-pose correction.)  Where the refit has no model for a marker (fewer than
   3 trusted neighbours: on captures with gaps everywhere, most markers), the first pass's prediction stands
   where it is sure and fits the frames beside the gap (:attr:`ModelConfig.seed_where_no_refit`,
   :func:`seed_elsewhere`); elsewhere the motion model and the global PCA bridge the gap, or, with
   :attr:`ModelConfig.refit_untrusted` (off, as measured), a
   model on every near marker predicts it (its predictions' roughness measured as white error,
   :func:`rough_variance`).

5. :func:`reported_sd`: where a prediction's neighbours take a pose its model never learnt (their residual off the
   model's components beyond the held-out frames'), its variance grows by that factor for the reported posterior
   sd (the smoother's variances, computed again); the fill itself keeps the cross-validated sd.
6. :func:`~mocapfill.methods.auto_records.gap_records`: one record per gap, what filled it and whether a person
   should review it (its largest posterior standard deviation above :attr:`ModelConfig.review_sd_mm`), the reason
   text formatted from the config.
"""

from __future__ import annotations

from functools import cache, partial
from typing import Any, Callable, Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..engines.local_pca import reconstruct_local
from ..engines.motion_smoother import MotionModel, acceleration_memory, jerk_density, jerk_gain, smooth
from ..errors import MethodError
from ..gaps import fragments, runs
from ..guards.copies import bones_on_distinct, distinct_markers, lent_by_copies, widened, with_lent
from ..guards.windows import DEFAULT_WINDOW, fill_in_windows
from ..references import completed_frames
from ..runtime.blas import single_blas_thread
from ..runtime.executor import forked_map, resolve_jobs
from ..units import length_factor
from .auto_config import DEFAULT_CONFIG, ModelConfig
from .auto_records import displaced_records, gap_records, restate_record
from .base import FillResult, check_positions, finish, review_indices


def fill_auto(
    positions: np.ndarray,
    *,
    seed: int | None = None,
    units: str = "mm",
    labels: Sequence[str] | None = None,
    rate: float | None = None,
    bones: Any = None,
    refine: bool = True,
    reference_frames: np.ndarray | None = None,
    reference_weights: np.ndarray | None = None,
    model: Any = None,
    config: ModelConfig = DEFAULT_CONFIG,
    jobs: int | None = None,
) -> FillResult:
    """Fill gaps with the default's model (see the module docstring).

    Parameters
    ----------
    positions : ndarray (n_frames, n_markers, 3), NaN = missing
    seed : ignored (deterministic); accepted for a uniform signature.
    units : "mm", "cm" or "m"; converts every length of ``config``.
    labels : marker labels (n_markers,), for ``info["gap_methods"]``.
    rate : frame rate (Hz); converts the config's times (``config.default_rate`` without it).
    bones : BoneSet, None (estimate from the observed frames) or False (no bone stage).
    refine : run the bone stage (same as ``bones=False`` when False).
    reference_frames : ndarray (n, n_markers, 3) or None: frames of other takes of the same marker set, added to
        the spatial model's training frames (NaN allowed: with weights, completed as predictors, never targets).
    reference_weights : ndarray (n,) in [0, 1] or None: each reference frame's weight as a training row (how well
        its take fits the capture, :func:`mocapfill.references.weigh`); each local model then keeps the references
        only where they lower its cross-validated error on the capture's own frames (``info["references"]``:
        frames, models, how many kept them).  None: every reference frame counts as the capture's own.
    model : a learned denoiser (:class:`~mocapfill.engines.denoiser.DenoiserModel` or a path, ``mocapfill train``)
        or None: its estimate is a second spatial measurement (:func:`prior_stage`).
    config : ModelConfig
    jobs : worker processes (None: 1, this one; 0: every core; the output does not depend on it): the windows of a
        take longer than :data:`~mocapfill.guards.windows.DEFAULT_WINDOW` frames run on them, and on a shorter take
        the local models of stages 1 and 4 (one marker's at a time) and the bone stage's problems
        (:func:`~mocapfill.runtime.executor.forked_map`: forked, so only on Linux).

    Markers that are exact copies of another (:mod:`mocapfill.guards.copies`) are filled once and copied back
    (``info["copies"]`` lists them).

    Returns
    -------
    FillResult with ``std`` the posterior standard deviation per coordinate, ``info["gap_methods"]`` one record per
    gap (``marker``, ``marker_index``, ``start``, ``length``, ``method``, ``reason``, ``review``, ``max_std``).
    """
    del seed
    positions = check_positions(positions)
    if labels is not None and len(labels) != positions.shape[1]:
        raise MethodError(f"{len(labels)} labels for {positions.shape[1]} markers")
    if reference_frames is not None:
        reference_frames = np.asarray(reference_frames, dtype=np.float64)
        if reference_frames.ndim != 3 or reference_frames.shape[1:] != positions.shape[1:]:
            raise MethodError(f"reference_frames must have shape (n, {positions.shape[1]}, 3), got "
                              f"{reference_frames.shape}")
        if reference_weights is not None:
            reference_weights = np.asarray(reference_weights, dtype=np.float64)
            if reference_weights.shape != (len(reference_frames),):
                raise MethodError(f"reference_weights must have shape ({len(reference_frames)},), got "
                                  f"{reference_weights.shape}")
    if model is not None:
        from .learned import resolve_model

        model = resolve_model(model)
    # exact copies of a marker: filled once (guards/copies.py); copies whose gaps differ take their twins' samples
    # first, after which they are bit-identical, gaps included (so lent samples always come with copies)
    lending, lent, lenders = lent_by_copies(positions)
    keep, source = distinct_markers(lending)
    if len(keep) < positions.shape[1]:
        sub = None if labels is None else [labels[m] for m in keep]
        if bones is not None and bones is not False:
            bones = bones_on_distinct(bones, source)
        part = fill_auto(lending[:, keep], units=units, labels=sub, rate=rate, bones=bones, refine=refine,
                         reference_frames=None if reference_frames is None else reference_frames[:, keep],
                         reference_weights=reference_weights, model=model, config=config, jobs=jobs)
        result = widened(lending, part, keep, source, labels)
        return with_lent(result, positions, lent, lenders, labels) if lent.any() else result
    core = partial(model_fill, units=units, labels=labels, rate=rate, bones=bones, refine=refine,
                   reference_frames=reference_frames, reference_weights=reference_weights, prior=model,
                   config=config)
    jobs = resolve_jobs(jobs)
    with single_blas_thread():
        if positions.shape[0] > DEFAULT_WINDOW:  # long takes: overlapping windows, time linear in frames
            # (each window's models in its own worker; a gap's record restated for the sd the blend gave it)
            result = fill_in_windows(positions, core, jobs=jobs,
                                     restate=partial(restate_record, config=config, mm=length_factor("mm", units)),
                                     keywords=partial(lost_marker_frames, positions, np.isnan(positions).any(axis=2),
                                                      reference_frames, reference_weights))
            result.info["review"] = review_indices(result.info.get("gap_methods"))
            if reference_weights is not None:
                windows_references(result.info, int((np.asarray(reference_weights) > 0).sum()))
            return result
        return core(positions, jobs=jobs)


def windows_references(info: dict, frames: int) -> None:
    """A long take's ``info["references"]`` (its windows', :func:`~mocapfill.guards.windows.fill_in_windows`, each
    under ``info["windows"]`` where they differ, once where they agree): ``frames`` (the caller's reference frames
    with a weight), and the local models and those that kept the references summed over the windows.  In place."""
    rows = info.get("windows") or []
    per = [row.pop("references") for row in rows if isinstance(row.get("references"), dict)]
    if not per and isinstance(info.get("references"), dict):
        per = [info["references"]] * len(rows)  # every window said the same
    if per:
        info["references"] = {"frames": frames, "models": sum(int(p.get("models", 0)) for p in per),
                              "used": sum(int(p.get("used", 0)) for p in per)}
        completed = max(int(p.get("completed", 0)) for p in per)  # (each window completes the same references)
        if completed:
            info["references"]["completed"] = completed


def model_fill(positions: np.ndarray, *, units: str, labels, rate, bones, refine: bool,
               reference_frames: np.ndarray | None, config: ModelConfig,
               reference_weights: np.ndarray | None = None, prior: Any = None, jobs: int = 1) -> FillResult:
    """The model on one (already validated) array: stages 1-6 of the module docstring (``prior``: a learned
    denoiser whose estimate :func:`prior_stage` fuses with every spatial prediction; ``jobs``: processes the
    local models of stages 1 and 4 and the bone stage's problems run on, the output the same)."""
    mm = length_factor("mm", units)
    rate = float(rate) if rate and np.isfinite(rate) and rate > 0 else config.default_rate
    missing = np.isnan(positions).any(axis=2)
    observed_refs = reference_frames  # (the records count the frames that show each marker)
    reference_known = None  # where the reference frames observe each marker, once they are completed
    if (reference_frames is not None and reference_weights is not None and config.reference_pca_mm
            and np.isnan(reference_frames).any()):
        reference_known = ~np.isnan(reference_frames).any(axis=2)
        reference_frames = completed_frames(positions, reference_frames, config.reference_pca_mm * mm)
    pred, pred_sd, edge, edge_sd, sinfo = spatial_stage(positions, config, mm, reference_frames=reference_frames,
                                                        reference_weights=reference_weights,
                                                        reference_known=reference_known, jobs=jobs)
    off = sinfo.get("extrapolation")  # how far each prediction's pose lies off its model's training poses
    seed = (pred, pred_sd, edge, edge_sd)  # stage 1's own: where a refit has no model, they stand
    info: dict[str, Any] = {"pipeline": "local weighted PCA + white-jerk smoother", "fallback": sinfo["fallback"]}
    used_refs: list | None = [] if reference_frames is not None and reference_weights is not None else None
    report_sd = reported_sd(pred_sd, off)
    prior_est = None
    if prior is not None:
        prior_est = prior_estimate(positions, prior, labels=labels, units=units, rate=rate, config=config)
        pred, pred_sd, edge, edge_sd, report_sd = joined(positions, pred, pred_sd, edge, edge_sd, report_sd,
                                                         prior_est, None, config, mm)
        info["prior"] = {"markers": int(np.isfinite(prior_est[1]).sum()),
                         "median_sd": float(np.nanmedian(prior_est[1])) if np.isfinite(prior_est[1]).any()
                         else None}
    # the global PCA, where the local models left samples without a prediction, and the bones' set-up
    tasks = [task for task, needed in (("global", config.global_sd_mm and (missing & ~np.isfinite(pred_sd)).any()),
                                       ("bones", refine and bones is not False)) if needed]
    done = take_stage(positions, bones, config, mm, tasks, units=units, labels=labels, jobs=jobs)
    glob, globbed = done.get("global"), np.zeros(missing.shape, dtype=bool)  # the global PCA, and where it predicted
    if glob is not None:
        pred, pred_sd, edge, edge_sd, report_sd = joined(positions, pred, pred_sd, edge, edge_sd, report_sd, None,
                                                         glob, config, mm, globbed=globbed)
    anchor, anchored = None, np.zeros(missing.shape, dtype=bool)
    if config.anchor and missing.any():
        from ..engines.body_anchor import body_anchor
        anchor = cache(partial(body_anchor, positions, rate))  # computed once, where a sample first needs it
        pred, pred_sd, report_sd = anchor_stage(positions, pred, pred_sd, report_sd, anchor, anchored=anchored)
    boneset = None
    broken = None  # (n_frames, n_bones): where the last bone stage left a bone out (:func:`bone_breaks`)
    reach, stretched = None, None  # the reaches, and where the last bone stage found a prediction past one
    holds = False  # whether the bone stage has anything to hold a prediction with
    solved: dict = {}  # the bone problems solved so far: the refit's bone stage reuses those it left as they were
    if "bones" in done:
        boneset, rates, reach = done["bones"]
        broken = np.zeros((len(positions), len(boneset)), dtype=bool)
        if reach is not None:
            stretched = np.zeros((len(positions), len(reach.pairs)), dtype=bool)
        holds = bool(len(boneset)) or (reach is not None and bool(len(reach.pairs)))
        if holds and np.isfinite(pred_sd).any():
            pred = bone_stage(positions, pred, pred_sd, boneset, config, mm, anchored, report_sd=report_sd,
                              broken=broken, rates=rates, reach=reach, stretched=stretched, jobs=jobs, memo=solved)
    info["bones"] = 0 if boneset is None else int(len(boneset))
    info["reaches"] = 0 if reach is None else int(len(reach.pairs))
    model = motion_model(positions, missing, config, mm, rate)
    # the refit below reads the seed's posterior sd: only the last pass's sd is the reported one
    displaced = displaced_runs(positions, edge, edge_sd, config, mm)
    # the take as the smoother believes it, for a refit on untrusted neighbours (:attr:`ModelConfig.refit_untrusted`)
    believed = (np.empty(positions.shape), np.empty(missing.shape)) if config.refit_untrusted else None
    fill, sd, outliers = temporal_stage(positions, pred, pred_sd, edge, edge_sd, model, config, mm, rate,
                                        report_sd=None if config.impute_passes else report_sd, displaced=displaced,
                                        believed=believed, white_only=anchored, globbed=globbed, jobs=jobs)
    segment_used = None  # where the last refit's segment models predicted (none without a refit)
    spread = None  # the spread of the last refit's widths (:func:`reported_sd`)
    moved = None  # how far the last refit's bone stage moved each prediction (:attr:`ModelConfig.bone_move_sd`)
    for k in range(config.impute_passes):
        last = k == config.impute_passes - 1
        if used_refs is not None:
            used_refs.clear()  # the last pass's models make the prediction: they are the ones reported
        off = np.full(missing.shape, np.nan) if config.extrapolation_sd and last else None
        spread = np.full(missing.shape, np.nan) if config.width_spread_sd and last else None
        moved = None
        segment_used = np.zeros(missing.shape, dtype=bool)
        untrusted_used = np.zeros(missing.shape[1], dtype=bool)
        refit = impute_stage(positions, fill, sd, config, mm, reference_frames=reference_frames,
                             reference_weights=reference_weights, reference_known=reference_known,
                             used_references=used_refs,
                             extrapolation=off, segment_used=segment_used, untrusted=believed,
                             untrusted_used=untrusted_used, disagreement=spread, jobs=jobs)
        if config.seed_where_no_refit:
            refit = seed_elsewhere(positions, refit, seed, max_sd=config.impute_trust_mm * mm, max_z=config.outlier,
                                   edge_frames=config.edge_frames)
        pred, pred_sd, edge, edge_sd = body_stage(positions, *refit, config, mm)
        pred, pred_sd, edge, edge_sd, report_sd = joined(positions, pred, pred_sd, edge, edge_sd,
                                                         reported_sd(pred_sd, off, spread), prior_est, glob, config, mm,
                                                         anchor=anchor, anchored=anchored, globbed=globbed)
        # a model on guessed neighbours weighs how far they lie off the poses it learnt (the fill's sd is the
        # reported one there: :func:`reported_sd`)
        if untrusted_used.any():
            pred_sd = np.where(untrusted_used[None, :], report_sd, pred_sd)
        if holds:
            # a segment model's predictions ride on the markers observed throughout the gap: the bones stay off them
            boned = np.where(segment_used[..., None], pred,
                             bone_stage(positions, pred, pred_sd, boneset, config, mm, anchored,
                                        report_sd=report_sd, broken=broken, rates=rates, reach=reach,
                                        stretched=stretched, jobs=jobs, memo=solved))
            if config.bone_move_sd:  # (NaN where there is no prediction: nothing moved)
                moved_sq = np.nan_to_num(np.sum((boned - pred) ** 2, axis=2))
                report_sd = np.sqrt(report_sd ** 2 + moved_sq / 3.0)
                moved = np.sqrt(moved_sq)
            pred = boned
        displaced = displaced_runs(positions, edge, edge_sd, config, mm)
        displaced[:, untrusted_used] = False  # a model on guessed neighbours does not overrule an observation
        fill, sd, outliers = temporal_stage(positions, pred, pred_sd, edge, edge_sd, model, config, mm, rate,
                                            report_sd=report_sd if last else None, displaced=displaced,
                                            rough=untrusted_used, white_only=anchored, globbed=globbed, jobs=jobs)
    if used_refs is not None:
        info["references"] = ({"frames": int((reference_weights > 0).sum()), "models": len(used_refs),
                               "used": int(sum(used_refs))} if config.impute_passes
                              else sinfo.get("references", {"frames": 0, "models": 0, "used": 0}))
        if reference_known is not None:  # the samples the weighted PCA completed (frames that weigh anything)
            completed = ~reference_known & np.isfinite(reference_frames).all(axis=2)  # (not one it could not)
            info["references"]["completed"] = int(completed[np.asarray(reference_weights) > 0].sum())
    spatial = missing & np.isfinite(pred_sd)
    info["gap_methods"] = gap_records(missing, sd, spatial & ~anchored & ~globbed, outliers, config, mm, labels,
                                      boneset, off, displaced, segment_used, anchored, spread=spread, broken=broken,
                                      reach=reach, stretched=stretched, globbed=globbed, moved=moved,
                                      shown_by_references=shown_by(observed_refs, reference_weights))
    info["displaced"] = displaced_records(positions, displaced, edge, mm, labels)
    info["review"] = review_indices(info["gap_methods"])
    return finish(positions, fill, std=sd, info=info)


#: Frames from which the take's models (:func:`take_stage`) and the smoother's last two passes
#: (:func:`temporal_stage`) each get a process of their own: a fork costs 10-25 ms, about what either
#: costs on a take of a few hundred frames (the smoother's pass ~0.1 ms a frame), so shorter takes run them in turn.
FORK_FRAMES = 500


def take_stage(positions: np.ndarray, bones, config: ModelConfig, mm: float, tasks: list[str], *, units: str, labels,
               jobs: int = 1) -> dict[str, Any]:
    """What stage 1's :func:`global_stage` and stage 2's bones learn from the take: :func:`take_models` for each of
    ``tasks``, which read the take alone, at once on up to ``jobs`` processes from :data:`FORK_FRAMES` frames
    (:func:`~mocapfill.runtime.executor.forked_map`; the same numbers as one after the other).  Returns {task: its
    result}."""
    return dict(zip(tasks, forked_map(partial(take_models, positions, bones, config, mm, units=units, labels=labels),
                                      tasks, jobs if len(positions) >= FORK_FRAMES else 1)))


def take_models(positions: np.ndarray, bones, config: ModelConfig, mm: float, task: str, *, units: str, labels):
    """What the model learns from the take ``positions`` (n_frames, n_markers, 3) alone, by ``task``: "global", the
    global PCA's prediction (:func:`global_prediction`); "bones", the bone set (``bones`` as
    :func:`mocapfill.bones.boneset.resolve_bones` takes it), its break rates (:func:`bone_break_rates`; None for a
    take without gaps, which has no bone to judge, or without bones) and the reaches
    (:func:`mocapfill.bones.reach.reaches`; None without ``reach_partners``)."""
    if task == "global":
        return global_prediction(positions, units)
    from ..bones.boneset import resolve_bones

    boneset = resolve_bones(positions, bones, units=units, labels=labels)
    rates = (bone_break_rates(positions, boneset, config, mm)
             if len(boneset) and config.bone_break_dof and np.isnan(positions).any() else None)
    reach = None
    if config.reach_partners > 0:
        from ..bones.reach import reaches
        reach = reaches(positions, boneset.pairs, partners=config.reach_partners, turned_deg=config.reach_turned_deg)
    return boneset, rates, reach


def shown_by(reference_frames: np.ndarray | None, reference_weights: np.ndarray | None) -> np.ndarray | None:
    """How many reference frames (n_ref, n_markers, 3) with a weight above 0 (n_ref,) show each marker (n_markers,);
    None without references."""
    if reference_frames is None or not len(reference_frames):
        return None
    seen = ~np.isnan(reference_frames).any(axis=2)
    if reference_weights is not None:
        seen &= (np.asarray(reference_weights) > 0)[:, None]
    return seen.sum(axis=0)


#: Most frames of the rest of a long take lent to a window as reference frames (:func:`lost_marker_frames`).
LOST_MARKER_FRAMES = 1000


def lost_marker_frames(positions: np.ndarray, missing: np.ndarray, reference_frames: np.ndarray | None,
                       reference_weights: np.ndarray | None, start: int, stop: int) -> dict:
    """The reference frames for the window ``[start, stop)`` of a long take (positions (n_frames, n_markers, 3),
    missing (n_frames, n_markers) its mask, formed once for all the windows):
    where the window never shows a marker the rest of the take does (a marker lost for good), the take's nearest
    frames (at most :data:`LOST_MARKER_FRAMES`) that show it join the caller's ``reference_frames`` / ``weights``,
    as reference rows of weight 1, so the window's models learn that marker from them; {} where the window shows
    every marker the take does (its fill is the window's own)."""
    lost = missing[start:stop].all(axis=0) & ~missing.all(axis=0)
    if not lost.any():
        return {}
    outside = np.ones(len(positions), dtype=bool)
    outside[start:stop] = False
    frames = np.flatnonzero(outside & ~missing[:, lost].all(axis=1))
    frames = frames[np.argsort(np.minimum(np.abs(frames - start), np.abs(frames - (stop - 1))), kind="stable")]
    frames = np.sort(frames[:LOST_MARKER_FRAMES])
    lent = positions[frames]
    if reference_frames is None:
        return {"reference_frames": lent, "reference_weights": np.ones(len(frames))}
    weights = np.ones(len(reference_frames)) if reference_weights is None else reference_weights
    return {"reference_frames": np.concatenate([reference_frames, lent]),
            "reference_weights": np.concatenate([weights, np.ones(len(frames))])}


def joined(positions: np.ndarray, pred: np.ndarray, pred_sd: np.ndarray, edge: np.ndarray, edge_sd: np.ndarray,
           report_sd: np.ndarray, prior_est: tuple | None, glob: tuple | None, config: ModelConfig, mm: float,
           anchor: Callable | None = None, anchored: np.ndarray | None = None, globbed: np.ndarray | None = None):
    """The learned denoiser's estimate (``prior_est``, :func:`prior_stage`), the global PCA's (``glob``,
    :func:`global_stage`; ``globbed`` receives where it predicted) and the body anchor's (``anchor``,
    :func:`anchor_stage`; ``anchored`` receives where it predicted) joined to the spatial predictions, each where
    given, in both the sd the fill uses (``pred_sd``) and the one it reports (``report_sd``, :func:`reported_sd`).
    Arrays as :func:`spatial_stage` returns them; returns pred, pred_sd, edge, edge_sd, report_sd."""
    if prior_est is not None:
        report_sd = prior_stage(positions, pred, report_sd, edge, edge_sd, *prior_est)[1]
        pred, pred_sd, edge, edge_sd = prior_stage(positions, pred, pred_sd, edge, edge_sd, *prior_est)
    if glob is not None:
        report_sd = global_stage(positions, pred, report_sd, *glob, config, mm)[1]
        pred, pred_sd = global_stage(positions, pred, pred_sd, *glob, config, mm, globbed=globbed)
    if anchor is not None:
        pred, pred_sd, report_sd = anchor_stage(positions, pred, pred_sd, report_sd, anchor, anchored=anchored)
    return pred, pred_sd, edge, edge_sd, report_sd


def anchor_stage(positions: np.ndarray, pred: np.ndarray, pred_sd: np.ndarray, report_sd: np.ndarray,
                 anchor: Callable[[], tuple[np.ndarray, np.ndarray, float]], *, anchored: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 1d: missing samples still without a prediction (NaN ``pred_sd``) take the body anchor's
    (``anchor()``, called only if there are such samples: :func:`mocapfill.engines.body_anchor.body_anchor`'s
    anchor (n_frames, n_markers, 3), anchor_sd (n_frames, n_markers) and memory (frames)) as a white measurement of
    sd ``anchor_sd * sqrt(memory)``: its error persists over ``memory`` frames, so n frames of it count as
    n / memory independent ones, and :func:`temporal_stage` is told (``white_only``) to give it no correlated part.
    pred / pred_sd / report_sd as :func:`joined` has them; returns the three with those samples filled; ``anchored``
    (n_frames, n_markers) bool or None receives where the anchor predicted."""
    todo = np.isnan(positions).any(axis=2) & ~np.isfinite(pred_sd)
    if todo.any():
        est, anchor_sd, memory = anchor()
        todo &= np.isfinite(anchor_sd)
    if anchored is not None:
        anchored[:] = todo
    if not todo.any():
        return pred, pred_sd, report_sd
    white = anchor_sd * np.sqrt(memory)
    return np.where(todo[..., None], est, pred), np.where(todo, white, pred_sd), np.where(todo, white, report_sd)


def rigid_noise(config: ModelConfig, mm: float) -> float | None:
    """With :attr:`ModelConfig.align_rigid`, the spread (data units) the cameras' noise alone gives the distance of
    two markers (each coordinate of each with sd ``obs_sd_mm``): below it a spread says nothing of rigidity
    (:func:`mocapfill.engines.local_pca.rigidity_weights`); None without it."""
    return float(np.sqrt(2.0) * config.obs_sd_mm * mm) if config.align_rigid else None


def spatial_stage(positions: np.ndarray, config: ModelConfig, mm: float, *,
                  reference_frames: np.ndarray | None = None, reference_weights: np.ndarray | None = None,
                  reference_known: np.ndarray | None = None, jobs: int = 1):
    """Stage 1: the local weighted PCA's prediction of every missing sample.

    positions (n_frames, n_markers, 3); mm data units per millimetre; reference_frames (n, n_markers, 3) or None,
    reference_known (n, n_markers) bool or None: where they observe each marker, if their gaps were completed.
    Returns pred (n_frames, n_markers, 3) (NaN where no model), sd (n_frames, n_markers) per coordinate (NaN where
    no model), the reconstruction at observed frames next to gaps (n_frames, n_markers, 3) and its sd, and info
    (with ``config.extrapolation_sd`` and no refit to follow (``impute_passes`` 0), ``info["extrapolation"]``
    (n_frames, n_markers): how far each prediction's pose lies off its model's training poses, NaN where none;
    :func:`reported_sd`).  ``jobs``: processes the local models are fitted on (the output does not depend on it).
    """
    n = len(positions)
    weighed = reference_frames is not None and reference_weights is not None
    data = positions if reference_frames is None or weighed else np.concatenate([positions, reference_frames])
    scales, knn = (config.scales_mm, config.knn) if config.impute_passes == 0 else (config.seed_scales_mm,
                                                                                     config.seed_knn)
    # weighed references train each model beside the capture's frames where its cross-validation keeps them
    pred, sd, info = reconstruct_local(data, scales=tuple(np.asarray(scales) * mm),
                                       align_scale=config.align_mm * mm, knn=knn, edge=None, folds=config.cv_folds,
                                       max_predictors=config.max_predictors,
                                       edge_frames=config.edge_frames,
                                       reference_frames=reference_frames if weighed else None,
                                       reference_weights=reference_weights if weighed else None,
                                       reference_known=reference_known if weighed else None,
                                       extrapolation=config.extrapolation_sd and not config.impute_passes,
                                       rigid_align=rigid_noise(config, mm), jobs=jobs)
    if "extrapolation" in info:
        info["extrapolation"] = info["extrapolation"][:n]
    missing = np.isnan(positions).any(axis=2)
    pred, sd = pred[:n], sd[:n]
    sd = np.where(missing, sd, np.nan)
    pred = np.where(np.isfinite(sd)[..., None], pred, np.nan)
    return (*body_stage(positions, pred, sd, info["edge_estimate"][:n], info["edge_std"][:n], config, mm), info)


def body_stage(positions: np.ndarray, pred: np.ndarray, sd: np.ndarray, edge: np.ndarray, edge_sd: np.ndarray,
               config: ModelConfig, mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Stage 1b: missing samples without a spatial prediction (NaN sd) get the rigid one of
    :func:`mocapfill.engines.local_pca.rigid_prediction` (the marker on its nearest markers seen at that frame, its
    scatter relative to them as the sd).  positions / pred / edge (n_frames, n_markers, 3), sd / edge_sd (n_frames,
    n_markers): as :func:`spatial_stage` returns them; returns the four with those samples filled where the body
    allows, and the rigid prediction at the observed frames next to them where ``edge`` had none (so the smoother
    learns its error there too and the fill meets the observations without a kink)."""
    from ..engines.local_pca import rigid_prediction

    todo = np.isnan(positions).any(axis=2) & ~np.isfinite(sd)
    if not config.rigid_nearest or not todo.any():
        return pred, sd, edge, edge_sd
    est, est_sd, r_edge, r_edge_sd = rigid_prediction(positions, todo, nearest=config.rigid_nearest,
                                                      align_scale=config.align_mm * mm, edge_frames=config.edge_frames)
    use = todo & np.isfinite(est_sd)
    at_edge = ~np.isfinite(edge_sd) & np.isfinite(r_edge_sd)
    return (np.where(use[..., None], est, pred), np.where(use, est_sd, sd), np.where(at_edge[..., None], r_edge, edge),
            np.where(at_edge, r_edge_sd, edge_sd))


def global_prediction(positions: np.ndarray, units: str) -> tuple[np.ndarray, np.ndarray]:
    """Stage 1c's prediction: the global distance-weighted PCA (:func:`mocapfill.methods.pca.fill_pca`) of every
    missing sample.  positions (n_frames, n_markers, 3); returns its fill (n_frames, n_markers, 3) and a (n_frames,
    n_markers) mask of where it has one inside the body: a sample that leaves the body's observed extent or steps
    faster than its marker was seen to (:func:`mocapfill.guards.plausibility.implausible`), or accelerates more than
    anything observed in the capture, is no prediction (``pca``'s fill can be metres off where few markers are
    seen)."""
    from ..engines.weighted_pca import reconstruct, weight_width
    from ..evaluation.smoothness import accelerations
    from ..guards.plausibility import implausible, observed_speed

    # ``pca``'s fill (fill_pca's defaults) without its cross-validated sd: this prediction's sd is global_sd_mm
    glob = finish(positions, reconstruct(positions, scale=weight_width(units, None), uncertainty=False)[0]).positions
    has = np.isfinite(glob).all(axis=2)
    acc = np.full(has.shape, np.inf)
    acc[1:-1] = accelerations(glob)
    observed = accelerations(positions)  # NaN wherever one of the three samples is missing
    observed = observed[np.isfinite(observed)]
    limit = float(observed.max()) if observed.size else np.inf
    wild = ~(np.nan_to_num(acc, nan=np.inf) <= limit)
    wild |= implausible(np.where(has[..., None], glob, positions), positions,
                        observed_speed(positions, ~np.isfinite(positions).all(axis=2), floor=0.0))
    wild[1:] |= wild[:-1]  # a wild second difference spoils its three samples
    wild[:-1] |= wild[1:]
    return glob, has & ~wild


def global_stage(positions: np.ndarray, pred: np.ndarray, sd: np.ndarray, glob: np.ndarray, has: np.ndarray,
                 config: ModelConfig, mm: float, *, globbed: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Stage 1c: missing samples the local model could not predict (NaN ``sd``, (n_frames, n_markers)) take the
    global PCA's prediction ``glob`` (n_frames, n_markers, 3; ``has`` where it has one) with sd
    ``config.global_sd_mm``, so a marker seen in few frames still moves with the body; the smoother weighs it like
    any spatial prediction.  Returns pred and sd with those samples filled; ``globbed`` (n_frames, n_markers) bool or
    None receives where."""
    todo = np.isnan(positions).any(axis=2) & ~np.isfinite(sd) & has
    if globbed is not None:
        globbed[:] = todo
    if not todo.any():
        return pred, sd
    return np.where(todo[..., None], glob, pred), np.where(todo, config.global_sd_mm * mm, sd)


def impute_stage(positions: np.ndarray, completed: np.ndarray, sd: np.ndarray, config: ModelConfig, mm: float, *,
                 reference_frames: np.ndarray | None = None, reference_weights: np.ndarray | None = None,
                 reference_known: np.ndarray | None = None,
                 used_references: list | None = None, extrapolation: np.ndarray | None = None,
                 segment_used: np.ndarray | None = None, untrusted: tuple | None = None,
                 untrusted_used: np.ndarray | None = None, disagreement: np.ndarray | None = None,
                 jobs: int = 1):
    """Stage 4: the spatial model fitted again with the neighbours taken from the completed take.

    positions (n_frames, n_markers, 3) the input (NaN = missing); completed the same filled by stage 3, sd
    (n_frames, n_markers) its posterior sd (0 observed).  One model per marker with gaps, trained on every frame
    where it is observed, every near marker a predictor (:func:`mocapfill.engines.local_refit.reconstruct_completed`;
    a filled neighbour's sd is propagated into the prediction's; with :attr:`ModelConfig.refit_by_run`, a marker
    without one model for all its gaps gets one per group of gaps with the same trusted neighbours).  Returns pred,
    sd, edge, edge_sd as :func:`spatial_stage` (NaN where the refit has no model; :func:`body_stage` runs after it,
    and with :attr:`ModelConfig.seed_where_no_refit`, :func:`seed_elsewhere` before that); ``extrapolation``
    (n_frames, n_markers) or None receives how far each prediction's pose lies off its model's training poses
    (:func:`reported_sd`); ``segment_used`` (n_frames, n_markers) bool or None receives where a segment model
    predicted (:attr:`ModelConfig.segment_mm`).  ``untrusted`` (take, sd) or None, with
    :attr:`ModelConfig.refit_untrusted`: where fewer than 3 neighbours are trusted, a model on every near marker read
    from that take; ``untrusted_used`` (n_markers,) bool or None receives which markers got one; ``disagreement``
    (n_frames, n_markers) or None receives the spread of the widths' predictions (:func:`reported_sd`).  ``jobs``:
    processes the models are fitted on (the output does not depend on it).
    """
    from ..engines.local_refit import reconstruct_completed

    pred, pred_sd, edge, edge_sd = reconstruct_completed(
        positions, completed, sd, scales=tuple(np.asarray(config.scales_mm) * mm), align_scale=config.align_mm * mm,
        knn=config.knn, folds=config.cv_folds, max_predictors=config.max_predictors, edge_frames=config.edge_frames,
        reference=reference_frames,
        leverage_weight=config.leverage_weight, trust=config.impute_trust_mm * mm if config.impute_trust_mm else None,
        reference_weights=reference_weights, used_references=used_references, extrapolation=extrapolation,
        segment=config.segment_mm * mm if config.segment_mm else None, segment_used=segment_used,
        parts=config.refit_parts, untrusted=untrusted, untrusted_used=untrusted_used, disagreement=disagreement,
        run_scales=tuple(np.asarray(config.seed_scales_mm) * mm) if config.refit_by_run else None,
        run_knn=config.seed_knn, run_max_rms=config.review_sd_mm * mm, rigid_align=rigid_noise(config, mm),
        reference_known=reference_known, jobs=jobs)
    return pred, pred_sd, edge, edge_sd


def seed_elsewhere(positions: np.ndarray, refit: tuple, seed: tuple, *, max_sd: float, max_z: float,
                   edge_frames: int) -> tuple:
    """Stage 4's predictions where its refit has a model, stage 1's elsewhere where stage 1 is sure of them.

    positions (n_frames, n_markers, 3), NaN = missing; refit and seed are (pred (n_frames, n_markers, 3), sd
    (n_frames, n_markers), edge, edge_sd) as :func:`impute_stage` and :func:`spatial_stage` return them (NaN sd: no
    prediction).  The refit has no model for a marker with fewer than 3 trusted neighbours (filled with an sd above
    :attr:`ModelConfig.impute_trust_mm` during its gaps: on a capture with gaps everywhere, most of them); the first
    pass conditioned only on the neighbours observed where it predicts, and where it is as sure as a neighbour the
    refit trusts (its sd at most ``max_sd``) its prediction is the best the capture gives there: Walking_Hybrid_1_1's
    thigh marker, hidden for 395 frames before a gap to the take's end, predicted by its three cluster neighbours at
    1.3 mm rms, which the refit, trusting no three of them over the run, left to the global PCA 112 mm off.  A gap
    run keeps none of it where the first pass's reconstruction of the observed samples beside it (up to
    ``edge_frames`` either side) misses them by more than ``max_z`` sds (RMS per coordinate): a model that does not
    fit the frames next to the gap is not one to bend the fill to (VER4C3D: a toe reconstructed 60-110 mm off the
    three frames before its take-end gap with an sd of 8.4 mm swung the fill 40.8 mm/frame^2 against 27.1
    observed).  Stage 1's arrays hold :func:`body_stage`'s rigid predictions where its local PCA had none, so the
    order is: the refit, the first pass's local PCA, the body.  Returns the four arrays.
    """
    pred, sd, edge, edge_sd = refit
    missing = np.isnan(positions).any(axis=2)
    use = missing & ~np.isfinite(sd) & (np.nan_to_num(seed[1], nan=np.inf) <= max_sd)
    with np.errstate(invalid="ignore", divide="ignore"):
        miss_by = np.sqrt(np.sum((positions - seed[2]) ** 2, axis=2) / 3.0) / seed[3]  # (observed, edge frames)
    for m in np.flatnonzero(use.any(axis=0)):
        for start, length in runs(missing[:, m]):
            if not use[start:start + length, m].any():
                continue
            beside = miss_by[max(start - edge_frames, 0):start + length + edge_frames, m]
            if (beside[np.isfinite(beside)] > max_z).any():
                use[start:start + length, m] = False
    at_edge = ~np.isfinite(edge_sd) & np.isfinite(seed[3])
    return (np.where(use[..., None], seed[0], pred), np.where(use, seed[1], sd),
            np.where(at_edge[..., None], seed[2], edge), np.where(at_edge, seed[3], edge_sd))


def prior_estimate(positions: np.ndarray, model: Any, *, labels, units: str, rate: float, config: ModelConfig
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A learned denoiser's estimate of every sample and its sd, for :func:`prior_stage`.

    positions (n_frames, n_markers, 3), NaN = missing; model a DenoiserModel.  Returns the network's smoothed
    estimate (n_frames, n_markers, 3) (:func:`mocapfill.methods.learned.network_estimate`) and its sd per
    coordinate per marker (n_markers,) (NaN for markers outside the layout or never observed): the RMS error of
    the network's estimate of a marker at up to ``config.prior_frames`` frames where it was observed, each hidden
    together with the markers missing at one of its gap frames (drawn at random): the network is judged under the
    capture's own occlusions, not with every neighbour in view.
    """
    from ..engines.denoiser import from_layout, layout_index, predict_frames, to_layout
    from .learned import network_estimate

    est = network_estimate(positions, model, labels=labels, units=units, rate=rate)
    idx = layout_index(model, labels, positions.shape[1])
    mine = to_layout(positions, idx, model, units)
    hidden = np.isnan(mine).any(axis=2)
    rng = np.random.default_rng(0)  # which frames are hidden; fixed, so the fill is deterministic
    batches, owners = [], []
    for k in range(model.n_markers):
        rows, gaps = np.flatnonzero(~hidden[:, k]), np.flatnonzero(hidden[:, k])
        if not len(rows) or not len(gaps):
            continue
        n = min(len(rows), config.prior_frames)
        rows = rng.choice(rows, n, replace=False)
        x = mine[rows].copy()
        x[hidden[rng.choice(gaps, n)]] = np.nan  # each a gap frame's missing markers (k among them)
        batches.append(x)
        owners.append((k, rows))
    sd_layout = np.full(model.n_markers, np.nan)
    if batches:
        out = predict_frames(np.concatenate(batches), model)
        at = 0
        for k, rows in owners:
            err = out[at:at + len(rows), k] - mine[rows, k]
            at += len(rows)
            err = err[np.isfinite(err).all(axis=1)]
            if len(err):
                sd_layout[k] = float(np.sqrt(np.mean(err ** 2)))
    sd = from_layout(np.repeat(sd_layout[None, :, None], 3, axis=2), idx, positions.shape[1], model, units)[0, :, 0]
    sd[np.isnan(positions).any(axis=2).all(axis=0)] = np.nan
    return est, sd * config.prior_sd_scale


def prior_stage(positions: np.ndarray, pred: np.ndarray, pred_sd: np.ndarray, edge: np.ndarray,
                edge_sd: np.ndarray, prior: np.ndarray, prior_sd: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A learned denoiser's estimate as a second spatial measurement, fused with the spatial stage's.

    positions / pred / edge (n_frames, n_markers, 3) and pred_sd / edge_sd (n_frames, n_markers) as
    :func:`spatial_stage` returns them; prior (n_frames, n_markers, 3) the network's estimate and prior_sd
    (n_markers,) its sd (:func:`prior_estimate`).  Where both predict, the two are averaged by inverse variance
    (independent errors: the variance is the harmonic combination); where only the network does, its estimate
    stands.  The same at the observed frames next to gaps (``edge``), so the smoother learns the fused
    measurement's error there.  Returns pred, pred_sd, edge, edge_sd.
    """
    missing = np.isnan(positions).any(axis=2)
    p_sd = np.broadcast_to(prior_sd[None, :], pred_sd.shape)
    ok = np.isfinite(prior).all(axis=2) & np.isfinite(p_sd) & (p_sd > 0)

    def fuse(a, a_sd, where):
        have = where & ok
        both = have & np.isfinite(a_sd) & np.isfinite(a).all(axis=2)
        with np.errstate(divide="ignore", invalid="ignore"):
            wa = np.where(both, 1.0 / a_sd ** 2, 0.0)
            wp = np.where(have, 1.0 / p_sd ** 2, 0.0)
            tot = wa + wp
            mean = (wa[..., None] * np.nan_to_num(a) + wp[..., None] * np.nan_to_num(prior)) / tot[..., None]
            var = 1.0 / tot
        return (np.where(have[..., None], mean, a), np.where(have, np.sqrt(var), a_sd))

    pred, pred_sd = fuse(pred, pred_sd, missing)
    # the edge measurement exists only where the spatial model had one: the network joins it there
    edge, edge_sd = fuse(edge, edge_sd, ~missing & np.isfinite(edge_sd))
    return pred, pred_sd, edge, edge_sd


def bone_stage(positions: np.ndarray, pred: np.ndarray, sd: np.ndarray, boneset, config: ModelConfig, mm: float,
               anchored: np.ndarray | None = None, *, report_sd: np.ndarray | None = None,
               broken: np.ndarray | None = None, rates: np.ndarray | None = None, reach=None,
               stretched: np.ndarray | None = None, jobs: int = 1, memo: dict | None = None) -> np.ndarray:
    """Stage 2: predictions (n_frames, n_markers, 3) moved to the most probable positions given the bones.

    sd (n_frames, n_markers) the predictions' standard deviations (NaN: not moved); boneset a BoneSet.  With
    ``config.bone_extrapolation`` each bone's spread is per frame (:func:`bone_spreads`).  anchored (n_frames,
    n_markers) bool or None: the body anchor's predictions (:func:`anchor_stage`), left out: the anchor's error is
    as large as a bone, so the bones would place them anywhere on a sphere about their neighbours, and a bone to
    one of them does not count.  A bone the predictions say broke at a frame is left out there
    (:func:`bone_breaks`, judged with ``report_sd``, the sd that knows where the model extrapolates; None: ``sd``);
    ``broken`` (n_frames, n_bones) bool or None receives where; ``rates`` the bones' break rates if already computed
    (:func:`bone_break_rates`; None: computed here).  ``reach`` (:func:`mocapfill.bones.reach.reaches`) or None:
    pairs that only a distance past their limit costs, held with the bones; ``stretched`` (n_frames, n_reaches) bool
    or None receives where a prediction stretched one past its limit.  ``jobs``: processes the frames' problems are
    solved on (the output does not depend on it).  ``memo`` (a dict) or None: problems solved by an earlier bone
    stage of the same fill, reused where their inputs are the same (:func:`~mocapfill.bones.refinement.refine_bones`).
    """
    from ..bones.refinement import refine_bones

    if anchored is not None and anchored.any():
        kept = pred
        pred = np.where(anchored[..., None], np.nan, pred)
        return np.where(anchored[..., None], kept, bone_stage(positions, pred, sd, boneset, config, mm,
                                                              report_sd=report_sd, broken=broken, rates=rates,
                                                              reach=reach, stretched=stretched, jobs=jobs,
                                                              memo=memo))

    est = np.where(np.isnan(positions), pred, positions)
    spread = bone_spreads(positions, est, sd, boneset, config, mm) if config.bone_extrapolation else boneset.spread
    gone = bone_breaks(positions, est, sd if report_sd is None else report_sd, boneset, config, mm, rates)
    if broken is not None:
        broken[:] = gone
    if gone.any():  # an infinite spread leaves the bone out at that frame
        spread = np.where(gone, np.inf, np.broadcast_to(spread, gone.shape))
    pairs, lengths, one_sided = np.asarray(boneset.pairs, dtype=int).reshape(-1, 2), boneset.lengths, None
    if reach is not None and len(reach.pairs):
        pairs = np.concatenate([pairs, reach.pairs])
        lengths = np.concatenate([lengths, reach.limit])
        spread = np.asarray(spread, dtype=float)
        spread = np.concatenate([spread, np.broadcast_to(reach.spread, spread.shape[:-1] + (len(reach.pairs),))],
                                axis=-1)
        one_sided = np.arange(len(pairs)) >= len(boneset)
    refined, info = refine_bones(est, positions, sd * config.bone_trust, pairs, lengths,
                                 spread, spread_floor=config.spread_floor_mm * mm, one_sided=one_sided, jobs=jobs,
                                 memo=memo)
    if stretched is not None and one_sided is not None:
        stretched[:] = info["stretched"]
    return np.where(np.isfinite(pred), refined, np.nan)


def bone_break_rates(positions: np.ndarray, boneset, config: ModelConfig, mm: float) -> np.ndarray:
    """Each bone's break rate (n_bones,) on the capture ``positions`` (n_frames, n_markers, 3), NaN = missing:
    :func:`~mocapfill.bones.refinement.break_rates` with the spreads floored as the bone stage floors them."""
    from ..bones.refinement import break_rates

    pairs = np.asarray(boneset.pairs, dtype=int).reshape(-1, 2)
    return break_rates(positions, pairs, np.asarray(boneset.lengths, dtype=float), _floored_spread(boneset, config, mm),
                       dof=config.bone_break_dof)


def _floored_spread(boneset, config: ModelConfig, mm: float) -> np.ndarray:
    return np.maximum(np.nan_to_num(np.asarray(boneset.spread, dtype=float), nan=0.0), config.spread_floor_mm * mm)


def bone_breaks(positions: np.ndarray, est: np.ndarray, sd: np.ndarray, boneset, config: ModelConfig, mm: float,
                rates: np.ndarray | None = None) -> np.ndarray:
    """Where each bone does not hold (n_frames, n_bones) bool, by the predictions' word against the bone's.

    positions (n_frames, n_markers, 3) NaN = missing; est the same with the predictions in the missing samples; sd
    (n_frames, n_markers) their sd per coordinate (NaN: no prediction).  At a frame where an end is predicted, the
    bone's miss r = |x_a - x_b| - L has variance v = s^2 + sd_a^2 + sd_b^2 (s the bone's spread; 0 for an observed
    end).  The bone is broken there where its break rate p (how often it broke where both ends were observed,
    :func:`~mocapfill.bones.refinement.break_rates`) times the density of r if it broke, N(0, L^2 + v), exceeds
    1 - p times the density if it held, a Student t with ``bone_break_dof`` degrees of freedom scaled by sqrt(v) (the
    prediction's error is heavier-tailed than its sd says; :func:`~mocapfill.bones.refinement.miss_log_densities`).
    A bone that held at every observed frame holds everywhere.  ``rates`` (n_bones,) or None: the break rates, if
    already computed (:func:`bone_break_rates`).
    """
    from ..bones.refinement import miss_log_densities

    missing = np.isnan(positions).any(axis=2)
    pairs = np.asarray(boneset.pairs, dtype=int).reshape(-1, 2)
    out = np.zeros((len(positions), len(pairs)), dtype=bool)
    if not len(pairs) or not config.bone_break_dof > 0 or not (missing[:, pairs[:, 0]] | missing[:, pairs[:, 1]]).any():
        return out  # (no bone with an end to judge: its break rate is not needed)
    p = bone_break_rates(positions, boneset, config, mm) if rates is None else rates
    live = np.flatnonzero(p > 0)  # a bone that held at every observed frame holds
    if not len(live):
        return out
    a, b = pairs[live, 0], pairs[live, 1]
    need = missing[:, a] | missing[:, b]
    length = np.asarray(boneset.lengths, dtype=float)[live]
    var = np.where(missing, sd, 0.0) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.linalg.norm(est[:, a] - est[:, b], axis=2) - length
        held, gone = miss_log_densities(r, _floored_spread(boneset, config, mm)[live] ** 2 + var[:, a] + var[:, b],
                                        length, config.bone_break_dof)
        # (NaN: an end without an estimate: no verdict)
        out[:, live] = need & (np.log(p[live]) + gone > np.log1p(-p[live]) + held)
    return out


def bone_spreads(positions: np.ndarray, est: np.ndarray, sd: np.ndarray, boneset, config: ModelConfig, mm: float
                 ) -> np.ndarray:
    """Per frame and bone spread (n_frames, n_bones): the bone's spread s times the square root of how far, at that
    frame, the bone's vector d = x_a - x_b (from the estimates ``est`` (n_frames, n_markers, 3), whose sd per
    coordinate is ``sd`` (n_frames, n_markers), 0 observed) lies off the vectors that measured it (the frames with
    both ends observed, mean mu and covariance S): z^2 = (d - mu)^T (S + (s^2 + sd_a^2 + sd_b^2) I)^-1 (d - mu) / 3,
    discounted by how much the bone turned there while keeping its length: the factor is max(1, z^2 s^2 / (s^2 + m))
    with m the variance per axis of the measured vectors beyond their length's.  A bone measured only while its ends
    stood still (m ~ 0: two still markers look rigid) says nothing once the estimates say an end moved; one seen
    turning while it kept its length keeps its spread; an uncertain estimate off the bone is not held against it."""
    missing = np.isnan(positions).any(axis=2)
    out = np.tile(np.asarray(boneset.spread, dtype=float), (len(positions), 1))
    floor2 = (config.spread_floor_mm * mm) ** 2
    var = np.where(missing, np.nan_to_num(sd, nan=np.inf) ** 2, 0.0)
    for k, ((a, b), s) in enumerate(zip(boneset.pairs, boneset.spread)):
        co = ~missing[:, a] & ~missing[:, b]
        need = np.flatnonzero(missing[:, a] | missing[:, b])
        if co.sum() < 2 or not np.isfinite(s) or not len(need):
            continue
        s2 = max(s * s, floor2)
        vec = positions[co, a] - positions[co, b]
        lam, q = np.linalg.eigh(np.cov(vec.T))
        moved = max(float(lam.sum()) - float(np.var(np.linalg.norm(vec, axis=1))), 0.0) / 3.0
        proj = ((est[need, a] - est[need, b] - vec.mean(axis=0)) @ q) ** 2  # (n, 3) along S's axes
        with np.errstate(invalid="ignore"):
            z2 = (proj / (np.maximum(lam, 0.0) + s2 + (var[need, a] + var[need, b])[:, None])).sum(axis=1) / 3.0
        out[need, k] = s * np.sqrt(np.maximum(np.nan_to_num(z2 * s2 / (s2 + moved), nan=1.0), 1.0))
    return out


def motion_model(positions: np.ndarray, missing: np.ndarray, config: ModelConfig, mm: float, rate: float
                 ) -> MotionModel:
    """The smoother's parameters for this capture: the jerk density per marker (n_markers,) from its observed
    third differences (:func:`~mocapfill.engines.motion_smoother.jerk_density`), the config's times in frames."""
    q = jerk_density(positions, missing, floor=config.jerk_floor_mm2 * mm ** 2) * config.jerk_scale
    gain = jerk_gain(positions, missing, q, window=int(round(config.gain_seconds * rate)), floor=config.gain_floor)
    rest = config.rest_seconds * rate
    rho_acc = None
    if config.measured_acc_memory:
        # how long this capture's accelerations persist: where they are mostly noise, an acceleration estimated at a
        # gap's edge (often a poor sample) is not carried into the gap
        tau_acc = min(acceleration_memory(positions, missing, max_lag=int(np.ceil(rest))), rest)
        rho_acc = float(np.exp(-1.0 / max(tau_acc, 1e-3)))
    return MotionModel(q=q, rho=float(np.exp(-1.0 / rest)),
                       phi=float(np.exp(-1.0 / (config.bias_seconds * rate))), r_obs=(config.obs_sd_mm * mm) ** 2,
                       gain=gain, rho_acc=rho_acc)


def reported_sd(pred_sd: np.ndarray, off: np.ndarray | None, spread: np.ndarray | None = None) -> np.ndarray:
    """The spatial sd (n_frames, n_markers) the reported posterior sd is computed with: sqrt(pred_sd^2 off + spread),
    ``off`` (n_frames, n_markers, >= 1) how far each prediction's pose lies off its model's training poses (NaN or
    None: 1) and ``spread`` (n_frames, n_markers) the variance per coordinate of the model's widths about their mix
    (:attr:`ModelConfig.width_spread_sd`; NaN or None: 0).  Where the neighbours take a pose the model never saw, its
    cross-validated error understates the prediction's (qualisys-walk, dense 5 %: a heel trained in stance,
    predicted in swing, 40 mm off with a cross-validated sd of 1 mm); where its widths disagree, so does their
    average's."""
    if off is None and spread is None:
        return pred_sd
    var = pred_sd ** 2
    if off is not None:
        var = var * np.where(np.isfinite(off), np.maximum(off, 1.0), 1.0)
    if spread is not None:
        var = var + np.where(np.isfinite(spread), spread, 0.0)
    return np.sqrt(var)


def displaced_runs(positions: np.ndarray, edge: np.ndarray, edge_sd: np.ndarray, config: ModelConfig, mm: float
                   ) -> np.ndarray:
    """Stage 3a: observed runs between two gaps that the spatial model says were displaced as a whole.

    positions / edge (n_frames, n_markers, 3): the input and the spatial model's reconstruction at the observed
    frames next to gaps, edge_sd (n_frames, n_markers) its sd per coordinate (NaN: none there).  For each observed
    run with a gap on both sides, r = the mean over its reconstructed frames of (observed - reconstructed) and
    s^2 = the mean of edge_sd^2 + the camera's variance.  Two hypotheses (a run's errors are correlated in time, so
    the mean is not credited with averaging): the run is right, r ~ N(0, s^2 I_3), or it was displaced by an offset
    of sd ``displacement_mm`` per axis, r ~ N(0, (s^2 + v) I_3), with prior probability ``displaced_prior``.  Where the
    second is the more probable,
    |r|^2 > 2 s^2 (s^2 + v) / v [ln((1 - p) / p) + 3/2 ln((s^2 + v) / s^2)],
    the run's samples are marked (about 5 s where s is 10 mm, 6 s at 2 mm).  A run at the take's start or end is left
    alone (one gap beside it; counting those changed no trial of ``bench_corruption``'s tennis serve by more than
    0.1 %).  Returns (n_frames, n_markers) bool.
    """
    missing = np.isnan(positions).any(axis=2)
    out = np.zeros(missing.shape, dtype=bool)
    p = config.displaced_prior
    if not 0.0 < p < 1.0:
        return out
    v = (config.displacement_mm * mm) ** 2
    r_obs = (config.obs_sd_mm * mm) ** 2
    between = fragments(missing, missing.shape[0])  # every observed run with a gap on both sides
    for m in np.flatnonzero(between.any(axis=0)):
        for start, length in runs(between[:, m]):
            sl = slice(start, start + length)
            seen = np.isfinite(edge_sd[sl, m]) & np.isfinite(edge[sl, m]).all(axis=1)
            if not seen.any():
                continue
            r = (positions[sl, m][seen] - edge[sl, m][seen]).mean(axis=0)
            s2 = float(np.mean(edge_sd[sl, m][seen] ** 2)) + r_obs
            bound = 2.0 * s2 * (s2 + v) / v * (np.log((1.0 - p) / p) + 1.5 * np.log((s2 + v) / s2))
            if float(r @ r) > bound:
                out[sl, m] = True
    return out


def temporal_stage(positions: np.ndarray, pred: np.ndarray, pred_sd: np.ndarray, edge: np.ndarray,
                   edge_sd: np.ndarray, model: MotionModel, config: ModelConfig, mm: float, rate: float,
                   report_sd: np.ndarray | None = None, displaced: np.ndarray | None = None,
                   rough: np.ndarray | None = None, believed: tuple[np.ndarray, np.ndarray] | None = None,
                   white_only: np.ndarray | None = None, globbed: np.ndarray | None = None, jobs: int | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 3: the smoother's posterior mean and sd for every marker with gaps.

    positions / pred / edge (n_frames, n_markers, 3); pred_sd / edge_sd (n_frames, n_markers) (NaN: no spatial
    measurement there); model with q (n_markers,).  Returns fill (n_frames, n_markers, 3) (the input where
    observed; NaN for markers never observed), sd (n_frames, n_markers) (0 observed) and the (n_frames, n_markers)
    mask of spatial predictions down-weighted as outliers.  ``report_sd`` (n_frames, n_markers) or None: the
    spatial sd the returned posterior sd is computed with (:func:`reported_sd`; the mean keeps ``pred_sd``): the
    smoother runs again, for its variances, on the markers where it differs.  ``displaced`` (n_frames, n_markers)
    bool or None: observed samples judged displaced (:func:`displaced_runs`), measured with the sd
    ``displacement_mm`` instead of the camera's.  ``globbed`` (n_frames, n_markers) bool or None: where the global
    PCA predicted (:func:`global_stage`); with :attr:`ModelConfig.bias_per_model`, the prediction's correlated error
    is drawn anew where the kind of model changes (local PCA, global PCA, the anchor's ``white_only``:
    :func:`model_changes`).  ``rough`` (n_markers,) bool or None: markers whose spatial
    predictions' white error variance grows by :func:`rough_variance`.  ``believed`` (take (n_frames, n_markers, 3),
    sd (n_frames, n_markers)) or None receives the take as the smoother believes it: the fill and its sd, but at the
    observed samples it measured as noisy (fragments, displaced runs) its posterior mean and sd.  ``jobs``: the
    processes the last mean pass and the variance pass share (from :data:`FORK_FRAMES` frames; the same numbers as one
    after the other).
    """
    missing = np.isnan(positions).any(axis=2)
    # (a marker the take never shows is smoothed where a reference take let the spatial model predict it)
    todo = np.flatnonzero(missing.any(axis=0) & (~missing.all(axis=0) | np.isfinite(pred_sd).any(axis=0)))
    fill = positions.copy()
    sd_out = np.where(missing, np.nan, 0.0)
    outliers = np.zeros_like(missing)
    if not len(todo):
        return fill, sd_out, outliers
    obs = positions[:, todo]
    sp = np.where(missing[:, todo, None], pred[:, todo], edge[:, todo])
    sp_sd = np.where(missing[:, todo], pred_sd[:, todo], edge_sd[:, todo])
    sp = np.where(np.isfinite(sp_sd)[..., None], sp, np.nan)
    extra = None  # the white variance measured from the predictions' roughness, where asked
    if rough is not None and rough[todo].any():
        extra = np.where(rough[todo][None, :], rough_variance(obs, sp), 0.0)
    wo = None if white_only is None else white_only[:, todo] & missing[:, todo]

    def split(s: np.ndarray, cols: Any = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """The white and correlated sds of spatial measurements of sd ``s`` (n_frames, the series ``cols``):
        ``white_share`` of the variance white (plus ``extra``), the rest correlated; a measurement ``white_only``
        marks (the body anchor's) wholly white at the variance given."""
        white = s * np.sqrt(config.white_share)
        if extra is not None:
            white = np.sqrt(white ** 2 + extra[:, cols])
        bias = s * np.sqrt(1.0 - config.white_share)
        if wo is not None:
            white, bias = np.where(wo[:, cols], s, white), np.where(wo[:, cols], 0.0, bias)
        return white, bias

    white, bias = split(sp_sd)
    sub = model._replace(q=model.q[todo])
    short = fragments(missing[:, todo], config.fragment_frames)
    # a fragment is distrusted beside the marker's longer runs; a marker seen only in fragments (every other frame
    # dropped) has nothing surer, and at 20 mm its fill strayed millimetres from the samples it passes between
    run = config.fragment_frames + 1  # frames in a row that make a run longer than a fragment
    seen = ~missing[:, todo]
    longer = (sliding_window_view(seen, run, axis=0).all(axis=2).any(axis=0) if len(seen) >= run
              else np.zeros(len(todo), dtype=bool))
    short &= longer[None, :]
    obs_var = np.where(short, (config.fragment_sd_mm * mm) ** 2, model.r_obs)
    if displaced is not None:  # measured with the displacement's spread: the fill does not bend to them
        obs_var = np.where(displaced[:, todo], (config.displacement_mm * mm) ** 2, obs_var)
    reset = None  # where the kind of spatial model changes, its error is drawn anew
    if config.bias_per_model:
        kind = np.ones(sp_sd.shape, dtype=int)  # the local PCA (and its reconstruction beside the gaps)
        if globbed is not None:
            kind[globbed[:, todo] & missing[:, todo]] = 2
        if wo is not None:
            kind[wo] = 3
        reset = model_changes(np.where(np.isfinite(sp_sd), kind, 0))
    inflate = np.ones_like(sp_sd)

    def mean_pass() -> tuple[np.ndarray, np.ndarray]:
        return smooth(obs, sp, white * np.sqrt(inflate), bias * np.sqrt(inflate), sub, obs_var=obs_var, reset=reset)

    for _ in range(config.reweight_passes):  # predictions far off the smoothed path weigh less, and it runs again
        mean, _ = mean_pass()
        with np.errstate(invalid="ignore"):
            z = np.sqrt(np.sum((sp - mean) ** 2, axis=2) / 3.0) / sp_sd
        bad = np.nan_to_num(z) > config.outlier
        if not bad.any():
            break
        inflate = np.where(bad, np.maximum(inflate, (z / config.outlier) ** 2 * 10.0), inflate)
    outliers[:, todo] = inflate > 1.0
    redo = np.zeros(0, dtype=int)  # the series whose reported sd exceeds somewhere the one the mean pass uses
    if report_sd is not None:
        rep = np.where(missing[:, todo], report_sd[:, todo], edge_sd[:, todo]) * np.sqrt(inflate)
        redo = np.flatnonzero((np.nan_to_num(rep) > np.nan_to_num(sp_sd * np.sqrt(inflate))).any(axis=0))

    def last_pass(which: str):
        if which == "mean":
            return mean_pass()
        # a Kalman smoother's variances do not depend on the measurements' values: the sd alone, with the reported sd
        return smooth(obs[:, redo], sp[:, redo], *split(rep[:, redo], redo), sub._replace(q=sub.q[redo]),
                      obs_var=obs_var[:, redo], reset=None if reset is None else reset[:, redo])[1]

    # the last mean pass and the variance pass read the same weights: at once, one process each (from FORK_FRAMES)
    (mean, sd), *variance = forked_map(last_pass, ["mean", "variance"][:1 + bool(len(redo))],
                                       jobs if len(obs) >= FORK_FRAMES else 1)
    if variance:
        sd[:, redo] = variance[0]
    fill[:, todo] = np.where(missing[:, todo, None], mean, positions[:, todo])
    sd_out[:, todo] = np.where(missing[:, todo], sd, 0.0)
    if believed is not None:
        noisy = short if displaced is None else short | displaced[:, todo]
        believed[0][:], believed[1][:] = fill, sd_out
        believed[0][:, todo] = np.where(noisy[..., None], mean, fill[:, todo])
        believed[1][:, todo] = np.where(noisy, sd, sd_out[:, todo])
    return fill, sd_out, outliers


def model_changes(sources: np.ndarray) -> np.ndarray:
    """(n_frames, n_series) bool: the frames where a series' spatial measurement comes from another kind of model
    than its last one before (``sources`` (n_frames, n_series) int, 0 where there is none)."""
    T, S = sources.shape
    at = np.where(sources > 0, np.arange(T)[:, None], -1)
    last = np.maximum.accumulate(at, axis=0)
    before = np.vstack([np.full((1, S), -1), last[:-1]])
    prev = np.where(before >= 0, sources[np.maximum(before, 0), np.arange(S)], 0)
    return (sources > 0) & (prev > 0) & (sources != prev)


def rough_variance(obs: np.ndarray, sp: np.ndarray) -> np.ndarray:
    """The white error variance per coordinate (n_frames, n_markers) of spatial predictions ``sp`` (n_frames,
    n_markers, 3; NaN: none), measured from their own roughness: a white error of variance s^2 adds 6 s^2 to the
    mean square per coordinate of a second difference, so s^2 = max(0, |d2 sp|^2 / 3 - a^2) / 6 with a^2 the
    marker's mean square observed second difference per coordinate (``obs`` (n_frames, n_markers, 3), NaN =
    missing); each sample takes the largest of the three second differences it enters (0 where none is defined).
    A smooth prediction adds nothing; one that jumps from frame to frame is weighed as the noise it is."""
    def second(x: np.ndarray) -> np.ndarray:
        out = np.full(x.shape[:2], np.nan)
        out[1:-1] = np.sum((x[2:] - 2.0 * x[1:-1] + x[:-2]) ** 2, axis=2) / 3.0
        return out

    observed = second(obs)
    seen = np.isfinite(observed)
    true2 = np.where(seen, observed, 0.0).sum(axis=0) / np.maximum(seen.sum(axis=0), 1)  # 0 where none is seen
    ex = np.nan_to_num(np.maximum(second(sp) - true2, 0.0)) / 6.0
    out = ex.copy()
    out[1:] = np.maximum(out[1:], ex[:-1])
    out[:-1] = np.maximum(out[:-1], ex[1:])
    return out
