import numpy as np

from mocapfill.gaps import all_missing_markers, blackout_frames, find_gaps, missing_mask, runs


def test_runs_finds_every_run_in_order():
    assert runs(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)) == [(1, 2), (4, 1), (7, 1)]
    assert runs(np.zeros(0, bool)) == []
    assert runs(np.ones(3, bool)) == [(0, 3)]


def test_find_gaps_marks_edges():
    missing = np.zeros((6, 2), bool)
    missing[:2, 0] = True
    missing[3, 0] = True
    missing[4:, 1] = True
    gaps = find_gaps(missing)
    assert [(g.marker, g.start, g.length, g.at_start, g.at_end) for g in gaps] == [
        (0, 0, 2, True, False),
        (0, 3, 1, False, False),
        (1, 4, 2, False, True),
    ]
    assert gaps[2].stop == 6


def test_blackouts_and_all_missing_markers():
    positions = np.zeros((4, 3, 3))
    positions[1] = np.nan
    positions[:, 2] = np.nan
    missing = missing_mask(positions)
    assert blackout_frames(missing).tolist() == [1]
    assert all_missing_markers(missing).tolist() == [2]
