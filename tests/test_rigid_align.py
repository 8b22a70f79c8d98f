"""The local frame rides the marker's own segment (``ModelConfig.align_rigid``): the alignment weighs each neighbour
by the inverse variance of its distance to the marker (:func:`~mocapfill.engines.local_pca.rigidity_weights`)."""

from __future__ import annotations

import numpy as np

from mocapfill.engines.local_pca import local_frames, marker_weights, rigidity_weights
from mocapfill.engines.weighted_pca import distance_spreads_to
from mocapfill.methods.auto import fill_auto
from mocapfill.methods.auto_config import ModelConfig
from synthetic import moving_body, rot_x, rot_z


def test_distance_spreads_are_the_spread_of_each_distance_over_the_frames_both_are_seen():
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(50, 6, 3)) * 200
    pos[rng.random((50, 6)) < 0.3] = np.nan
    pos[:, 5] = np.nan  # never seen
    spread = distance_spreads_to(pos)
    for m in range(5):
        dist = np.linalg.norm(pos - pos[:, m:m + 1], axis=2)
        expected = np.array([np.std(d[np.isfinite(d)]) if np.isfinite(d).any() else np.nan for d in dist.T])
        np.testing.assert_allclose(spread(m), expected, rtol=1e-12, atol=1e-9)
        assert np.isnan(spread(m)[5])


def test_rigidity_weights_are_inverse_variances_scaled_by_the_third_most_rigid():
    spread = np.array([0.0, 1.0, 2.0, 2.0, 20.0, np.nan])  # marker 0 is the target
    w = rigidity_weights(spread, 0)
    s0 = 2.0  # the third smallest of the others' spreads
    np.testing.assert_allclose(w[1:5], s0 ** 2 / (spread[1:5] ** 2 + s0 ** 2))
    assert w[5] == 0.0 and w[0] == 0.0  # never seen with it; the target itself is no anchor
    assert (w[1:4] >= 0.5).all()  # at least three markers define the frame
    np.testing.assert_array_equal(rigidity_weights(np.array([0.0, 1.0, 3.0, np.nan]), 0), np.ones(4))  # < 3 known


def test_marker_weights_multiply_the_alignment_by_the_rigidity():
    dist = np.array([0.0, 100.0, 150.0, 300.0])
    spread = np.array([0.0, 5.0, 1.0, 1.0])
    weights, align = marker_weights(dist, 0, (200.0,), 200.0, 0.02)
    weights_r, align_r = marker_weights(dist, 0, (200.0,), 200.0, 0.02, spread)
    np.testing.assert_array_equal(weights[0], weights_r[0])  # the PCA's weights are the distances' alone
    np.testing.assert_allclose(align_r, align * rigidity_weights(spread, 0))


def _forearm_beside_its_upper_arm() -> tuple[np.ndarray, np.ndarray]:
    """Two segments of four markers each, one 120 mm from the other (as close as its own markers are to each other),
    on a hinge that bends further and further (to 70 degrees) while the whole sways and turns: (positions (600, 8,
    3) in mm, the bending segment's markers)."""
    rng = np.random.default_rng(7)
    upper = rng.normal(scale=50.0, size=(4, 3))
    fore = rng.normal(scale=50.0, size=(4, 3)) + [120.0, 0.0, 0.0]
    bend = lambda t: rot_z(1.2 * t / t[-1] + 0.1 * np.sin(2 * np.pi * 1.13 * t))  # noqa: E731
    pos = moving_body(600, body=np.concatenate([upper, fore]), rate=100.0, hinge=(slice(4, 8), bend, [0, 0, 0]),
                      rotation=lambda t: rot_x(0.5 * np.sin(2 * np.pi * 0.2 * t)) @ rot_z(2 * np.pi * 0.1 * t),
                      noise=0.3, seed=1)
    return pos, np.arange(4, 8)


def test_the_local_frame_rides_the_markers_own_segment():
    truth, fore = _forearm_beside_its_upper_arm()
    m = fore[0]
    others = np.flatnonzero(np.arange(truth.shape[1]) != m)
    dist = np.linalg.norm(truth - truth[:, m:m + 1], axis=2).mean(axis=0)
    spread = distance_spreads_to(truth)(m)
    wobble = {}
    for rigid in (False, True):
        _, align = marker_weights(dist, m, (200.0,), 200.0, 0.02, spread if rigid else None)
        centre, rot = local_frames(truth, np.arange(len(truth)), others, align[others], np.arange(len(truth)))
        local = np.einsum("tmc,tcd->tmd", truth[:, fore] - centre[:, None], rot)
        wobble[rigid] = float(local.std(axis=0).max())  # how far the segment moves in the marker's frame (mm)
    assert wobble[True] < 1.0 and wobble[False] > 5 * wobble[True], wobble  # (noise 0.3 mm per coordinate)


def test_the_default_with_a_rigid_alignment_keeps_every_observed_sample_and_fills_every_gap():
    truth, fore = _forearm_beside_its_upper_arm()
    gapped = truth.copy()
    gapped[450:, fore[0]] = np.nan
    gapped[100:160, fore[2]] = np.nan
    result = fill_auto(gapped, rate=100.0, config=ModelConfig(align_rigid=True))
    observed = ~np.isnan(gapped)
    assert np.array_equal(result.positions[observed], gapped[observed])
    assert np.isfinite(result.positions).all()
    assert np.sqrt(np.mean((result.positions[450:, fore[0]] - truth[450:, fore[0]]) ** 2)) < 5.0
