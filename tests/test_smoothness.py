"""The acceleration measure of issue 21 (mocapfill.evaluation.smoothness) on hand-made arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mocapfill.evaluation.smoothness import (accelerations, least_max_filled, outcome_smoothness, short_fragments,
                                              smooth_enough, smoothness)


def _track(xs) -> np.ndarray:
    """One marker moving along x: positions (n_frames, 1, 3)."""
    out = np.zeros((len(xs), 1, 3))
    out[:, 0, 0] = xs
    return out


def _mask(pattern: str) -> np.ndarray:
    """(n_frames, 1) bool from 'ooMMo' (M = missing)."""
    return np.array([[c == "M"] for c in pattern])


def test_accelerations_are_the_norm_of_the_second_difference():
    pos = np.zeros((4, 2, 3))
    pos[:, 0] = [[0, 0, 0], [1, 0, 0], [3, 0, 0], [6, 0, 0]]  # second differences (1, 0, 0) twice
    pos[:, 1] = [[0, 0, 0], [0, 3, 4], [0, 0, 0], [0, 0, 0]]  # (0, -6, -8), then (0, 3, 4)
    acc = accelerations(pos)
    assert acc.shape == (2, 2)
    np.testing.assert_allclose(acc, [[1, 10], [1, 5]])
    assert accelerations(np.zeros((2, 3, 3))).shape == (0, 3)


def test_filled_and_observed_split():
    # frames 0..7; frame 4 missing (filled) -> differences centred at 3, 4, 5 are "filled"
    xs = [0, 0, 0, 0, 10, 0, 0, 0]
    s = smoothness(_track(xs), _mask("ooooMooo"))
    assert s.n_filled == 3 and s.n_observed == 3
    assert s.max_filled == 20.0  # 0 - 20 + 0 at frame 4
    assert s.max_observed == 0.0
    assert s.worst_frame == 4 and s.worst_marker == 0
    assert s.filled_samples == 1
    ok, reasons = smooth_enough(s)
    assert not ok and "largest filled" in reasons[0]


def test_an_observed_glitch_sets_the_bound():
    xs = [0, 0, 5, 0, 0, 1, 0, 0]  # an observed glitch of 10 at frame 2; the fill's bump at frame 5 is 2
    s = smoothness(_track(xs), _mask("oooooMoo"))
    assert s.max_observed == 10.0 and s.max_filled == 2.0
    assert smooth_enough(s) == (True, [])
    assert s.ratio_max == pytest.approx(0.2)


@pytest.mark.parametrize("pattern, fragment", [
    ("ooMoMooo", [3]),  # 'MoM': frame 3 is a one-frame fragment
    ("oMooMooo", [2, 3]),  # 'MooM': frames 2-3
])
def test_short_fragments_are_found(pattern, fragment):
    frag = short_fragments(_mask(pattern))
    assert list(np.flatnonzero(frag[:, 0])) == fragment


def test_runs_at_the_edges_and_longer_runs_are_not_fragments():
    assert not short_fragments(_mask("oMooooMoo")).any()  # frame 0 touches the edge; 2-5 is four frames long
    assert not short_fragments(_mask("ooMoooMo")).any()  # three observed frames between gaps
    assert not short_fragments(_mask("Mo")).any()
    assert short_fragments(_mask("MooMoooM"), longest=3)[:, 0].tolist() == [False, True, True, False, True, True,
                                                                            True, False]


def test_differences_touching_a_fragment_are_left_out():
    # 'ooMoMooo': frame 3 is a fragment; the differences centred at 2, 3, 4 involve it and are left out; those at
    # 1 and 5 touch a missing frame only (filled), 6 is observed
    xs = [0, 0, 0, 50, 0, 0, 0, 0]  # the fragment is a glitch: it must not count against the fill
    s = smoothness(_track(xs), _mask("ooMoMooo"))
    assert s.n_fragment == 3
    assert s.n_filled == 2 and s.n_observed == 1
    assert s.max_filled == 0.0
    s_all = smoothness(_track(xs), _mask("ooMoMooo"), longest_fragment=0)
    assert s_all.n_fragment == 0 and s_all.max_filled == 100.0


def test_unfilled_samples_and_selected_points():
    pos = np.concatenate([_track([0, 0, 0, 0, 0]), _track([0, 1, 4, 9, 16])], axis=1)  # second marker: acc 2
    pos[2, 0] = np.nan  # left missing by the fill
    missing = np.zeros((5, 2), dtype=bool)
    missing[2, 0] = True
    s = smoothness(pos, missing)
    assert s.n_unfilled == 3 and s.n_filled == 0 and s.filled_samples == 0
    assert s.max_observed == 2.0 and s.n_observed == 3
    only_first = smoothness(pos, missing, points=np.array([True, False]))
    assert only_first.n_observed == 0 and math.isnan(only_first.max_observed)
    assert smooth_enough(only_first) == (True, [])  # nothing filled: nothing to fail


def test_percentile_rule_needs_enough_filled_samples():
    rng = np.random.default_rng(0)
    n = 3000
    acc = rng.normal(size=n)  # the acceleration centred at frame t is acc[t + 1]
    acc[500] = 20.0  # one observed glitch: it sets the largest observed, not the percentile
    acc[990:2210] = 0.0  # the truth is a straight line through the gap and a little around it
    xs = np.cumsum(np.cumsum(acc))
    missing = np.zeros((n, 1), dtype=bool)
    missing[1000:2200] = True  # 1,200 filled samples
    pos = _track(xs)  # the fill found the truth
    s = smoothness(pos, missing)
    assert s.filled_samples == 1200 and s.n_filled == 1202
    assert s.max_observed == pytest.approx(20.0) and s.max_filled == pytest.approx(0.0, abs=1e-6)
    assert 2.0 < s.p_observed < 5.0
    assert smooth_enough(s) == (True, [])
    # a wobbly fill whose peaks stay under the largest observed but whose 99.9th percentile is high
    wobble = pos.copy()
    wobble[1000:2200, 0, 0] += 9.0 * (np.arange(1200) % 2)  # second differences of 18
    w = smoothness(wobble, missing)
    assert w.max_filled == pytest.approx(18.0) and w.max_filled <= w.max_observed
    assert w.p_filled > 1.5 * w.p_observed
    ok, reasons = smooth_enough(w)
    assert not ok and len(reasons) == 1 and "percentile" in reasons[0]
    assert smooth_enough(w, min_filled=5000) == (True, [])  # too few filled samples for the percentile rule


def test_scaled_and_dict():
    s = smoothness(_track([0, 0, 0, 0, 10, 0, 0, 0]), _mask("ooooMooo"))
    t = s.scaled(1000.0)
    assert t.max_filled == 20000.0 and t.n_filled == s.n_filled
    d = s.to_dict()
    assert d["max_observed"] == 0.0 and d["ratio_max"] is None  # observed max 0: no ratio
    with pytest.raises(ValueError):
        smoothness(np.zeros((5, 2, 3)), np.zeros((5, 3), dtype=bool))


def test_outcome_smoothness_counts_rejected_samples_as_filled_and_measures_markers_only():
    from types import SimpleNamespace

    xs = [0, 0, 0, 0, 10, 0, 0, 0]
    pos = np.concatenate([_track(xs), _track(xs)], axis=1)  # the same spike in a marker and a model point
    data = SimpleNamespace(positions=pos, kinds=["marker", "model"])
    rejected = np.zeros((8, 2), dtype=bool)
    rejected[4] = True  # an outlier rejected and filled again: its spike is the fill's
    outcome = SimpleNamespace(data=data, work=data, output=data, rejected=rejected)
    s = outcome_smoothness(outcome)
    assert s.n_filled == 3 and s.max_filled == 20.0 and s.filled_samples == 1
    outcome.rejected = None  # nothing rejected: the spike is observed
    s = outcome_smoothness(outcome)
    assert s.n_filled == 0 and s.max_observed == 20.0 and s.n_observed == 6


def test_least_max_filled_is_the_linear_programmes_bound():
    """One missing frame between two still stretches 10 mm apart: every fill has a second difference of at least
    5 mm / frame^2 at the gap (|y| and |y - 10| both at most s needs s >= 5); the midpoint reaches it.  A gap at the
    take's edge binds nothing, and a difference that involves a short fragment is left out."""
    x = np.zeros((8, 2, 3))
    x[4:, 0, 0] = 10.0
    x[3, 0] = np.nan
    x[:2, 1] = np.nan  # at the start: extrapolated with no acceleration
    missing = np.isnan(x).any(axis=2)
    least, marker, start = least_max_filled(x, missing)
    assert least == pytest.approx(5.0, abs=1e-7)
    assert (marker, start) == (0, 3)
    filled = x.copy()
    filled[3, 0] = [5.0, 0.0, 0.0]
    filled[:2, 1] = 0.0
    assert smoothness(filled, missing).max_filled == pytest.approx(least)
    # the observed samples after the gap become a fragment (MoM): nothing binds any more
    frag = missing.copy()
    frag[5, 0] = True
    assert least_max_filled(np.where(frag[..., None], np.nan, x), frag)[0] == pytest.approx(0.0, abs=1e-7)
