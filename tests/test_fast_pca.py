"""The cross-validation curve from the held-out blocks' sums equals the one from reconstructing every row."""

import numpy as np
import pytest

from mocapfill.engines.weighted_pca import _blocks, cv_curve, fit_model, predictor_residual, weighted_sums


def curve_by_rows(flat, train, targets, predictors, marker_weight, row_weight=None, holdout=None):
    """The plain computation: every held-out row reconstructed with k = 1..q components."""
    cols = np.concatenate([3 * t + np.arange(3) for t in np.concatenate([targets, predictors])])
    block_all = flat[np.ix_(train, cols)]
    s1, s2, n = weighted_sums(block_all, row_weight)
    rows_out = np.arange(len(train)) if holdout is None else np.flatnonzero(holdout)
    nt = 3 * len(targets)
    sq, count = np.zeros((len(cols), nt)), 0
    for b in _blocks(len(rows_out), 5):
        rows = rows_out[b]
        held = block_all[rows]
        h1, h2, hn = weighted_sums(held, None if row_weight is None else row_weight[rows])
        model = fit_model(flat, train, targets, predictors, marker_weight, gram=(s1 - h1, s2 - h2, n - hn),
                          components=len(cols))
        z = (held - model.mean) / model.scale * model.weight
        z[:, :nt] = 0.0
        scores = z @ model.basis
        for k in range(1, len(cols) + 1):
            recon = scores[:, :k] @ model.basis[:nt, :k].T / model.weight[:nt] * model.scale[:nt] + model.mean[:nt]
            sq[k - 1] += ((recon - held[:, :nt]) ** 2).sum(axis=0)
        count += len(rows)
    return (sq / count).reshape(len(cols), len(targets), 3).mean(axis=2).T


@pytest.mark.parametrize("case", range(6))
def test_cv_curve_matches_row_by_row_reconstruction(case):
    rng = np.random.default_rng(case)
    n_markers, n = 6 + case, 150 + 40 * case
    flat = rng.normal(size=(n, 3)) @ rng.normal(size=(3, 3 * n_markers)) * 40 + rng.normal(size=(n, 3 * n_markers))
    flat += rng.normal(size=3 * n_markers) * 300  # off-centre, as laboratory coordinates are
    train = np.sort(rng.choice(n, n - 20, replace=False))
    weight = rng.uniform(0.05, 1.0, n_markers)
    row_weight = holdout = None
    if case % 2:
        row_weight = rng.uniform(0.2, 1.0, len(train))
        if case % 3:
            holdout = rng.uniform(size=len(train)) < 0.7
            row_weight[holdout] = 1.0
    want = curve_by_rows(flat, train, np.array([0]), np.arange(1, n_markers), weight, row_weight, holdout)
    got = cv_curve(flat, train, np.array([0]), np.arange(1, n_markers), weight, row_weight=row_weight,
                   holdout=holdout)
    np.testing.assert_allclose(got, want, rtol=1e-8)
    assert np.argmin(got[0]) == np.argmin(want[0])


def test_cv_curve_of_an_exactly_predicted_marker_is_finite_and_not_negative():
    # a rigid marker: its coordinates are a linear function of the predictors' (the error is round-off only)
    rng = np.random.default_rng(7)
    pred = rng.normal(size=(300, 4, 3)) * 50 + 800.0
    target = pred[:, :1] * 0.5 + pred[:, 1:2] * 0.5
    flat = np.concatenate([target, pred], axis=1).reshape(300, -1)
    curve = cv_curve(flat, np.arange(300), np.array([0]), np.arange(1, 5), np.ones(5))
    assert np.isfinite(curve).all() and (curve >= 0).all()


@pytest.mark.parametrize("case", range(3))
def test_held_out_predictor_residuals_match_the_rows(case):
    # cv_curve(residuals=True): each held-out row's predictors projected off the fold model's first k components
    rng = np.random.default_rng(10 + case)
    n_markers, n = 5 + case, 160
    flat = rng.normal(size=(n, 4)) @ rng.normal(size=(4, 3 * n_markers)) * 30 + rng.normal(size=(n, 3 * n_markers))
    flat += 500.0
    train = np.arange(n)
    weight = rng.uniform(0.05, 1.0, n_markers)
    targets, predictors = np.array([0]), np.arange(1, n_markers)
    curve, residual = cv_curve(flat, train, targets, predictors, weight, residuals=True)
    np.testing.assert_allclose(curve, cv_curve(flat, train, targets, predictors, weight), rtol=1e-12)
    cols = np.concatenate([3 * t + np.arange(3) for t in np.concatenate([targets, predictors])])
    s1, s2, cnt = weighted_sums(flat[:, cols], None)
    want = np.zeros(len(cols))
    for b in _blocks(n, 5):
        h1, h2, hn = weighted_sums(flat[b][:, cols], None)
        model = fit_model(flat, train, targets, predictors, weight, gram=(s1 - h1, s2 - h2, cnt - hn),
                          components=len(cols))
        for k in range(1, len(cols) + 1):
            want[k - 1] += predictor_residual(model._replace(basis=model.basis[:, :k],
                                                             singular=model.singular[:k]), flat[b]).sum()
    got = np.array([residual(k) for k in range(1, len(cols) + 1)])
    np.testing.assert_allclose(got, want / n, rtol=1e-7, atol=1e-9 * want.max())


def test_predictor_residual_is_zero_on_the_model_and_grows_off_it():
    rng = np.random.default_rng(3)
    flat = rng.normal(size=(200, 2)) @ rng.normal(size=(2, 12)) * 20 + 100.0  # rank 2 (+ the mean)
    # the target barely weighs (as a missing marker does), so the predictors' rows of the basis are ~orthonormal
    model = fit_model(flat, np.arange(200), np.array([0]), np.arange(1, 4), np.array([0.02, 1, 1, 1]), components=2)
    on = predictor_residual(model, flat)
    off = predictor_residual(model, flat[:5] + rng.normal(size=(5, 12)) * 20)
    assert on.max() < 1e-3 and (off > 1.0).all()


def test_few_rows_are_cross_validated_across_their_largest_time_gap():
    """A marker seen only at a short take's two ends (10-19 frames: one ordinary block) is scored by holding out each
    end in turn, as the gap between them would; an end of a single frame leaves nothing to score with."""
    rng = np.random.default_rng(3)
    base = rng.normal(size=(1, 5, 3)) * 100.0
    drift = np.linspace(0.0, 1.0, 200)[:, None, None] * rng.normal(size=(1, 5, 3)) * 30.0
    flat = (base + drift + rng.normal(size=(200, 5, 3))).reshape(200, -1)
    two_ends = np.r_[0:4, 194:200]
    assert cv_curve(flat, two_ends, np.array([0]), np.arange(1, 5), np.ones(5)) is None  # no times: one block
    curve = cv_curve(flat, two_ends, np.array([0]), np.arange(1, 5), np.ones(5), times=two_ends)
    expected = np.zeros((1, 15))
    for held, fit in ((np.arange(4), np.arange(4, 10)), (np.arange(4, 10), np.arange(4))):
        block = flat[np.ix_(two_ends, np.arange(15))]
        model = fit_model(flat, two_ends[fit], np.array([0]), np.arange(1, 5), np.ones(5), components=15)
        z = (block[held] - model.mean) / model.scale * model.weight
        z[:, :3] = 0.0
        scores = z @ model.basis
        for k in range(1, 16):
            recon = scores[:, :k] @ model.basis[:3, :k].T / model.weight[:3] * model.scale[:3] + model.mean[:3]
            expected[0, k - 1] += ((recon - block[held, :3]) ** 2).sum()
    # (beyond 3 components the 4-frame fold's basis is any basis of a null space: compare the first 3)
    assert np.allclose(curve[:, :3], expected[:, :3] / 10 / 3)
    one_end = np.r_[0, 189:200]  # the first end a single frame: nothing to fit when the other is held out
    assert cv_curve(flat, one_end, np.array([0]), np.arange(1, 5), np.ones(5), times=one_end) is None
