"""Issue 23's rules on every capture of ../shared/data (``benchmarks/sweep_readers.py``): no parameter-chain note on
a valid file, no held sample in the complete captures and static trials, labels in their right columns, unlabelled
trajectories never filled unless named.  Skips without ../shared/data."""

from __future__ import annotations

import importlib.util
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import mocapfill
from mocapfill.pipeline import FillSettings, fill_capture

pytestmark = pytest.mark.shared

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "sweep_readers.py"
if str(_PATH.parent) not in sys.path:  # the script imports the benchmarks' harness, as when run from benchmarks/
    sys.path.insert(0, str(_PATH.parent))


def _sweep():
    spec = importlib.util.spec_from_file_location("sweep_readers", _PATH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_no_false_positive_anywhere(shared_data):
    sweep = _sweep()
    rows = [sweep.sweep_file(shared_data / rel, rel) for rel in sweep.captures(shared_data)]
    assert len(rows) > 50
    assert sweep.check(rows) == []
    covered = [r["file"] for r in rows if r["file"].startswith(sweep.NO_HELD)]
    assert "cmu/85_02.c3d" in covered and sum(f.startswith("cmu-train/") for f in covered) == 12


def test_kinds_of_the_plug_in_gait_and_cmu_files(shared_data):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        movement = mocapfill.read(shared_data / "pycgm/Movement_trial.c3d")
        cmu = mocapfill.read(shared_data / "cmu-train/16_07.c3d")
        gait = mocapfill.read(shared_data / "btk/TRCSamples/Gait.trc")
    count = lambda d, k: sum(1 for x in d.kinds if x == k)  # noqa: E731
    assert (count(movement, "marker"), count(movement, "model"), count(movement, "unlabelled")) == (39, 78, 42)
    assert all(movement.labels[i].startswith("*") for i, k in enumerate(movement.kinds) if k == "unlabelled")
    assert (count(cmu, "marker"), count(cmu, "model")) == (41, 289)
    # BTK's ragged Gait.trc: the 33 names in the first 33 columns, as the matching C3D names them
    assert gait.labels[:3] == ["R.Shoulder", "R.Offset", "R.Elbow"] and gait.labels[32] == "PX"
    assert count(gait, "unlabelled") == 72


def test_unlabelled_trajectories_are_not_filled(shared_data):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = mocapfill.read(shared_data / "pycgm/Movement_trial.c3d")
    outcome = fill_capture(data, FillSettings(method="spline"))
    aside = [k for k, kind in enumerate(data.kinds) if kind != "marker"]
    assert data.missing[:, aside].sum() > 1000  # every gap of this file is in its unlabelled trajectories
    assert np.array_equal(outcome.output.positions[:, aside], data.positions[:, aside], equal_nan=True)
    assert not outcome.result.filled.any()
