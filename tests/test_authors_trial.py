"""One of the BoLeRO authors' fixed trials (../shared/data/bolero): our DynaMMo at least as accurate as their code.

Skips cleanly when ../shared/data is absent.  The full comparison (40 trials, four methods) is
``benchmarks/bench_authors.py``.
"""

from __future__ import annotations

import csv
import warnings

import numpy as np
import pytest

from mocapfill.methods.dynammo import fill_dynammo

#: Accuracy thresholds on real captures: not in a bare `pytest`; `pytest -m accuracy` (and .ci/run) runs them.
pytestmark = pytest.mark.accuracy


def authors_rmse(folder, clip, protocol, trial, method):
    with open(folder / "authors-code-results.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            if (row["clip"], row["protocol"], int(row["trial"]), row["method"]) == (clip, protocol, trial, method):
                return float(row["rmse_mm"])
    raise AssertionError(f"no {method} row for {clip} {protocol} {trial}")


def test_dynammo_matches_the_authors_code_on_a_short_shared_trial(shared_data, authors_trial):
    folder = shared_data / "bolero"
    data, occluded, hidden = authors_trial("127_07", "P2", 3)  # RUPA + RELB
    labels = list(data.labels)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fill_dynammo(occluded, seed=0)
    assert np.array_equal(res.positions[~hidden], data.positions[~hidden])
    # The authors' score: RMSE over the hidden coordinates (mm); their DynaMMo gave 8.1 mm, linear 11.5.
    rmse = float(np.sqrt(np.mean((res.positions - data.positions)[hidden] ** 2)))
    assert rmse <= authors_rmse(folder, "127_07", "P2", 3, "dynammo")
    assert res.info["frame"] == "yaw"
    assert {"LBWT", "LFWT", "RBWT", "RFWT"} <= {labels[k] for k in res.info["frame_markers"]}  # pelvis + torso
    assert np.all(res.std[hidden] > 0) and np.all(np.isfinite(res.std[hidden]))
