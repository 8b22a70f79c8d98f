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


def test_no_best_when_every_hidden_sample_is_left_unfilled(test_data):
    """newwalk.c3d's marker trials fall in its blackouts: every RMSE is "-", so no method is named best; the CSV and
    the JSON have no score either."""
    walk = test_data / "newwalk.c3d"
    res = run(walk, "-m", "linear,pca", "-n", "2", "-s", "1")
    assert res.exit_code == 0, res.output
    assert "best by mean RMSE: none (no method scored any hidden sample)" in res.stderr
    assert "best by mean RMSE: linear" not in res.stderr
    rows = list(csv.DictReader(io.StringIO(run(walk, "-m", "linear,pca", "-n", "2", "-s", "1", "--csv", "-q").stdout)))
    assert len(rows) == 4 and all(r["rmse"] == "" and r["unfilled"] == r["n_scored"] for r in rows)
    doc = json.loads(run(walk, "-m", "linear,pca", "-n", "2", "-s", "1", "--json", "-q").stdout)
    assert all(doc["summary"][m]["rmse"]["mean"] is None for m in ("linear", "pca"))


def test_every_method_failing_every_trial_is_an_error(clip):
    """A table of failures exits 1 (it said 0); one method that scores is a result; --jobs is checked."""
    res = run(clip, "-m", "msvd", "-n", "2", "-s", "1", "-o", "max_iter=-5")
    assert res.exit_code == 1 and "every method failed on every trial; nothing was scored" in res.stderr
    assert "max_iter must be >= 0" in res.stderr and "Traceback" not in res.output
    assert run(clip, "-m", "msvd,linear", "-n", "1", "-s", "1", "-o", "max_iter=-5", "-q").exit_code == 0
    jobs = run(clip, "-m", "linear", "-n", "1", "--jobs", "-3")
    assert jobs.exit_code == 2 and "-3 is not in the range x>=0" in jobs.output


def test_methods_given_twice_are_both_run(clip):
    res = run(clip, "-m", "linear", "-m", "spline,linear", "-n", "1", "-s", "1", "--csv", "-q")
    assert res.exit_code == 0, res.output
    assert [r["method"] for r in csv.DictReader(io.StringIO(res.stdout))] == ["linear", "spline"]


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


def test_option_of_the_wrong_type_is_one_line_naming_it(clip, tmp_path):
    """``-o max_iter=abc`` reached dynammo as a string (a TypeError in its loop): refused before the file is read,
    naming the option as typed; numbers stay numbers, and a method that ignores the option does not judge it."""
    absent = tmp_path / "absent.c3d"  # not read: the options are checked first
    for option, wanted in (("max_iter=abc", "an integer for max_iter"), ("max-iter=2.5", "an integer for max_iter"),
                           ("tol=fast", "a number for tol"), ("energy=yes", "a number or none for energy")):
        res = run(absent, "-m", "linear,dynammo", "-n", "2", "-s", "1", "-o", option)
        assert res.exit_code == 1, res.output
        assert res.stderr.strip().splitlines() == [f"Error: -o {option}: method 'dynammo' takes {wanted}"]
    res = run(clip, "-m", "linear,dynammo", "-n", "1", "-s", "1", "--occlusion-max", "20", "-o", "max_iter=3",
              "-o", "tol=1e-3", "-o", "energy=none", "--json", "-q")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["settings"]["options"] == {"max_iter": 3, "tol": 0.001, "energy": None}


def test_evaluate_checks_option_types_in_python(sample_data):
    import mocapfill
    from mocapfill.errors import MethodError
    from mocapfill.evaluation import evaluate

    data = mocapfill.read(sample_data / "85_02.c3d")
    with pytest.raises(MethodError, match=r"option max_iter='abc': method 'msvd' takes an integer for max_iter"):
        evaluate(data, ["msvd"], trials=1, seed=1, options={"max_iter": "abc"})


def test_ignored_option_is_a_warning_not_an_error(clip):
    res = run(clip, "-m", "linear", "-n", "1", "-s", "0", "-o", "max_iter=5")
    assert res.exit_code == 0, res.output
    assert "'linear' ignores option(s): max_iter" in res.stderr
