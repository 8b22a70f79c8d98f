"""Per-frame bone-length solvers for BoLeRO, vectorised across frames.

Both solvers work on one frame at a time in principle: the unknowns are the coordinates of the frame's missing
markers ``y`` (k markers, 3k numbers), the target is the model's estimate ``e`` = G E[z_t] at those markers, and the
active bones are the bones with at least one missing endpoint (the other endpoint, when observed, is fixed at its
observed position).  Frames that share the same missing pattern share the same system structure, so they are grouped
and solved together as stacks of small dense systems ``(n_frames_in_group, p, p)`` with :func:`numpy.linalg.solve`.

Every bone residual is written in length units, ``r_b = (|x_u - x_v|^2 - L_b^2) / (2 L_b)``, which equals
``|x_u - x_v| - L_b`` to first order and is smooth everywhere (the plain distance is not differentiable at 0); its
gradient ``(x_u - x_v) / L_b`` is dimensionless.

- :func:`solve_hard`: ``min |y - e|^2  s.t.  r(y) = 0`` (BoLeRO-HC).  Phase 1 (restoration) runs Levenberg-Marquardt
  on ``|r|^2`` from ``e``; frames where the constraints cannot all hold keep that least-squares point (its small
  damped steps leave the under-determined directions near ``e``).  Phase 2 runs damped Newton on the Lagrangian's
  KKT system from the restored point, backtracking on the KKT residual, and keeps the result only if it is feasible
  and nearer to ``e`` than the restored point.  Cold starts go through a penalty continuation from ``e`` (follows the
  branch nearest ``e``); with ``start=`` (BoLeRO-HC's previous EM iteration) and ``start_unanchored_only``, frames
  whose bones touch no observed marker (whole-body blackouts, where the cold start on the full system was the cost:
  50 s of a 30-frame blackout on CMU 85_02, now ~5 s) start from the previous solution moved rigidly onto ``e``.
- :func:`solve_soft`: ``min |y - e|^2 + w sum_b r_b^2`` (BoLeRO-SC with lambda_b = w / (4 sigma^2 L_b^2), see
  :mod:`mocapfill.methods.bolero`).  Newton with the exact Hessian, shifted where it is not positive definite, and
  an Armijo line search; warm-started from the previous EM iteration's solution.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from ..engines.body_frame import nearest_rotation
from ..gaps import members, unique_rows

#: Relative bone residual |r_b| / L_b under which a frame counts as satisfying its hard constraints.
FEASIBLE_RTOL = 1e-9

#: Stationarity tolerance of the KKT Newton iteration, relative to the shortest active bone (see _kkt_newton).
KKT_GTOL = 1e-9


@dataclass
class SolveStats:
    """What one call of a solver did (JSON-ready through :meth:`as_dict`).

    Violations are mean absolute bone-length errors ``| |x_u - x_v| - L_b |`` in data units over the active
    (bone, frame) pairs, before (at the estimate) and after the solve; ``max_rel_after`` is the largest relative
    error after.  ``iterations`` is the largest iteration count of any frame group (phase 1 + phase 2 for the hard
    solver).  ``infeasible`` lists the frames (indices into the input) whose bones could not all hold.
    """

    n_frames: int = 0
    n_groups: int = 0
    n_constraints: int = 0
    iterations: int = 0
    violation_before: float = 0.0
    violation_after: float = 0.0
    max_rel_after: float = 0.0
    n_infeasible: int = 0
    infeasible: list = field(default_factory=list)
    _sum_before: float = field(default=0.0, repr=False)
    _sum_after: float = field(default=0.0, repr=False)

    def add(self, before: np.ndarray, after: np.ndarray, lengths: np.ndarray, iterations: int) -> None:
        """Accumulate one group: ``before``/``after`` are |d| - L of shape (n, m), ``lengths`` (m,)."""
        self.n_frames += before.shape[0]
        self.n_groups += 1
        self.n_constraints += before.size
        self.iterations = max(self.iterations, int(iterations))
        self._sum_before += float(np.abs(before).sum())
        self._sum_after += float(np.abs(after).sum())
        if after.size:
            self.max_rel_after = max(self.max_rel_after, float((np.abs(after) / lengths).max()))
        if self.n_constraints:
            self.violation_before = self._sum_before / self.n_constraints
            self.violation_after = self._sum_after / self.n_constraints

    def as_dict(self) -> dict:
        return {
            "frames": self.n_frames,
            "groups": self.n_groups,
            "constraints": self.n_constraints,
            "iterations": self.iterations,
            "violation_before": self.violation_before,
            "violation_after": self.violation_after,
            "max_rel_violation_after": self.max_rel_after,
            "infeasible_frames": self.n_infeasible,
        }


class _Group:
    """The frames sharing one missing pattern, with the structure of their per-frame systems.

    Attributes: ``frames`` (n,), ``var`` (k,) the missing markers, ``bones`` (m,) indices of the active bones,
    ``lengths`` (m,), ``S`` (m, k) incidence of bones on unknown markers (+1 at u, -1 at v, 0 if fixed),
    ``iu``/``iv`` (m,) endpoint indices into Z = [y, fixed] of shape (n, k + q, 3), ``fixed`` (n, q, 3).
    """

    def __init__(self, frames, var, bones, pairs, lengths, observed):
        self.frames = frames
        self.var = var
        self.bones = bones
        self.lengths = lengths[bones]
        ends = pairs[bones]  # (m, 2)
        k = var.size
        loc = {int(mk): i for i, mk in enumerate(var)}
        fixed = sorted({int(mk) for mk in ends.ravel() if int(mk) not in loc})
        for i, mk in enumerate(fixed):
            loc[mk] = k + i
        self.iu = np.array([loc[int(a)] for a in ends[:, 0]], dtype=np.intp)
        self.iv = np.array([loc[int(b)] for b in ends[:, 1]], dtype=np.intp)
        m = bones.size
        self.S = np.zeros((m, k))
        rows = np.arange(m)
        self.S[rows[self.iu < k], self.iu[self.iu < k]] = 1.0
        self.S[rows[self.iv < k], self.iv[self.iv < k]] = -1.0
        self.fixed = observed[np.ix_(frames, np.array(fixed, dtype=np.intp), np.arange(3))] if fixed else \
            np.zeros((frames.size, 0, 3))

    @property
    def k(self) -> int:
        return self.var.size

    def diffs(self, y: np.ndarray) -> np.ndarray:
        """Bone vectors x_u - x_v, shape (n, m, 3), for unknowns ``y`` of shape (n, k, 3)."""
        z = np.concatenate([y, self.fixed[: y.shape[0]]], axis=1) if self.fixed.shape[1] else y
        return z[:, self.iu] - z[:, self.iv]

    def residual(self, d: np.ndarray) -> np.ndarray:
        """r_b = (|d|^2 - L^2) / (2 L), shape (n, m)."""
        return ((d * d).sum(axis=2) - self.lengths**2) / (2.0 * self.lengths)

    def jacobian(self, d: np.ndarray) -> np.ndarray:
        """dr/dy, shape (n, m, 3k): row b holds d_b / L_b at marker u and -d_b / L_b at marker v."""
        n, m, _ = d.shape
        jac = np.einsum("bi,nbc->nbic", self.S / self.lengths[:, None], d)
        return jac.reshape(n, m, 3 * self.k)

    def jt_dot(self, d: np.ndarray, coef: np.ndarray) -> np.ndarray:
        """``J^T coef`` = sum_b coef_b dr_b/dy, shape (n, 3k), for ``coef`` (n, m), without forming J."""
        return np.matmul(self.S.T, (coef / self.lengths)[:, :, None] * d).reshape(d.shape[0], 3 * self.k)

    def curvature(self, coef: np.ndarray) -> np.ndarray:
        """sum_b coef_b * Hessian(r_b) = kron(S^T diag(coef / L) S, I3), shape (n, 3k, 3k), for coef (n, m)."""
        c = np.matmul(self.S.T[None] * (coef / self.lengths)[:, None, :], self.S[None])  # S^T diag(.) S (BLAS)
        n, k = c.shape[0], self.k
        out = np.zeros((n, k, 3, k, 3))
        for a in range(3):  # kron(c, I3) by three strided copies (cheaper than a broadcast product)
            out[:, :, a, :, a] = c
        return out.reshape(n, 3 * k, 3 * k)


def frame_groups(positions: np.ndarray, missing: np.ndarray, pairs: np.ndarray, lengths: np.ndarray,
                 frames: np.ndarray | None = None) -> list:
    """The per-pattern systems of a solve, to pass as ``groups=`` when the same gaps are solved repeatedly.

    ``positions`` (n_frames, n_markers, 3) and ``missing`` (n_frames, n_markers) as for :func:`solve_hard`; the
    observed partners are copied, so later solves reuse them.  Returns an opaque list.
    """
    positions, missing, pairs, lengths = _prepare(positions, positions, missing, pairs, lengths)[1:]
    return list(_groups(missing, pairs, lengths, positions, frames))


def _groups(missing: np.ndarray, pairs: np.ndarray, lengths: np.ndarray, observed: np.ndarray,
            frames: np.ndarray | None = None) -> Iterator[_Group]:
    """Yield one :class:`_Group` per distinct missing pattern that has at least one active bone."""
    if pairs.size == 0:
        return
    cand = np.flatnonzero(missing.any(axis=1)) if frames is None else np.asarray(frames, dtype=np.intp)
    if cand.size == 0:
        return
    patterns, inverse, _ = unique_rows(missing[cand])
    for pattern, rows in zip(patterns, members(inverse, len(patterns))):
        touches = pattern[pairs[:, 0]] | pattern[pairs[:, 1]]
        if not touches.any():
            continue
        yield _Group(cand[rows], np.flatnonzero(pattern), np.flatnonzero(touches), pairs, lengths,
                     observed)


def _bone_error(group: _Group, y: np.ndarray) -> np.ndarray:
    """| x_u - x_v | - L, shape (n, m)."""
    return np.linalg.norm(group.diffs(y), axis=2) - group.lengths


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the stack a (n, p, p) x = b (n, p); a frame whose system is singular gets a least-squares step."""
    try:
        return np.linalg.solve(a, b[..., None])[..., 0]
    except np.linalg.LinAlgError:
        out = np.empty_like(b)
        for i in range(a.shape[0]):
            out[i] = np.linalg.lstsq(a[i], b[i], rcond=None)[0]
        return out


def _prepare(estimate, positions, missing, pairs, lengths):
    estimate = np.asarray(estimate, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    missing = np.asarray(missing, dtype=bool)
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    lengths = np.asarray(lengths, dtype=np.float64).ravel()
    if estimate.shape != positions.shape or missing.shape != positions.shape[:2]:
        raise ValueError("estimate, positions and missing must agree: (n_frames, n_markers, 3) and "
                         "(n_frames, n_markers)")
    if not (np.isfinite(lengths) & (lengths > 0)).all():
        raise ValueError("bone lengths must be finite and positive")
    return estimate, positions, missing, pairs, lengths


# ----------------------------------------------------------------------------------------------- hard constraints
def _restore(group: _Group, y: np.ndarray, *, max_iter: int, tol: float) -> tuple[np.ndarray, int]:
    """Levenberg-Marquardt on |r(y)|^2 from ``y`` (n, k, 3); returns the least-squares point and iterations."""
    n, k3 = y.shape[0], 3 * group.k
    mu = np.full(n, 1e-6)
    d = group.diffs(y)
    r = group.residual(d)
    cost = (r * r).sum(axis=1)
    eye = np.eye(k3)
    stalled = np.zeros(n, dtype=bool)
    it = 0
    for it in range(1, max_iter + 1):
        jac = group.jacobian(d)
        grad = np.matmul(r[:, None, :], jac)[:, 0]
        done = (np.abs(r) <= tol * group.lengths).all(axis=1) | (np.linalg.norm(grad, axis=1) <= tol * 1e-3 *
                                                                  group.lengths.min()) | stalled
        if done.all():
            break
        jtj = np.matmul(jac.transpose(0, 2, 1), jac)
        # J is dimensionless, so mu is too; plain mu*I (not Marquardt's diag(J^T J)) also damps the directions no
        # bone constrains, which keeps them at the estimate.
        step = _solve(jtj + mu[:, None, None] * eye, -grad)
        y_new = y + step.reshape(y.shape)
        d_new = group.diffs(y_new)
        r_new = group.residual(d_new)
        cost_new = (r_new * r_new).sum(axis=1)
        ok = (cost_new < cost) & ~done
        # Inconsistent bones: the least-squares cost stops falling (relative gain below 1e-9) or the damping
        # saturates; that frame is done.
        # A Gauss-Newton-sized step below 1e-9 of the shortest bone that does not lower the cost means the frame
        # is at its least-squares point to rounding (raising the damping through 14 decades would only confirm it).
        tiny = np.abs(step).max(axis=1) <= 1e-9 * group.lengths.min()
        stalled |= (ok & (cost - cost_new <= 1e-9 * cost)) | (~ok & ((mu >= 1e8) | tiny))
        y = np.where(ok[:, None, None], y_new, y)
        d = np.where(ok[:, None, None], d_new, d)
        r = np.where(ok[:, None], r_new, r)
        cost = np.where(ok, cost_new, cost)
        mu = np.where(ok, np.maximum(mu / 10.0, 1e-12), np.minimum(mu * 10.0, 1e8))
    return y, it


def _kkt_newton(group: _Group, y: np.ndarray, target: np.ndarray, *, max_iter: int, tol: float
                ) -> tuple[np.ndarray, int]:
    """Damped Newton on the KKT system of min |y - e|^2 / 2 s.t. r(y) = 0, from a (nearly) feasible ``y``."""
    n, k3 = y.shape[0], 3 * group.k
    m = group.bones.size
    scale = float(group.lengths.min())
    delta = 1e-12  # regularises the (2,2) block so redundant constraints do not make the KKT matrix singular
    eye_y = np.eye(k3)
    d = group.diffs(y)
    jac = group.jacobian(d)
    dev = (y - target).reshape(n, k3)
    # Least-squares multipliers: the best eta with y - e + J^T eta = 0.
    jjt = np.matmul(jac, jac.transpose(0, 2, 1)) + delta * np.eye(m)
    eta = _solve(jjt, -np.matmul(jac, dev[:, :, None])[:, :, 0])

    y, eta = y.copy(), eta.copy()
    # Stationarity to 1e-9 of the shortest bone is far below any accuracy that matters (the bones themselves are
    # held to ``tol`` and polished afterwards); asking for ``tol`` = 1e-12 there only chases rounding in the
    # coordinates (|y| ~ 1e3 bone lengths) until the line search gives up.
    gtol = max(tol, KKT_GTOL) * scale
    live = np.arange(n)  # frames still iterating: converged ones drop out, so late steps are cheap
    it = 0
    for it in range(1, max_iter + 1):
        sub = _subgroup(group, live)
        yl, el, tl = y[live], eta[live], target[live]
        d, g, r, merit = _kkt_residual(sub, yl, el, tl)
        going = ~((np.abs(g).max(axis=1) <= gtol) & (np.abs(r) <= tol * group.lengths).all(axis=1))
        if not going.all():
            live = live[going]
            if not live.size:
                break
            sub = _subgroup(group, live)
            yl, el, tl, d, g, r, merit = yl[going], el[going], tl[going], d[going], g[going], r[going], merit[going]
        nl = live.size
        jac = sub.jacobian(d)
        kkt = np.zeros((nl, k3 + m, k3 + m))
        kkt[:, :k3, :k3] = eye_y + sub.curvature(el)
        kkt[:, :k3, k3:] = np.transpose(jac, (0, 2, 1))
        kkt[:, k3:, :k3] = jac
        kkt[:, k3:, k3:] = -delta * np.eye(m)
        step = _solve(kkt, -np.concatenate([g, r], axis=1))
        dy, deta = step[:, :k3].reshape(yl.shape), step[:, k3:]
        alpha = np.ones(nl)
        accepted = np.zeros(nl, dtype=bool)
        for _ in range(30):  # backtracking on the KKT residual, frame by frame
            y_try = yl + alpha[:, None, None] * dy
            eta_try = el + alpha[:, None] * deta
            merit_try = _kkt_residual(sub, y_try, eta_try, tl)[3]
            ok = ~accepted & (merit_try < (1.0 - 1e-4 * alpha) * merit)
            y[live[ok]], eta[live[ok]] = y_try[ok], eta_try[ok]
            accepted |= ok
            if accepted.all():
                break
            alpha = np.where(accepted, alpha, alpha * 0.5)
        # A frame whose line search found no decrease is at a numerical stationary point (the same step would
        # fail again): it stops.
        live = live[accepted]
        if not live.size:
            break
    return y, it


def _kkt_residual(group: _Group, y: np.ndarray, eta: np.ndarray, target: np.ndarray):
    """(d (n, m, 3), g (n, 3k), r (n, m), merit (n,)) of the KKT system at ``y`` (n, k, 3) and multipliers ``eta``.

    ``g = y - e + J^T eta`` is formed without J: the line search evaluates this several times per Newton step.
    """
    d = group.diffs(y)
    g = (y - target).reshape(y.shape[0], -1) + group.jt_dot(d, eta)
    r = group.residual(d)
    return d, g, r, (g * g).sum(axis=1) + (r * r).sum(axis=1)


def solve_hard(
    estimate: np.ndarray,
    positions: np.ndarray,
    missing: np.ndarray,
    pairs: np.ndarray,
    lengths: np.ndarray,
    *,
    frames: np.ndarray | None = None,
    groups: list | None = None,
    start: np.ndarray | None = None,
    start_unanchored_only: bool = False,
    warm_newton_iter: int | None = None,
    max_iter: int = 50,
    tol: float = 1e-12,
) -> tuple[np.ndarray, SolveStats]:
    """Move every missing sample to the nearest point (Euclidean) that meets its bones exactly.

    Parameters
    ----------
    estimate : ndarray, shape (n_frames, n_markers, 3)
        The target, e.g. G E[z_t] in data units; only its missing samples are used.
    positions : ndarray, shape (n_frames, n_markers, 3)
        The data; observed samples are the fixed partners of bones.
    missing : ndarray of bool, shape (n_frames, n_markers)
    pairs : ndarray of int, shape (B, 2); lengths : ndarray, shape (B,)
        The bones; a bone is active in a frame when one of its markers is missing there.
    frames : ndarray of int, optional
        Restrict the solve to these frames (default: every frame with a missing marker).
    groups : list, optional
        :func:`frame_groups` of the same positions, missing mask and bones (saves regrouping on repeated solves).
    start : ndarray, shape (n_frames, n_markers, 3), optional
        A previous solution to start from (restoration + Newton only); frames where that fails start cold.
    start_unanchored_only : bool
        Use ``start`` only in frames whose active bones touch no observed marker (whole-body blackouts): there every
        marker is unknown, which makes the cold start (penalty continuation on the full system) the expensive
        part, while with an observed partner a warm start was measured to keep frames on a branch that is no
        longer the nearest (see :mod:`mocapfill.methods.bolero`).
    warm_newton_iter : int, optional
        Cap on the KKT Newton steps from a warm start (default ``max_iter``): the answer still meets its bones
        (restoration polishes it), but may stop short of the nearest point, which is what an EM iteration that
        re-solves next time can afford.
    max_iter : int
        Cap for each phase (restoration, then Newton on the KKT system).
    tol : float
        Relative tolerance on bone residuals |r_b| / L_b and on the KKT gradient.

    Returns
    -------
    out : ndarray, shape (n_frames, n_markers, 3)
        The data completed: observed samples from ``positions``, missing samples from ``estimate``, those of
        constrained frames replaced by the solution; frames whose bones cannot all hold
        (over-determined or inconsistent) get the least-squares point of the bone residuals nearest the estimate.
    stats : SolveStats
        ``n_infeasible`` counts those frames.
    """
    estimate, positions, missing, pairs, lengths = _prepare(estimate, positions, missing, pairs, lengths)
    out = np.where(missing[:, :, None], estimate, positions)
    stats = SolveStats()
    for group in (groups if groups is not None else _groups(missing, pairs, lengths, positions, frames)):
        target = estimate[np.ix_(group.frames, group.var, np.arange(3))]
        if not np.isfinite(target).all():
            continue
        before = _bone_error(group, target)
        rows = np.arange(group.frames.size)
        y = np.empty_like(target)
        feasible = np.zeros(rows.size, dtype=bool)
        settled = np.zeros(rows.size, dtype=bool)  # frames the warm start has answered
        iters = 0
        unanchored = group.fixed.shape[1] == 0
        if start is not None and (unanchored or not start_unanchored_only):
            # Warm start (the previous EM iteration's solution): restoration + Newton from there; frames where that
            # does not end feasible take the cold path below, except without anchors (see below).
            y0 = np.asarray(start, dtype=np.float64)[np.ix_(group.frames, group.var, np.arange(3))]
            ok = np.isfinite(y0).all(axis=(1, 2))
            if ok.any():
                sub = rows[ok]
                y0 = y0[sub]
                if unanchored:
                    # Without anchors the problem is invariant under rigid motions: move the start rigidly onto the
                    # estimate first (bone residuals unchanged), so it follows the estimate's pose.
                    y0 = _rigid_onto(y0, target[sub])
                ys, fs, iters = _restore_and_newton(_subgroup(group, sub), y0, target[sub], max_iter, tol,
                                                    warm_newton_iter)
                # Without anchors, a frame whose bones cannot all hold keeps the least-squares point restoration
                # reached from the aligned start: the cold path would cost the full continuation on every EM
                # iteration (whole-body blackouts of an over-determined bone set); the final solve is cold anyway.
                take = np.ones_like(fs) if unanchored else fs
                y[sub[take]] = ys[take]
                feasible[sub[fs]] = True
                settled[sub[take]] = True
        cold = rows[~settled]
        if cold.size:
            sub_group = _subgroup(group, cold)
            # Penalty continuation: the soft problem's minimiser moves from the estimate to the constrained
            # optimum as the weight grows, following the branch nearest the estimate (Newton on the Lagrangian
            # from a poor start can wander to a farther critical point).
            yc = target[cold].copy()
            for weight in 10.0 ** np.arange(0, 9, 2):
                yc, it = _soft_newton(sub_group, target[cold], weight, start=yc, max_iter=15, tol=1e-6)
                iters += it
            yc, fc, it = _restore_and_newton(sub_group, yc, target[cold], max_iter, tol)
            iters += it
            y[cold] = yc
            feasible[cold] = fc
        # A missing marker no active bone touches is free: the estimate (the cold paths leave it there; a warm start
        # would leave it where the previous solution had it).
        free = ~group.S.any(axis=0)
        y[:, free] = target[:, free]
        stats.n_infeasible += int((~feasible).sum())
        stats.infeasible.extend(int(f) for f in group.frames[~feasible])
        out[np.ix_(group.frames, group.var, np.arange(3))] = y
        stats.add(before, _bone_error(group, y), group.lengths, iters)
    return out, stats


def _rigid_onto(y: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``y`` (n, k, 3) moved per frame by the rigid motion (Kabsch) that best fits it to ``target`` (n, k, 3)."""
    cy, ct = y.mean(axis=1, keepdims=True), target.mean(axis=1, keepdims=True)
    p = y - cy
    rot = nearest_rotation(np.matmul((target - ct).transpose(0, 2, 1), p))  # sum_i q_i p_i^T per frame
    return np.matmul(p, rot.transpose(0, 2, 1)) + ct


def _restore_and_newton(group: _Group, y0: np.ndarray, target: np.ndarray, max_iter: int, tol: float,
                        newton_iter: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Restoration (LM on the bone residuals) from ``y0`` (n, k, 3), then Newton on the KKT system where feasible.

    Returns the points (n, k, 3), which frames met every bone (n,) bool, and the iterations used.
    """
    y1, iters = _restore(group, y0, max_iter=max_iter, tol=tol)
    feasible = (np.abs(group.residual(group.diffs(y1))) <= FEASIBLE_RTOL * group.lengths).all(axis=1)
    y = y1.copy()
    if feasible.any():
        sub = np.flatnonzero(feasible)
        sub_group = _subgroup(group, sub)
        # Newton on the KKT system from there converges in a few steps to the exact constrained optimum; a final
        # restoration step polishes to rounding.
        y2, it2 = _kkt_newton(sub_group, y1[sub], target[sub], max_iter=newton_iter or max_iter, tol=tol)
        y2, _ = _restore(sub_group, y2, max_iter=5, tol=tol)
        iters += it2
        r2 = sub_group.residual(sub_group.diffs(y2))
        obj1 = ((y1[sub] - target[sub]) ** 2).sum(axis=(1, 2))
        obj2 = ((y2 - target[sub]) ** 2).sum(axis=(1, 2))
        # Near the optimum the objective is flat to rounding, so only a clearly worse point is refused.
        nearer = obj2 <= obj1 * (1.0 + 1e-8) + (1e-9 * group.lengths.min()) ** 2
        good = (np.abs(r2) <= FEASIBLE_RTOL * sub_group.lengths).all(axis=1) & nearer
        y[sub[good]] = y2[good]
    return y, feasible, iters


def _subgroup(group: _Group, rows: np.ndarray) -> _Group:
    """The same system restricted to some of its frames."""
    sub = object.__new__(_Group)
    sub.__dict__.update(group.__dict__)
    sub.frames = group.frames[rows]
    sub.fixed = group.fixed[rows]
    return sub


# ----------------------------------------------------------------------------------------------- soft constraints
def solve_soft(
    estimate: np.ndarray,
    positions: np.ndarray,
    missing: np.ndarray,
    pairs: np.ndarray,
    lengths: np.ndarray,
    *,
    weight,
    frames: np.ndarray | None = None,
    groups: list | None = None,
    start: np.ndarray | None = None,
    max_iter: int = 30,
    tol: float = 1e-6,
) -> tuple[np.ndarray, SolveStats]:
    """Minimise |y - e|^2 + weight * sum_b r_b(y)^2 over each frame's missing coordinates.

    With r_b = (|d_b|^2 - L_b^2) / (2 L_b) this is the paper's per-frame objective (Eq. 11) multiplied by sigma^2,
    with lambda_b = weight / (4 sigma^2 L_b^2); the minimiser does not depend on sigma^2, the units or the number
    of markers.

    Parameters
    ----------
    estimate, positions : ndarray, shape (n_frames, n_markers, 3)
        Target (e.g. G E[z_t]) and data (observed samples are the bones' fixed partners).
    missing : ndarray of bool, shape (n_frames, n_markers)
    pairs : ndarray of int, shape (B, 2); lengths : ndarray, shape (B,)
    weight : float or ndarray, shape (B,)
        Dimensionless penalty weight w >= 0, or one per bone (all 0 returns the estimate).
    frames : ndarray of int, optional
        Restrict the solve to these frames.
    groups : list, optional
        :func:`frame_groups` of the same positions, missing mask and bones.
    start : ndarray, shape (n_frames, n_markers, 3), optional
        First iterate at the missing samples (e.g. the previous EM iteration's solution, which is usually one or two
        Newton steps from the new one); default, and wherever ``start`` is not finite: the estimate.
    max_iter : int
        Newton iterations per frame group.
    tol : float
        Stop when every frame's step is below tol times the shortest active bone.

    Returns
    -------
    out : ndarray, shape (n_frames, n_markers, 3)
        Observed samples from ``positions``, missing ones from ``estimate`` or, in constrained frames, the
        minimiser.
    stats : SolveStats
    """
    estimate, positions, missing, pairs, lengths = _prepare(estimate, positions, missing, pairs, lengths)
    out = np.where(missing[:, :, None], estimate, positions)
    stats = SolveStats()
    weight = np.asarray(weight, dtype=np.float64)
    if weight.ndim and weight.shape != lengths.shape:
        raise ValueError(f"weight must be a scalar or one per bone {lengths.shape}, got {weight.shape}")
    if not (weight > 0).any():
        return out, stats
    for group in (groups if groups is not None else _groups(missing, pairs, lengths, positions, frames)):
        target = estimate[np.ix_(group.frames, group.var, np.arange(3))]
        if not np.isfinite(target).all():
            continue
        y0 = target
        if start is not None:
            y0 = np.asarray(start, dtype=np.float64)[np.ix_(group.frames, group.var, np.arange(3))]
            y0 = np.where(np.isfinite(y0), y0, target)
        y, it = _soft_newton(group, target, weight, start=y0, max_iter=max_iter, tol=tol)
        out[np.ix_(group.frames, group.var, np.arange(3))] = y
        stats.add(_bone_error(group, target), _bone_error(group, y), group.lengths, it)
    return out, stats


def _soft_newton(group: _Group, target: np.ndarray, weight, *, max_iter: int, tol: float,
                 start: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Newton (Hessian shifted to positive definite where needed) with Armijo backtracking, per frame.

    ``target`` (n, k, 3) is the estimate, ``start`` (n, k, 3) the first iterate (default: the estimate),
    ``weight`` a scalar or one weight per bone of the whole set, shape (B,) (``group.bones`` indexes it).
    """
    wb = np.asarray(weight, dtype=np.float64)[group.bones] if np.ndim(weight) else \
        np.full(group.bones.size, float(weight))
    n, k3 = target.shape[0], 3 * group.k
    eye = np.eye(k3)
    scale = float(group.lengths.min())
    y = (target if start is None else start).copy()

    def objective(y_):
        d_ = group.diffs(y_)
        r_ = group.residual(d_)
        return d_, r_, ((y_ - target) ** 2).sum(axis=(1, 2)) + (wb * r_ * r_).sum(axis=1)

    d, r, f = objective(y)
    active = np.ones(n, dtype=bool)
    it = 0
    for it in range(1, max_iter + 1):
        jac = group.jacobian(d)
        grad = (y - target).reshape(n, k3) + np.matmul((wb * r)[:, None, :], jac)[:, 0]
        # The exact Hessian; compressed bones (r < 0) add negative curvature, so where it is not safely positive
        # definite it is shifted by a multiple of the identity (dropping those terms instead converges only
        # linearly).  The identity block of the likelihood term sets the scale: eigenvalues >= 0.1.
        # (batched matmul goes through BLAS; a three-operand einsum does not, which matters for blackouts)
        hess = eye + np.matmul(jac.transpose(0, 2, 1) * wb, jac) + group.curvature(wb * r)
        # S_b^T S_b has eigenvalues 0 and 2, so lambda_min >= 1 + 2 w sum_{r_b < 0} r_b / L_b: only frames where
        # that bound is below 0.1 need the eigenvalues.
        bound = 1.0 + 2.0 * (wb * np.minimum(r, 0.0) / group.lengths).sum(axis=1)
        check = np.flatnonzero(bound < 0.1)
        if check.size:
            try:  # usually the Gauss-Newton part dominates: one batched Cholesky proves lambda_min > 0.1
                np.linalg.cholesky(hess[check] - 0.1 * eye)
            except np.linalg.LinAlgError:
                low = np.linalg.eigvalsh(hess[check])[:, 0]
                hess[check] += np.maximum(0.1 - low, 0.0)[:, None, None] * eye
        step = _solve(hess, -grad)
        slope = (grad * step).sum(axis=1)
        alpha = np.ones(n)
        # A frame whose full step is below tolerance has converged: take the step and stop it (Armijo cannot
        # tell such steps apart from rounding).
        tiny = np.abs(step).max(axis=1) <= tol * scale
        y_next = np.where(tiny[:, None, None], y + step.reshape(y.shape), y)
        active &= ~tiny
        accepted = ~active
        for _ in range(12):  # Newton steps on a positive definite model: 12 halvings (alpha >= 2.4e-4) suffice
            y_try = y + alpha[:, None, None] * step.reshape(y.shape)
            _, _, f_try = objective(y_try)
            ok = ~accepted & (f_try <= f + 1e-4 * alpha * slope)
            y_next[ok] = y_try[ok]
            accepted |= ok
            if accepted.all():
                break
            alpha = np.where(accepted, alpha, alpha * 0.5)
        active &= accepted  # a frame whose line search found no decrease is at a (numerical) minimum
        y = y_next
        d, r, f = objective(y)
        if not active.any():
            break
    return y, it


def bone_errors(positions: np.ndarray, pairs: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """|x_u - x_v| - L per frame and bone, shape (n_frames, B) (NaN where a marker is missing)."""
    positions = np.asarray(positions, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    d = positions[:, pairs[:, 0]] - positions[:, pairs[:, 1]]
    return np.linalg.norm(d, axis=2) - np.asarray(lengths, dtype=np.float64)
