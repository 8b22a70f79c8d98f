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


def _pair_minors(d0, d1, d2, d3, k01, k02, k03, k12, k13, k23):
    """The 2 x 2 minors of rows (0, 1) and of rows (2, 3) of the symmetric 4 x 4 matrix with diagonal d0..d3 and
    upper entries kij (each entry an array over frames), as the adjugate below wants them."""
    return (d0 * d1 - k01 * k01, d0 * k12 - k01 * k02, d0 * k13 - k01 * k03, k01 * k12 - d1 * k02,
            k01 * k13 - d1 * k03, k02 * k13 - k12 * k03,
            k02 * k13 - k03 * k12, k02 * k23 - k03 * d2, k02 * d3 - k03 * k23, k12 * k23 - k13 * d2,
            k12 * d3 - k13 * k23, d2 * d3 - k23 * k23)


def nearest_rotation(A: np.ndarray) -> np.ndarray:
    """The proper rotation R maximising trace(R^T A[t]) per frame (Kabsch), A (T, 3, 3) -> R (T, 3, 3).

    Horn's quaternion form: trace(R(q)^T A) = q^T K q for the unit quaternion q = (w, x, y, z) of R, with K the
    symmetric, traceless 4 x 4 matrix of A's sums and differences below; the best R is that of K's eigenvector of
    its largest eigenvalue lambda = s1 + s2 + sign(det A) s3 (A's singular values).  K's characteristic polynomial
    is lambda^4 - 2 |A|_F^2 lambda^2 - 8 det(A) lambda + det(K); its roots are all real, so Newton's iteration from
    sqrt(3) |A|_F, above the largest, descends to it monotonically; the eigenvector is the largest row of the
    adjugate of K - lambda I (each row is a multiple of it, of squared norm up to the product of lambda's distances to
    the other eigenvalues).  Every step is elementwise over the frames: 40 % of the cost of a polar iteration and a
    tenth of T batched SVDs, equal to the SVD's answer to 1e-11 even for three anchors (a planar shape, s3 = 0:
    lambda stays apart from the next eigenvalue, s1 - s2 - sign(det A) s3).  Frames whose largest adjugate row is
    below 1e-2 lambda^3 (lambda close to the next eigenvalue: a nearly collinear shape, whose rotation about its axis
    is barely determined and where the adjugate loses precision) and non-finite ones take the SVD.
    """
    A = np.asarray(A, dtype=np.float64)
    T = len(A)
    sxx, sxy, sxz, syx, syy, syz, szx, szy, szz = A.reshape(T, 9).T
    k00, k11, k22, k33 = sxx + syy + szz, sxx - syy - szz, syy - sxx - szz, szz - sxx - syy
    k01, k02, k03 = szy - syz, sxz - szx, syx - sxy
    k12, k13, k23 = sxy + syx, szx + sxz, syz + szy
    f2 = sxx * sxx + sxy * sxy + sxz * sxz + syx * syx + syy * syy + syz * syz + szx * szx + szy * szy + szz * szz
    det_a = sxx * (syy * szz - syz * szy) - sxy * (syx * szz - syz * szx) + sxz * (syx * szy - syy * szx)
    off = (k01, k02, k03, k12, k13, k23)
    s0, s1, s2, s3, s4, s5, c0, c1, c2, c3, c4, c5 = _pair_minors(k00, k11, k22, k33, *off)
    det_k = s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0
    p2, p1 = -2.0 * f2, -8.0 * det_a
    with np.errstate(all="ignore"):
        lam = np.sqrt(3.0 * f2)
        for _ in range(60):
            l2 = lam * lam
            step = ((l2 + p2) * l2 + p1 * lam + det_k) / ((4.0 * l2 + 2.0 * p2) * lam + p1)
            lam = lam - step
            if not (np.abs(step) > 1e-13 * lam).any():
                break
        d0, d1, d2, d3 = k00 - lam, k11 - lam, k22 - lam, k33 - lam
        s0, s1, s2, s3, s4, s5, c0, c1, c2, c3, c4, c5 = _pair_minors(d0, d1, d2, d3, *off)
        rows = np.array([  # adj(K - lambda I), row by row: (4, 4, T)
            [d1 * c5 - k12 * c4 + k13 * c3, k02 * c4 - k01 * c5 - k03 * c3,
             k13 * s5 - k23 * s4 + d3 * s3, d2 * s4 - k12 * s5 - k23 * s3],
            [k12 * c2 - k01 * c5 - k13 * c1, d0 * c5 - k02 * c2 + k03 * c1,
             k23 * s2 - k03 * s5 - d3 * s1, k02 * s5 - d2 * s2 + k23 * s1],
            [k01 * c4 - d1 * c2 + k13 * c0, k01 * c2 - d0 * c4 - k03 * c0,
             k03 * s4 - k13 * s2 + d3 * s0, k12 * s2 - k02 * s4 - k23 * s0],
            [d1 * c1 - k01 * c3 - k12 * c0, d0 * c3 - k01 * c1 + k02 * c0,
             k13 * s1 - k03 * s3 - k23 * s0, k02 * s3 - k12 * s1 + d2 * s0]])
        norms = (rows * rows).sum(axis=1)
        pick = np.argmax(norms, axis=0)
        frames = np.arange(T)
        best = norms[pick, frames]
        w, x, y, z = rows[pick, :, frames].T / np.sqrt(best)
        ok = np.isfinite(best) & (lam > 0) & (best > (1e-2 * lam ** 3) ** 2)
    R = np.stack([w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y),
                  2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x),
                  2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z], axis=1).reshape(T, 3, 3)
    rest = np.flatnonzero(~ok)
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
