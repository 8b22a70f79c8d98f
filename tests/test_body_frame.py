"""The body frame DynaMMo models the data in: vertical axis, frame markers, and the fit itself."""

from __future__ import annotations

import numpy as np

import mocapfill
from mocapfill.engines import body_frame as bf


def short(labels, idx):
    return sorted(labels[k].split(":")[-1] for k in idx)


def test_finds_the_pelvis_and_the_vertical_on_cmu_and_on_a_y_up_capture(sample_data):
    cmu = mocapfill.read(sample_data / "85_02.c3d")
    assert bf.vertical_axis(cmu.positions) == 2
    assert short(cmu.labels, bf.frame_markers(cmu.positions, torso=0)) == ["LBWT", "LFWT", "RBWT", "RFWT"]
    pelvis_and_torso = set(short(cmu.labels, bf.frame_markers(cmu.positions)))
    assert {"LBWT", "LFWT", "RBWT", "RFWT"} < pelvis_and_torso <= {"LBWT", "LFWT", "RBWT", "RFWT", "C7", "T10", "CLAV",
                                                                   "STRN", "RBAC"}
    tennis = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")
    y_up = tennis.positions[:, :, [0, 2, 1]]  # the same capture with Y up
    assert bf.vertical_axis(y_up) == 1
    assert short(tennis.labels, bf.frame_markers(y_up, torso=0)) == ["LASI", "LPSI", "RASI", "RPSI"]
    assert {"STRN", "T10"} <= set(short(tennis.labels, bf.frame_markers(y_up)))


def test_yaw_fit_recovers_a_known_motion_and_ignores_a_dropped_marker():
    rng = np.random.default_rng(0)
    T, K = 50, 4
    shape = rng.normal(scale=100.0, size=(K, 3))
    angle = np.linspace(0, 3.0, T)
    R = bf._rotation_about(2, angle)
    c = np.cumsum(rng.normal(scale=10.0, size=(T, 3)), axis=0)
    X = np.einsum("tij,kj->tki", R, shape) + c[:, None, :]
    w = np.ones((T, K))
    w[20:30, 1] = bf.FLOOR_WEIGHT  # one marker "missing": the frame must not move
    R_fit, c_fit = bf.fit_frames(X, w, axis=2)
    local = np.einsum("tki,tij->tkj", X - c_fit[:, None, :], R_fit)
    assert np.allclose(local, local[0], atol=1e-8)  # the shape stands still in the body frame
    full, _ = bf.fit_frames(X, w, axis=None)
    assert bf.tilt_percentile(full, 2) < 1e-3  # degrees (arccos near 1)


def test_fade_weights_fall_towards_gaps():
    observed = np.ones((12, 2), dtype=bool)
    observed[5:7, 0] = False
    w = bf.fade_weights(observed, fade=2)
    assert np.allclose(w[:, 1], 1.0)
    assert np.allclose(w[2:10, 0], [1.0, 2 / 3, 1 / 3, bf.FLOOR_WEIGHT, bf.FLOOR_WEIGHT, 1 / 3, 2 / 3, 1.0])


def test_fade_weights_are_the_distance_to_the_nearest_gap_on_random_masks():
    rng = np.random.default_rng(0)
    for T in (1, 2, 7, 300):
        for p in (0.0, 0.03, 0.5, 1.0):
            observed = rng.random((T, 5)) >= p
            observed[:, 0] = True
            d = np.full(observed.shape, float(T + 10))  # the definition, by brute force
            for t in range(T):
                for k in range(5):
                    gaps = np.flatnonzero(~observed[:, k])
                    if gaps.size:
                        d[t, k] = np.abs(gaps - t).min()
            expected = np.maximum(np.minimum(1.0, d / (bf.FADE_FRAMES + 1.0)), bf.FLOOR_WEIGHT)
            np.testing.assert_array_equal(bf.fade_weights(observed), expected)


def test_a_long_take_chooses_its_frame_markers_from_evenly_spaced_frames(sample_data, monkeypatch):
    from mocapfill.io import read

    positions = read(sample_data / "85_02.c3d").positions
    chosen = bf.frame_markers(positions)
    monkeypatch.setattr(bf, "STAT_FRAMES", len(positions) // 3)  # every third frame
    np.testing.assert_array_equal(bf.frame_markers(positions), chosen)


def test_a_rigid_hand_far_from_the_centre_does_not_carry_the_frame():
    """A hand can be as rigid as the pelvis (CMU 127_07: 4.2 against 5.4 mm); the frame must still be the pelvis."""
    rng = np.random.default_rng(1)
    T = 300
    t = np.linspace(0.0, 6.0, T)
    pelvis = np.array([[120.0, 80, 0], [-120, 80, 0], [120, -80, 0], [-120, -80, 0]])
    hand = np.array([[0.0, 0, 0], [60, 0, 0], [0, 60, 0], [50, 50, 40]])
    root = np.stack([200 * np.sin(t), 100 * t, 950 + 20 * np.sin(3 * t)], axis=1)  # (T, 3)
    yaw = bf._rotation_about(2, 0.3 * t)
    swing = np.stack([400 + 150 * np.sin(2 * t), 300 * np.cos(2 * t), 200 * np.sin(t)], axis=1)  # the arm moves
    P = np.concatenate([
        np.einsum("tij,kj->tki", yaw, pelvis) + rng.normal(scale=4.0, size=(T, 4, 3)),  # a slightly loose pelvis
        np.einsum("tij,kj->tki", yaw, hand + swing[:, None, :].mean(axis=0)) + swing[:, None, :]
        + rng.normal(scale=1.0, size=(T, 4, 3)),  # a stiff hand, far out
        np.einsum("tij,kj->tki", yaw, rng.normal(scale=300.0, size=(4, 3))) + rng.normal(scale=40.0, size=(T, 4, 3)),
    ], axis=1) + root[:, None, :]
    assert list(bf.frame_markers(P, axis=2, torso=0)) == [0, 1, 2, 3]
