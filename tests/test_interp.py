"""`linear` and `spline`: exact on what they can represent, edges held, never-observed markers left alone."""

from __future__ import annotations

import numpy as np

from mocapfill.methods.interp import fill_linear, fill_spline, interpolate_linear


def trajectories(n_frames: int = 40) -> np.ndarray:
    """Two markers: a straight line and a cubic in time; shape (n_frames, 2, 3)."""
    t = np.arange(n_frames, dtype=float)
    line = np.stack([2 * t + 1, -t, 0.5 * t + 3], axis=1)
    cubic = np.stack([0.01 * t**3 - 0.2 * t**2 + t, 0.002 * t**3 + 5, -0.03 * t**2 + 0.1 * t], axis=1)
    return np.stack([line, cubic], axis=1)


def test_linear_is_exact_on_a_line_and_spline_on_a_cubic():
    truth = trajectories()
    pos = truth.copy()
    pos[10:20] = np.nan  # both markers: a blackout of the whole body
    pos[25:28, 1] = np.nan
    lin = fill_linear(pos)
    spl = fill_spline(pos)
    np.testing.assert_allclose(lin.positions[:, 0], truth[:, 0], atol=1e-9)
    np.testing.assert_allclose(spl.positions[:, 0], truth[:, 0], atol=1e-9)
    np.testing.assert_allclose(spl.positions[:, 1], truth[:, 1], atol=1e-8)  # not-a-knot reproduces cubics
    assert not np.allclose(lin.positions[10:20, 1], truth[10:20, 1])
    for result in (lin, spl):
        assert result.filled[10:20].all() and result.n_iter == 0 and result.converged
        assert result.std is None


def test_edge_gaps_hold_the_nearest_observation():
    truth = trajectories()
    pos = truth.copy()
    pos[:5, 1] = np.nan
    pos[-8:, 1] = np.nan
    for fill in (fill_linear, fill_spline):
        out = fill(pos).positions
        np.testing.assert_array_equal(out[:5, 1], np.repeat(truth[5:6, 1], 5, axis=0))
        np.testing.assert_array_equal(out[-8:, 1], np.repeat(truth[-9:-8, 1], 8, axis=0))
        assert fill(pos).info["edges"] == "held"


def test_spline_stays_bounded_on_a_short_noisy_marker():
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(200, 1, 3))
    pos[:80] = np.nan
    pos[120:] = np.nan
    out = fill_spline(pos).positions
    seen = pos[80:120, 0]
    assert np.all(out[:, 0] >= seen.min(axis=0) - 1e-12) and np.all(out[:, 0] <= seen.max(axis=0) + 1e-12)


def test_single_observation_is_held_and_never_observed_stays_missing():
    pos = trajectories(12)
    pos[:, 0] = np.nan
    pos[:, 1] = np.nan
    pos[4, 1] = [1.0, 2.0, 3.0]
    for fill in (fill_linear, fill_spline):
        result = fill(pos)
        assert np.isnan(result.positions[:, 0]).all() and not result.filled[:, 0].any()
        np.testing.assert_array_equal(result.positions[:, 1], np.tile([1.0, 2.0, 3.0], (12, 1)))
        assert result.info["all_missing"] == [0]


def test_observed_samples_are_bit_identical_and_input_untouched():
    rng = np.random.default_rng(1)
    pos = rng.normal(size=(50, 4, 3)) * 1e3
    pos[rng.random((50, 4)) < 0.3] = np.nan
    before = pos.copy()
    for fill in (fill_linear, fill_spline):
        result = fill(pos)
        seen = ~np.isnan(pos).any(axis=2)
        assert np.array_equal(result.positions[seen], pos[seen])
        np.testing.assert_array_equal(pos, before)


def test_spline_with_two_or_three_observations():
    pos = np.full((10, 1, 3), np.nan)
    pos[2, 0] = 0.0
    pos[8, 0] = 6.0
    out = fill_spline(pos).positions[:, 0, 0]
    np.testing.assert_allclose(out, [0, 0, 0, 1, 2, 3, 4, 5, 6, 6])
    pos[5, 0] = 3.0
    np.testing.assert_allclose(fill_spline(pos).positions[:, 0, 0], [0, 0, 0, 1, 2, 3, 4, 5, 6, 6])


def test_interpolate_linear_matches_fill_linear():
    pos = trajectories()
    pos[3:9, 0] = np.nan
    np.testing.assert_array_equal(interpolate_linear(pos), fill_linear(pos).positions)
