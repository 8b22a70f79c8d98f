"""Shared fixtures: where the committed data and the optional ../shared/data live."""

from __future__ import annotations

from pathlib import Path

import pytest

from mocapfill.blas import single_blas_thread

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


@pytest.fixture(scope="session", autouse=True)
def one_blas_thread():
    """Small matrices everywhere: BLAS threads only add contention on a busy 2-core machine (10-50x slower fills)."""
    with single_blas_thread():
        yield
