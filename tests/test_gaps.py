import numpy as np
import pytest

from mocapfill.gaps import all_missing_markers, blackout_frames, find_gaps, members, missing_mask, runs, unique_rows


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


@pytest.mark.parametrize("shape", [(0, 4), (1, 1), (6, 0), (200, 7), (300, 64), (300, 65), (400, 130)])
def test_unique_rows_is_numpys_row_unique(shape):
    """unique_rows (packed words) returns what np.unique(axis=0) does: the patterns in order, inverse and counts;
    members lists each pattern's rows in ascending order."""
    rng = np.random.default_rng(shape[1])
    for density in (0.0, 0.1, 0.5, 1.0):
        mask = rng.random(shape) < density
        mask[::3] = mask[:1]  # repeated rows
        want = np.unique(mask, axis=0, return_inverse=True, return_counts=True)
        got = unique_rows(mask)
        assert np.array_equal(got[0], want[0])
        assert np.array_equal(got[1], np.ravel(want[1]))
        assert np.array_equal(got[2], want[2])
        for g, rows in enumerate(members(got[1], len(got[0]))):
            assert np.array_equal(rows, np.flatnonzero(got[1] == g))
