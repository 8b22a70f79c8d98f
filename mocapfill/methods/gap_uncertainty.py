"""How wrong a fill is likely to be inside a long gap, measured on the capture itself (cross-validation).

A linear dynamical system's posterior hardly grows inside a long gap: the markers it still sees pin its state, and
its error comes from the gap's poses not being the ones it was fitted to, which the model cannot know.  So the
uncertainty of a long gap is measured instead: for the gap's missing markers S and the markers O seen throughout
it, a ridge regression of S on O (in the body frame the fill works in) is fitted on the frames where both are seen,
with a block as long as the gap held out, at :data:`BLOCKS` places; the RMS error on the held-out blocks is the
predicted RMS error per coordinate of the fill over the gap.  Held-out blocks make it an out-of-sample error: a
marker the others explain well gets a small one, a marker that moves on its own (a hand, a box carried about) a
large one.

Measured with ``python benchmarks/bench_dynammo.py --uncertainty`` (DynaMMo's gaps longer than 1 s, actual / this
predicted RMS error): see ``benchmarks/README.md``, issue 10, fourth session.  The DynaMMo posterior with a
Brownian drift fitted to three clips had a median ratio of 1.4 there and 3.8 on five clips it was not fitted to;
this has ~1 on both, and no ratio above 10 where the drift had 140.

Shapes: ``T`` frames, ``M`` markers; ``X`` (T, 3 M) with each marker's x, y, z consecutive.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..gaps import runs

#: Held-out blocks per gap, spread evenly over the frames where S and O are seen.
BLOCKS = 4
#: A held-out block is as long as the gap, but at most this share of those frames (the fit keeps the rest).
BLOCK_SHARE = 0.25
#: Ridge penalty, relative to the mean eigenvalue of the features' scatter matrix.
RIDGE = 1e-2
#: Gaps shorter than this (frames) keep the model's own variance; so do gaps past :data:`MAX_GAPS` (longest first).
MIN_FRAMES = 24
MAX_GAPS = 64
#: The error scales with the observed markers' RMS speed in the gap over that in the held-out blocks, within
#: [1 / MAX_ACTIVITY, MAX_ACTIVITY].
MAX_ACTIVITY = 10.0
#: At most this many training frames per regression (evenly thinned): bounded cost on long takes.
MAX_ROWS = 4000


def held_out_error(X: np.ndarray, observed: np.ndarray, hidden: np.ndarray, frames: np.ndarray,
                   speed: np.ndarray | None = None) -> float | None:
    """RMS error per coordinate of a ridge prediction of the ``hidden`` markers on blocks of held-out frames.

    X : (T, 3 M) coordinates (body frame); observed : (T, M) bool; hidden : (k,) marker indices (S);
    frames : (n,) the gap's frames (O = markers observed at all of them, besides S).
    Returns None when there is nothing to learn from (no O, or fewer than 8 usable frames per held-out block's fit).
    """
    T, M = observed.shape
    others = observed[frames].all(axis=0)
    others[hidden] = False
    if not others.any():
        return None
    rows = np.flatnonzero(observed[:, hidden].all(axis=1) & observed[:, others].all(axis=1))
    if len(rows) > MAX_ROWS:
        rows = rows[np.linspace(0, len(rows) - 1, MAX_ROWS).astype(np.intp)]
    n = len(rows)
    block = min(len(frames), int(BLOCK_SHARE * n))
    if block < 1 or n - block < 8:
        return None
    cols_o = (3 * np.flatnonzero(others)[:, None] + np.arange(3)).ravel()
    cols_s = (3 * np.asarray(hidden)[:, None] + np.arange(3)).ravel()
    # One scatter matrix over all the rows, each fit's by taking its block out: with an intercept column (not
    # penalised) this is the ridge on the fit's own centred data, at the cost of one pass over the rows.
    A_all = np.hstack([X[np.ix_(rows, cols_o)], np.ones((n, 1))])
    B_all = X[np.ix_(rows, cols_s)]
    d = A_all.shape[1] - 1
    gram_all, cross_all = A_all.T @ A_all, A_all.T @ B_all
    sq = 0.0
    held = np.zeros(n, bool)
    for start in np.linspace(0, n - block, BLOCKS).astype(np.intp):
        test = slice(start, start + block)
        held[test] = True
        At, Bt = A_all[test], B_all[test]
        gram = gram_all - At.T @ At
        sums, count = gram[:d, d], gram[d, d]
        centred_trace = np.trace(gram[:d, :d]) - float(sums @ sums) / count
        gram[np.arange(d), np.arange(d)] += RIDGE * max(centred_trace, 1e-300) / d
        W = np.linalg.solve(gram, cross_all - At.T @ Bt)
        sq += float(np.mean((At @ W - Bt) ** 2))
    err = float(np.sqrt(sq / BLOCKS))
    if speed is not None:  # the body moving twice as fast in the gap as in the held-out blocks: twice the error
        gap_power = np.nanmean(speed[np.ix_(frames, others)] ** 2)
        held_power = np.nanmean(speed[np.ix_(rows[held], others)] ** 2)
        if np.isfinite(gap_power) and np.isfinite(held_power) and held_power > 0:
            err *= float(np.clip(np.sqrt(gap_power / held_power), 1.0 / MAX_ACTIVITY, MAX_ACTIVITY))
    return err


def gap_variance(X: np.ndarray, observed: np.ndarray, speed: np.ndarray | None = None,
                 refit: Callable[[np.ndarray], np.ndarray | None] | None = None) -> np.ndarray:
    """(T, M) cross-validated error variance per coordinate of each sample in a long gap, NaN elsewhere.

    X : (T, 3 M) coordinates in the body frame (the missing entries are not read); observed : (T, M) bool;
    speed : (T, M) the markers' steps (:func:`marker_speed`) or None; ``refit(hidden)``: the coordinates in a body
    frame fitted without the ``hidden`` markers, or None when they are not among its markers.  Without it a frame
    marker's motion leaks into the others' body coordinates, where the regression finds it again (in the gap the
    frame is fitted without it).
    For each gap of at least :data:`MIN_FRAMES` frames (the :data:`MAX_GAPS` longest), S = the markers missing in
    most of its frames, and the gap's squared error ``e^2`` from :func:`held_out_error` is spread over it in the
    shape of a Brownian bridge (growing from the observed end alone at a capture edge), scaled so that its mean over
    the gap is ``e^2``: a fill is right at the ends of a gap and wrong most in its middle.  NaN where a gap is
    shorter, past the budget, or has nothing to learn from (the caller keeps the model's variance there).
    """
    T, M = observed.shape
    out = np.full((T, M), np.nan)
    missing = ~observed
    gaps = [(length, a, k) for k in range(M) if missing[:, k].any() and observed[:, k].any()
            for a, length in runs(missing[:, k]) if length >= MIN_FRAMES]
    gaps.sort(key=lambda g: -g[0])
    cache: dict[tuple, float | None] = {}
    for length, a, k in gaps[:MAX_GAPS]:
        frames = np.arange(a, a + length)
        hidden = np.flatnonzero((missing[frames].mean(axis=0) > 0.5) & observed.any(axis=0))
        if k not in hidden:
            hidden = np.union1d(hidden, [k])
        key = (tuple(hidden), tuple(observed[frames].all(axis=0)), length)
        if key not in cache:
            coords = refit(hidden) if refit is not None else None
            cache[key] = held_out_error(X if coords is None else coords, observed, hidden, frames, speed)
        err = cache[key]
        if err is None:
            continue
        t = np.arange(length, dtype=np.float64)
        if a > 0 and a + length < T:
            shape = (t + 1.0) * (length - t)
        elif a > 0:
            shape = t + 1.0
        else:
            shape = length - t
        out[frames, k] = err ** 2 * shape / shape.mean()
    return out


def marker_speed(positions: np.ndarray) -> np.ndarray:
    """(T, M) each marker's step length into each frame (data units per frame); NaN at frame 0 and wherever either
    end of the step is missing.  positions (T, M, 3), NaN = missing."""
    out = np.full(positions.shape[:2], np.nan)
    out[1:] = np.linalg.norm(np.diff(positions, axis=0), axis=2)
    return out
