"""Where a marker is, given only the markers seen with it: their mean offsets, translation only.

The model: over the frames where markers j and k are both observed, x_j - x_k has mean d_jk and variance v_jk
per coordinate.  At a frame where j is missing, each observed k predicts x_k + d_jk; the anchor is their
inverse-variance weighted mean and its variance per coordinate the weighted mean of the v_jk (the errors of the
k are correlated, a rotation of the body moves them together, so averaging does not shrink it).  It knows no
rotation, so it is coarse; but it lies inside the body by construction and its variance is the spread the capture
showed, which is what a fill needs where nothing better predicts (a gap at a take's end, a marker seen in a few
frames): without it, the motion model alone carries the last velocity and acceleration out of the body.

A pair seen together in few frames has a variance estimate that knows little of the body's rotations: it is
shrunk towards |d_jk|^2 / 3 (per coordinate, a point anywhere on the sphere of radius |d_jk| about marker k) with
the weight of one second of frames, about the time over which a body's pose decorrelates.  Where nothing seen
with a marker is observed (a blackout of the whole body), :func:`held` keeps the nearest frame's anchor.
"""

from __future__ import annotations

import numpy as np


def body_anchor(positions: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The anchor of every sample (module docstring).

    positions (n_frames, n_markers, 3), NaN = missing; rate frames per second.  Returns the anchor (n_frames,
    n_markers, 3), its sd per coordinate (n_frames, n_markers) (at frames where nothing seen with the marker is
    observed, the nearest anchored frame's, grown by :func:`held`; NaN for a marker never seen with another) and
    how many frames its error persists (:func:`error_memory`).
    """
    n_frames, n_markers, _ = positions.shape
    seen = np.isfinite(positions).all(axis=2)
    O = seen.astype(np.float64)
    centre = np.nanmean(positions[seen], axis=0) if seen.any() else np.zeros(3)
    X = np.where(seen[..., None], positions - centre, 0.0)  # centred: sums of squares without cancellation
    co = O.T @ O  # (M, M) frames both observed
    d = np.empty((n_markers, n_markers, 3))
    ss = np.zeros((n_markers, n_markers))
    for a in range(3):
        xa = X[:, :, a]
        A = xa.T @ O  # A[j, k] = sum over co-observed frames of x_j
        B = (xa ** 2).T @ O
        C = xa.T @ xa
        with np.errstate(invalid="ignore", divide="ignore"):
            d[:, :, a] = (A - A.T) / co
        ss += B + B.T - 2 * C
    with np.errstate(invalid="ignore", divide="ignore"):
        v_hat = np.maximum(ss / co - (d ** 2).sum(axis=2), 0.0) / 3.0
    prior = (d ** 2).sum(axis=2) / 3.0
    n_eff = co / max(float(rate), 1.0)  # seconds seen together
    v = (n_eff * v_hat + prior) / (n_eff + 1.0)
    ok = (co >= 2) & (v > 0)
    np.fill_diagonal(ok, False)
    w = np.where(ok, 1.0 / np.where(ok, v, 1.0), 0.0)  # (M, M), w[j, k]
    den = O @ w.T  # (T, M): sum over observed k of w_jk
    est = np.empty(positions.shape)
    for a in range(3):
        est[:, :, a] = (X[:, :, a] @ w.T + O @ (w * np.nan_to_num(d[:, :, a])).T)
    count = O @ ok.T.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        est = est / den[..., None] + centre
        var = count / den  # weighted mean of v with weights 1/v: the harmonic mean
    has = den > 0
    est, sd = np.where(has[..., None], est, np.nan), np.where(has, np.sqrt(var), np.nan)
    return (*held(est, sd, has, body_speed(X, seen)), error_memory(est - centre - X, seen & has, max_lag=int(rate)))


def error_memory(resid: np.ndarray, ok: np.ndarray, *, max_lag: int) -> float:
    """How many frames the anchor's error persists: the lag (frames, at least 1, at most ``max_lag``) at which the
    autocorrelation of its residuals at the observed samples falls to 1/e.  resid (n_frames, n_markers, 3), ok
    (n_frames, n_markers) where it is defined; each marker's residual taken about its mean (the offset a smoother
    learns at a gap's edge is no error)."""
    r = np.where(ok[..., None], resid, 0.0)
    r = r - r.sum(axis=0) / np.maximum(ok.sum(axis=0), 1)[:, None]  # (a marker never anchored where seen: no mean)
    r = np.where(ok[..., None], r, 0.0)
    power = float((r ** 2).sum())
    if power <= 0:
        return 1.0
    prev = 1.0
    for lag in range(1, min(max_lag, len(r) - 1) + 1):
        both = ok[lag:] & ok[:-lag]
        if not both.any():
            break
        a, b = r[lag:][both], r[:-lag][both]
        aa = (a ** 2).sum()
        c = float((a * b).sum() / np.sqrt(aa * (b ** 2).sum())) if aa > 0 else 0.0
        if c < np.exp(-1.0):
            return max(1.0, lag - 1 + (prev - np.exp(-1.0)) / max(prev - c, 1e-12))
        prev = c
    return float(max_lag)


def body_speed(X: np.ndarray, seen: np.ndarray) -> float:
    """The RMS observed frame-to-frame step per coordinate (data units per frame) of X (n_frames, n_markers, 3),
    seen (n_frames, n_markers): how fast the body moves, typically."""
    both = seen[1:] & seen[:-1]
    if not both.any():
        return 0.0
    return float(np.sqrt(np.mean(np.diff(X, axis=0)[both] ** 2)))


def held(est: np.ndarray, sd: np.ndarray, has: np.ndarray, speed: float) -> tuple[np.ndarray, np.ndarray]:
    """Frames where a marker has no anchor (nothing seen with it, a blackout of the whole body) take the anchor of
    its nearest frame that has one, its sd grown by ``speed`` per frame away from it: the body may have moved on at
    its usual pace, in a direction nobody saw.  est (n_frames, n_markers, 3), sd / has (n_frames, n_markers)."""
    n = len(has)
    idx = np.arange(n)[:, None]
    before = np.maximum.accumulate(np.where(has, idx, -1), axis=0)
    after = np.minimum.accumulate(np.where(has, idx, n)[::-1], axis=0)[::-1]
    gap_b = np.where(before >= 0, idx - before, n + 1)
    gap_a = np.where(after < n, after - idx, n + 1)
    src = np.where(gap_b <= gap_a, before, after)
    dist = np.minimum(gap_b, gap_a)
    todo = ~has & (dist <= n)
    if not todo.any():
        return est, sd
    cols = np.broadcast_to(np.arange(has.shape[1]), has.shape)
    src = np.clip(src, 0, n - 1)
    est = np.where(todo[..., None], est[src, cols], est)
    sd = np.where(todo, sd[src, cols] + speed * dist, sd)
    return est, sd
