"""`mocapfill evaluate` through click's CliRunner: outputs, replay, exit codes and messages."""

from __future__ import annotations

import csv
import io
import json

import pytest
from click.testing import CliRunner

from mocapfill.cli import cli


@pytest.fixture(scope="module")
def clip(sample_data):
    return str(sample_data / "85_02.c3d")


def run(*args):
    return CliRunner().invoke(cli, ["evaluate", *map(str, args)])


def test_table_on_stderr_csv_on_stdout(clip):
    res = run(clip, "--methods", "linear,spline", "-n", "3", "--seed", "1", "--occlusion-max", "0.5s", "--csv")
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader(io.StringIO(res.stdout)))
    assert len(rows) == 6 and {r["method"] for r in rows} == {"linear", "spline"}
    assert all(float(r["rmse"]) > 0 for r in rows)
    assert "RMSE mean" in res.stderr and "win rate" in res.stderr and "seed 1" in res.stderr
    assert "best by mean RMSE" in res.stderr


def test_json_save_and_replay_give_the_same_numbers(clip, tmp_path):
    spec = tmp_path / "spec.json"
    first = run(clip, "-m", "linear,spline", "-p", "limb", "-n", "2", "-s", "5", "--occlusion-max", "40",
                "--save-occlusions", spec, "--json", "--quiet")
    assert first.exit_code == 0, first.output
    assert first.stderr == ""
    doc = json.loads(first.stdout)
    assert doc["protocol"] == "limb" and doc["seed"] == 5 and len(doc["trials"]) == 2
    saved = json.loads(spec.read_text())
    assert saved["format"] == "mocapfill-occlusions/1" and len(saved["trials"]) == 2
    again = run(clip, "-m", "linear,spline", "--occlusions", spec, "-s", "5", "--json", "-q")
    assert again.exit_code == 0, again.output
    redo = json.loads(again.stdout)
    assert redo["protocol"] == "replay"
    for a, b in zip(doc["trials"], redo["trials"]):
        assert a["occlusions"] == b["occlusions"]
        for method in ("linear", "spline"):
            assert a["scores"][method]["rmse"] == b["scores"][method]["rmse"]


def test_unknown_method(clip):
    res = run(clip, "--methods", "linear,nope", "-n", "1")
    assert res.exit_code == 1
    assert "Error: unknown method 'nope'" in res.stderr


def test_bad_spec_file(clip, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2")
    res = run(clip, "-m", "linear", "--occlusions", bad)
    assert res.exit_code == 1 and "bad.json: not valid JSON" in res.stderr
    bad.write_text(json.dumps({"trials": [{"occlusions": [{"markers": ["ZZZ"], "first_frame": 3, "length": 4}]}]}))
    res = run(clip, "-m", "linear", "--occlusions", bad)
    assert res.exit_code == 1 and "trial 1, occlusion 1: no marker called 'ZZZ'" in res.stderr
    res = run(clip, "-m", "linear", "--occlusions", tmp_path / "absent.json")
    assert res.exit_code == 1 and "absent.json: no such file" in res.stderr


def test_usage_errors(clip, tmp_path):
    res = run(clip, "-m", "linear", "--json", "--csv")
    assert res.exit_code == 2 and "choose one of --json and --csv" in res.stderr
    res = run(clip, "-m", "linear", "--occlusion-min", "ten")
    assert res.exit_code == 1 and "--occlusion-min 'ten'" in res.stderr
    res = run(clip, "-m", "linear", "-o", "novalue")
    assert res.exit_code == 2 and "KEY=VALUE" in res.stderr
    res = run(tmp_path / "absent.c3d", "-m", "linear")
    assert res.exit_code == 1 and "absent.c3d" in res.stderr
    res = run(clip, "-m", "linear", "-p", "sideways")
    assert res.exit_code == 2


def test_ignored_option_is_a_warning_not_an_error(clip):
    res = run(clip, "-m", "linear", "-n", "1", "-s", "0", "-o", "max_iter=5")
    assert res.exit_code == 0, res.output
    assert "'linear' ignores option(s): max_iter" in res.stderr
