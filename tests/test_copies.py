"""Markers that are exact copies of another (guards/copies.py): the default fills them once."""

from __future__ import annotations

import numpy as np

from mocapfill.bones.boneset import BoneSet
from mocapfill.guards.copies import bones_on_distinct, distinct_markers
from mocapfill.methods.auto import fill_auto
from synthetic import moving_body, rot_z


def _with_copies():
    truth = moving_body(240, 8, seed=3, rotation=lambda t: rot_z(0.7 * t))
    pos = truth.copy()
    pos[60:90, 2] = np.nan
    pos[150:170, 5] = np.nan
    pos[100:104, 6] = np.nan
    # markers 8 and 9 repeat 2 (gaps included), 10 repeats 5
    return truth, np.concatenate([pos, pos[:, [2, 2, 5]]], axis=1)


def test_distinct_markers_finds_bit_identical_trajectories():
    _, pos = _with_copies()
    keep, source = distinct_markers(pos)
    assert keep.tolist() == list(range(8))
    assert source.tolist() == list(range(8)) + [2, 2, 5]
    shifted = pos.copy()
    shifted[0, 9, 0] += 1e-9  # one sample apart: no copy
    assert distinct_markers(shifted)[1].tolist() == list(range(8)) + [2, 8, 5]


def test_copies_are_filled_once_and_reported_under_their_own_labels():
    _, pos = _with_copies()
    labels = [f"M{i}" for i in range(8)] + ["M2_copy", "M2_again", "M5_copy"]
    both = fill_auto(pos, labels=labels, rate=100.0)
    alone = fill_auto(pos[:, :8], labels=labels[:8], rate=100.0)
    source = [*range(8), 2, 2, 5]
    assert np.array_equal(both.positions, alone.positions[:, source], equal_nan=True)
    assert np.array_equal(both.std, alone.std[:, source], equal_nan=True)
    gaps = both.info["gap_methods"]
    assert [(g["marker"], g["start"]) for g in gaps] == [("M2", 60), ("M5", 150), ("M6", 100), ("M2_copy", 60),
                                                         ("M2_again", 60), ("M5_copy", 150)]
    assert [g["marker_index"] for g in gaps] == [2, 5, 6, 8, 9, 10]
    assert both.info["review"] == [i for i, g in enumerate(gaps) if g["review"]]
    assert both.info["copies"] == [{"marker": "M2_copy", "marker_index": 8, "copy_of": "M2"},
                                   {"marker": "M2_again", "marker_index": 9, "copy_of": "M2"},
                                   {"marker": "M5_copy", "marker_index": 10, "copy_of": "M5"}]
    assert "copies" not in alone.info


def test_bones_move_onto_the_distinct_markers():
    bones = BoneSet(np.array([[0, 1], [0, 8], [2, 8], [1, 10], [1, 5]]), np.array([1.0, 2.0, 3.0, 4.0, 5.0]),
                    np.ones(5), np.full(5, 10), "mm")
    moved = bones_on_distinct(bones, np.array([*range(8), 2, 2, 5]))
    assert moved.pairs.tolist() == [[0, 1], [0, 2], [1, 5]]  # 2-8 joins two copies; 1-10 repeats 1-5
    assert moved.lengths.tolist() == [1.0, 2.0, 4.0]


def test_markers_missing_throughout_are_no_copies():
    _, pos = _with_copies()
    pos[:, 3] = np.nan
    pos[:, 4] = np.nan
    keep, source = distinct_markers(pos)
    assert 3 in keep and 4 in keep


def test_info_names_the_copies(tmp_path):
    from click.testing import CliRunner

    from mocapfill.cli import cli
    from mocapfill.io import write
    from mocapfill.markers import MarkerData
    from mocapfill.summary import summarize

    _, pos = _with_copies()
    labels = [f"M{i}" for i in range(8)] + ["M2_copy", "M2_again", "M5_copy"]
    data = MarkerData(pos, labels, 100.0, "mm")
    assert summarize(data)["copies"] == [{"marker": "M2_copy", "copy_of": "M2"}, {"marker": "M2_again", "copy_of": "M2"},
                                         {"marker": "M5_copy", "copy_of": "M5"}]
    path = tmp_path / "copies.trc"
    write(data, path)
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 0, result.output
    assert "3 markers repeat another's samples exactly" in result.output


def test_fill_says_which_markers_were_copies(tmp_path):
    from click.testing import CliRunner

    from mocapfill.cli import cli
    from mocapfill.io import write
    from mocapfill.markers import MarkerData

    _, pos = _with_copies()
    labels = [f"M{i}" for i in range(8)] + ["M2_copy", "M2_again", "M5_copy"]
    path = tmp_path / "copies.trc"
    write(MarkerData(pos, labels, 100.0, "mm"), path)
    result = CliRunner().invoke(cli, ["fill", str(path), str(tmp_path / "out.trc")])
    assert result.exit_code == 0, result.output
    assert "3 markers are exact copies of another, filled once and copied: M2_copy = M2" in result.output
    assert "M2_copy 60" not in result.output  # a review line names a gap once, under the original
    assert "taken from an exact copy" not in result.output
    pos[100:130, 9] = np.nan  # hidden in one copy only: its twins keep it
    write(MarkerData(pos, labels, 100.0, "mm"), path)
    result = CliRunner().invoke(cli, ["fill", str(path), str(tmp_path / "out.trc")])
    assert result.exit_code == 0, result.output
    # (a TRC's frames count from 1)
    assert "30 samples taken from an exact copy observed there: M2_again 101-130" in result.output


def test_evaluate_hides_copies_together_and_scores_each_error_once():
    from mocapfill.evaluation.runner import copies_hidden_together

    truth, pos = _with_copies()
    clean = np.concatenate([truth, truth[:, [2, 2, 5]]], axis=1)
    hidden = np.zeros(clean.shape[:2], dtype=bool)
    hidden[10:20, 8] = True  # a copy of marker 2 only
    hidden[30:35, 5] = True  # marker 5 only
    corrupted = clean.copy()
    corrupted[hidden] = np.nan
    shifted = np.zeros_like(hidden)
    out, scored_hidden, scored_shifted = copies_hidden_together(clean, corrupted, hidden, shifted)
    missing = np.isnan(out).any(axis=2)
    assert missing[10:20][:, [2, 8, 9]].all() and missing[30:35][:, [5, 10]].all()
    assert np.array_equal(np.flatnonzero(scored_hidden.any(axis=0)), [2, 5])  # each error counted once
    assert scored_hidden.sum() == 15 and not scored_shifted.any()
    plain = clean[:, :8]
    same = copies_hidden_together(plain, plain, hidden[:, :8], shifted[:, :8])
    assert same[0] is plain and same[1] is not None


def test_many_renamed_duplicate_labels_make_one_note():
    from mocapfill.cli.common import grouped_notes

    notes = [f"duplicate label 'M{i}' renamed 'M{i}_2'" for i in range(5)] + ["file truncated"]
    assert grouped_notes(notes) == ["5 duplicate labels renamed: 'M0' -> 'M0_2', 'M1' -> 'M1_2', 'M2' -> 'M2_2', "
                                    "... (all in the report)", "file truncated"]
    assert grouped_notes(notes[:2]) == notes[:2]


def test_copies_whose_gaps_differ_lend_each_other_their_samples():
    from mocapfill.guards.copies import lent_by_copies

    _, pos = _with_copies()
    pos[10:40, 8] = np.nan  # M2's first copy misses frames where M2 and its other copy are seen
    pos[75:80, 9] = np.nan  # inside 60-89, which all three miss: nothing to lend there
    lending, lent, lenders = lent_by_copies(pos)
    assert np.flatnonzero(lent.any(axis=0)).tolist() == [8]
    assert lent[:, 8].sum() == 30
    assert np.array_equal(lending[:, 8], pos[:, 2], equal_nan=True)
    assert set(lenders) == {(8, 2)}
    shifted = pos.copy()
    shifted[5, 9, 0] += 1e-9  # one co-observed sample apart: no copy of 2, lends nothing, borrows nothing
    assert not lent_by_copies(shifted)[1][:, 9].any()
    few = pos.copy()
    few[:, 10] = np.nan
    few[:8, 10] = pos[:8, 5]  # eight shared frames only: not enough to call them copies
    assert not lent_by_copies(few)[1][:, [5, 10]].any()


def test_a_copy_fills_its_twins_gap_exactly_and_says_so():
    truth, pos = _with_copies()
    labels = [f"M{i}" for i in range(8)] + ["M2_copy", "M2_again", "M5_copy"]
    pos[100:130, 9] = np.nan  # hidden in one copy only: M2 and M2_copy keep it
    pos[20:50, 2] = np.nan  # and in the original, M2_copy and M2_again keep it
    out = fill_auto(pos, labels=labels, rate=100.0)
    observed = ~np.isnan(pos).any(axis=2)
    assert np.array_equal(out.positions[observed], pos[observed])
    assert np.array_equal(out.positions[100:130, 9], truth[100:130, 2])
    assert np.array_equal(out.positions[20:50, 2], truth[20:50, 2])
    assert np.all(out.std[100:130, 9] == 0) and np.all(out.std[20:50, 2] == 0)
    copied = [(g["marker"], g["start"], g["length"]) for g in out.info["gap_methods"] if g["method"] == "copy"]
    assert copied == [("M2", 20, 30), ("M2_again", 100, 30)]
    assert {"marker": "M2", "marker_index": 2, "copy": "M2_copy"} in out.info["lent"]
    starts = [(g["marker_index"], g["start"]) for g in out.info["gap_methods"]]
    assert starts == sorted(starts)
    from mocapfill.markers import MarkerData
    from mocapfill.summary import summarize

    assert summarize(MarkerData(pos, labels, 100.0, "mm"))["copies"][:2] == [
        {"marker": "M2_copy", "copy_of": "M2"}, {"marker": "M2_again", "copy_of": "M2"}]
    # the gap all three miss is the model's, as before
    assert any(g["marker"] == "M2" and g["start"] == 60 and g["method"] != "copy" for g in out.info["gap_methods"])



def test_a_gap_a_copy_fills_in_part_has_one_record():
    truth, pos = _with_copies()
    labels = [f"M{i}" for i in range(8)] + ["M2_copy", "M2_again", "M5_copy"]
    pos[100:130, 2] = np.nan
    pos[115:140, 8] = pos[115:140, 9] = np.nan  # the copies see 100-114 only: a copy lends those, the model the rest
    out = fill_auto(pos, labels=labels, rate=100.0)
    mine = [g for g in out.info["gap_methods"]
            if g["marker"] == "M2" and g["start"] < 140 and g["start"] + g["length"] > 100]
    assert len(mine) == 1 and (mine[0]["start"], mine[0]["length"]) == (100, 30)
    assert mine[0]["method"].startswith("copy+")
    assert mine[0]["reason"].startswith("frames 100-114: taken from its exact copy")
    assert np.array_equal(out.positions[100:115, 2], truth[100:115, 2])

def test_evaluation_hides_a_sample_in_every_copy_whose_gaps_differ():
    from mocapfill.evaluation.runner import copies_hidden_together

    truth, pos = _with_copies()
    clean = pos.copy()
    clean[10:40, 8] = np.nan  # the capture's own copies: M2_copy misses frames M2 keeps
    hidden = np.zeros(clean.shape[:2], dtype=bool)
    hidden[200:210, 8] = True
    corrupted = clean.copy()
    corrupted[hidden] = np.nan
    corrupted, scored, _ = copies_hidden_together(clean, corrupted, hidden, np.zeros_like(hidden))
    assert np.isnan(corrupted[200:210][:, [2, 8, 9]]).all()  # no twin gives it away
    assert scored[200:210, 2].all() and scored.sum() == 10  # scored once, on the first copy
