"""Bone-length refinement of a fill, weighted by what each side knows.

A reconstruction ``e`` of the missing markers comes with a per-sample standard deviation ``sigma`` (per coordinate),
and each bone ``(u, v, L)`` with a spread ``s`` (the robust standard deviation of its length over the observed
frames).  Treating both as independent Gaussian errors, the most probable positions of a frame's missing markers
minimise

    sum_i |y_i - e_i|^2 / sigma_i^2  +  sum_b (|y_u - y_v| - L_b)^2 / s_b^2

over the missing markers ``y`` (observed ends stay fixed).  A bone whose length visibly varies (large ``s``) or a
marker the reconstruction already knows well (small ``sigma``) is barely moved; a loose estimate next to a rigid bone
is pulled onto it.  This is BoLeRO-SC's bone penalty with per-bone and per-sample weights instead of one global
lambda, solved after the fill rather than inside EM.

The solve is Gauss-Newton with a Levenberg-Marquardt damping and a monotone acceptance test, vectorised over all
frames that share one pattern of missing markers (a stack of small dense systems, 3 x missing markers each).
"""

from __future__ import annotations

import numpy as np


def _patterns(missing: np.ndarray, frames: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Frames grouped by their missing pattern: list of (frames (n,), missing markers (k,))."""
    rows = missing[frames]
    uniq, inverse = np.unique(rows, axis=0, return_inverse=True)
    inverse = np.asarray(inverse).ravel()
    return [(frames[inverse == p], np.flatnonzero(uniq[p])) for p in range(len(uniq))]


def _bone_sums(ia: np.ndarray, ib: np.ndarray, k: int):
    """Sparse sums over the bones for the Gauss-Newton gradient and Hessian of :func:`refine_bones`.

    ia, ib (nb,) slot (0..k-1) of each bone's ends among the k moved markers, -1 where the end is fixed.  Bone j's
    residual has Jacobian +u_j at slot ia[j] and -u_j at slot ib[j]; summing only those blocks (instead of a dense
    (n, nb, 3k) Jacobian contracted with itself) keeps the cost linear in bones, not bones x (3k)^2.  Returns
    grad_sum(v (n, nb, 3)) -> (n, k, 3) = sum_j J_j^T v_j and hess_sum(o (n, nb, 3, 3)) -> (n, 3k, 3k) =
    sum_j J_j^T o_j J_j (o_j the per-bone outer products times the bone's weight).
    """
    ends = [(j, s, sign) for j in range(len(ia)) for s, sign in ((ia[j], 1.0), (ib[j], -1.0)) if s >= 0]
    bone = np.array([e[0] for e in ends], dtype=int)
    slot = np.array([e[1] for e in ends], dtype=int)
    sign = np.array([e[2] for e in ends])

    def segments(keys: np.ndarray):
        order = np.argsort(keys, kind="stable")  # bones ascending within a slot, as the dense sum adds them
        uniq, starts = np.unique(keys[order], return_index=True)
        return order, uniq, starts

    g_order, g_slots, g_starts = segments(slot)
    # Hessian blocks: every pair of ends of one bone, sign +1 on the same slot and -1 across
    first = np.searchsorted(bone, np.arange(len(ia)))  # each bone's first end (bone is ascending)
    count = np.bincount(bone, minlength=len(ia))
    pa = np.concatenate([first[count >= 1], first[count == 2], first[count == 2] + 1, first[count == 2] + 1])
    pb = np.concatenate([first[count >= 1], first[count == 2] + 1, first[count == 2], first[count == 2] + 1])
    h_bone, h_sign = bone[pa], sign[pa] * sign[pb]
    h_order, h_keys, h_starts = segments(slot[pa] * k + slot[pb])

    def grad_sum(v: np.ndarray) -> np.ndarray:
        out = np.zeros((v.shape[0], k, 3))
        if len(g_order):
            terms = v[:, bone[g_order]] * sign[g_order][None, :, None]
            out[:, g_slots] = np.add.reduceat(terms, g_starts, axis=1)
        return out

    h_row, h_col = h_keys // k, h_keys % k

    def hess_sum(o: np.ndarray) -> np.ndarray:
        out = np.zeros((o.shape[0], k, 3, k, 3))  # block (a, b) at [:, a, :, b, :]: no transposing copy after
        if len(h_order):
            terms = o[:, h_bone[h_order]] * h_sign[h_order][None, :, None, None]
            # (indices apart around a slice: the blocks come first in the indexed view)
            out[:, h_row, :, h_col, :] = np.add.reduceat(terms, h_starts, axis=1).transpose(1, 0, 2, 3)
        return out.reshape(o.shape[0], 3 * k, 3 * k)

    return grad_sum, hess_sum


def _norm3(d: np.ndarray) -> np.ndarray:
    """np.linalg.norm(d, axis=-1) of (..., 3) vectors, the same numbers (squares added in order), without the
    per-vector loop of a reduction over a length-3 axis."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.sqrt(x * x + y * y + z * z)


def refine_bones(
    estimate: np.ndarray,
    positions: np.ndarray,
    std: np.ndarray,
    pairs: np.ndarray,
    lengths: np.ndarray,
    spread: np.ndarray,
    *,
    spread_floor: float,
    max_iter: int = 10,
) -> tuple[np.ndarray, dict]:
    """Move each frame's missing markers to the most probable positions given the fill and the bones.

    Parameters
    ----------
    estimate : ndarray (n_frames, n_markers, 3)
        The fill (finite at the samples to refine).
    positions : ndarray (n_frames, n_markers, 3)
        The input, NaN = missing; observed samples are fixed bone ends.
    std : ndarray (n_frames, n_markers)
        Per-coordinate standard deviation of each filled sample (NaN / non-positive samples are not moved).
    pairs : ndarray int (B, 2); lengths, spread : ndarray (B,)
        Bones, their lengths and spreads (data units); a NaN spread counts as ``spread_floor``.
    spread_floor : float
        Smallest spread used (data units), so that a bone never becomes an exact constraint.
    max_iter : int
        Gauss-Newton iterations per pattern of missing markers.

    Returns
    -------
    refined (n_frames, n_markers, 3), info dict (frames refined, mean |bone error| before / after on the bones
    touching a refined marker).
    """
    out = np.array(estimate, dtype=np.float64)
    missing = np.isnan(positions).any(axis=2)
    movable = missing & np.isfinite(std) & (std > 0) & np.isfinite(out).all(axis=2)
    pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
    info = {"frames": 0, "bone_error_before": float("nan"), "bone_error_after": float("nan")}
    if not len(pairs) or not movable.any():
        return out, info
    spread = np.where(np.isfinite(spread), np.maximum(spread, spread_floor), spread_floor)
    frames = np.flatnonzero((movable[:, pairs[:, 0]] | movable[:, pairs[:, 1]]).any(axis=1))
    before_sum = after_sum = 0.0
    count = 0
    for rows, markers in _patterns(movable, frames):
        touch = np.isin(pairs, markers).any(axis=1)
        if not touch.any():
            continue
        bp, bl, bs = pairs[touch], lengths[touch], spread[touch]
        k = len(markers)
        slot = -np.ones(out.shape[1], dtype=int)
        slot[markers] = np.arange(k)
        ia, ib = slot[bp[:, 0]], slot[bp[:, 1]]  # -1 where the end is fixed
        fixed = out[rows]  # (n, M, 3): fixed ends come from here (observed or already filled)
        # (the arrays keep the memory layouts of these expressions: the sums below add in layout order)
        fixed_a, fixed_b = fixed[:, bp[:, 0]], fixed[:, bp[:, 1]]  # (n, nb, 3), once, not per cost evaluation
        target = fixed[:, markers]  # (n, k, 3)
        prec = 1.0 / std[rows][:, markers] ** 2  # (n, k) per-coordinate precision
        prec3 = np.repeat(prec, 3, axis=1)
        bw = 1.0 / bs ** 2  # (nb,)

        def ends(y):
            pa = np.where(ia[None, :, None] >= 0, y[:, np.maximum(ia, 0)], fixed_a)
            pb = np.where(ib[None, :, None] >= 0, y[:, np.maximum(ib, 0)], fixed_b)
            return pa - pb  # (n, nb, 3)

        def cost(y):
            d = ends(y)
            r = _norm3(d) - bl
            # a bone whose other end is unknown in this frame (missing and not filled) does not count
            d = np.where(np.isfinite(d), d, 0.0)
            r = np.where(np.isfinite(r), r, 0.0)
            return (prec[..., None] * (y - target) ** 2).sum(axis=(1, 2)) + (bw * r ** 2).sum(axis=1), d, r

        y = target.copy()
        f, d, r = cost(y)
        r0 = np.abs(r)
        lam = np.full(len(rows), 1e-3)
        diagonal = np.arange(3 * k)
        grad_sum, hess_sum = _bone_sums(ia, ib, k)
        for _ in range(max_iter):
            norm = np.maximum(_norm3(d), 1e-300)[:, :, None]
            unit = d / norm  # (n, nb, 3): dr/dy_a = unit, dr/dy_b = -unit
            weighted = unit * bw[None, :, None]
            grad = (prec3 * (y - target).reshape(len(rows), 3 * k)
                    + grad_sum(weighted * r[:, :, None]).reshape(len(rows), 3 * k))
            hess = hess_sum(weighted[:, :, :, None] * unit[:, :, None, :])
            hess[:, diagonal, diagonal] += prec3
            # damped = hess + (lam diag(hess)) I: only the diagonal changes, so in place
            hess[:, diagonal, diagonal] += lam[:, None] * hess[:, diagonal, diagonal]
            step = np.linalg.solve(hess, -grad[:, :, None])[:, :, 0].reshape(y.shape)
            y_try = y + step
            f_try, d_try, r_try = cost(y_try)
            ok = f_try <= f
            if ok.all():
                y, f, d, r = y_try, f_try, d_try, r_try
            else:
                y[ok], f[ok], d[ok], r[ok] = y_try[ok], f_try[ok], d_try[ok], r_try[ok]
            lam = np.where(ok, lam * 0.3, lam * 10.0)
            if np.abs(step[ok]).max(initial=0.0) < 1e-9 * max(float(bl.min()), 1e-12) and ok.all():
                break
        out[np.ix_(rows, markers)] = y
        before_sum += float(r0.sum())
        after_sum += float(np.abs(r).sum())
        count += r.size
        info["frames"] += int(len(rows))
    if count:
        info["bone_error_before"] = before_sum / count
        info["bone_error_after"] = after_sum / count
    return out, info
