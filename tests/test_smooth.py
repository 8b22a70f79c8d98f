"""savgol_smooth: run-by-run, NaN-aware, polynomial-exact, parameter checks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import savgol_filter

from mocapfill.errors import MocapfillError
from mocapfill.guards.smooth import default_window, savgol_smooth, short_runs
from synthetic import moving_body


def _noisy(seed: int = 0, n_frames: int = 200, n_markers: int = 3) -> tuple[np.ndarray, np.ndarray]:
    def body(noise):
        return moving_body(n_frames, seed=seed, body=np.zeros((n_markers, 3)), rate=100.0, noise=noise,
                           path=lambda t: np.stack([np.sin(2 * np.pi * t * (1 + k)) * 100 + k for k in range(3)],
                                                   axis=1))

    return body(0.0), body(1.0)


def test_reduces_noise_and_keeps_shape():
    clean, noisy = _noisy()
    smoothed = savgol_smooth(noisy, window=9, order=3)
    assert smoothed.shape == noisy.shape and smoothed is not noisy
    assert np.sqrt(np.mean((smoothed - clean) ** 2)) < 0.7 * np.sqrt(np.mean((noisy - clean) ** 2))


def test_cubic_is_left_exactly():
    t = np.linspace(-1, 1, 50)
    cubic = (2 * t**3 - t + 3)[:, None, None] * np.ones((1, 2, 3))
    np.testing.assert_allclose(savgol_smooth(cubic, window=7, order=3), cubic, atol=1e-9)


def test_each_run_separately_and_short_runs_untouched():
    _, noisy = _noisy(1, n_frames=60, n_markers=1)
    data = noisy.copy()
    data[20:23, 0] = np.nan  # runs 0-19 and 23-59
    data[40:55, 0] = np.nan  # runs 23-39 and 55-59 (5 frames: shorter than the window)
    out = savgol_smooth(data, window=7, order=2)
    assert np.isnan(out[20:23, 0]).all() and np.isnan(out[40:55, 0]).all()
    np.testing.assert_allclose(out[0:20, 0], savgol_filter(data[0:20, 0], 7, 2, axis=0, mode="interp"))
    np.testing.assert_allclose(out[23:40, 0], savgol_filter(data[23:40, 0], 7, 2, axis=0, mode="interp"))
    np.testing.assert_array_equal(out[55:60, 0], data[55:60, 0])
    assert short_runs(data, 7) == [(0, 55, 5)] and short_runs(data, 1) == []  # what it left, for the warning


def test_default_window_from_rate():
    assert default_window(3, 120.0) == 9
    assert default_window(3, 50.0) == 5
    assert default_window(3, None) == 7
    assert default_window(5, 30.0) == 7
    _, noisy = _noisy(2)
    np.testing.assert_array_equal(savgol_smooth(noisy, rate=120.0), savgol_smooth(noisy, window=9, order=3))


@pytest.mark.parametrize("kwargs", [dict(window=8), dict(window=3, order=3), dict(order=-1)])
def test_bad_parameters(kwargs):
    with pytest.raises(MocapfillError):
        savgol_smooth(np.zeros((20, 1, 3)), **kwargs)
