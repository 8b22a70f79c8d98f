"""``bilinear``: the DCT-conditioned bilinear spatiotemporal model S = Theta C B^T (Akhter et al. 2012).

The capture is a matrix S of shape (F, 3P) (one row per frame, markers' x, y, z side by side), centred by its column
means mu.  The model (sections 3.4-3.5 of the paper) writes it as ``S - mu = Theta C B^T`` with

- Theta (F, K_t): the first K_t vectors of the orthonormal DCT-II basis (a predefined trajectory basis);
- B (3P, K_s): an orthonormal shape basis learned from the clip itself: the top right singular vectors of the
  centred, linearly pre-filled matrix (section 3.5.2 with a single training sequence);
- C (K_t, K_s): coefficients fitted to the observed entries only (section 4.2), by least squares.

B and mu are then re-learned up to ``refine`` times (default 20, or until the fill changes by less than ``tol``) from
the model's own completion (observed entries plus the model's reconstruction of the missing ones) and C refitted:
the alternating estimation of section 3.5, which removes the bias of the linear pre-fill.

The fit minimises ``sum over observed (i, j) of (S_ij - mu_j - (Theta C B^T)_ij)^2 + sum_k,s w_k C_ks^2`` with
``w_k = ridge + smooth * (pi k / L)^4``: ``(pi k / L)^4`` is the squared second difference of DCT vector k per frame
(L the window length), so the penalty is the paper's W_0 (heavier weight on high frequencies, section 4.3) sized
like a curvature penalty.  It is negligible (< 1 %) next to any coefficient the observations pin down and decides
the ones they do not, which is what makes whole-body blackouts come out as smooth bridges instead of dropping to
the mean shape.

A truncated shape basis misses every observed sample by some residual (tens of millimetres in world coordinates),
so a raw reconstruction would jump at each gap's ends.  With ``bridge`` (default) the residual of each coordinate
is interpolated linearly across the gap (held at the clip's ends) and added to the model: the model supplies the
motion inside the gap, the residual bridge makes it meet the observed samples on both sides.

Normal equations use the Kronecker structure: with orthonormal bases, a fully observed frame contributes
``theta_i theta_i^T (x) I``, so ``A = I - sum_g (Theta_g^T Theta_g) (x) (B_g^T B_g) + W``, one term per distinct
missing pattern g (the rows of B of the coordinates missing in it), solved by Cholesky.

Choice of K_s and K_t (documented rule):

- K_s: the smallest number of shape vectors holding ``shape_energy`` (default 99 %) of the centred shapes' energy.
- K_t: the DCT frequencies up to ``cutoff`` Hz (default 6 Hz, the bandwidth of human movement), i.e.
  ``K_t = ceil(2 L cutoff / rate) + 1`` for a window of L frames (DCT vector k oscillates at k * rate / (2 L) Hz).
  Without a frame rate, ``K_t = ceil(L / 10)``.

Long clips are solved in overlapping windows of ``window`` frames (default 5 s; hop window / 2, blended with
triangular weights), so memory stays bounded; only windows holding a missing sample are solved.  A window is never
shorter than four times the longest whole-body blackout, so every blackout has observed frames around it.  Cost
grows linearly with the clip (measured: 6 s for 10,000 frames x 41 markers, 1 % missing, one BLAS thread).

Shapes: ``positions`` is ``(n_frames, n_markers, 3)`` float64 with NaN = missing.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import MethodError
from ..gaps import all_missing_markers, blackout_frames, missing_mask, runs
from .base import FillResult, finish
from .interp import interpolate_linear
from ..runtime.blas import single_blas_thread
from .msvd import energy_rank


def dct_basis(n_frames: int, n_vectors: int) -> np.ndarray:
    """The first ``n_vectors`` orthonormal DCT-II basis vectors as columns, shape (n_frames, n_vectors)."""
    t = np.arange(n_frames)[:, None] + 0.5
    k = np.arange(n_vectors)[None, :]
    theta = np.cos(np.pi * t * k / n_frames) * np.sqrt(2.0 / n_frames)
    theta[:, 0] = np.sqrt(1.0 / n_frames)
    return theta


def n_trajectory_vectors(n_frames: int, rate: float | None, cutoff: float) -> int:
    """K_t for a window of ``n_frames``: the DCT vectors up to ``cutoff`` Hz (or n_frames / 10 without a rate)."""
    if rate is None or rate <= 0:
        k = math.ceil(n_frames / 10)
    else:
        k = math.ceil(2.0 * n_frames * cutoff / rate) + 1
    return int(min(max(k, 2), n_frames))


def fit_window(
    values: np.ndarray, hole: np.ndarray, shape_basis: np.ndarray, n_traj: int, *, smooth: float, ridge: float
) -> np.ndarray:
    """Fit C to the observed entries of one window and return the reconstruction Theta C B^T.

    Parameters
    ----------
    values : ndarray, shape (L, D)
        Centred window of the data matrix; entries under ``hole`` are ignored (may hold anything finite).
    hole : ndarray of bool, shape (L, D)
        True for missing entries.
    shape_basis : ndarray, shape (D, K_s)
        Orthonormal columns.
    n_traj : int
        K_t, the number of DCT vectors.

    Returns
    -------
    ndarray, shape (L, D): the model's reconstruction of the whole window.
    """
    length = values.shape[0]
    n_shape = shape_basis.shape[1]
    theta = dct_basis(length, n_traj)
    observed = np.where(hole, 0.0, values)
    rhs = theta.T @ observed @ shape_basis  # (K_t, K_s)

    # A = sum over observed entries of (theta_i theta_i^T) (x) (b_j b_j^T) as a (K_t, K_s, K_t, K_s) tensor: the
    # fully observed part is the identity; subtract one Kronecker term per distinct missing pattern.
    size = n_traj * n_shape
    patterns, which = np.unique(hole, axis=0, return_inverse=True)
    which = which.ravel()
    keep = np.flatnonzero(patterns.any(axis=1))
    if keep.size:
        traj_terms = np.empty((keep.size, n_traj * n_traj))
        shape_terms = np.empty((keep.size, n_shape * n_shape))
        for row, k in enumerate(keep):
            th = theta[which == k]
            bm = shape_basis[patterns[k]]
            traj_terms[row] = (th.T @ th).ravel()
            shape_terms[row] = (bm.T @ bm).ravel()
        missing_part = (traj_terms.T @ shape_terms).reshape(n_traj, n_traj, n_shape, n_shape)
        lhs = -missing_part.transpose(0, 2, 1, 3).reshape(size, size)
    else:
        lhs = np.zeros((size, size))
    freq = (np.pi * np.arange(n_traj) / length) ** 4
    penalty = np.repeat(ridge + smooth * freq, n_shape)
    lhs[np.diag_indices(size)] += 1.0 + penalty
    lhs = (lhs + lhs.T) / 2
    try:
        factor = np.linalg.cholesky(lhs)
        coef = np.linalg.solve(factor.T, np.linalg.solve(factor, rhs.ravel()))
    except np.linalg.LinAlgError:  # pragma: no cover - the ridge keeps A positive definite
        coef = np.linalg.lstsq(lhs, rhs.ravel(), rcond=None)[0]
    return theta @ coef.reshape(n_traj, n_shape) @ shape_basis.T


def _windows(n_frames: int, window: int) -> list[tuple[int, int]]:
    """(start, stop) of windows of ``window`` frames with hop window // 2 covering 0..n_frames."""
    if n_frames <= window:
        return [(0, n_frames)]
    hop = max(window // 2, 1)
    starts = list(range(0, n_frames - window, hop)) + [n_frames - window]
    return [(s, s + window) for s in sorted(set(starts))]


def _fit_windows(centred: np.ndarray, hole: np.ndarray, shape_basis: np.ndarray, spans: list[tuple[int, int]], *,
                 rate: float | None, cutoff: float, smooth: float, ridge: float) -> np.ndarray:
    """Model reconstruction (F, D) of every window holding a missing entry, blended; 0 on frames no window solved."""
    n_frames = centred.shape[0]
    total = np.zeros_like(centred)
    weight = np.zeros(n_frames)
    for a, b in spans:
        if not hole[a:b].any():
            continue
        length = b - a
        with single_blas_thread():  # moderate sizes: threads on busy cores cost more than they give
            fit = fit_window(centred[a:b], hole[a:b], shape_basis, n_trajectory_vectors(length, rate, cutoff),
                             smooth=smooth, ridge=ridge)
        # Triangular weights favour each window's centre, where the DCT fit is least affected by the window edges.
        w = np.minimum(np.arange(1, length + 1), np.arange(length, 0, -1)).astype(np.float64)
        if a == 0:
            w[: length // 2] = w.max()
        if b == n_frames:
            w[length // 2:] = w.max()
        total[a:b] += fit * w[:, None]
        weight[a:b] += w
    return np.where(weight[:, None] > 0, total / np.maximum(weight, 1e-300)[:, None], 0.0)


def fill_bilinear(
    positions: np.ndarray,
    *,
    rate: float | None = None,
    cutoff: float = 6.0,
    shape_energy: float = 0.99,
    n_shape: int | None = None,
    window: int | None = None,
    smooth: float = 100.0,
    ridge: float = 1e-8,
    bridge: bool = True,
    refine: int = 20,
    tol: float = 1e-4,
    seed: int | None = None,
) -> FillResult:
    """Fill gaps with the DCT-conditioned bilinear model fitted to the observed entries.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    rate : float, optional
        Frame rate in Hz (context keyword); sets K_t through ``cutoff``.
    cutoff : float
        Highest DCT frequency kept, Hz (K_t = ceil(2 L cutoff / rate) + 1 for a window of L frames).
    shape_energy : float in (0, 1]
        Energy of the centred shapes the shape basis keeps (sets K_s).
    n_shape : int, optional
        K_s given directly instead of by ``shape_energy`` (clipped to 1..3P).
    window : int, optional
        Frames per solved window (clips up to this length are solved in one piece); default 5 s of frames
        (``5 * rate``), or 500 frames without a rate.  K_t grows with it, and the cost with K_t^3.
    smooth : float
        Weight of the curvature-like penalty on the DCT coefficients (see the module docstring).
    ridge : float
        Plain ridge on every coefficient (keeps the normal equations positive definite).
    bridge : bool
        Add the model's residual, linearly interpolated across each gap from the observed samples around it, so
        that the fill joins the data continuously (see the module docstring).
    refine : int
        Most times the mean and shape basis are re-learned from the model's own completion (then C refitted); 0
        keeps the basis of the linear pre-fill.
    tol : float
        Stop re-learning when the missing entries change by less than this, relative to their (centred) norm.
    seed : ignored (the method is deterministic); accepted for a uniform interface.

    Returns
    -------
    FillResult
        ``positions`` (n_frames, n_markers, 3); every marker observed at least once is filled, including
        whole-body blackouts; ``info`` holds ``n_shape`` (K_s), ``n_traj`` (K_t of a full window), ``window`` and
        ``all_missing`` (markers never observed, left NaN).
    """
    if not 0 < shape_energy <= 1:
        raise MethodError(f"bilinear: shape_energy must be in (0, 1], got {shape_energy}")
    if window is None:
        window = int(round(5 * rate)) if rate is not None and rate > 0 else 500
    if cutoff <= 0 or window < 2 or smooth < 0 or ridge < 0:
        raise MethodError("bilinear: cutoff must be > 0, window >= 2, smooth >= 0 and ridge >= 0")
    positions = np.asarray(positions, dtype=np.float64)
    n_frames, n_markers, _ = positions.shape
    missing = missing_mask(positions)
    dead = all_missing_markers(missing)
    info: dict = {"all_missing": [int(m) for m in dead]}
    live = np.setdiff1d(np.arange(n_markers), dead)
    if not missing.any() or live.size == 0 or not missing[:, live].any():
        return finish(positions, positions, info=info)

    start = interpolate_linear(positions)[:, live].reshape(n_frames, -1)  # (F, 3P)
    hole = np.repeat(missing[:, live], 3, axis=1)
    mean = start.mean(axis=0)
    centred = start - mean
    _, singular, vt = np.linalg.svd(centred, full_matrices=False)
    n_shape = energy_rank(singular, shape_energy) if n_shape is None else int(np.clip(n_shape, 1, singular.size))
    shape_basis = vt[:n_shape].T  # (3P, K_s)

    longest_blackout = max((length for _, length in runs(np.isin(np.arange(n_frames),
                                                                 blackout_frames(missing)))), default=0)
    window = int(max(window, 4 * longest_blackout))
    spans = _windows(n_frames, window)
    fit = _fit_windows(centred, hole, shape_basis, spans, rate=rate, cutoff=cutoff, smooth=smooth, ridge=ridge)
    rounds = 0
    for rounds in range(1, refine + 1):
        # Re-learn the mean and the shape basis from the model's completion instead of the linear pre-fill
        # (alternating between B and C, as the paper's iterative bilinear estimation), then refit C.
        completed = np.where(hole, fit, centred) + mean
        mean = completed.mean(axis=0)
        centred = np.where(hole, 0.0, start - mean)
        _, _, vt = np.linalg.svd(completed - mean, full_matrices=False)
        shape_basis = vt[:n_shape].T
        before = completed[hole]
        fit = _fit_windows(centred, hole, shape_basis, spans, rate=rate, cutoff=cutoff, smooth=smooth, ridge=ridge)
        after = (fit + mean)[hole]
        if np.linalg.norm(after - before) <= tol * max(np.linalg.norm(before - mean[np.nonzero(hole)[1]]), 1e-300):
            break
    if bridge:
        # The low-rank model misses each observed sample by its residual; interpolating that residual across each
        # gap makes the fill meet the data at both ends instead of jumping to the model's reconstruction.
        resid = np.where(hole, np.nan, centred - fit).reshape(n_frames, live.size, 3)
        fit = fit + interpolate_linear(resid).reshape(n_frames, -1)
    estimate_live = fit + mean
    estimate = np.full_like(positions, np.nan)
    estimate[:, live] = estimate_live.reshape(n_frames, live.size, 3)
    info.update(refine=int(rounds), n_shape=int(n_shape),
                n_traj=n_trajectory_vectors(min(window, n_frames), rate, cutoff),
                window=int(min(window, n_frames)))
    return finish(positions, estimate, info=info)
