"""pair_distance_stats: exact against NumPy's nan-reductions, chunking, edge cases."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapfill.bones.distances import all_pairs, pair_distance_stats, pair_distances, pair_index
from mocapfill.errors import MocapfillError


def _random_positions(seed: int, n_frames: int = 120, n_markers: int = 9, missing: float = 0.25) -> np.ndarray:
    rng = np.random.default_rng(seed)
    positions = rng.normal(0, 100, (n_frames, n_markers, 3))
    positions[rng.random((n_frames, n_markers)) < missing] = np.nan
    return positions


def _reference(positions: np.ndarray, pairs: np.ndarray, levels):
    d = pair_distances(positions, pairs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return (d, np.nanmean(d, 0), np.nanstd(d, 0), np.nanmin(d, 0), np.nanmax(d, 0),
                np.nanpercentile(d, levels, axis=0).T)


@pytest.mark.parametrize("chunk", [1, 5, None])
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_nan_reductions(seed, chunk):
    positions = _random_positions(seed)
    positions[:, 4] = np.nan  # a marker never observed: its pairs have count 0 and NaN statistics
    positions[3, 2, 1] = np.nan  # one NaN coordinate makes the whole sample missing
    levels = (0, 1, 5, 50, 95, 99, 100)
    stats = pair_distance_stats(positions, percentiles=levels, chunk=chunk)
    d, mean, std, dmin, dmax, pct = _reference(np.where(np.isnan(positions).any(2, keepdims=True), np.nan,
                                                        positions), stats.pairs, levels)
    np.testing.assert_array_equal(stats.count, (~np.isnan(d)).sum(0))
    for got, want in [(stats.mean, mean), (stats.std, std), (stats.min, dmin), (stats.max, dmax),
                      (stats.percentiles, pct)]:
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9, equal_nan=True)
    assert np.isnan(stats.mean[(stats.pairs == 4).any(1)]).all()
    np.testing.assert_array_equal(stats.percentile(50), stats.percentiles[:, 3])


def test_given_pairs_and_layout():
    positions = _random_positions(3, missing=0.0)
    pairs = np.array([[0, 1], [5, 2], [8, 0]])
    stats = pair_distance_stats(positions, pairs)
    np.testing.assert_array_equal(stats.pairs, pairs)
    assert stats.percentiles.shape == (3, 5)
    expected = np.linalg.norm(positions[:, 5] - positions[:, 2], axis=1)
    assert stats.mean[1] == pytest.approx(expected.mean(), rel=1e-13)
    assert (stats.count == positions.shape[0]).all()


def test_all_pairs_and_index():
    pairs = all_pairs(5)
    assert pairs.shape == (10, 2) and (pairs[:, 0] < pairs[:, 1]).all()
    index = pair_index(pairs, 5)
    assert index[3, 1] == index[1, 3] == 5 and index[2, 2] == -1


def test_empty_inputs():
    stats = pair_distance_stats(np.zeros((0, 3, 3)))
    assert stats.count.tolist() == [0, 0, 0] and np.isnan(stats.mean).all()
    stats = pair_distance_stats(np.zeros((10, 1, 3)))
    assert stats.pairs.shape == (0, 2) and stats.percentiles.shape == (0, 5)


@pytest.mark.parametrize("bad", [dict(positions=np.zeros((4, 3))),
                                 dict(pairs=np.array([[0, 7]])),
                                 dict(pairs=np.array([0.0, 1.0])),
                                 dict(percentiles=(50, 101))])
def test_bad_arguments(bad):
    kwargs = {"positions": np.zeros((4, 3, 3))} | bad
    with pytest.raises(MocapfillError):
        pair_distance_stats(**kwargs)
    with pytest.raises(MocapfillError, match="not computed"):
        pair_distance_stats(np.zeros((4, 3, 3))).percentile(25)


def test_no_percentiles_and_running_median():
    positions = _random_positions(4, missing=0.1)
    stats = pair_distance_stats(positions, percentiles=())
    assert stats.percentiles.shape == (len(stats.pairs), 0) and np.isfinite(stats.std).all()
    from numpy.lib.stride_tricks import sliding_window_view

    d = pair_distances(positions, stats.pairs)
    med = np.median(sliding_window_view(d, 3, axis=0), axis=-1)  # NaN where the window touches a gap
    windowed = pair_distance_stats(positions, percentiles=(0, 100), window=3)
    np.testing.assert_array_equal(windowed.count, np.isfinite(med).sum(0))
    np.testing.assert_allclose(windowed.max, np.nanmax(med, 0))
    np.testing.assert_allclose(windowed.percentiles[:, 0], np.nanmin(med, 0))
    with pytest.raises(MocapfillError, match="window"):
        pair_distance_stats(positions, window=4)
