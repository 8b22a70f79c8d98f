"""Issue 21, "smooth": the default's fill of every committed capture with real gaps accelerates no more than the
capture itself (mocapfill.evaluation.smoothness; benchmarks/bench_default_real.py measures every real capture).

The fill runs as ``mocapfill fill IN OUT`` runs it (:func:`mocapfill.pipeline.fill_capture`, default settings).
"""

from __future__ import annotations

import warnings

import pytest

from mocapfill.evaluation.smoothness import outcome_smoothness, smooth_enough
from mocapfill.io import read
from mocapfill.pipeline import FillSettings, fill_capture

#: Every committed capture with real gaps (``sample_data/markers.csv`` is the same trial as markers_analogs.c3d).
CASES = [
    pytest.param("sample_data/kinematics_tennis_serve_nan.c3d", id="tennis_serve_nan"),
    pytest.param("sample_data/markers_analogs.c3d", id="markers_analogs"),
    pytest.param("tests/data/ADemo1_rewrite_c3d_pc_float.c3d", id="ADemo1"),
    pytest.param("tests/data/kinematics_racing_full.c3d", id="racing_full"),
    pytest.param("tests/data/qtm_JaneDoe_Dynamic_2.tsv", id="qtm_JaneDoe"),
    pytest.param("tests/data/newwalk.c3d", id="newwalk"),
    pytest.param("tests/data/MACsample.c3d", id="MACsample"),
]


@pytest.mark.accuracy
@pytest.mark.parametrize("relative", CASES)
def test_default_fill_is_no_jerkier_than_the_capture(relative, sample_data):
    path = sample_data.parent / relative
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = read(path)
        outcome = fill_capture(data, FillSettings().check())
    s = outcome_smoothness(outcome)
    assert s.n_filled > 0, "the capture has gaps: the fill must have supplied samples"
    ok, reasons = smooth_enough(s)
    assert ok, f"{relative}: " + "; ".join(reasons) + f" (file units; worst at frame {s.worst_frame}, " \
                                                      f"marker {data.labels[s.worst_marker]})"
