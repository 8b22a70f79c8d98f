"""Evaluation: protocols, replayed specs, metrics, determinism, serial == parallel."""

from __future__ import annotations

import json
import sys
import types

import numpy as np
import pytest

import mocapfill
from mocapfill.errors import MethodError, MocapfillError
from mocapfill.markers import MarkerData
from mocapfill.evaluation import (EvaluationResult, Occlusion, Trial, evaluate, gap_range, load_spec,
                                make_occlusions, parse_length, save_spec, score, spec_of, trials_from_spec)
from mocapfill.methods import METHODS, MethodSpec
from mocapfill.methods.base import finish

METRIC_FIELDS = ("rmse", "max_error", "mse", "bone_error", "n_scored", "unfilled", "n_iter", "converged", "error")


@pytest.fixture(scope="module")
def clip(sample_data):
    """The CMU clip cropped to 240 frames (2 s) for speed; positions (240, 41, 3) mm."""
    data = mocapfill.read(sample_data / "85_02.c3d")
    return MarkerData(data.positions[:240].copy(), data.labels, data.rate, data.units, data.first_frame,
                      path=data.path)


def _numbers(result: EvaluationResult):
    return [tuple(getattr(s, f) for f in ("trial", "method") + METRIC_FIELDS) for s in result.scores]


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x[:2] == y[:2]
        for u, v in zip(x[2:], y[2:]):
            assert (u == v) or (isinstance(u, float) and np.isnan(u) and np.isnan(v)), (x, y)


# ---------------------------------------------------------------- lengths and protocols

def test_parse_length_forms():
    assert parse_length(40, 810, 120.0) == 40
    assert parse_length("40", 810, 120.0) == 40
    assert parse_length("0.5s", 810, 120.0) == 60
    assert parse_length("10%", 810, 120.0) == 81
    assert parse_length("0.001s", 810, 120.0) == 1
    for bad in ("abc", "-3", "10 parsecs"):
        with pytest.raises(MocapfillError, match="--occlusion-min .*expected frames"):
            parse_length(bad, 810, 120.0, name="--occlusion-min")
    with pytest.raises(MocapfillError, match="must be whole"):
        parse_length("1.5", 810, 120.0)


def test_gap_range_defaults_and_errors():
    assert gap_range("marker", 810, 120.0) == (81, 405)
    assert gap_range("blackout", 810, 120.0) == (6, 30)
    assert gap_range("marker", 100, 120.0, gap_max=500) == (10, 98)  # clipped to fit an interior gap
    with pytest.raises(MocapfillError, match="--occlusion-min 50 .* longer than --occlusion-max 10"):
        gap_range("marker", 810, 120.0, gap_min=50, gap_max=10)
    with pytest.raises(MocapfillError, match="--occlusion-min 900 is 900 frames"):
        gap_range("marker", 810, 120.0, gap_min=900)


@pytest.mark.parametrize("protocol", ["marker", "limb", "blackout", "random"])
def test_protocols_hide_interior_gaps_in_range(clip, protocol):
    trials = make_occlusions(clip, protocol, trials=6, seed=5, gap_min=10, gap_max=40)
    assert len(trials) == 6
    n_frames, n_markers = clip.positions.shape[:2]
    for trial in trials:
        assert trial.occlusions
        for occ in trial.occlusions:
            assert 10 <= occ.length <= 40 and occ.start >= 1 and occ.stop <= n_frames - 1
        hidden = trial.hidden_mask(n_frames, n_markers)
        if protocol == "marker":
            assert len(trial.occlusions) == 1 and len(trial.occlusions[0].markers) == 1
        if protocol == "limb":
            assert len(trial.occlusions[0].markers) == 2
        if protocol == "blackout":
            assert hidden[trial.occlusions[0].start].all()
        if protocol != "random":
            assert not trial.shifts
    if protocol == "random":
        assert any(t.shifts for t in trials)
        shifted = [t.shift_field(n_frames, n_markers) for t in trials]
        assert max(np.abs(s).max() for s in shifted) <= 500.0  # 50 cm in mm


def test_limb_protocol_hides_rigid_neighbours(clip):
    short = [label.split(":")[-1] for label in clip.labels]
    knee = short.index("RKNE")
    chains = [t.occlusions[0].markers for t in make_occlusions(clip, "limb", trials=40, seed=0, limb_size=3)]
    assert all(len(c) == 3 for c in chains)
    # Wherever the right knee is in a chain, its partners are leg markers, never a hand or the head.
    leg = {"RTHI", "RKNE", "RSHN", "RANK", "RHEE", "RTOE", "RMT5", "RFWT", "RBWT", "LKNE"}
    for chain in chains:
        if knee in chain:
            assert {short[m] for m in chain} <= leg


def test_occlusions_are_seeded_per_trial(clip):
    a = make_occlusions(clip, "random", trials=5, seed=11)
    assert make_occlusions(clip, "random", trials=5, seed=11) == a
    assert make_occlusions(clip, "random", trials=3, seed=11) == a[:3]  # a trial does not depend on the count
    assert make_occlusions(clip, "random", trials=5, seed=12) != a


def test_unknown_protocol_and_bad_trials(clip):
    with pytest.raises(MocapfillError, match="unknown protocol 'nope'"):
        make_occlusions(clip, "nope")
    with pytest.raises(MocapfillError, match="at least 1"):
        make_occlusions(clip, "marker", trials=0)


# ---------------------------------------------------------------- replayed specs

def test_replayed_spec_hides_exactly_what_it_names(clip, tmp_path):
    spec = {"format": "mocapfill-occlusions/1", "trials": [
        {"occlusions": [{"markers": ["RKNE", "Male:RSHN"], "first_frame": 25, "length": 66}]},
        {"occlusions": [{"markers": "*", "start": 100, "length": 5},
                        {"marker": "LELB", "first_frame": 11, "length": 3}],
         "shifts": [{"marker": "CLAV", "first_frame": 200, "length": 2, "offset": [1.0, 2.0, 2.0]}]},
    ]}
    trials = trials_from_spec(spec, clip)
    n_frames, n_markers = clip.positions.shape[:2]
    idx = {label.split(":")[-1]: i for i, label in enumerate(clip.labels)}

    expected = np.zeros((n_frames, n_markers), bool)
    expected[24:90, [idx["RKNE"], idx["RSHN"]]] = True  # first_frame 25 in the file's numbering (from 1)
    corrupted, hidden, shifted = trials[0].apply(clip.positions)
    assert np.array_equal(hidden, expected) and not shifted.any()
    assert np.array_equal(np.isnan(corrupted).any(axis=2), expected)

    expected[:] = False
    expected[100:105] = True
    expected[10:13, idx["LELB"]] = True
    corrupted, hidden, shifted = trials[1].apply(clip.positions)
    assert np.array_equal(hidden, expected)
    assert np.flatnonzero(shifted.any(axis=1)).tolist() == [199, 200] and shifted.sum() == 2
    assert np.allclose(corrupted[199, idx["CLAV"]] - clip.positions[199, idx["CLAV"]], [1, 2, 2])

    # Round trip through a file, and through an evaluation's JSON output.
    path = tmp_path / "spec.json"
    save_spec(trials, clip, path)
    assert load_spec(path, clip) == trials
    result = evaluate(clip, ["linear"], occlusions=str(path), seed=0)
    assert result.protocol == "replay" and result.trials == trials
    assert [s.n_scored for s in result.scores] == [132, 5 * n_markers + 3 + 2]
    assert trials_from_spec(json.loads(json.dumps(result.to_dict())), clip) == trials
    # shift error is the displacement when nothing detects it
    assert result.scores[1].max_error == pytest.approx(3.0)


@pytest.mark.parametrize("spec, message", [
    ({"trials": [{"occlusions": [{"markers": ["NOPE"], "first_frame": 5, "length": 3}]}]},
     "trial 1, occlusion 1: no marker called 'NOPE'"),
    ({"trials": [{"occlusions": [{"markers": ["RKNE"], "first_frame": 230, "length": 30}]}]},
     r"frames 230-259 fall outside the clip's frames 1-240"),
    ({"trials": [{"occlusions": [{"markers": ["RKNE"], "first_frame": 5, "length": 0}]}]}, "'length' must be"),
    ({"trials": [{"occlusions": [{"markers": ["RKNE"], "length": 3}]}]}, "needs 'first_frame'"),
    ({"trials": []}, "non-empty list 'trials'"),
    ({"format": "other/2", "trials": []}, "format 'other/2'"),
    ({"trials": [{"occlusions": [], "shifts": [{"marker": "RKNE", "start": 3, "length": 2, "offset": [1, 2]}]}]},
     "'offset' must be three numbers"),
])
def test_bad_specs_name_the_fault(clip, spec, message):
    with pytest.raises(MocapfillError, match=message):
        trials_from_spec(spec, clip, name="spec.json")


def test_bad_spec_files(clip, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(MocapfillError, match=r"bad\.json: not valid JSON \(line 1"):
        load_spec(bad, clip)
    with pytest.raises(MocapfillError, match="no such file"):
        load_spec(tmp_path / "absent.json", clip)


# ---------------------------------------------------------------- metrics

def test_metrics_on_a_known_error():
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(50, 4, 3)) * 100
    hidden = np.zeros((50, 4), bool)
    hidden[10:20, 1] = True
    estimate = truth.copy()
    estimate[hidden] += [3.0, 4.0, 0.0]  # every hidden sample off by 5
    estimate[12, 1] += [0.0, 0.0, 12.0]  # one off by 13
    estimate[19, 1] = np.nan  # one left unfilled
    pairs = np.array([[0, 1], [2, 3]])
    lengths = np.linalg.norm(truth[:, 0] - truth[:, 1], axis=1).mean(), 1.0
    m = score(estimate, truth, hidden, hidden, pairs, np.array(lengths))
    errs = np.array([5.0] * 8 + [13.0])
    assert m["rmse"] == pytest.approx(np.sqrt(np.mean(errs ** 2)))
    assert m["max_error"] == pytest.approx(13.0)
    assert m["mse"] == pytest.approx(np.mean(errs ** 2) / 3)  # Eq. 13: per coordinate
    assert (m["n_scored"], m["unfilled"]) == (10, 1)
    d = np.linalg.norm(estimate[10:19, 0] - estimate[10:19, 1], axis=1)
    assert m["bone_error"] == pytest.approx(np.mean(np.abs(d - lengths[0])))  # bone (2, 3) never hidden
    assert np.isnan(m["error_ratio"])  # no std: no honesty to score
    std = np.full((50, 4), np.nan)
    std[hidden] = 2.0
    m = score(estimate, truth, hidden, hidden, pairs, np.array(lengths), std)
    assert m["error_ratio"] == pytest.approx(np.sqrt(np.mean(errs ** 2) / 3) / 2.0)  # per coordinate / std


# ---------------------------------------------------------------- the runner

def _stub_module():
    """A registered-method stand-in: linear fill plus seeded noise, an objective, and a failure on demand."""
    from mocapfill.methods.interp import fill_linear

    def fill_stub(positions, *, seed=None, hidden=3, units="mm"):
        base = fill_linear(positions)
        rng = np.random.default_rng(seed)
        missing = np.isnan(positions).any(axis=2)
        if missing.sum() > 2000:
            raise MethodError("stub: too many missing samples")
        est = base.positions + rng.normal(0, 1.0, positions.shape)
        return finish(positions, est, std=np.ones(missing.shape), n_iter=hidden, converged=False,
                      objective=[3.0, 2.0, 1.0], info={"hidden": hidden})

    module = types.ModuleType("mocapfill.methods._test_stub")
    module.fill_stub = fill_stub
    return module


@pytest.fixture
def stub(monkeypatch):
    monkeypatch.setitem(sys.modules, "mocapfill.methods._test_stub", _stub_module())
    monkeypatch.setitem(METHODS, "stub", MethodSpec("stub", "_test_stub:fill_stub", "test stub", True))
    return "stub"


def test_evaluate_gives_the_same_numbers_twice(clip, stub):
    kwargs = dict(trials=4, seed=7, occlusion_min=10, occlusion_max=60)
    a = evaluate(clip, ["linear", "spline", stub], "marker", **kwargs)
    b = evaluate(clip, ["linear", "spline", stub], "marker", **kwargs)
    _same(_numbers(a), _numbers(b))
    assert a.seed == 7 and len(a.scores) == 12
    assert all(s.n_scored > 0 and np.isfinite(s.rmse) for s in a.scores)
    stub_scores = [s for s in a.scores if s.method == "stub"]
    assert all(s.n_iter == 3 and not s.converged for s in stub_scores)
    assert a.summary()["stub"]["not_converged"] == 4
    c = evaluate(clip, ["linear", stub], "marker", trials=4, seed=8, occlusion_min=10, occlusion_max=60)
    assert _numbers(c) != _numbers(a)[:8]


def test_method_options_reach_the_method_and_failures_are_recorded(clip, stub):
    result = evaluate(clip, [stub, "linear"], "blackout", trials=2, seed=1, occlusion_min=60, occlusion_max=60,
                      method_options={"stub": {"hidden": 5}})
    stub_scores = [s for s in result.scores if s.method == "stub"]
    assert all(s.error == "stub: too many missing samples" for s in stub_scores)  # 60 x 41 > 2000
    assert all(np.isnan(s.rmse) for s in stub_scores)
    assert result.summary()["stub"]["failures"] == 2
    assert result.win_rates()["linear"]["stub"] == 1.0 and result.best() == "linear"
    ok = evaluate(clip, [stub], "marker", trials=1, seed=1, occlusion_min=5, occlusion_max=5, options={"hidden": 5})
    assert ok.scores[0].n_iter == 5


def test_no_best_method_when_nothing_was_scored(clip, stub, capsys):
    """Every trial failed: no method is best (the first of the unranked ones was named), in the table, the page and
    the JSON."""
    from mocapfill.cli.evaluate import _show
    from mocapfill.report.evaluation_html import render_evaluation_html

    result = evaluate(clip, [stub], "blackout", trials=2, seed=1, occlusion_min=60, occlusion_max=60)
    assert result.summary()["stub"]["failures"] == 2
    assert result.best() is None and result.ranking() == ["stub"]
    _show(result, quiet=False)
    assert "best by mean RMSE: none (no method scored any hidden sample)" in capsys.readouterr().err
    page = render_evaluation_html(result)
    assert "Best by mean RMSE: none (no method scored any hidden sample)." in page
    assert "<th>problems</th>" in page and "2 failed" in page  # the page names them, as the table does
    doc = result.to_dict()
    assert doc["summary"]["stub"]["rmse"] == {"mean": None, "median": None} and "best" not in json.dumps(doc)


def test_unknown_method_and_ignored_options(clip):
    with pytest.raises(MethodError, match="unknown method 'nope'"):
        evaluate(clip, ["linear", "nope"], trials=1, seed=0)
    with pytest.warns(UserWarning, match="'linear' ignores option.*max_iter"):
        evaluate(clip, ["linear"], trials=1, seed=0, options={"max_iter": 5})


@pytest.mark.slow
def test_serial_and_parallel_agree(clip):
    kwargs = dict(trials=4, seed=3, occlusion_min=20, occlusion_max=80)
    serial = evaluate(clip, ["linear", "spline"], "limb", jobs=1, **kwargs)
    parallel = evaluate(clip, ["linear", "spline"], "limb", jobs=2, **kwargs)
    _same(_numbers(serial), _numbers(parallel))
    assert serial.trials == parallel.trials


def test_summary_win_rates_and_outputs(clip):
    result = evaluate(clip, ["linear", "spline"], "blackout", trials=5, seed=2)
    vals = result.values("rmse")
    assert vals.shape == (5, 2)
    s = result.summary()
    assert s["linear"]["rmse"]["mean"] == pytest.approx(vals[:, 0].mean())
    assert s["spline"]["rmse"]["median"] == pytest.approx(np.median(vals[:, 1]))
    rates = result.win_rates()
    assert rates["linear"]["spline"] + rates["spline"]["linear"] == pytest.approx(1.0)
    assert rates["spline"]["linear"] == pytest.approx(np.mean(vals[:, 1] < vals[:, 0]))
    doc = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert doc["schema"] == "mocapfill-evaluation/1" and len(doc["trials"]) == 5
    assert set(doc["trials"][0]["scores"]) == {"linear", "spline"}
    rows = result.to_csv().splitlines()
    assert rows[0].startswith("trial,method,markers,first_frame,length,n_scored,rmse") and len(rows) == 11
    assert spec_of(result.trials, clip)["trials"][0]["occlusions"][0]["markers"] == "*"


def test_random_protocol_scores_shifted_samples(clip):
    result = evaluate(clip, ["linear"], "random", trials=3, seed=4)
    for trial, s in zip(result.trials, result.scores):
        _, hidden, shifted = trial.apply(clip.positions)
        assert s.n_scored == int((hidden | shifted).sum())
    # Shifts are never detected without outlier rejection, so they cost their displacement.
    assert max(s.max_error for s in result.scores) > 100.0


def test_only_observed_samples_are_scored(clip):
    pos = clip.positions.copy()
    pos[50:60, 0] = np.nan
    holey = clip.with_positions(pos)
    trial = Trial((Occlusion((0,), 40, 30),))
    result = evaluate(holey, ["linear"], occlusions=[trial], seed=0)
    assert result.scores[0].n_scored == 20


def test_outlier_rejection_with_the_clean_reference_catches_shifts(clip):
    pytest.importorskip("mocapfill.guards.outliers")
    plain = evaluate(clip, ["linear"], "random", trials=2, seed=4)
    cleaned = evaluate(clip, ["linear"], "random", trials=2, seed=4, reject_outliers="clean")
    assert all(s.detected is None for s in plain.scores)
    assert all(s.detected > 0.9 for s in cleaned.scores)
    assert cleaned.summary()["linear"]["rmse"]["mean"] < plain.summary()["linear"]["rmse"]["mean"]
    with pytest.raises(MocapfillError, match="reject_outliers must be"):
        evaluate(clip, ["linear"], "random", trials=1, seed=4, reject_outliers="sometimes")


def test_markers_never_observed_are_not_picked(clip):
    pos = clip.positions.copy()
    pos[:, 1:] = np.nan  # only marker 0 is ever observed
    trials = make_occlusions(clip.with_positions(pos), "marker", trials=5, seed=0, gap_min=5, gap_max=10)
    assert all(t.occlusions[0].markers == (0,) for t in trials)
    with pytest.raises(MocapfillError, match="nothing to hide"):
        make_occlusions(clip.with_positions(np.full_like(pos, np.nan)), "marker", trials=1, seed=0)


def test_progress_and_save_occlusions_before_running(clip, tmp_path):
    calls = []
    path = tmp_path / "trials.json"
    result = evaluate(clip, ["linear"], "marker", trials=3, seed=9, progress=lambda d, t: calls.append((d, t)),
                      save_occlusions=path)
    assert calls == [(0, 3), (1, 3), (2, 3), (3, 3)]
    assert load_spec(path, clip) == result.trials
    assert json.loads(path.read_text())["source"]["seed"] == 9


def test_percent_defaults_are_capped_on_long_takes():
    assert gap_range("marker", 810, 120.0) == (81, 405)  # a short clip: 10 % to 50 %
    assert gap_range("limb", 100_000, 100.0) == (100, 500)  # a long take: 1 s to 5 s
    assert gap_range("marker", 100_000, 100.0, gap_min="10%", gap_max="20%") == (10_000, 20_000)  # as asked


def test_methods_with_a_std_get_their_honesty_scored(clip, stub):
    result = evaluate(clip, [stub, "linear"], "marker", trials=2, seed=3)
    summary = result.summary()
    assert summary[stub]["error_ratio"]["median"] > 0  # the stub says std 1 everywhere
    assert summary["linear"]["error_ratio"]["median"] is None
    rows = result.to_csv().splitlines()
    assert rows[0].endswith(",error,error_ratio") and rows[1].split(",")[-1] != "" and rows[2].endswith(",")
    from mocapfill.report.evaluation_html import render_evaluation_html

    page = render_evaluation_html(result)  # the page scores it too, beside the terminal table
    assert '<th class="num">err/std</th>' in page and "err/std: the RMS error per coordinate" in page
