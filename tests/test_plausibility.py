"""Plausibility of the default's fills (issue 9): within the body's observed extent, no faster than observed.

On every committed capture with real gaps, no filled sample lies farther from the body's median centre than 1.1x
the farthest observed marker, and no step touching a filled sample is longer than 1.5x its marker's largest
observed step (:mod:`mocapfill.guards.plausibility`).  ``benchmarks/bench_messy.py`` runs the same check on every
capture with real gaps in ../shared/data.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import mocapfill
from mocapfill.evaluation.occlusions import make_occlusions
from mocapfill.methods.auto_stack import MIN_SPEED_MM, fill_auto_stack, mix_by_uncertainty
from mocapfill.guards.plausibility import (body_centre, implausible, observed_speed, plausibility,
                                            project_plausible)
from mocapfill.units import length_factor
from synthetic import moving_body

GAPPY = [("sample_data", "kinematics_tennis_serve_nan.c3d"), ("sample_data", "markers_analogs.c3d"),
         ("test_data", "ADemo1_rewrite_c3d_pc_float.c3d"), ("test_data", "kinematics_racing_full.c3d")]


@pytest.mark.accuracy
@pytest.mark.parametrize("where,name", GAPPY)
def test_default_fills_of_real_gaps_are_plausible(where, name, request):
    data = mocapfill.read(request.getfixturevalue(where) / name)
    missing = np.isnan(data.positions).any(axis=2)
    assert missing.any() and not missing.all()  # the file really has gaps
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = mocapfill.fill(data, method="auto")
    ratios = plausibility(res.positions, data.positions, floor=MIN_SPEED_MM * length_factor("mm", data.units))
    assert ratios["extent"] <= 1.1
    assert ratios["speed"] <= 1.5


def test_plausibility_measures_extent_and_speed():
    rng = np.random.default_rng(0)
    pos = np.cumsum(rng.normal(size=(200, 5, 3)), axis=0) + np.arange(5)[None, :, None] * 100.0
    gappy = pos.copy()
    gappy[50:60, 0] = np.nan
    missing = np.isnan(gappy).any(axis=2)
    centre, radius = body_centre(gappy, missing)
    assert centre.shape == (200, 3) and np.isfinite(centre).all() and radius > 0
    assert plausibility(gappy, gappy) == {"extent": 0.0, "speed": 0.0}  # nothing filled
    flying = pos.copy()
    flying[55, 0] = centre[55] + 3.0 * radius  # a filled sample far out: beyond the extent and a huge step
    bad = implausible(flying, gappy, observed_speed(gappy, missing, floor=0.0))
    assert bad[55, 0] and bad[54:57, 0].sum() == 3 and not bad[:, 1:].any()
    ratios = plausibility(flying, gappy)
    assert ratios["extent"] > 2.0 and ratios["speed"] > 10.0


@pytest.mark.accuracy
def test_dense_gaps_learn_from_incomplete_frames(sample_data):
    # 20 % of the CMU clip's samples hidden in 0.25-2 s single-marker gaps leaves 2 % of the frames complete; the
    # local models then keep the nearest observed neighbours (measured: median / RMSE 9.6 / 26 mm; 169 / 331 mm
    # on the clips before, bolero-sc 22 / 58 here).
    data = mocapfill.read(sample_data / "85_02.c3d")
    trial = make_occlusions(data, "dense", trials=1, seed=0, missing=0.2)[0]
    pos, hidden, _ = trial.apply(data.positions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fill_auto_stack(pos, units=data.units, rate=data.rate, labels=data.labels)
    err = np.linalg.norm(res.positions[hidden] - data.positions[hidden], axis=1)
    assert np.median(err) < 15.0 and np.sqrt(np.mean(err ** 2)) < 45.0
    assert all("method" in g and "reason" in g for g in res.info["gap_methods"])


def _circling(n_markers: int = 9, n_frames: int = 300) -> np.ndarray:
    """Markers on a line circling a point: (n_frames, n_markers, 3), 5 mm per frame."""
    k = np.arange(n_markers) - n_markers // 2
    return moving_body(n_frames, body=np.stack([k * 20, 0 * k, k], axis=1), rate=1.0,
                       path=lambda t: np.stack([np.sin(t / 20) * 100, np.cos(t / 20) * 100, 0 * t], axis=1))


def test_projection_keeps_the_bounds_and_moves_little():
    pos = _circling()
    gappy = pos.copy()
    gappy[100:160, 4] = np.nan
    missing = np.isnan(gappy).any(axis=2)
    speed = observed_speed(gappy, missing, floor=0.0)
    spiky = pos.copy()
    spiky[130, 4] += 100.0  # one filled sample 100 mm off: a 20x step
    assert plausibility(spiky, gappy)["speed"] > 10
    out, moved, forced = project_plausible(spiky, gappy, speed)
    ratios = plausibility(out, gappy)
    assert ratios["speed"] <= 1.5 and ratios["extent"] <= 1.1
    assert moved[100:160, 4].all() and not moved[:, :4].any() and not forced.any()
    assert np.array_equal(out[~missing], spiky[~missing])  # observations untouched
    assert np.abs(out[100:160, 4] - pos[100:160, 4]).max() < 30.0  # the spike spread, not a line through the gap
    # a plausible fill is returned unchanged
    same, moved, _ = project_plausible(pos, gappy, speed)
    assert np.array_equal(same, pos) and not moved.any()


def test_projection_reports_runs_the_observations_force():
    pos = _circling()
    gappy = pos.copy()
    gappy[100:103, 4] = np.nan
    gappy[103:, 4] += 200.0  # the marker reappears 200 mm away: no path of 4 steps of 7.5 mm gets there
    missing = np.isnan(gappy).any(axis=2)
    speed = observed_speed(gappy, missing, floor=0.0)
    est = gappy.copy()
    est[100:103, 4] = pos[100:103, 4]
    out, _, forced = project_plausible(est, gappy, speed)
    assert forced[100:103, 4].all() and not forced[:, :4].any()
    # the calmest path there is: no step longer than the straight line's (a quarter of the way each)
    steps = np.linalg.norm(np.diff(out[99:104, 4], axis=0), axis=1)
    assert steps.max() <= np.linalg.norm(gappy[103, 4] - gappy[99, 4]) / 4 * (1 + 1e-9)


def test_mix_by_uncertainty_weights_each_estimate_by_its_inverse_variance():
    positions = np.full((4, 1, 3), np.nan)
    positions[0] = 0.0
    mine = np.zeros((4, 1, 3))
    other = np.ones((4, 1, 3))
    std = np.array([[0.0], [1.0], [np.nan], [2.0]])
    other_std = np.array([[0.0], [1.0], [1.0], [np.nan]])
    out, sd, mixed = mix_by_uncertainty(positions, mine, std, other, other_std)
    np.testing.assert_allclose(out[1:, 0, 0], [0.5, 1.0, 0.0])  # equal weights; only the other's; only mine
    np.testing.assert_allclose(sd[1:, 0], [1 / np.sqrt(2), 1.0, 2.0])
    assert mixed.tolist() == [[False], [True], [True], [False]] and out[0, 0, 0] == 0.0
