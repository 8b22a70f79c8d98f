"""`mocapfill estimate-bones`: stdout carries the data, the table goes to stderr, errors are one line."""

from __future__ import annotations

import csv
import io
import json

import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.bones import load_bones
from mocapfill.cli import cli


@pytest.fixture()
def runner() -> CliRunner:
    return CliRunner()


def test_json_to_stdout_and_table_to_stderr(runner, sample_data):
    result = runner.invoke(cli, ["estimate-bones", str(sample_data / "85_02.c3d")])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["units"] == "mm" and len(doc["bones"]) > 30
    pairs = {frozenset((b["a"], b["b"])) for b in doc["bones"]}
    assert frozenset(("Male:RKNE", "Male:RSHN")) in pairs
    assert "length (mm)" in result.stderr and "Male:RKNE" in result.stderr


def test_table_names_the_bones_that_did_not_hold(runner, sample_data):
    """The tennis serve's right wrist marker jumps off its forearm partners at a few frames: the table says so (the
    default fill leaves such a bone out where its predictions say it broke); 85_02's bones all held."""
    result = runner.invoke(cli, ["estimate-bones", str(sample_data / "kinematics_tennis_serve.c3d")])
    assert result.exit_code == 0, result.output
    said = " ".join(result.stderr.split())
    assert "did not hold at some frames" in said and "Derrick:RFIN - Derrick:RWRA" in said
    clean = runner.invoke(cli, ["estimate-bones", str(sample_data / "85_02.c3d")])
    assert "did not hold" not in clean.stderr


def test_output_file_round_trips_and_csv(runner, sample_data, tmp_path):
    out = tmp_path / "bones.json"
    result = runner.invoke(cli, ["estimate-bones", str(sample_data / "85_02.c3d"), "-o", str(out), "-q"])
    assert result.exit_code == 0 and result.stdout == "" and result.stderr == ""
    data = mocapfill.read(sample_data / "85_02.c3d")
    bones = load_bones(out, data.labels, units=data.units)
    assert len(bones) == len(json.loads(out.read_text())["bones"])
    result = runner.invoke(cli, ["estimate-bones", str(sample_data / "85_02.c3d"), "--format", "csv", "-q"])
    rows = list(csv.reader(io.StringIO(result.stdout)))
    assert rows[0] == ["marker_a", "marker_b", "length_mm", "spread_mm", "frames"] and len(rows) == len(bones) + 1
    out_csv = tmp_path / "bones.csv"
    assert runner.invoke(cli, ["estimate-bones", str(sample_data / "85_02.c3d"), "-o", str(out_csv)]).exit_code == 0
    assert out_csv.read_text().startswith("marker_a,")


def test_thresholds_and_units(runner, sample_data):
    path = str(sample_data / "kinematics_tennis_serve.c3d")
    default = json.loads(runner.invoke(cli, ["estimate-bones", path, "-q"]).stdout)
    assert default["units"] == "m"
    same = json.loads(runner.invoke(cli, ["estimate-bones", path, "-q", "--max-abs-spread", "6mm"]).stdout)
    assert same == default
    strict = json.loads(runner.invoke(cli, ["estimate-bones", path, "-q", "--max-abs-spread", "0.002",
                                            "--max-rel-spread", "0.01", "--min-partners", "0"]).stdout)
    assert 0 < len(strict["bones"]) < len(default["bones"])
    assert all(b["spread"] <= 0.002 and b["spread"] <= 0.01 * b["length"] for b in strict["bones"])


@pytest.mark.parametrize("args, message", [
    (["--max-abs-spread", "six"], "--max-abs-spread: not a length"),
    (["--max-rel-spread", "0"], "--max-rel-spread must be positive"),
    (["--min-partners", "-1"], "--min-partners must be >= 0"),
])
def test_bad_options(runner, sample_data, args, message):
    result = runner.invoke(cli, ["estimate-bones", str(sample_data / "85_02.c3d"), *args])
    assert result.exit_code == 1
    assert f"Error: {message}" in result.stderr and result.stdout == ""


def test_missing_input_and_same_output(runner, sample_data, tmp_path):
    result = runner.invoke(cli, ["estimate-bones", str(tmp_path / "nope.c3d")])
    assert result.exit_code == 1 and "nope.c3d" in result.stderr
    src = str(sample_data / "85_02.c3d")
    result = runner.invoke(cli, ["estimate-bones", src, "-o", src])
    assert result.exit_code == 1 and "same file as the input" in result.stderr
