"""One of the BoLeRO authors' fixed trials (../shared/data/bolero): our DynaMMo at least as accurate as their code.

Skips cleanly when ../shared/data is absent.  The full comparison (40 trials, four methods) is
``benchmarks/bench_authors.py``.
"""

from __future__ import annotations

import csv
import json
import warnings

import numpy as np

import mocapfill
from mocapfill.methods.dynammo import fill_dynammo


def authors_rmse(folder, clip, protocol, trial, method):
    with open(folder / "authors-code-results.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            if (row["clip"], row["protocol"], int(row["trial"]), row["method"]) == (clip, protocol, trial, method):
                return float(row["rmse_mm"])
    raise AssertionError(f"no {method} row for {clip} {protocol} {trial}")


def test_dynammo_matches_the_authors_code_on_a_short_shared_trial(shared_data):
    folder = shared_data / "bolero"
    spec = json.loads((folder / "occlusions.json").read_text())["trials"]
    t = next(t for t in spec if (t["clip"], t["protocol"], t["trial"]) == ("127_07", "P2", 3))  # RUPA + RELB
    data = mocapfill.read(folder / "127_07.csv", rate=120.0)
    labels = list(data.labels)
    hidden = np.zeros(data.positions.shape[:2], dtype=bool)
    hidden[t["start"]:t["start"] + t["length"], [labels.index(m) for m in t["markers"]]] = True
    occluded = data.positions.copy()
    occluded[hidden] = np.nan
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
