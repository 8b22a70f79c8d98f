"""``msvd``: iterative low-rank SVD imputation.

The capture is a matrix X of shape (n_frames, 3 * n_markers) (one row per frame).  Missing entries start from the
per-marker linear interpolation (edges held), the columns are centred, and the rank r is fixed once as the smallest
rank holding ``energy`` of the squared singular values of that initial matrix.  Each iteration then

1. re-centres the columns and takes the rank-r right singular subspace V of the current (completed) matrix,
2. re-estimates the missing entries of every frame from the least-squares fit of its observed entries on V,

until the relative change of the missing entries falls below ``tol`` or ``max_iter`` is reached (then a
:class:`ConvergenceWarning`).  This is the alternating form of SVD imputation: it minimises the same objective as
repeated "SVD, reconstruct, replace the missing entries" (the squared error on the observed entries over rank-r
matrices) and, like it, never increases that objective (reported per iteration as an RMS in data units), but
converges in far fewer iterations on long gaps.  Frames with no observed entry (whole-body blackouts) keep their
linear interpolation: a shape model alone has nothing to fit there.

Shapes: ``positions`` is ``(n_frames, n_markers, 3)`` float64 with NaN = missing.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import ConvergenceWarning, MethodError
from ..gaps import all_missing_markers, missing_mask
from .base import FillResult, ProgressFn, finish
from .interp import interpolate_linear
from ..runtime.blas import single_blas_thread


def energy_rank(singular_values: np.ndarray, energy: float) -> int:
    """Smallest r such that the first r squared singular values hold at least ``energy`` of their sum (>= 1)."""
    power = np.asarray(singular_values, dtype=np.float64) ** 2
    total = power.sum()
    if total <= 0:
        return 1
    return int(min(np.searchsorted(np.cumsum(power) / total, energy) + 1, power.size))


def fill_msvd(
    positions: np.ndarray,
    *,
    energy: float = 0.999,
    rank: int | None = None,
    max_iter: int = 200,
    tol: float = 1e-5,
    seed: int | None = None,
    progress: ProgressFn | None = None,
) -> FillResult:
    """Fill gaps by iterative rank-r SVD reconstruction.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    energy : float in (0, 1]
        Fraction of the squared singular values (of the centred, linearly pre-filled matrix) the rank must keep.
    rank : int, optional
        Use this rank instead of the energy rule (clipped to the matrix size).
    max_iter : int
        Iteration cap; hitting it issues a ConvergenceWarning.
    tol : float
        Stop when ||X_new - X_old|| / ||X_old|| over the missing entries (centred) is below this.
    seed : ignored (the method is deterministic); accepted for a uniform interface.
    progress : callable, optional
        ``progress(iteration, max_iter, objective)`` once per iteration.

    Returns
    -------
    FillResult
        ``positions`` (n_frames, n_markers, 3); ``objective`` the RMS residual on the observed entries per
        iteration (data units); ``info`` holds ``rank`` and ``all_missing`` (markers never observed, left NaN).
    """
    if not 0 < energy <= 1:
        raise MethodError(f"msvd: energy must be in (0, 1], got {energy}")
    if max_iter < 0:
        raise MethodError(f"msvd: max_iter must be >= 0, got {max_iter}")
    positions = np.asarray(positions, dtype=np.float64)
    n_frames, n_markers, _ = positions.shape
    missing = missing_mask(positions)
    dead = all_missing_markers(missing)
    info: dict = {"all_missing": [int(m) for m in dead]}
    live = np.setdiff1d(np.arange(n_markers), dead)
    if not missing.any() or live.size == 0 or not missing[:, live].any():
        return finish(positions, positions, info={**info, "rank": 0})

    start = interpolate_linear(positions)[:, live].reshape(n_frames, -1)
    hole = np.repeat(missing[:, live], 3, axis=1)  # (n_frames, 3 * n_live)
    mean = start.mean(axis=0)
    x = start - mean
    singular = np.linalg.svd(x, compute_uv=False)
    r = energy_rank(singular, energy) if rank is None else int(np.clip(rank, 1, singular.size))
    info["rank"] = r

    # Frames sharing one missing pattern are solved together (a gap gives a run of identical rows).
    patterns, which = np.unique(hole, axis=0, return_inverse=True)
    which = which.ravel()
    groups = [(pattern, np.flatnonzero(which == k)) for k, pattern in enumerate(patterns) if pattern.any()]

    objective: list[float] = []
    converged = max_iter == 0
    n_iter = 0
    # Many small LAPACK calls: BLAS threads gain nothing and, on busy cores, slow them down many times.
    with single_blas_thread():
        for n_iter in range(1, max_iter + 1):
            # The rank-r subspace is spanned by the top right singular vectors of the current matrix, i.e. the top
            # eigenvectors of the small (3M x 3M) Gram matrix: far cheaper than an SVD of the tall matrix.
            # The model is mean + rank r: re-centre on the current completion (the pre-fill's mean is biased).
            shift = x.mean(axis=0)
            x -= shift
            mean += shift
            gram = x.T @ x
            _, vecs = np.linalg.eigh((gram + gram.T) / 2)
            basis = vecs[:, ::-1][:, :r]
            old = x[hole]
            sq_resid = 0.0
            for pattern, rows in groups:
                seen = ~pattern
                if not seen.any():
                    # A blackout frame has nothing to fit: it keeps its interpolated start.
                    continue
                # Least-squares coefficients of each row's observed entries on the subspace (a tiny ridge keeps rows
                # with fewer observed entries than r well posed), then the missing entries from those coefficients.
                v_seen = basis[seen]
                lhs = v_seen.T @ v_seen + 1e-9 * np.eye(r)
                coef = np.linalg.solve((lhs + lhs.T) / 2, v_seen.T @ x[np.ix_(rows, seen)].T)
                x[np.ix_(rows, pattern)] = (basis[pattern] @ coef).T
                sq_resid += float(np.sum((v_seen @ coef - x[np.ix_(rows, seen)].T) ** 2))
            complete = ~hole.any(axis=1)
            if complete.any():
                low = x[complete] @ basis
                sq_resid += float(np.sum((low @ basis.T - x[complete]) ** 2))
            objective.append(float(np.sqrt(sq_resid / max(int((~hole).sum()), 1))))
            new = x[hole]
            if progress is not None:
                progress(n_iter, max_iter, objective[-1])
            change = np.linalg.norm(new - old) / max(np.linalg.norm(old), np.finfo(float).tiny)
            if change < tol:
                converged = True
                break
    if not converged:
        warnings.warn(f"msvd stopped after {max_iter} iterations before reaching tol={tol:g}",
                      ConvergenceWarning, stacklevel=2)
    estimate = np.full_like(positions, np.nan)
    estimate[:, live] = (x + mean).reshape(n_frames, live.size, 3)
    return finish(positions, estimate, n_iter=n_iter, converged=converged, objective=objective, info=info)
