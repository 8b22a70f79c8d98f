"""A per-frame body-fixed frame for DynaMMo: which markers carry it, which axis is vertical, and the fit itself.

A linear dynamical system cannot explain a subject travelling and turning across the capture volume, so DynaMMo
models the markers in a frame that moves with the body (the authors' mocap experiments do the same: a translation
and a rotation about the vertical axis, fitted to torso and hip markers).  Without a marker set the pieces are found
from the data:

- :func:`vertical_axis`: the coordinate axis along which the body is tallest (median over frames of the observed
  markers' extent).  Works for Z-up and Y-up captures alike; a somersault or a roll on the floor does not move the
  median of a capture that is mostly upright.
- :func:`frame_markers`: the pelvis: among the markers nearest the body's centre (the per-frame centroid of the
  observed markers), the groups of ``n`` that are nearly the most rigid (largest standard deviation of a pairwise
  distance, over the frames where both are observed, relative to the group's size), and of those the most central.
  The head and a hand can be as rigid, but they turn on the neck or the arm and are far from the centre.  Then two torso markers: above the pelvis by
  0.05-0.35 body heights, the most rigid to it (a yaw fitted to the pelvis alone follows its swing in running);
  "above" assumes the capture's floor is at height 0 (every lab convention: the body stands on the positive side).
- :func:`fit_frames`: per frame, the weighted least-squares placement of one reference shape (refined by
  generalised Procrustes) onto the frame's markers, with a rotation about the vertical axis only (``axis``) or a
  full rotation (``axis=None``).  The translation is that of the fitted shape, not the weighted centroid, so a
  marker dropping out does not move the frame; weights fade linearly to (almost) zero over a few frames before and
  after each of a marker's gaps (:func:`fade_weights`), so the frame does not jump at a gap's ends either.

Conventions: ``positions`` (T, M, 3); ``R`` (T, 3, 3) and ``c`` (T, 3) with ``world = R @ local + c``, i.e. the
local coordinates of frame t are ``(positions[t] - c[t]) @ R[t]``.
"""

from __future__ import annotations

import warnings
from itertools import combinations

import numpy as np

from ..bones.distances import all_pairs, pair_distance_stats

#: ``frame`` options of DynaMMo: "auto" = "yaw" unless the frame markers tilt more than UPRIGHT_TILT_DEG (then
#: "full"); "yaw" = rotation about the vertical axis; "full" = any rotation; "none" = the data's own coordinates.
FRAMES = ("auto", "yaw", "full", "none")

#: "auto" turns to a full rotation when the 95th percentile of the frame markers' tilt exceeds this (degrees):
#: somersaults and rolls (CMU 85_02: 64 deg at the 90th percentile, 130 at most), not running or a tennis serve
#: (19 and 35 deg at most).
UPRIGHT_TILT_DEG = 45.0

#: Markers of the automatic frame: a pelvis of FRAME_MARKERS (searched among the CENTRAL_CANDIDATES markers nearest
#: the centre) and TORSO_MARKERS above it (the authors fit "torso and hip markers").  On the 40 shared trials (median
#: RMSE one marker / two markers): the four hip markers alone 13.8 / 22.3 mm, + T10 and STRN 12.5 / 18.7, + the five
#: CMU torso markers 13.2 / 18.6.
FRAME_MARKERS = 4
TORSO_MARKERS = 4
CENTRAL_CANDIDATES = 12

#: The pelvis: of the groups whose relative spread (largest standard deviation of a pairwise distance over the
#: group's mean pairwise distance) is within RIGID_SLACK of the most rigid group's, the one nearest the centre.  On
#: the BoLeRO authors' 40 trials the most rigid group alone was a hand in 12 (CMU's four hand markers vary 2.8-4.2 mm
#: in distance, the pelvis's 4.3-5.4 mm) and DynaMMo's median RMSE was 13.2 / 21.2 mm (one marker / two); with
#: this rule every trial gets the pelvis, 11.2 / 19.7 mm.
RIGID_SLACK = 1.5

#: :func:`frame_markers` reads at most this many frames (evenly spaced) of a long take.
STAT_FRAMES = 10000

#: Frames over which a frame marker's weight fades to ``FLOOR_WEIGHT`` towards one of its gaps.
FADE_FRAMES = 5

#: Weight of a missing (interpolated) sample: only decisive where every frame marker is missing.
FLOOR_WEIGHT = 1e-6


def vertical_axis(positions: np.ndarray) -> int:
    """Index (0, 1, 2) of the axis along which the observed markers extend most, median over frames.

    positions : (T, M, 3), NaN = missing.  Frames with fewer than two observed markers are ignored.
    """
    with warnings.catch_warnings():  # all-NaN frames (blackouts) are dropped below
        warnings.simplefilter("ignore", RuntimeWarning)
        ext = np.nanmax(positions, axis=1) - np.nanmin(positions, axis=1)  # (T, 3)
    ok = np.isfinite(ext).all(axis=1)
    if not ok.any():
        return 2
    return int(np.argmax(np.median(ext[ok], axis=0)))


def frame_markers(positions: np.ndarray, *, axis: int | None = None, n: int = FRAME_MARKERS,
                  torso: int = TORSO_MARKERS, candidates: int = CENTRAL_CANDIDATES) -> np.ndarray:
    """The markers carrying the body frame (see the module docstring), sorted indices.

    positions : (T, M, 3), NaN = missing; ``axis``: the vertical (default :func:`vertical_axis`).  The pelvis: the
    most central of the nearly most rigid groups of ``n`` among the ``candidates`` nearest the body's centre (see
    :data:`RIGID_SLACK`); then up to ``torso``
    markers above it: of the markers 0.05-0.35 body heights above the pelvis centre (median over frames), those
    whose largest distance spread to the pelvis markers is smallest.  With ``M <= n`` every usable marker.
    """
    if len(positions) > STAT_FRAMES:  # statistics of a long take: every k-th frame tells the same
        positions = positions[::-(-len(positions) // STAT_FRAMES)]
    T, M, _ = positions.shape
    observed = ~np.isnan(positions).any(axis=2)
    usable = np.flatnonzero(observed.sum(axis=0) >= 2)
    if len(usable) <= n:
        return usable if len(usable) >= 1 else np.arange(M)
    if axis is None:
        axis = vertical_axis(positions)
    with warnings.catch_warnings():  # all-NaN frames give NaN, ignored by the medians
        warnings.simplefilter("ignore", RuntimeWarning)
        centre = np.nanmean(positions, axis=1)  # (T, 3)
        dist = np.nanmedian(np.linalg.norm(positions - centre[:, None, :], axis=2), axis=0)  # (M,)
    central = usable[np.argsort(dist[usable], kind="stable")[:max(candidates, n)]]
    # Only pairs with a central marker are ever looked at (groups of central markers, torso markers against them).
    pairs = all_pairs(len(usable))
    is_central = np.isin(usable, central)
    pairs = pairs[is_central[pairs[:, 0]] | is_central[pairs[:, 1]]]
    stats = pair_distance_stats(positions[:, usable, :], pairs, percentiles=())
    spread = np.full((M, M), np.inf)
    i, j = usable[stats.pairs[:, 0]], usable[stats.pairs[:, 1]]
    s = np.where(stats.count >= 2, stats.std, np.inf)
    spread[i, j] = spread[j, i] = s
    size = np.zeros((M, M))  # mean distances: a group's spread counts relative to its size (the frame's lever arm)
    size[i, j] = size[j, i] = np.where(stats.count >= 2, stats.mean, 0.0)
    groups = np.array(list(combinations(central, n)))  # (n_groups, n), all groups at once
    iu, ju = np.triu_indices(n, 1)
    gi, gj = groups[:, iu], groups[:, ju]
    score = spread[gi, gj].max(axis=1) / np.maximum(size[gi, gj].mean(axis=1), 1e-300)
    ok = np.isfinite(score)
    if not ok.any():  # no group observed together: the most central markers
        return np.sort(central[:n])
    # Of the groups nearly as rigid as the most rigid one, the most central: a hand can be as rigid as the pelvis
    # (see RIGID_SLACK), but it is far from the centre, and in its frame the rest of the body swings.
    near = np.flatnonzero(ok & (score <= RIGID_SLACK * score[ok].min()))
    best = groups[near[np.argmin(dist[groups[near]].mean(axis=1))]]
    if torso <= 0:
        return np.sort(best)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        height = float(np.nanmedian(np.nanmax(positions[:, :, axis], axis=1) - np.nanmin(positions[:, :, axis], axis=1)))
        pelvis = np.nanmean(positions[:, best, axis], axis=1)  # (T,)
        up = -1.0 if np.nanmedian(pelvis) < 0 else 1.0  # the lab's floor is at height 0: the body stands above it
        rise = np.nanmedian(up * (positions[:, :, axis] - pelvis[:, None]), axis=0) / height
    others = np.setdiff1d(usable, best)
    above = others[(rise[others] >= 0.05) & (rise[others] <= 0.35)]
    rigid = spread[np.ix_(above, best)].max(axis=1)
    above = above[np.isfinite(rigid)]
    extra = above[np.argsort(rigid[np.isfinite(rigid)], kind="stable")[:torso]]
    return np.sort(np.concatenate([best, extra]))


def fade_weights(observed: np.ndarray, *, fade: int = FADE_FRAMES, floor: float = FLOOR_WEIGHT) -> np.ndarray:
    """(T, M) weights: 1 away from a marker's gaps, falling linearly to ``floor`` at them, ``floor`` inside.

    observed : (T, M) bool.  A frame ``d`` frames from the nearest missing frame of its marker weighs
    ``min(1, d / (fade + 1))`` (d = 0 inside a gap); markers never missing weigh 1 throughout.
    """
    T, M = observed.shape
    big = T + fade + 2
    t = np.arange(T)[:, None]
    # Distance to the nearest missing frame: the last one at or before t and the first one at or after t.
    before = np.maximum.accumulate(np.where(observed, -big, t), axis=0)
    after = np.minimum.accumulate(np.where(observed, T + big, t)[::-1], axis=0)[::-1]
    d = np.minimum(np.minimum(t - before, after - t), big)
    return np.maximum(np.minimum(1.0, d / (fade + 1.0)), floor)


def tilt_percentile(R: np.ndarray, axis: int, q: float = 95.0) -> float:
    """The ``q``-th percentile over frames of the angle (degrees) between the frame's up axis and its mean direction.

    R : (T, 3, 3) full rotations from :func:`fit_frames`; the frame's up axis is column ``axis`` (the reference
    shape is set up in world orientation).
    """
    up = R[:, :, axis]
    mean = up.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm == 0:
        return 180.0
    return float(np.percentile(np.degrees(np.arccos(np.clip(up @ (mean / norm), -1.0, 1.0))), q))


def _rotation_about(axis: int, angle: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations by ``angle`` (T,) about coordinate ``axis`` (right-handed)."""
    u, v = (axis + 1) % 3, (axis + 2) % 3
    R = np.zeros(angle.shape + (3, 3))
    c, s = np.cos(angle), np.sin(angle)
    R[:, axis, axis] = 1.0
    R[:, u, u] = c
    R[:, v, v] = c
    R[:, v, u] = s
    R[:, u, v] = -s
    return R


# cofactor k of a 3 x 3 matrix stored as 9 entries (3 r + c): entries P1 * P2 - P3 * P4
_P1 = np.array([4, 5, 3, 7, 8, 6, 1, 2, 0])
_P2 = np.array([8, 6, 7, 2, 0, 1, 5, 3, 4])
_P3 = np.array([5, 3, 4, 8, 6, 7, 2, 0, 1])
_P4 = np.array([7, 8, 6, 1, 2, 0, 4, 5, 3])
_ROW0 = np.array([0, 1, 2])


def nearest_rotation(A: np.ndarray) -> np.ndarray:
    """The proper rotation R maximising trace(R^T A[t]) per frame (Kabsch via SVD), A (T, 3, 3) -> R (T, 3, 3).

    Where det A > 0 that is the orthogonal polar factor of A, found by a scaled Newton iteration with closed-form
    3 x 3 inverses (a tenth of the cost of T batched SVDs; equal to the SVD's answer to round-off).  Where A is
    near singular (three anchors: a planar shape), the iteration runs on A + k cof(A) instead: with A = U S V^T,
    cof(A) = det(U V^T) U diag(s2 s3, s1 s3, s1 s2) V^T has A's singular vectors, so the sum keeps them and, for
    k = |A| / |cof A|, has the singular values s1 + O(s3), s2 + O(s3) and s3 + det(U V^T) k s1 s2: its polar factor
    is U diag(1, 1, det(U V^T)) V^T, Kabsch's proper rotation.  Frames with det A < 0 (a reflection: the third
    singular value is not small), collinear (cof A = 0) or not converged take the SVD.
    """
    A = np.asarray(A, dtype=np.float64)
    R = np.full(A.shape, np.nan)
    X = A.reshape(-1, 9).T.copy()  # (9, T): entry 3 r + c of each frame's matrix
    det = (X[_ROW0] * (X[_P1[:3]] * X[_P2[:3]] - X[_P3[:3]] * X[_P4[:3]])).sum(axis=0)
    norm = np.sqrt((X ** 2).sum(axis=0))
    with np.errstate(all="ignore"):
        # det / |A|^3 = s1 s2 s3 / (s1^2 + s2^2 + s3^2)^1.5: small when A is near singular
        flat = np.flatnonzero(np.isfinite(det) & (np.abs(det) <= 1e-6 * norm ** 3))
        if len(flat):
            cof = X[_P1][:, flat] * X[_P2][:, flat] - X[_P3][:, flat] * X[_P4][:, flat]
            X[:, flat] += cof * (norm[flat] / np.sqrt((cof ** 2).sum(axis=0)))
            det[flat] = (X[_ROW0][:, flat] * (X[_P1[:3]][:, flat] * X[_P2[:3]][:, flat]
                                              - X[_P3[:3]][:, flat] * X[_P4[:3]][:, flat])).sum(axis=0)
            norm[flat] = np.sqrt((X[:, flat] ** 2).sum(axis=0))
        newton = np.flatnonzero(np.isfinite(det) & (det > 1e-6 * norm ** 3))
        if len(newton) >= 32:  # fewer: the SVD's fixed cost is lower
            X = X[:, newton] / norm[newton]
            last = False
            for _ in range(30):
                cof = X[_P1] * X[_P2] - X[_P3] * X[_P4]  # det X * X^-T, closed form
                inv_t = cof / (X[_ROW0] * cof[_ROW0]).sum(axis=0)
                # Higham's scaling: gamma = (|X^-1| / |X|)^(1/2)
                gamma = np.sqrt(np.sqrt((inv_t ** 2).sum(axis=0) / (X ** 2).sum(axis=0)))
                nxt = 0.5 * (gamma * X + inv_t / gamma)
                change = np.abs(nxt - X).max(axis=0)
                X = nxt
                if last:
                    break
                last = change.max() < 1e-7  # quadratic convergence: one more step reaches round-off
            done = change < 1e-12
            R[newton[done]] = X[:, done].T.reshape(-1, 3, 3)
    rest = np.flatnonzero(~np.isfinite(R[:, 0, 0]))
    if len(rest):
        U, _, Vt = np.linalg.svd(A[rest])
        s = np.sign(np.linalg.det(U @ Vt))
        s[s == 0] = 1.0
        U[:, :, 2] *= s[:, None]  # no reflections
        R[rest] = U @ Vt
    return R


def fit_frames(positions: np.ndarray, weights: np.ndarray, *, axis: int | None, rounds: int = 3
               ) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame placement of one reference shape onto the weighted markers (see the module docstring).

    Parameters
    ----------
    positions : (T, K, 3) finite positions of the frame markers (missing ones interpolated).
    weights : (T, K) non-negative, each frame with a positive sum.
    axis : vertical coordinate axis (rotation about it only), or None for a full rotation.
    rounds : generalised Procrustes rounds refining the reference shape.

    Returns
    -------
    R (T, 3, 3), c (T, 3): ``positions[t, k] ~= R[t] @ ref[k] + c[t]``.
    """
    T, K, _ = positions.shape
    w = weights / weights.sum(axis=1, keepdims=True)
    xbar = np.einsum("tk,tkd->td", w, positions)
    Y = positions - xbar[:, None, :]  # weighted-centred frames
    ref = Y[int(np.argmax(weights.sum(axis=1)))].copy()  # the best-observed frame starts the reference
    for _ in range(rounds):
        rbar = w @ ref  # (T, 3): the reference's weighted centroid under each frame's weights
        Q = ref[None, :, :] - rbar[:, None, :]
        if axis is None:
            R = nearest_rotation(np.einsum("tk,tki,tkj->tij", w, Y, Q))
        else:
            u, v = (axis + 1) % 3, (axis + 2) % 3
            num = np.einsum("tk,tk->t", w, Q[:, :, u] * Y[:, :, v] - Q[:, :, v] * Y[:, :, u])
            den = np.einsum("tk,tk->t", w, Q[:, :, u] * Y[:, :, u] + Q[:, :, v] * Y[:, :, v])
            R = _rotation_about(axis, np.arctan2(num, den))
        c = xbar - np.einsum("tij,tj->ti", R, rbar)
        local = np.einsum("tki,tij->tkj", positions - c[:, None, :], R)  # R^T (x - c) per marker
        wk = weights.sum(axis=0)
        ref = np.einsum("tk,tkd->kd", weights, local) / np.where(wk > 0, wk, 1.0)[:, None]
    return R, c
