"""Fast paths of the default's spatial model (issue 21, helper "local"): each equals the plain computation it replaces.

The plain versions below are the straightforward forms (the code before the speed changes).  On this machine the fast
ones give the same numbers bit for bit, except the nearest-pose mean (the same neighbours, added in another order);
where a BLAS product is grouped differently the tests allow round-off.
"""

from __future__ import annotations

import numpy as np
import pytest

import mocapfill.engines.local_pca as lp
import mocapfill.engines.local_refit as lr
from mocapfill.bones.refinement import _bone_sums, _norm3, refine_bones
from mocapfill.engines.body_frame import nearest_rotation
from mocapfill.engines.weighted_pca import cv_curve, fit_model, mean_distances, predict, weighted_sums
from mocapfill.gaps import runs
from synthetic import moving_body, rot_x, rot_z


# ----------------------------------------------------------------------------------------------- nearest poses


def _plain_nearest(query, data, k):
    d2 = (query ** 2).sum(axis=1)[:, None] + (data ** 2).sum(axis=1)[None, :] - 2.0 * query @ data.T
    return np.argpartition(d2, k - 1, axis=1)[:, :k]


def _same_sets(a, b):
    return np.array_equal(np.sort(a, axis=1), np.sort(b, axis=1))


@pytest.mark.parametrize("g, n, q, k", [(150, 900, 12, 20), (7, 40, 5, 10), (70, 300, 30, 1), (1, 25, 4, 24)])
def test_nearest_rows_selects_the_argpartition_neighbours(g, n, q, k):
    rng = np.random.default_rng(g)
    data = rng.normal(size=(n, q)) * np.exp(-np.arange(q) / 4)
    query = data[rng.integers(0, n, g)] + 0.05 * rng.normal(size=(g, q))
    assert _same_sets(lp.nearest_rows(query, data, k), _plain_nearest(query, data, k))


def test_nearest_rows_keeps_argpartitions_choice_among_ties():
    rng = np.random.default_rng(3)
    base = rng.normal(size=(30, 6))
    data = np.concatenate([base, base, base[:10], base[:10] * (1 + 1e-12)])  # exact and float32 ties
    query = np.concatenate([base[:12] + 1e-3 * rng.normal(size=(12, 6)), base[:5]])
    for k in (1, 2, 3, 5, 10):
        assert np.array_equal(np.sort(lp.nearest_rows(query, data, k), axis=1),
                              np.sort(_plain_nearest(query, data, k), axis=1))


def test_nearest_rows_with_k_at_least_n_takes_every_row():
    data = np.arange(12.0).reshape(4, 3)
    out = lp.nearest_rows(data[:2] + 0.5, data, 4)
    assert out.shape == (2, 4) and all(sorted(row) == [0, 1, 2, 3] for row in out)


def _plain_knn(model, flat, est_local, n_train, k):
    nt = model.n_target
    z = (flat[:, model.columns] - model.mean) / model.scale * model.weight
    z[:, :nt] = 0.0
    resid = flat[:n_train, model.columns[:nt]] - est_local[:n_train]
    near = _plain_nearest(z[n_train:], z[:n_train], int(min(k, n_train)))
    out = np.zeros_like(est_local)
    out[n_train:] = resid[near].mean(axis=1)
    return out


# ----------------------------------------------------------------------------------------------- distances


def _plain_mean_distances(positions, m):
    n_frames, n_markers, _ = positions.shape
    out = np.full(n_markers, np.nan)
    for j in range(n_markers):
        d = [np.sqrt(((positions[t, j] - positions[t, m]) ** 2).sum()) for t in range(n_frames)]
        d = [x for x in d if np.isfinite(x)]
        if d:
            out[j] = sum(d) / len(d)
    return out


def _norm_mean_distances(positions, m):
    """mean_distances as first written: a norm over the last axis, then a nansum over the frames."""
    diff = np.linalg.norm(positions - positions[:, m:m + 1, :], axis=2)
    with np.errstate(invalid="ignore"):
        counts = np.isfinite(diff).sum(axis=0)
        return np.where(counts > 0, np.nansum(diff, axis=0) / np.maximum(counts, 1), np.nan)


def test_distances_to_equals_mean_distances():
    rng = np.random.default_rng(4)
    pos = rng.normal(size=(60, 7, 3)) * 300
    pos[rng.random((60, 7)) < 0.3] = np.nan
    pos[5, 2, 1] = np.nan  # one coordinate missing
    pos[:, 6] = np.nan  # never observed
    dist = lp.distances_to(pos)
    for m in range(7):
        assert np.array_equal(dist(m), _norm_mean_distances(pos, m), equal_nan=True)  # bit for bit
        assert np.array_equal(dist(m), mean_distances(pos, m), equal_nan=True)
        np.testing.assert_allclose(dist(m), _plain_mean_distances(pos, m), rtol=1e-12)


# ----------------------------------------------------------------------------------------------- local frames


def test_kabsch_cross_covariance_is_the_stacked_product():
    rng = np.random.default_rng(5)
    for n, p in [(300, 3), (40, 7), (1, 4), (64, 20)]:
        shapes = rng.normal(size=(n, p, 3)) * 100
        shapes -= shapes.mean(axis=1, keepdims=True)
        reference = rng.normal(size=(p, 3)) * 100
        w = rng.random(p)
        plain = nearest_rotation(np.swapaxes(shapes, 1, 2) @ (w[:, None] * reference))
        # bit for bit with this machine's OpenBLAS; another BLAS may group the products' sums otherwise
        np.testing.assert_allclose(lp.kabsch_rotations(shapes, reference, w), plain, rtol=0, atol=1e-13)


def test_local_frames_gathers_only_the_anchors():
    rng = np.random.default_rng(6)
    pos = rng.normal(size=(80, 9, 3)) * 100
    frames, anchors = np.sort(rng.choice(80, 50, replace=False)), np.array([1, 4, 6, 7])
    w = rng.random(4)
    centre, rot = lp.local_frames(pos, frames, anchors, w, np.arange(30))
    pts = pos[frames][:, anchors]
    c = np.einsum("tjc,j->tc", pts, w) / w.sum()
    assert np.array_equal(centre, c)
    shapes = pts - c[:, None, :]
    ref = shapes[15]
    r = nearest_rotation(np.swapaxes(shapes[:30], 1, 2) @ (w[:, None] * ref))
    ref = (shapes[:30] @ r).mean(axis=0)
    ref -= (w[:, None] * ref).sum(axis=0) / w.sum()
    assert np.array_equal(rot, nearest_rotation(np.swapaxes(shapes, 1, 2) @ (w[:, None] * ref)))


def test_edge_mask_equals_the_loop_over_runs():
    rng = np.random.default_rng(7)
    for _ in range(300):
        n, width = int(rng.integers(1, 60)), int(rng.integers(0, 5))
        gap = rng.random(n) < rng.uniform(0, 1)
        plain = np.zeros(n, dtype=bool)
        for start, length in runs(gap):
            plain[max(start - width, 0):start] = True
            plain[start + length:start + length + width] = True
        assert np.array_equal(lp.edge_mask(np.flatnonzero(gap), n, width), plain)


# ----------------------------------------------------------------------------------------------- the local model


def _plain_group_model(positions, m, group, predictors, train, weights, align_weight, dist, scales, *, reach,
                       normalise, folds, knn, row_weight=None, used_references=None, max_predictors=None,
                       extrapolation=None, disagreement=None, split_by_time=False, max_rms=None):
    """group_model as first written: a full-width (n, 3 n_markers) NaN array of local coordinates, the training
    block gathered by rows and columns, the nearest poses by a float64 argpartition (no reference rows, no bound on
    the predictors)."""
    assert row_weight is None and max_predictors is None and extrapolation is None and disagreement is None
    assert max_rms is None
    n_markers = positions.shape[1]
    needed = np.concatenate([[m], predictors])
    anchors = lp._anchor_set(predictors, align_weight)
    used = np.concatenate([train, group])
    n_train = len(train)
    centre, rot = lp.local_frames(positions, used, anchors, align_weight[anchors], np.arange(n_train))
    local = np.full((len(used), n_markers, 3), np.nan)
    local[:, needed] = (positions[used][:, needed] - centre[:, None, :]) @ rot
    flat = local.reshape(len(used), 3 * n_markers)
    tr = np.arange(n_train)
    target = np.array([m])
    ests, rmss, levs, ks, sens = [], [], [], [], []
    for w, width in zip(weights, scales):
        pred = predictors[dist[predictors] <= reach * width]
        if len(pred) < 3:
            pred = predictors[np.argsort(dist[predictors])[:3]]
        curve = cv_curve(flat, tr, target, pred, w, normalise=normalise, folds=folds,
                         times=train if split_by_time else None)
        k, rms = (None, np.nan) if curve is None else (int(np.argmin(curve[0])) + 1, None)
        if curve is not None:
            rms = float(np.sqrt(curve[0, k - 1]))
        gram = weighted_sums(flat[np.ix_(tr, lp._cols(target) + lp._cols(pred))], None)
        model = fit_model(flat, tr, target, pred, w, normalise=normalise, components=k, gram=gram)
        est_local, leverage = predict(model, flat)
        if knn:
            est_local[n_train:] += _plain_knn(model, flat, est_local, n_train, knn)[n_train:]
        ests.append(est_local)
        rmss.append(rms)
        levs.append(leverage)
        ks.append(int(model.basis.shape[1]))
        nt = model.n_target
        gain = (model.weight[nt:] / model.scale[nt:])[:, None] * (model.basis[nt:] @ model.basis[:nt].T) \
            * (model.scale[:nt] / model.weight[:nt])[None, :]
        full = np.zeros((3 * n_markers, 3))
        full[model.columns[nt:]] = gain
        sens.append(full)
    rmss_a = np.asarray(rmss)
    mix = 1.0 / rmss_a ** 2 if np.isfinite(rmss_a).all() and (rmss_a > 0).all() else np.ones(len(ests))
    mix = mix / mix.sum()
    est_local = np.einsum("s,std->td", mix, np.stack(ests))
    leverage = np.einsum("s,st->t", mix, np.stack(levs))
    rms_mix = float(np.dot(mix, rmss_a)) if np.isfinite(rmss_a).all() else np.nan
    est_all = (rot @ est_local[:, :, None])[:, :, 0] + centre
    sensitivity = (np.einsum("s,sqc->qc", mix, np.stack(sens)) ** 2).reshape(n_markers, 9).sum(axis=1) / 3.0
    return est_all, leverage, rms_mix, ks, rmss, anchors, sensitivity


def _capture():
    """A turning body whose last markers swing on a hinge, with gaps of several markers at once."""
    t_angle = lambda t: 0.8 * np.sin(1.3 * t)  # noqa: E731
    pos = moving_body(400, 10, seed=8, rotation=lambda t: rot_z(0.7 * t) @ rot_x(0.3 * np.sin(t)),
                      hinge=(slice(7, 10), lambda t: rot_x(t_angle(t)), [0.0, 0.0, 0.0]), noise=0.5)
    rng = np.random.default_rng(8)
    missing = np.zeros(pos.shape[:2], dtype=bool)
    for m in (0, 3, 5, 8, 9):
        for _ in range(3):
            start = int(rng.integers(0, 360))
            missing[start:start + int(rng.integers(5, 40)), m] = True
    pos[missing] = np.nan
    return pos


SCALES = (150.0, 200.0, 300.0, 3000.0)


def test_reconstruct_local_equals_the_full_width_model(monkeypatch):
    pos = _capture()
    kw = dict(scales=SCALES, align_scale=200.0, knn=0, edge=None, edge_frames=3)
    est, std, info = lp.reconstruct_local(pos, **kw)
    monkeypatch.setattr(lp, "group_model", _plain_group_model)
    est0, std0, info0 = lp.reconstruct_local(pos, **kw)
    assert np.isfinite(est).sum() > np.isfinite(pos).sum()  # it filled something
    # bit for bit on this machine (the Kabsch products' grouping aside, the same numpy and BLAS operations)
    for a, b in [(est, est0), (std, std0), (info["edge_estimate"], info0["edge_estimate"]),
                 (info["edge_std"], info0["edge_std"]), (info["anchors"], info0["anchors"])]:
        assert np.array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    assert [g["components"] for g in info["groups"]] == [g["components"] for g in info0["groups"]]
    np.testing.assert_allclose([g["cv_rms"] for g in info["groups"]], [g["cv_rms"] for g in info0["groups"]],
                               rtol=1e-12)


def test_reconstruct_completed_equals_the_full_width_model(monkeypatch):
    pos = _capture()
    missing = np.isnan(pos).any(axis=2)
    completed = np.where(missing[..., None], lp.reconstruct_local(pos, scales=SCALES, align_scale=200.0)[0], pos)
    sd = np.where(missing, 5.0, 0.0)
    kw = dict(scales=SCALES, align_scale=200.0, knn=20, edge_frames=3, trust=10.0)
    out = lr.reconstruct_completed(pos, completed, sd, **kw)
    monkeypatch.setattr(lr, "group_model", _plain_group_model)
    out0 = lr.reconstruct_completed(pos, completed, sd, **kw)
    assert np.isfinite(out[1]).any()
    for a, b in zip(out, out0):
        # the same neighbours; their mean residual added in another order
        assert np.array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


# ----------------------------------------------------------------------------------------------- bone refinement


def test_norm3_is_the_norm_bit_for_bit():
    rng = np.random.default_rng(9)
    d = rng.normal(size=(50, 7, 3)) * np.exp(rng.normal(size=(50, 7, 3)) * 4)
    assert np.array_equal(_norm3(d), np.linalg.norm(d, axis=2))


def test_hess_sum_equals_the_dense_block_sum():
    ia = np.array([0, 1, -1, 2, 0, 3, 0])
    ib = np.array([1, -1, 2, 3, 2, -1, 1])
    k, n = 4, 5
    rng = np.random.default_rng(10)
    o = rng.normal(size=(n, len(ia), 3, 3))
    dense = np.zeros((n, 3 * k, 3 * k))
    for j in range(len(ia)):
        for a, sa in ((ia[j], 1.0), (ib[j], -1.0)):
            for b, sb in ((ia[j], 1.0), (ib[j], -1.0)):
                if a >= 0 and b >= 0:
                    dense[:, 3 * a:3 * a + 3, 3 * b:3 * b + 3] += sa * sb * o[:, j]
    np.testing.assert_allclose(_bone_sums(ia, ib, k)[1](o), dense, atol=1e-12)


def _objective(y, estimate, std, pairs, lengths, spread, frame, markers):
    """refine_bones' objective for one frame, ``y`` the moved markers' positions (3 k,)."""
    pos = estimate[frame].copy()
    pos[markers] = y.reshape(-1, 3)
    prior = ((pos[markers] - estimate[frame, markers]) ** 2).sum(axis=1) / std[frame, markers] ** 2
    r = np.linalg.norm(pos[pairs[:, 0]] - pos[pairs[:, 1]], axis=1) - lengths
    touch = np.isin(pairs, markers).any(axis=1)
    return prior.sum() + (r[touch] ** 2 / spread[touch] ** 2).sum()


def _loose_limbs(seed=11, noise=60.0, sd=(50.0, 300.0), share=0.4):
    """60 frames of 12 markers, ``share`` of the samples missing, their estimates ``noise`` mm off (sd in ``sd``): markers
    with weak estimates hang on bones their estimates break."""
    rng = np.random.default_rng(seed)
    truth = moving_body(60, 12, seed=seed, rotation=lambda t: rot_z(0.9 * t))
    pairs = np.array([(i, j) for i in range(12) for j in range(i + 1, 12) if (i + j) % 3 != 0])
    lengths = np.linalg.norm(truth[0, pairs[:, 0]] - truth[0, pairs[:, 1]], axis=1)
    spread = rng.uniform(1.0, 3.0, len(pairs))
    positions = truth.copy()
    missing = rng.random((60, 12)) < share
    positions[missing] = np.nan
    estimate = truth + np.where(missing[..., None], rng.normal(size=truth.shape) * noise, 0.0)
    std = np.where(missing, rng.uniform(*sd, missing.shape), 0.0)
    return estimate, positions, std, pairs, lengths, spread


def test_refine_bones_reaches_the_minimum_a_general_optimiser_finds():
    from scipy.optimize import minimize

    estimate, positions, std, pairs, lengths, spread = _loose_limbs()
    out, info = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0)
    assert info["frames"] > 40
    missing = np.isnan(positions).any(axis=2)
    for frame in range(0, 60, 7):
        markers = np.flatnonzero(missing[frame])
        if not len(markers):
            continue
        args = (estimate, std, pairs, lengths, spread, frame, markers)
        ours = _objective(out[frame, markers].ravel(), *args)
        best = minimize(_objective, out[frame, markers].ravel(), args=args, method="BFGS", options={"gtol": 1e-10})
        # from our answer a general optimiser finds nothing lower to speak of (the objective is twice a negative log
        # likelihood: 0.1 is a tenth of a standard deviation's worth), and ours is far below the start
        assert ours <= best.fun + 0.1
        assert ours < 0.5 * _objective(estimate[frame, markers].ravel(), *args)
    assert info["unconverged"] == 0


def test_refine_bones_is_not_stopped_halfway_by_an_iteration_count():
    # estimates 30 cm off with sds of 30-100 cm on tight bones: the Gauss-Newton steps this solver replaced left the
    # objective 13x its minimum after their 10 iterations (a loose marker slid along its bones' tangents and was
    # damped back); with the curvature across stretched bones the default bound ends within a few per cent of it
    estimate, positions, std, pairs, lengths, spread = _loose_limbs(seed=5, noise=300.0, sd=(300.0, 1000.0), share=0.6)
    missing = np.isnan(positions).any(axis=2)

    def total(out):
        return sum(_objective(out[t, np.flatnonzero(missing[t])].ravel(), estimate, std, pairs, lengths, spread, t,
                              np.flatnonzero(missing[t])) for t in range(len(out)) if missing[t].any())

    out, _ = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0)
    full, info = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0, max_iter=1000)
    assert total(full) <= total(out) <= 1.05 * total(full)
    assert info["unconverged"] == 0


def test_bone_components_split_the_moved_markers_by_the_bones_between_them():
    from mocapfill.bones.refinement import _components

    markers = np.array([2, 3, 5, 7, 8, 9, 11, 12])
    pairs = np.array([(2, 3), (3, 0), (1, 5), (7, 8), (9, 0), (8, 11), (4, 6)])  # 12 is on no bone
    comps = sorted(c.tolist() for c in _components(markers, pairs))
    assert comps == [[2, 3], [5], [7, 8, 11], [9]]


def test_refine_bones_takes_spreads_per_frame():
    """Spreads per frame and bone (n_frames, B) that repeat the per-bone ones give the same answer bit for bit; a
    spread raised in some frames frees the markers there and only there."""
    estimate, positions, std, pairs, lengths, spread = _loose_limbs()
    out, _ = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0)
    tiled = np.tile(spread, (len(positions), 1))
    same, _ = refine_bones(estimate, positions, std, pairs, lengths, tiled, spread_floor=1.0)
    assert np.array_equal(out, same)
    tiled[:30] = 1e6  # no bone holds in the first 30 frames
    free, _ = refine_bones(estimate, positions, std, pairs, lengths, tiled, spread_floor=1.0)
    assert np.allclose(free[:30], estimate[:30], atol=1e-3)
    assert np.array_equal(free[30:], out[30:])


def test_refine_bones_reuses_the_problems_a_memo_holds(monkeypatch):
    """With a memo shared between two calls, the second solves only the problems whose inputs changed, and both give
    what calls without it give, bit for bit (the info too)."""
    import mocapfill.bones.refinement as refinement

    estimate, positions, std, pairs, lengths, spread = _loose_limbs()
    plain, plain_info = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0)
    moved = estimate.copy()
    moved[40:] += 5.0  # the later frames' fill changed (a refit there), the earlier ones' not
    plain2, plain2_info = refine_bones(moved, positions, std, pairs, lengths, spread, spread_floor=1.0)

    solved = []
    real = refinement.forked_map

    def counting(func, items, jobs, cost=None):
        items = list(items)
        solved.append(len(items))
        return real(func, items, jobs, cost=cost)

    monkeypatch.setattr(refinement, "forked_map", counting)
    memo: dict = {}
    out, info = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0, memo=memo)
    again, again_info = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0, memo=memo)
    out2, info2 = refine_bones(moved, positions, std, pairs, lengths, spread, spread_floor=1.0, memo=memo)
    assert np.array_equal(out, plain) and np.array_equal(again, plain) and np.array_equal(out2, plain2)
    assert info == plain_info == again_info and info2 == plain2_info
    assert solved[0] == len(memo) - solved[2] and solved[1] == 0  # the same inputs: nothing solved again
    assert 0 < solved[2] < solved[0]  # only the problems with a frame from 40 on
