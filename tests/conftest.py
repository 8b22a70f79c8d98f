"""Shared fixtures: where the committed data and the optional ../shared/data live."""

from __future__ import annotations

from pathlib import Path

import pytest

from mocapfill.runtime.blas import single_blas_thread

REPO = Path(__file__).resolve().parents[1]
SAMPLE_DATA = REPO / "sample_data"
TEST_DATA = REPO / "tests" / "data"
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def sample_data() -> Path:
    """The committed sample captures (always present)."""
    return SAMPLE_DATA


@pytest.fixture(scope="session")
def test_data() -> Path:
    """The committed small test files (always present)."""
    return TEST_DATA


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data beside the checkout; tests using it skip cleanly when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present")
    return SHARED_DATA


@pytest.fixture(scope="module")
def halves(sample_data):
    """CMU 85_02's first half (the capture, path "first") and second half (a reference take of the same subject,
    path "second"), 405 frames each; fresh for each module."""
    import mocapfill
    from mocapfill.markers import MarkerData

    cmu = mocapfill.read(sample_data / "85_02.c3d")
    first = MarkerData(cmu.positions[:405].copy(), list(cmu.labels), cmu.rate, cmu.units, path="first")
    second = MarkerData(cmu.positions[405:].copy(), list(cmu.labels), cmu.rate, cmu.units, path="second")
    return first, second


@pytest.fixture(scope="session", autouse=True)
def one_blas_thread():
    """Small matrices everywhere: BLAS threads only add contention on a busy 2-core machine (10-50x slower fills)."""
    with single_blas_thread():
        yield


@pytest.fixture(scope="session")
def authors_trial(shared_data):
    """``load(clip, protocol, trial) -> (data, occluded, hidden)``: one of the BoLeRO authors' fixed trials
    (../shared/data/bolero, 120 Hz), its markers hidden over its span; hidden (n_frames, n_markers) bool."""
    import json

    import numpy as np

    import mocapfill

    folder = shared_data / "bolero"
    spec = json.loads((folder / "occlusions.json").read_text())["trials"]

    def load(clip: str, protocol: str, trial: int):
        t = next(t for t in spec if (t["clip"], t["protocol"], t["trial"]) == (clip, protocol, trial))
        data = mocapfill.read(folder / f"{clip}.csv", rate=120.0)
        labels = list(data.labels)
        hidden = np.zeros(data.positions.shape[:2], dtype=bool)
        hidden[t["start"]:t["start"] + t["length"], [labels.index(m) for m in t["markers"]]] = True
        occluded = data.positions.copy()
        occluded[hidden] = np.nan
        return data, occluded, hidden

    return load
