"""The distance-weighted PCA fill (``--method pca``, Gløersen & Federolf 2016) and its building blocks."""

from __future__ import annotations

import numpy as np
import pytest

import mocapfill
from mocapfill.errors import MethodError
from mocapfill.methods import get_method
from mocapfill.engines.weighted_pca import (
    _keep,
    gaussian_weights,
    mean_distances,
    pattern_groups,
    ranked_groups,
    weight_width,
)
from mocapfill.methods.pca import fill_pca


def walking_cloud(n_frames: int = 400, n_markers: int = 10, seed: int = 1) -> np.ndarray:
    """Markers (mm) whose local positions are linear in two latent signals, translated along x: every marker is a
    linear function of the others, which is exactly what the PCA reconstruction assumes.  (n_frames, n_markers, 3)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / 100.0
    latent = np.stack([np.sin(2 * np.pi * 0.8 * t), np.cos(2 * np.pi * 1.3 * t)], axis=1)  # (n_frames, 2)
    base = rng.normal(scale=150.0, size=(n_markers, 3))
    modes = rng.normal(scale=30.0, size=(2, n_markers, 3))
    pos = base[None] + np.einsum("fk,kmc->fmc", latent, modes)
    pos[:, :, 0] += 500.0 * t[:, None]
    return pos


def test_registered_and_default_options():
    assert get_method("pca").load() is fill_pca
    assert weight_width("mm", None) == 200.0
    assert weight_width("cm", None) == pytest.approx(20.0)
    assert weight_width("m", None) == pytest.approx(0.2)
    assert weight_width("m", 0.5) == 0.5


def test_weights_are_gaussian_in_mean_distance():
    pos = np.zeros((5, 3, 3))
    pos[:, 1, 0] = 200.0
    pos[:, 2, 0] = 400.0
    pos[0, 2] = np.nan  # a missing sample does not enter the mean
    d = mean_distances(pos, 0)
    assert d == pytest.approx([0.0, 200.0, 400.0])
    w = gaussian_weights(d, 200.0)
    assert w == pytest.approx(np.exp(-0.5 * np.array([0.0, 1.0, 4.0])))
    assert gaussian_weights(np.array([np.nan]), 200.0)[0] == 0.0  # never seen together: no weight


def test_components_reach_99_percent_of_cumulative_singular_values():
    s = np.array([50.0, 30.0, 15.0, 4.0, 0.6, 0.4])
    assert _keep(s, 0.99) == 4  # 99 % of the sum is 99.0; the first four give 99.0
    assert _keep(s, 0.5) == 1
    assert _keep(s, 1.0) == 6


def test_fills_a_linear_marker_exactly_and_keeps_observed_bits():
    truth = walking_cloud()
    pos = truth.copy()
    pos[100:220, 3] = np.nan
    res = fill_pca(pos)
    assert res.filled[100:220, 3].all() and res.filled.sum() == 120
    observed = ~np.isnan(pos).any(axis=2)
    assert np.array_equal(res.positions[observed], pos[observed])  # bit-identical
    err = np.linalg.norm(res.positions[100:220, 3] - truth[100:220, 3], axis=1)
    assert err.max() < 1.0  # mm: a marker that is a linear function of the others comes back almost exactly
    assert res.std.shape == (400, 10)
    assert (res.std[observed] == 0).all() and np.isfinite(res.std[100:220, 3]).all()
    assert res.info["components"] and res.info["fallback"] == []


def test_units_only_rescale_the_fill():
    truth = walking_cloud()
    pos = truth.copy()
    pos[50:150, 2] = np.nan
    pos[200:260, 7] = np.nan
    mm = fill_pca(pos, units="mm").positions
    m = fill_pca(pos / 1000.0, units="m").positions
    assert np.allclose(m * 1000.0, mm, atol=1e-6)


def test_separate_and_joint_strategies_fill_several_markers():
    truth = walking_cloud()
    pos = truth.copy()
    pos[100:200, [2, 3]] = np.nan  # two markers sharing a gap
    pos[250:300, 6] = np.nan
    for strategy in ("separate", "joint"):
        res = fill_pca(pos, strategy=strategy)
        assert res.filled.sum() == 250
        err = np.linalg.norm(res.positions - truth, axis=2)[np.isnan(pos).any(axis=2)]
        assert err.max() < 1.0, strategy


def test_no_predictors_falls_back_to_interpolation_and_all_missing_stays_missing():
    pos = walking_cloud(n_markers=4)
    pos[:, 3] = np.nan  # never observed
    pos[10:20] = np.nan  # blackout: nothing to predict from
    res = fill_pca(pos)
    assert np.isnan(res.positions[:, 3]).all()
    assert np.isfinite(res.positions[:, :3]).all()
    assert set(res.info["fallback"]) == {0, 1, 2}


def test_pattern_groups_are_bounded():
    missing = np.zeros((12, 5), dtype=bool)
    frames = np.arange(12)
    for f in frames:  # every frame has its own pattern of missing candidates
        missing[f, 1 + f % 4] = True
        missing[f, 1 + (f // 4) % 4] = True
    groups = pattern_groups(missing, frames, np.arange(1, 5), 3)
    assert len(groups) == 3
    assert sorted(np.concatenate([g for g, _ in groups])) == list(frames)
    for g, predictors in groups:  # predictors are observed in every frame of their group
        assert not missing[np.ix_(g, predictors)].any()


def test_ranked_groups_rank_by_summed_size_and_merge_the_rest_on_the_or_of_their_keys():
    """Equal rows are one group; the groups come largest summed size first (between equal sums, the later key in
    lexicographic order first); past ``max_groups`` the rest are one group, last, keyed by the OR of theirs."""
    keys = np.array([[0, 1, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0], [0, 0, 0]], dtype=bool)
    got = [(rows.tolist(), key.astype(int).tolist()) for rows, key in ranked_groups(keys, None, 4)]
    assert got == [([1, 4], [1, 0, 0]), ([0, 2], [0, 1, 0]), ([3], [0, 0, 1]), ([5], [0, 0, 0])]
    got = [(rows.tolist(), key.astype(int).tolist()) for rows, key in ranked_groups(keys, None, 3)]
    assert got == [([1, 4], [1, 0, 0]), ([0, 2], [0, 1, 0]), ([3, 5], [0, 0, 1])]
    sizes = np.array([1.0, 1.0, 1.0, 9.0, 1.0, 1.0])  # the single row of key 001 now outweighs the pairs
    got = [(rows.tolist(), key.astype(int).tolist()) for rows, key in ranked_groups(keys, sizes, 2)]
    assert got == [([3], [0, 0, 1]), ([0, 1, 2, 4, 5], [1, 1, 0])]


def test_bad_options_raise_method_errors():
    pos = walking_cloud()
    pos[10:20, 1] = np.nan
    with pytest.raises(MethodError, match="variance"):
        fill_pca(pos, variance=1.5)
    with pytest.raises(MethodError, match="strategy"):
        fill_pca(pos, strategy="both")
    with pytest.raises(MethodError, match="units"):
        fill_pca(pos, units="inch")
    with pytest.raises(MethodError, match="scale"):
        fill_pca(pos, scale=-1.0)


def test_real_clip_through_the_api(sample_data):
    """A 20 %-of-clip gap of one marker on the CMU clip (its centre marker STRN) is filled within a few cm and the
    uncertainty is of the right order."""
    data = mocapfill.read(sample_data / "85_02.c3d")
    pos = data.positions.copy()
    m = data.marker_index(next(label for label in data.labels if label.endswith("STRN")))
    pos[300:460, m] = np.nan
    res = mocapfill.fill(pos, "pca", units=data.units)
    err = np.linalg.norm(res.positions[300:460, m] - data.positions[300:460, m], axis=1)
    rmse = float(np.sqrt(np.mean(err ** 2)))
    assert rmse < 30.0
    per_coord = rmse / np.sqrt(3)
    assert 0.2 * per_coord < np.sqrt(np.mean(res.std[300:460, m] ** 2)) < 5 * per_coord
