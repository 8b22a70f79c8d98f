"""The body anchor (:mod:`mocapfill.engines.body_anchor`) and the default's stage that uses it."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapfill.engines.body_anchor import body_anchor, error_memory, held
from mocapfill.guards.plausibility import plausibility
from mocapfill.methods.auto import anchor_stage, fill_auto
from synthetic import moving_body, rot_z


def test_a_translating_body_anchors_a_hidden_marker_where_it_is():
    truth = moving_body(200, 5, seed=1)  # translation only: every offset between markers is constant
    gappy = truth.copy()
    gappy[80:120, 0] = np.nan
    est, sd, _ = body_anchor(gappy, rate=100.0)
    assert np.allclose(est[80:120, 0], truth[80:120, 0], atol=1e-6)
    assert np.all(np.isfinite(sd[80:120, 0])) and np.all(sd[80:120, 0] > 0)


def test_the_anchor_sd_learns_the_spread_the_longer_markers_are_seen_together():
    rng = np.random.default_rng(0)
    truth = moving_body(4000, 4, seed=2, spread=30.0)
    truth[:, 0] += rng.normal(scale=10.0, size=(4000, 3))  # marker 0 wobbles 10 mm per coordinate about its place
    short = body_anchor(truth[:200], rate=100.0)[1][:, 0]  # 2 s together: the rotation prior weighs more
    long = body_anchor(truth, rate=100.0)[1][:, 0]  # 40 s
    assert np.all(long >= 9.0) and np.median(long) < np.median(short)
    assert np.median(long) < 12.0


def test_a_blackout_holds_the_last_anchor_and_grows_its_sd():
    truth = moving_body(150, 6, seed=3)
    gappy = truth.copy()
    gappy[120:] = np.nan  # nothing seen in the last 30 frames
    gappy[100:, 0] = np.nan
    est, sd, _ = body_anchor(gappy, rate=100.0)
    assert np.allclose(est[120:, 0], est[119, 0])
    grow = np.diff(sd[119:, 0])
    assert np.all(grow > 0) and np.allclose(grow, grow[0])  # linear: the body's usual pace, direction unknown


def test_held_leaves_anchored_frames_alone():
    est = np.arange(12.0).reshape(4, 1, 3)
    sd = np.ones((4, 1))
    has = np.array([[True], [False], [False], [True]])
    out, out_sd = held(np.where(has[..., None], est, np.nan), np.where(has, sd, np.nan), has, speed=2.0)
    assert np.array_equal(out[[0, 3]], est[[0, 3]])
    assert np.array_equal(out[1], est[0]) and np.array_equal(out[2], est[3])
    assert out_sd[1, 0] == 3.0 and out_sd[2, 0] == 3.0


def test_error_memory_of_an_autoregressive_error():
    rng = np.random.default_rng(4)
    phi = 0.9
    e = np.zeros((20000, 1, 3))
    for t in range(1, len(e)):
        e[t] = phi * e[t - 1] + rng.normal(size=(1, 3))
    memory = error_memory(e, np.ones((len(e), 1), dtype=bool), max_lag=100)
    assert abs(memory - (-1.0 / np.log(phi))) < 1.0  # the lag where phi^lag = 1/e: 9.5 frames


def test_anchor_stage_takes_only_samples_nothing_else_predicts():
    positions = np.zeros((5, 2, 3))
    positions[1:4, 0] = np.nan
    pred = np.full((5, 2, 3), np.nan)
    pred_sd = np.full((5, 2), np.nan)
    pred[1, 0], pred_sd[1, 0] = 7.0, 3.0  # a spatial prediction at frame 1
    anchor, anchor_sd = np.ones((5, 2, 3)), np.full((5, 2), 2.0)
    anchored = np.zeros((5, 2), dtype=bool)
    out, out_sd, rep = anchor_stage(positions, pred, pred_sd, pred_sd.copy(), lambda: (anchor, anchor_sd, 4.0),
                                    anchored=anchored)
    assert anchored[:, 0].tolist() == [False, False, True, True, False] and not anchored[:, 1].any()
    assert np.all(out[1, 0] == 7.0) and np.all(out[2:4, 0] == 1.0)
    assert np.allclose(out_sd[2:4, 0], 4.0) and np.allclose(rep[2:4, 0], 4.0)  # sd x sqrt(memory): a white error


def test_anchor_stage_computes_no_anchor_where_nothing_needs_it():
    positions = np.zeros((3, 1, 3))
    positions[1, 0] = np.nan
    pred, pred_sd = np.ones((3, 1, 3)), np.ones((3, 1))

    def never():
        raise AssertionError("the anchor was computed")

    anchored = np.ones((3, 1), dtype=bool)
    out = anchor_stage(positions, pred, pred_sd, pred_sd, never, anchored=anchored)
    assert out[0] is pred and not anchored.any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_take_that_ends_with_two_markers_seen_is_filled_near_the_body(seed):
    # the last 2 s of a turning body show two of its six markers: without the anchor the motion model alone carried
    # the others 2.7-4.7x the body's observed extent away, posterior sds 20-40 m; with it 1.15-1.32x, under 0.5 m
    truth = moving_body(500, 6, seed=seed, noise=0.3, rotation=lambda t: rot_z(0.8 * np.sin(3 * t)))
    gappy = truth.copy()
    gappy[300:, :4] = np.nan
    gappy[280:, 0] = np.nan
    res = fill_auto(gappy, rate=100.0)
    assert plausibility(res.positions, gappy)["extent"] < 1.5
    assert np.nanmax(res.std) < 1000.0
    assert any("body anchor" in r["reason"] for r in res.info["gap_methods"])


@pytest.mark.parametrize("case", ["one marker", "a marker never seen", "one frame", "nothing seen"])
def test_degenerate_takes_give_no_anchor_and_no_warning(case):
    rng = np.random.default_rng(5)
    positions = {"one marker": rng.normal(size=(50, 1, 3)),
                 "a marker never seen": np.concatenate([rng.normal(size=(50, 1, 3)), np.full((50, 1, 3), np.nan)],
                                                       axis=1),
                 "one frame": rng.normal(size=(1, 4, 3)),
                 "nothing seen": np.full((10, 3, 3), np.nan)}[case]
    positions[:, 0][len(positions) // 2:] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an empty mean's RuntimeWarning would reach the user's terminal
        est, sd, memory = body_anchor(positions, rate=100.0)
    assert memory >= 1.0
    assert np.array_equal(np.isnan(est).any(axis=2), np.isnan(sd))
