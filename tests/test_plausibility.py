"""Plausibility of the default's fills (issue 9): within the body's observed extent, no faster than observed.

On every committed capture with real gaps, no filled sample lies farther from the body's median centre than 1.1x
the farthest observed marker, and no step touching a filled sample is longer than 1.5x its marker's largest
observed step (:mod:`mocapfill.methods.plausibility`).  ``benchmarks/bench_messy.py`` runs the same check on every
capture with real gaps in ../shared/data.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import mocapfill
from mocapfill.evaluation.occlusions import make_occlusions
from mocapfill.methods.auto import MIN_SPEED_MM, fill_auto
from mocapfill.methods.plausibility import body_centre, implausible, observed_speed, plausibility
from mocapfill.units import length_factor

GAPPY = [("sample_data", "kinematics_tennis_serve_nan.c3d"), ("sample_data", "markers_analogs.c3d"),
         ("test_data", "ADemo1_rewrite_c3d_pc_float.c3d"), ("test_data", "kinematics_racing_full.c3d")]


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


def test_dense_gaps_learn_from_incomplete_frames(sample_data):
    # 20 % of the CMU clip's samples hidden in 0.25-2 s single-marker gaps leaves 2 % of the frames complete; the
    # local models then keep the nearest observed neighbours (measured: median / RMSE 9.6 / 26 mm; 169 / 331 mm
    # on the clips before, bolero-sc 22 / 58 here).
    data = mocapfill.read(sample_data / "85_02.c3d")
    trial = make_occlusions(data, "dense", trials=1, seed=0, missing=0.2)[0]
    pos, hidden, _ = trial.apply(data.positions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fill_auto(pos, units=data.units, rate=data.rate, labels=data.labels)
    err = np.linalg.norm(res.positions[hidden] - data.positions[hidden], axis=1)
    assert np.median(err) < 15.0 and np.sqrt(np.mean(err ** 2)) < 45.0
    assert all("method" in g and "reason" in g for g in res.info["gap_methods"])
