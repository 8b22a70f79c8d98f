"""The technician's controls (issue 25): --max-gap, --edges, --min-fragment, --markers / --exclude, --status, and
which options may change observed samples; on small real files."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.errors import MethodError, MocapfillError
from mocapfill.gaps import find_gaps
from mocapfill.guards.fragments import short_fragments
from mocapfill.guards.limits import leave_reasons, parse_max_gap
from mocapfill.markers import MarkerData
from mocapfill.pipeline import FillSettings, fill_capture, sample_status, select_markers
from mocapfill.status import NAMES, Status


@pytest.fixture()
def runner() -> CliRunner:
    return CliRunner()


@pytest.fixture(scope="module")
def gappy(sample_data):
    """markers.csv: 580 frames x 51 markers at 100 Hz, 34 interior gaps of 1-71 frames, fragments between some."""
    return sample_data / "markers.csv"


@pytest.fixture(scope="module")
def gappy_data(gappy):
    return mocapfill.read(gappy)


def _fill(runner, source, out, *options):
    result = runner.invoke(cli, ["fill", str(source), str(out), "-m", "linear", *options])
    assert result.exit_code == 0, result.output
    return result


def _one_line_error(result, *words):
    assert result.exit_code == 1, result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: ") and "Traceback" not in result.output, result.stderr
    for word in words:
        assert word in lines[0], lines[0]


# ------------------------------------------------------------------------------------------------------ --max-gap

def test_parse_max_gap():
    assert parse_max_gap(40, 100.0) == 40 and parse_max_gap("40", None) == 40
    assert parse_max_gap("0.5s", 120.0) == 60 and parse_max_gap("0.001s", 100.0) == 1
    for bad in ("ten", "1.5", "0", "-3", "10%"):
        with pytest.raises(MethodError, match="--max-gap"):
            parse_max_gap(bad, 100.0)
    with pytest.raises(MethodError, match="no frame rate"):
        parse_max_gap("0.5s", float("nan"))


def test_a_gap_above_max_gap_is_untouched_and_reported(runner, gappy, gappy_data, tmp_path):
    out, report, status = tmp_path / "out.csv", tmp_path / "r.json", tmp_path / "s.csv"
    result = _fill(runner, gappy, out, "--max-gap", "0.2s", "--report", str(report), "--status", str(status))
    data, filled = gappy_data, mocapfill.read(out)
    seen = ~data.missing
    np.testing.assert_array_equal(filled.positions[seen], data.positions[seen])  # bit-identical
    long_gaps = [g for g in find_gaps(data.missing) if g.length > 20]
    assert sorted(g.length for g in long_gaps) == [27, 45, 71]
    left = np.zeros_like(data.missing)
    for g in long_gaps:
        left[g.start:g.stop, g.marker] = True
    np.testing.assert_array_equal(filled.missing, left)  # exactly the long gaps stay missing, all else filled
    assert "left missing (too long): 3 gaps" in result.stderr and "Daphnee:SCAP_CP 340-410" in result.stderr
    rep = json.loads(report.read_text())
    assert rep["summary"]["left_missing_gaps"] == 3 and rep["summary"]["left_missing_samples"] == int(left.sum())
    assert rep["summary"]["settings"]["max_gap"] == {"given": "0.2s", "frames": 20}
    listed = {(g["marker"], g["first_frame"], g["length"], g["reason"]) for g in rep["left_missing"]}
    assert ("Daphnee:SCAP_CP", 340, 71, "left missing (too long)") in listed and len(listed) == 3
    assert sum(1 for g in rep["gaps"] if g["left"]) == 3
    assert rep["summary"]["observed_changed"] == []
    rows = list(csv.DictReader(status.open()))
    by_key = {(int(r["frame"]), r["marker"]): r["status"] for r in rows}
    assert by_key[(340, "Daphnee:SCAP_CP")] == "left missing (too long)"
    assert by_key[(318, "Daphnee:SCAP_CP")] == "filled" and by_key[(1, "Daphnee:SCAP_CP")] == "observed"


def test_max_gap_in_python_and_html(gappy_data, tmp_path, monkeypatch):
    result = mocapfill.fill(gappy_data, "linear", max_gap=20)
    assert len(result.info["left_missing"]) == 3
    assert {r["reason"] for r in result.info["left_missing"]} == {"left missing (too long)"}
    assert not result.filled[np.isnan(result.positions).any(axis=2)].any()
    bare = mocapfill.fill(gappy_data.positions, "linear", max_gap="0.2s", rate=100.0)
    np.testing.assert_array_equal(bare.positions, result.positions)
    outcome = fill_capture(gappy_data, FillSettings(method="linear", max_gap="0.2s"))
    from mocapfill.pipeline import write_fill_report

    pytest.importorskip("matplotlib")
    from mocapfill.report import plots

    # the page's text is what is checked here: its 53 plots (7 s of matplotlib) are tested in test_report.py
    for name in ("trajectory_svg", "bone_svg"):
        monkeypatch.setattr(plots, name, lambda *args, **kwargs: "<svg></svg>")
    html = tmp_path / "r.html"
    write_fill_report(outcome, str(html), method="linear", input_path="in.csv", output_path="out.csv",
                      smoothed=False)
    text = html.read_text()
    assert "Left missing as asked (3 gaps)" in text and "left missing (too long)" in text



def test_a_gap_left_missing_is_recorded_as_not_filled():
    from mocapfill.guards.limits import apply_limits
    from mocapfill.methods.base import FillResult

    missing = np.zeros((60, 2), bool)
    missing[5:10, 0] = missing[20:50, 1] = True
    records = [{"marker": "a", "marker_index": 0, "start": 5, "length": 5, "method": "local-pca+motion",
                "reason": "local weighted PCA predicted 100% of the frames", "review": False, "max_std": 1.0},
               {"marker": "b", "marker_index": 1, "start": 20, "length": 30, "method": "local-pca+motion",
                "reason": "local weighted PCA predicted 100% of the frames", "review": True, "max_std": 40.0,
                "extrapolation": 2.0}]
    result = FillResult(np.zeros((60, 2, 3)), missing.copy(), np.where(missing, 1.0, 0.0),
                        info={"gap_methods": records, "review": [1]})
    left, _ = apply_limits(result, missing, max_gap=10)
    kept, gone = left.info["gap_methods"]
    assert kept == records[0]  # the gap filled keeps its record
    assert gone["method"] == "none" and gone["reason"] == "left missing (too long): not filled"
    assert gone["review"] is False and gone["max_std"] is None and "extrapolation" not in gone
    assert left.info["review"] == [] and records[1]["method"] == "local-pca+motion"  # (the input left as it was)

def test_max_gap_in_batch(gappy, tmp_path):
    rows = mocapfill.batch([str(gappy)], tmp_path / "out", method="linear", max_gap=20, status=True)
    assert rows[0].status == "filled" and rows[0].left_samples == 143
    out = mocapfill.read(rows[0].output)
    assert int(out.missing.sum()) == 143
    statuses = [r["status"] for r in csv.DictReader(open(rows[0].status_csv))]
    assert statuses.count("left missing (too long)") == 143


def test_evaluate_measures_what_max_gap_costs(sample_data, runner):
    clip = mocapfill.read(sample_data / "85_02.c3d")
    free = mocapfill.evaluate(clip, ["linear"], "marker", trials=3, seed=2, occlusion_min=30, occlusion_max=30)
    capped = mocapfill.evaluate(clip, ["linear"], "marker", trials=3, seed=2, occlusion_min=30, occlusion_max=30,
                                max_gap=29)
    assert all(s.unfilled == 0 for s in free.scores)
    assert all(s.unfilled == s.n_scored == 30 for s in capped.scores)
    assert capped.settings["max_gap_frames"] == 29
    with pytest.raises(MocapfillError, match="gap_min are now occlusion_min"):
        mocapfill.evaluate(clip, ["linear"], "marker", trials=1, seed=1, gap_min=10)
    res = runner.invoke(cli, ["evaluate", str(sample_data / "85_02.c3d"), "-m", "linear", "-n", "2", "-s", "1",
                              "--occlusion-min", "30", "--occlusion-max", "30", "--max-gap", "0.2s"])
    assert res.exit_code == 0, res.output
    assert "left missing by the limits: linear 60 of 60 (100.0 %)" in res.stderr


@pytest.mark.parametrize("old,new", [("--gap-min", "--occlusion-min"), ("--gap-max", "--occlusion-max")])
def test_old_evaluate_gap_options_name_the_new_ones(runner, sample_data, old, new):
    res = runner.invoke(cli, ["evaluate", str(sample_data / "85_02.c3d"), "-m", "linear", old, "10"])
    _one_line_error(res, old, new)


def test_malformed_max_gap_is_one_line(runner, gappy, tmp_path):
    _one_line_error(runner.invoke(cli, ["fill", str(gappy), str(tmp_path / "o.csv"), "--max-gap", "1.5"]),
                    "--max-gap '1.5'")


# -------------------------------------------------------------------------------------------------------- --edges

def test_edges_fill_or_leave(runner, test_data, tmp_path):
    source = test_data / "qtm_JaneDoe_Dynamic_2.tsv"  # one gap, the last 7 frames
    data = mocapfill.read(source)
    (gap,) = find_gaps(data.missing)
    assert gap.at_end and gap.length == 7
    report = tmp_path / "r.json"
    _fill(runner, source, tmp_path / "a.tsv", "--report", str(report))
    rep = json.loads(report.read_text())
    assert rep["summary"]["edges"] == "fill" and rep["summary"]["edge_gaps_filled"] == 1
    assert not mocapfill.read(tmp_path / "a.tsv").missing.any()
    result = _fill(runner, source, tmp_path / "b.tsv", "--edges", "leave", "--report", str(report))
    rep = json.loads(report.read_text())
    assert rep["summary"]["edges"] == "leave" and rep["summary"]["edge_gaps_left"] == 1
    assert rep["left_missing"][0]["reason"] == "left missing (at an edge)" and rep["left_missing"][0]["length"] == 7
    after = mocapfill.read(tmp_path / "b.tsv")
    np.testing.assert_array_equal(after.missing, data.missing)
    np.testing.assert_array_equal(after.positions[~data.missing], data.positions[~data.missing])
    assert "left missing (at an edge): 1 gaps" in result.stderr and "edges: leave" in result.stderr


def test_leave_reasons_precedence():
    missing = np.zeros((20, 3), dtype=bool)
    missing[:8, 0] = True  # at the start and long
    missing[5:15, 1] = True  # interior, long
    missing[18:, 2] = True  # at the end, short
    reasons = leave_reasons(missing, max_gap=5, edges="leave", chosen=np.array([True, True, False]))
    assert set(reasons[:8, 0]) == {Status.MISSING_EDGE}
    assert set(reasons[5:15, 1]) == {Status.MISSING_TOO_LONG}
    assert set(reasons[18:, 2]) == {Status.MISSING_NOT_CHOSEN}
    assert (reasons[~missing] == 0).all()


def test_a_marker_never_observed_is_left_by_no_limit():
    # Missing in every frame: no --max-gap or --edges left it, nothing could fill it; it stays MISSING (reported as
    # never observed), not "too long" or "at an edge" as well
    missing = np.zeros((20, 2), dtype=bool)
    missing[:, 0] = True
    missing[5:15, 1] = True
    for edges in ("fill", "leave"):
        reasons = leave_reasons(missing, max_gap=5, edges=edges)
        assert (reasons[:, 0] == 0).all() and set(reasons[5:15, 1]) == {Status.MISSING_TOO_LONG}


# -------------------------------------------------------------------------------------------------- --min-fragment

def test_short_fragments():
    missing = np.zeros((12, 1), dtype=bool)
    missing[[2, 3, 5, 8], 0] = True  # observed: 0-1 (edge), 4 (1 frame), 6-7 (2 frames), 9-11 (edge)
    np.testing.assert_array_equal(np.flatnonzero(short_fragments(missing, 2)[:, 0]), [4])
    np.testing.assert_array_equal(np.flatnonzero(short_fragments(missing, 3)[:, 0]), [4, 6, 7])
    assert not short_fragments(missing, 1).any()


def test_min_fragment_fills_over_fragments_and_says_so(runner, gappy, gappy_data, tmp_path):
    data = gappy_data
    fragments = short_fragments(data.missing, 3)
    assert fragments.sum() == 18
    out, report, status = tmp_path / "out.csv", tmp_path / "r.json", tmp_path / "s.csv"
    result = _fill(runner, gappy, out, "--min-fragment", "3", "--report", str(report), "--status", str(status))
    after = mocapfill.read(out)
    keep = ~data.missing & ~fragments
    np.testing.assert_array_equal(after.positions[keep], data.positions[keep])
    assert not after.missing.any() and (after.positions[fragments] != data.positions[fragments]).any()
    rep = json.loads(report.read_text())
    assert rep["summary"]["fragment_samples"] == 18 and rep["summary"]["fragments"] == rep["summary"]["settings"][
        "min_fragment"]["fragments"] > 0
    assert rep["summary"]["observed_changed"] == ["--min-fragment (18 samples)"]
    assert "observed samples changed by: --min-fragment (18 samples)" in result.stderr
    codes = [r["status"] for r in csv.DictReader(status.open())]
    assert codes.count("rejected (fragment)") == 18


def test_a_fragment_joining_a_gap_left_missing_is_kept(gappy_data):
    data = gappy_data
    sterr = data.labels.index("Daphnee:STERr")  # gaps 237+16 and 255+16 around a 2-frame fragment
    joined = FillSettings(method="linear", min_fragment=3, max_gap=20)
    outcome = fill_capture(data, joined)
    assert not outcome.fragments[:, sterr].any()  # 34 frames joined would be too long: fragment kept as observed
    np.testing.assert_array_equal(outcome.output.positions[253:255, sterr], data.positions[253:255, sterr])
    assert outcome.fragments.sum() > 0  # others still dropped
    roomy = fill_capture(data, FillSettings(method="linear", min_fragment=3, max_gap=40))
    assert roomy.fragments[253:255, sterr].all() and np.isfinite(roomy.output.positions[237:271, sterr]).all()


# ----------------------------------------------------------------------------------------- --markers / --exclude

def test_select_markers_patterns_prefixes_and_kinds():
    labels = ["Sub:LASI", "Sub:RASI", "Sub:LKNE", "Sub:RKNE", "Sub:LKneeAngles", "*unlabelled1"]
    kinds = ["marker"] * 4 + ["model", "unlabelled"]
    assert select_markers(labels, kinds).tolist() == [True] * 4 + [False, False]
    assert select_markers(labels, kinds, "L*").tolist() == [True, False, True, False, False, False]
    assert select_markers(labels, kinds, "Sub:L*").tolist() == select_markers(labels, kinds, "L*").tolist()
    assert select_markers(labels, kinds, "LKneeAngles, RASI").tolist() == [False, True, False, False, True, False]
    assert select_markers(labels, kinds, "*unlabelled1").tolist() == [False] * 5 + [True]  # a name, though a '*'
    with pytest.raises(MethodError, match="pattern '\\*Angles' matches no marker"):  # a pattern: markers only
        select_markers(labels, kinds, "*Angles")
    assert select_markers(labels, kinds, exclude="?KNE").tolist() == [True, True, False, False, False, False]
    assert select_markers(labels, kinds, ["[LR]ASI"], exclude="R*").tolist() == [True] + [False] * 5
    with pytest.raises(MethodError, match=r"no marker called 'LKEN'; near: LKNE"):
        select_markers(labels, kinds, "LKEN", path="t.c3d")
    with pytest.raises(MethodError, match="pattern 'Q\\*' matches no marker"):
        select_markers(labels, kinds, "Q*")
    with pytest.warns(UserWarning, match="pattern 'Q\\*' matches no marker"):  # one of several: said, not fatal
        assert select_markers(labels, kinds, "L*,Q*").tolist() == [True, False, True, False, False, False]
    with pytest.raises(MethodError, match="leave no marker"):
        select_markers(labels, kinds, "LASI", exclude="L*")


def test_markers_leaves_the_others_gaps_as_they_were(runner, gappy, gappy_data, tmp_path):
    data = gappy_data
    out, status = tmp_path / "out.csv", tmp_path / "s.csv"
    result = _fill(runner, gappy, out, "--markers", "STER*,LASTC", "--status", str(status))
    after = mocapfill.read(out)
    chosen = np.array([label.split(":")[1].startswith("STER") or label.endswith(":LASTC") for label in data.labels])
    assert chosen.sum() == 4
    np.testing.assert_array_equal(after.missing[:, ~chosen], data.missing[:, ~chosen])
    assert not after.missing[:, chosen].any()
    seen = ~data.missing
    np.testing.assert_array_equal(after.positions[seen], data.positions[seen])
    assert "left missing (not chosen)" in result.stderr
    statuses = {r["status"] for r in csv.DictReader(status.open()) if r["marker"] == "Daphnee:MEDH"}
    assert statuses == {"observed", "left missing (not chosen)"}


def test_every_marker_still_informs_the_fill(gappy_data):
    """A method that models all markers together fills a chosen marker as it does without a choice."""
    everything = mocapfill.fill(gappy_data, "pca")
    chosen = mocapfill.fill(gappy_data, "pca", markers="Daphnee:SCAP_CP")
    m = gappy_data.labels.index("Daphnee:SCAP_CP")
    np.testing.assert_array_equal(chosen.positions[:, m], everything.positions[:, m])
    others = np.ones(gappy_data.n_markers, dtype=bool)
    others[m] = False
    np.testing.assert_array_equal(np.isnan(chosen.positions[:, others]), np.isnan(gappy_data.positions[:, others]))


def test_exclude_and_unknown_label_errors(runner, gappy, gappy_data, tmp_path):
    out = tmp_path / "out.csv"
    _fill(runner, gappy, out, "--exclude", "boite:*,LASTC")
    after = mocapfill.read(out)
    left = [label for label in gappy_data.labels if after.missing[:, gappy_data.labels.index(label)].any()]
    assert sorted(left) == sorted(["boite:gauche_ext", "boite:gauche_int", "boite:droite_int", "boite:droite_ext",
                                   "Daphnee:LASTC"])
    res = runner.invoke(cli, ["fill", str(gappy), str(out), "--markers", "LASTX"])
    _one_line_error(res, "--markers", "'LASTX'", "near: LASTC")
    res = runner.invoke(cli, ["fill", str(gappy), str(out), "--exclude", "Z*"])
    _one_line_error(res, "--exclude", "'Z*'")


# ------------------------------------------------------------------------------------- status, and what changes

def test_status_array_and_csv(gappy_data, tmp_path):
    data = gappy_data
    settings = FillSettings(method="linear", max_gap=20, min_fragment=3, exclude="boite:droite_ext")
    outcome = fill_capture(data, settings)
    status = outcome.status
    assert status.shape == data.missing.shape and status.dtype == np.int8
    np.testing.assert_array_equal(status, sample_status(outcome))
    assert (status[~data.missing & ~outcome.fragments] == Status.OBSERVED).all()
    assert (status[outcome.fragments] == Status.REJECTED_FRAGMENT).all()
    m = data.labels.index("boite:droite_ext")
    assert (status[data.missing[:, m], m] == Status.MISSING_NOT_CHOSEN).all()
    assert (status[339:410, data.labels.index("Daphnee:SCAP_CP")] == Status.MISSING_TOO_LONG).all()
    filled = status == Status.FILLED
    assert np.isfinite(outcome.output.positions[filled]).all() and data.missing[filled].all()
    from mocapfill.pipeline import write_status_csv

    path = tmp_path / "s.csv"
    write_status_csv(outcome, str(path))
    rows = list(csv.reader(path.open()))
    assert rows[0] == ["frame", "marker", "status"] and len(rows) == 1 + data.n_frames * data.n_markers
    assert rows[1] == [str(data.first_frame), data.labels[0], "observed"]
    assert rows[1 + 339 * data.n_markers + data.labels.index("Daphnee:SCAP_CP")] == [
        str(data.first_frame + 339), "Daphnee:SCAP_CP", "left missing (too long)"]
    texts = {row[2] for row in rows[1:]}
    assert texts <= set(NAMES.values())


def test_status_of_a_marker_never_observed():
    rng = np.random.default_rng(1)
    positions = np.cumsum(rng.normal(size=(40, 3, 3)), axis=0)
    positions[:, 2] = np.nan  # never observed: nothing fills it without a reference
    positions[10:15, 0] = np.nan
    data = MarkerData(positions, ["A", "B", "C"], 100.0)
    outcome = fill_capture(data, FillSettings(method="linear"))
    assert (outcome.status[:, 2] == Status.MISSING_NEVER_OBSERVED).all()
    assert NAMES[Status.MISSING_NEVER_OBSERVED] == "left missing (never observed)"
    assert (outcome.status[10:15, 0] == Status.FILLED).all()
    chosen = fill_capture(data, FillSettings(method="linear", markers="A,B"))  # a reason given on request wins
    assert (chosen.status[:, 2] == Status.MISSING_NOT_CHOSEN).all()


def test_status_of_model_points_and_unlabelled():
    rng = np.random.default_rng(0)
    positions = np.cumsum(rng.normal(size=(50, 4, 3)), axis=0)
    positions[10:15, :] = np.nan
    data = MarkerData(positions, ["A", "B", "Model", "U1"], 100.0, kinds=["marker", "marker", "model", "unlabelled"])
    outcome = fill_capture(data, FillSettings(method="linear"))
    assert (outcome.status[:, 2] == Status.MODEL_POINT).all() and (outcome.status[:, 3] == Status.UNLABELLED).all()
    assert np.isnan(outcome.output.positions[10:15, 2:]).all()  # kept untouched
    assert (outcome.status[10:15, :2] == Status.FILLED).all()
    named = fill_capture(data, FillSettings(method="linear", markers="A,Model"))  # an exact name reaches a model point
    assert (named.status[10:15, 2] == Status.FILLED).all()
    assert (named.status[10:15, 1] == Status.MISSING_NOT_CHOSEN).all()
    assert (named.status[:, 3] == Status.UNLABELLED).all()
    python = mocapfill.fill(data, "linear", markers="A,Model")  # the same rule in mocapfill.fill
    np.testing.assert_array_equal(python.positions, named.output.positions)
    assert {(r["marker"], r["reason"]) for r in python.info["left_missing"]} == {(1, "left missing (not chosen)")}
    assert np.isnan(mocapfill.fill(data, "linear").positions[10:15, 2:]).all()


@pytest.mark.parametrize("options", [
    {}, {"max_gap": 10}, {"edges": "leave"}, {"markers": "Daphnee:*"}, {"exclude": "*STER*"},
    {"max_gap": "0.1s", "edges": "leave", "exclude": "LASTC"},
])
@pytest.mark.parametrize("method", ["linear", "spline", "pca"])
def test_observed_samples_bit_identical_under_every_other_option(gappy_data, method, options):
    outcome = fill_capture(gappy_data, FillSettings(method=method, **options))
    seen = ~gappy_data.missing
    assert np.array_equal(outcome.output.positions[seen], gappy_data.positions[seen])
    assert outcome.observed_changed() == []
    assert not np.isin(outcome.status, [Status.SMOOTHED, Status.REJECTED_FRAGMENT, Status.REJECTED_OUTLIER]).any()


def test_auto_keeps_observed_samples_under_the_limits(gappy_data):
    outcome = fill_capture(gappy_data, FillSettings(max_gap=15, exclude="boite:*"))
    seen = ~gappy_data.missing
    assert np.array_equal(outcome.output.positions[seen], gappy_data.positions[seen])
    assert (outcome.status[seen] == Status.OBSERVED).all()


@pytest.mark.parametrize("options,said,code", [
    ({"smooth": True}, "--smooth", Status.SMOOTHED), ({"min_fragment": 3}, "--min-fragment", Status.REJECTED_FRAGMENT),
    ({"reject_outliers": True}, "--reject-outliers", Status.REJECTED_OUTLIER),
])
def test_options_that_change_observed_samples_say_so(sample_data, options, said, code):
    data = mocapfill.read(sample_data / "85_02.c3d")
    positions = data.positions.copy()
    knee = data.labels.index("Male:LKNE")
    positions[[200, 350, 500], knee] += [300.0, 0.0, 0.0]  # three outliers
    positions[100:110, knee] = np.nan  # a 2-frame fragment between two gaps
    positions[112:120, knee] = np.nan
    data = data.with_positions(positions)
    outcome = fill_capture(data, FillSettings(method="linear", **options))
    changed = outcome.observed_changed()
    assert len(changed) == 1 and changed[0].startswith(said), changed
    seen = ~data.missing
    moved = seen & (outcome.output.positions != data.positions).any(axis=2)
    assert moved.any() and (outcome.status[moved] == code).all()
    assert (outcome.status[seen & ~moved] == Status.OBSERVED).all()


def test_smooth_touches_only_the_chosen_markers(gappy_data):
    outcome = fill_capture(gappy_data, FillSettings(method="linear", smooth=True, markers="Daphnee:*"))
    boite = [i for i, label in enumerate(gappy_data.labels) if label.startswith("boite:")]
    np.testing.assert_array_equal(outcome.output.positions[:, boite], gappy_data.positions[:, boite])


def test_c3d_keeps_its_residuals_under_max_gap(runner, sample_data, tmp_path):
    source = sample_data / "kinematics_tennis_serve_nan.c3d"  # RSHO: ten gaps of 4-42 frames at 50 Hz
    data = mocapfill.read(source)
    out = tmp_path / "out.c3d"
    result = _fill(runner, source, out, "--max-gap", "0.3s")  # 15 frames: the 23- and 42-frame gaps stay
    after = mocapfill.read(out)
    seen = ~data.missing
    np.testing.assert_array_equal(after.positions[seen], data.positions[seen])
    assert sorted(g.length for g in find_gaps(after.missing)) == [23, 42]
    assert "left missing (too long): 2 gaps" in result.stderr
