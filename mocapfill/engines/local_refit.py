"""Stage 4 of the default: the local models refitted on the completed take, one EM-style imputation step.

The first pass (:func:`.local_pca.reconstruct_local`) models each marker only on the neighbours observed where it
predicts; where a neighbour vanished with the marker, it loses that neighbour.  Once every marker has a fill and a
posterior sd (the smoother's), :func:`reconstruct_completed` fits one model per marker on all its near markers,
trusting a neighbour only where its fill is sure (``trust``), with the neighbours' uncertainty propagated through
the model's sensitivity (:func:`.local_pca.group_model`, the same local weighted PCA).  Beside it:
a model per part of the gaps where a left-out neighbour is seen (:func:`refit_parts`), per group of gap runs with
the same trusted neighbours (:func:`trusted_runs`, :func:`beside_blackouts`), and a segment model on the markers
observed throughout the gaps (:func:`segment_markers`, chosen by :func:`prefer_segment`); each a
:class:`RefitModel`, compared by :func:`predicted_variance`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..gaps import runs
from ..runtime.executor import forked_map
from .local_pca import (
    MIN_TRAIN_WANTED,
    edge_samples,
    empty_estimates,
    group_model,
    marker_weights,
    reference_rows,
)
from .weighted_pca import (
    MIN_TRAINING_FRAMES,
    distance_spreads_to,
    distances_to,
    pattern_groups,
    ranked_groups,
)


def segment_markers(near: np.ndarray, dist: np.ndarray, gap_missing: np.ndarray, radius: float) -> np.ndarray:
    """The markers of ``near`` (n,) within ``radius`` of the target (``dist`` (n_markers,), data units) that are
    observed in every frame of its gaps (``gap_missing`` (n_gap_frames, n_markers) bool), in ``near``'s order:
    the body segment it rides on, as far as the capture shows it during the gaps."""
    seen = ~gap_missing[:, near].any(axis=0)
    return near[(dist[near] <= radius) & seen]


def predicted_variance(rms: float, off: np.ndarray | None) -> float:
    """A model's predicted variance per coordinate over some gap frames: its cross-validated ``rms`` squared times
    the mean of ``off`` (n,), how far each frame's pose lies off the poses it learnt from (None: 1)."""
    return rms ** 2 * (1.0 if off is None else float(np.mean(off)))


class RefitModel(NamedTuple):
    """One refit model of a marker (:func:`reconstruct_completed`): its predictors ``near`` (p,), training frames
    ``train`` (n,), reconstruction ``est`` (n + n_group, 3) and ``leverage`` (n + n_group,) of the training then
    the ``group`` (n_group,) frames, cross-validated ``rms``, predictor sensitivity ``sens`` (n_markers,),
    pose-residual factor ``off`` (n_group,) or None, whether it is the segment model, and the widths'
    ``disagreement`` (n + n_group,) (:func:`group_model`) or None."""

    group: np.ndarray
    near: np.ndarray
    train: np.ndarray
    est: np.ndarray
    leverage: np.ndarray
    rms: float
    sens: np.ndarray
    off: np.ndarray | None
    segment: bool
    disagreement: np.ndarray | None = None


def prefer_segment(seg_rms: float, seg_off: np.ndarray, rms: float, off: np.ndarray) -> bool:
    """Whether the segment model predicts a marker's gaps in place of its neighbourhood model.

    rms: each model's cross-validated RMS per coordinate; off (n_gap_frames,): how far each gap frame's pose lies
    off the poses the model learnt from (:func:`group_model`'s ``extrapolation``, the scale of a multivariate t's
    conditional variance).  The segment model is preferred where it extrapolates less (smaller mean ``off``) and
    its predicted variance, rms^2 times the mean ``off``, is smaller.  Why: cross-validation holds out blocks of the
    training frames, which in a short take are all of one phase, so it cannot see that a model of 40 predictors
    fitted on 44 frames of a stance extrapolates badly into the swing (the short walk: an ankle 30.7 mm off with
    them, 3.0 mm with its four foot markers); the pose residual can.
    """
    if not (np.isfinite(seg_rms) and np.isfinite(rms) and seg_rms > 0 and rms > 0):
        return False
    return (float(np.mean(seg_off)) < float(np.mean(off))
            and predicted_variance(seg_rms, seg_off) < predicted_variance(rms, off))


def reconstruct_completed(
    positions: np.ndarray,
    completed: np.ndarray,
    completed_std: np.ndarray,
    *,
    scales: tuple[float, ...],
    align_scale: float,
    missing_weight: float = 0.02,
    normalise: bool = True,
    folds: int = 5,
    knn: int = 10,
    reach: float = 3.0,
    max_predictors: int | None = None,
    edge_frames: int = 0,
    reference: np.ndarray | None = None,
    leverage_weight: float = 1.0,
    trust: float | None = None,
    reference_weights: np.ndarray | None = None,
    used_references: list | None = None,
    extrapolation: np.ndarray | None = None,
    segment: float | None = None,
    segment_used: np.ndarray | None = None,
    parts: int = 1,
    untrusted: tuple[np.ndarray, np.ndarray] | None = None,
    untrusted_used: np.ndarray | None = None,
    disagreement: np.ndarray | None = None,
    run_scales: tuple[float, ...] | None = None,
    run_knn: int = 0,
    run_max_rms: float = np.inf,
    rigid_align: float | None = None,
    reference_known: np.ndarray | None = None,
    jobs: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The local model refitted on a completed take (one EM-style imputation step).

    positions (n_frames, n_markers, 3) the input, NaN = missing; completed the same with the missing samples
    estimated (NaN for markers never observed), completed_std (n_frames, n_markers) their std per coordinate (0 where
    observed).  For each marker with gaps, ONE model whose predictors are all its near markers (within ``reach``
    times the largest width), trained on every frame where the marker is observed (the neighbours' missing samples
    taken from ``completed``), predicts all its missing samples; the predictors' uncertainty is propagated into the
    prediction's (``sensitivity`` of :func:`group_model`; ``max_predictors`` as in :func:`reconstruct_local`).
    reference (n, n_markers, 3) or None: frames of other takes added to the training frames where the marker and its
    predictors are finite, the marker a target only where ``reference_known`` (n, n_markers) bool says a reference
    observes it (default: where finite; a completed reference's other samples are predictors only).  Returns
    estimate (n_frames, n_markers, 3) and std (n_frames, n_markers) at the missing samples (NaN elsewhere and where
    no model could be fitted), and the reconstruction / std at up to ``edge_frames`` observed frames either side of
    each gap.
    ``leverage_weight`` scales how much a frame's leverage grows its std (1: as :func:`reconstruct_local`).
    ``trust`` (data units) or None: when given, only neighbours whose RMS completed std over the marker's gap frames
    is at most ``trust`` are predictors: a neighbour that vanished with the marker (filled, uncertain) does not steer
    its prediction, and the cross-validated error is that of the markers still known there.
    ``reference_weights`` (n,) in [0, 1] or None (every reference frame counts as the capture's own): each reference
    frame's weight as a training row, and each model keeps the references only where they lower its cross-validated
    error on the capture's own frames (as in :func:`reconstruct_local`); whether each model kept them is appended to
    ``used_references`` (a list) when given.  ``extrapolation`` (n_frames, n_markers) or None: when given, receives
    at each estimated sample how far its pose lies off the poses its model learnt from (:func:`group_model`).
    ``segment`` (data units) or None: beside each marker's neighbourhood model, a segment model on the markers within
    this distance that are observed throughout the marker's gaps (:func:`segment_markers`; at least 3), with its own
    local frame, predicts in its place where :func:`prefer_segment` says so; ``segment_used`` (n_frames, n_markers)
    bool or None receives where it did.  ``parts`` (with ``trust``): a marker's gap frames are split into at most
    this many parts by which left-out neighbours are observed there (:func:`refit_parts`); a part where one is seen
    gets its own model with it, which predicts there in place of the whole-gap model where its predicted variance
    (CV rms^2 times the mean pose-residual factor) is the smaller and it has ``MIN_TRAIN_WANTED`` training frames
    (reference frames count); only beside a whole-gap model (1: one model per marker).
    ``untrusted`` (with ``trust``): (take, std) shaped as ``completed`` / ``completed_std``, or None: a marker with
    fewer than 3 trusted neighbours (on a capture with gaps everywhere, most) gets one model on every candidate
    instead of none, its neighbours read from ``take`` with variance ``std**2`` (the smoother's estimates where it did
    not take an observed sample as exact: a flickering neighbour's one-frame fragment is often the take's worst
    sample), and it predicts only at the gap frames where one of its predictors is observed; ``untrusted_used``
    (n_markers,) bool or None receives which markers got one.  ``disagreement`` (n_frames, n_markers) or None
    receives at each estimated sample the variance per coordinate of its model's widths about their mix
    (:func:`group_model`; 0 for a segment model, which has one width).  ``run_scales`` (with ``trust``) or None: a
    marker left without a whole-gap model (fewer than 3 neighbours trusted over all its gaps, or too few training
    frames) gets one model with these widths and ``run_knn`` nearest poses per group of its gap runs with the same
    trusted neighbours over the run (:func:`trusted_runs`, at most ``parts`` groups), each kept where its
    cross-validated rms is at most ``run_max_rms`` (data units): a neighbour that vanished with the marker in one
    gap no longer leaves every other gap without a model; a gap run that runs into a whole-body blackout, where
    nothing is trusted over the run, is judged again on its frames outside the blackout (:func:`beside_blackouts`),
    its models kept only within ``trust``.  ``jobs`` and ``rigid_align`` (the marker's neighbourhood models) as in
    :func:`reconstruct_local`.
    """
    n_frames, n_markers, _ = positions.shape
    missing = np.isnan(positions).any(axis=2)
    row_weight = None
    if reference is not None and reference_weights is not None:
        reference, row_weight, reference_known = reference_rows(reference, reference_weights, n_frames,
                                                                reference_known)
    data = completed if reference is None else np.concatenate([completed, reference])
    var = np.nan_to_num(completed_std, nan=np.inf) ** 2
    if reference is not None:
        var = np.concatenate([var, np.zeros(reference.shape[:2])])
    if reference is not None and reference_known is None:
        reference_known = np.isfinite(reference).all(axis=2)
    known = np.concatenate([~missing, reference_known]) if reference is not None else ~missing
    finite = np.isfinite(data).all(axis=2)
    estimate, std, info = empty_estimates(n_frames, n_markers)
    known_data = np.where(known[..., None], data, np.nan)
    known_distances = distances_to(known_data)  # once, not per marker
    known_spreads = distance_spreads_to(known_data) if rigid_align is not None else None
    blackout = missing.all(axis=1)  # frames where nothing is observed
    if untrusted is not None:
        u_data = np.array(untrusted[0], dtype=np.float64) if reference is None else np.concatenate(
            [untrusted[0], reference])
        u_var = np.nan_to_num(untrusted[1], nan=np.inf) ** 2
        if reference is not None:
            u_var = np.concatenate([u_var, var[n_frames:]])

    def refit(m: int, group: np.ndarray, near: np.ndarray, dist: np.ndarray, weights: list[np.ndarray],
              align_weight: np.ndarray, min_train: int = MIN_TRAINING_FRAMES, data: np.ndarray = data,
              refs: list | None = None, max_rms: float | None = None, scales: tuple[float, ...] = scales,
              knn: int = knn) -> RefitModel | None:
        """One model of marker ``m`` on the predictors ``near`` for its missing ``group`` frames (None: fewer than
        3 predictors or ``min_train`` training frames, or a cross-validated rms not at most ``max_rms``): its
        reconstruction of the training then the group's frames, and what :func:`store` and :func:`prefer_segment`
        need (``data``: the take its predictors are read from; ``weights`` one per width in ``scales``)."""
        train = np.flatnonzero(known[:, m] & finite[:, near].all(axis=1)) if len(near) else np.zeros(0, int)
        if len(near) < 3 or len(train) < min_train:
            return None
        close = segment_markers(near, dist, missing[group], segment) if segment else near[:0]
        with_segment = 3 <= len(close) < len(near)
        off: list | None = [] if extrapolation is not None or segment else None
        spread: list | None = [] if disagreement is not None else None
        fitted = group_model(
            data, m, group, near, train, weights, align_weight, dist, scales, reach=reach,
            max_predictors=max_predictors, normalise=normalise, folds=folds, knn=knn, row_weight=row_weight,
            used_references=refs if row_weight is not None and used_references is not None else None,
            extrapolation=off, disagreement=spread, split_by_time=True,
            max_rms=None if with_segment else max_rms)  # (a segment model may still pass where this one fails)
        if fitted is None:
            return None
        est_all, leverage, rms_mix, _, _, _, sens = fitted
        fit = RefitModel(group, near, train, est_all, leverage, rms_mix, sens, off[0] if off else None, False,
                         spread[0] if spread else None)
        if with_segment:
            seg_weights, seg_align = marker_weights(dist, m, (segment,), align_scale, missing_weight)
            seg_off: list = []
            seg_spread: list | None = None if spread is None else []
            seg_all, seg_leverage, seg_rms, _, _, _, seg_sens = group_model(
                data, m, group, close, train, seg_weights, seg_align, dist, (segment,), reach=np.inf,
                normalise=normalise, folds=folds, knn=knn, row_weight=row_weight, extrapolation=seg_off,
                disagreement=seg_spread, split_by_time=True)
            if prefer_segment(seg_rms, seg_off[0], rms_mix, fit.off):
                fit = fit._replace(est=seg_all, leverage=seg_leverage, rms=seg_rms, sens=seg_sens, off=seg_off[0],
                                   segment=True, disagreement=seg_spread[0] if seg_spread else None)
        return None if max_rms is not None and not fit.rms <= max_rms else fit

    def store(m: int, fit: RefitModel, var: np.ndarray = var) -> None:
        """Write one model's prediction of marker ``m`` at its group's frames (and at the observed frames next to
        them) into the outputs (``var``: its predictors' variances)."""
        group, near, train, n_train = fit.group, fit.near, fit.train, len(fit.train)
        if segment_used is not None:
            segment_used[group, m] = fit.segment  # a part's model replaces the whole-gap one's flag too
        if extrapolation is not None:
            extrapolation[group, m] = fit.off
        if disagreement is not None:
            disagreement[group, m] = fit.disagreement[n_train:]
        with np.errstate(invalid="ignore"):
            spread = var[group][:, near] @ fit.sens[near]  # propagated predictor variance (n_group,)
        estimate[group, m] = fit.est[n_train:]
        std[group, m] = np.sqrt(fit.rms ** 2 * (1.0 + leverage_weight * fit.leverage[n_train:]) + spread)
        if edge_frames:
            own = train < n_frames
            with np.errstate(invalid="ignore"):
                spread_t = var[train[own]][:, near] @ fit.sens[near]
            edge_samples(info, m, group, train[own], fit.est[:n_train][own],
                         np.sqrt(fit.rms ** 2 * (1.0 + leverage_weight * fit.leverage[:n_train][own]) + spread_t),
                         edge_frames)

    def models(m: int) -> tuple[list[tuple[RefitModel, bool]], list]:
        """Marker ``m``'s models, in the order :func:`store` writes them (a part's model over the whole-gap one's),
        each with whether it is an untrusted one; and the references' use they appended (pure: no output touched,
        so the markers may be fitted in any process)."""
        refs: list = []
        gap_frames = np.flatnonzero(missing[:, m])
        dist = known_distances(m)
        weights, align_weight = marker_weights(dist, m, scales, align_scale, missing_weight,
                                               None if rigid_align is None else known_spreads(m), rigid_align or 0.0)
        sure = np.ones(n_markers, dtype=bool)
        if trust is not None:
            # a neighbour filled with little certainty during this marker's gaps (it vanished with it) is no
            # predictor: the model and its cross-validated error are those of the markers still known there
            sure = trusted_over(var[gap_frames], trust)
        others = np.flatnonzero(np.arange(n_markers) != m)
        candidates = others[np.isfinite(dist[others]) & (dist[others] <= reach * max(scales))
                            & finite[gap_frames][:, others].all(axis=0)]
        candidates = candidates[np.argsort(dist[candidates], kind="stable")]
        trusted = candidates[sure[candidates]]
        if untrusted is not None and trust is not None and len(trusted) < 3:
            own = u_data[:n_frames, m].copy()
            u_data[:n_frames, m] = data[:n_frames, m]  # the marker's own samples stay as observed: its targets
            try:  # (put back before returning: the next marker, here or in a worker, reads the take as it was)
                fit = refit(m, gap_frames, candidates, dist, weights, align_weight, data=u_data, refs=refs)
            finally:
                u_data[:n_frames, m] = own
            return ([] if fit is None else [(fit, True)]), refs
        whole = refit(m, gap_frames, trusted, dist, weights, align_weight, refs=refs)
        if whole is None:
            if run_scales is None or trust is None:
                return [], refs
            run_weights, run_align = marker_weights(dist, m, run_scales, align_scale, missing_weight)
            fits = [refit(m, frames, near, dist, run_weights, run_align, refs=refs, max_rms=run_max_rms,
                          scales=run_scales, knn=run_knn)
                    for frames, near in trusted_runs(missing[:, m], var, candidates, trust, parts)]
            # a gap that runs into a whole-body blackout, judged on its frames outside it; kept only as sure as a
            # trusted neighbour (weaker models there drew other markers off through the bones)
            fits += [refit(m, frames, near, dist, run_weights, run_align, refs=refs, max_rms=trust,
                           scales=run_scales, knn=run_knn)
                     for frames, near in beside_blackouts(missing[:, m], var, candidates, trust, parts,
                                                          blackout)]
            return [(fit, False) for fit in fits if fit is not None], refs
        out = [(whole, False)]
        # the parts of the gaps where a left-out neighbour is seen: a model of their own with it, in place of the
        # whole-gap model's where it predicts the smaller variance there (CV rms^2 times the mean pose-residual
        # factor); only beside a whole-gap model (a marker no trusted neighbour predicts is not handed to the few
        # that are seen now and then: a wheelchair marker predicted from an arm's was 600 mm off)
        for group, near in refit_parts(missing, gap_frames, candidates, sure[candidates], parts):
            if len(near) == len(trusted):
                continue  # no left-out neighbour seen here: the whole-gap model's
            # a model on few frames: its cross-validated error cannot tell the two apart (checked before the fit)
            fit = refit(m, group, near, dist, weights, align_weight, min_train=MIN_TRAIN_WANTED, refs=refs)
            if fit is None:
                continue
            whole_off = None if whole.off is None else whole.off[np.searchsorted(gap_frames, group)]
            if predicted_variance(fit.rms, fit.off) < predicted_variance(whole.rms, whole_off):
                out.append((fit, False))
        return out, refs

    # (``known`` holds the references' rows: a marker the take never shows is refitted where a reference shows it)
    todo = np.flatnonzero(missing.any(axis=0) & known.any(axis=0))
    for m, (fits, refs) in zip(todo, forked_map(models, todo, jobs, cost=missing[:, todo].sum(axis=0))):
        if used_references is not None:
            used_references.extend(refs)
        for fit, untrusted_fit in fits:
            if not untrusted_fit:
                store(m, fit)
                continue
            store(m, fit, u_var)
            # where none of its predictors is observed it would play the smoother's own guesses back: no
            # prediction there (a whole-body blackout to the end of btk's Gait.c3d)
            blind = fit.group[~known[fit.group][:, fit.near].any(axis=1)]
            estimate[blind, m] = np.nan
            std[blind, m] = np.nan
            if untrusted_used is not None:
                untrusted_used[m] = True
    return estimate, std, info["edge_estimate"], info["edge_std"]


def trusted_over(var: np.ndarray, trust: float) -> np.ndarray:
    """(k,) bool: which of k neighbours the refit trusts over some frames, var (n, k) their completed variance per
    coordinate there (0 observed, inf without a value): a mean variance of at most ``trust ** 2``."""
    with np.errstate(invalid="ignore"):
        return np.nan_to_num(var.mean(axis=0), nan=np.inf) <= trust ** 2


def trusted_runs(gaps: np.ndarray, var: np.ndarray, candidates: np.ndarray, trust: float, max_groups: int
                 ) -> list[tuple[np.ndarray, np.ndarray]]:
    """One marker's gap runs grouped by the neighbours trusted over each: [(frames, predictors)].

    gaps (n_frames,) bool, the marker's missing frames; var (n_frames, n_markers) the completed take's variance per
    coordinate (0 observed, inf where it has no value); candidates (p,) its near markers, nearest first.  A
    candidate is trusted over a run as :func:`trusted_over` says; runs with fewer than 3 are left out, runs with the
    same trusted candidates form one group.  At most ``max_groups`` groups (each a model to fit): the
    ``max_groups - 1`` with the most frames keep theirs, the other runs form one group on the candidates trusted over
    every one of them (left out if fewer than 3) (:func:`~.weighted_pca.ranked_groups`).  Frames ascending,
    predictors in ``candidates``' order.
    """
    spans = [(start, length, trusted_over(var[start:start + length][:, candidates], trust))
             for start, length in runs(gaps)]
    spans = [span for span in spans if span[2].sum() >= 3]
    if not spans:
        return []
    untrusted = ~np.array([sure for _, _, sure in spans])
    lengths = np.array([length for _, length, _ in spans])
    return [(np.concatenate([np.arange(spans[i][0], spans[i][0] + spans[i][1]) for i in items]), candidates[~key])
            for items, key in ranked_groups(untrusted, lengths, max_groups) if (~key).sum() >= 3]


def beside_blackouts(gaps: np.ndarray, var: np.ndarray, candidates: np.ndarray, trust: float, max_groups: int,
                     blackout: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The gap runs :func:`trusted_runs` leaves out (fewer than 3 neighbours trusted over the run) because they run
    into a whole-body blackout (``blackout`` (n_frames,) bool: no marker observed), judged again on their frames
    outside it, grouped as :func:`trusted_runs` groups: [(frames, predictors)]."""
    kept = np.zeros_like(gaps)
    for start, length in runs(gaps):
        run = slice(start, start + length)
        if blackout[run].any() and trusted_over(var[run][:, candidates], trust).sum() < 3:
            kept[run] = True
    return trusted_runs(kept & ~blackout, var, candidates, trust, max_groups) if kept.any() else []


def refit_parts(missing: np.ndarray, gap_frames: np.ndarray, candidates: np.ndarray, sure: np.ndarray,
                max_parts: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split one marker's gap frames for the refit: [(frames, predictors)], each part one model.

    missing (n_frames, n_markers); gap_frames (n,) ascending; candidates (p,) the near markers, nearest first;
    sure (p,) bool: trusted over all the gap frames (observed, or filled with a small sd).  The candidates the
    whole-gap model leaves out may be observed during part of the gaps (a thigh marker seen for the first half of an
    ankle's gap, missing with it for the second): the frames are grouped by which of those are observed
    (:func:`~.weighted_pca.pattern_groups`, at most ``max_parts`` groups), and each part's predictors are the trusted
    candidates plus those observed throughout it.  Where every candidate is trusted, or ``max_parts`` is 1, one part
    with the trusted candidates.
    """
    trusted = candidates[sure]
    left_out = candidates[~sure]
    if max_parts <= 1 or not len(left_out):
        return [(gap_frames, trusted)]
    out = []
    for frames, seen in pattern_groups(missing, gap_frames, left_out, max_parts):
        near = candidates[np.isin(candidates, np.concatenate([trusted, seen]))]  # nearest first, as candidates
        out.append((frames, near))
    return out
