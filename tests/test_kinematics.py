"""OpenSim IK in evaluate and the kinematic fill, on a three-pin leg model built in the test (skips without opensim).

The model's markers are simulated along known joint angles, so IK on the complete capture must give those angles,
and a fill that puts the hidden markers back where they were must give them too.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mocapfill
from mocapfill.errors import MethodError, MocapfillError
from mocapfill.markers import MarkerData

REPO = Path(__file__).resolve().parents[1]
RATE = 100.0
N_FRAMES = 60


def test_without_opensim_one_line_names_the_extra(monkeypatch):
    from mocapfill.kinematics.opensim_ik import require_opensim

    monkeypatch.setitem(sys.modules, "opensim", None)  # import opensim -> ImportError
    with pytest.raises(MocapfillError, match=r"mocapfill\[opensim\]") as info:
        require_opensim()
    assert "\n" not in str(info.value)


def test_fill_without_model_names_the_option():
    pos = np.zeros((5, 3, 3))
    pos[2, 1] = np.nan
    with pytest.raises(MethodError, match="--ik-model") as info:
        mocapfill.fill(pos, "opensim-ik", labels=["a", "b", "c"])
    assert "\n" not in str(info.value)


@pytest.fixture(scope="module")
def leg(tmp_path_factory):
    """(MarkerData of the simulated leg in mm, known angles (N_FRAMES, 3) in degrees, model path, setup path)."""
    osim = pytest.importorskip("opensim")
    import osim_models

    osim.Logger.setLevelString("off")
    osim.Logger.removeFileSink()
    folder = tmp_path_factory.mktemp("leg")
    model = str(folder / "leg.osim")
    names = osim_models.leg_model(model)
    angles = osim_models.leg_angles(N_FRAMES, RATE)
    positions = osim_models.simulate_leg(model, angles)
    setup = str(folder / "leg_ik.xml")
    osim_models.ik_setup_xml(setup, model, names)
    data = MarkerData(positions, names, RATE, "mm", 1, path="leg.trc")
    return data, np.degrees(angles), model, setup


def test_ik_recovers_known_angles(leg):
    from mocapfill.kinematics.opensim_ik import load_setup, run_ik

    data, degrees, model, setup = leg
    angles = run_ik(load_setup(setup), data)
    assert list(angles.frames) == list(range(N_FRAMES))
    order = [angles.names.index(n) for n in ("hip_flexion", "knee_angle", "ankle_angle")]
    assert all(angles.kinds[c] == "rotational" for c in order)
    assert np.abs(angles.values[:, order] - degrees).max() < 0.01


def test_kinematic_fill_reads_hidden_markers_off_the_model(leg):
    data, degrees, model, setup = leg
    pos = data.positions.copy()
    pos[10:30, data.labels.index("SHK2")] = np.nan  # one marker of a body whose others are seen
    pos[35:50, data.labels.index("THI1")] = np.nan
    foot = [data.labels.index(n) for n in ("FT1", "FT2", "FT3")]
    pos[20:26][:, foot] = np.nan  # a whole segment drops out: the ankle angle is interpolated across it
    result = mocapfill.fill(data.with_positions(pos), "opensim-ik", ik_model=model)
    hidden = np.isnan(pos).any(axis=2)
    assert result.filled[hidden].all()
    err = np.linalg.norm(result.positions - data.positions, axis=2)
    not_foot = hidden.copy()
    not_foot[:, foot] = False
    assert err[not_foot].max() < 0.5  # mm: the model is exact
    assert err[hidden].max() < 40.0  # the foot's angle, interpolated over 6 frames of a 1.7 Hz swing
    assert np.isfinite(result.std[hidden]).all() and (result.std[hidden] >= 0).all()
    assert result.info["frames_solved"] == N_FRAMES
    assert result.info["coordinates_interpolated"] >= 6


def test_kinematic_fill_attaches_a_marker_the_model_lacks(leg):
    data, degrees, model, setup = leg
    shank = data.positions[:, [data.labels.index(n) for n in ("SHK1", "SHK2", "SHK3")]]
    extra = np.einsum("tmc,m->tc", shank, [0.5, -0.2, 0.7])  # an affine combination of shank markers rides on the shank
    pos = np.concatenate([data.positions, extra[:, None]], axis=1)
    truth = pos.copy()
    pos[15:40, -1] = np.nan
    moved = MarkerData(pos, data.labels + ["EXTRA"], RATE, "mm", 1)
    result = mocapfill.fill(moved, "opensim-ik", ik_model=model)
    assert result.info["attached"] == {"EXTRA": "shank"}
    assert np.linalg.norm(result.positions - truth, axis=2)[15:40, -1].max() < 0.5


def test_evaluate_scores_joint_angles(leg, tmp_path):
    data, degrees, model, setup = leg
    result = mocapfill.evaluate(data, ["linear", "opensim-ik"], "marker", trials=2, seed=3, ik=setup,
                                occlusion_min=10, occlusion_max=25)
    assert result.ik["coordinates"] == {"hip_flexion": "rotational", "knee_angle": "rotational",
                                        "ankle_angle": "rotational"}
    assert len(result.left_missing) == 2
    summary = result.summary()
    kin = summary["opensim-ik"]
    assert kin["angle_worst"]["median"] < 0.1  # exact model, exact markers: the fill gives the angles back
    assert summary["linear"]["angle_median"]["median"] is not None
    assert all(np.isfinite(s.angle_worst) for s in result.left_missing)
    assert result.best_for_angles() in ("linear", "opensim-ik")
    record = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert record["ik"]["left_missing"]["angle_median"]["median"] is not None
    assert "angle_worst" in record["trials"][0]["scores"]["linear"]
    assert "left_missing" in record["trials"][0]
    lines = result.to_csv().splitlines()
    assert "angle_median" in lines[0] and sum(",left missing," in line for line in lines) == 2
    from mocapfill.report.evaluation_html import render_evaluation_html

    page = render_evaluation_html(result)
    assert "Best for joint angles" in page and "knee_angle" in page and "(left missing)" in page


@pytest.mark.slow
def test_evaluate_cli_ik(leg, tmp_path):
    from click.testing import CliRunner

    from mocapfill.cli import cli

    data, degrees, model, setup = leg
    trc = tmp_path / "leg.trc"
    mocapfill.write(data, trc)
    report = tmp_path / "ev.html"
    # in a process of its own: OpenSim writes to file descriptor 1 itself, and stdout must stay pure JSON
    res = subprocess.run([sys.executable, "-m", "mocapfill", "evaluate", str(trc), "-m", "linear,opensim-ik", "-n",
                          "2", "-s", "1", "--ik", setup, "--report", str(report), "--json", "--jobs", "2"],
                         capture_output=True, text=True, cwd=REPO, timeout=300)
    assert res.returncode == 0, res.stderr
    record = json.loads(res.stdout)
    assert record["ik"]["best_for_angles"] in ("linear", "opensim-ik")
    assert "best for joint angles" in res.stderr
    assert report.read_text().startswith("<!DOCTYPE html>")
    assert not (tmp_path / "opensim.log").exists() and not (REPO / "opensim.log").exists()
    runner = CliRunner()
    # the kinematic fill without a model: one line naming the option
    res = runner.invoke(cli, ["evaluate", str(trc), "-m", "linear,opensim-ik", "-n", "1"])
    assert res.exit_code == 1 and "--ik-model" in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_ik_runs_when_the_last_marker_is_missing(leg):
    """OpenSim's TRC reader drops a row's final empty field: the writer must still give it every column."""
    from mocapfill.kinematics.angles import coordinate_errors
    from mocapfill.kinematics.opensim_ik import load_setup, run_ik

    data, degrees, model, setup = leg
    pos = data.positions.copy()
    pos[5:20, -1] = np.nan  # the last marker of the file, missing: rows end in empty fields
    ik = load_setup(setup)
    gappy = run_ik(ik, data.with_positions(pos))
    errors = coordinate_errors(run_ik(ik, data), gappy)
    assert max(errors.values()) < 0.01  # the foot's other two markers still hold the ankle angle
