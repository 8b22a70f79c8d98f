"""Filling a long take in overlapping windows (:mod:`mocapfill.guards.windows`)."""

from __future__ import annotations

import numpy as np
import pytest

import mocapfill
from mocapfill.errors import MethodError
from mocapfill.methods.base import finish
from mocapfill.methods.interp import fill_linear
from mocapfill.methods.pca import fill_pca
from mocapfill.guards.windows import fill_in_windows, window_bounds


@pytest.fixture(scope="module")
def long_take(sample_data):
    """85_02 played forwards and backwards to 3,000 frames, 41 markers, mm."""
    data = mocapfill.read(sample_data / "85_02.c3d")
    cycle = np.concatenate([data.positions, data.positions[-2:0:-1]])
    return np.tile(cycle, (2, 1, 1))[:3000]


def _with_gaps(truth, seed, n_gaps=60, lo=20, hi=120):
    rng = np.random.default_rng(seed)
    pos = truth.copy()
    for _ in range(n_gaps):
        m, length = rng.integers(truth.shape[1]), rng.integers(lo, hi)
        start = rng.integers(1, truth.shape[0] - length - 1)
        pos[start:start + length, m] = np.nan
    return pos


def test_bounds_cover_the_take_with_overlaps_and_prefer_complete_edge_frames():
    missing = np.zeros((10_000, 5), dtype=bool)
    missing[:, 0] = True
    missing[4000:4600:3, 1] = True  # a striped region near the nominal edges: edges move to clean frames
    bounds = window_bounds(missing[:, 1:], window=2000, overlap=200)
    assert bounds[0][0] == 0 and bounds[-1][1] == 10_000
    for (a0, a1), (b0, b1) in zip(bounds, bounds[1:]):
        assert b0 < a1 and a1 - b0 >= 100 and b0 > a0
    for s, e in bounds:
        assert not missing[s, 1] or s == 0
        assert not missing[e - 1, 1] or e == 10_000
    assert window_bounds(missing, 20_000, 200) == [(0, 10_000)]
    with pytest.raises(MethodError):
        window_bounds(missing, 300, 200)


def test_windowed_linear_equals_the_whole_linear_fill(long_take):
    """Linear interpolation needs only each gap's two ends: if every gap is held whole by some window, the windowed
    fill is the whole fill (up to rounding in the blend), including gaps across window edges."""
    pos = _with_gaps(long_take, 0)
    # a gap straddling the first nominal edge (frame 1000 + ...): held whole by the first window only
    pos[880:1010, 7] = np.nan
    whole = fill_linear(pos)
    win = fill_in_windows(pos, fill_linear, window=1000, overlap=200)
    missing = np.isnan(pos).any(axis=2)
    assert np.array_equal(win.positions[~missing], pos[~missing])  # observed: bit-identical
    assert np.array_equal(win.filled, whole.filled)
    np.testing.assert_allclose(win.positions, whole.positions, rtol=0, atol=1e-9)


@pytest.mark.accuracy
def test_windowed_pca_is_as_accurate_and_keeps_per_gap_info(long_take):
    pos = _with_gaps(long_take, 1)
    missing = np.isnan(pos).any(axis=2)
    whole = fill_pca(pos)
    win = fill_in_windows(pos, fill_pca, window=1200, overlap=240)
    assert len(win.info["windows"]) >= 3
    assert np.array_equal(win.positions[~missing], pos[~missing])
    # the blend is a convex combination: no sample is worse than the worst window holding it
    worst = np.zeros(missing.shape)
    for w in win.info["windows"]:
        a, b = w["start"], w["stop"]
        own = fill_pca(pos[a:b]).positions
        worst[a:b] = np.maximum(worst[a:b], np.linalg.norm(own - long_take[a:b], axis=2))
    err = np.linalg.norm(win.positions - long_take, axis=2)
    assert (err[missing] <= worst[missing] + 1e-9).all()
    # windows of 1,200 frames see less of the (repeated) motion than the whole take, yet stay close
    err_whole = np.linalg.norm(whole.positions[missing] - long_take[missing], axis=1)
    assert np.median(err[missing]) <= 2.0 * np.median(err_whole)
    # no jump where windows meet: every filled step stays within what the truth does
    step = np.linalg.norm(np.diff(win.positions, axis=0), axis=2)
    true_step = np.linalg.norm(np.diff(long_take, axis=0), axis=2)
    assert step.max() <= 2 * true_step.max()


def test_gap_info_is_merged_in_take_frames():
    """A toy fill that names each gap: the merged list has one entry per gap of the take, in the take's frames."""
    rng = np.random.default_rng(3)
    truth = np.cumsum(rng.normal(size=(900, 3, 3)), axis=0)
    pos = truth.copy()
    gaps = [(0, 100, 30), (1, 290, 40), (2, 455, 20), (0, 700, 50)]
    for m, s, n in gaps:
        pos[s:s + n, m] = np.nan

    def toy(p):
        res = fill_linear(p)
        from mocapfill.gaps import find_gaps

        res.info = {"gap_methods": [{"marker_index": g.marker, "start": g.start, "length": g.length,
                                     "method": "linear"} for g in find_gaps(np.isnan(p).any(axis=2))],
                    "rank": 3, "frames": float(p[0, 0, 0])}
        res.std = np.where(res.filled, 1.0, 0.0)
        return res

    out = fill_in_windows(pos, toy, window=400, overlap=120)
    got = [(e["marker_index"], e["start"], e["length"]) for e in out.info["gap_methods"]]
    assert got == sorted((m, s, n) for m, s, n in gaps)
    assert out.info["rank"] == 3 and "frames" not in out.info
    assert all("frames" in w and "start" in w for w in out.info["windows"])
    np.testing.assert_allclose(out.std[out.filled], 1.0)
    assert (out.std[~np.isnan(pos).any(axis=2)] == 0).all()



def test_records_follow_the_blended_sd_and_a_marker_no_window_fills_keeps_one():
    """``restate`` sees each merged record with its gap's blended sd (a gap inside two windows' overlap cross-fades
    their fills and sds); a marker no window fills keeps the first window's record."""
    rng = np.random.default_rng(4)
    pos = np.cumsum(rng.normal(size=(900, 3, 3)), axis=0)
    pos[330:340, 1] = np.nan  # inside the overlap of the first two windows
    pos[:, 2] = np.nan  # never observed

    def toy(p):
        from mocapfill.gaps import find_gaps

        res = fill_linear(p)
        k = float(p.shape[0] + np.nansum(p[:5]))  # a value of its own per window
        res.std = np.where(res.filled, k, 0.0)
        res.info = {"gap_methods": [{"marker_index": g.marker, "start": g.start, "length": g.length,
                                     "max_std": k} for g in find_gaps(np.isnan(p).any(axis=2))]}
        return res

    def restate(record, std):
        return dict(record, max_std=float(np.max(std))) if np.isfinite(std).any() else record

    out = fill_in_windows(pos, toy, window=400, overlap=120, restate=restate)
    first, second = out.info["windows"][:2]
    assert second["start"] < 330 and 340 < first["stop"]
    records = out.info["gap_methods"]
    assert [(e["marker_index"], e["start"], e["length"]) for e in records] == [(1, 330, 10), (2, 0, 900)]
    assert records[0]["max_std"] == pytest.approx(np.max(out.std[330:340, 1]), rel=1e-12)
    windows = [toy(pos[w["start"]:w["stop"]]).std[330 - w["start"], 1] for w in (first, second)]
    assert min(windows) < records[0]["max_std"] < max(windows)  # the blend, not one window's



def test_a_marker_lost_for_good_is_learnt_in_later_windows_from_the_frames_that_show_it():
    """``keywords(start, stop)`` reach each window's fill; ``auto``'s lends a window that never shows a marker the
    take's nearest frames that do, as reference frames, so the marker lost at frame 300 of 900 is filled in every
    window, not left NaN past the first."""
    from functools import partial

    from synthetic import tumbling_body
    from mocapfill.methods.auto import LOST_MARKER_FRAMES, lost_marker_frames, model_fill
    from mocapfill.methods.auto_config import DEFAULT_CONFIG

    truth = tumbling_body(n_frames=900)
    pos = truth.copy()
    pos[300:, 0] = np.nan
    missing = np.isnan(pos).any(axis=2)
    assert lost_marker_frames(pos, missing, None, None, 0, 400) == {}  # the first window shows it
    lent = lost_marker_frames(pos, missing, None, None, 480, 900)
    assert len(lent["reference_frames"]) == min(300, LOST_MARKER_FRAMES)
    np.testing.assert_array_equal(lent["reference_frames"], pos[:300])
    seen = []

    def fill(p, **kw):
        seen.append(sorted(kw))
        kw.setdefault("reference_frames", None)
        return model_fill(p, units="mm", labels=None, rate=100.0, bones=None, refine=True, config=DEFAULT_CONFIG,
                          **kw)

    out = fill_in_windows(pos, fill, window=400, overlap=80,
                          keywords=partial(lost_marker_frames, pos, missing, None, None))
    assert seen[0] == [] and ["reference_frames", "reference_weights"] in seen[1:]
    assert np.isfinite(out.positions[:, 0]).all()
    assert np.sqrt(np.mean((out.positions[300:, 0] - truth[300:, 0]) ** 2)) < 5.0

def test_short_take_is_one_call():
    pos = np.random.default_rng(0).normal(size=(50, 4, 3))
    pos[10:20, 1] = np.nan
    calls = []

    def fill(p):
        calls.append(p.shape)
        return finish(p, np.nan_to_num(p))

    out = fill_in_windows(pos, fill, window=100, overlap=20)
    assert calls == [(50, 4, 3)] and out.filled.sum() == 10


def test_windows_in_worker_processes_give_the_same_fill(long_take):
    pos = _with_gaps(long_take, 2)
    serial = fill_in_windows(pos, fill_linear, window=1000, overlap=200)
    parallel = fill_in_windows(pos, fill_linear, window=1000, overlap=200, jobs=2)
    np.testing.assert_array_equal(parallel.positions, serial.positions)


def test_observed_run_records_are_kept_once_in_the_takes_frames():
    """A fill that lists observed runs (``auto``'s ``info["displaced"]``) in each window's frames: the merged list
    has each run once (from the window whose share holds it, not the overlap's other window), in the take's frames."""
    truth = np.cumsum(np.random.default_rng(0).normal(size=(3000, 3, 3)), axis=0)
    pos = truth.copy()
    pos[1000:1010, 0] = np.nan

    def fill(window):
        res = fill_linear(window)
        seen = ~np.isnan(window).any(axis=2)
        # every window reports each observed run of marker 1 between frames 5 and 8 of a 100-frame grid
        runs = [{"marker": 1, "marker_index": 1, "start": s, "length": 3}
                for s in range(0, len(window) - 3, 100) if seen[s:s + 3, 1].all()]
        res.info["displaced"] = runs
        return res

    out = fill_in_windows(pos, fill, window=1200, overlap=300)
    starts = [r["start"] for r in out.info["displaced"]]
    assert starts == sorted(set(starts)) and len(starts) > 20
    assert all(0 <= s < 3000 for s in starts)
