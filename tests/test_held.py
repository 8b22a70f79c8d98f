"""The held-sample guard (mocapfill.guards.held): held and zeroed runs found, edge runs reported only, and no false
positive on a static trial, a resting marker or quantised integer storage."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.guards.held import MIN_HELD_FRAMES, find_held
from mocapfill.markers import MarkerData
from mocapfill.pipeline import FillSettings, fill_capture
from mocapfill.status import Status


def _walk(n_frames: int = 300, seed: int = 0, speed: float = 8.0) -> np.ndarray:
    """Two rigid 4-marker segments walking forward (``speed`` mm per frame) and swinging, with 0.2 mm noise:
    positions (n_frames, 8, 3)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None]
    trunk = np.array([[0.0, 0, 1000], [100, 0, 1000], [0, 100, 1050], [100, 100, 1050]])
    leg = np.array([[0.0, 0, 400], [60, 0, 400], [0, 0, 200], [60, 0, 200]])
    swing = 150 * np.sin(t / 15.0)
    out = np.concatenate([trunk[None] + np.stack([speed * t, 0 * t, 0 * t], axis=2),
                          leg[None] + np.stack([speed * t + swing, 0 * t, 20 * np.cos(t / 15.0)], axis=2)], axis=1)
    return out + rng.normal(0, 0.2, out.shape)


def test_held_run_found_and_the_first_sample_kept():
    positions = _walk()
    positions[101:121, 5] = positions[100, 5]  # the exporter held marker 5 for 20 frames
    result = find_held(positions)
    assert result.held[:, 5].nonzero()[0].tolist() == list(range(101, 121))
    assert not result.held[:, [0, 1, 2, 3, 4, 6, 7]].any() and not result.edge.any()
    assert [(r["marker"], r["start"], r["length"], r["kind"]) for r in result.runs] == [(5, 101, 20, "held")]


def test_zeroed_run_found_even_at_the_end():
    positions = _walk()
    positions[250:, 2, 2] = 0.0  # z exactly 0 from frame 250 to the end (a frozen head marker)
    positions[250:, 2, :2] = positions[249, 2, :2]
    result = find_held(positions)
    assert result.held[:, 2].nonzero()[0].tolist() == list(range(250, 300))
    assert {r["kind"] for r in result.runs} >= {"zero"}


def test_edge_runs_reported_not_rejected():
    positions = _walk()
    positions[:15, 6] = positions[15, 6]  # the first frames hold the first observed value (an edge fill)
    positions[285:, 1] = positions[284, 1]
    result = find_held(positions)
    assert not result.held.any()
    assert result.edge[:15, 6].sum() == 14 and result.edge[285:, 1].all()
    assert sorted(r["kind"] for r in result.runs) == ["edge", "edge"]


def test_short_repeats_and_a_static_trial_are_not_held():
    positions = _walk()
    positions[101, 5] = positions[100, 5]  # one repeat: shorter than MIN_HELD_FRAMES
    assert MIN_HELD_FRAMES > 2 and not find_held(positions).held.any()
    static = np.repeat(_walk(1)[:1], 500, axis=0) + np.random.default_rng(1).normal(0, 0.2, (500, 8, 3))
    static = np.round(static / 0.5) * 0.5  # quantised: values repeat often
    result = find_held(static, quantum=0.5)
    assert not result.held.any() and not result.edge.any()


def test_a_resting_marker_is_not_held():
    positions = _walk()
    reference = np.array([500.0, -300.0, 0.0])
    positions = np.concatenate([positions, np.repeat(reference[None, None], 300, axis=0)], axis=1)
    positions[:, 8, 1] = -300.0  # exactly constant: a reference point on the floor while the body walks past
    result = find_held(positions)
    assert not result.held.any() and not result.edge.any()


def test_slow_marker_in_integer_storage_is_not_held():
    # a slow creep (0.02 mm per frame) quantised to 0.1 mm repeats values for 5 frames at a time, while the body
    # moves slowly too
    positions = _walk(speed=0.02)
    positions[:, 4:] = _walk(speed=0.02)[:, :4] + np.array([0, 300.0, 0])  # the "leg" creeps like the trunk
    positions = np.round(positions / 0.1) * 0.1
    result = find_held(positions, quantum=0.1)
    assert not result.held.any()


def test_pipeline_fills_held_samples_unless_kept():
    positions = _walk()
    positions[101:121, 5] = positions[100, 5]
    truth = _walk()
    data = MarkerData(positions, [f"M{k}" for k in range(8)], 100.0, "mm")
    outcome = fill_capture(data, FillSettings(method="spline"))
    assert outcome.held is not None and outcome.held[101:121, 5].all() and outcome.held.sum() == 20
    assert outcome.result.filled[101:121, 5].all()
    error_held = np.abs(positions[101:121, 5] - truth[101:121, 5]).max()
    error_filled = np.abs(outcome.output.positions[101:121, 5] - truth[101:121, 5]).max()
    assert error_filled < error_held / 3
    kept = fill_capture(data, FillSettings(method="spline", keep_held=True))
    assert kept.held is None and np.array_equal(kept.output.positions, positions)
    assert kept.held_summary["held"] == 1
    assert Status.REJECTED_HELD == 8


@pytest.mark.parametrize("keep", [False, True])
def test_cli_info_and_fill_say_what_was_found(tmp_path, keep):
    positions = _walk()
    positions[101:121, 5] = positions[100, 5]
    labels = [f"M{k}" for k in range(7)] + ["*3"]
    path = tmp_path / "h.trc"
    mocapfill.write(MarkerData(positions, labels, 100.0, "mm"), path)
    info = CliRunner().invoke(cli, ["info", str(path)])
    assert info.exit_code == 0
    assert "1 unlabelled trajectories" in info.stderr
    assert "1 held run(s): 20 samples of M5" in " ".join(info.stderr.split())
    out = tmp_path / "o.trc"
    args = ["fill", str(path), str(out), "--method", "spline"] + (["--keep-held"] if keep else [])
    fill = CliRunner().invoke(cli, args)
    assert fill.exit_code == 0, fill.output
    text = " ".join(fill.stderr.split())
    assert "points: 7 marker(s); 1 unlabelled trajectory(ies) kept untouched" in text
    assert ("(kept: --keep-held)" in text) == keep and ("made gaps and filled" in text) != keep
