"""Reference takes (issue 26): matching by label, units, static trials, weights, and their use by every stage."""

from __future__ import annotations

import json
from pathlib import Path
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.errors import DataWarning, MocapfillError
from mocapfill.markers import MarkerData
from mocapfill.references import (MIN_WEIGHT, ReferenceError, is_static, match_reference, outlier_frames,
                                  pair_length_differences, prepare, shape_difference, training_frames)


@pytest.fixture(scope="module")
def cmu(sample_data):
    return mocapfill.read(sample_data / "85_02.c3d")


def test_matched_by_label_in_any_order_without_prefix_and_converted(cmu):
    order = np.random.default_rng(0).permutation(cmu.n_markers)
    ref_labels = [cmu.labels[k].split(":")[-1] for k in order]  # no "Male:" prefix, shuffled
    ref = match_reference(cmu.labels, "mm", cmu.positions[:50, order] / 1000.0, ref_labels, "m", name="r.c3d")
    assert ref.shared == list(cmu.labels) and not ref.lacking
    np.testing.assert_allclose(ref.positions, cmu.positions[:50], atol=1e-9)


def test_unmatched_markers_are_named(cmu):
    with pytest.warns(DataWarning, match=r"r\.c3d: lacks 2 of the capture's markers \(Male:LFWT, Male:RFWT\)"):
        ref = match_reference(cmu.labels, "mm", cmu.positions[:20, 2:], cmu.labels[2:], "mm", name="r.c3d")
    assert np.isnan(ref.positions[:, :2]).all()
    with pytest.raises(ReferenceError, match=r"^other\.c3d: shares 2 marker label\(s\) with the capture"):
        match_reference(cmu.labels, "mm", cmu.positions[:20, :2], ["LFWT", "RFWT"], "mm", name="other.c3d")


def test_a_marker_the_reference_never_shows_is_one_it_lacks(cmu):
    ref_positions = cmu.positions[:20].copy()
    ref_positions[:, :2] = np.nan  # labelled, never observed
    with pytest.warns(DataWarning, match=r"r\.c3d: lacks 2 of the capture's markers \(Male:LFWT, Male:RFWT\)"):
        ref = match_reference(cmu.labels, "mm", ref_positions, cmu.labels, "mm", name="r.c3d")
    assert ref.lacking == ["Male:LFWT", "Male:RFWT"] and len(ref.shared) == cmu.n_markers - 2
    with pytest.warns(DataWarning, match=r"empty\.c3d: lacks 41 of the capture's markers .*; it shows none of them"):
        (empty,) = prepare(cmu, [MarkerData(np.full((20, cmu.n_markers, 3), np.nan), list(cmu.labels), 120.0, "mm",
                                             path="empty.c3d")])
    training_frames([empty])
    assert empty.weight == 0
    assert empty.stages["fill"] == "not used: no marker pair to compare its body with the capture's by"


def test_a_static_trial_is_recognised(cmu):
    rng = np.random.default_rng(1)
    static = cmu.positions[:1].repeat(200, axis=0) + rng.normal(scale=2.0, size=(200, cmu.n_markers, 3))
    assert is_static(static, "mm") and is_static(static / 1000.0, "m")
    assert not is_static(cmu.positions, "mm")


def test_weights_follow_the_body(halves, sample_data):
    first, second = halves
    serve = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")  # another lab, subject and unit (metres)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        same, other = prepare(first, [second, serve])
    assert same.weight > 0.3 and other.weight < MIN_WEIGHT
    frames, weights = training_frames([same, other])
    assert len(frames) == second.n_frames and np.all(weights == same.weight)
    assert other.stages["fill"].startswith("not used")


def test_a_few_pairs_off_do_not_leave_a_static_trial_out(cmu, halves):
    """A static trial whose toe sits 300 mm off (in a standing take, the two feet's pairs look rigid and differ so
    from the trial's stance): three of the compared pairs 100-300 mm off made an RMS of 53 mm and a weight of ~0;
    the median keeps the weight of the trial without them."""
    first, _ = halves
    static = cmu.positions[500:501].repeat(100, axis=0)
    moved = static.copy()
    moved[:, cmu.labels.index("Male:RTOE")] += [300.0, 0.0, 0.0]
    diff = pair_length_differences(first.positions, moved)
    assert (np.abs(diff) > 100).sum() >= 3 and np.sqrt(np.mean(diff ** 2)) > 40
    plain, off = prepare(first, [MarkerData(x, list(cmu.labels), cmu.rate, cmu.units, path=name)
                                 for name, x in (("static", static), ("moved", moved))])
    assert plain.static and off.static
    assert 0.25 < plain.weight and off.weight > 0.8 * plain.weight
    assert off.shape_difference == pytest.approx(shape_difference(first.positions, moved))


def test_another_take_widens_the_outlier_ranges_it_does_not_replace_them(halves):
    """Another take of the subject did not pose every pose of this one: its ranges alone rejected 1,315 of this clean
    half's samples (16_07 against 16_08: 7,120 of 17,302); with the take's own ranges beside them, no more than the
    take alone rejects.  Markers not chosen are not touched."""
    from mocapfill.pipeline import FillSettings, fill_capture

    first, second = halves
    settings = FillSettings(method="linear", reject_outliers=True).check()
    alone = fill_capture(first, settings)
    widened = fill_capture(first, settings, reference=[second])
    assert widened.rejected.sum() <= alone.rejected.sum() <= 5
    assert widened.references[0].stages["reject_outliers"].endswith("give the distance ranges")
    chosen = FillSettings(method="linear", reject_outliers=True, markers="Male:LKNE").check()
    one = fill_capture(first, chosen, reference=[second])
    others = [k for k, label in enumerate(first.labels) if label != "Male:LKNE"]
    assert not one.rejected[:, others].any()
    assert np.array_equal(one.output.positions[:, others], first.positions[:, others])


def test_static_trial_gives_shape_but_no_outlier_ranges(halves):
    first, second = halves
    static = MarkerData(np.repeat(second.positions[:1], 100, axis=0), list(second.labels), 120.0, "mm", path="st")
    refs = prepare(first, [static, second])
    assert refs[0].static and not refs[1].static
    ranges = outlier_frames(refs)
    assert len(ranges) == second.n_frames
    assert refs[0].stages["reject_outliers"].startswith("not used: a static trial")


@pytest.mark.accuracy
def test_references_make_the_default_and_pca_better(halves):
    from mocapfill.evaluation.occlusions import make_occlusions

    first, second = halves
    trial = make_occlusions(first, "dense", trials=1, seed=2, missing=0.2)[0]
    corrupted, hidden, _ = trial.apply(first.positions)
    gappy = first.with_positions(corrupted)

    def rmse(result):
        return np.sqrt(np.mean(((result.positions - first.positions)[hidden]) ** 2) * 3)

    for method in ("pca", "auto"):
        plain = mocapfill.fill(gappy, method)
        with_ref = mocapfill.fill(gappy, method, reference=second)
        assert rmse(with_ref) < 0.7 * rmse(plain), method
        assert with_ref.info["reference_takes"][0]["name"] == "second"
        observed = ~np.isnan(corrupted).any(axis=2)
        assert np.array_equal(with_ref.positions[observed], corrupted[observed])


def test_reference_frames_argument_checks_its_shape(halves):
    first, _ = halves
    with pytest.raises(MocapfillError, match="reference_frames must have shape"):
        mocapfill.fill(first.positions, "auto", reference_frames=np.zeros((5, 3, 3)))


def test_cli_repeatable_reference_and_report(halves, sample_data, tmp_path):
    first, second = halves
    gappy = first.positions.copy()
    gappy[100:160, 5] = np.nan
    gappy[200:230, 20] = np.nan
    src, ref = tmp_path / "take.c3d", tmp_path / "other_take.csv"
    mocapfill.write(MarkerData(gappy, list(first.labels), 120.0, "mm"), src)
    mocapfill.write(second, ref)
    report = tmp_path / "r.json"
    result = CliRunner().invoke(cli, ["fill", str(src), str(tmp_path / "o.c3d"), "-m", "pca", "--reference",
                                      str(ref), "--reference", str(sample_data / "kinematics_tennis_serve.c3d"),
                                      "--reject-outliers", "--report", str(report)])
    assert result.exit_code == 0, result.output
    assert "reference " in result.stderr and "weight" in result.stderr
    assert "lacks" in result.stderr  # the tennis serve's marker set differs: named on one line
    refs = json.loads(report.read_text())["summary"]["settings"]["references"]
    assert [r["frames"] for r in refs] == [second.n_frames, 1092]
    assert refs[0]["stages"]["fill"].startswith(f"{second.n_frames} frames train")
    assert refs[0]["stages"]["reject_outliers"].endswith("give the distance ranges")
    assert refs[1]["weight"] < MIN_WEIGHT



def test_cli_fills_a_marker_the_take_never_shows_from_a_reference(halves, tmp_path):
    first, second = halves
    j = first.labels.index("Male:LFRM")
    take = first.positions.copy()
    take[:, j] = np.nan
    src, ref, out = tmp_path / "take.c3d", tmp_path / "static.c3d", tmp_path / "o.c3d"
    mocapfill.write(MarkerData(take, list(first.labels), 120.0, "mm"), src)
    mocapfill.write(second, ref)
    alone = CliRunner().invoke(cli, ["fill", str(src), str(out)])
    assert alone.exit_code == 0 and "never observed, left empty: Male:LFRM" in alone.stderr
    helped = CliRunner().invoke(cli, ["fill", str(src), str(out), "--force", "--reference", str(ref)])
    assert helped.exit_code == 0 and "never observed" not in helped.stderr, helped.stderr
    filled = mocapfill.read(out).positions[:, j]
    err = np.linalg.norm(filled - first.positions[:, j], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 15.0


def test_a_reference_too_short_to_learn_a_marker_from_is_named_in_its_record(halves):
    """A static trial of 5 frames shows the marker the take never does, but no model learns from 5 frames: the record
    says so (it had said no reference showed it), and the reference's own line is still true of the other models."""
    first, second = halves
    j = first.labels.index("Male:LFRM")
    take = first.positions.copy()
    take[:, j] = np.nan
    take[100:140, 3] = np.nan
    short = MarkerData(second.positions[:5].copy(), list(first.labels), 120.0, "mm", path="static")
    result = mocapfill.fill(MarkerData(take, list(first.labels), 120.0, "mm"), "auto", reference=short)
    (rec,) = [r for r in result.info["gap_methods"] if r["marker_index"] == j]
    assert rec["method"] == "none" and rec["review"]
    assert "the reference takes show it in 5 frame(s), fewer than the 20 a model cross-validates on" in rec["reason"]
    assert result.info["reference_takes"][0]["stages"]["fill"].startswith("5 frames train the body model")


def test_evaluate_refuses_the_test_capture_and_labels_the_oracle(halves):
    first, second = halves
    with pytest.raises(MocapfillError, match="is the test capture itself"):
        mocapfill.evaluate(first, ["linear"], "marker", trials=1, seed=0, reference=[first])
    # the same take in metres, its labels without the subject's prefix, in another marker order
    order = np.arange(first.n_markers)[::-1]
    exported = MarkerData(np.round(first.positions[:, order] / 1000.0, 7), [first.labels[k].split(":")[-1]
                          for k in order], 120.0, "m", path="exported.trc")
    with pytest.raises(MocapfillError, match="exported.trc is the test capture itself"):
        mocapfill.evaluate(first, ["linear"], "marker", trials=1, seed=0, reference=[exported])
    # the take the test capture was cut from, in metres: it holds the truth too
    whole = MarkerData(np.concatenate([second.positions[::-1], first.positions]) / 1000.0, list(first.labels), 120.0,
                       "m", path="whole.c3d")
    with pytest.raises(MocapfillError, match="whole.c3d holds the test capture's frames"):
        mocapfill.evaluate(first, ["linear"], "marker", trials=1, seed=0, reference=[whole])
    result = mocapfill.evaluate(first, ["pca"], "marker", trials=1, seed=0, reference=[second],
                                reject_outliers="clean")
    assert result.settings["oracle"] is True and result.settings["references"] == ["second"]
    from mocapfill.report.evaluation_html import render_evaluation_html

    assert "ORACLE: the outlier ranges came from the clean file itself" in render_evaluation_html(result)


def test_evaluate_says_how_much_each_method_used_each_reference(halves, sample_data):
    from mocapfill.evaluation import reference_words

    first, second = halves
    serve = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        result = mocapfill.evaluate(first, ["pca", "linear"], "marker", trials=2, seed=0, reference=[second, serve])
    use = result.summary()["pca"]["references"]
    (weights,) = [w for name, w in use["weights"].items() if name == "second"]
    assert 0.3 < weights["min"] <= weights["max"] <= 1
    assert max(w["max"] for name, w in use["weights"].items() if name != "second") < MIN_WEIGHT
    assert "references" not in result.summary()["linear"]  # a method that takes none
    assert result.to_dict()["trials"][0]["scores"]["pca"]["references"]["weights"]["second"] >= weights["min"]
    assert "(not used: its body differs)" in reference_words(use)
    from mocapfill.report.evaluation_html import render_evaluation_html

    page = render_evaluation_html(result)
    assert "Reference takes: second, " in page and "pca: second weight" in page and "ORACLE" not in page
    auto = {"weights": {"a": {"min": 0.5, "max": 0.5}}, "models": 10, "used": 4}
    assert reference_words(auto) == "a weight 0.50; kept by 4 of the 10 local models it fitted over the trials"


def session_folder(first, tmp_path) -> Path:
    """A folder holding one take: the capture with one 40-frame gap."""
    folder = tmp_path / "session"
    folder.mkdir()
    gappy = first.positions.copy()
    gappy[100:140, 7] = np.nan
    mocapfill.write(MarkerData(gappy, list(first.labels), 120.0, "mm"), folder / "take.c3d")
    return folder


def test_batch_hands_references_to_every_file(halves, tmp_path):
    first, second = halves
    folder = session_folder(first, tmp_path)
    ref = tmp_path / "static.csv"
    mocapfill.write(MarkerData(np.repeat(second.positions[:1], 60, axis=0), list(first.labels), 120.0, "mm"), ref)
    rows = mocapfill.batch(folder, tmp_path / "out", method="pca", reference=[str(ref)], report="json")
    assert [r.status for r in rows] == ["filled"], rows[0].error
    doc = json.loads(Path(rows[0].report).read_text())
    (record,) = doc["summary"]["settings"]["references"]
    assert record["static"] and record["frames"] == 60
    assert rows[0].references == f"{ref} {record['weight']:.2f}"


def test_a_reference_that_does_not_match_one_input_fails_that_input_by_name(halves, tmp_path):
    first, second = halves
    folder = session_folder(first, tmp_path)
    mocapfill.write(MarkerData(first.positions, [f"X{k}" for k in range(first.n_markers)], 120.0, "mm"),
                    folder / "other.c3d")
    mocapfill.write(second, tmp_path / "second.c3d")
    rows = mocapfill.batch(folder, tmp_path / "out", method="linear", reference=[str(tmp_path / "second.c3d")])
    (bad,) = [row for row in rows if row.status == "failed"]
    assert bad.error.startswith(f"{folder / 'other.c3d'}: reference {tmp_path / 'second.c3d'}: shares 0 marker label")
    assert [row.status for row in rows].count("filled") == 1


def test_fill_refuses_stdin_as_both_capture_and_reference(halves, tmp_path):
    result = CliRunner().invoke(cli, ["fill", "-", str(tmp_path / "o.csv"), "--reference", "-"], input="x")
    assert result.exit_code != 0 and "standard input carries the capture" in result.output


def test_batch_refuses_a_shared_file_it_cannot_read_before_it_starts(halves, tmp_path):
    """A --reference, --bones or --model that is not there is the batch's one error, not a failed row per input."""
    first, _ = halves
    folder = session_folder(first, tmp_path)
    junk = tmp_path / "junk.c3d"
    junk.write_bytes(b"junk")
    for option, path, said in (("--reference", tmp_path / "typo.c3d", "no such file"),
                               ("--reference", junk, "not a C3D file"),
                               ("--bones", tmp_path / "typo.json", "no such file")):
        result = CliRunner().invoke(cli, ["batch", str(folder), "-o", str(tmp_path / "out"), option, str(path)])
        assert result.exit_code == 1 and f"{path}: {said}" in result.stderr, result.output
        assert f"({option}, given to every input)" in result.stderr and "Traceback" not in result.output
        assert not (tmp_path / "out").exists()


def read_rows(path: Path) -> list[dict]:
    """The rows of a batch's results table."""
    import csv

    with open(path, encoding="utf-8", newline="") as handle:
        return list(csv.DictReader(handle))


def test_batch_says_which_files_left_a_reference_out(halves, sample_data, tmp_path):
    """The results table has each reference's weight per file; the CLI names a reference some files left out."""
    first, second = halves
    folder = session_folder(first, tmp_path)
    mocapfill.write(second, tmp_path / "second.c3d")
    serve = str(sample_data / "kinematics_tennis_serve.c3d")
    args = ["batch", str(folder), "-o", str(tmp_path / "out"), "-m", "pca", "--reference", serve,
            "--reference", str(tmp_path / "second.c3d")]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert f"reference {serve}: not used for 1 of 1 files" in result.stderr
    (row,) = read_rows(tmp_path / "out" / "mocapfill-batch.csv")
    assert row["references"].startswith(f"{serve} 0.00 not used; ") and not row["references"].endswith("not used")
    linear = CliRunner().invoke(cli, ["batch", str(folder), "-o", str(tmp_path / "lin"), "-m", "linear"] + args[6:])
    assert linear.exit_code == 0 and "not used for 1 of 1 files (the method takes no reference frames" in linear.stderr
    again = CliRunner().invoke(cli, args)  # skipped: the row keeps what the fill said
    (row,) = read_rows(tmp_path / "out" / "mocapfill-batch.csv")
    assert again.exit_code == 0 and row["status"] == "skipped" and "not used" in row["references"]


def test_a_method_without_weights_gets_only_the_well_fitting_references(halves):
    from mocapfill.references import method_options

    first, second = halves
    (ref,) = prepare(first, [second])
    ref.weight = 0.9
    options = method_options([ref], "x", {"reference_frames"})
    assert set(options) == {"reference_frames"} and len(options["reference_frames"]) == second.n_frames
    ref.weight = 0.2
    assert method_options([ref], "x", {"reference_frames"}) == {}
    assert "takes no weights" in ref.stages["fill"]
    assert method_options([ref], "linear", set()) == {} and ref.stages["fill"].startswith("not used: method")


@pytest.mark.accuracy
def test_a_reference_with_gaps_and_a_marker_it_lacks_still_trains_the_default(halves):
    """A session's take has gaps: no frame of this one shows every marker, and it lacks RFIN altogether.  Its gaps
    are completed as predictors (``references.completed_frames``, ``ModelConfig.reference_pca_mm``): it still trains
    the models."""
    from mocapfill.evaluation.occlusions import make_occlusions

    first, second = halves
    corrupted, hidden, _ = make_occlusions(first, "dense", trials=1, seed=3, missing=0.2)[0].apply(first.positions)
    holed, _, _ = make_occlusions(second, "dense", trials=1, seed=7, missing=0.1)[0].apply(second.positions)
    holed[:, first.labels.index("Male:RFIN")] = np.nan
    assert np.isnan(holed).any(axis=(1, 2)).all()
    gappy = first.with_positions(corrupted)

    def rmse(result):
        return np.sqrt(np.mean(((result.positions - first.positions)[hidden]) ** 2) * 3)

    from mocapfill.pipeline import FillSettings, fill_capture

    plain = mocapfill.fill(gappy)
    with pytest.warns(DataWarning, match=r"lacks 1 of the capture's markers \(Male:RFIN\)"):
        outcome = fill_capture(gappy, FillSettings(), reference=[second.with_positions(holed)])
    with_ref, n = outcome.result, int(np.isnan(holed).any(axis=2).sum())
    assert with_ref.info["references"]["used"] > 0 and with_ref.info["references"]["completed"] == n
    assert outcome.references[0].stages["fill"].endswith(f"; the references' {n} missing samples completed as "
                                                         "predictors")
    assert rmse(with_ref) < 0.9 * rmse(plain)  # (17.05 -> 13.83 mm; 17.28 before the references were completed)
    observed = ~np.isnan(corrupted).any(axis=2)
    assert np.array_equal(with_ref.positions[observed], corrupted[observed])


def test_completed_frames_keep_observed_samples_and_fill_a_marker_the_reference_lacks(halves):
    from mocapfill.references import completed_frames

    first, second = halves
    holed = second.positions.copy()
    holed[::3, 5] = np.nan
    holed[:, 7] = np.nan  # lacked by the reference, shown by the capture
    done = completed_frames(first.positions, holed, scale=200.0)
    observed = ~np.isnan(holed)
    assert np.array_equal(done[observed], holed[observed]) and np.isfinite(done).all()
    err = np.linalg.norm(done[:, 7] - second.positions[:, 7], axis=1)
    assert np.median(err) < 30.0  # (mm: a marker it never saw, from the capture's body model)


def test_a_long_takes_reference_use_is_summed_over_its_windows():
    from mocapfill.methods.auto import windows_references

    info = {"windows": [{"start": 0, "stop": 5000, "references": {"frames": 410, "models": 30, "used": 20}},
                        {"start": 4600, "stop": 9000, "references": {"frames": 400, "models": 25, "used": 5}}]}
    windows_references(info, 400)
    assert info["references"] == {"frames": 400, "models": 55, "used": 25}
    assert all("references" not in row for row in info["windows"])
    agreed = {"references": {"frames": 400, "models": 3, "used": 1}, "windows": [{}, {}, {}]}
    windows_references(agreed, 400)  # (the windows agreed: the merge kept one copy)
    assert agreed["references"] == {"frames": 400, "models": 9, "used": 3}


def test_a_reference_holding_the_captures_own_frames_is_left_out(halves, tmp_path):
    """A session's glob as references hands each take to itself: its held-out frames would be in training (an
    oracle's cross-validation, a shrunken sd).  fill leaves it out and says so; batch says per file."""
    first, second = halves
    gappy = first.positions.copy()
    gappy[100:140, 7] = np.nan
    capture = first.with_positions(gappy)
    plain = mocapfill.fill(capture)
    itself = mocapfill.fill(capture, reference=[first])  # the complete take it was cut from
    (record,) = itself.info["reference_takes"]
    assert record["weight"] == 0.0 and record["stages"]["fill"].startswith("not used: it holds the capture's own")
    assert np.array_equal(itself.positions, plain.positions, equal_nan=True)
    folder = session_folder(first, tmp_path)
    mocapfill.write(second, folder / "other.c3d")
    args = ["batch", str(folder), "-o", str(tmp_path / "out"), "--reference", str(folder / "take.c3d"),
            "--reference", str(folder / "other.c3d")]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    rows = {Path(row["input"]).name: row for row in read_rows(tmp_path / "out" / "mocapfill-batch.csv")}
    assert rows["take.c3d"]["references"].startswith(f"{folder / 'take.c3d'} 0.00 not used: the file itself; ")
    assert rows["other.c3d"]["references"].endswith(f"{folder / 'other.c3d'} 0.00 not used: the file itself")
    assert "not used for 1 of 2 files (it is the file itself, or holds its frames" in result.stderr
