"""Distance-weighted PCA reconstruction of missing markers (Gløersen & Federolf 2016, PLOS ONE 11(3): e0152616).

The idea, from the published description: every marker is correlated with the others through the body's
coordination patterns, and the nearest markers carry most of that information.  First the body's translation is
removed: the per-frame centroid of the markers observed in every frame is subtracted (and added back at the end).
On 20 early one-marker trials of the CMU flips clip this step alone took the median RMSE from 37 to 29 mm; our
reading is that the published centring is meant to do this, but the paper's exact pre-processing is not reproduced
from code.  Then, for
a marker with a gap:

1. take the frames where the marker and the markers that can help (those observed throughout the gap frames) are
   all present ("training" frames); centre each coordinate column on its training mean and normalise it by its
   training standard deviation;
2. weight every marker by a Gaussian of its mean distance to the missing marker (scale about 200 mm), and give the
   missing marker itself a small weight (0.02) so that it barely shapes the principal components;
3. compute the principal components of the weighted training matrix and keep those reaching 99 % of the cumulative
   singular values;
4. for each gap frame, set the missing marker's (centred) coordinates to zero, project the weighted frame onto the
   kept components and reconstruct; the missing marker's reconstructed coordinates, divided by its weight and
   de-normalised, are the fill.

Because the missing marker's weight is small, step 4 is in effect a regression of its coordinates on the principal
component scores of the weighted observed markers.  Gaps in several markers are handled one marker at a time
(``strategy="separate"``: each marker gets its own weights) or all markers missing in a frame together
(``strategy="joint"``: one PCA per pattern, weights from the nearest missing marker); "separate" is the default
because it measured more accurate (see ``benchmarks/bench_default.py``).

The per-sample uncertainty comes from a leave-one-block-out reconstruction of the same marker on its own training
frames (five contiguous blocks, so each held-out block looks like a gap), inflated by the frame's leverage in the
component space.  It is the root-mean-square error per coordinate, in data units.

Two cost bounds that do not change the method's figures: markers farther than 4 widths (weight < 3.4e-4) are left
out of the decomposition, and a marker's gap frames are split into at most 3 groups by which other markers are
observed there (the 2 largest patterns exactly, the rest together with the markers observed in all of them).

Everything here is pure NumPy; the heavy step per (marker, gap pattern) is one Gram matrix and one symmetric
eigendecomposition of at most 3 x n_markers, so a 1,500-frame, 41-marker clip with one gap fills in about 0.02 s,
and with gaps in 37 of its markers in about 0.5 s (``benchmarks/bench_default.py``).
"""

from __future__ import annotations

import warnings
from typing import Any, Callable, NamedTuple

import numpy as np

from ..errors import MethodError
from ..gaps import members, unique_rows
from ..methods.interp import interpolate_columns
from ..units import length_factor

#: Default Gaussian width of the distance weights, per unit (200 mm).
DEFAULT_SCALE_MM = 200.0

#: Fewest training frames a reconstruction needs; below this a marker's gap falls back to linear interpolation.
MIN_TRAINING_FRAMES = 10
#: Fewest training frames cross-validation splits into two blocks (:func:`_blocks`): a model needs them.
MIN_CV_FRAMES = 2 * MIN_TRAINING_FRAMES


class PCAModel(NamedTuple):
    """A fitted weighted-PCA reconstruction for one set of target markers from one set of predictor markers.

    ``columns`` (q,) are coordinate column indices into the flattened (n_frames, 3 n_markers) data, targets first;
    ``n_target`` is how many of them belong to the targets (3 per target marker).  ``mean`` / ``scale`` (q,) are the
    training centring and normalisation, ``weight`` (q,) the per-column weight, ``basis`` (q, k) the kept
    components and ``singular`` (k,) their singular values.
    """

    columns: np.ndarray
    n_target: int
    mean: np.ndarray
    scale: np.ndarray
    weight: np.ndarray
    basis: np.ndarray
    singular: np.ndarray


def weight_width(units: str, scale: float | None) -> float:
    """The Gaussian width in data units: ``scale`` if given, else 200 mm converted to ``units``."""
    if scale is not None:
        if not np.isfinite(scale) or scale <= 0:
            raise MethodError(f"pca scale must be a positive length, got {scale!r}")
        return float(scale)
    return DEFAULT_SCALE_MM * length_factor("mm", units)


def _plane_distances(planes: list[np.ndarray], m: int) -> np.ndarray:
    """|x_j - x_m| per frame (n_frames, n_markers) from the coordinate planes (3 of (n_frames, n_markers)), NaN where
    either is missing: |d|^2 = (d0^2 + d1^2) + d2^2, numpy's norm to round-off (~1e-12 relative on real captures)
    without its per-sample loop over a length-3 axis."""
    sq = None
    for plane in planes:
        d = plane - plane[:, m:m + 1]
        d *= d
        if sq is None:
            sq = d
        else:
            sq += d
    return np.sqrt(sq, out=sq)


def distances_to(positions: np.ndarray):
    """:func:`mean_distances` as a function of the target, positions (n_frames, n_markers, 3) read once.

    The coordinate planes are split once for all targets (:func:`_plane_distances`).
    Per target m: (n_markers,), NaN where never co-observed.
    """
    planes = [np.ascontiguousarray(positions[..., c]) for c in range(3)]

    def mean_to(m: int) -> np.ndarray:
        dist = _plane_distances(planes, m)
        counts = np.isfinite(dist).sum(axis=0)
        np.copyto(dist, 0.0, where=np.isnan(dist))  # nansum
        total = dist.sum(axis=0)
        with np.errstate(invalid="ignore"):
            return np.where(counts > 0, total / np.maximum(counts, 1), np.nan)

    return mean_to


def distance_spreads_to(positions: np.ndarray):
    """How much each marker's distance to a target varies: per target m, the standard deviation (n_markers,) over
    the frames where both are observed of |x_j - x_m| (NaN where never co-observed), positions (n_frames,
    n_markers, 3) read once.  Small for the markers of the target's own rigid segment."""
    planes = [np.ascontiguousarray(positions[..., c]) for c in range(3)]

    def spread_to(m: int) -> np.ndarray:
        dist = _plane_distances(planes, m)
        seen = np.isfinite(dist)
        counts = seen.sum(axis=0)
        dist[~seen] = 0.0
        with np.errstate(invalid="ignore", divide="ignore"):
            dev = np.where(seen, dist - dist.sum(axis=0) / counts, 0.0)
            return np.where(counts > 0, np.sqrt((dev ** 2).sum(axis=0) / np.maximum(counts, 1)), np.nan)

    return spread_to


def mean_distances(positions: np.ndarray, target: int) -> np.ndarray:
    """Mean distance of every marker to marker ``target`` over the frames where both are observed.

    positions (n_frames, n_markers, 3) with NaN = missing; returns (n_markers,), NaN where never co-observed.  For
    many targets of one take, :func:`distances_to` reads the positions once.
    """
    return distances_to(positions)(target)


def gaussian_weights(distances: np.ndarray, scale: float) -> np.ndarray:
    """exp(-d^2 / (2 scale^2)) for distances (n,); markers never seen together (NaN) get weight 0."""
    w = np.exp(-0.5 * (np.nan_to_num(distances, nan=np.inf) / scale) ** 2)
    return w


def _columns(markers: np.ndarray) -> np.ndarray:
    """Flattened coordinate columns (3 len(markers),) of ``markers`` in a (n_frames, 3 n_markers) matrix."""
    markers = np.asarray(markers, dtype=int)
    return (3 * markers[:, None] + np.arange(3)[None, :]).ravel()


def _layout(targets: np.ndarray, predictors: np.ndarray, marker_weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A model's coordinate columns (q,) in the flattened data, targets first, and each column's weight (q,)."""
    columns = np.concatenate([_columns(targets), _columns(predictors)])
    return columns, np.repeat(np.concatenate([marker_weight[targets], marker_weight[predictors]]), 3)


def _keep(singular: np.ndarray, variance: float) -> int:
    """Number of components whose cumulative singular values first reach ``variance`` of their sum."""
    total = singular.sum()
    if total <= 0:
        return 0
    cum = np.cumsum(singular) / total
    return int(min(np.searchsorted(cum, variance - 1e-12) + 1, len(singular)))


def fit_model(
    flat: np.ndarray,
    train: np.ndarray,
    targets: np.ndarray,
    predictors: np.ndarray,
    marker_weight: np.ndarray,
    *,
    variance: float = 0.99,
    normalise: bool = True,
    gram: tuple[np.ndarray, np.ndarray, int] | None = None,
    components: int | None = None,
) -> PCAModel:
    """Fit the weighted PCA of the training frames.

    Parameters
    ----------
    flat : ndarray (n_frames, 3 n_markers)
        Flattened positions (NaN = missing).
    train : ndarray of int (n_train,)
        Training frames: targets and predictors all observed.
    targets, predictors : ndarray of int
        Marker indices (disjoint).
    marker_weight : ndarray (n_markers,)
        Weight of every marker (the targets' entries are the small fitting weight).
    gram : (sum (q,), outer-product sum (q, q), count) or None
        Precomputed raw sums over the training frames (lets cross-validation subtract a block instead of
        recomputing).
    components : int, optional
        Keep exactly this many components instead of applying the ``variance`` rule.
    """
    columns, weight = _layout(targets, predictors, marker_weight)
    if gram is None:
        block = flat[np.ix_(train, columns)]
        s1, s2, n = block.sum(axis=0), block.T @ block, len(train)
    else:
        s1, s2, n = gram
    (model,) = _fit_stacked(columns, 3 * len(targets), np.asarray(s1)[None], np.asarray(s2)[None],
                            np.array([float(n)]), weight, normalise=normalise, variance=variance,
                            components=components)
    return model


def _fit_stacked(columns: np.ndarray, n_target: int, s1: np.ndarray, s2: np.ndarray, n: np.ndarray,
                 weight: np.ndarray, *, normalise: bool, variance: float = 0.99, components: int | None = None
                 ) -> list[PCAModel]:
    """:func:`fit_model` from the raw sums of F training sets at once: s1 (F, q), s2 (F, q, q), n (F,) rows.

    One stacked eigendecomposition for the F sets (cross-validation's folds): the same numbers per set as F calls,
    every operation elementwise or per matrix, without F times the per-call overhead of small arrays.
    """
    mean = s1 / n[:, None]
    dof = np.maximum(n - 1, 1)[:, None, None]
    cov = (s2 - n[:, None, None] * (mean[:, :, None] * mean[:, None, :])) / dof
    cov = (cov + np.swapaxes(cov, 1, 2)) / 2
    std = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    if normalise:
        # A coordinate that never moves would divide by zero; leave it unscaled (it carries no correlation anyway).
        scale = np.where(std > 1e-12 * np.maximum(std.max(axis=1, keepdims=True), 1e-300), std, 1.0)
    else:
        scale = np.ones_like(std)
    d = weight / scale
    wcov = cov * (d[:, :, None] * d[:, None, :]) * dof  # Gram of the centred, normalised, weighted training matrix
    evals, evecs = np.linalg.eigh(wcov)
    order = np.argsort(evals, axis=1)[:, ::-1]
    out = []
    for f, o in enumerate(order):
        singular = np.sqrt(np.clip(evals[f][o], 0, None))
        k = _keep(singular, variance) if components is None else int(min(max(components, 1), len(singular)))
        # (the reordered eigenvectors come column-major, as a single fit's always did: a product's last bits can
        # depend on its operands' layout)
        out.append(PCAModel(columns, n_target, mean[f], scale[f], weight, evecs[f][:, o][:, :k], singular[:k]))
    return out


def predict(model: PCAModel, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reconstruct the targets of ``rows`` (n, 3 n_markers) from their predictors.

    Returns the target coordinates (n, n_target) in data units and the leverage of each row (n,): the squared
    norm of its component scores relative to the training spread (used to inflate the uncertainty away from the
    training poses).
    """
    x = rows[:, model.columns]
    z = (x - model.mean) / model.scale * model.weight
    z[:, :model.n_target] = 0.0  # the missing marker contributes nothing to the projection
    scores = z @ model.basis  # (n, k)
    recon = scores @ model.basis[:model.n_target].T  # (n, n_target)
    nt = model.n_target
    out = recon / model.weight[:nt] * model.scale[:nt] + model.mean[:nt]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # a singular value of 0 (rigid data) is masked
        rel = np.where(model.singular > 0, scores / np.maximum(model.singular, 1e-300), 0.0)
    leverage = (rel ** 2).sum(axis=1)
    return out, leverage


def _blocks(n: int, folds: int) -> list[np.ndarray]:
    """Split range(n) into ``folds`` contiguous blocks (fewer when n is small)."""
    folds = max(1, min(folds, n // MIN_TRAINING_FRAMES))
    return [b for b in np.array_split(np.arange(n), folds) if len(b)]


def cross_validated_rms(
    flat: np.ndarray,
    train: np.ndarray,
    targets: np.ndarray,
    predictors: np.ndarray,
    marker_weight: np.ndarray,
    *,
    variance: float,
    normalise: bool,
    folds: int = 5,
) -> np.ndarray:
    """Leave-one-block-out RMS reconstruction error per coordinate of each target marker (n_targets,).

    Each contiguous block of the training frames is held out in turn (like a gap), the model refitted on the rest
    by subtracting the block's sums, and the block reconstructed.  NaN when there are too few frames.
    """
    columns = np.concatenate([_columns(targets), _columns(predictors)])
    block_all = flat[np.ix_(train, columns)]
    s1, s2, n = block_all.sum(axis=0), block_all.T @ block_all, len(train)
    blocks = _blocks(n, folds)
    if len(blocks) < 2:
        return np.full(len(targets), np.nan)
    sq = np.zeros(3 * len(targets))
    count = 0
    for rows in blocks:
        held = block_all[rows]
        gram = (s1 - held.sum(axis=0), s2 - held.T @ held, n - len(rows))
        model = fit_model(flat, train, targets, predictors, marker_weight, variance=variance,
                          normalise=normalise, gram=gram)
        est, _ = predict(model, flat[train[rows]])
        sq += ((est - held[:, :3 * len(targets)]) ** 2).sum(axis=0)
        count += len(rows)
    per_coord = sq.reshape(len(targets), 3) / count
    return np.sqrt(per_coord.mean(axis=1))


def reference_trajectory(positions: np.ndarray, missing: np.ndarray) -> np.ndarray:
    """Per-frame centroid of the markers observed in every frame, shape (n_frames, 1, 3).

    Subtracting it removes the body's translation, which otherwise dominates the principal components.  When no
    marker is complete, the centroid of the markers observed in at least 90 % of the frames is taken per frame over
    those present and linearly interpolated where none is; zeros when even that is impossible.
    """
    n_frames = positions.shape[0]
    complete = ~missing.any(axis=0)
    if complete.sum() >= 1:
        return positions[:, complete].mean(axis=1, keepdims=True)
    mostly = missing.mean(axis=0) <= 0.1
    if not mostly.any():
        return np.zeros((n_frames, 1, 3))
    with np.errstate(invalid="ignore"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            centre = np.nanmean(positions[:, mostly], axis=1)  # (n_frames, 3)
    gone = np.isnan(centre).any(axis=1)
    if gone.all():
        return np.zeros((n_frames, 1, 3))
    return linear_fallback(centre, gone)[:, None, :]


def weighted_sums(block: np.ndarray, row_weight: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, float]:
    """Raw sums of rows (n, q) for :func:`fit_model`'s ``gram``: (sum w x (q,), sum w x x^T (q, q), sum w)."""
    if row_weight is None:
        return block.sum(axis=0), block.T @ block, float(len(block))
    wb = block * row_weight[:, None]
    return wb.sum(axis=0), block.T @ wb, float(row_weight.sum())


def _centred(h1: np.ndarray, h2: np.ndarray, hn: float, mean: np.ndarray) -> np.ndarray:
    """sum over a block's rows of (x - mean)(x - mean)^T from its raw sums h1 = sum x, h2 = sum x x^T, hn rows."""
    return h2 - np.outer(h1, mean) - np.outer(mean, h1) + hn * np.outer(mean, mean)


def _fold_errors(model: PCAModel, h1: np.ndarray, h2: np.ndarray, hn: float) -> np.ndarray:
    """Summed squared error (K, nt) of a held-out block's targets reconstructed with the first k = 1..K components.

    h1 (q,), h2 (q, q), hn: the block's raw sums (sum x, sum x x^T, rows) in ``model.columns`` order.  With the
    block centred on the model's mean, c = x - mean, the scores are s = B_p^T D_p c_p (D = weight / scale, B_p the
    basis' predictor rows) and the reconstruction error of target coordinate t with k components is
    e_t(k) = -c_t + sum_{j<=k} s_j u_tj, u_tj = B_tj scale_t / weight_t.  Summed over the rows,
    sum e_t(k)^2 = C_tt - 2 sum_{j<=k} u_tj A_jt + sum_{i,j<=k} u_ti S_ij u_tj with C the block's centred Gram,
    A = B_p^T D_p C_pt and S = B_p^T D_p C_pp D_p B_p: every truncation from q x q sums, without touching the rows
    again (the cost no longer grows with the block's length).
    """
    nt = model.n_target
    mean, basis = model.mean, model.basis
    cent = _centred(h1, h2, hn, mean)  # sum c c^T (q, q)
    d = (model.weight / model.scale)[nt:]
    bp = basis[nt:] * d[:, None]  # (q_p, K): scores s = bp^T c_p
    a = bp.T @ cent[nt:, :nt]  # (K, nt): sum over rows of s c_t
    gram_s = bp.T @ cent[nt:, nt:] @ bp  # (K, K): sum over rows of s s^T
    u = basis[:nt].T * (model.scale[:nt] / model.weight[:nt])  # (K, nt)
    # sum_{i,j<=k} u_i S_ij u_j grows by 2 u_k sum_{i<k} S_ik u_i + S_kk u_k^2 at step k
    below = np.triu(gram_s, 1).T @ u  # (K, nt): row k = sum_{i<k} S_ik u_i
    step = u * (2.0 * below + np.diag(gram_s)[:, None] * u) - 2.0 * u * a
    # a marker the predictors fix exactly has error ~0, which the expansion's round-off can take below zero
    return np.maximum(np.diag(cent)[:nt][None, :] + np.cumsum(step, axis=0), 0.0)


def _fold_residual(model: PCAModel, h1: np.ndarray, h2: np.ndarray, hn: float, k: int) -> float:
    """Summed squared residual of a held-out block's predictors off the model's first ``k`` components.

    h1, h2, hn as in :func:`_fold_errors`.  In the model's weighted, normalised predictor space z_p = D_p c_p (as
    :func:`predictor_residual` forms it), the scores are s = B_p^T z_p and the residual r = z_p - B_p s; summed over
    the rows, |r|^2 = tr(Z) - 2 tr(S) + tr(G S) with Z = D_p C_pp D_p, S = B_p^T Z B_p and G = B_p^T B_p (the
    basis' predictor rows alone are not orthonormal), B_p the first k columns: O(q^2 k), not a pass over the rows.
    """
    nt = model.n_target
    mean, basis = model.mean[nt:], model.basis[nt:, :k]
    cent = _centred(h1[nt:], h2[nt:, nt:], hn, mean)  # sum c_p c_p^T
    d = (model.weight / model.scale)[nt:]
    bp = basis * d[:, None]
    s_mat = bp.T @ cent @ bp  # (k, k)
    total = float(np.dot(d * d, np.diag(cent))) - 2.0 * float(np.trace(s_mat)) + float(np.sum((basis.T @ basis) * s_mat))
    return max(total, 0.0)


def predictor_residual(model: PCAModel, rows: np.ndarray) -> np.ndarray:
    """Squared norm (n,) of each row's predictors off the model's components, in its weighted, normalised space.

    rows (n, 3 n_markers) as :func:`predict` takes them.  Small where a row's predictors look like the training
    poses; large where the model has to extrapolate (the pose lies outside the components it learnt).
    """
    nt = model.n_target
    z = (rows[:, model.columns[nt:]] - model.mean[nt:]) / model.scale[nt:] * model.weight[nt:]
    r = z - (z @ model.basis[nt:]) @ model.basis[nt:].T
    return (r ** 2).sum(axis=1)


def cv_curve(
    flat: np.ndarray,
    train: np.ndarray,
    targets: np.ndarray,
    predictors: np.ndarray,
    marker_weight: np.ndarray,
    *,
    normalise: bool = True,
    folds: int = 5,
    row_weight: np.ndarray | None = None,
    holdout: np.ndarray | None = None,
    residuals: bool = False,
    times: np.ndarray | None = None,
    fitted: list | None = None,
) -> np.ndarray | tuple[np.ndarray, Callable[[int], float]] | None:
    """Leave-one-block-out mean squared error per coordinate of the targets for every number of components.

    Same splitting as :func:`cross_validated_rms`, except with ``times`` (n_train,), each row's frame, and fewer than
    two blocks' worth of rows (``MIN_TRAINING_FRAMES`` <= n < twice that, which gave one block, no error and so no
    model): then the rows on either side of their largest time gap are the two blocks, as a gap there would hide
    them (each at least 2 rows).  One eigendecomposition per fold serves every truncation because the reconstruction
    with k components is a cumulative sum over components.  Returns (n_targets, q) with q = 3 (n_targets +
    n_predictors) (entry k-1 = error with k components), or None with too few frames.

    ``row_weight`` (n_train,): the weight of each training row in the sums (reference frames beside the capture's
    own, see :mod:`mocapfill.references`; default 1).  ``holdout`` (n_train,) bool: the rows that are held out in
    blocks (the capture's own); the others always stay in training.  Default: every row.  ``residuals``: also a
    function k -> the held-out rows' mean squared predictor residual with k components (:func:`_fold_residual`: the
    scale of :func:`predictor_residual` on poses a model did not learn from), returned as ``(curve, residual)``.
    ``fitted`` (a list): receives the model on every row with every component, what :func:`fit_model` gives on the
    same rows and weights (truncated to k components, it is that number's fit), from the folds' decomposition.
    """
    columns, weight = _layout(targets, predictors, marker_weight)
    block_all = flat[np.ix_(train, columns)]
    s1, s2, n = weighted_sums(block_all, row_weight)
    rows_out = np.arange(len(train)) if holdout is None else np.flatnonzero(holdout)
    n_out = len(rows_out)
    if times is not None and MIN_TRAINING_FRAMES <= n_out < 2 * MIN_TRAINING_FRAMES:
        # too few frames for two ordinary blocks (a marker seen a few frames of a short take): hold out the frames on
        # either side of the largest time gap between them, what a gap there would hide, each side leaving the other
        # at least 2 frames to fit (a covariance)
        cut = int(np.argmax(np.diff(np.asarray(times)[rows_out]))) + 1
        blocks = [rows_out[:cut], rows_out[cut:]] if min(cut, n_out - cut) >= 2 else []
    else:
        blocks = [rows_out[b] for b in _blocks(n_out, folds)]
    if len(blocks) < 2:
        return None
    nt = 3 * len(targets)
    held_sums = []  # per fold: the held-out rows' sums as weighed in training, and as counted in the error
    for rows in blocks:
        held = block_all[rows]
        hw = None if row_weight is None else row_weight[rows]
        sums = weighted_sums(held, hw)
        # the error counts every held row once
        held_sums.append((sums, weighted_sums(held, None) if hw is not None and not np.all(hw == 1.0) else sums))
    # the folds' models and, last, the model on every row: one stacked decomposition
    models = _fit_stacked(columns, nt, np.stack([s1 - h[0][0] for h in held_sums] + [s1]),
                          np.stack([s2 - h[0][1] for h in held_sums] + [s2]),
                          np.array([n - h[0][2] for h in held_sums] + [n], dtype=np.float64), weight,
                          normalise=normalise, components=len(columns))
    if fitted is not None:
        fitted.append(models[-1])
    models = models[:-1]
    sq = np.zeros((len(columns), nt))
    kept = []  # (fold model, held-out sums) for the residual, once the number of components is chosen
    count = 0
    for rows, model, (_, (h1, h2, hn)) in zip(blocks, models, held_sums):
        sq += _fold_errors(model, h1, h2, hn)  # (per fold: numpy's stacked products of this size are slower)
        if residuals:
            kept.append((model, h1, h2, hn))
        count += len(rows)
    per = sq / count  # (q, nt)
    curve = per.reshape(len(columns), len(targets), 3).mean(axis=2).T
    if not residuals:
        return curve
    return curve, lambda k: sum(_fold_residual(*fold, k) for fold in kept) / count


def ranked_groups(keys: np.ndarray, sizes: np.ndarray | None, max_groups: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rows of ``keys`` (n, p) bool grouped by equal row, at most ``max_groups`` groups: [(rows ascending, key (p,))].

    The groups are ranked by their rows' summed ``sizes`` (n,) (None: 1 each), largest first (between equal sums, the
    later key in lexicographic order first); with more than ``max_groups``, the largest ``max_groups - 1`` keep their
    key and the other rows form one group, last, keyed by the OR of theirs.  The one split behind
    :func:`pattern_groups` (a marker's frames by their missing predictors) and
    :func:`~.local_refit.trusted_runs` (its gap runs by their untrusted neighbours).
    """
    patterns, inverse, counts = unique_rows(keys)
    totals = counts if sizes is None else np.bincount(inverse, weights=sizes, minlength=len(patterns))
    order = np.argsort(totals, kind="stable")[::-1]
    keep = order if len(order) <= max_groups else order[:max(max_groups - 1, 0)]
    rows = members(inverse, len(patterns))
    out = [(rows[p], patterns[p]) for p in keep]
    if len(keep) < len(order):
        rest = np.flatnonzero(~np.isin(inverse, keep))
        out.append((rest, keys[rest].any(axis=0)))
    return out


def pattern_groups(missing: np.ndarray, frames: np.ndarray, near: np.ndarray, max_patterns: int
                   ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split one marker's gap ``frames`` into (frames, predictors) groups, at most ``max_patterns`` of them.

    ``near`` (p,) are the candidate predictor markers; a group's predictors are those observed in all its frames.
    Frames with the same pattern of observed candidates form a group; when there are more than ``max_patterns``
    patterns, the largest ``max_patterns - 1`` keep theirs and the rest are merged (:func:`ranked_groups`).
    """
    return [(frames[rows], near[~key])
            for rows, key in ranked_groups(missing[np.ix_(frames, near)], None, max_patterns)]


def linear_fallback(series: np.ndarray, missing: np.ndarray) -> np.ndarray:
    """Per-coordinate linear interpolation (nearest value beyond the ends) of one marker (n_frames, 3)."""
    return interpolate_columns(series, np.repeat(np.asarray(missing, dtype=bool)[:, None], 3, axis=1))


def reconstruct(
    positions: np.ndarray,
    *,
    scale: float,
    missing_weight: float = 0.02,
    variance: float = 0.99,
    strategy: str = "separate",
    normalise: bool = True,
    folds: int = 5,
    uncertainty: bool = True,
    centroid: bool = True,
    max_patterns: int = 3,
    reach: float = 4.0,
    reference_frames: np.ndarray | None = None,
    reference_weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The weighted-PCA estimate of every missing sample.

    Parameters
    ----------
    positions : ndarray (n_frames, n_markers, 3), NaN = missing
    scale : float
        Gaussian width of the distance weights in data units.
    missing_weight, variance, strategy, normalise : see :func:`fill_pca`.
    folds : contiguous blocks of the leave-one-block-out uncertainty.
    uncertainty : compute ``std`` (False leaves it NaN on filled samples).
    centroid : remove the per-frame centroid of the complete markers first.
    max_patterns : groups per marker (see the module docstring).
    reach : markers beyond ``reach`` widths are left out.
    reference_frames, reference_weights : frames (n_ref, n_markers, 3) of reference takes in the capture's units and
        marker order (NaN where lacking) and their weights (n_ref,) in [0, 1] (:mod:`mocapfill.references`): their
        frames, centred the same way, join the training frames of every model with that weight.

    Returns
    -------
    estimate : ndarray (n_frames, n_markers, 3)
        Input with missing samples estimated (NaN where nothing could be estimated).
    std : ndarray (n_frames, n_markers)
        Per-coordinate RMS uncertainty of each estimated sample (0 on observed samples, NaN where unknown).
    info : dict
        ``components`` per reconstruction, ``fallback`` markers filled by linear interpolation.
    """
    n_frames, n_markers, _ = positions.shape
    missing = np.isnan(positions).any(axis=2)
    reference = reference_trajectory(positions, missing) if centroid else np.zeros((n_frames, 1, 3))
    local = positions - reference
    flat = local.reshape(n_frames, 3 * n_markers)
    train_flat, train_missing, row_w = flat, missing, None
    if reference_frames is not None and len(reference_frames):
        ref = np.asarray(reference_frames, dtype=np.float64)
        if ref.ndim != 3 or ref.shape[1:] != positions.shape[1:]:
            raise MethodError(f"reference_frames must have shape (n, {n_markers}, 3), got {ref.shape}")
        rw = np.ones(len(ref)) if reference_weights is None else np.clip(np.asarray(reference_weights, float), 0, 1)
        if centroid:
            complete = ~missing.any(axis=0)
            cols = complete if complete.any() else missing.mean(axis=0) <= 0.1
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                centre = np.nanmean(ref[:, cols], axis=1, keepdims=True) if cols.any() else np.zeros((len(ref), 1, 3))
            ref = ref - centre
        ok = np.isfinite(ref).any(axis=(1, 2)) & (rw > 0)
        ref, rw = ref[ok], rw[ok]
        train_flat = np.concatenate([flat, ref.reshape(len(ref), 3 * n_markers)])
        train_missing = np.concatenate([missing, np.isnan(ref).any(axis=2)])
        row_w = np.concatenate([np.ones(n_frames), rw])
    estimate = local.copy()
    std = np.where(missing, np.nan, 0.0)
    info: dict[str, Any] = {"strategy": strategy, "components": [], "fallback": []}
    gap_markers = np.flatnonzero(missing.any(axis=0) & ~missing.all(axis=0))

    distance_to = distances_to(positions)
    if strategy == "separate":
        tasks = []
        for m in gap_markers:
            frames = np.flatnonzero(missing[:, m])
            dist = distance_to(m)
            weight = gaussian_weights(dist, scale)
            weight[m] = missing_weight
            tasks.append((np.array([m]), frames, weight))
    elif strategy == "joint":
        tasks = []
        rows = missing[missing.any(axis=1)]
        frames_any = np.flatnonzero(missing.any(axis=1))
        patterns, inverse, _ = unique_rows(rows)
        groups = members(inverse, len(patterns))
        cache: dict[int, np.ndarray] = {}
        for p, pattern in enumerate(patterns):
            targets = np.flatnonzero(pattern & ~missing.all(axis=0))
            if len(targets) == 0:
                continue
            ws = []
            for m in targets:
                if m not in cache:
                    cache[m] = gaussian_weights(distance_to(m), scale)
                ws.append(cache[m])
            weight = np.max(ws, axis=0)
            weight[targets] = missing_weight
            tasks.append((targets, frames_any[groups[p]], weight))
    else:
        raise MethodError(f"pca strategy must be 'separate' or 'joint', got {strategy!r}")

    for targets, frames, weight in tasks:
        # Frames of this task grouped by which other markers are observed there: each group gets the predictors
        # observed throughout it (at most ``max_patterns`` groups per task, to bound the cost on messy data).
        others = np.ones(n_markers, dtype=bool)
        others[targets] = False
        # Markers beyond ``reach`` widths weigh < 3.4e-4 (for reach 4): the published method keeps them with that
        # negligible weight; leaving them out changed no benchmark figure and cuts the cost of each decomposition.
        candidates = np.flatnonzero(others & (weight > np.exp(-0.5 * reach ** 2)))
        rms = None
        for group, predictors in pattern_groups(missing, frames, candidates, max_patterns):
            needed = np.concatenate([targets, predictors])
            train = np.flatnonzero(~train_missing[:, needed].any(axis=1))
            if len(predictors) == 0 or len(train) < MIN_TRAINING_FRAMES:
                for m in targets:
                    info["fallback"].append(int(m))
                    est = linear_fallback(local[:, m], missing[:, m])
                    estimate[group, m] = est[group]
                continue
            gram = None
            if row_w is not None:
                cols = np.concatenate([_columns(targets), _columns(predictors)])
                gram = weighted_sums(train_flat[np.ix_(train, cols)], row_w[train])
            model = fit_model(train_flat, train, targets, predictors, weight, variance=variance,
                              normalise=normalise, gram=gram)
            est, leverage = predict(model, flat[group])
            estimate[np.ix_(group, targets)] = est.reshape(len(group), len(targets), 3)
            info["components"].append(int(model.basis.shape[1]))
            if uncertainty:
                if rms is None:  # cross-validated on the task's largest group; its other groups reuse it (cost)
                    rms = cross_validated_rms(train_flat, train, targets, predictors, weight, variance=variance,
                                              normalise=normalise, folds=folds)
                std[np.ix_(group, targets)] = rms[None, :] * np.sqrt(1.0 + leverage)[:, None]
    info["fallback"] = sorted(set(info["fallback"]))
    return estimate + reference, std, info
