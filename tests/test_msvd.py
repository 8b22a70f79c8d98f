"""`msvd`: recovers low-rank data, objective never increases, rank rule, convergence warning."""

from __future__ import annotations

import numpy as np
import pytest

from mocapfill.errors import ConvergenceWarning, MethodError
from mocapfill.methods.msvd import energy_rank, fill_msvd


def low_rank(n_frames: int = 120, n_markers: int = 10, rank: int = 3, seed: int = 0) -> np.ndarray:
    """Smooth rank-``rank`` trajectories plus a constant offset; shape (n_frames, n_markers, 3)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, n_frames)
    time_part = np.stack([np.sin((k + 1) * t + rng.uniform(0, 3)) for k in range(rank)], axis=1)
    x = time_part @ rng.normal(size=(rank, 3 * n_markers)) * 100 + rng.normal(size=3 * n_markers) * 500
    return x.reshape(n_frames, n_markers, 3)


def test_recovers_low_rank_data_with_gaps():
    truth = low_rank()
    pos = truth.copy()
    pos[20:60, 2] = np.nan
    pos[70:90, 5] = np.nan
    pos[:10, 7] = np.nan
    result = fill_msvd(pos, rank=3, tol=1e-10, max_iter=2000)
    assert result.converged and result.info["rank"] == 3
    np.testing.assert_allclose(result.positions, truth, atol=1e-3)


def test_energy_rule_and_objective_never_increases():
    truth = low_rank(rank=4)
    pos = truth.copy()
    pos[60, 1] = np.nan  # a one-frame gap barely disturbs the pre-filled matrix's spectrum
    assert fill_msvd(pos, energy=0.999999).info["rank"] == 4
    pos[30:50, 1] = np.nan
    pos[40:80, 6] = np.nan
    result = fill_msvd(pos, rank=4, tol=1e-9, max_iter=500)
    obj = np.array(result.objective)
    assert obj.size == result.n_iter >= 1
    assert np.all(np.diff(obj) <= 1e-9 * max(obj[0], 1.0))


def test_energy_rank():
    assert energy_rank(np.array([10.0, 1.0, 0.1]), 0.9) == 1
    assert energy_rank(np.array([10.0, 1.0, 0.1]), 0.999) == 2
    assert energy_rank(np.array([10.0, 1.0, 0.1]), 1.0) == 3
    assert energy_rank(np.zeros(3), 0.9) == 1


def test_iteration_cap_warns_and_progress_is_called():
    pos = low_rank()
    pos[20:60, 2] = np.nan
    calls = []
    with pytest.warns(ConvergenceWarning):
        result = fill_msvd(pos, max_iter=2, tol=0.0, progress=lambda i, n, obj: calls.append((i, n)))
    assert not result.converged and result.n_iter == 2 and calls == [(1, 2), (2, 2)]


def test_blackout_and_never_observed_marker():
    truth = low_rank()
    pos = truth.copy()
    pos[50:53] = np.nan
    pos[:, 4] = np.nan
    result = fill_msvd(pos)
    assert np.isnan(result.positions[:, 4]).all() and result.info["all_missing"] == [4]
    others = [m for m in range(truth.shape[1]) if m != 4]
    assert result.filled[50:53][:, others].all()


def test_nothing_to_fill_and_bad_options():
    pos = low_rank()
    result = fill_msvd(pos)
    assert not result.filled.any() and np.array_equal(result.positions, pos)
    with pytest.raises(MethodError):
        fill_msvd(pos, energy=0.0)
    with pytest.raises(MethodError):
        fill_msvd(pos, max_iter=-1)
