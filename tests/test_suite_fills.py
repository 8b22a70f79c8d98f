"""The suites' fills (``woltring``, ``pattern``, ``rigid``): each reproduces its textbook rule on a hand-made case,
and declines (leaves missing, reports) the gaps its rule cannot fill."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import mocapfill
from mocapfill.errors import MethodError
from mocapfill.methods import METHODS
from mocapfill.methods.base import declined_mask
from mocapfill.methods.suite import parse_donors


def declined_gaps(info: dict) -> list[tuple[int, int, int]]:
    return [(rec["marker_index"], rec["start"], rec["length"]) for rec in info["declined"]]


def _rotation(angle: float, axis: np.ndarray) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def rigid_body(n_frames: int = 120, seed: int = 0) -> np.ndarray:
    """Six markers of one rigid body moved by a known rotation and translation per frame, mm: (n_frames, 6, 3)."""
    rng = np.random.default_rng(seed)
    body = rng.normal(scale=80.0, size=(6, 3))
    t = np.arange(n_frames) / 100.0
    out = np.empty((n_frames, 6, 3))
    for f, s in enumerate(t):
        rot = _rotation(2.5 * np.sin(1.3 * s) + s, np.array([np.sin(s), 1.0, 0.3 + np.cos(2 * s)]))
        shift = np.array([900 * s, 200 * np.sin(3 * s), 1000 + 50 * np.cos(5 * s)])
        out[f] = body @ rot.T + shift
    return out


def test_the_suite_methods_are_registered_and_may_decline():
    for name in ("woltring", "pattern", "rigid"):
        assert METHODS[name].may_decline
    assert not METHODS["auto"].may_decline and not METHODS["linear"].may_decline


@pytest.mark.parametrize("donors", [None, ["M1", "M2", "M3"], "M0=M5,M4,M3,M2"])
def test_rigid_recovers_a_rigid_body_exactly(donors):
    truth = rigid_body()
    labels = [f"M{i}" for i in range(6)]
    positions = truth.copy()
    positions[30:75, 0] = np.nan  # interior
    positions[:12, 4] = np.nan  # at the start: one end only
    result = mocapfill.fill(positions, "rigid", donors=donors, labels=labels)
    assert result.info["declined"] == []
    span = np.ptp(truth, axis=0).max()
    assert np.abs(result.positions - truth).max() < 1e-9 * span
    used = {rec["marker"]: rec["donors"] for rec in result.info["gap_methods"]}
    if isinstance(donors, list):
        assert used["M0"] == donors
    elif isinstance(donors, str):
        assert used["M0"] == ["M5", "M4", "M3", "M2"]
    else:
        assert len(used["M0"]) == 3


def test_pattern_fill_of_a_translated_donor_is_exact():
    rng = np.random.default_rng(1)
    n = 200
    donor = np.cumsum(rng.normal(scale=5.0, size=(n, 3)), axis=0) + 500.0  # any trajectory
    other = donor + rng.normal(scale=30.0, size=(n, 3))  # a poor donor: its offset jitters
    marker = donor + np.array([40.0, -25.0, 110.0])
    truth = np.stack([marker, other, donor], axis=1)
    positions = truth.copy()
    positions[50:120, 0] = np.nan
    positions[185:, 0] = np.nan  # at the end: the offset of the one end is carried
    result = mocapfill.fill(positions, "pattern", labels=["RKNE", "X", "RTHI"])
    assert np.abs(result.positions - truth).max() < 1e-9
    assert [rec["donors"] for rec in result.info["gap_methods"]] == [["RTHI"], ["RTHI"]]  # chosen: steadiest distance


def test_pattern_bridges_a_changing_offset_linearly():
    n = 100
    t = np.arange(n, dtype=float)
    donor = np.stack([100 * np.sin(t / 9), 3 * t, 50 + 0 * t], axis=1)
    offset = np.stack([10 + 0.5 * t, -2 + 0 * t, 0.25 * t], axis=1)  # linear in time: the bridge is exact
    truth = np.stack([donor + offset, donor], axis=1)
    positions = truth.copy()
    positions[20:70, 0] = np.nan
    result = mocapfill.fill(positions, "pattern", donors=["D"], labels=["M", "D"])
    np.testing.assert_allclose(result.positions, truth, rtol=0, atol=1e-9)


def test_woltring_reproduces_a_quintic_to_1e6_of_its_range():
    n = 160
    u = np.linspace(-1.0, 1.0, n)
    coeffs = np.random.default_rng(2).normal(size=(6, 3))
    quintic = np.stack([np.polyval(coeffs[:, k], u) for k in range(3)], axis=1) * 400.0 + 1000.0
    truth = np.stack([quintic, quintic[::-1]], axis=1)
    positions = truth.copy()
    positions[50:110, 0] = np.nan  # 60 frames: 35 on each side
    positions[20:24, 1] = np.nan
    positions[30:31, 1] = np.nan  # frames on a side need not be consecutive
    result = mocapfill.fill(positions, "woltring")
    assert result.info["declined"] == []
    span = np.ptp(truth, axis=0)
    err = np.abs(result.positions - truth) / span
    assert err.max() < 1e-6


def test_woltring_declines_gaps_with_fewer_than_five_frames_on_a_side():
    n = 60
    t = np.arange(n, dtype=float)
    truth = np.stack([np.stack([t, t ** 2 / 50, np.sin(t / 7)], axis=1)] * 2, axis=1)
    positions = truth.copy()
    positions[4:20, 0] = np.nan  # 4 valid frames before
    positions[30:40, 0] = np.nan  # interior, fine
    positions[:3, 1] = np.nan  # at the start: none before
    positions[56:, 1] = np.nan  # at the end
    result = mocapfill.fill(positions, "woltring", labels=["A", "B"])
    assert sorted(declined_gaps(result.info)) == [(0, 4, 16), (1, 0, 3), (1, 56, 4)]
    reasons = {(r["marker"], r["start"]): r["reason"] for r in result.info["declined"]}
    assert reasons[("A", 4)] == "4 valid frames before the gap, fewer than 5"
    assert reasons[("B", 56)] == "0 valid frames after the gap, fewer than 5"
    assert np.isnan(result.positions[4:20, 0]).all() and np.isnan(result.positions[:3, 1]).all()
    assert np.isfinite(result.positions[30:40, 0]).all()
    declined = [g for g in result.info["gap_methods"] if g["method"] == "declined"]
    assert len(declined) == 3
    mask = declined_mask(result.info, (n, 2))
    assert mask.sum() == 16 + 3 + 4 and mask[4:20, 0].all() and not mask[30:40, 0].any()


def test_pattern_declines_when_its_donor_is_missing_in_the_gap_or_at_its_ends():
    truth = rigid_body(n_frames=80)
    labels = [f"M{i}" for i in range(6)]
    positions = truth.copy()
    positions[20:40, 0] = np.nan
    positions[40, 1] = np.nan  # the donor is missing at the gap's end frame
    positions[50:60, 2] = np.nan
    positions[55, 3] = np.nan  # ... and here inside the gap
    result = mocapfill.fill(positions, "pattern", donors="M0=M1;M2=M3", labels=labels)
    assert sorted(declined_gaps(result.info))[:2] == [(0, 20, 20), (2, 50, 10)]
    assert "missing in the gap or at its ends" in result.info["declined"][0]["reason"]
    assert np.isnan(result.positions[20:40, 0]).all() and np.isnan(result.positions[50:60, 2]).all()
    # automatic donors find another one for the same gaps
    auto = mocapfill.fill(positions, "pattern", labels=labels)
    assert not any(rec["marker"] in ("M0", "M2") for rec in auto.info["declined"])


def test_rigid_declines_without_three_donors_seen_throughout():
    truth = rigid_body(n_frames=80)[:, :4]
    positions = truth.copy()
    positions[20:40, 0] = np.nan
    positions[30, 1] = np.nan  # only two donors seen throughout
    result = mocapfill.fill(positions, "rigid")
    assert declined_gaps(result.info) == [(0, 20, 20), (1, 30, 1)]  # marker 1's donors: 2 and 3 only
    assert "fewer than 3" in result.info["declined"][0]["reason"]
    assert np.isnan(result.positions[20:40, 0]).all()
    assert np.isnan(result.positions[30, 1]).all()


def test_rigid_declines_donors_in_a_line():
    n = 50
    t = np.arange(n, dtype=float)[:, None]
    line = np.stack([np.array([0.0, 0, 0]), np.array([100.0, 0, 0]), np.array([200.0, 0, 0])])
    truth = np.concatenate([line[None] + t[:, :, None] * np.array([1.0, 2, 3]),
                            (np.array([50.0, 80, 0]) + t * np.array([1.0, 2, 3]))[:, None]], axis=1)
    positions = truth.copy()
    positions[10:20, 3] = np.nan
    result = mocapfill.fill(positions, "rigid", donors=[0, 1, 2])
    assert result.info["declined"][0]["reason"] == "the donors lie nearly in a line"


def test_donor_names_match_after_a_subject_prefix_and_unknown_ones_fail_in_one_line():
    labels = ["Bob:LKNE", "Bob:LTHI", "Bob:LSHN", "Bob:LANK"]
    table = parse_donors("LKNE=LTHI, LSHN ; LANK", labels, 4)
    assert table[0] == [1, 2] and table[1] == [3] and table[3] == []
    assert parse_donors({"Bob:LKNE": "LTHI"}, labels, 4) == {0: [1]}
    with pytest.raises(MethodError, match=r"unknown donor label 'LTHY'; near: Bob:LTHI"):
        parse_donors(["LTHY"], labels, 4)
    with pytest.raises(MethodError, match="unknown marker label"):
        parse_donors("RKNE=LTHI", labels, 4)


def test_rigid_and_pattern_on_a_real_capture(sample_data):
    data = mocapfill.read(sample_data / "85_02.c3d")
    truth = data.positions
    positions = truth.copy()
    knee = data.labels.index("LKNE") if "LKNE" in data.labels else 10
    positions[300:360, knee] = np.nan
    for name in ("rigid", "pattern", "woltring"):
        result = mocapfill.fill(data.with_positions(positions), name)
        assert result.info["declined"] == []
        err = np.linalg.norm(result.positions[300:360, knee] - truth[300:360, knee], axis=1)
        assert np.isfinite(err).all()
        observed = ~np.isnan(positions).any(axis=2)
        assert np.array_equal(result.positions[observed], positions[observed])


# --- through the CLI and the pipeline --------------------------------------------------------------------------

def _cli(args):
    from click.testing import CliRunner

    from mocapfill.cli import cli

    return CliRunner().invoke(cli, [str(a) for a in args])


def test_fill_command_with_named_donors_and_a_declined_gap(sample_data, tmp_path):
    data = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")
    positions = data.positions.copy()
    positions[200:260, 5] = np.nan
    positions[400:420, 7] = np.nan
    positions[410, 8] = np.nan  # the named donor of marker 7 is missing inside its gap: declined
    gappy = tmp_path / "gappy.c3d"
    mocapfill.write(data.with_positions(positions), gappy)
    labels = data.labels
    donors = [f"{labels[5]}={labels[4]},{labels[6]},{labels[3]}", f"{labels[7]}={labels[8]}"]
    out, report = tmp_path / "out.c3d", tmp_path / "out.json"
    result = _cli(["fill", gappy, out, "-m", "pattern", "--donors", donors[0], "--donors", donors[1],
                   "--report", report])
    assert result.exit_code == 0, result.output
    assert "pattern declined 1 gap, left missing" in result.stderr
    assert "missing in the gap or at its ends" in result.stderr
    written = mocapfill.read(out)
    assert np.isnan(written.positions[400:420, 7]).all() and np.isfinite(written.positions[200:260, 5]).all()
    doc = json.loads(report.read_text())
    assert doc["summary"]["settings"]["donors"] == ";".join(donors)
    gaps = {(g["marker"], g["first_frame"] - data.first_frame): g for g in doc["gaps"]}
    assert gaps[(labels[5], 200)]["reason"] == f"donors {labels[4]}"
    assert gaps[(labels[7], 400)]["status"] == "unfilled" and gaps[(labels[7], 400)]["method"] == "declined"


def test_donors_need_a_donor_method_and_known_labels(sample_data, tmp_path):
    gappy = sample_data / "kinematics_tennis_serve_nan.c3d"
    result = _cli(["fill", gappy, tmp_path / "o.c3d", "--donors", "A,B"])
    assert result.exit_code == 2 and "--donors applies to the methods pattern and rigid" in result.stderr
    result = _cli(["fill", gappy, tmp_path / "o.c3d", "-m", "rigid", "--donors", "NOPE"])
    assert result.exit_code == 1 and result.stderr.startswith("Error: unknown donor label 'NOPE'")


@pytest.mark.parametrize("lowpass", ["6", "auto", "auto-marker"])
def test_fill_command_lowpass_reports_its_cutoff(sample_data, tmp_path, lowpass):
    gappy = sample_data / "kinematics_tennis_serve_nan.c3d"
    out, report = tmp_path / "out.c3d", tmp_path / "out.json"
    result = _cli(["fill", gappy, out, "-m", "linear", "--lowpass", lowpass, "--report", report])
    assert result.exit_code == 0, result.output
    doc = json.loads(report.read_text())
    used = doc["summary"]["settings"]["lowpass"]
    assert f"low-passed at {used['used']}" in result.stderr and doc["summary"]["smoothed"]
    if lowpass == "6":
        assert used["cutoff_hz"] == 6.0
    elif lowpass == "auto":
        assert 2.0 < used["cutoff_hz"] < 25.0
    else:
        assert len(used["cutoff_hz"]) == 39


def test_pipeline_lowpass_changes_observed_samples_and_records_the_cutoff(sample_data):
    from mocapfill.pipeline import FillSettings, fill_capture

    data = mocapfill.read(sample_data / "kinematics_tennis_serve_nan.c3d")
    outcome = fill_capture(data, FillSettings(method="linear", lowpass=6.0).check())
    seen = ~data.missing
    changed = (outcome.output.positions != data.positions).any(axis=2) & seen
    assert changed[seen].mean() > 0.99
    assert outcome.settings["lowpass"]["cutoff_hz"] == 6.0 and outcome.settings["lowpass"]["used"] == "6 Hz"
    plain = fill_capture(data, FillSettings(method="linear"))
    assert np.array_equal(plain.output.positions[seen], data.positions[seen])
    with pytest.raises(MethodError, match="'auto' or 'auto-marker'"):
        FillSettings(lowpass="fast").check()


def test_declined_records_name_the_whole_captures_column_when_model_points_are_kept_out():
    from mocapfill.markers import MarkerData

    n = 60
    t = np.arange(n, dtype=float)
    track = np.stack([t, t ** 2 / 50, np.sin(t / 7)], axis=1)
    positions = np.stack([track + 5, track, track + 1], axis=1)
    positions[2:20, 2] = np.nan  # 2 valid frames before: declined
    positions[30:35, 0] = np.nan  # a model point's gap: not filled, not declined
    data = MarkerData(positions, ["PELVIS_ANGLE", "A", "B"], 100.0, "mm", kinds=["model", "marker", "marker"])
    result = mocapfill.fill(data, "woltring")
    assert [(r["marker"], r["marker_index"]) for r in result.info["declined"]] == [("B", 2)]
    mask = declined_mask(result.info, (n, 3))
    assert mask[2:20, 2].all() and mask.sum() == 18
    assert np.isnan(result.positions[30:35, 0]).all()


def test_batch_takes_donors_and_lowpass(sample_data, tmp_path):
    rows = mocapfill.batch([str(sample_data / "kinematics_tennis_serve_nan.c3d")], str(tmp_path / "out"),
                           method="pattern", donors=["RSHO", "LSHO"], lowpass="auto", report="json")
    assert [row.status for row in rows] == ["filled"], rows
    doc = json.loads(Path(rows[0].report).read_text())
    settings = doc["summary"]["settings"]
    assert settings["donors"] == "RSHO,LSHO" and settings["lowpass"]["per"] == "take"


def test_status_marks_declined_gaps_and_lowpassed_observed_samples(sample_data):
    from mocapfill.pipeline import FillSettings, fill_capture
    from mocapfill.status import Status

    data = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")
    positions = data.positions.copy()
    positions[2:30, 6] = np.nan  # 2 valid frames before: woltring declines it
    positions[300:320, 9] = np.nan
    outcome = fill_capture(data.with_positions(positions), FillSettings(method="woltring", lowpass=6.0).check())
    status = outcome.status
    assert (status[2:30, 6] == Status.MISSING_DECLINED).all()
    assert (status[300:320, 9] == Status.FILLED).all()
    assert (status[100:200, 0] == Status.SMOOTHED).all()
