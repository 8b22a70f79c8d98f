"""`bilinear`: DCT basis, K_t rule, exact recovery of data in the model, blackouts, windows."""

from __future__ import annotations

import numpy as np
import pytest

from mocapfill.errors import MethodError
from mocapfill.methods.bilinear import dct_basis, fill_bilinear, n_trajectory_vectors
from mocapfill.methods.interp import fill_linear


def in_model(n_frames: int = 150, n_markers: int = 8, k_t: int = 6, k_s: int = 3, seed: int = 0) -> np.ndarray:
    """Data exactly of the form mu + Theta C B^T; shape (n_frames, n_markers, 3)."""
    rng = np.random.default_rng(seed)
    theta = dct_basis(n_frames, k_t)
    basis, _ = np.linalg.qr(rng.normal(size=(3 * n_markers, k_s)))
    coef = rng.normal(size=(k_t, k_s)) * 300
    s = theta @ coef @ basis.T + rng.normal(size=3 * n_markers) * 200
    return s.reshape(n_frames, n_markers, 3)


def test_dct_basis_is_orthonormal_and_k_t_rule():
    theta = dct_basis(64, 64)
    np.testing.assert_allclose(theta.T @ theta, np.eye(64), atol=1e-12)
    assert n_trajectory_vectors(600, 120.0, 6.0) == 61  # 2 * 600 * 6 / 120 + 1
    assert n_trajectory_vectors(250, 50.0, 6.0) == 61
    assert n_trajectory_vectors(100, None, 6.0) == 10
    assert n_trajectory_vectors(5, 120.0, 6.0) == 2


def test_recovers_data_that_is_in_the_model():
    truth = in_model()
    pos = truth.copy()
    pos[30:70, 1] = np.nan
    pos[100:140, 5] = np.nan
    pos[:12, 6] = np.nan
    # K_t = ceil(2 * 150 * 3 / 150) + 1 = 7 >= 6 trajectory vectors; the shape basis holds all 3 modes.
    result = fill_bilinear(pos, rate=150.0, cutoff=3.0, n_shape=3, smooth=0.0, refine=300, tol=1e-12)
    assert result.info["n_shape"] == 3
    np.testing.assert_allclose(result.positions, truth, atol=1e-3)


def test_blackout_is_filled_smoothly():
    t = np.arange(300) / 100.0
    rng = np.random.default_rng(2)
    body = rng.normal(scale=100, size=(6, 3))
    root = np.stack([300 * np.sin(2 * np.pi * 0.4 * t), 200 * t, 50 * np.cos(2 * np.pi * 0.9 * t)], axis=1)
    truth = body[None] + root[:, None]
    pos = truth.copy()
    pos[140:152] = np.nan  # 0.12 s of nothing
    pos[40:90, 2] = np.nan
    result = fill_bilinear(pos, rate=100.0)
    assert result.filled[140:152].all()
    err = np.linalg.norm(result.positions[140:152] - truth[140:152], axis=-1).max()
    lin = np.linalg.norm(fill_linear(pos).positions[140:152] - truth[140:152], axis=-1).max()
    assert err < 5.0 and err < lin


def test_long_clip_is_solved_in_windows():
    truth = in_model(n_frames=1300, k_t=12)
    pos = truth.copy()
    pos[200:260, 3] = np.nan
    pos[640:700, 4] = np.nan  # across a window boundary
    pos[1250:, 0] = np.nan
    result = fill_bilinear(pos, rate=100.0, window=400)
    assert result.info["window"] == 400
    assert result.filled[pos[..., 0] != pos[..., 0]].all()
    rms = np.sqrt(np.mean((result.positions - truth) ** 2))
    assert rms < 5.0


def test_never_observed_marker_and_no_gaps():
    truth = in_model()
    result = fill_bilinear(truth, rate=100.0)
    assert not result.filled.any() and np.array_equal(result.positions, truth)
    pos = truth.copy()
    pos[:, 2] = np.nan
    pos[10:20, 3] = np.nan
    result = fill_bilinear(pos, rate=100.0)
    assert np.isnan(result.positions[:, 2]).all() and result.info["all_missing"] == [2]
    assert result.filled[10:20, 3].all()


def test_bad_options():
    with pytest.raises(MethodError):
        fill_bilinear(in_model(), shape_energy=1.5)
    with pytest.raises(MethodError):
        fill_bilinear(in_model(), cutoff=0.0)
