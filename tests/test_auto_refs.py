"""Reference takes and a learned model as the default's inputs (issue 26): the weights
reach it through the pipeline, each local model keeps references only where they help, and a
denoiser's estimate is fused as a second spatial measurement (:func:`mocapfill.methods.auto.prior_stage`)."""

from __future__ import annotations

import numpy as np
import pytest

import mocapfill
from mocapfill.methods import get_method
from mocapfill.methods.auto import prior_stage


@pytest.fixture(scope="module")
def gappy(halves):
    from mocapfill.evaluation.occlusions import make_occlusions

    first, _ = halves
    trial = make_occlusions(first, "dense", trials=1, seed=2, missing=0.2)[0]
    corrupted, hidden, _ = trial.apply(first.positions)
    return first.with_positions(corrupted), hidden


def rmse(result, truth, hidden):
    return float(np.sqrt(np.mean(((result.positions - truth.positions)[hidden]) ** 2) * 3))


def test_prior_stage_fuses_by_inverse_variance():
    positions = np.zeros((4, 2, 3))
    positions[1:3, 0] = np.nan
    pred = np.full((4, 2, 3), np.nan)
    pred[1:3, 0] = 10.0
    sd = np.full((4, 2), np.nan)
    sd[1, 0], sd[2, 0] = 3.0, np.nan  # frame 2: the spatial model had nothing there
    edge = np.full((4, 2, 3), np.nan)
    edge[0, 0] = 1.0
    edge_sd = np.full((4, 2), np.nan)
    edge_sd[0, 0] = 3.0
    prior = np.full((4, 2, 3), 20.0)
    prior_sd = np.array([4.0, 4.0])
    p, p_sd, e, e_sd = prior_stage(positions, pred, sd, edge, edge_sd, prior, prior_sd)
    w1, w2 = 1 / 9, 1 / 16
    np.testing.assert_allclose(p[1, 0], (10 * w1 + 20 * w2) / (w1 + w2))
    assert p_sd[1, 0] == pytest.approx(np.sqrt(1 / (w1 + w2)))
    np.testing.assert_allclose(p[2, 0], 20.0)  # only the network: its estimate and sd
    assert p_sd[2, 0] == 4.0
    np.testing.assert_allclose(e[0, 0], (1 * w1 + 20 * w2) / (w1 + w2))  # the edge measurement is fused too
    assert np.isnan(e_sd[3, 0]) and np.isnan(p_sd[0, 1]) and np.isnan(p[:, 1]).all()  # nothing new elsewhere
    # a network without an sd (marker outside the layout) changes nothing
    p2, p2_sd, _, _ = prior_stage(positions, pred, sd, edge, edge_sd, prior, np.array([np.nan, 4.0]))
    np.testing.assert_array_equal(p2_sd, sd)


@pytest.mark.accuracy
def test_weighted_references_reach_auto(halves, gappy):
    first, second = halves
    data, hidden = gappy
    assert {"reference_frames", "reference_weights", "model"} <= get_method("auto").parameters()
    # the other half grown 3 % about each frame's centroid (the markers placed anew): a body that fits less well
    centre = second.positions.mean(axis=1, keepdims=True)
    second = second.with_positions(centre + 1.03 * (second.positions - centre))
    plain = mocapfill.fill(data, "auto")
    with_ref = mocapfill.fill(data, "auto", reference=second)
    (take,) = with_ref.info["reference_takes"]
    assert 0.05 < take["weight"] < 0.5  # below the weightless methods' cut: only weights let it in
    used = with_ref.info["references"]
    assert used["frames"] == second.n_frames and 0 < used["used"] <= used["models"]
    assert rmse(with_ref, first, hidden) < 0.8 * rmse(plain, first, hidden)
    observed = ~np.isnan(data.positions).any(axis=2)
    assert np.array_equal(with_ref.positions[observed], data.positions[observed])


@pytest.mark.accuracy
def test_each_model_keeps_a_wrong_body_out(halves, gappy):
    """Frames of another body forced in at weight 1: the models' cross-validation keeps them out where they hurt."""
    first, second = halves
    data, hidden = gappy
    rng = np.random.default_rng(0)
    other = second.positions * np.array([1.3, 0.8, 1.1]) + rng.normal(0, 30.0, size=(1, second.n_markers, 3))
    plain = mocapfill.fill(data, "auto")
    forced = mocapfill.fill(data.positions, "auto", reference_frames=other,
                            reference_weights=np.ones(len(other)), rate=data.rate)
    assert forced.info["references"]["used"] < forced.info["references"]["models"]
    assert rmse(forced, first, hidden) < 1.1 * rmse(plain, first, hidden)


def test_fill_reference_reports_how_much_auto_used_it(halves, tmp_path):
    """``fill --reference`` reaches the default with its weight; the report says how many local models kept it."""
    import json

    from click.testing import CliRunner

    from mocapfill.cli import cli

    first, second = halves
    gappy = first.positions.copy()
    gappy[100:160, 20] = np.nan
    gappy[200:230, 7] = np.nan
    mocapfill.write(first.with_positions(gappy), tmp_path / "a.c3d")
    mocapfill.write(second, tmp_path / "b.c3d")
    report = tmp_path / "r.json"
    result = CliRunner().invoke(cli, ["fill", str(tmp_path / "a.c3d"), str(tmp_path / "o.c3d"), "-m", "auto",
                                      "--reference", str(tmp_path / "b.c3d"), "--report", str(report)])
    assert result.exit_code == 0, result.output
    (ref,) = json.loads(report.read_text())["summary"]["settings"]["references"]
    assert 0.05 < ref["weight"] < 1 and "train the body model" in ref["stages"]["fill"]
    assert "local models" in ref["stages"]["fill"]
