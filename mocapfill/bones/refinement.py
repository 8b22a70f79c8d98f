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

The solve is Newton's method with a Levenberg-Marquardt damping (Nielsen's update of the damping from the gain ratio)
and a monotone acceptance test, vectorised over all frames where one group of moved markers occurs.  The Hessian of
a bone's term is w (u u^T + (r / |d|) (I - u u^T)) in the bone vector d = y_u - y_v (u = d / |d|, r = |d| - L): its
first part is Gauss-Newton's, the second the curvature of the length across the bone.  That curvature is kept where
the bone is stretched (r > 0) and dropped where it is compressed (it would be negative there), so every system stays
positive definite.  Without it a loose marker hanging on a bone is moved along the bone's tangent as if its length did
not change, overshoots and is damped back: on messy captures (a third of the markers missing) most frames were still
moving after 10 iterations, at a cost thousands of times the optimum's (kineticstoolkit's basket sprint: 1.9e9
against 4.7e5 now), and each frame stopped at a different place, so the fill jerked from frame to frame.  A frame stops
when an accepted step's model promised the objective (twice a negative log-likelihood) less than ``tolerance``.
Moved markers joined by no bone between moved markers do not interact: the objective is a sum over the connected
components of those bones, and each component is solved alone, batched over every frame where it occurs
(:func:`_components`).
"""

from __future__ import annotations

import hashlib
from math import lgamma

import numpy as np

from ..gaps import members, unique_rows
from ..runtime.executor import forked_map


def _patterns(missing: np.ndarray, frames: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Frames grouped by their missing pattern: list of (frames (n,), missing markers (k,))."""
    rows = missing[frames]
    uniq, inverse, _ = unique_rows(rows)
    return [(frames[part], np.flatnonzero(uniq[p])) for p, part in enumerate(members(inverse, len(uniq)))]


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


def _components(markers: np.ndarray, pairs: np.ndarray) -> list[np.ndarray]:
    """The moved ``markers`` (k,) of one pattern split into independent problems: connected components of the bones
    between two of them (a bone to a fixed end ties nobody), each as the marker indices it moves; markers on no bone
    at all are left out (nothing moves them).

    The objective is a sum over these components, so each is minimised alone, batched with every frame (of any
    pattern) where the same markers form a component: a frame missing 33 markers of 6 limbs solves six systems of
    15-18 unknowns, each with the other frames missing that limb, rather than one of 99 with only the frames missing
    exactly those 33.
    """
    k = len(markers)
    slot = -np.ones(int(max(pairs.max(initial=0), markers.max(initial=0))) + 1, dtype=int)
    slot[markers] = np.arange(k)
    ia, ib = slot[pairs[:, 0]], slot[pairs[:, 1]]  # -1 where the end is fixed
    on_bone = np.zeros(k, dtype=bool)
    on_bone[ia[ia >= 0]] = True
    on_bone[ib[ib >= 0]] = True
    label = np.arange(k)
    both = (ia >= 0) & (ib >= 0)
    a, b = ia[both], ib[both]
    # the smallest label spread along the bones until nothing changes (k is at most a few dozen; importing
    # scipy.sparse.csgraph for this would add 0.4 s to every fill, which loads nothing else of scipy.sparse)
    while True:
        low = np.minimum(label[a], label[b])
        new = label.copy()
        np.minimum.at(new, a, low)
        np.minimum.at(new, b, low)
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    return [markers[label == c] for c in np.unique(label[on_bone])]


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
    max_iter: int = 30,
    tolerance: float = 0.01,
    one_sided: np.ndarray | None = None,
    jobs: int | None = None,
    memo: dict | None = None,
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
    pairs : ndarray int (B, 2); lengths : ndarray (B,); spread : ndarray (B,) or (n_frames, B)
        Bones, their lengths and spreads (data units), the spreads per bone or per frame and bone; a NaN spread
        counts as ``spread_floor``, an infinite one leaves the bone out (at that frame).
    spread_floor : float
        Smallest spread used (data units), so that a bone never becomes an exact constraint.
    max_iter : int
        Most Newton iterations of a frame (a bound on the cost: on the messiest capture measured, kineticstoolkit's
        basket sprint, a tenth of the frames' components were still moving after 30, at 1 % above the optimum's cost
        in all; they are counted in ``info``).
    tolerance : float
        A frame has converged when its last step was accepted and the damped model promised a decrease of the
        objective (twice a negative log-likelihood) of at most this: a hundredth of a standard deviation's worth.
    one_sided : ndarray bool (B,) or None
        Pairs that only a distance beyond their ``lengths`` costs (reaches, :mod:`mocapfill.bones.reach`): their term
        is max(0, |x_a - x_b| - L)^2 / spread^2, with neither pull nor curvature within L, at the frames where the
        estimate stretches the pair past L from a fixed end (one end moved, the other not).  None: every pair a bone.
    jobs : int or None
        Processes the independent problems (a component's markers over the frames where they are one) are solved
        on (:func:`~mocapfill.runtime.executor.forked_map`; None or 1: this one); the output does not depend on it.
    memo : dict or None
        Results of problems solved before, by a digest of everything a problem reads (its frames, markers, bones and
        spreads, the fill and the bones' ends there, the fill's sds): a problem found in it is not solved again, and
        the ones solved here are added.  The default's two passes share one, so the problems whose inputs the refit
        left as they were (a blackout's markers, predicted by the global PCA in both) are solved once: the output
        is the same as without it.

    Returns
    -------
    refined (n_frames, n_markers, 3), info dict (frames refined, mean |bone error| before / after on the bones
    touching a refined marker, ``unconverged``: a frame's components still moving after ``max_iter``, ``cost``: the
    objective's sum over the refined frames; with ``one_sided``, ``stretched`` (n_frames, n_one_sided) bool: where
    each such pair acted).
    """
    out = np.array(estimate, dtype=np.float64)
    missing = np.isnan(positions).any(axis=2)
    movable = missing & np.isfinite(std) & (std > 0) & np.isfinite(out).all(axis=2)
    pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
    info = {"frames": 0, "bone_error_before": float("nan"), "bone_error_after": float("nan"), "unconverged": 0,
            "cost": 0.0}
    if one_sided is not None:
        info["stretched"] = np.zeros((len(out), int(np.sum(one_sided))), dtype=bool)
    if not len(pairs) or not movable.any():
        return out, info
    spread = np.where(np.isnan(spread), spread_floor, np.maximum(spread, spread_floor))  # (+inf: weight 0)
    two = np.ones(len(pairs), dtype=bool) if one_sided is None else ~np.asarray(one_sided, dtype=bool)
    bones = pairs[two]
    frames = np.flatnonzero((movable[:, bones[:, 0]] | movable[:, bones[:, 1]]).any(axis=1))
    if not two.all():
        # a reach acts only at the frames where the fill stretches it from a fixed end (observed, or not moved):
        # between two moved markers it would join their problems into one, at several times the cost, for a bound
        # between two guesses
        reach = np.flatnonzero(~two)
        a, b = pairs[reach, 0], pairs[reach, 1]
        with np.errstate(invalid="ignore"):
            stretched = (movable[:, a] ^ movable[:, b]) & (_norm3(out[:, a] - out[:, b]) > lengths[reach])
        frames = np.union1d(frames, np.flatnonzero(stretched.any(axis=1)))
        info["stretched"] = stretched
    problems: dict[tuple, list[np.ndarray]] = {}  # a component's markers -> the frames where they are one
    for rows, markers in _patterns(movable, frames):
        comps = _components(markers, bones)
        if not two.all():  # a marker on no bone, held by a reach alone, is a problem of its own
            held = np.zeros(movable.shape[1], dtype=bool)
            held[pairs[reach[stretched[rows].any(axis=0)]].ravel()] = True
            for comp in comps:
                held[comp] = False
            comps = comps + [np.array([m]) for m in markers if held[m]]
        for comp in comps:
            problems.setdefault(tuple(comp.tolist()), []).append(rows)

    def setup(item: tuple[tuple, list[np.ndarray]]) -> tuple:
        """Everything one problem (a component's markers, the frames where they are one) reads: its frames,
        markers, bones (pairs, lengths, which are reaches or None, spreads), the bones' ends and the markers' fill
        at its frames, and the fill's sds there."""
        key, parts = item
        rows, markers = np.sort(np.concatenate(parts)), np.array(key)
        touch = np.isin(pairs, markers).any(axis=1)
        if two.all():
            bs = spread[touch] if spread.ndim == 1 else spread[rows][:, touch]  # (nb,) or per frame (n, nb)
        else:  # the reaches stretched somewhere in its frames, each left out (infinite spread) where it is not
            touch &= two | np.isin(np.arange(len(pairs)), reach[stretched[rows].any(axis=0)])
            bs = np.array(np.broadcast_to(spread, (len(movable), len(pairs)))[rows][:, touch])
            col = np.flatnonzero(touch)
            on = ~two[col]
            bs[:, on] = np.where(stretched[rows][:, np.searchsorted(reach, col[on])], bs[:, on], np.inf)
        bp, bl = pairs[touch], lengths[touch]
        hinge = ~two[touch]  # the reaches among its terms
        if not hinge.any():
            hinge = None
        fixed = out[rows]  # (n, M, 3): fixed ends come from here (observed, or filled and not moved)
        # (the arrays keep the memory layouts of these expressions: the sums below add in layout order)
        fixed_a, fixed_b = fixed[:, bp[:, 0]], fixed[:, bp[:, 1]]  # (n, nb, 3), once, not per cost evaluation
        return rows, markers, bp, bl, hinge, bs, fixed_a, fixed_b, fixed[:, markers], std[rows][:, markers]

    def solve(problem: tuple) -> tuple:
        """One problem as :func:`setup` gives it: its frames, markers, refined positions (n, k, 3), summed cost,
        frames still moving, and the summed |bone error| before / after and their count (pure: the problems share
        no moved sample, so they may be solved in any process)."""
        rows, markers, bp, bl, hinge, bs, fixed_a, fixed_b, target, sd = problem
        k = len(markers)
        slot = -np.ones(out.shape[1], dtype=int)
        slot[markers] = np.arange(k)
        ia, ib = slot[bp[:, 0]], slot[bp[:, 1]]  # -1 where the end is fixed
        prec = 1.0 / sd ** 2  # (n, k) per-coordinate precision
        prec3 = np.repeat(prec, 3, axis=1)
        bw = 1.0 / bs ** 2  # (nb,) or per frame (n, nb)

        def weight(at):
            """The bone weights of the frames ``at``: (nb,), broadcast over frames, or (len(at), nb)."""
            return bw[at] if bw.ndim == 2 else bw

        def cost(y, at):
            """Cost (len(at),), bone vectors and length residuals of the frames ``at`` (rows of this problem)."""
            pa = np.where(ia[None, :, None] >= 0, y[:, np.maximum(ia, 0)], fixed_a[at])
            pb = np.where(ib[None, :, None] >= 0, y[:, np.maximum(ib, 0)], fixed_b[at])
            d = pa - pb  # (n, nb, 3)
            r = _norm3(d) - bl
            if hinge is not None:  # a reach: only stretching past it costs
                r = np.where(hinge & (r < 0.0), 0.0, r)
            # a bone whose other end is unknown in this frame (missing and not filled) does not count
            d = np.where(np.isfinite(d), d, 0.0)
            r = np.where(np.isfinite(r), r, 0.0)
            prior = (prec[at][..., None] * (y - target[at]) ** 2).sum(axis=(1, 2))
            return prior + (weight(at) * r ** 2).sum(axis=1), d, r

        y = target.copy()
        f, d, r = cost(y, slice(None))
        r0 = np.abs(r)
        lam = np.full(len(rows), 1e-3)
        nu = np.full(len(rows), 2.0)
        diagonal = np.arange(3 * k)
        grad_sum, hess_sum = _bone_sums(ia, ib, k)
        active = np.arange(len(rows))  # frames still moving: a converged frame leaves the batch
        for _ in range(max_iter):
            ya, da, ra, n = y[active], d[active], r[active], len(active)
            norm = np.maximum(_norm3(da), 1e-300)[:, :, None]
            unit = da / norm  # (n, nb, 3): dr/dy_a = unit, dr/dy_b = -unit
            wa = weight(active)[..., None]
            if hinge is not None:  # a reach within its bound adds nothing (nor curvature)
                wa = np.where((hinge & (ra == 0.0))[..., None], 0.0, wa)
            weighted = unit * wa
            grad = (prec3[active] * (ya - target[active]).reshape(n, 3 * k)
                    + grad_sum(weighted * ra[:, :, None]).reshape(n, 3 * k))
            outer = unit[:, :, :, None] * unit[:, :, None, :]
            # the length's curvature across a stretched bone (module docstring); none for a compressed one
            across = np.maximum(ra, 0.0)[:, :, None, None] / norm[:, :, :, None]
            hess = hess_sum((outer + across * (np.eye(3) - outer)) * wa[..., None])
            hess[:, diagonal, diagonal] += prec3[active]
            damp = lam[active, None] * hess[:, diagonal, diagonal]  # Marquardt: lam diag(H)
            hess[:, diagonal, diagonal] += damp
            step = np.linalg.solve(hess, -grad[:, :, None])[:, :, 0]
            y_try = ya + step.reshape(ya.shape)
            f_try, d_try, r_try = cost(y_try, active)
            # gain ratio: the decrease of f achieved over the one the damped quadratic model predicted, h^T (D h - g)
            # (grad and hess are half f's gradient and Hessian)
            predicted = (step * (damp * step - grad)).sum(axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                gain = (f[active] - f_try) / predicted
            ok = f_try <= f[active] * (1.0 + 1e-12)  # (a step lost in round-off is taken: at the minimum it is all)
            took = active[ok]
            y[took], f[took], d[took], r[took] = y_try[ok], f_try[ok], d_try[ok], r_try[ok]
            # Nielsen's update: a good model lets lam fall fast, a poor one raises it ever faster
            good = ok & (gain > 0)
            gain = np.clip(np.nan_to_num(gain), -1.0, 2.0)
            lam[active] = np.minimum(np.where(good, lam[active] * np.maximum(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3),
                                              lam[active] * nu[active]), 1e16)  # (a frame that cannot move stops)
            nu[active] = np.where(good, 2.0, nu[active] * 2.0)
            active = active[~(ok & (predicted <= tolerance))]
            if not len(active):
                break
        cols = slice(None) if hinge is None else ~hinge  # the bones' errors (a reach's are not)
        return (rows, markers, y, float(f.sum()), len(active), float(r0[:, cols].sum()),
                float(np.abs(r[:, cols]).sum()), r[:, cols].size)

    before_sum = after_sum = 0.0
    count = unconverged = 0
    prepared = [setup(item) for item in problems.items()]
    settings = np.array([max_iter, tolerance], dtype=float)  # (a memo shared by calls with other settings)
    digests = ([_digest((*problem, settings)) for problem in prepared] if memo is not None
               else [None] * len(prepared))
    todo = [i for i, d in enumerate(digests) if memo is None or d not in memo]
    size = [len(prepared[i][0]) * len(prepared[i][1]) ** 2 for i in todo]  # frames x the solve's size
    solved = dict(zip(todo, forked_map(solve, [prepared[i] for i in todo], jobs, cost=size)))
    if memo is not None:
        memo.update((digests[i], result) for i, result in solved.items())
    for i in range(len(prepared)):
        rows, markers, y, cost_sum, moving, before, after, n_terms = solved[i] if i in solved else memo[digests[i]]
        unconverged += moving
        info["cost"] += cost_sum
        out[np.ix_(rows, markers)] = y
        before_sum += before
        after_sum += after
        count += n_terms
    info["frames"] = int(len(frames))  # each has a moved marker on a bone, so a problem of its own
    info["unconverged"] = unconverged
    if count:
        info["bone_error_before"] = before_sum / count
        info["bone_error_after"] = after_sum / count
    return out, info


def _digest(arrays: tuple) -> bytes:
    """A 128-bit digest of a tuple of arrays (or None), their dtypes, shapes and bytes: the key of a solved problem
    in :func:`refine_bones`'s ``memo``."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        if a is None:
            h.update(b"none;")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype}{a.shape};".encode())
        h.update(a.tobytes())
    return h.digest()


def miss_log_densities(r: np.ndarray, v: np.ndarray, lengths: np.ndarray, dof: float) -> tuple[np.ndarray, np.ndarray]:
    """Log densities of a bone's miss r = |x_a - x_b| - L (any shape, bones last) if the bone holds, a Student t with
    ``dof`` degrees of freedom scaled by sqrt(v) (v its variance: the bone's spread squared plus the ends'
    uncertainty), and if it broke, N(0, L^2 + v) (its ends anywhere within about its length ``lengths``)."""
    held = (lgamma((dof + 1) / 2) - lgamma(dof / 2) - 0.5 * np.log(dof * np.pi * v)
            - (dof + 1) / 2 * np.log1p(r ** 2 / (dof * v)))
    w = lengths ** 2 + v
    return held, -0.5 * np.log(2 * np.pi * w) - 0.5 * r ** 2 / w


def break_rates(positions: np.ndarray, pairs: np.ndarray, lengths: np.ndarray, spread: np.ndarray, *, dof: float,
                iterations: int = 50) -> np.ndarray:
    """How often each bone broke where both its ends were observed (n_bones,): the maximum-likelihood weight p of
    the mixture (1 - p) held + p broken (:func:`miss_log_densities` with v = spread^2) over those frames, by EM.

    positions (n_frames, n_markers, 3) NaN = missing; pairs (B, 2); lengths, spread (B,), spread > 0.  A bone seen
    to hold everywhere gets p = 0 (its tail within the t's); one that let go for a while (a hand on a robot arm) gets
    the share of frames it was off.  0 where no frame has both ends.  (EM from p = 0.5: after 50 iterations the
    rates above 1e-4 of three captures' bones were within 1e-5 of their values after 400.)
    """
    missing = np.isnan(positions).any(axis=2)
    a, b = pairs[:, 0], pairs[:, 1]
    co = ~missing[:, a] & ~missing[:, b]
    n = co.sum(axis=0)
    with np.errstate(invalid="ignore"):
        r = np.where(co, np.linalg.norm(positions[:, a] - positions[:, b], axis=2) - lengths, 0.0)
    held, gone = miss_log_densities(r, spread ** 2, lengths, dof)
    ratio = np.where(co, np.exp(np.clip(gone - held, -700.0, 700.0)), 0.0)  # broken over held, per frame
    # the log-likelihood sum log(1 - p + p ratio) is concave in p with slope sum(ratio - 1) at 0: where the mean
    # ratio is at most 1 (a bone that held), the maximum is p = 0, and only the others need EM
    p = np.zeros(len(pairs))
    todo = np.flatnonzero((n > 0) & (ratio.sum(axis=0) > n))
    if len(todo):
        rt, q = ratio[:, todo], np.full(len(todo), 0.5)
        for _ in range(iterations):
            q = (q * rt / (q * rt + 1.0 - q)).sum(axis=0) / n[todo]
        p[todo] = q
    return p
