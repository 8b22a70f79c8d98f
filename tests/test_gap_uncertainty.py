"""The cross-validated error of long gaps (methods/gap_uncertainty.py) and DynaMMo's std that uses it."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapfill.engines import gap_uncertainty as gu
from mocapfill.methods.dynammo import run_dynammo


def test_second_opinion_is_a_centred_ridge_from_the_markers_seen_throughout_the_gap():
    rng = np.random.default_rng(0)
    T, M = 300, 6
    X = rng.standard_normal((T, 3 * M)) + 5.0
    observed = np.ones((T, M), bool)
    observed[120:180, [1, 4]] = False
    observed[150:160, 5] = False  # not seen throughout the gap: not a feature
    observed[10:20, 0] = False  # a training frame with a feature missing: not a row
    frames = np.arange(120, 180)
    got = gu.second_opinion(X, observed, np.array([1, 4]), frames)
    rows = np.r_[0:10, 20:120, 180:T]
    co = np.r_[0:3, 6:12]  # markers 0, 2, 3
    cs = np.r_[3:6, 12:15]
    A, B = X[np.ix_(rows, co)], X[np.ix_(rows, cs)]
    am, bm = A.mean(axis=0), B.mean(axis=0)
    gram = (A - am).T @ (A - am)
    gram += gu.RIDGE * np.trace(gram) / gram.shape[0] * np.eye(len(co))
    expected = (X[np.ix_(frames, co)] - am) @ np.linalg.solve(gram, (A - am).T @ (B - bm)) + bm
    np.testing.assert_allclose(got, expected, rtol=1e-10)
    observed[120:180] = False  # nothing seen throughout the gap: no opinion
    assert gu.second_opinion(X, observed, np.array([1, 4]), frames) is None


def bridged_opinion(X, observed, k, a, b):
    """The second opinion on frames [a, b) of marker k, moved to meet the data at frames a - 1 and b."""
    op = gu.second_opinion(X, observed, np.array([k]), np.arange(a - 1, b + 1))
    left, right = X[a - 1, 3 * k:3 * k + 3] - op[0], X[b, 3 * k:3 * k + 3] - op[-1]
    w = (np.arange(b - a) + 1.0)[:, None] / (b - a + 1.0)
    return op[1:-1] + (1 - w) * left + w * right


def test_gap_variance_is_the_disagreement_with_the_bridged_opinion_spread_over_the_gap():
    rng = np.random.default_rng(2)
    T, M = 500, 5
    X = np.cumsum(rng.standard_normal((T, 3 * M)), axis=0)
    observed = np.ones((T, M), bool)
    observed[200:300, 3] = False  # long enough: a second opinion
    observed[50:55, 1] = False  # too short: left to the model
    X[200:300, 9:12] += 4.0 * np.sin(np.linspace(0, np.pi, 100))[:, None]  # a fill that bulges away in the middle
    var = gu.gap_variance(X, observed)
    assert np.isnan(var[observed]).all() and np.isnan(var[50:55, 1]).all()
    opinion = bridged_opinion(X, observed, 3, 200, 300)
    np.testing.assert_allclose(var[200:300, 3].mean(), np.mean((opinion - X[200:300, 9:12]) ** 2))
    assert var[250, 3] > var[200, 3] and var[250, 3] > var[299, 3]
    X[200:300, 9:12] = opinion  # a fill that agrees: nothing to doubt
    assert np.nanmax(gu.gap_variance(X, observed)) < 1e-20


def test_dynammo_std_follows_the_error_on_a_long_gap():
    """A marker rigidly tied to the others and one that wanders on its own, hidden equally long: the std says which
    fill to trust (the model's own posterior says the same for both)."""
    rng = np.random.default_rng(3)
    T = 600
    t = np.arange(T) / 100.0
    body = np.stack([np.sin(t), np.cos(0.7 * t), 0.3 * t], axis=1) * 100.0
    markers = [body + 30.0 * rng.standard_normal(3) for _ in range(5)]
    wander = body + np.cumsum(rng.standard_normal((T, 3)), axis=0) * 3.0
    P = np.stack(markers + [wander], axis=1)
    results = {}
    for k in (2, 5):
        X = P.copy()
        X[250:400, k] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = run_dynammo(X, hidden=4, max_iter=40, seed=0)
            model = run_dynammo(X, hidden=4, max_iter=40, seed=0, uncertainty="model")
        err = np.sqrt(np.mean((res.positions[250:400, k] - P[250:400, k]) ** 2))
        results[k] = (err, np.sqrt(np.mean(res.std[250:400, k] ** 2)), np.sqrt(np.mean(model.std[250:400, k] ** 2)))
        np.testing.assert_array_equal(res.positions, model.positions)  # only the std differs
    (e_tied, s_tied, _), (e_wander, s_wander, _) = results[2], results[5]
    assert e_wander > 5 * e_tied
    assert s_wander > 5 * s_tied
    for err, std, _ in results.values():
        assert 0.2 < err / std < 5


@pytest.mark.accuracy
def test_honest_on_the_authors_two_marker_trial_where_the_model_was_8x_overconfident(authors_trial):
    """132_32 P2 3: knee and shin hidden for 270 frames; DynaMMo misses by ~94 mm where its posterior said ~11."""
    data, occluded, hidden = authors_trial("132_32", "P2", 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run_dynammo(occluded, seed=0)
    actual = np.sqrt(np.mean((res.positions - data.positions)[hidden] ** 2))
    predicted = np.sqrt(np.mean(res.std[hidden] ** 2))
    assert 0.5 <= actual / predicted <= 2.0
