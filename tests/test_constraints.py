"""The per-frame bone-length solvers on small problems with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from mocapfill.bones.constraints import bone_errors, solve_hard, solve_soft


def _scene(n_frames=6, n_markers=5, seed=0, scale=100.0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n_frames, n_markers, 3)) * scale


def test_one_partner_is_projection_onto_sphere():
    pos = _scene()
    missing = np.zeros(pos.shape[:2], bool)
    missing[:, 1] = True
    pairs = np.array([[0, 1]])
    lengths = np.array([50.0])
    est = pos + 7.0
    out, stats = solve_hard(est, pos, missing, pairs, lengths)
    centre = pos[:, 0]
    direction = est[:, 1] - centre
    expected = centre + 50.0 * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    np.testing.assert_allclose(out[:, 1], expected, rtol=0, atol=1e-9)
    # Observed samples come from the data.
    np.testing.assert_array_equal(out[:, [0, 2, 3, 4]], pos[:, [0, 2, 3, 4]])
    assert stats.n_infeasible == 0 and stats.max_rel_after < 1e-9


def _rigid_frames(base, n_frames, seed):
    """Frames that are random rotations and shifts of one configuration ``base`` (n_markers, 3)."""
    from scipy.spatial.transform import Rotation

    rots = Rotation.random(n_frames, random_state=seed).as_matrix()
    shifts = np.random.default_rng(seed).normal(size=(n_frames, 1, 3)) * 500
    return np.einsum("fij,mj->fmi", rots, base) + shifts


def test_two_missing_markers_match_a_generic_constrained_solver():
    base = _scene(n_frames=1, seed=1)[0]
    pos = _rigid_frames(base, 4, seed=1)
    missing = np.zeros(pos.shape[:2], bool)
    missing[:, [1, 2]] = True
    pairs = np.array([[0, 1], [1, 2], [2, 3], [1, 4]])
    lengths = np.linalg.norm(base[pairs[:, 0]] - base[pairs[:, 1]], axis=1)
    est = pos + np.random.default_rng(1).normal(size=pos.shape) * 30
    out, stats = solve_hard(est, pos, missing, pairs, lengths)
    err = bone_errors(out, pairs, lengths)
    assert stats.n_infeasible == 0
    assert np.abs(err / lengths).max() < 1e-9
    # Warm-started from its own solution, the solver stays there.
    again, _ = solve_hard(est, pos, missing, pairs, lengths, start=out)
    np.testing.assert_allclose(again, out, atol=1e-8)
    for t in range(pos.shape[0]):
        e = est[t, [1, 2]].ravel()

        def cons(y, b):
            z = pos[t].copy()
            z[[1, 2]] = y.reshape(2, 3)
            u, v = pairs[b]
            return np.sum((z[u] - z[v]) ** 2) - lengths[b] ** 2

        def cons_jac(y, b):  # exact gradients: SLSQP's finite differences made this test take seconds
            z = pos[t].copy()
            z[[1, 2]] = y.reshape(2, 3)
            u, v = pairs[b]
            g = np.zeros((5, 3))
            g[u] += 2.0 * (z[u] - z[v])
            g[v] -= 2.0 * (z[u] - z[v])
            return g[[1, 2]].ravel()

        best = None
        for start in (out[t, [1, 2]].ravel(), e + 1.0):
            res = minimize(lambda y: np.sum((y - e) ** 2), start, jac=lambda y: 2.0 * (y - e), method="SLSQP",
                           constraints=[{"type": "eq", "fun": cons, "jac": cons_jac, "args": (b,)}
                                        for b in range(4)],
                           options={"ftol": 1e-9, "maxiter": 500})  # f ~ 1e3-1e4: 1e-14 is below round-off
            feasible = max(abs(cons(res.x, b)) for b in range(4)) < 1e-6 * lengths.min() ** 2
            if feasible and (best is None or res.fun < best):
                best = res.fun
        ours = np.sum((out[t, [1, 2]].ravel() - e) ** 2)
        assert best is not None and ours <= best * (1 + 1e-6) + 1e-9


def test_inconsistent_bones_fall_back_to_least_squares():
    pos = _scene(n_frames=3, seed=2)
    missing = np.zeros(pos.shape[:2], bool)
    missing[:, 0] = True
    pairs = np.array([[0, 1], [0, 2], [0, 3], [0, 4]])
    true_len = np.linalg.norm(pos[:, [0]] - pos[:, 1:], axis=2)  # (n, 4), differs per frame
    lengths = true_len.mean(axis=0) * np.array([1.0, 1.3, 0.8, 1.1])  # cannot all hold
    out, stats = solve_hard(pos, pos, missing, pairs, lengths)
    assert stats.n_infeasible == 3
    assert np.isfinite(out).all()
    # The returned point is a stationary point of the squared residuals: no better nearby point.
    err = bone_errors(out, pairs, lengths)
    rng = np.random.default_rng(0)
    for t in range(3):
        base = np.sum(((err[t] + lengths) ** 2 - lengths**2) ** 2 / lengths**2)
        for _ in range(20):
            z = out[t].copy()
            z[0] += rng.normal(size=3) * 1e-3
            e2 = np.linalg.norm(z[0] - z[1:], axis=1) - lengths
            assert np.sum(((e2 + lengths) ** 2 - lengths**2) ** 2 / lengths**2) >= base - 1e-9


def test_blackout_and_unconstrained_markers():
    pos = _scene(n_frames=5, seed=3)
    missing = np.ones(pos.shape[:2], bool)  # everything missing: bones among missing markers only
    missing[0] = False
    pairs = np.array([[0, 1], [1, 2], [2, 0]])
    lengths = np.array([80.0, 80.0, 80.0])
    out, stats = solve_hard(pos + 3.0, pos, missing, pairs, lengths)
    err = bone_errors(out[1:], pairs, lengths)
    assert np.abs(err / lengths).max() < 1e-9
    # Markers 3 and 4 have no bone: the estimate is kept.
    np.testing.assert_array_equal(out[1:, 3:], (pos + 3.0)[1:, 3:])
    # Frame 0 has nothing missing: the data.
    np.testing.assert_array_equal(out[0], pos[0])


def test_many_patterns_vectorised_equal_frame_by_frame():
    rng = np.random.default_rng(4)
    pos = _scene(n_frames=40, n_markers=8, seed=4)
    missing = rng.random(pos.shape[:2]) < 0.3
    pairs = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 6], [6, 7], [0, 7], [2, 6]])
    lengths = np.linalg.norm(pos[0, pairs[:, 0]] - pos[0, pairs[:, 1]], axis=1)
    est = pos + rng.normal(size=pos.shape) * 5
    all_at_once, _ = solve_soft(est, pos, missing, pairs, lengths, weight=10.0)
    for t in range(0, 40, 7):
        one, _ = solve_soft(est, pos, missing, pairs, lengths, weight=10.0, frames=np.array([t]))
        np.testing.assert_allclose(all_at_once[t], one[t], atol=1e-8)


@pytest.mark.parametrize("weight", [0.1, 1.0, 100.0, 1e4])
def test_soft_matches_a_generic_minimiser(weight):
    pos = _scene(n_frames=3, seed=5)
    missing = np.zeros(pos.shape[:2], bool)
    missing[:, [1, 3]] = True
    pairs = np.array([[0, 1], [1, 2], [1, 3], [3, 4]])
    lengths = np.array([120.0, 90.0, 60.0, 150.0])
    est = pos + 10.0
    out, stats = solve_soft(est, pos, missing, pairs, lengths, weight=weight, max_iter=50)
    for t in range(3):
        e = est[t, [1, 3]].ravel()

        def f(y):
            z = pos[t].copy()
            z[[1, 3]] = y.reshape(2, 3)
            d = z[pairs[:, 0]] - z[pairs[:, 1]]
            r = (np.sum(d * d, axis=1) - lengths**2) / (2 * lengths)
            return np.sum((y - e) ** 2) + weight * np.sum(r * r)

        ref = minimize(f, out[t, [1, 3]].ravel() + 0.5, method="BFGS", options={"gtol": 1e-10})
        assert f(out[t, [1, 3]].ravel()) <= ref.fun * (1 + 1e-7) + 1e-9
    assert stats.violation_after < stats.violation_before


def test_soft_weight_zero_and_units_invariance():
    pos = _scene(n_frames=4, seed=6)
    missing = np.zeros(pos.shape[:2], bool)
    missing[:, 2] = True
    pairs = np.array([[1, 2], [2, 3]])
    lengths = np.array([100.0, 130.0])
    est = pos + 20.0
    out0, _ = solve_soft(est, pos, missing, pairs, lengths, weight=0.0)
    np.testing.assert_array_equal(out0[:, 2], est[:, 2])
    mm, _ = solve_soft(est, pos, missing, pairs, lengths, weight=5.0)
    m, _ = solve_soft(est / 1000, pos / 1000, missing, pairs, lengths / 1000, weight=5.0)
    np.testing.assert_allclose(m * 1000, mm, rtol=1e-9, atol=1e-9)


def test_unanchored_warm_start_follows_the_estimate_and_matches_cold():
    """In a whole-body blackout (no observed partner) a warm start from a moved, rotated earlier solution is first
    carried rigidly onto the estimate, then converges to the same constrained optimum as the cold start."""
    from scipy.spatial.transform import Rotation

    base = _scene(n_frames=1, n_markers=5, seed=11)[0]
    pos = _rigid_frames(base, 4, seed=12)
    missing = np.ones(pos.shape[:2], bool)
    pairs = np.array([[0, 1], [1, 2], [2, 0], [2, 3], [3, 4]])
    lengths = np.linalg.norm(base[pairs[:, 0]] - base[pairs[:, 1]], axis=1)
    est = pos + np.random.default_rng(13).normal(size=pos.shape) * 5.0
    cold, _ = solve_hard(est, pos, missing, pairs, lengths)
    turn = Rotation.from_rotvec([0.0, 0.0, 0.7]).as_matrix()
    start = cold @ turn.T + 400.0  # the right shape, far away and turned
    warm, stats = solve_hard(est, pos, missing, pairs, lengths, start=start, start_unanchored_only=True)
    assert stats.n_infeasible == 0
    np.testing.assert_allclose(warm, cold, rtol=0, atol=1e-6)


def test_start_unanchored_only_leaves_anchored_frames_cold():
    pos = _scene(n_frames=4, seed=14)
    missing = np.zeros(pos.shape[:2], bool)
    missing[:, 1] = True
    pairs = np.array([[0, 1]])
    lengths = np.array([50.0])
    est = pos + 7.0
    cold, _ = solve_hard(est, pos, missing, pairs, lengths)
    start = cold.copy()
    start[:, 1] = 2 * pos[:, 0] - cold[:, 1]  # the far point of the sphere: a warm start would stay there
    out, _ = solve_hard(est, pos, missing, pairs, lengths, start=start, start_unanchored_only=True)
    np.testing.assert_allclose(out, cold, rtol=0, atol=1e-9)
