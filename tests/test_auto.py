"""The default's model (``auto``): each stage on its own small case, then the whole fill."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mocapfill.engines.motion_smoother import (JERK_GAIN, MotionModel, acceleration_memory, jerk_density,
                                               jerk_gain, smooth, transition)
from mocapfill.errors import MethodError
from synthetic import tumbling_body
from synthetic import moving_body, rot_x, rot_z
from mocapfill.methods import get_method
from mocapfill.engines.local_pca import rigid_prediction
from mocapfill.engines.local_refit import prefer_segment, refit_parts, segment_markers
from mocapfill.methods.auto import (FORK_FRAMES, body_stage, displaced_runs, fill_auto, global_prediction,
                                   global_stage, model_changes, motion_model, rough_variance, seed_elsewhere,
                                   spatial_stage, take_stage, temporal_stage)
from mocapfill.methods.auto_records import gap_records, restate_record
from mocapfill.methods.auto_config import DEFAULT_CONFIG, ModelConfig


def model(n_series: int, q: float = 1e-3, gain=None) -> MotionModel:
    return MotionModel(q=np.full(n_series, q), rho=np.exp(-1 / 50), phi=np.exp(-1 / 30), r_obs=0.01, gain=gain)


def test_registered():
    assert get_method("auto").load() is fill_auto



def test_frames_dropped_in_turn_are_interpolated_not_strayed_from():
    """Every other frame of the take dropped (a capture upsampled with empty frames): no marker has four observed
    frames in a row, so the jerk density comes from third differences two frames apart, and the observed samples,
    all of them one-frame fragments, are the marker's best data, not noise to distrust."""
    rng = np.random.default_rng(0)
    fine = rng.normal(size=(8 * 20000, 2, 3))  # white jerk on 8 steps per frame: nearly the continuous model
    x = np.cumsum(np.cumsum(np.cumsum(fine, axis=0), axis=0), axis=0)[::8]
    every_other = np.ones((20000, 2), bool)
    every_other[::2] = False
    whole = jerk_density(x, np.zeros((20000, 2), bool), floor=1e-9)
    np.testing.assert_allclose(jerk_density(x, every_other, floor=1e-9), whole, rtol=0.1)
    truth = tumbling_body()
    gapped = truth.copy()
    gapped[1::2] = np.nan
    gapped[-1] = truth[-1]
    res = fill_auto(gapped, rate=100.0)
    missing = np.isnan(gapped).any(axis=2)
    err = np.linalg.norm(res.positions - truth, axis=2)[missing]
    assert np.array_equal(res.positions[~missing], gapped[~missing])
    assert np.median(err) < 0.5 and np.median(err) < 3 * np.median(res.std[missing])


def test_a_capture_where_nothing_moves_fills_without_a_numpy_warning():
    import warnings

    pos = np.repeat(np.array([[[0.0, 0, 1000], [100, 0, 1000], [0, 100, 1000], [0, 0, 1100]]]), 200, axis=0)
    gapped = pos.copy()
    gapped[50:80, 1] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        res = fill_auto(gapped, rate=120.0)
    np.testing.assert_allclose(res.positions, pos, atol=1e-6)

def test_transition_is_the_white_jerk_model():
    F, Q = transition(model(2, q=2.0))
    assert F.shape == (4, 4) and Q.shape == (2, 4, 4)
    assert Q[0, 2, 2] == pytest.approx(2.0) and Q[0, 0, 0] == pytest.approx(2.0 / 20)
    assert Q[0, 3, 3] == pytest.approx(1 - np.exp(-2 / 30))
    assert np.all(np.linalg.eigvalsh(Q[0]) > 0)


def test_jerk_density_recovers_simulated_white_jerk():
    rng = np.random.default_rng(0)
    q = 0.5
    jerk = rng.normal(scale=np.sqrt(q), size=(20000, 2, 3))
    x = np.cumsum(np.cumsum(np.cumsum(jerk, axis=0), axis=0), axis=0)
    est = jerk_density(x, np.zeros((20000, 2), bool), floor=1e-9)
    # discrete white jerk: Var(third difference) = q, so the estimate is q / JERK_GAIN
    assert np.allclose(est * JERK_GAIN, q, rtol=0.05)
    gain = jerk_gain(x, np.zeros((20000, 2), bool), est, window=10, floor=0.05)
    assert gain.shape == (20000,) and abs(np.median(gain) - 1.0) < 0.2


def test_acceleration_memory_is_short_for_noise_and_long_for_smooth_motion():
    rng = np.random.default_rng(1)
    t = np.arange(2000, dtype=float)
    none = np.zeros((2000, 2), bool)
    noise = rng.normal(size=(2000, 2, 3))
    # second differences of white noise: lag-1 autocorrelation -2/3, so the memory is under a frame
    assert acceleration_memory(noise, none, max_lag=50) < 1.0
    # a sinusoid of period 100 frames: autocorrelation cos(2 pi lag / 100) falls to 1/e at ~19.1 frames
    wave = np.stack([np.sin(2 * np.pi * t / 100)] * 3, axis=1)[:, None, :].repeat(2, axis=1)
    missing = none.copy()
    missing[500:560, 0] = True
    wave[500:560, 0] = np.nan
    assert acceleration_memory(wave, missing, max_lag=50) == pytest.approx(100 / (2 * np.pi) * np.arccos(np.exp(-1)),
                                                                          abs=0.3)
    assert acceleration_memory(wave, missing, max_lag=10) == 10.0
    still = np.zeros((50, 2, 3))  # no acceleration at all: nothing to measure
    assert acceleration_memory(still, np.zeros((50, 2), bool), max_lag=7) == 7.0


def test_smoother_keeps_observations_and_bridges_a_gap_smoothly():
    t = np.arange(300, dtype=float)
    truth = np.stack([100 * np.sin(t / 40), 50 * np.cos(t / 25), 0.5 * t], axis=1)[:, None, :]
    obs = truth.copy()
    obs[120:160] = np.nan
    none = np.full((300, 1, 3), np.nan)
    nosd = np.full((300, 1), np.nan)
    q = jerk_density(truth, np.zeros((300, 1), bool), floor=1e-9)
    mean, sd = smooth(obs, none, nosd, nosd, model(1, q=float(q[0])))
    assert np.abs(mean[:100] - truth[:100]).max() < 0.5  # observations kept (r_obs small)
    assert np.abs(mean[120:160] - truth[120:160]).max() < 15.0
    assert sd[140, 0] > sd[121, 0] > sd[100, 0]  # uncertainty grows into the gap
    acc = np.linalg.norm(np.diff(mean[:, 0], 2, axis=0), axis=1)
    assert acc[115:165].max() < 2 * np.linalg.norm(np.diff(truth[:, 0], 2, axis=0), axis=1).max()


def test_smoother_uses_spatial_predictions_by_their_variance():
    t = np.arange(200, dtype=float)
    truth = np.stack([80 * np.sin(t / 15), 0 * t, 0 * t], axis=1)[:, None, :]
    obs = truth.copy()
    obs[60:140] = np.nan
    rng = np.random.default_rng(1)
    sp = np.where(np.isnan(obs), truth + rng.normal(scale=2.0, size=truth.shape), np.nan)
    sd = np.where(np.isnan(obs[..., 0]), 2.0, np.nan)
    q = jerk_density(truth, np.zeros((200, 1), bool), floor=1e-9)
    mean, post = smooth(obs, sp, sd, 0.5 * sd, model(1, q=float(q[0])))
    err = np.sqrt(np.mean((mean[60:140] - truth[60:140]) ** 2))
    assert err < 2.0  # better than the predictions themselves (2 per coordinate)
    assert np.all(post[60:140, 0] < 2.5)


def test_temporal_stage_down_weights_a_jumping_prediction():
    pos = tumbling_body()
    gapped = pos.copy()
    gapped[100:160, 0] = np.nan
    missing = np.isnan(gapped).any(axis=2)
    pred = np.where(missing[..., None], pos, np.nan)
    pred[130, 0] += 500.0  # one prediction half a metre off
    sd = np.where(missing, 3.0, np.nan)
    none = np.full_like(pos, np.nan)
    config = ModelConfig(reweight_passes=2)
    mdl = motion_model(gapped, missing, config, 1.0, 100.0)
    fill, post, outliers = temporal_stage(gapped, pred, sd, none, np.full_like(sd, np.nan), mdl, config, 1.0, 100.0)
    assert outliers[130, 0]
    assert np.linalg.norm(fill[130, 0] - pos[130, 0]) < 30.0
    assert np.array_equal(fill[~missing], gapped[~missing])


def test_temporal_stage_runs_its_mean_and_variance_passes_at_once_with_the_same_numbers():
    """With a reported sd, the last mean pass and the variance pass run on two processes: the fill, its sd and the
    outliers are those of one process; the variance pass widens the sd where the reported sd is the larger, also
    where the reweighting passes stop early (no prediction off the smoothed path)."""
    pos = tumbling_body(FORK_FRAMES)  # (shorter takes run the passes in turn)
    gapped = pos.copy()
    gapped[100:160, 0] = np.nan
    gapped[30:50, 2] = np.nan
    missing = np.isnan(gapped).any(axis=2)
    pred = np.where(missing[..., None], pos + 2.0, np.nan)
    sd = np.where(missing, 3.0, np.nan)
    report = np.where(missing, 3.0, np.nan)
    report[100:160, 0] = 9.0  # the reported sd above the one the mean pass used: marker 0 only
    none = np.full_like(pos, np.nan)
    for config in (ModelConfig(), ModelConfig(reweight_passes=2)):
        mdl = motion_model(gapped, missing, config, 1.0, 100.0)
        runs = [temporal_stage(gapped, pred, sd, none, np.full_like(sd, np.nan), mdl, config, 1.0, 100.0,
                               report_sd=rep, jobs=jobs) for rep, jobs in ((report, 1), (report, 2), (None, 1))]
        for a, b in zip(runs[0], runs[1]):
            assert np.array_equal(a, b, equal_nan=True)
        np.testing.assert_array_equal(runs[0][0], runs[2][0])  # the mean does not read the reported sd
        assert np.all(runs[0][1][100:160, 0] > runs[2][1][100:160, 0])
        np.testing.assert_array_equal(runs[0][1][:, 2], runs[2][1][:, 2])


def test_take_stage_learns_the_global_pca_and_the_bones_at_once_with_the_same_numbers():
    """The global PCA's prediction and the bones' set-up read the take alone: on two processes, what one gives."""
    pos = tumbling_body(FORK_FRAMES)  # (shorter takes run the two in turn)
    gapped = pos.copy()
    gapped[100:160, 0] = np.nan
    gapped[20:40, 3] = np.nan
    labels = [f"m{i}" for i in range(pos.shape[1])]
    one, two = (take_stage(gapped, None, DEFAULT_CONFIG, 1.0, ["global", "bones"], units="mm", labels=labels,
                           jobs=jobs) for jobs in (1, 2))
    assert list(one) == list(two) == ["global", "bones"]
    for a, b in zip(one["global"], two["global"]):
        assert np.array_equal(a, b, equal_nan=True)
    (bones_1, rates_1, reach_1), (bones_2, rates_2, reach_2) = one["bones"], two["bones"]
    assert len(bones_1) > 0 and np.array_equal(bones_1.pairs, bones_2.pairs)
    assert np.array_equal(bones_1.lengths, bones_2.lengths) and np.array_equal(rates_1, rates_2, equal_nan=True)
    assert np.array_equal(reach_1.pairs, reach_2.pairs)


def test_model_changes_where_the_kind_of_measurement_changes():
    kinds = np.array([[1, 0], [1, 2], [0, 2], [2, 0], [2, 1], [1, 1]])  # 0: no spatial measurement
    assert model_changes(kinds).tolist() == [[False, False], [False, False], [False, False], [True, False],
                                             [False, True], [True, False]]


def test_a_local_models_error_is_not_read_as_the_global_pcas():
    """A gap whose first half the local PCA predicts 10 mm off (its reconstruction beside the gap shows the same
    offset) and whose second half the global PCA predicts without error (sd 300): the local model's bias, scaled by
    the global prediction's 60-fold loading, must not push the second half off."""
    pos = tumbling_body()
    gapped = pos.copy()
    gapped[100:180, 0] = np.nan
    missing = np.isnan(gapped).any(axis=2)
    pred = np.where(missing[..., None], pos, np.nan)
    pred[100:140, 0] += 10.0
    sd = np.where(missing, 5.0, np.nan)
    globbed = np.zeros_like(missing)
    globbed[140:180, 0] = True
    sd[globbed] = 300.0
    edge = np.full_like(pos, np.nan)
    edge[95:100, 0] = pos[95:100, 0] + 10.0
    edge[180:185, 0] = pos[180:185, 0]
    edge_sd = np.where(np.isfinite(edge[..., 0]), 5.0, np.nan)
    errors = {}
    for apart in (True, False):
        config = ModelConfig(bias_per_model=apart)
        mdl = motion_model(gapped, missing, config, 1.0, 100.0)
        fill, _, _ = temporal_stage(gapped, pred, sd, edge, edge_sd, mdl, config, 1.0, 100.0, globbed=globbed)
        errors[apart] = np.linalg.norm(fill[100:180, 0] - pos[100:180, 0], axis=1).max()
        assert np.array_equal(fill[~missing], gapped[~missing])
    assert errors[True] < 0.7 * errors[False]  # (4.6 against 8.6 mm)


def test_spatial_stage_predicts_a_rigid_marker():
    pos = tumbling_body()
    gapped = pos.copy()
    gapped[100:160, 0] = np.nan
    pred, sd, edge, edge_sd, _ = spatial_stage(gapped, DEFAULT_CONFIG, 1.0)
    assert np.abs(pred[100:160, 0] - pos[100:160, 0]).max() < 5.0
    assert np.isfinite(sd[100:160, 0]).all() and np.isnan(sd[:100]).all()
    assert np.isfinite(edge[97:100, 0]).all() and np.isnan(edge[:90, 0]).all()


def test_rigid_prediction_carries_a_marker_on_its_nearest_seen_markers():
    pos = tumbling_body()
    gapped = pos.copy()
    gapped[100:160, :2] = np.nan  # marker 0 and one neighbour vanish together
    todo = np.isnan(gapped).any(axis=2)
    est, sd, edge, edge_sd = rigid_prediction(gapped, todo, nearest=3, align_scale=200.0, edge_frames=2)
    assert np.isfinite(edge_sd[[98, 99, 160, 161], 0]).all() and np.isnan(edge_sd[[97, 162], 0]).all()
    assert np.abs(edge[98, 0] - pos[98, 0]).max() < 1.0
    assert np.abs(est[100:160, 0] - pos[100:160, 0]).max() < 1.0  # a rigid body: exact up to round-off
    assert np.isfinite(sd[100:160, :2]).all() and np.isnan(sd[:100]).all() and sd[120, 0] < 1.0


def test_body_stage_fills_only_samples_without_a_spatial_prediction():
    pos = tumbling_body()
    gapped = pos.copy()
    gapped[100:160, 0] = np.nan
    pred = np.full_like(pos, np.nan)
    sd = np.full(pos.shape[:2], np.nan)
    pred[100:130, 0], sd[100:130, 0] = 7.0, 3.0  # the local PCA's (kept) and none for frames 130-159
    none = np.full_like(pos, np.nan)
    out, out_sd, edge, edge_sd = body_stage(gapped, pred, sd, none, sd * np.nan, ModelConfig(rigid_nearest=3), 1.0)
    assert np.all(out[100:130, 0] == 7.0) and np.all(out_sd[100:130, 0] == 3.0)
    assert np.abs(out[130:160, 0] - pos[130:160, 0]).max() < 1.0 and np.isfinite(out_sd[130:160, 0]).all()
    assert np.isnan(out_sd[:100]).all()
    assert np.isfinite(edge_sd[160, 0]) and np.isnan(edge_sd[:97]).all()
    off = body_stage(gapped, pred, sd, none, sd * np.nan, ModelConfig(rigid_nearest=0), 1.0)[0]
    assert np.isnan(off[130:160, 0]).all()


def test_global_stage_predicts_a_marker_seen_in_a_few_frames_only():
    pos = moving_body(300, 9, seed=3, rotation=lambda t: rot_z(0.8 * np.sin(2 * np.pi * 0.3 * t)))  # walks, sways
    gapped = pos.copy()
    gapped[3:297, 0] = np.nan  # seen in 6 frames: no local model can train on it
    pred, sd, *_ = spatial_stage(gapped, DEFAULT_CONFIG, 1.0)
    assert np.isnan(sd[3:297, 0]).all()
    glob, has = global_prediction(gapped, "mm")
    config = ModelConfig(global_sd_mm=300.0)
    out, out_sd = global_stage(gapped, pred, sd, glob, has, config, 1.0)
    # a prediction that jumps off the observed ends (pca, in the laboratory frame, cannot follow the tumble) is no
    # prediction there; inside the gap it is
    assert np.all(out_sd[4:296, 0] == 300.0) and np.isnan(out_sd[:3]).all()
    assert np.array_equal(out[4:296, 0], glob[4:296, 0])
    kept = np.isfinite(sd)
    assert np.array_equal(out_sd[kept], sd[kept])  # the local predictions stand where they exist
    done = np.zeros(sd.shape, dtype=bool)
    global_stage(gapped, pred, sd, glob, has, config, 1.0, globbed=done)
    assert np.array_equal(done, np.isfinite(out_sd) & ~kept & np.isnan(gapped).any(axis=2))
    # the gap's record says which model predicted it: the global PCA, not a local model
    rec = fill_auto(gapped, rate=100.0, config=config).info["gap_methods"]
    first = [r for r in rec if r["marker_index"] == 0]
    assert [r["method"] for r in first] == ["global-pca+motion"]
    assert "no local model could predict it: the global weighted PCA" in first[0]["reason"]
    assert f"an sd of {config.global_sd_mm:g} mm" in first[0]["reason"]


def test_gap_records_flag_uncertain_gaps_with_the_config_number():
    missing = np.zeros((50, 2), bool)
    missing[10:20, 0] = missing[30:35, 1] = True
    sd = np.where(missing, 1.0, 0.0)
    sd[15, 0] = 80.0
    spatial = missing.copy()
    config = ModelConfig(review_sd_mm=40.0)
    recs = gap_records(missing, sd, spatial, np.zeros_like(missing), config, 1.0, ["a", "b"], None)
    assert [r["review"] for r in recs] == [True, False]
    assert "40 mm" in recs[0]["reason"] and recs[0]["marker"] == "a"
    off = np.where(missing, 1.0, np.nan)
    off[15, 0] = 16.0  # the neighbours' pose off the training poses there: named in the flagged gap's reason
    recs = gap_records(missing, sd, spatial, np.zeros_like(missing), config, 1.0, ["a", "b"], None, off)
    assert recs[0]["extrapolation"] == 16.0 and "4.0x" in recs[0]["reason"]
    assert recs[1]["extrapolation"] == 1.0 and "never learnt" not in recs[1]["reason"]
    moved = np.zeros(missing.shape)
    moved[12, 0], moved[31, 1] = 90.0, 90.0  # the bones pulled a prediction 90 mm (52 mm per coordinate > 40)
    recs = gap_records(missing, sd, spatial, np.zeros_like(missing), config, 1.0, ["a", "b"], None, off, moved=moved)
    assert "moved its predictions by up to 90.0 mm" in recs[0]["reason"]
    assert "moved" not in recs[1]["reason"]  # named only in a gap flagged for review


def test_gap_records_claim_bones_only_for_markers_on_a_bone_and_never_round_a_part_to_nothing():
    missing = np.zeros((400, 3), bool)
    missing[10:20, 0] = missing[30:35, 1] = True
    sd = np.where(missing, 1.0, 0.0)
    spatial = missing.copy()
    globbed = np.zeros_like(missing)
    spatial[31:35, 1], globbed[31:35, 1] = False, True  # the global PCA predicts 4 of its 5 frames
    boneset = type("Bones", (), {"pairs": np.array([[0, 2]]), "__len__": lambda self: 1})()
    recs = gap_records(missing, sd, spatial, np.zeros_like(missing), DEFAULT_CONFIG, 1.0, ["a", "b", "c"], boneset,
                       globbed=globbed)
    assert "refined with the bone lengths" in recs[0]["reason"]
    assert "bone" not in recs[1]["reason"]  # marker b is on no bone: the bone stage never moved it
    assert "predicted 20% of the frames" in recs[1]["reason"]
    missing[40:397, 2] = True  # one frame of 357 predicted locally: not "0%"
    sd = np.where(missing, 1.0, 0.0)
    spatial, globbed = np.zeros_like(missing), np.zeros_like(missing)
    spatial[40, 2], globbed[41:397, 2] = True, True
    rec = gap_records(missing, sd, spatial, np.zeros_like(missing), DEFAULT_CONFIG, 1.0, ["a", "b", "c"], None,
                      globbed=globbed)[-1]
    assert "local weighted PCA predicted <1% of the frames" in rec["reason"]
    assert "global weighted PCA" in rec["reason"] and "predicted >99% of the frames" in rec["reason"]



def test_a_record_restated_for_its_blended_sd():
    missing = np.zeros((50, 1), bool)
    missing[10:20, 0] = True
    config = ModelConfig(review_sd_mm=40.0)
    (rec,) = gap_records(missing, np.where(missing, 50.0, 0.0), missing.copy(), np.zeros_like(missing), config, 1.0,
                         ["a"], None)
    assert rec["review"] and "largest posterior sd 50.0 mm > 40 mm: review this gap" in rec["reason"]
    calm = restate_record(rec, np.full(10, 30.0), config=config, mm=1.0)
    assert calm["max_std"] == 30.0 and not calm["review"]
    assert "largest posterior sd 30.0 mm" in calm["reason"] and "review this gap" not in calm["reason"]
    assert restate_record(rec, np.full(10, 50.0), config=config, mm=1.0) is rec
    assert restate_record(calm, np.full(10, 45.0), config=config, mm=1.0)["review"]
    part = restate_record(calm, np.r_[np.full(4, 30.0), np.full(6, np.nan)], config=config, mm=1.0)
    assert part["review"] and "6 of its 10 frames left missing" in part["reason"]

def test_fill_keeps_observed_samples_and_gives_std():
    pos = tumbling_body()
    gapped = pos.copy()
    gapped[100:160, 0] = np.nan
    gapped[50:70, 3] = np.nan
    res = fill_auto(gapped, rate=100.0)
    missing = np.isnan(gapped).any(axis=2)
    assert np.array_equal(res.positions[~missing], gapped[~missing])
    assert np.isfinite(res.positions).all() and np.isfinite(res.std[missing]).all()
    assert np.sqrt(np.mean((res.positions[missing] - pos[missing]) ** 2)) < 10.0
    assert len(res.info["gap_methods"]) == 2


def test_reference_frames_hook():
    pos = tumbling_body()
    gapped = pos.copy()
    gapped[:, 0] = np.nan
    gapped[100:160, 0] = np.nan
    gapped[:60, 0] = pos[:60, 0]  # the marker seen only in 60 frames of the take
    ref = tumbling_body(seed=2)[150:]
    res = fill_auto(gapped, rate=100.0, reference_frames=ref)
    missing = np.isnan(gapped).any(axis=2)
    assert np.isfinite(res.positions[missing]).all()
    with pytest.raises(MethodError):
        fill_auto(gapped, reference_frames=ref[:, :3])



def test_a_marker_the_take_never_shows_is_filled_from_a_reference_take(sample_data):
    """A marker missing in every frame of the take but present in a reference take (the static trial, the session's
    other takes) is modelled from the references alone, smoothed, and its record says so; without the reference it
    stays empty."""
    import mocapfill

    data = mocapfill.read(sample_data / "85_02.c3d")
    j = data.labels.index("Male:LFRM")
    take = data.positions[:400].copy()
    take[:, j] = np.nan
    alone = fill_auto(take, rate=120.0, labels=data.labels)
    assert np.isnan(alone.positions[:, j]).all()
    assert [g["method"] for g in alone.info["gap_methods"] if g["marker_index"] == j] == ["none"]
    res = fill_auto(take, rate=120.0, labels=data.labels, reference_frames=data.positions[400:])
    err = np.linalg.norm(res.positions[:, j] - data.positions[:400, j], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 15.0 and np.isfinite(res.std[:, j]).all()
    observed = ~np.isnan(take).any(axis=2)
    assert np.array_equal(res.positions[observed], take[observed])
    (rec,) = [g for g in res.info["gap_methods"] if g["marker_index"] == j]
    assert rec["method"] == "local-pca+motion" and "never show this marker" in rec["reason"]
    assert rec["review"]  # a model the take cannot check: its offset is not in the sd

def test_fragments_are_short_observed_runs_between_gaps():
    from mocapfill.gaps import fragments

    missing = np.array([[0, 1, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 0]], bool).T
    frag = fragments(missing, 2)[:, 0]
    assert list(np.flatnonzero(frag)) == [2, 5, 6]  # not the run at the start, nor the 3-frame run


def test_displaced_runs_weigh_a_run_between_gaps_against_the_spatial_sd():
    """A run between two gaps 300 mm off the spatial model (sd 5 mm) is judged displaced, the same run where it
    belongs is not, nor is a run at the take's start (not between two gaps), and the bound grows with the sd: 60 mm
    off is displaced at sd 5 mm and not at sd 20 mm."""
    rng = np.random.default_rng(0)
    truth = np.cumsum(rng.normal(size=(60, 2, 3)), axis=0)
    pos = truth.copy()
    pos[10:20, 0] = np.nan
    pos[25:40, 0] = np.nan  # frames 20-24: a run between two gaps
    pos[5:8, 1] = np.nan  # marker 1: frames 0-4 a run at the take's start
    edge = truth + rng.normal(scale=5.0, size=truth.shape)
    edge_sd = np.full((60, 2), 5.0)

    def judged(offset, sd=5.0, at=(slice(20, 25), 0)):
        shifted = pos.copy()
        shifted[at] += offset
        return displaced_runs(shifted, edge, np.full((60, 2), sd), DEFAULT_CONFIG, 1.0)

    assert not displaced_runs(pos, edge, edge_sd, DEFAULT_CONFIG, 1.0).any()
    assert list(np.flatnonzero(judged([300.0, 0, 0])[:, 0])) == [20, 21, 22, 23, 24]
    assert not judged([300.0, 0, 0], at=(slice(0, 5), 1)).any()
    assert judged([60.0, 0, 0]).any() and not judged([60.0, 0, 0], sd=20.0).any()
    off = ModelConfig(displaced_prior=0.0)
    assert not displaced_runs(pos + np.where(np.arange(60)[:, None, None] == 22, 300.0, 0.0), edge, edge_sd, off,
                              1.0).any()


def test_the_fill_does_not_bend_to_a_displaced_run_and_says_so():
    """A 5-frame run between two gaps displaced by 40 cm (a swap outlier rejection cannot see: no step beside it):
    the fill of the gaps around it stays with the body instead of reaching for it, the run comes back as observed,
    and the gaps beside it are flagged for review with the run's frames."""
    truth = moving_body(400, 9, seed=4, spread=150.0, rate=100.0, rotation=lambda t: rot_z(1.5 * t))
    gapped = truth.copy()
    gapped[150:170, 0] = np.nan
    gapped[175:200, 0] = np.nan
    gapped[170:175, 0] += [400.0, -150.0, 100.0]
    res = fill_auto(gapped, rate=100.0, labels=[f"m{i}" for i in range(9)])
    assert np.array_equal(res.positions[170:175, 0], gapped[170:175, 0])
    hidden = np.isnan(gapped).any(axis=2)
    err = np.linalg.norm(res.positions[hidden] - truth[hidden], axis=1)
    assert err.max() < 5.0
    assert [(r["marker"], r["start"], r["length"]) for r in res.info["displaced"]] == [("m0", 170, 5)]
    beside = [r for r in res.info["gap_methods"] if r["marker"] == "m0"]
    assert all(r["review"] and "run of 5 frame(s) just" in r["reason"] for r in beside)
    plain = fill_auto(gapped, rate=100.0, config=ModelConfig(displaced_prior=0.0))
    assert np.linalg.norm(plain.positions[hidden] - truth[hidden], axis=1).max() > 100.0
    from mocapfill.markers import MarkerData
    from mocapfill.pipeline import FillSettings, fill_capture
    from mocapfill.status import Status

    outcome = fill_capture(MarkerData(gapped, [f"m{i}" for i in range(9)], 100.0, "mm"),
                           FillSettings(method="auto").check())
    assert (outcome.status[170:175, 0] == Status.SUSPECT).all()
    assert (outcome.status[~hidden & (np.arange(400)[:, None] < 170)] == Status.OBSERVED).all()


@pytest.mark.accuracy
def test_markers_seen_in_a_few_frames_move_with_the_body(shared_data):
    """CMU 16_08 (239 frames, dense 20 %): markers hidden in all but 6 frames were bridged by the motion alone up to
    1.8 m off (RMSE 348 mm against pca's 66); the global PCA's prediction (stage 1c) keeps them with the body."""
    import mocapfill
    from mocapfill.evaluation import make_occlusions

    data = mocapfill.read(shared_data / "cmu-train" / "16_08.c3d")
    corrupted, hidden, _ = make_occlusions(data, "dense", trials=1, seed=1, missing=0.2)[0].apply(data.positions)
    gappy = data.with_positions(corrupted)

    def rmse(method):
        err = np.linalg.norm(mocapfill.fill(gappy, method).positions[hidden] - data.positions[hidden], axis=1)
        return np.sqrt(np.mean(err[np.isfinite(err)] ** 2))

    assert rmse("auto") < rmse("pca")


def test_max_predictors_bounds_each_models_predictors_and_changes_nothing_at_or_above_the_set():
    """The cost bound keeps the nearest predictors per width; with the bound at the number of other markers the
    reconstruction is the one without a bound, to the bit."""
    import mocapfill.engines.local_pca as lp

    pos = moving_body(n_frames=300, n_markers=12, seed=3)
    gapped = pos.copy()
    gapped[100:160, 0] = np.nan
    widths = []
    original = lp.cv_curve

    def spy(flat, train, targets, predictors, *args, **kwargs):
        widths.append(len(predictors))
        return original(flat, train, targets, predictors, *args, **kwargs)

    lp.cv_curve = spy
    try:
        full, full_sd, _ = lp.reconstruct_local(gapped, scales=(3000.0,), align_scale=200.0, knn=0, edge=None)
        assert max(widths) == 11
        same, same_sd, _ = lp.reconstruct_local(gapped, scales=(3000.0,), align_scale=200.0, knn=0, edge=None,
                                                max_predictors=11)
        widths.clear()
        capped, _, _ = lp.reconstruct_local(gapped, scales=(3000.0,), align_scale=200.0, knn=0, edge=None,
                                            max_predictors=4)
    finally:
        lp.cv_curve = original
    assert max(widths) == 4 and np.isfinite(capped[100:160, 0]).all()
    assert np.array_equal(full, same, equal_nan=True) and np.array_equal(full_sd, same_sd, equal_nan=True)
    assert DEFAULT_CONFIG.max_predictors >= 40  # every accuracy benchmark's marker set (<= 41 markers) unchanged


def bent_knee(n_frames: int = 240, gap: slice = slice(90, 150)) -> np.ndarray:
    """A thigh and a shank (markers 0-3) joined at a knee that bends a little outside ``gap`` and far (1.3 rad)
    inside it: while marker 0 is missing its neighbours take poses it was never seen in.  (n_frames, 8, 3) mm."""
    def bend(t):
        k = np.clip((t * 100.0 - gap.start) / (gap.stop - gap.start), 0.0, 1.0)
        return rot_x(0.15 * np.sin(2 * np.pi * 1.1 * t) + 1.3 * np.sin(np.pi * k))

    body = [[40, 10, -150], [-30, 40, -250], [20, -50, -350], [0, 0, -100],
            [0, 0, 400], [60, 0, 300], [-50, 20, 250], [10, -60, 350]]
    return moving_body(n_frames, 8, body=body, hinge=([0, 1, 2, 3], bend, [0, 0, 0]), noise=0.3, seed=4)


def test_the_reported_sd_grows_where_the_neighbours_take_unseen_poses_and_the_fill_stays():
    pos = bent_knee()
    gapped = pos.copy()
    gapped[90:150, 0] = np.nan
    *_, info = spatial_stage(gapped, ModelConfig(impute_passes=0), 1.0)
    off = info["extrapolation"][:, 0]
    assert np.isnan(off[:90]).all() and (off[90:150] >= 1.0).all()
    assert off[115:125].min() > 50.0 and off[[90, 149]].max() < 10.0  # the knee bent most mid-gap
    plain = fill_auto(gapped, config=ModelConfig(extrapolation_sd=False, bone_move_sd=False))
    told = fill_auto(gapped, config=ModelConfig(bone_move_sd=False))
    assert np.array_equal(told.positions, plain.positions)  # the mean keeps the cross-validated sd
    err = np.sqrt(np.mean((told.positions[90:150, 0] - pos[90:150, 0]) ** 2, axis=1))  # per coordinate
    assert err.max() > 10.0 * plain.std[90:150, 0].max()  # the sd it reported before: far too sure
    assert told.std[115:125, 0].min() > 10.0 * plain.std[115:125, 0].max()
    assert err.max() < 3.0 * told.std[90:150, 0].max()


def test_the_reported_sd_grows_by_what_the_bones_moved_and_the_fill_stays():
    """Marker 1 vanishes too while the knee bends far: its prediction is off by tens of mm and the bones pull it;
    the reported sd takes in how far (ModelConfig.bone_move_sd), the fill does not change."""
    pos = bent_knee()
    gapped = pos.copy()
    gapped[90:150, 0] = np.nan
    gapped[100:130, 1] = np.nan
    plain = fill_auto(gapped, config=ModelConfig(bone_move_sd=False))
    told = fill_auto(gapped)
    assert np.array_equal(told.positions, plain.positions)

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x ** 2)))

    err = rms(told.positions[100:130, 1] - pos[100:130, 1])  # per coordinate
    assert err > 3.0 * rms(plain.std[100:130, 1])  # far too sure without it
    assert rms(told.std[100:130, 1]) > 1.5 * rms(plain.std[100:130, 1])


def test_a_bone_measured_while_its_ends_stood_still_lets_go_once_one_moves():
    """bone_spreads: two markers still in every frame that measured them (a hand resting by a robot link) look rigid;
    where the estimates put one 250 mm away the bone's spread grows by that many of its spreads.  A bone seen turning
    while it kept its length keeps its spread in a new pose, and so does a bone whose estimate is uncertain enough
    to explain the difference."""
    from mocapfill.bones.boneset import BoneSet
    from mocapfill.methods.auto import bone_spreads

    n = 200
    rng = np.random.default_rng(4)
    t = np.arange(n) / 100.0
    pos = np.zeros((n, 4, 3))
    pos[:, 0] = [0.0, 0.0, 1000.0] + rng.normal(scale=0.3, size=(n, 3))  # still
    pos[:, 1] = [400.0, 0.0, 1000.0] + rng.normal(scale=0.3, size=(n, 3))  # still, then moves (hidden)
    angle = 0.8 * np.sin(2 * np.pi * 0.5 * t)  # a segment turning about marker 2
    pos[:, 2] = [0.0, 500.0, 1000.0]
    pos[:, 3] = pos[:, 2] + 300.0 * np.stack([np.cos(angle), np.sin(angle), 0 * angle], axis=1)
    est = pos.copy()
    est[150:, 1] += [0.0, 250.0, 0.0]  # where marker 1 is missing, the estimate has it 250 mm away
    est[150:, 3] = pos[150:, 2] + 300.0 * np.array([np.cos(1.5), np.sin(1.5), 0.0])  # a pose never measured
    positions = pos.copy()
    positions[150:, 1] = np.nan
    positions[150:, 3] = np.nan
    bones = BoneSet(np.array([[0, 1], [2, 3]]), np.array([400.0, 300.0]), np.array([0.5, 0.5]),
                    np.array([150, 150]), "mm")
    sd = np.where(np.isnan(positions).any(axis=2), 1.0, 0.0)
    out = bone_spreads(positions, est, sd, bones, DEFAULT_CONFIG, 1.0)
    assert np.array_equal(out[:150], np.tile(bones.spread, (150, 1)))  # measured frames: unchanged
    assert out[150:, 0].min() > 50 * bones.spread[0]  # the still pair lets go
    assert np.allclose(out[150:, 1], bones.spread[1], rtol=0.5)  # the turning segment holds
    unsure = bone_spreads(positions, est, np.where(sd > 0, 1000.0, 0.0), bones, DEFAULT_CONFIG, 1.0)
    assert unsure[150:, 0].max() < 1.5 * bones.spread[0]  # an estimate 1 m unsure is not held against the bone


def test_segment_markers_are_near_and_observed_throughout_the_gap():
    near = np.array([3, 1, 4, 2])
    dist = np.array([0.0, 50.0, 300.0, 30.0, 100.0])
    gap_missing = np.zeros((5, 5), dtype=bool)
    gap_missing[2, 4] = True  # marker 4 vanishes in one gap frame
    assert segment_markers(near, dist, gap_missing, 120.0).tolist() == [3, 1]
    assert segment_markers(near, dist, np.zeros((5, 5), bool), 120.0).tolist() == [3, 1, 4]


def test_prefer_segment_needs_less_extrapolation_and_a_smaller_predicted_variance():
    ones = np.ones(4)
    assert prefer_segment(1.0, ones, 1.0, 4 * ones)  # same CV error, the neighbourhood model extrapolates
    assert not prefer_segment(1.0, 2 * ones, 1.0, 2 * ones)  # no less extrapolation
    assert not prefer_segment(3.0, ones, 1.0, 2 * ones)  # extrapolates less, but 9 x 1 > 1 x 2
    assert not prefer_segment(np.nan, ones, 1.0, 4 * ones)
    assert not prefer_segment(1.0, ones, 0.0, 4 * ones)


def test_segment_model_carries_an_ankle_through_a_short_walk():
    """A lateral ankle marker of the committed 2.3 s Qualisys walk hidden for 80 % of it: the refit's neighbourhood
    model (every near marker, trained on the stance frames the ankle was seen in) extrapolates 28 mm RMS into the
    swing; the segment model on its four foot markers follows it within a few mm, and its gap record says so."""
    from pathlib import Path
    from mocapfill import read

    data = read(Path(__file__).parent / "data" / "qtm_JaneDoe_Dynamic_2.tsv")
    m = data.labels.index("R_FAL")
    hidden = data.positions.copy()
    hidden[12:197, m] = np.nan
    res = fill_auto(hidden, units=data.units, labels=data.labels, rate=data.rate)
    err = np.linalg.norm(res.positions[12:197, m] - data.positions[12:197, m], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 5.0
    record = next(r for r in res.info["gap_methods"] if r["marker_index"] == m and r["start"] == 12)
    assert "segment model" in record["reason"]
    off = fill_auto(hidden, units=data.units, labels=data.labels, rate=data.rate,
                    config=ModelConfig(segment_mm=0.0))
    err_off = np.linalg.norm(off.positions[12:197, m] - data.positions[12:197, m], axis=1)
    assert np.sqrt(np.mean(err_off ** 2)) > 4 * np.sqrt(np.mean(err ** 2))


def test_refit_parts_split_the_gap_by_the_left_out_neighbours_seen():
    """The whole-gap model keeps the trusted candidates; a left-out one observed in part of the gap frames gives
    those frames a model of their own with it as a predictor."""
    missing = np.zeros((10, 6), dtype=bool)
    gap = np.arange(2, 8)
    missing[gap, 0] = True
    missing[5:8, 4] = True  # candidate 4 is seen in frames 2-4 of the gap only
    candidates = np.array([4, 1, 2, 3, 5])  # nearest first
    sure = np.array([False, True, True, True, False])  # 4 and 5 left out of the whole-gap model
    parts = refit_parts(missing, gap, candidates, sure, 3)
    got = sorted((f.tolist(), p.tolist()) for f, p in parts)
    assert got == [([2, 3, 4], [4, 1, 2, 3, 5]), ([5, 6, 7], [1, 2, 3, 5])]
    assert [(f.tolist(), p.tolist()) for f, p in refit_parts(missing, gap, candidates, sure, 1)] == \
        [(gap.tolist(), [1, 2, 3])]
    assert [(f.tolist(), p.tolist()) for f, p in refit_parts(missing, gap, candidates, np.ones(5, bool), 3)] == \
        [(gap.tolist(), candidates.tolist())]


@pytest.mark.accuracy
def test_refit_parts_carry_a_knee_on_a_thigh_seen_for_part_of_its_gap():
    """85_02 with the left shank and foot hidden for 1.25 s and the thigh marker for the second half of that and
    beyond: one model for the knee's whole gap leaves the thigh out (it is filled uncertainly for half the gap) and
    predicts the knee from the far markers; the part where the thigh is seen has it as a predictor."""
    from pathlib import Path
    from mocapfill import read

    data = read(Path(__file__).parents[1] / "sample_data" / "85_02.c3d")
    bare = [x.split(":")[-1] for x in data.labels]
    hidden = data.positions.copy()
    for name in ("LKNE", "LSHN", "LANK", "LHEE", "LMT5", "LTOE"):
        hidden[100:250, bare.index(name)] = np.nan
    hidden[180:310, bare.index("LTHI")] = np.nan
    k = bare.index("LKNE")

    def knee_rmse(parts: int) -> float:
        res = fill_auto(hidden, units=data.units, labels=data.labels, rate=data.rate,
                        config=ModelConfig(refit_parts=parts))
        err = np.linalg.norm(res.positions[100:250, k] - data.positions[100:250, k], axis=1)
        return float(np.sqrt(np.mean(err ** 2)))

    with_parts, one_model = knee_rmse(3), knee_rmse(1)
    assert with_parts < 25.0
    assert one_model > 2 * with_parts


def test_seed_elsewhere_keeps_the_first_pass_where_the_refit_has_no_model():
    """Where the refit has no prediction, the first pass's stands if its sd is within ``max_sd`` and its
    reconstruction of the observed samples beside the gap run (edge estimates) misses none by more than ``max_z``
    sds; the refit's elsewhere; observed samples are not predictions."""
    positions = np.zeros((2, 2, 3))
    positions[:, 0] = np.nan  # marker 0 missing in both frames, marker 1 in the second
    positions[1, 1] = np.nan
    refit = (np.full((2, 2, 3), 1.0), np.array([[np.nan, np.nan], [2.0, np.nan]]),
             np.full((2, 2, 3), 3.0), np.array([[np.nan, 4.0], [np.nan, np.nan]]))
    seed = (np.full((2, 2, 3), 5.0), np.array([[6.0, 6.0], [6.0, np.nan]]),
            np.full((2, 2, 3), 7.0), np.array([[8.0, 8.0], [np.nan, np.nan]]))
    kw = dict(max_z=3.0, edge_frames=3)
    pred, sd, edge, edge_sd = seed_elsewhere(positions, refit, seed, max_sd=10.0, **kw)
    np.testing.assert_array_equal(sd, [[6.0, np.nan], [2.0, np.nan]])
    np.testing.assert_array_equal(pred[:, :, 0], [[5.0, 1.0], [1.0, 1.0]])
    np.testing.assert_array_equal(edge_sd, [[8.0, 4.0], [np.nan, np.nan]])
    np.testing.assert_array_equal(edge[:, :, 0], [[7.0, 3.0], [3.0, 3.0]])
    # a first pass less sure than max_sd: nothing kept
    assert np.isnan(seed_elsewhere(positions, refit, seed, max_sd=5.0, **kw)[1][0, 0])


def test_seed_elsewhere_drops_a_gap_run_whose_first_pass_misses_the_samples_beside_it():
    """One marker, a gap at frames 5-9 between observed frames: the first pass's reconstruction of the frames beside
    it (edge, sd 1) within 3 sds keeps its prediction in the gap; 10 sds off the frame before the gap drops it."""
    positions = np.zeros((15, 1, 3))
    positions[5:10] = np.nan
    refit = (np.full((15, 1, 3), np.nan), np.full((15, 1), np.nan), np.full((15, 1, 3), np.nan),
             np.full((15, 1), np.nan))
    edge = np.full((15, 1, 3), np.nan)
    edge_sd = np.full((15, 1), np.nan)
    edge[[2, 3, 4, 10, 11, 12]] = 1.0  # 1 mm off the observed zeros
    edge_sd[[2, 3, 4, 10, 11, 12]] = 1.0
    seed = (np.full((15, 1, 3), 0.5), np.full((15, 1), 2.0), edge, edge_sd)
    kw = dict(max_sd=10.0, max_z=3.0, edge_frames=3)
    assert np.isfinite(seed_elsewhere(positions, refit, seed, **kw)[1][5:10]).all()
    edge[4] = 10.0
    assert np.isnan(seed_elsewhere(positions, refit, seed, **kw)[1][5:10]).all()


def _toe_without_trusted_neighbours():
    """85_02's first 400 frames with a toe hidden for 100 frames while every other marker misses one frame of them:
    (data, truth, toe index, hidden positions)."""
    from pathlib import Path
    from mocapfill import read

    data = read(Path(__file__).parents[1] / "sample_data" / "85_02.c3d")
    truth = data.positions[:400]
    m = [x.split(":")[-1] for x in data.labels].index("LTOE")
    hidden = truth.copy()
    hidden[100:200, m] = np.nan
    for i, j in enumerate(j for j in range(truth.shape[1]) if j != m):
        hidden[100 + (7 * i) % 100, j] = np.nan
    return data, truth, m, hidden


def _toe_fill(config: ModelConfig) -> tuple[float, list, np.ndarray, np.ndarray]:
    """The toe case filled with ``config``: its RMS error (mm), its gaps' methods, the fill and the hidden input."""
    data, truth, m, hidden = _toe_without_trusted_neighbours()
    res = fill_auto(hidden, units=data.units, labels=data.labels, rate=data.rate, config=config)
    err = np.linalg.norm(res.positions[100:200, m] - truth[100:200, m], axis=1)
    methods = [g["method"] for g in res.info["gap_methods"] if g["marker_index"] == m]
    return float(np.sqrt(np.mean(err ** 2))), methods, res.positions, hidden


@pytest.mark.accuracy
def test_a_marker_the_refit_cannot_model_is_bridged_where_the_first_pass_is_not_sure():
    """The toe case: with no filled neighbour trusted (``impute_trust_mm`` 1e-6), the refit has no model for the
    toe, and the first pass is not as sure as a trusted neighbour, so the motion model and the body anchor bridge
    the gap (35.7 mm RMS with the motion alone, 24.6 with both); with ``seed_where_no_refit`` off, the same."""
    for config in (ModelConfig(impute_trust_mm=1e-6), ModelConfig(impute_trust_mm=1e-6, seed_where_no_refit=False)):
        bridged = _toe_fill(config)
        assert bridged[0] > 20.0 and bridged[1] == ["anchor+motion"]


@pytest.mark.accuracy
def test_a_marker_without_trusted_neighbours_gets_a_model_on_all_of_them():
    """The toe case with ``refit_untrusted``: no neighbour is trusted, so the refit fits one model on every near
    marker, read from the first pass's smoother (2.1 mm RMS; 35.7 without a model)."""
    rms, methods, filled, hidden = _toe_fill(ModelConfig(impute_trust_mm=1e-6, refit_untrusted=True))
    assert rms < 5.0 and methods == ["local-pca+motion"]
    np.testing.assert_array_equal(filled[~np.isnan(hidden)], hidden[~np.isnan(hidden)])


def test_rough_variance_measures_a_prediction_that_jumps():
    rng = np.random.default_rng(0)
    t = np.arange(200.0)
    smooth_track = np.stack([np.sin(t / 20.0), np.cos(t / 25.0), t / 50.0], axis=1)[:, None, :] * 100.0
    obs = smooth_track.copy()
    assert np.all(rough_variance(obs, smooth_track) < 0.01)  # a smooth prediction adds (next to) nothing
    noisy = smooth_track + rng.normal(0.0, 10.0, smooth_track.shape)
    var = rough_variance(obs, noisy)
    # white noise of sd 10: the mean square second difference per coordinate is 6 * 100; each sample takes the
    # largest of its three, so the estimate runs above 100 and never below 0
    assert var.shape == (200, 1) and np.all(var >= 0)
    assert 60.0 < np.median(var[1:-1]) < 400.0
    jump = smooth_track.copy()
    jump[100] += 300.0
    v = rough_variance(obs, jump)[:, 0]
    # a 300 mm jump per coordinate at one frame: its second difference there is 600 per coordinate, s^2 = 600^2 / 6;
    # the samples next to it enter that second difference too
    assert v[100] > 0.9 * 600.0 ** 2 / 6 and np.all(v[98:103] > 0)
    assert np.all(v[:98] < 0.01) and np.all(v[103:] < 0.01)


def _neighbours_filled_uncertainly(frames: int, *gaps: slice) -> tuple:
    """85_02's first ``frames`` frames with marker 5 missing in ``gaps`` and every other marker filled with an sd of
    50 mm (above the trust of 10) during the first of them: (truth, positions, sd, the marker,
    reconstruct_completed's options)."""
    from pathlib import Path
    from mocapfill import read

    truth = read(Path(__file__).parents[1] / "sample_data" / "85_02.c3d").positions[:frames]
    m = 5
    pos = truth.copy()
    for gap in gaps:
        pos[gap, m] = np.nan
    sd = np.zeros(truth.shape[:2])
    sd[gaps[0]] = 50.0
    sd[gaps[0], m] = 0.0
    return truth, pos, sd, m, dict(scales=(150.0, 3000.0), align_scale=200.0, knn=20, edge_frames=3, trust=10.0)


def test_the_refit_without_trusted_neighbours_models_on_every_one_when_asked():
    """reconstruct_completed: every neighbour of a marker filled with an sd (50 mm) above ``trust`` during its gap
    leaves it without a model; with ``untrusted`` it gets one on all of them, read from that take, which predicts
    where one of them is observed."""
    from mocapfill.engines.local_refit import reconstruct_completed

    truth, pos, sd, m, kw = _neighbours_filled_uncertainly(300, slice(100, 160))
    est, est_sd = reconstruct_completed(pos, truth, sd, **kw)[:2]
    assert np.isnan(est_sd[100:160, m]).all()
    used = np.zeros(truth.shape[1], dtype=bool)
    est, est_sd = reconstruct_completed(pos, truth, sd, untrusted=(truth, sd), untrusted_used=used, **kw)[:2]
    assert used[m] and used.sum() == 1
    assert np.isfinite(est_sd[100:160, m]).all()
    assert np.sqrt(np.mean(np.sum((est[100:160, m] - truth[100:160, m]) ** 2, axis=1))) < 10.0
    # where none of its predictors is observed (every marker missing at frames 150-159) it predicts nothing: it
    # would play the smoother's own guesses back
    pos[150:160] = np.nan
    sd[150:160] = 50.0
    est, est_sd = reconstruct_completed(pos, truth, sd, untrusted=(truth, sd), **kw)[:2]
    assert np.isnan(est_sd[150:160, m]).all() and np.isfinite(est_sd[100:150, m]).all()


def test_trusted_runs_group_a_markers_gaps_by_the_neighbours_trusted_over_each():
    """Each run of the marker's gaps takes the candidates whose mean variance over it is within trust^2; runs with
    the same such set are one group (frames ascending, predictors in the candidates' order); fewer than 3: none;
    past the most groups, the smaller ones merge on the candidates trusted over all of them."""
    from mocapfill.engines.local_refit import trusted_runs

    gaps = np.zeros(20, dtype=bool)
    gaps[2:5] = gaps[8:10] = gaps[14:18] = True
    var = np.zeros((20, 6))
    var[8:10, 4] = 400.0  # candidate 4 filled uncertainly in the second run only
    var[14:18, 1:4] = np.inf  # the third run: three candidates without a value
    candidates = np.array([4, 1, 2, 3, 5])
    got = [(f.tolist(), p.tolist()) for f, p in trusted_runs(gaps, var, candidates, 10.0, 3)]
    assert got == [([2, 3, 4], [4, 1, 2, 3, 5]), ([8, 9], [1, 2, 3, 5])]
    # at most 2 groups: the largest keeps its own, the rest share the candidates trusted over all of them
    gaps[0] = True
    var[0, 5] = 400.0
    got = [(f.tolist(), p.tolist()) for f, p in trusted_runs(gaps, var, candidates, 10.0, 2)]
    assert got == [([2, 3, 4], [4, 1, 2, 3, 5]), ([0, 8, 9], [1, 2, 3])]


def test_beside_blackouts_judges_a_gap_running_into_a_blackout_on_its_frames_outside_it():
    """A gap run that :func:`trusted_runs` leaves out because it runs into a whole-body blackout (every candidate
    unknown there, so none is trusted over the run) is judged again on its frames outside the blackout; runs that
    touch no blackout, or keep their trusted candidates, are :func:`trusted_runs`' alone."""
    from mocapfill.engines.local_refit import beside_blackouts, trusted_runs

    gaps = np.zeros(30, dtype=bool)
    gaps[2:5] = gaps[12:30] = True  # the second run ends in the blackout
    blackout = np.zeros(30, dtype=bool)
    blackout[20:] = True
    var = np.zeros((30, 6))
    var[blackout] = 1e6  # every marker filled with a large sd there
    candidates = np.array([4, 1, 2, 3, 5])
    assert [f.tolist() for f, _ in trusted_runs(gaps, var, candidates, 10.0, 3)] == [[2, 3, 4]]
    got = [(f.tolist(), p.tolist()) for f, p in beside_blackouts(gaps, var, candidates, 10.0, 3, blackout)]
    assert got == [(list(range(12, 20)), [4, 1, 2, 3, 5])]
    # without the blackout's frames there is nothing to judge again
    assert beside_blackouts(gaps, var, candidates, 10.0, 3, np.zeros(30, dtype=bool)) == []
    # frames beside it whose candidates are themselves unsure stay without a model
    var[12:20, 1:4] = 400.0
    assert beside_blackouts(gaps, var, candidates, 10.0, 3, blackout) == []


def test_a_gap_running_into_a_whole_body_blackout_is_predicted_where_its_neighbours_are_seen():
    """85_02: the right knee marker vanishes 60 frames before every marker does (a subject leaving the capture
    volume).  Trusted over the whole run, which the blackout dominates, no neighbour was, and the global PCA filled
    those 60 frames 109 mm off (RMS); judged on its frames outside the blackout, a local model predicts them."""
    from pathlib import Path
    from mocapfill import read

    data = read(Path(__file__).parents[1] / "sample_data" / "85_02.c3d")
    j = data.labels.index("Male:RKNE")
    cut = data.positions.copy()
    cut[640:, j] = np.nan
    cut[700:] = np.nan
    out = fill_auto(cut, units=data.units, labels=data.labels, rate=data.rate, bones=None, refine=True)
    err = np.linalg.norm(out.positions[640:700, j] - data.positions[640:700, j], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 20.0
    (record,) = [g for g in out.info["gap_methods"] if g["marker_index"] == j]
    assert record["method"].startswith("local-pca") and "local weighted PCA predicted" in record["reason"]


def test_the_refit_models_a_gap_on_the_neighbours_trusted_there_when_no_whole_gap_model_exists():
    """reconstruct_completed: every neighbour filled with a large sd during one gap of the marker is untrusted over
    its gaps together, so the marker gets no whole-gap model; ``run_scales`` gives its other gap, where they are
    observed, a model of its own (the gap where they were filled stays without one)."""
    from mocapfill.engines.local_refit import reconstruct_completed

    truth, pos, sd, m, kw = _neighbours_filled_uncertainly(400, slice(100, 160), slice(250, 280))
    est, est_sd = reconstruct_completed(pos, truth, sd, **kw)[:2]
    assert np.isnan(est_sd[100:160, m]).all() and np.isnan(est_sd[250:280, m]).all()
    est, est_sd = reconstruct_completed(pos, truth, sd, run_scales=(200.0,), run_max_rms=25.0, **kw)[:2]
    assert np.isnan(est_sd[100:160, m]).all()
    assert np.isfinite(est_sd[250:280, m]).all()
    assert np.sqrt(np.mean(np.sum((est[250:280, m] - truth[250:280, m]) ** 2, axis=1))) < 10.0
    # a model whose cross-validated rms is above run_max_rms is not kept (a marker moved about at random)
    wild = truth.copy()
    wild[:, m] += np.random.default_rng(0).normal(0.0, 200.0, (len(truth), 3))
    wild_pos = wild.copy()
    wild_pos[100:160, m] = wild_pos[250:280, m] = np.nan
    est, est_sd = reconstruct_completed(wild_pos, np.where(np.isnan(wild_pos), truth, wild), sd, run_scales=(200.0,),
                                        run_max_rms=25.0, **kw)[:2]
    assert np.isnan(est_sd[250:280, m]).all()


def test_reported_sd_grows_by_the_square_root_of_the_extrapolation_factor():
    """reported_sd: the variance times the factor, never below the cross-validated one; NaN or no factor: 1."""
    from mocapfill.methods.auto import reported_sd

    sd = np.array([[2.0, 2.0, 2.0, np.nan]])
    off = np.array([[4.0, 0.5, np.nan, 9.0]])
    out = reported_sd(sd, off)
    assert np.array_equal(out[0, :3], [4.0, 2.0, 2.0]) and np.isnan(out[0, 3])
    assert reported_sd(sd, None) is sd
    spread = np.array([[9.0, np.nan, 0.0, 1.0]])  # the widths' variance about their mix adds (NaN: none)
    assert np.array_equal(reported_sd(sd, off, spread)[0, :3], [5.0, 2.0, 2.0])


def test_the_reported_sd_adds_the_spread_of_the_widths_and_the_fill_stays():
    """The refit averages its widths' predictions; the variance of that mix adds their spread about it
    (:attr:`ModelConfig.width_spread_sd`): none on a rigid body (every width exact), some where a knee bends."""
    from mocapfill.methods.auto import impute_stage

    for pos, gap, apart in ((tumbling_body(), slice(100, 160), False), (bent_knee(), slice(90, 150), True)):
        gapped = pos.copy()
        gapped[gap, 0] = np.nan
        told = fill_auto(gapped)
        plain = fill_auto(gapped, config=ModelConfig(width_spread_sd=False))
        assert np.array_equal(told.positions, plain.positions)  # the mean keeps the cross-validated sd
        assert (told.std[gap, 0] >= plain.std[gap, 0]).all()
        spread = np.full(pos.shape[:2], np.nan)
        _, pred_sd, *_ = impute_stage(gapped, told.positions, np.where(np.isnan(gapped).any(axis=2), told.std, 0.0),
                                      DEFAULT_CONFIG, 1.0, disagreement=spread)
        assert np.isfinite(spread[gap, 0]).all() and np.isnan(spread[:gap.start]).all()
        if apart:
            assert spread[gap, 0].max() > pred_sd[gap, 0].max() ** 2 and (told.std[gap, 0] > plain.std[gap, 0]).all()
        else:
            assert spread[gap, 0].max() < 1e-6 and np.allclose(told.std, plain.std)


def _impute_case(neighbour_shift: float, neighbour_sd: float):
    """A rigid body whose marker 0 and nearest neighbour (4) vanish together; the neighbour's filled samples are
    ``neighbour_shift`` mm off in x with sd ``neighbour_sd`` mm.  Returns truth and impute_stage's four outputs."""
    from mocapfill.methods.auto import impute_stage

    pos = tumbling_body()
    gapped = pos.copy()
    gapped[100:160, [0, 4]] = np.nan
    completed = pos.copy()
    completed[100:160, 4, 0] += neighbour_shift
    sd = np.zeros(pos.shape[:2])
    sd[100:160, 0], sd[100:160, 4] = 5.0, neighbour_sd
    return pos, impute_stage(gapped, completed, sd, DEFAULT_CONFIG, 1.0)


def test_impute_stage_refits_on_the_completed_take_with_its_trusted_neighbours():
    """Stage 4 (the EM-style refit): a neighbour filled with an sd above ``impute_trust_mm`` is no predictor, so a
    wrong fill of it does not steer the marker; a trusted one does.  Predictions only at the missing samples, their
    sd with them, and the reconstruction at ``edge_frames`` observed frames either side of the gap."""
    pos, (pred, pred_sd, edge, edge_sd) = _impute_case(200.0, 50.0)
    assert np.abs(pred[100:160, 0] - pos[100:160, 0]).max() < 2.0  # a rigid body: the other markers fix it
    assert np.isfinite(pred_sd[100:160, 0]).all() and np.isnan(pred_sd[:100, 0]).all()
    assert np.isnan(pred[:, 1]).all()  # observed throughout: nothing to predict
    assert np.isfinite(edge_sd[[97, 99, 160, 162], 0]).all() and np.isnan(edge_sd[[96, 163, 50], 0]).all()
    assert np.abs(edge[97:100, 0] - pos[97:100, 0]).max() < 2.0
    _, (steered, *_) = _impute_case(200.0, 1.0)  # the same wrong fill, trusted
    assert np.abs(steered[100:160, 0] - pos[100:160, 0]).max() > 10.0


def test_bone_stage_pulls_a_prediction_onto_its_bone_and_leaves_the_anchor_and_the_unknown_alone():
    """Stage 2: a prediction 104 mm from its bone partner, where the bone is 100 +- 1 mm and the prediction's sd 10
    mm, moves onto the bone; one with no sd is not moved, and the body anchor's predictions are left out."""
    from mocapfill.bones.boneset import BoneSet
    from mocapfill.methods.auto import bone_stage

    n = 40
    pos = np.zeros((n, 3, 3))
    pos[:, 1] = np.arange(n)[:, None] * [5.0, 0.0, 0.0] + [0.0, 0.0, 1000.0]
    pos[:, 0] = pos[:, 1] + [100.0, 0.0, 0.0]
    pos[:, 2] = pos[:, 1] + [0.0, 200.0, 0.0]
    gapped = pos.copy()
    gapped[10:20, 0] = np.nan
    pred = np.full_like(pos, np.nan)
    pred[10:20, 0] = pos[10:20, 0] + [0.0, 30.0, 0.0]
    sd = np.full(pos.shape[:2], np.nan)
    sd[10:20, 0] = 10.0
    sd[12, 0] = np.nan  # no uncertainty known: not moved
    anchored = np.zeros(pos.shape[:2], dtype=bool)
    anchored[15, 0] = True
    bones = BoneSet(np.array([[0, 1], [1, 2]]), np.array([100.0, 200.0]), np.array([1.0, 1.0]),
                    np.array([n, n]), "mm")
    out = bone_stage(gapped, pred, sd, bones, DEFAULT_CONFIG, 1.0, anchored)
    moved = [t for t in range(10, 20) if t not in (12, 15)]
    length = np.linalg.norm(out[moved, 0] - pos[moved, 1], axis=1)
    assert np.abs(length - 100.0).max() < 1.0  # was 104.4
    assert np.array_equal(out[[12, 15], 0], pred[[12, 15], 0])
    assert np.isnan(out[:10]).all() and np.isnan(out[:, 1:]).all()  # only the predictions come back


def test_no_edge_frames_fills_without_the_edge_samples():
    """``edge_frames=0`` (the smoother learns no error at a gap's ends) is a valid model, not a crash."""
    pos = moving_body(n_frames=120)
    gapped = pos.copy()
    gapped[40:70, 0] = np.nan
    res = fill_auto(gapped, config=dataclasses.replace(DEFAULT_CONFIG, edge_frames=0))
    assert np.isfinite(res.positions).all() and np.array_equal(res.positions[:40], pos[:40])


def _bone_case(miss_mm: float, off: int = 2):
    """Two markers 100 mm apart (the bone, spread 1 mm) but 300 mm apart at ``off`` of the 40 frames (a hand that let
    go of what it held); marker 0 hidden at frames 10-19 and predicted ``miss_mm`` farther along the bone with an sd
    of 5 mm."""
    from mocapfill.bones.boneset import BoneSet

    n = 40
    pos = np.zeros((n, 2, 3))
    pos[:, 1] = np.arange(n)[:, None] * [5.0, 0.0, 0.0] + [0.0, 0.0, 1000.0]
    pos[:, 0] = pos[:, 1] + [100.0, 0.0, 0.0]
    pos[30:30 + off, 0] += [200.0, 0.0, 0.0]
    gapped = pos.copy()
    gapped[10:20, 0] = np.nan
    pred = np.full_like(pos, np.nan)
    pred[10:20, 0] = pos[10:20, 1] + [100.0 + miss_mm, 0.0, 0.0]
    sd = np.full(pos.shape[:2], np.nan)
    sd[10:20, 0] = 5.0
    bones = BoneSet(np.array([[0, 1]]), np.array([100.0]), np.array([1.0]), np.array([n]), "mm")
    return pos, gapped, pred, sd, bones


def test_bone_breaks_leaves_out_a_bone_the_predictions_say_broke():
    """A prediction 150 mm off a 100 +- 1 mm bone (that broke at 2 of its 38 observed frames) with an sd of 5 mm: the
    bone broke more probably than a Student-t miss of 30 sds, so the bone stage leaves the prediction alone and says
    where; frames with both ends observed keep the bone; a bone that held at every observed frame holds."""
    from mocapfill.bones.refinement import break_rates
    from mocapfill.methods.auto import bone_breaks, bone_stage

    pos, gapped, pred, sd, bones = _bone_case(150.0)
    p = break_rates(gapped, bones.pairs, bones.lengths, bones.spread, dof=3.0)
    assert p[0] == pytest.approx(2 / 30, rel=0.05)  # the share of observed frames it was off
    est = np.where(np.isnan(gapped), pred, gapped)
    broken = bone_breaks(gapped, est, sd, bones, DEFAULT_CONFIG, 1.0)
    assert broken[10:20, 0].all() and not broken[:10].any() and not broken[20:].any()
    seen = np.zeros_like(broken)
    out = bone_stage(gapped, pred, sd, bones, DEFAULT_CONFIG, 1.0, broken=seen)
    assert np.array_equal(out[10:20, 0], pred[10:20, 0]) and np.array_equal(seen, broken)
    # a bone that always held, or a model with no breaks (0 degrees of freedom): the bone pulls the prediction on
    kept = gapped.copy()
    kept[30:32, 0] = pos[30:32, 1] + [100.0, 0.0, 0.0]
    assert break_rates(kept, bones.pairs, bones.lengths, bones.spread, dof=3.0)[0] < 1e-6
    for case, config in ((kept, DEFAULT_CONFIG), (gapped, dataclasses.replace(DEFAULT_CONFIG, bone_break_dof=0.0))):
        held = bone_stage(case, pred, sd, bones, config, 1.0)
        assert np.abs(np.linalg.norm(held[10:20, 0] - pos[10:20, 1], axis=1) - 100.0).max() < 25.0  # was 250


def test_bone_breaks_keeps_a_bone_against_an_overconfident_miss():
    """A prediction 30 mm off (6 of its sds) a bone that broke at one observed frame: with a near-Gaussian miss (30
    degrees of freedom) that looks like a break; the Student t's tail says the prediction missed, so the bone holds
    and pulls it back (an overconfident wrist prediction on the tennis serve)."""
    from mocapfill.methods.auto import bone_breaks, bone_stage

    pos, gapped, pred, sd, bones = _bone_case(30.0, off=1)
    est = np.where(np.isnan(gapped), pred, gapped)
    gaussian = dataclasses.replace(DEFAULT_CONFIG, bone_break_dof=30.0)
    assert bone_breaks(gapped, est, sd, bones, gaussian, 1.0)[10:20].all()
    assert not bone_breaks(gapped, est, sd, bones, DEFAULT_CONFIG, 1.0).any()
    out = bone_stage(gapped, pred, sd, bones, DEFAULT_CONFIG, 1.0)
    assert np.abs(np.linalg.norm(out[10:20, 0] - pos[10:20, 1], axis=1) - 100.0).max() < 10.0  # was 130


def test_gap_records_name_the_bones_left_out():
    from mocapfill.methods.auto_records import gap_records

    pos, gapped, pred, sd, bones = _bone_case(150.0)
    missing = np.isnan(gapped).any(axis=2)
    broken = np.zeros((len(pos), 1), dtype=bool)
    broken[12:17, 0] = True
    post = np.where(missing, 5.0, 0.0)
    rec = gap_records(missing, post, missing, np.zeros_like(missing), DEFAULT_CONFIG, 1.0, ["HAND", "ROBOT"], bones,
                      broken=broken)
    assert len(rec) == 1 and "the bone(s) to ROBOT (5 frames)" in rec[0]["reason"]
    assert "did not hold" not in gap_records(missing, post, missing, np.zeros_like(missing), DEFAULT_CONFIG, 1.0,
                                             ["HAND", "ROBOT"], bones)[0]["reason"]


def test_displaced_records_name_each_displaced_run_and_its_offset():
    from mocapfill.methods.auto_records import displaced_records

    pos = np.zeros((30, 2, 3))
    edge = np.full_like(pos, np.nan)
    edge[5:8, 1] = pos[5:8, 1] + [0.03, 0.0, 0.04]  # the spatial model's reconstruction 0.05 m away (metres)
    displaced = np.zeros((30, 2), dtype=bool)
    displaced[5:8, 1] = True
    displaced[20:22, 1] = True  # a run without a reconstruction: no offset
    out = displaced_records(pos, displaced, edge, 0.001, ["A", "B"])
    assert [(r["marker"], r["marker_index"], r["start"], r["length"]) for r in out] == [("B", 1, 5, 3), ("B", 1, 20, 2)]
    assert out[0]["offset_mm"] == pytest.approx(50.0) and out[1]["offset_mm"] is None


@pytest.mark.slow
def test_the_fill_on_two_processes_is_the_fill_on_one(test_data):
    """jobs spreads the markers' local models (stages 1 and 4) and the bones' problems over forked processes: the
    same numbers, the same gap records (a real capture with gaps in most markers: refit parts, bones, reaches)."""
    from mocapfill.io import read

    data = read(test_data / "kinematics_racing_full.c3d")
    kw = dict(units=data.units, labels=data.labels, rate=data.rate)
    one = fill_auto(data.positions[:300], **kw)
    two = fill_auto(data.positions[:300], jobs=2, **kw)
    assert np.array_equal(one.positions, two.positions, equal_nan=True)
    assert np.array_equal(one.std, two.std, equal_nan=True)
    assert one.info["gap_methods"] == two.info["gap_methods"]


def test_a_marker_seen_only_at_a_short_takes_two_ends_is_predicted_by_the_refit():
    """10 frames (4 at the start, 6 at the end) are one cross-validation block: the refit's model had no error, so no
    weight, and the marker was bridged by the global PCA and the motion (171 mm RMSE here).  Cross-validated across
    the time gap between the two ends, the refit's model predicts it (btk's Knee.trc draw 2: 1.96 -> 0.12 mm)."""
    pos = moving_body(200, 9, seed=3, rotation=lambda t: rot_z(0.8 * np.sin(2 * np.pi * 0.3 * t)))
    gapped = pos.copy()
    gapped[4:194, 0] = np.nan
    res = fill_auto(gapped, rate=100.0)
    err = np.linalg.norm(res.positions[4:194, 0] - pos[4:194, 0], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 1.0
    assert [r["method"] for r in res.info["gap_methods"]] == ["local-pca+motion"]
    assert "local weighted PCA predicted 100% of the frames" in res.info["gap_methods"][0]["reason"]
