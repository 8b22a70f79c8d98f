"""How wrong a fill is likely to be inside a gap, from a second opinion measured on the capture itself.

A linear dynamical system's posterior hardly grows inside a long gap: the markers it still sees pin its state, and
its error comes from the gap's poses not being the ones it was fitted to, which the model cannot know.  So the
uncertainty of a gap is measured instead, as the disagreement between the fill and an independent prediction: a
ridge regression of the missing marker on its nearest markers seen throughout the gap, fitted on the frames around
it where all of them are seen (in the body frame the fill works in), evaluated in the gap and bridged to the
observed frames on either side as the fill is.  Where the two agree, the gap's poses are ones the capture has shown
and both fills are probably right; where they part, at least one is wrong by about that much, and the fill's error
follows (the errors of two fills of the same gap are correlated, so it is the whole disagreement, not a share).

Measured with ``python benchmarks/bench_dynammo.py --uncertainty`` (actual / predicted RMS error per gap;
``benchmarks/README.md``, issue 10, fourth session).  Gaps longer than 1 s: the DynaMMo posterior with a Brownian
drift fitted to three clips had a median ratio of 1.4 there (59 % of gaps within 0.5-2) and 3.8 on five clips it
was not fitted to (35 %, one gap 140).  Tried and left: the regression's own error on held-out blocks as long as the
gap (55 % within 0.5-2 on the five clips: it says how hard the capture is, not how this fill went), the
disagreement without the bridge (88 % there instead of 95 %).

Shapes: ``T`` frames, ``M`` markers; ``X`` (T, 3 M) with each marker's x, y, z consecutive.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..gaps import brownian_variance, end_blend, runs

#: Gaps shorter than this (frames) keep the model's own variance; so do gaps past :data:`MAX_GAPS` (longest first;
#: each costs a ridge of ~40 features, a few ms).
MIN_FRAMES = 8
MAX_GAPS = 5000
#: Ridge penalty, relative to the mean eigenvalue of the features' centred scatter matrix.
RIDGE = 1e-2
#: Training frames: those within half this many frames of the gap, at most this many of them (evenly thinned).
MAX_ROWS = 1000
#: Fewer training frames than this: no second opinion (the model's variance stays).
MIN_ROWS = 16
#: At most this many frames of body frames are fitted again without a gap's frame markers (longest gaps first); past
#: it, a frame marker's opinion is taken in the fill's frame, which its own motion moved a little (a cost guard for
#: long takes: a full-rotation fit costs ~3 us per frame; a 72,000-frame take needs ~540,000).
REFIT_FRAMES = 200_000
#: The opinion comes from the marker's nearest markers seen throughout the gap (median distance over up to 200 frames
#: where it is seen): local, like a person's guess, and a bounded cost per gap.  On the 74 gaps of the benchmark, 12
#: or all of them make no difference to the ratios' spread (8-24 tried).
NEAREST = 12


def second_opinion(X: np.ndarray, observed: np.ndarray, hidden: np.ndarray, frames: np.ndarray) -> np.ndarray | None:
    """A ridge prediction of the ``hidden`` markers in the gap's ``frames`` from the markers seen throughout it.

    X : (T, 3 M) coordinates (body frame; only observed entries are read); observed : (T, M) bool;
    hidden : (k,) marker indices (S); frames : (n,) the gap's frames (O = the :data:`NEAREST` markers observed at all
    of them, besides S, nearest to S).
    Returns (n, 3 k), or None when there is nothing to learn from (no O, or fewer than :data:`MIN_ROWS` frames
    where S and O are all seen).
    """
    others = observed[frames].all(axis=0)
    others[hidden] = False
    if not others.any():
        return None
    # Learn from the frames around the gap only (a long take's poses drift over minutes; and a bounded cost).
    lo = max(0, int(frames[0]) - MAX_ROWS // 2)
    hi = min(len(X), int(frames[-1]) + 1 + MAX_ROWS // 2)
    X, observed, frames = X[lo:hi], observed[lo:hi], frames - lo
    if others.sum() > NEAREST:
        seen = observed[:, hidden].all(axis=1)
        probe = np.flatnonzero(seen)[np.linspace(0, seen.sum() - 1, min(int(seen.sum()), 200)).astype(np.intp)]
        cand = np.flatnonzero(others)
        P = X[probe].reshape(len(probe), -1, 3)
        dist = np.linalg.norm(P[:, cand, None, :] - P[:, None, hidden, :], axis=3).mean(axis=2)  # (probe, cand)
        dist[~observed[np.ix_(probe, cand)]] = np.inf
        d = np.median(dist, axis=0) if len(probe) else np.zeros(len(cand))
        others = np.zeros_like(others)
        others[cand[np.argsort(d)[:NEAREST]]] = True
    rows = np.flatnonzero(observed[:, hidden].all(axis=1) & observed[:, others].all(axis=1))
    if len(rows) < MIN_ROWS:
        return None
    if len(rows) > MAX_ROWS:
        rows = rows[np.linspace(0, len(rows) - 1, MAX_ROWS).astype(np.intp)]
    cols_o = (3 * np.flatnonzero(others)[:, None] + np.arange(3)).ravel()
    cols_s = (3 * np.asarray(hidden)[:, None] + np.arange(3)).ravel()
    A, B = X[np.ix_(rows, cols_o)], X[np.ix_(rows, cols_s)]
    a_mean, b_mean = A.mean(axis=0), B.mean(axis=0)
    A = A - a_mean
    gram = A.T @ A
    gram.flat[:: gram.shape[0] + 1] += RIDGE * max(np.trace(gram), 1e-300) / gram.shape[0]
    W = np.linalg.solve(gram, A.T @ (B - b_mean))
    return (X[np.ix_(frames, cols_o)] - a_mean) @ W + b_mean


def gap_variance(X: np.ndarray, observed: np.ndarray,
                 refit: Callable[[np.ndarray, int, int], np.ndarray | None] | None = None) -> np.ndarray:
    """(T, M) error variance per coordinate of each sample of a long gap's fill, NaN elsewhere.

    X : (T, 3 M) the filled data in the body frame (observed entries = the data, missing ones = the fill);
    observed : (T, M) bool; ``refit(hidden, lo, hi)``: frames [lo, hi) of the same filled data in a body frame
    fitted without the ``hidden`` markers, or None when they are not among its markers (else a frame marker's motion leaks into the others' body
    coordinates, where the regression finds it again; in the gap the frame was fitted without it).
    For each gap of marker k of at least :data:`MIN_FRAMES` frames (the :data:`MAX_GAPS` longest), the mean squared
    disagreement ``d^2`` between k's fill and the bridged :func:`second_opinion` is spread over the gap in the shape
    of a Brownian bridge (growing from the observed end alone at a capture edge) with mean ``d^2``: a fill is right
    at the ends of a gap and wrong most in its middle.  NaN where a gap is shorter, past the budget, or has no second
    opinion (the caller keeps the model's variance there).
    """
    T, M = observed.shape
    out = np.full((T, M), np.nan)
    missing = ~observed
    gaps = [(length, a, k) for k in range(M) if missing[:, k].any() and observed[:, k].any()
            for a, length in runs(missing[:, k]) if length >= MIN_FRAMES]
    gaps.sort(key=lambda g: -g[0])
    refitted = 0  # frames of body frames fitted again so far (REFIT_FRAMES)
    for length, a, k in gaps[:MAX_GAPS]:
        b = a + length
        frames = np.arange(a, b)
        # Everything happens in a window around the gap (second_opinion learns from no more): bounded cost.
        lo, hi = max(a - 1 - MAX_ROWS // 2, 0), min(b + 1 + MAX_ROWS // 2, T)
        absent = np.union1d(np.flatnonzero((missing[frames].mean(axis=0) > 0.5) & observed.any(axis=0)), [k])
        coords = None
        if refit is not None and refitted + hi - lo <= REFIT_FRAMES:
            coords = refit(absent, lo, hi)
            refitted += 0 if coords is None else hi - lo
        coords = X[lo:hi] if coords is None else coords
        seen = observed[lo:hi]
        first, last = max(a - 1, 0), min(b + 1, T)  # with the observed frame on either side
        opinion = second_opinion(coords, seen, np.array([k]), np.arange(first - lo, last - lo))
        if opinion is None:
            continue
        # Bridged as the fill is (dynammo.bridge_residuals): the opinion's residuals at the observed frames on either
        # side, blended across.
        left = coords[a - 1 - lo, 3 * k:3 * k + 3] - opinion[0] if a > 0 else None
        right = coords[b - lo, 3 * k:3 * k + 3] - opinion[-1] if b < T else None
        inner = opinion[int(a > 0):int(a > 0) + length] + end_blend(left, right, length)
        d2 = float(np.mean((inner - coords[a - lo:b - lo, 3 * k:3 * k + 3]) ** 2))
        shape = brownian_variance(a, length, T)
        out[frames, k] = d2 * shape / shape.mean()
    return out
