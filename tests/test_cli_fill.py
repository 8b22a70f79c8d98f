"""`mocapfill fill`: files and pipes, refusal to overwrite the input, usage errors, reports, bones, outliers,
smoothing, one-line warnings."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli



@pytest.fixture()
def runner() -> CliRunner:
    return CliRunner()


@pytest.fixture()
def gappy(sample_data):
    return sample_data / "kinematics_tennis_serve_nan.c3d"


def test_fill_a_c3d_file(runner, gappy, tmp_path):
    out = tmp_path / "filled.c3d"
    result = runner.invoke(cli, ["fill", str(gappy), str(out), "--method", "spline"])
    assert result.exit_code == 0, result.output
    assert result.stdout == ""
    assert "spline" in result.stderr and "filled 145 of 145" in result.stderr and "0 gaps left" in result.stderr
    before, after = mocapfill.read(gappy), mocapfill.read(out)
    assert not after.missing.any()
    seen = ~before.missing
    # The C3D writer stores float32 samples: observed samples round-trip to the same stored values.
    np.testing.assert_array_equal(after.positions[seen], before.positions[seen])


def test_pipe_csv_stdin_to_stdout(runner, gappy, tmp_path):
    data = mocapfill.read(gappy)
    source = tmp_path / "in.csv"
    mocapfill.write(data, source)
    result = runner.invoke(cli, ["fill", "-", "-", "--format", "csv", "--method", "linear"],
                           input=source.read_bytes())
    assert result.exit_code == 0, result.stderr
    back = tmp_path / "back.csv"
    back.write_bytes(result.stdout_bytes)
    filled = mocapfill.read(back)
    assert filled.positions.shape == data.positions.shape and not filled.missing.any()
    assert "filled 145 of 145" in result.stderr and "filled" not in result.stdout.splitlines()[0]


def test_format_that_disagrees_with_the_extension_is_warned_and_written_as_asked(runner, test_data, tmp_path):
    """`-f c3d` into out.csv wrote binary C3D silently, which `info out.csv` then could not read."""
    out = tmp_path / "out.csv"
    result = runner.invoke(cli, ["fill", str(test_data / "T.trc"), str(out), "-f", "c3d", "-m", "linear"])
    assert result.exit_code == 0, result.output
    warned = [line for line in result.stderr.splitlines() if line.startswith("warning")]
    assert warned == [f"warning {out}: --format c3d writes C3D into a .csv file; reading it back will need "
                      "--input-format c3d"]
    assert mocapfill.read(out, format="c3d").n_frames == mocapfill.read(test_data / "T.trc").n_frames
    for name, fmt in (("same.c3d", "c3d"), ("none.dat", "trc")):  # agreeing, or an extension of no format
        result = runner.invoke(cli, ["fill", str(test_data / "T.trc"), str(tmp_path / name), "-f", fmt, "-m",
                                     "linear"])
        assert result.exit_code == 0 and "warning" not in result.stderr, result.output


def test_output_equal_to_input_is_refused_unless_forced(runner, gappy, tmp_path):
    copy = tmp_path / "copy.c3d"
    shutil.copy(gappy, copy)
    result = runner.invoke(cli, ["fill", str(copy), str(copy), "-m", "linear"])
    assert result.exit_code == 1
    assert "same file as the input" in result.stderr and "Traceback" not in result.output
    result = runner.invoke(cli, ["fill", str(copy), str(copy), "-m", "linear", "--force", "-q"])
    assert result.exit_code == 0, result.output
    assert not mocapfill.read(copy).missing.any()


def test_output_through_a_symlink_keeps_the_link(runner, test_data, tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    (real / "target.csv").write_text("old content")
    link = tmp_path / "link.csv"
    link.symlink_to(real / "target.csv")
    result = runner.invoke(cli, ["fill", str(test_data / "T.trc"), str(link), "-m", "linear"])
    assert result.exit_code == 0, result.output
    assert link.is_symlink() and not mocapfill.read(real / "target.csv").missing.any()
    sink = tmp_path / "sink.csv"
    sink.symlink_to(os.devnull)  # a device: written to, not replaced by a file
    result = runner.invoke(cli, ["fill", str(test_data / "T.trc"), str(sink), "-m", "linear"])
    assert result.exit_code == 0, result.output
    assert sink.is_symlink() and os.readlink(sink) == os.devnull
    source = tmp_path / "in.trc"
    shutil.copy(test_data / "T.trc", source)
    to_input = tmp_path / "to_input.trc"
    to_input.symlink_to(source)
    result = runner.invoke(cli, ["fill", str(source), str(to_input), "-m", "linear"])
    assert result.exit_code == 1 and "same file as the input" in result.stderr
    assert source.read_bytes() == (test_data / "T.trc").read_bytes()


@pytest.mark.parametrize("option, name, kind", [("--report", "missing/r.json", "does not exist"),
                                                  ("--status", "missing/s.csv", "does not exist"),
                                                  ("--report", "somedir.json", "is a directory"),
                                                  ("--status", "adir.c3d", "is a directory")])
def test_a_bad_report_or_status_path_fails_before_the_fill(runner, test_data, tmp_path, monkeypatch, option,
                                                           name, kind):
    import mocapfill.pipeline

    monkeypatch.setattr(mocapfill.pipeline, "fill_capture", lambda *a, **k: pytest.fail("the fill ran"))
    for folder in ("somedir.json", "adir.c3d"):
        (tmp_path / folder).mkdir()
    out = tmp_path / "out.csv"
    result = runner.invoke(cli, ["fill", str(test_data / "T.trc"), str(out), "-m", "linear", option,
                                 str(tmp_path / name)])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.stderr.startswith(f"Error: {tmp_path / name}: ") and kind in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and not out.exists()
    bad = tmp_path / "missing" / "out.csv"
    result = runner.invoke(cli, ["fill", str(test_data / "T.trc"), str(bad), "-m", "linear"])
    assert result.exit_code == 1 and "does not exist" in result.stderr


def test_a_failed_status_write_leaves_no_output(runner, test_data, tmp_path, monkeypatch):
    import mocapfill.pipeline
    from mocapfill.errors import InputError

    def refuse(outcome, path):
        raise InputError(f"{path}: cannot write: No space left on device")

    monkeypatch.setattr(mocapfill.pipeline, "write_status_csv", refuse)
    out, report = tmp_path / "out.csv", tmp_path / "r.json"
    result = runner.invoke(cli, ["fill", str(test_data / "T.trc"), str(out), "-m", "linear", "--report",
                                 str(report), "--status", str(tmp_path / "s.csv")])
    assert result.exit_code == 1 and "No space left on device" in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    source = tmp_path / "in.trc"  # under --force the output is the input: a failed status leaves it as it was
    shutil.copy(test_data / "T.trc", source)
    result = runner.invoke(cli, ["fill", str(source), str(source), "-m", "linear", "--force", "--status",
                                 str(tmp_path / "s.csv")])
    assert result.exit_code == 1 and source.read_bytes() == (test_data / "T.trc").read_bytes()


def test_unknown_method_is_a_usage_error(runner, gappy, tmp_path):
    result = runner.invoke(cli, ["fill", str(gappy), str(tmp_path / "o.c3d"), "--method", "magic"])
    assert result.exit_code == 2
    assert "magic" in result.stderr and "spline" in result.stderr


def test_options_without_their_switch_are_usage_errors(runner, gappy, tmp_path):
    out = str(tmp_path / "o.c3d")
    assert runner.invoke(cli, ["fill", str(gappy), out, "--delta", "0.2"]).exit_code == 2
    assert runner.invoke(cli, ["fill", str(gappy), out, "--smooth-window", "9"]).exit_code == 2
    assert runner.invoke(cli, ["fill", str(gappy), out, "--report", str(tmp_path / "r.txt")]).exit_code == 2


def test_missing_input_is_one_line(runner, tmp_path):
    result = runner.invoke(cli, ["fill", str(tmp_path / "nope.c3d"), str(tmp_path / "o.c3d")])
    assert result.exit_code == 1 and "nope.c3d" in result.stderr and "Traceback" not in result.output


def test_json_report_lists_every_gap_with_uncertainty(runner, gappy, tmp_path):
    report = tmp_path / "report.json"
    result = runner.invoke(cli, ["fill", str(gappy), str(tmp_path / "o.c3d"), "-m", "dynammo", "--max-iter", "20",
                                 "--seed", "1", "--report", str(report), "-q"])
    assert result.exit_code == 0, result.output
    doc = json.loads(report.read_text())
    gaps = doc["gaps"]
    assert len(gaps) == 10 and sum(g["length"] for g in gaps) == 145
    for gap in gaps:
        assert {"marker", "first_frame", "length"} <= set(gap)
        assert gap["mean_std"] is not None and gap["mean_std"] >= 0
    assert doc["summary"]["method"] == "dynammo"
    assert doc["summary"]["settings"].get("max_iter") == 20


@pytest.mark.slow
def test_html_report(runner, gappy, tmp_path):
    pytest.importorskip("matplotlib")
    report = tmp_path / "report.html"
    result = runner.invoke(cli, ["fill", str(gappy), str(tmp_path / "o.c3d"), "-m", "spline", "--report",
                                 str(report), "-q"])
    assert result.exit_code == 0, result.output
    text = report.read_text()
    assert text.lstrip().lower().startswith("<!doctype html") and "<svg" in text


def test_convergence_warning_is_one_line(runner, gappy, tmp_path):
    result = runner.invoke(cli, ["fill", str(gappy), str(tmp_path / "o.c3d"), "-m", "dynammo", "--max-iter", "2"])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stderr.splitlines() if "ConvergenceWarning" in line]
    assert len(lines) == 1 and "Traceback" not in result.stderr
    assert "not converged" in result.stderr
    assert lines[0].count("ConvergenceWarning") == 1  # the category once, not again from the message object
    quiet = runner.invoke(cli, ["fill", str(gappy), str(tmp_path / "o2.c3d"), "-m", "dynammo", "--max-iter", "2",
                                "-q"])
    assert quiet.exit_code == 0 and quiet.stderr == ""


def test_bones_option(runner, sample_data, tmp_path):
    from mocapfill.bones import estimate_bones, save_bones

    data = mocapfill.read(sample_data / "85_02.c3d")
    bones = estimate_bones(data.positions, units=data.units, labels=data.labels)
    bones_path = tmp_path / "bones.json"
    save_bones(bones, bones_path, labels=data.labels, units=data.units)
    hidden = data.positions.copy()
    knee = data.labels.index("Male:RKNE")
    hidden[300:400, knee] = np.nan
    source = tmp_path / "hidden.c3d"
    mocapfill.write(data.with_positions(hidden), source)
    report = tmp_path / "r.json"
    result = runner.invoke(cli, ["fill", str(source), str(tmp_path / "o.c3d"), "-m", "bolero-sc", "--max-iter", "10",
                                 "--bones", str(bones_path), "--report", str(report), "-q"])
    assert result.exit_code == 0, result.output
    doc = json.loads(report.read_text())
    assert doc["summary"]["settings"]["bones"] == str(bones_path)
    # the report checks every bone of the file, and lists exactly the knee's bones (the filled marker) with the
    # frames it was filled in and a length error the soft constraints kept small
    assert doc["bones"]["total"] == len(bones)
    knee_bones = {frozenset((data.labels[a], data.labels[b])) for a, b in bones.pairs if knee in (a, b)}
    touching = doc["bones"]["touching_filled"]
    assert knee_bones and {frozenset(t["markers"]) for t in touching} == knee_bones
    for record in touching:
        assert record["filled_frames"] == 100
        assert 0 <= record["mean_error"] <= record["max_error"] < 0.5 * record["length"]
        assert record["mean_error"] < 10.0  # mm
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    result = runner.invoke(cli, ["fill", str(source), str(tmp_path / "o.c3d"), "--bones", str(bad)])
    assert result.exit_code == 1 and "bad.json" in result.stderr


def test_reject_outliers_turns_shifted_samples_into_filled_gaps(runner, sample_data, tmp_path):
    data = mocapfill.read(sample_data / "85_02.c3d")
    corrupted = data.positions.copy()
    marker = data.labels.index("Male:LKNE")
    frames = [200, 350, 500]
    corrupted[frames, marker] += [300.0, 0.0, 0.0]  # 30 cm off in three single frames (the paper's corruption)
    source = tmp_path / "bad.c3d"
    mocapfill.write(data.with_positions(corrupted), source)
    out, report = tmp_path / "o.c3d", tmp_path / "r.json"
    result = runner.invoke(cli, ["fill", str(source), str(out), "-m", "spline", "--reject-outliers", "--report",
                                 str(report)])
    assert result.exit_code == 0, result.output
    assert "outlier samples rejected" in result.stderr
    doc = json.loads(report.read_text())
    assert {(r["marker"], r["frame"] - data.first_frame) for r in doc["rejected"]} >= {
        ("Male:LKNE", f) for f in frames}
    filled = mocapfill.read(out)
    error = np.linalg.norm(filled.positions[frames, marker] - data.positions[frames, marker], axis=-1)
    assert error.max() < 100.0  # the 300 mm shift is gone
    with_ref = runner.invoke(cli, ["fill", str(source), str(tmp_path / "o2.c3d"), "-m", "linear",
                                   "--reject-outliers", "--reference", str(sample_data / "85_02.c3d"),
                                   "--delta", "0.2", "-q"])
    assert with_ref.exit_code == 0, with_ref.output


def test_smooth_changes_observed_samples_and_is_reported(runner, gappy, tmp_path):
    out, report = tmp_path / "o.c3d", tmp_path / "r.json"
    result = runner.invoke(cli, ["fill", str(gappy), str(out), "-m", "spline", "--smooth", "--smooth-window", "7",
                                 "--smooth-order", "2", "--report", str(report)])
    assert result.exit_code == 0, result.output
    assert "output smoothed" in result.stderr
    before, after = mocapfill.read(gappy), mocapfill.read(out)
    seen = ~before.missing
    assert not np.array_equal(after.positions[seen], before.positions[seen])
    change = np.linalg.norm(after.positions[seen] - before.positions[seen], axis=-1)
    assert np.median(change) < 0.001 and change.max() < 0.1  # metres: smoothing (a fast serve), not damage
    doc = json.loads(report.read_text())
    assert doc["summary"].get("smoothed") is True


def test_smooth_window_longer_than_the_take_or_a_stretch_is_said(runner, gappy, tmp_path):
    """A window longer than the take smoothed nothing and said "output smoothed": now one line naming the file and
    the option, before the fill; stretches shorter than the window (left as they are, as before) are named in one
    warning."""
    out = tmp_path / "sm.c3d"
    result = runner.invoke(cli, ["fill", str(gappy), str(out), "-m", "linear", "--smooth", "--smooth-window", "1093"])
    assert result.exit_code == 1, result.output
    assert result.stderr.strip().splitlines() == [f"Error: {gappy}: --smooth-window 1093 is longer than the take "
                                                  "(1092 frames): nothing would be smoothed"]
    assert not out.exists()
    # gaps over 2 frames left missing: RSHO's observed 522-549 (28 frames) is shorter than a 31-frame window
    result = runner.invoke(cli, ["fill", str(gappy), str(out), "-m", "linear", "--smooth", "--smooth-window", "31",
                                 "--max-gap", "2"])
    assert result.exit_code == 0, result.output
    assert (f"warning UserWarning: {gappy}: --smooth left 1 stretch shorter than its 31-frame window unsmoothed: "
            "Derrick:RSHO 522-549") in " ".join(result.stderr.split())
    before, after = mocapfill.read(gappy), mocapfill.read(out)
    rsho = before.labels.index("Derrick:RSHO")
    np.testing.assert_array_equal(after.positions[521:549, rsho], before.positions[521:549, rsho])
    result = runner.invoke(cli, ["fill", str(gappy), str(out), "-m", "linear", "--smooth"])
    assert result.exit_code == 0 and "unsmoothed" not in result.stderr  # every stretch takes the default window


def test_bit_identical_only_where_the_output_format_holds_the_observed_samples(runner, gappy, sample_data, test_data,
                                                                              tmp_path):
    """The summary said "bit-identical" for a TSV (mm to 0.001, converted from metres) and a new C3D (float32): now
    it says how the format stores them, there only; the report's observed_stored says the same."""
    cases = [(gappy, "o.tsv", "converted from m to mm and rounded to the TSV's 0.001 mm"),
             (gappy, "o.c3d", None),  # a rewrite keeps the original's words
             (gappy, "o.trc", None),
             (sample_data / "markers.csv", "o.c3d", "stored as float32 by C3D"),
             (sample_data / "markers.csv", "o.tsv", "rounded to the TSV's 0.001 mm"),
             (test_data / "qtm_JaneDoe_Dynamic_2.tsv", "o.tsv", None)]  # already on the TSV's grid
    for src, name, stored in cases:
        out, report = tmp_path / name, tmp_path / "r.json"
        result = runner.invoke(cli, ["fill", str(src), str(out), "-m", "linear", "--report", str(report)])
        assert result.exit_code == 0, result.output
        line = ("observed samples returned bit-identical" if stored is None else
                f"observed samples returned as the output format stores them: {stored}")
        assert line in " ".join(result.stderr.split()), (src, name)
        assert json.loads(report.read_text())["summary"]["observed_stored"] == stored
        if stored is None:
            before, after = mocapfill.read(src), mocapfill.read(out)
            seen = ~before.missing
            assert np.array_equal(after.positions[seen], before.positions[seen])
    result = runner.invoke(cli, ["fill", str(gappy), str(tmp_path / "s.tsv"), "-m", "linear", "--smooth"])
    assert "observed samples changed by: --smooth" in result.stderr and "stores them" not in result.stderr


def test_storage_change_judges_the_numbers():
    from mocapfill.io import storage_change
    from mocapfill.markers import MarkerData

    on_grid = np.round(np.random.default_rng(0).normal(0, 500, (20, 2, 3)), 3)
    data = MarkerData(on_grid, ["A", "B"], 100.0, "mm")
    assert storage_change(data, "x.tsv") is None and storage_change(data, "x.csv") is None
    assert storage_change(data, "x.c3d") == "stored as float32 by C3D"
    off = data.with_positions(on_grid + 1e-4)
    assert storage_change(off, "x.tsv") == "rounded to the TSV's 0.001 mm"
    assert storage_change(off, "-", "trc") is None
    halves = data.with_positions(np.round(on_grid * 2) / 2)  # exact in float32
    assert storage_change(halves, "x.c3d") is None
    samples = np.zeros((20, 2), dtype=bool)  # only the samples asked about count
    assert storage_change(off, "x.tsv", samples=samples) is None


def test_every_method_is_offered(runner):
    result = runner.invoke(cli, ["fill", "--help"])
    assert result.exit_code == 0
    for name in mocapfill.methods.METHODS:
        assert name in result.output


def test_never_observed_marker_is_reported_and_left_empty(runner, gappy, tmp_path):
    data = mocapfill.read(gappy)
    pos = data.positions.copy()
    pos[:, 3] = np.nan
    source = tmp_path / "dead.csv"
    mocapfill.write(data.with_positions(pos), source)
    out = tmp_path / "o.csv"
    result = runner.invoke(cli, ["fill", str(source), str(out), "-m", "spline"])
    assert result.exit_code == 0, result.output
    assert "never observed" in result.stderr and data.labels[3] in result.stderr
    filled = mocapfill.read(out)
    assert filled.missing[:, 3].all() and not np.delete(filled.missing, 3, axis=1).any()


def test_report_checks_bones_estimated_from_the_observed_frames(runner, gappy, tmp_path):
    report = tmp_path / "r.json"
    result = runner.invoke(cli, ["fill", str(gappy), str(tmp_path / "o.c3d"), "-m", "spline", "--report",
                                 str(report), "-q"])
    assert result.exit_code == 0, result.output
    checked = json.loads(report.read_text())["bones"]
    # the bones are the ones the input's observed frames give, and the report lists each that touches a filled
    # sample, with the frames where either end was filled
    from mocapfill.bones import estimate_bones

    data = mocapfill.read(gappy)
    bones = estimate_bones(data.positions, units=data.units, labels=data.labels)
    assert checked["total"] == len(bones) > 0
    missing = data.missing
    expected = {frozenset((data.labels[a], data.labels[b])): int((missing[:, a] | missing[:, b]).sum())
                for a, b in bones.pairs if (missing[:, a] | missing[:, b]).any()}
    assert expected and {frozenset(t["markers"]): t["filled_frames"] for t in checked["touching_filled"]} == expected


def test_summary_names_the_gaps_to_review(runner, tmp_path):
    # A marker that moves on its own (no neighbour predicts it) vanishes for 1.5 s: the default bridges it by its
    # motion alone, its posterior sd grows, and the summary says to check that gap.
    rng = np.random.default_rng(0)
    pos = np.cumsum(rng.normal(0, 5, (300, 5, 3)), axis=0) + rng.normal(0, 300, (1, 5, 3))
    pos[100:250, 2] = np.nan
    src = tmp_path / "wander.csv"
    mocapfill.write(mocapfill.MarkerData(pos, [f"M{i}" for i in range(5)], 100.0, "mm", 1), src)
    report = tmp_path / "r.json"
    result = runner.invoke(cli, ["fill", str(src), str(tmp_path / "out.csv"), "--report", str(report)])
    assert result.exit_code == 0, result.output
    assert "review 1 gap" in result.stderr and "M2 101-250" in result.stderr
    doc = json.loads(report.read_text())
    assert doc["summary"]["review_gaps"] == 1 and [g["review"] for g in doc["gaps"]] == [True]


def test_gaps_left_missing_are_not_listed_for_review(runner, tmp_path):
    # The same wandering marker's gap, now longer than --max-gap, and a marker never observed: both are left missing
    # and listed as such; neither has a fill to check, so neither is listed (or reported) for review.
    rng = np.random.default_rng(0)
    pos = np.cumsum(rng.normal(0, 5, (300, 5, 3)), axis=0) + rng.normal(0, 300, (1, 5, 3))
    pos[100:250, 2] = np.nan
    pos[:, 4] = np.nan
    src = tmp_path / "wander.csv"
    mocapfill.write(mocapfill.MarkerData(pos, [f"M{i}" for i in range(5)], 100.0, "mm", 1), src)
    report = tmp_path / "r.json"
    result = runner.invoke(cli, ["fill", str(src), str(tmp_path / "out.csv"), "--max-gap", "50", "--report",
                                 str(report)])
    assert result.exit_code == 0, result.output
    assert "M2 101-250" in result.stderr and "never observed, left empty: M4" in result.stderr
    assert "review" not in result.stderr
    doc = json.loads(report.read_text())
    assert doc["summary"]["review_gaps"] == 0 and not any(g["review"] for g in doc["gaps"])
