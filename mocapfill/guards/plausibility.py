"""Is a fill physically plausible?  The body's observed extent and each marker's observed speed.

Two checks every fill of the default must pass (issue 9), measured on the input's own observations only:

- **extent**: no filled sample farther from the body's centre (per frame, the coordinate-wise median of the markers
  observed there; interpolated over frames with none) than ``EXTENT`` (1.1) times the farthest any observed marker
  ever is from it;
- **speed**: no frame-to-frame step touching a filled sample longer than ``SPEED`` (1.5) times its marker's largest
  observed step (:func:`observed_speed`).

:func:`implausible` marks the filled samples that break either; the default distrusts its model there and falls back
to something calm (a straight line through the observations, the nearest value held at the clip's edges).
"""

from __future__ import annotations

import numpy as np

from ..methods.interp import interpolate_columns

#: Filled samples may reach this multiple of the farthest observed distance from the body's centre ...
EXTENT = 1.1
#: ... and step at most this multiple of their marker's largest observed step.
SPEED = 1.5
#: Observed steps needed to know a marker's speed.
MIN_STEPS = 10


def observed_speed(positions: np.ndarray, missing: np.ndarray, *, floor: float) -> np.ndarray:
    """Each marker's largest observed frame-to-frame step (n_markers,), in data units per frame.

    positions (n_frames, n_markers, 3); missing (n_frames, n_markers).  Markers with fewer than ``MIN_STEPS``
    observed steps (too few to know how fast they move) get the largest over the markers; every value is at least
    ``floor`` and a quarter of the markers' median (a nearly still marker's noise is no speed limit).
    """
    both = ~missing[1:] & ~missing[:-1]
    step = np.where(both, np.linalg.norm(np.nan_to_num(np.diff(positions, axis=0)), axis=2), 0.0)
    speed = step.max(axis=0) if len(step) else np.zeros(positions.shape[1])
    known = both.sum(axis=0) >= MIN_STEPS
    if known.any():
        speed[~known] = speed[known].max()
        lower = 0.25 * np.median(speed[known])
    else:
        speed[:] = floor
        lower = floor
    return np.maximum(speed, max(floor, lower))


def body_centre(positions: np.ndarray, missing: np.ndarray) -> tuple[np.ndarray, float]:
    """Per-frame centre (n_frames, 3) and the farthest observed distance from it (data units).

    positions (n_frames, n_markers, 3), missing (n_frames, n_markers).  The centre is the coordinate-wise median of
    the markers observed in the frame, linearly interpolated (edges held) over frames with none; NaN throughout
    when nothing is observed (the radius is then NaN).
    """
    seen = np.where(missing[..., None], np.nan, positions)
    none = missing.all(axis=1)
    centre = np.full((positions.shape[0], 3), np.nan)
    if (~none).any():
        centre[~none] = np.nanmedian(seen[~none], axis=1)
        centre = interpolate_columns(centre, np.repeat(none[:, None], 3, axis=1))
    dist = np.linalg.norm(seen - centre[:, None, :], axis=2)
    radius = float(np.nanmax(dist)) if np.isfinite(dist).any() else float("nan")
    return centre, radius


def implausible(estimate: np.ndarray, positions: np.ndarray, speed: np.ndarray, *, factor: float = SPEED
                ) -> np.ndarray:
    """Filled samples (n_frames, n_markers) bool that leave the body's extent or step too fast.

    estimate (n_frames, n_markers, 3) the fill; positions (n_frames, n_markers, 3) the input, NaN = missing;
    speed (n_markers,) the largest observed step per marker (:func:`observed_speed`), or (n_frames - 1,
    n_markers) a per-step reference; a step longer than ``factor`` times it marks the filled sample(s) at either
    end of it.
    """
    speed = np.asarray(speed)
    if speed.ndim == 1:
        speed = speed[None, :]
    return _implausible(estimate, positions, factor * speed)


def _implausible(estimate: np.ndarray, positions: np.ndarray, speed: np.ndarray, extent: float = EXTENT
                 ) -> np.ndarray:
    """:func:`implausible` with ``speed`` broadcastable to (n_frames - 1, n_markers)."""
    missing = np.isnan(positions).any(axis=2)
    filled = missing & np.isfinite(estimate).all(axis=2)
    centre, radius = body_centre(positions, missing)
    out = np.zeros_like(filled)
    if np.isfinite(radius):
        far = np.linalg.norm(estimate - centre[:, None, :], axis=2) > extent * radius
        out |= far & filled
    step = np.nan_to_num(np.linalg.norm(np.diff(estimate, axis=0), axis=2), nan=0.0)
    fast = step > speed
    out[1:] |= fast & filled[1:]
    out[:-1] |= fast & filled[:-1]
    return out


def plausibility(estimate: np.ndarray, positions: np.ndarray, *, floor: float = 0.0) -> dict[str, float]:
    """Worst ratios of a fill: ``extent`` (largest filled distance from the centre over the farthest observed) and
    ``speed`` (largest step touching a filled sample over its marker's largest observed step).

    estimate / positions (n_frames, n_markers, 3) as in :func:`implausible`; ``floor`` the slowest speed limit
    (data units per frame).  0 when nothing is filled.
    """
    missing = np.isnan(positions).any(axis=2)
    filled = missing & np.isfinite(estimate).all(axis=2)
    if not filled.any():
        return {"extent": 0.0, "speed": 0.0}
    centre, radius = body_centre(positions, missing)
    dist = np.linalg.norm(estimate - centre[:, None, :], axis=2)
    extent = float(dist[filled].max() / radius) if np.isfinite(radius) and radius > 0 else float("nan")
    speed = observed_speed(positions, missing, floor=floor)
    step = np.linalg.norm(np.diff(estimate, axis=0), axis=2) / speed[None, :]
    touch = (filled[1:] | filled[:-1]) & np.isfinite(step)
    return {"extent": extent, "speed": float(step[touch].max()) if touch.any() else 0.0}


def project_plausible(estimate: np.ndarray, positions: np.ndarray, speed: np.ndarray, *, factor: float = SPEED,
                      extent: float = EXTENT, iterations: int = 3000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move every filled run that breaks the extent or speed bound to the nearest path that keeps both.

    Model: for a run x_1..x_L of one marker's filled samples, between observed (or held) x_0 and x_{L+1} where the
    clip has them, minimise sum_t |x_t - y_t|^2 (y the fill) subject to |x_{t+1} - x_t| <= v (every step touching
    the run; v = ``factor`` x the marker's ``speed``) and |x_t - c_t| <= r (c_t the body's centre, r = ``extent`` x
    the farthest observed distance from it, :func:`body_centre`).  Both sets are convex: ADMM splits them into a
    banded linear solve and two projections onto balls.  A run the solver leaves outside the bounds (slow
    convergence) is moved towards a straight line through its ends by the least fraction that puts it inside; a run
    where even that line breaks a bound gets one more ADMM pass from the calmest candidate (the world line, the line
    following the body, or the speed-only path); if that fails too (its observed ends are farther apart than v
    allows), the calmest candidate stays and the run is reported as ``forced``.

    estimate / positions (n_frames, n_markers, 3), NaN = missing in ``positions``; speed (n_markers,) the largest
    observed steps (:func:`observed_speed`), or (n_frames - 1, n_markers) a reference per step.  Returns the
    corrected estimate, the (n_frames, n_markers) mask of moved samples and the mask of runs forced by their
    observations.
    """
    from ..gaps import runs

    missing = np.isnan(positions).any(axis=2)
    filled = missing & np.isfinite(estimate).all(axis=2)
    n = len(estimate)
    bound = factor * np.broadcast_to(np.asarray(speed, dtype=float).reshape(-1, estimate.shape[1]),
                                     (max(n - 1, 0), estimate.shape[1]))
    bad = _implausible(estimate, positions, bound, extent)
    out = estimate.copy()
    moved = np.zeros_like(filled)
    forced = np.zeros_like(filled)
    if not bad.any():
        return out, moved, forced
    centre, radius = body_centre(positions, missing)
    reach = extent * radius if np.isfinite(radius) else np.inf
    with np.errstate(all="ignore"):  # the filled body's median: calmer than the observed markers' (no jumps where
        follow = np.nanmedian(np.where(np.isfinite(estimate), estimate, np.nan), axis=1)  # one of them vanishes)
    follow = np.where(np.isfinite(follow), follow, centre)
    for m in np.flatnonzero(bad.any(axis=0)):
        for start, length in runs(filled[:, m]):
            sl = slice(start, start + length)
            if not bad[sl, m].any():
                continue
            left = estimate[start - 1, m] if start > 0 and np.isfinite(estimate[start - 1, m]).all() else None
            right = (estimate[start + length, m] if start + length < n and np.isfinite(estimate[start + length, m]).all()
                     else None)
            v = bound[start - 1 if left is not None else start:start + length - (0 if right is not None else 1), m]
            path, ok = _plausible_run(estimate[sl, m], left, right, v, centre[sl], reach, iterations,
                                      follow[start - 1 if left is not None else start:
                                             start + length + (1 if right is not None else 0)])
            out[sl, m] = path
            moved[sl, m] = True
            forced[sl, m] = not ok
    return out, moved, forced


def _steps(path: np.ndarray, left, right) -> np.ndarray:
    """Step lengths (k,) of a run (L, 3) including the steps from ``left`` and to ``right`` where given."""
    parts = ([left[None]] if left is not None else []) + [path] + ([right[None]] if right is not None else [])
    return np.linalg.norm(np.diff(np.concatenate(parts), axis=0), axis=1)


def _inside(path, left, right, v, centre, reach) -> bool:
    return bool((_steps(path, left, right) <= v * (1 + 1e-9)).all()
                and (np.linalg.norm(path - centre, axis=1) <= reach * (1 + 1e-9)).all())


def _line(length: int, left, right, fill: np.ndarray) -> np.ndarray:
    """A straight line (length, 3) between the run's ends; the end held where only one exists."""
    if left is not None and right is not None:
        w = np.arange(1, length + 1)[:, None] / (length + 1)
        return (1 - w) * left + w * right
    end = left if left is not None else right
    return np.repeat((end if end is not None else fill.mean(axis=0))[None], length, axis=0)


def _plausible_run(fill, left, right, v, centre, reach, iterations, follow) -> tuple[np.ndarray, bool]:
    """One run of :func:`project_plausible`: fill / centre (L, 3), ends (3,) or None, v (k,) the step bounds,
    follow (L + ends, 3) the filled body's median over the run and its ends.  Returns the path and whether it keeps
    both bounds."""
    world = _line(len(fill), left, right, fill)
    if left is not None and right is not None and np.linalg.norm(right - left) > np.sum(v) * (1 + 1e-9):
        # the ends are farther apart than all the allowed steps together reach: no path keeps the bound; the
        # straight line has the smallest largest step there is
        return world, False
    path = _nearest_path(fill, left, right, 0.97 * v, centre, 0.97 * reach, iterations)
    if _inside(path, left, right, v, centre, reach):
        return path, True
    # straight lines through the ends: in the world, and following the body (keeping the marker's offset from it)
    lo = 1 if left is not None else 0
    inner = follow[lo:lo + len(fill)]
    offset = _line(len(fill), None if left is None else left - follow[0], None if right is None else
                   right - follow[-1], fill - inner)
    lines = [world, inner + offset]
    best = None
    for line in lines:
        mixed = _towards(path, line, lambda p: _inside(p, left, right, v, centre, reach))
        if mixed is not None and (best is None or mixed[1] < best[1]):
            best = mixed
    if best is not None:
        return best[0], True
    # the bounds cannot both hold (the observed ends are too far apart, or the centre jumps where markers vanish):
    # the calmest candidate, by its worst ratio to either bound
    speed_only = _nearest_path(fill, left, right, 0.97 * v, centre, np.inf, iterations)

    def worst(p):
        return max(float(np.max(_steps(p, left, right) / v)),
                   float(np.max(np.linalg.norm(p - centre, axis=1) / reach)) if np.isfinite(reach) else 0.0)
    calmest = min(lines + [speed_only], key=worst)
    # ADMM may not have converged from the fill (a long run far outside: a sprint out of the volume): once
    # more from the calmest candidate, which is usually near a feasible path when there is one
    again = _nearest_path(calmest, left, right, 0.97 * v, centre, 0.97 * reach, iterations)
    if _inside(again, left, right, v, centre, reach):
        return again, True
    return calmest, False


def _towards(path, line, feasible) -> tuple[np.ndarray, float] | None:
    """``path`` moved towards ``line`` by the least fraction (bisection) that is ``feasible``, with the fraction;
    None when even the line is not."""
    if feasible(path):
        return path, 0.0
    if not feasible(line):
        return None
    lo, hi = 0.0, 1.0  # both bounds are convex: every fraction above a feasible one is feasible too
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if feasible((1 - mid) * path + mid * line):
            hi = mid
        else:
            lo = mid
    return (1 - hi) * path + hi * line, hi


def _nearest_path(fill: np.ndarray, left, right, v, centre: np.ndarray, reach: float,
                  iterations: int) -> np.ndarray:
    """ADMM for :func:`project_plausible`'s problem on one run: fill / centre (L, 3); left / right (3,) or None;
    v (k,) the bounds of the steps that exist (from ``left``, between the run's samples, to ``right``).

    Splitting: s = D x + b (the steps, b carrying the fixed ends) and w = x, with scaled duals u, q and penalty rho;
    the x-update solves ((1 + rho) I + rho D^T D) x = y + rho D^T (s - u - b) + rho (w - q), a banded system
    factored once.  The steps are kept as an (L + 1, 3) array, step j from sample j - 1 to j, with the absent end
    steps held at zero, so D and D^T are two slices.
    """
    from scipy.linalg import cho_solve_banded, cholesky_banded

    length = len(fill)
    has = np.ones(length + 1, dtype=bool)
    has[0], has[-1] = left is not None, right is not None
    bound = np.zeros(length + 1)
    bound[has] = v
    zero = np.zeros(3)

    def apply_d(x):  # (L + 1, 3) steps; absent end steps 0
        out = np.empty((length + 1, 3))
        out[1:-1] = x[1:] - x[:-1]
        out[0] = x[0] - left if left is not None else zero
        out[-1] = right - x[-1] if right is not None else zero
        return out

    def apply_dt(steps):  # D^T: into a sample minus out of it
        return steps[:-1] - steps[1:]

    scale = max(float(np.max(v)), 1e-12)
    rho = 1.0
    degree = has[:-1].astype(float) + has[1:]
    bands = np.zeros((2, length))  # upper form: bands[1] the diagonal, bands[0, 1:] the superdiagonal
    bands[1] = 1.0 + rho + rho * degree
    bands[0, 1:] = -rho
    factor = cholesky_banded(bands)
    x = fill.copy()
    s = _clip_norm(apply_d(x), bound)
    w = _clip_ball(x, centre, reach)
    u = np.zeros_like(s)
    q = np.zeros_like(x)
    # D^T b: the fixed ends pull the first and last samples towards them
    ends = np.zeros_like(x)
    if left is not None:
        ends[0] += left
    if right is not None:
        ends[-1] += right
    for it in range(iterations):
        x = cho_solve_banded((factor, False), fill + rho * (apply_dt(s - u) + ends) + rho * (w - q))
        dx = apply_d(x)
        s = _clip_norm(dx + u, bound)
        w = _clip_ball(x + q, centre, reach)
        u += dx - s
        q += x - w
        if it % 25 == 24:
            if _inside(x, left, right, v / 0.97, centre, reach / 0.97):
                break  # inside the true bounds (the targets carry a 3 % margin): near enough
            if np.abs(dx - s).max() < 1e-4 * scale and np.abs(x - w).max() < 1e-4 * scale:
                break
    return x


def _clip_norm(vectors: np.ndarray, bound) -> np.ndarray:
    """Rows of ``vectors`` (k, 3) shortened to length ``bound`` (scalar or (k,)) where longer."""
    norm = np.linalg.norm(vectors, axis=1, keepdims=True)
    return vectors * np.minimum(1.0, np.reshape(bound, (-1, 1)) / np.maximum(norm, 1e-300))


def _clip_ball(points: np.ndarray, centre: np.ndarray, reach: float) -> np.ndarray:
    """Points (L, 3) moved onto the ball of radius ``reach`` around ``centre`` (L, 3) where outside it."""
    if not np.isfinite(reach):
        return points
    return centre + _clip_norm(points - centre, reach)
