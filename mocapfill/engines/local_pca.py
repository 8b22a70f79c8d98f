"""Weighted PCA in a moving local frame: the published distance-weighted PCA, made rotation-invariant.

Gløersen & Federolf's reconstruction (:mod:`.pca`) regresses a missing marker linearly on its neighbours in the
laboratory frame.  A linear map cannot follow a rotation, so when the body turns, jumps or flips the estimate drifts
even for a marker rigidly attached to observed neighbours (a back marker during a somersault was off by 15 cm).
Here, for each marker with gaps and each pattern of other missing markers during them:

1. the observed neighbours are weighted by a Gaussian of their mean distance to the missing marker (200 mm);
2. per frame, their weighted centroid is removed and the weighted best rotation (Kabsch, a batched 3 x 3 SVD) onto
   a reference shape of the neighbourhood is applied, so the neighbourhood stands still;
3. the published weighted PCA reconstruction runs on these local coordinates (the target's local position is nearly
   constant for a rigidly attached marker, and varies smoothly with joint angles otherwise), with three changes
   that each measured better on the benchmark's trials: the number of components is the one with the smallest
   leave-one-block-out error (one eigendecomposition per fold serves every truncation) instead of the 99 % rule;
   three weight widths (150, 200, 300 mm) are averaged by their inverse cross-validated variance; and the mean
   residual of the k = 10 nearest training poses (in the weighted predictor space) is added, which captures what a
   linear map misses when a movement repeats (the tennis serves);
4. the estimate is rotated and translated back, and the residual observed at the frames just outside each gap is
   carried into it as an Ornstein-Uhlenbeck bridge (correlation time 30 frames), so fills meet the observations.

The uncertainty is the cross-validated RMS (rotations preserve distances), grown with the frame's leverage and
shrunk next to the gap's ends by the bridge's conditional variance; per coordinate, in data units.  On the
benchmark's trials (20 per clip and protocol, after the default's bone refinement) the median ratio of the actual
per-coordinate RMS error to it was 0.7-1.0, with 10th-90th percentiles 0.3-1.9: roughly calibrated, a little
cautious.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import MethodError
from ..gaps import end_blend, members, runs, unique_rows
from ..methods.base import FillResult, finish
from ..runtime.blas import single_blas_thread
from ..runtime.executor import forked_map
from ..units import length_factor
from .body_frame import nearest_rotation
from .weighted_pca import (
    MIN_TRAINING_FRAMES,
    PCAModel,
    cv_curve,
    weighted_sums,
    linear_fallback,
    fit_model,
    gaussian_weights,
    distance_spreads_to,
    distances_to,
    mean_distances,
    pattern_groups,
    predict,
    predictor_residual,
)


#: Widths of the PCA distance weights (one reconstruction each, averaged) and of the alignment weights, in mm.
DEFAULT_SCALES_MM = np.array([150.0, 200.0, 300.0])
DEFAULT_ALIGN_MM = 200.0
#: Training frames a local model wants before it gives up predictors (nearest kept): when many markers are missing
#: at once, few frames have all of a marker's neighbours observed, and a model fitted to ten of them is worse than
#: one on fewer, nearer neighbours fitted to a hundred.
MIN_TRAIN_WANTED = 100
#: Nearest observed candidates per frame that define the groups of such frames.
NEAREST_OBSERVED = 8


def kabsch_rotations(shapes: np.ndarray, reference: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per-frame rotations R (n, 3, 3) minimising sum_j w_j |shapes[t, j] R - reference[j]|^2.

    shapes (n, p, 3) and reference (p, 3) are already centred on their weighted centroids; weights (p,).
    Row-vector convention: an aligned point is ``x @ R``.
    """
    # the best proper rotation of the weighted cross-covariance (n, 3, 3): one (3 n, p) x (p, 3) product instead of
    # n stacked ones (the same sums, bit for bit with the OpenBLAS measured; half the cost)
    n, p = shapes.shape[:2]
    cross = (np.swapaxes(shapes, 1, 2).reshape(3 * n, p) @ (weights[:, None] * reference)).reshape(n, 3, 3)
    return nearest_rotation(cross)


def local_frames(
    positions: np.ndarray, frames: np.ndarray, anchors: np.ndarray, weights: np.ndarray, reference_frames: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted centroids (n, 3) and rotations (n, 3, 3) that bring ``anchors`` to a common pose in ``frames``.

    positions (n_frames, n_markers, 3); anchors (p,) marker indices observed in every one of ``frames``; weights
    (p,); the reference shape is the (one-pass) Procrustes mean over ``reference_frames`` (positions within
    ``frames``).
    """
    pts = positions[np.asarray(frames)[:, None], anchors]  # (n, p, 3), without copying the other markers first
    wsum = weights.sum()
    centre = np.einsum("tjc,j->tc", pts, weights) / wsum
    shapes = pts - centre[:, None, :]
    # One Procrustes pass for the reference: align the training shapes to the middle one and average them (a second
    # pass changed no benchmark figure).
    reference = shapes[reference_frames[len(reference_frames) // 2]]
    rot = kabsch_rotations(shapes[reference_frames], reference, weights)
    reference = (shapes[reference_frames] @ rot).mean(axis=0)
    reference -= (weights[:, None] * reference).sum(axis=0) / wsum
    rot = kabsch_rotations(shapes, reference, weights)
    return centre, rot


def edge_shift(
    resid_before: np.ndarray | None, resid_after: np.ndarray | None, length: int, tau: float | str
) -> tuple[np.ndarray, np.ndarray]:
    """Residual to add inside one gap so the reconstruction meets the observations at both ends.

    ``resid_before`` / ``resid_after`` (3,) are observed minus reconstructed at the last frame before / first frame
    after the gap (None when that side has no observation); ``length`` frames.  With a number ``tau`` (frames) the
    residual is modelled as an Ornstein-Uhlenbeck process (correlation exp(-d / tau)) and the shift is its
    conditional mean given the two ends, so it relaxes towards zero in the middle of long gaps; ``"linear"``
    interpolates the two ends.  Returns the shift (length, 3) and the factor (length,) by which the residual's
    variance shrinks given the ends (1 far from any observation, near 0 next to one).
    """
    d_b = np.arange(1, length + 1, dtype=float)  # frames from the last observation before
    d_a = length + 1 - d_b  # frames to the first observation after
    if tau == "linear":
        shift = end_blend(resid_before, resid_after, length)
        return (np.zeros((length, 3)) if shift is None else shift), np.ones(length)
    tau = float(tau)
    rho_b, rho_a = np.exp(-d_b / tau), np.exp(-d_a / tau)
    if resid_before is not None and resid_after is not None:
        rho_t = np.exp(-(length + 1) / tau)
        denom = 1.0 - rho_t ** 2
        cb = (rho_b - rho_a * rho_t) / denom
        ca = (rho_a - rho_b * rho_t) / denom
        shift = cb[:, None] * resid_before + ca[:, None] * resid_after
        explained = cb * rho_b + ca * rho_a  # variance explained by the two ends (regression of OU on them)
    elif resid_before is not None:
        shift, explained = rho_b[:, None] * resid_before, rho_b ** 2
    elif resid_after is not None:
        shift, explained = rho_a[:, None] * resid_after, rho_a ** 2
    else:
        return np.zeros((length, 3)), np.ones(length)
    return shift, np.clip(1.0 - explained, 0.0, 1.0)


def edge_corrected(
    observed: np.ndarray, predicted: np.ndarray, frames: np.ndarray, *, tau: float | str = 30.0
) -> tuple[np.ndarray, np.ndarray]:
    """Predictions in ``frames`` shifted to meet the observations around each run of missing frames.

    observed (n_frames, 3) one marker, NaN = missing; predicted (n_frames, 3) its reconstruction wherever it exists
    (including the observed frames next to the gaps); frames (g,) the missing frames to correct.  Returns the
    corrected (g, 3) and the variance factor (g,) from :func:`edge_shift`.
    """
    n_frames = len(observed)
    out = predicted.copy()
    factor = np.ones(n_frames)
    gap = np.zeros(n_frames, dtype=bool)
    gap[frames] = True
    resid = observed - predicted  # NaN inside gaps and where there is no prediction
    for start, length in runs(gap):
        stop = start + length
        rb = resid[start - 1] if start > 0 and np.isfinite(resid[start - 1]).all() else None
        ra = resid[stop] if stop < n_frames and np.isfinite(resid[stop]).all() else None
        shift, fac = edge_shift(rb, ra, length, tau)
        out[start:stop] = predicted[start:stop] + shift
        factor[start:stop] = fac
    return out[frames], factor[frames]


def knn_correction(model, flat: np.ndarray, est_local: np.ndarray, n_train: int, k: int) -> np.ndarray:
    """Nonlinear correction of the linear reconstruction: the mean training residual of the k nearest poses.

    flat (n, 3 n_markers) local coordinates with the ``n_train`` training frames first; est_local (n, 3) the
    linear reconstruction of the target.  Poses are compared in the model's weighted, normalised predictor space
    (the target's own columns zeroed), so near markers dominate as in the reconstruction.  Returns (n, 3): zero on
    the training frames, the neighbours' mean residual on the others.
    """
    nt = model.n_target
    z = (flat[:, model.columns] - model.mean) / model.scale * model.weight
    z[:, :nt] = 0.0
    zt, zg = z[:n_train], z[n_train:]
    resid = flat[:n_train, model.columns[:nt]] - est_local[:n_train]
    k = int(min(k, n_train))
    out = np.zeros_like(est_local)
    if len(zg):
        out[n_train:] = resid[nearest_rows(zg, zt, k)].mean(axis=1)
    return out


#: Query rows whose distances are formed and searched at once in :func:`nearest_rows` (the blocks stay in cache).
_QUERY_CHUNK = 64


def nearest_rows(query: np.ndarray, data: np.ndarray, k: int) -> np.ndarray:
    """Indices (g, k) of the ``k`` rows of ``data`` (n, q) nearest each row of ``query`` (g, q), in no order.

    The squared distances are (|x|^2 + |y|^2) - 2 x.y, the numbers of that expression over all rows at once, formed
    for a block of query rows at a time; the selection is exactly that of ``np.argpartition(d2, k - 1,
    axis=1)[:, :k]`` as a set.  Rounding to float32 keeps the order of the distances (ties can only be added), so
    the k-th smallest float32 value bounds the k nearest: a row with exactly k distances at or below it has found
    them; a row with more (a float32 or an exact tie) takes the float64 argpartition.
    """
    g, n = len(query), len(data)
    if k >= n:
        return np.broadcast_to(np.arange(n), (g, n))
    qn = (query ** 2).sum(axis=1)
    dn = (data ** 2).sum(axis=1)
    cross = (2.0 * query) @ data.T  # one product (blocks of it would each repack ``data``)
    near = np.empty((g, k), dtype=np.intp)
    for s in range(0, g, _QUERY_CHUNK):
        d2 = cross[s:s + _QUERY_CHUNK]
        np.subtract(qn[s:s + _QUERY_CHUNK, None] + dn, d2, out=d2)
        d32 = d2.astype(np.float32)
        inside = d32 <= np.partition(d32, k - 1, axis=1)[:, k - 1:k]
        exact = inside.view(np.uint8).sum(axis=1, dtype=np.int32) == k
        out = near[s:s + _QUERY_CHUNK]
        if exact.all():  # (flatnonzero: a 2-d nonzero costs ten times more)
            out[:] = (np.flatnonzero(inside) % n).reshape(-1, k)
            continue
        out[exact] = (np.flatnonzero(inside[exact]) % n).reshape(-1, k)
        tied = np.flatnonzero(~exact)
        out[tied] = np.argpartition(d2[tied], k - 1, axis=1)[:, :k]
    return near


def _anchor_set(predictors: np.ndarray, weight: np.ndarray, min_anchors: int = 3, floor: float = 1e-3) -> np.ndarray:
    """Predictors that define the local frame: those with a weight above ``floor`` of the largest, at least 3."""
    w = weight[predictors]
    order = np.argsort(w)[::-1]
    keep = w >= floor * w.max()
    if keep.sum() < min_anchors:
        keep[order[:min_anchors]] = True
    return predictors[keep]


def _training(missing: np.ndarray, m: int, predictors: np.ndarray) -> np.ndarray:
    """Frames (ascending) where marker ``m`` and all ``predictors`` are observed; missing (n_frames, n_markers)."""
    return np.flatnonzero(~missing[:, m] & ~missing[:, predictors].any(axis=1))


def nearest_with_training(missing: np.ndarray, m: int, candidates: np.ndarray, wanted: int,
                          row_weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The longest nearest-first prefix of ``candidates`` that leaves ``wanted`` training frames for marker ``m``.

    candidates (p,) sorted by distance to ``m``; missing (n_frames, n_markers).  Each added predictor can only remove
    training frames (a frame must have all of them observed), so the prefix lengths trade predictors for frames;
    at least three predictors are kept.  ``row_weight`` (n_frames,): what each frame counts for (reference frames
    count by their weight; default 1).  Returns (predictors (k,), training frames (n,)).
    """
    ok = ~missing[:, m][:, None] & np.logical_and.accumulate(~missing[:, candidates], axis=1)  # (n_frames, p)
    counts = ok.sum(axis=0) if row_weight is None else row_weight @ ok
    enough = np.flatnonzero(counts >= wanted)
    k = max(int(enough[-1]) + 1 if len(enough) else 0, min(3, len(candidates)))
    return candidates[:k], np.flatnonzero(ok[:, k - 1]) if k else np.flatnonzero(~missing[:, m])


def observed_groups(missing: np.ndarray, m: int, frames: np.ndarray, near: np.ndarray, max_patterns: int,
                    wanted: int, row_weight: np.ndarray | None = None
                    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Split marker ``m``'s gap ``frames`` into (frames, predictors, training frames) groups.

    near (p,) candidate predictors sorted by distance to ``m``; missing (n_frames, n_markers).  First the published
    split (:func:`~.pca.pattern_groups`: a group's predictors are the candidates observed in all its frames); a
    group that leaves fewer than ``wanted`` frames where the marker and all its predictors are observed (many
    markers missing at once, few or no complete frames) is split again by which of its nearest observed
    candidates each frame has, and each part keeps the nearest of them that still leave ``wanted`` training
    frames (:func:`nearest_with_training`): the model learns from incomplete frames, conditioning only on markers
    observed where it predicts.  ``row_weight`` (n_frames,): what each frame counts for (default 1).
    """
    out = []
    for group, predictors in pattern_groups(missing, frames, near, max_patterns):
        train = _training(missing, m, predictors)
        count = len(train) if row_weight is None else row_weight[train].sum()
        if count >= wanted and len(predictors) >= 3:
            out.append((group, predictors, train))
            continue
        # per frame, the nearest observed candidates (how many: those a prefix can afford in training frames)
        obs = ~missing[np.ix_(group, near)]
        rank = np.cumsum(obs, axis=1)
        pattern = obs & (rank <= NEAREST_OBSERVED)
        uniq, inverse, _ = unique_rows(pattern)
        for p, rows in enumerate(members(inverse, len(uniq))):
            part = group[rows]
            preds, train = nearest_with_training(missing, m, near[uniq[p]], wanted, row_weight)
            out.append((part, preds, train))
    return out


def edge_mask(group: np.ndarray, n_frames: int, width: int) -> np.ndarray:
    """(n_frames,) bool: the ``width`` frames before and after each run of the ascending frames ``group`` (both
    sides of every run, clipped to the take; a run's own frames only where another run's edge reaches them).

    Counted in one pass over the runs' boundaries, not a loop over the runs."""
    group = np.asarray(group)
    count = np.zeros(n_frames + 1, dtype=int)
    if len(group):
        new_run = np.flatnonzero(np.diff(group) != 1)
        starts = group[np.concatenate([[0], new_run + 1])]
        stops = group[np.concatenate([new_run, [len(group) - 1]])] + 1
        # +1 where an edge interval opens, -1 where it closes: [start - width, start) and [stop, stop + width)
        np.add.at(count, np.maximum(starts - width, 0), 1)
        np.add.at(count, starts, -1)
        np.add.at(count, stops, 1)
        np.add.at(count, np.minimum(stops + width, n_frames), -1)
    return np.cumsum(count[:n_frames]) > 0


def edge_samples(info: dict, m: int, group: np.ndarray, train: np.ndarray, est_train: np.ndarray,
                 std_train: np.ndarray, width: int) -> None:
    """Store the reconstruction at the training frames within ``width`` frames of each run of ``group`` (marker
    ``m``) in ``info["edge_estimate"]`` / ``info["edge_std"]``; est_train (n_train, 3), std_train (n_train,)."""
    n_frames = info["edge_std"].shape[0]
    keep = edge_mask(group, n_frames, width)[train]
    info["edge_estimate"][train[keep], m] = est_train[keep]
    info["edge_std"][train[keep], m] = std_train[keep]


def marker_weights(dist: np.ndarray, m: int, scales: tuple[float, ...], align_scale: float, missing_weight: float,
                   spread: np.ndarray | None = None, noise: float = 0.0) -> tuple[list[np.ndarray], np.ndarray]:
    """Gaussian weights (n_markers,) of every marker for target ``m``, one array per width in ``scales`` (the target
    itself weighs ``missing_weight``), and the alignment weights; dist (n_markers,) mean distances to ``m``.
    ``spread`` (n_markers,) or None: how much each marker's distance to ``m`` varies; given, the alignment weights
    are also :func:`rigidity_weights` of it (``noise`` as there)."""
    weights = []
    for width in scales:
        w = gaussian_weights(dist, width)
        w[m] = missing_weight
        weights.append(w)
    align = gaussian_weights(dist, align_scale)
    if spread is not None:
        align = align * rigidity_weights(spread, m, noise)
    return weights, align


def rigidity_weights(spread: np.ndarray, m: int, noise: float = 0.0) -> np.ndarray:
    """Weights (n_markers,) in (0, 1] of the markers that define marker ``m``'s local frame, by how rigidly each
    moves with it: s0^2 / (s^2 + s0^2), s (``spread``, (n_markers,)) the standard deviation of its distance to
    ``m`` (0 for a marker never seen with it).

    The Kabsch alignment's weights are inverse variances: a neighbour on the marker's own segment locates its frame
    to within its skin and camera noise, one across a joint only to within the joint's motion.  The scale s0 is the
    third smallest spread, so at least three markers weigh about the same (a frame needs three; one nearly rigid
    marker alone would leave it free to turn about that marker), and at least ``noise``, the spread the cameras'
    noise alone gives a distance (data units): spreads below it tell nothing about the body (a take where nothing
    moves).  All 1 where fewer than three spreads are known.
    """
    s = np.asarray(spread, dtype=float).copy()
    s[m] = np.nan
    known = np.sort(s[np.isfinite(s)])
    if len(known) < 3:
        return np.ones(len(s))
    s0 = max(float(known[2]), float(noise), 1e-12)
    return np.where(np.isfinite(s), s0 ** 2 / (np.nan_to_num(s) ** 2 + s0 ** 2), 0.0)


def reference_rows(reference: np.ndarray, weights: np.ndarray, n_frames: int, known: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference frames (n, n_markers, 3) that weigh anything, every training row's weight, and where they
    observe each marker.

    weights (n,) are clipped to [0, 1]; frames of weight 0 are dropped.  Returns the kept frames (k, n_markers, 3),
    the row weights (n_frames + k,): 1 for the capture's own n_frames rows, below 1 for every reference row (so
    the capture's own rows are those of weight 1, as :func:`_choose_rows` tells them apart), and ``known`` (n,
    n_markers) bool of the kept frames (default: where they are finite): a marker is a target only there, its other
    samples (completed references, :func:`mocapfill.references.completed_frames`) predictors only.
    """
    ref_w = np.clip(np.asarray(weights, dtype=np.float64), 0.0, 1.0)
    if ref_w.shape != (len(reference),):
        raise MethodError(f"reference_weights must have shape ({len(reference)},), got {ref_w.shape}")
    keep = ref_w > 0
    shown = np.isfinite(reference[keep]).all(axis=2)
    return (reference[keep], np.concatenate([np.ones(n_frames), np.minimum(ref_w[keep], 1.0 - 1e-9)]),
            shown if known is None else np.asarray(known, dtype=bool)[keep] & shown)


def _cols(markers: np.ndarray) -> list[int]:
    """Flattened coordinate columns of ``markers`` (3 per marker), as a list."""
    return (3 * np.asarray(markers, dtype=int)[:, None] + np.arange(3)).ravel().tolist()


def _choose_rows(flat: np.ndarray, tr: np.ndarray, own: np.ndarray, rw: np.ndarray | None, target: np.ndarray,
                 pred: np.ndarray, w: np.ndarray, normalise: bool, folds: int, residuals: bool = False,
                 times: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None, PCAModel | None]:
    """Training rows, their weights and the cross-validation curve of one model, with or without reference rows.

    flat (n, 3 n_markers) local coordinates; tr (n_train,) training rows; own (n_train,) bool, the capture's own
    rows (the others are reference frames, weights ``rw`` (n_train,)).  Without reference rows: every row, the
    plain curve.  With them: where the capture's own rows allow two held-out blocks, the model with references is
    scored on those blocks (references always in training) against the model on the capture's rows alone, and the
    better is kept; otherwise the references stay and every row is held out in turn.  The fourth value: the kept
    model's held-out predictor residual as a function of the number of components (``residuals``; else None).
    ``times`` (n_train,) or None: each row's frame, for :func:`~.weighted_pca.cv_curve`'s split of few rows.  The
    fifth: the kept rows' model with every component (:func:`~.weighted_pca.cv_curve`'s ``fitted``), or None
    without a curve.
    """
    def curve_of(rows, **kw):
        fitted: list = []
        out = cv_curve(flat, rows, target, pred, w, normalise=normalise, folds=folds, residuals=residuals,
                       times=None if times is None else times[rows], fitted=fitted, **kw)
        full = fitted[0] if fitted else None
        return (None, None, None) if out is None else (*out, full) if residuals else (out, None, full)

    if rw is None or own.all():
        return (tr, None, *curve_of(tr))
    enough = own.sum() >= 2 * MIN_TRAINING_FRAMES
    curve, resid, full = curve_of(tr, row_weight=rw, holdout=own if enough else None)
    if not enough or curve is None:
        return tr, rw, curve, resid, full
    alone, alone_resid, alone_full = curve_of(tr[own])
    if alone is not None and alone[0].min() <= curve[0].min():
        return tr[own], None, alone, alone_resid, alone_full
    return tr, rw, curve, resid, full


def group_model(positions: np.ndarray, m: int, group: np.ndarray, predictors: np.ndarray, train: np.ndarray,
                weights: list[np.ndarray], align_weight: np.ndarray, dist: np.ndarray, scales: tuple[float, ...], *,
                reach: float, normalise: bool, folds: int, knn: int, row_weight: np.ndarray | None = None,
                used_references: list | None = None, max_predictors: int | None = None,
                extrapolation: list | None = None, disagreement: list | None = None, split_by_time: bool = False,
                max_rms: float | None = None):
    """One local model of marker ``m``: fitted on ``train`` frames, evaluated on ``train`` then ``group`` frames.

    positions (n_frames, n_markers, 3) finite at ``m`` on ``train`` and at ``predictors`` on every frame used;
    weights one (n_markers,) array per width in ``scales``; align_weight / dist (n_markers,).  Returns the
    reconstruction (n_train + n_group, 3) in the laboratory frame, the leverage (n_train + n_group,), the mixed
    cross-validated RMS, components and RMS per width, the anchor markers of the local frame and the sensitivity
    (n_markers,): an error of variance v per coordinate in marker j's sample adds sensitivity[j] v to the variance
    per coordinate of the reconstruction (rotations and the nearest-pose correction left out); None where
    ``max_rms`` rejects it.

    ``row_weight`` (n_frames,) or None: the weight of each frame of ``positions`` as a training row, 1 for the
    capture's own frames and below 1 for reference frames; with it each width keeps the reference rows only where
    they lower the cross-validated error on the capture's own rows (:func:`_choose_rows`), and appends whether it
    kept them to ``used_references``.  ``max_predictors``: each width keeps at most this many of its predictors,
    the nearest (None: all within ``reach``).  ``extrapolation`` (a list) receives the (n_group,) factor by
    which each row's pose lies off the poses the model learnt from: per width max(1, the row's predictor residual /
    the held-out rows' mean one, :func:`~.weighted_pca.predictor_residual`), averaged with the widths' weights.
    ``disagreement`` (a list) receives the (n_train + n_group,) variance per coordinate of the widths' reconstructions
    about their mix, sum_s mix_s |est_s - est|^2 / 3: the mixture's variance beyond its members' own.
    ``split_by_time``: fewer training frames than two cross-validation blocks are split at their largest time gap
    (:func:`~.weighted_pca.cv_curve`'s ``times``) instead of leaving the model without an error (and so unused).
    ``max_rms`` or None: where the mixed cross-validated RMS is not at most this, None, before any prediction (the
    widths' fits and curves come first, their predictions after).
    """
    n_markers = positions.shape[1]
    needed = np.concatenate([[m], predictors])
    anchors = _anchor_set(predictors, align_weight)
    used = np.concatenate([train, group])
    n_train = len(train)
    centre, rot = local_frames(positions, used, anchors, align_weight[anchors], np.arange(n_train))
    # The local coordinates of the needed markers only, marker j at column block ``slot[j]`` (0 for the target):
    # the models see the same numbers as in a full-width array, without allocating and indexing its NaN columns.
    slot = np.full(n_markers, -1)
    slot[needed] = np.arange(len(needed))
    flat = ((positions[used[:, None], needed] - centre[:, None, :]) @ rot).reshape(len(used), 3 * len(needed))
    full_cols = np.asarray(_cols(needed))  # compact column -> column of the (n, 3 n_markers) layout
    tr = np.arange(n_train)
    target = np.array([0])
    ests, rmss, levs, ks, sens, offs = [], [], [], [], [], []
    fitted = []  # per width: its model, components, training rows, own rows and held-out residual
    for w_all, width in zip(weights, scales):
        # markers beyond ``reach`` widths weigh < 0.012: leaving them out changed no median, only the cost
        pred = predictors[dist[predictors] <= reach * width]
        if len(pred) < 3:
            pred = predictors[np.argsort(dist[predictors])[:3]]
        if max_predictors is not None and len(pred) > max_predictors:
            pred = pred[np.argsort(dist[pred], kind="stable")[:max_predictors]]
        pred, w = slot[pred], w_all[needed]
        own = None if row_weight is None else row_weight[train] >= 1.0 - 1e-12
        if own is not None and own.all():
            own = None
        rows, row_w, curve, held, full = _choose_rows(flat, tr, np.ones(n_train, bool) if own is None else own,
                                                None if own is None else row_weight[train], target, pred, w,
                                                normalise, folds, residuals=extrapolation is not None,
                                                times=train if split_by_time else None)
        if curve is None:
            k, rms = None, np.nan
        else:
            k = int(np.argmin(curve[0])) + 1
            rms = float(np.sqrt(curve[0, k - 1]))
        if full is not None:  # the cross-validation's own fit on the kept rows, its first k components
            model = full._replace(basis=full.basis[:, :k], singular=full.singular[:k])
        else:
            cols = _cols(target) + _cols(pred)
            # all training rows: a slice, not a gather of every row (the same block, C-ordered as the sums expect)
            block = flat[:n_train].take(cols, axis=1) if rows is tr else flat[np.ix_(rows, cols)]
            model = fit_model(flat, rows, target, pred, w, normalise=normalise, components=k,
                              gram=weighted_sums(block, row_w))
        fitted.append((model, k, rows, own, held))
        rmss.append(rms)
    rmss_a = np.asarray(rmss)
    if np.isfinite(rmss_a).all() and (rmss_a > 0).all():
        mix = 1.0 / rmss_a ** 2
    else:
        mix = np.ones(len(rmss))
    mix = mix / mix.sum()
    rms_mix = float(np.dot(mix, rmss_a)) if np.isfinite(rmss_a).all() else np.nan
    if max_rms is not None and not rms_mix <= max_rms:
        return None
    for model, k, rows, own, held in fitted:
        est_local, leverage = predict(model, flat)
        if extrapolation is not None:  # the predicted rows only (a training row's pose is one the model learnt)
            scale = held(k) if k is not None and held is not None else 0.0
            offs.append(np.maximum(predictor_residual(model, flat[n_train:]) / scale, 1.0) if scale > 0
                        else np.ones(len(flat) - n_train))
        if knn:
            if rows is tr:  # training rows first, then the group's: already in that order
                correction = knn_correction(model, flat, est_local, n_train, knn)
            else:
                sel = np.concatenate([rows, np.arange(n_train, len(used))])
                correction = knn_correction(model, flat[sel], est_local[sel], len(rows), knn)
            est_local[n_train:] += correction[len(rows):]
        if used_references is not None and own is not None:
            used_references.append(bool((~own[rows]).any()))
        ests.append(est_local)
        levs.append(leverage)
        ks.append(int(model.basis.shape[1]))
        # d target / d predictor coordinate (q_p, 3): how an error in a predictor moves the reconstruction
        nt = model.n_target
        gain = (model.weight[nt:] / model.scale[nt:])[:, None] * (model.basis[nt:] @ model.basis[:nt].T) \
            * (model.scale[:nt] / model.weight[:nt])[None, :]
        full = np.zeros((3 * n_markers, 3))
        full[full_cols[model.columns[nt:]]] = gain
        sens.append(full)
    stacked = np.stack(ests)
    est_local = np.einsum("s,std->td", mix, stacked)
    if disagreement is not None:  # (a rotation keeps lengths: the local frame's spread is the laboratory's)
        disagreement.append(np.einsum("s,st->t", mix, ((stacked - est_local) ** 2).sum(axis=2)) / 3.0)
    leverage = np.einsum("s,st->t", mix, np.stack(levs))
    if extrapolation is not None:
        extrapolation.append(np.einsum("s,st->t", mix, np.stack(offs)))
    # back to the laboratory frame: x = local R^T + centre
    est_all = (rot @ est_local[:, :, None])[:, :, 0] + centre
    sensitivity = (np.einsum("s,sqc->qc", mix, np.stack(sens)) ** 2).reshape(n_markers, 9).sum(axis=1) / 3.0
    return est_all, leverage, rms_mix, ks, rmss, anchors, sensitivity


def reconstruct_local(
    positions: np.ndarray,
    *,
    scales: tuple[float, ...],
    align_scale: float,
    missing_weight: float = 0.02,
    normalise: bool = True,
    folds: int = 5,
    knn: int = 10,
    edge: float | str | None = 30.0,
    reach: float = 3.0,
    max_predictors: int | None = None,
    max_patterns: int = 3,
    min_train: int = MIN_TRAIN_WANTED,
    edge_frames: int = 0,
    context: np.ndarray | None = None,
    reference_frames: np.ndarray | None = None,
    reference_weights: np.ndarray | None = None,
    reference_known: np.ndarray | None = None,
    extrapolation: bool = False,
    rigid_align: float | None = None,
    jobs: int | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Estimate every missing sample with the weighted PCA in each missing marker's local frame.

    For each marker with gaps and each pattern of other missing markers during its gaps: align the frames on the
    marker's observed neighbourhood (:func:`local_frames`, Gaussian weights of width ``align_scale``); for every
    width in ``scales`` fit the weighted PCA with the number of components chosen by leave-one-block-out
    cross-validation, add the k-nearest-pose residual correction (``knn`` > 0) and weight the estimates by their
    inverse cross-validated variance; rotate back; carry the residual at the gap's ends into it (``edge``).

    Parameters
    ----------
    positions : ndarray (n_frames, n_markers, 3), NaN = missing
    scales : widths (data units) of the PCA's distance weights, one reconstruction each.
    align_scale : width (data units) of the alignment weights.
    reach : each width uses the markers within ``reach`` times it (farther ones weigh < 0.012).
    max_predictors : cost bound: each width uses at most this many of them, the nearest (None: all).
    max_patterns : cost bound: a marker's gap frames are split by which predictors are observed there, the
        ``max_patterns - 1`` largest patterns get their own model and the remaining frames share one model whose
        predictors are observed in all of them.
    edge_frames : ``info["edge_estimate"]`` (n_frames, n_markers, 3) and ``info["edge_std"]`` (n_frames, n_markers)
        hold the model's reconstruction (and its uncertainty) at up to this many observed training frames on either
        side of each gap run (NaN elsewhere; all NaN with 0): what a smoother needs to learn the model's error at a
        gap's ends instead of the ``edge`` bridge.
    context : ndarray (n_frames, n_markers, 3) or None: the take with the missing samples a previous estimate
        trusts filled (NaN elsewhere); when given, a marker's predictors are read from it (its own samples still
        from ``positions``): one EM-style imputation step, in which frames where a neighbour was missing but is
        now estimated become training and prediction frames.
    reference_frames : ndarray (n_ref_frames, n_markers, 3), optional
        Frames of reference takes of the same marker set (:mod:`mocapfill.references`), in the capture's units and
        marker order, NaN where a reference lacks a marker.  They train every model beside the capture's own frames
        (and count towards ``min_train``), each with its ``reference_weights`` entry (n_ref_frames,) in [0, 1]
        (default 1) relative to a capture frame.  Per model and width the capture's own frames decide: where at
        least two blocks of them are observed, the model with the references is kept only if its leave-one-block-
        out error on the capture's frames (the references always in training) is below that of the model without
        them; so a reference of another body or motion is dropped where it does not help.
    reference_known : ndarray (n_ref_frames, n_markers) bool, optional
        Where the reference frames observe each marker, when their gaps were completed
        (:func:`mocapfill.references.completed_frames`): a marker is a target only there, a predictor everywhere.
        Default: where they are finite.
    rigid_align : None, or the spread (data units) the cameras' noise alone gives a distance: the alignment weights
        also weigh each neighbour by how rigidly it moves with the marker (:func:`rigidity_weights` of the spread of
        its distance to it over the frames where both are seen, with this ``noise``).

    Returns
    -------
    estimate (n_frames, n_markers, 3) (NaN where nothing could be estimated), std (n_frames, n_markers) per-
    coordinate RMS (0 observed, NaN unknown), info with ``fallback`` markers, ``groups`` (one record per marker
    and pattern: marker, frames, components per scale, cross-validated RMS) and ``anchors`` (n_frames, n_markers)
    int: how many observed neighbours defined the local frame of each estimated sample (0 elsewhere); with
    ``extrapolation``, ``info["extrapolation"]`` (n_frames, n_markers): how far each estimated sample's pose lies off
    the poses its model learnt from (:func:`group_model`; >= 1, NaN elsewhere).  ``jobs``: processes the markers'
    models are fitted on (:func:`~mocapfill.runtime.executor.forked_map`; None or 1: this one); the output does not
    depend on it.
    """
    n_frames, n_markers, _ = positions.shape
    missing = np.isnan(positions).any(axis=2)
    estimate = positions.copy()
    std = np.where(missing, np.nan, 0.0)
    info: dict[str, Any] = {"fallback": [], "groups": [], "anchors": np.zeros((n_frames, n_markers), dtype=int)}
    if extrapolation:
        info["extrapolation"] = np.full((n_frames, n_markers), np.nan)
    info["edge_estimate"] = np.full((n_frames, n_markers, 3), np.nan)
    info["edge_std"] = np.full((n_frames, n_markers), np.nan)
    gap_markers = np.flatnonzero(missing.any(axis=0) & ~missing.all(axis=0))
    if context is not None:
        ctx_missing = np.isnan(context).any(axis=2)
    ref, row_weight = None, None
    if reference_frames is not None and len(reference_frames):
        ref = np.asarray(reference_frames, dtype=np.float64)
        if ref.ndim != 3 or ref.shape[1:] != positions.shape[1:]:
            raise MethodError(f"reference_frames must have shape (n, {n_markers}, 3), got {ref.shape}")
        ref, row_weight, ref_known = reference_rows(
            ref, np.ones(len(ref)) if reference_weights is None else reference_weights, n_frames, reference_known)
        info["references"] = {"frames": len(ref), "models": 0, "used": 0}
    own_distances = distances_to(positions) if context is None else None
    own_spreads = distance_spreads_to(positions) if context is None and rigid_align is not None else None
    if context is None and ref is not None:  # reference frames join the training rows (never the predicted ones)
        with_refs_src = np.concatenate([positions, ref])
        with_refs_miss = np.concatenate([missing, np.isnan(ref).any(axis=2)])
        # a marker the take never shows but a reference does: modelled from the references alone, its distances too
        shown = ~missing.all(axis=0) | ref_known.any(axis=0)
        if (missing.all(axis=0) & shown).any():
            gap_markers = np.flatnonzero(missing.any(axis=0) & shown)
            ref_distances = distances_to(with_refs_src)

    def marker_models(m: int) -> list[tuple]:
        """Marker ``m``'s groups: ``(group,)`` where no model could be fitted (the linear fallback), else ``(group,
        train, group_model's outputs, extrapolation, references kept)`` (pure: the markers may be fitted in any
        process)."""
        frames = np.flatnonzero(missing[:, m])
        src, miss = positions, missing
        if context is not None:  # predictors from the context, the target's own samples as observed
            src, miss = context.copy(), ctx_missing.copy()
            src[:, m], miss[:, m] = positions[:, m], missing[:, m]
            dist = mean_distances(src, m)
            spread = distance_spreads_to(src)(m) if rigid_align is not None else None
        else:
            dist = own_distances(m) if not missing[:, m].all() else ref_distances(m)
            spread = own_spreads(m) if rigid_align is not None else None
        if ref is not None:  # reference frames join the training rows (never the predicted ones)
            if context is None:
                src, miss = with_refs_src, with_refs_miss
            else:
                src = np.concatenate([src, ref])
                miss = np.concatenate([miss, np.isnan(ref).any(axis=2)])
            if not ref_known[:, m].all():  # a reference's completed samples of the target are no targets
                miss = miss.copy()
                miss[n_frames:, m] = ~ref_known[:, m]
        weights, align_weight = marker_weights(dist, m, scales, align_scale, missing_weight, spread,
                                               rigid_align or 0.0)
        others = np.ones(n_markers, dtype=bool)
        others[m] = False
        other_idx = np.flatnonzero(others)
        near = other_idx[np.isfinite(dist[other_idx]) & (dist[other_idx] <= reach * max(scales))]
        near = near[np.argsort(dist[near], kind="stable")]
        groups = observed_groups(miss, m, frames, near, max_patterns, min_train, row_weight)
        # groups that came out with the same predictors and training frames (on a capture with gaps everywhere, a
        # third of them) are one model: fitted once on all their frames, its rows handed back to each
        shared: dict[tuple[bytes, bytes], list[int]] = {}
        for i, (_, predictors, train) in enumerate(groups):
            if len(predictors) >= 3 and len(train) >= MIN_TRAINING_FRAMES:
                shared.setdefault((predictors.tobytes(), train.tobytes()), []).append(i)
        fits: dict[int, tuple] = {}
        for members_of in shared.values():
            _, predictors, train = groups[members_of[0]]
            together = np.sort(np.concatenate([groups[i][0] for i in members_of]))
            with_refs: list[bool] = []
            off: list | None = [] if extrapolation else None
            est_all, leverage, *rest = group_model(
                src, m, together, predictors, train, weights, align_weight, dist, scales, reach=reach,
                max_predictors=max_predictors, normalise=normalise, folds=folds, knn=knn, row_weight=row_weight,
                used_references=with_refs, extrapolation=off)
            n_train = len(train)
            for i in members_of:
                at = np.searchsorted(together, groups[i][0])  # this group's rows among the model's predicted ones
                rows = np.concatenate([np.arange(n_train), n_train + at])
                fits[i] = ((est_all[rows], leverage[rows], *rest), off[0][at] if off else None, with_refs)
        return [(group,) if i not in fits else (group, train, *fits[i])
                for i, (group, _, train) in enumerate(groups)]

    fitted_groups = forked_map(marker_models, gap_markers, jobs, cost=missing[:, gap_markers].sum(axis=0))
    for m, groups in zip(gap_markers, fitted_groups):
        interpolated = None  # the marker's linear interpolation, once for all its groups that need it
        for entry in groups:
            group = entry[0]
            if len(entry) == 1:
                info["fallback"].append(int(m))
                if interpolated is None:
                    interpolated = linear_fallback(positions[:, m], missing[:, m])
                estimate[group, m] = interpolated[group]
                continue
            _, train, (est_all, leverage, rms_mix, ks, rmss, anchors, _), off, with_refs = entry
            n_train = len(train)
            if off is not None:
                info["extrapolation"][group, m] = off
            used = np.concatenate([train, group])
            est = est_all[n_train:]
            factor = np.ones(len(group))
            if edge is not None:
                pred = np.full((n_frames, 3), np.nan)
                mine = used < n_frames
                pred[used[mine]] = est_all[mine]
                est, factor = edge_corrected(positions[:, m], pred, group, tau=edge)
            estimate[group, m] = est
            std[group, m] = rms_mix * np.sqrt((1.0 + leverage[n_train:]) * factor)
            if edge_frames:
                own = train < n_frames
                edge_samples(info, m, group, train[own], est_all[:n_train][own],
                             rms_mix * np.sqrt(1.0 + leverage[:n_train][own]), edge_frames)
            info["anchors"][group, m] = len(anchors)
            record = {"marker": int(m), "frames": int(len(group)), "components": ks,
                      "cv_rms": [float(r) for r in rmss]}
            if row_weight is not None:
                record["references"] = with_refs
                info["references"]["models"] += len(with_refs)
                info["references"]["used"] += int(sum(with_refs))
            info["groups"].append(record)
    info["fallback"] = sorted(set(info["fallback"]))
    return estimate, std, info


def empty_estimates(n_frames: int, n_markers: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """NaN estimate (n_frames, n_markers, 3), std (n_frames, n_markers) and ``{"edge_estimate", "edge_std"}`` of
    the same shapes, for the reconstructions that fill them marker by marker."""
    return (np.full((n_frames, n_markers, 3), np.nan), np.full((n_frames, n_markers), np.nan),
            {"edge_estimate": np.full((n_frames, n_markers, 3), np.nan),
             "edge_std": np.full((n_frames, n_markers), np.nan)})


def rigid_prediction(positions: np.ndarray, todo: np.ndarray, *, nearest: int = 3, align_scale: float,
                     edge_frames: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The body's answer where the local PCA has none: each wanted sample rigidly attached to its nearest markers
    observed at that frame.

    positions (n_frames, n_markers, 3), NaN = missing; todo (n_frames, n_markers) bool: the missing samples wanted.
    Per marker and per set of its ``nearest`` nearest (mean distance) markers observed at a wanted frame, the
    marker's mean position in their weighted local frame (:func:`local_frames`, Gaussian weights of width
    ``align_scale``) over the frames where all are observed is carried to the wanted frames; its standard deviation
    per coordinate is the RMS scatter of that local position there (how far the marker moves relative to them: a
    foot relative to its shank is honest about the ankle's angle), times sqrt(1 + 1 / n_train).  A run of wanted
    frames keeps one anchor set where markers seen throughout it allow.  Returns estimate (n_frames, n_markers, 3)
    and std (n_frames, n_markers), NaN where not wanted or fewer than ``MIN_TRAINING_FRAMES`` frames saw the
    marker with its anchors, and the same prediction (and std) at up to ``edge_frames`` observed frames on either
    side of each run (NaN elsewhere), where a smoother learns its error.
    """
    n_frames, n_markers, _ = positions.shape
    missing = np.isnan(positions).any(axis=2)
    estimate, std, edges = empty_estimates(n_frames, n_markers)
    own_distances = distances_to(positions)
    for m in np.flatnonzero(todo.any(axis=0) & ~missing.all(axis=0)):
        dist = own_distances(m)
        dist[m] = np.nan
        order = np.flatnonzero(np.isfinite(dist))
        order = order[np.argsort(dist[order], kind="stable")]
        frames = np.flatnonzero(todo[:, m])
        seen = ~missing[np.ix_(frames, order)]
        # one anchor set per run of wanted frames where the run allows it (the markers seen throughout it): a set
        # that changed from frame to frame would make the prediction jump where it changes
        run_id = np.cumsum(np.diff(frames, prepend=-2) != 1)
        for r in np.unique(run_id):
            rows = run_id == r
            whole = seen[rows].all(axis=0)
            if whole.sum() >= 3:
                seen[rows] = whole
        rank = np.cumsum(seen, axis=1)
        pattern = seen & (rank <= nearest)
        uniq, inverse, _ = unique_rows(pattern)
        for p, rows in enumerate(members(inverse, len(uniq))):
            anchors = order[uniq[p]]
            if len(anchors) < 3:
                continue
            group = frames[rows]
            train = _training(missing, m, anchors)
            if len(train) < MIN_TRAINING_FRAMES:
                continue
            weights = gaussian_weights(dist[anchors], align_scale) + 1e-6
            used = np.concatenate([train, group])
            centre, rot = local_frames(positions, used, anchors, weights, np.arange(len(train)))
            local = np.einsum("tc,tcd->td", positions[train, m] - centre[:len(train)], rot[:len(train)])
            mu = local.mean(axis=0)
            sigma = np.sqrt(np.mean(np.sum((local - mu) ** 2, axis=1)) / 3.0 * (1.0 + 1.0 / len(train)))
            n = len(train)
            estimate[group, m] = centre[n:] + np.einsum("d,tcd->tc", mu, rot[n:])
            std[group, m] = sigma
            if edge_frames:
                edge_samples(edges, m, group, train, centre[:n] + np.einsum("d,tcd->tc", mu, rot[:n]),
                             np.full(n, sigma), edge_frames)
    return estimate, std, edges["edge_estimate"], edges["edge_std"]


def fill_local_pca(
    positions: np.ndarray,
    *,
    units: str = "mm",
    scales: tuple[float, ...] | None = None,
    align_scale: float | None = None,
    missing_weight: float = 0.02,
    normalise: bool = True,
    knn: int = 10,
    edge: float | str | None = 30.0,
) -> FillResult:
    """Fill gaps with the distance-weighted PCA computed in each missing marker's local frame.

    positions (n_frames, n_markers, 3), NaN = missing; ``scales`` / ``align_scale`` in data units (defaults
    150, 200, 300 mm / 200 mm converted from ``units``).  Returns a FillResult with a per-coordinate RMS ``std``.
    """
    positions = np.asarray(positions, dtype=np.float64)
    mm = length_factor("mm", units)  # data units per millimetre
    scales = tuple(DEFAULT_SCALES_MM * mm) if scales is None else tuple(float(x) for x in scales)
    align = DEFAULT_ALIGN_MM * mm if align_scale is None else float(align_scale)
    if not scales or min(scales) <= 0 or align <= 0:
        raise MethodError(f"scales and align_scale must be positive lengths, got {scales!r}, {align!r}")
    with single_blas_thread():
        estimate, std, info = reconstruct_local(positions, scales=scales, align_scale=align,
                                                missing_weight=missing_weight, normalise=normalise, knn=knn,
                                                edge=edge)
    info.pop("anchors")  # per-sample array: internal to the default's trust check, not for reports
    return finish(positions, estimate, std=std, info=info)
