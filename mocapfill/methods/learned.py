"""The registered ``learned`` method: fill gaps with a denoiser trained on clean takes of the layout (Holden 2018).

``mocapfill train CLEAN_TAKES... --output layout.model`` trains it (:mod:`mocapfill.engines.denoiser_training`, the
``learn`` extra); filling needs only NumPy (:mod:`mocapfill.engines.denoiser`).  Per frame the network estimates every
marker of the layout from the observed ones in the body frame; the estimates are smoothed over time (Holden's
Savitzky-Golay filter, about 1/8 s) and, in each gap, shifted so that they meet the observations at the gap's ends
(the residual there carried in as an Ornstein-Uhlenbeck bridge, as the default's local PCA does).  Observed samples
come back bit-identical; ``--denoise`` (:mod:`mocapfill.guards.denoise`) is what moves observed samples.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..engines.denoiser import (DenoiserModel, from_layout, layout_index, load_model, predict_frames,
                                to_layout)
from ..errors import MethodError
from ..gaps import runs
from .base import FillResult, finish
from .interp import interpolate_columns

#: Temporal smoothing of the per-frame outputs (seconds; Savitzky-Golay, order 2): the network sees one frame at a
#: time, so its outputs jitter from frame to frame.
SMOOTH_SECONDS = 0.125
SMOOTH_ORDER = 2
#: Correlation time (frames) of the residual carried into a gap from its ends.
EDGE_TAU = 30.0


def resolve_model(model: Any) -> DenoiserModel:
    """A :class:`DenoiserModel` from a model or a path; MethodError when none is given."""
    if model is None:
        raise MethodError("method 'learned' needs a model: --model layout.model (from `mocapfill train`)")
    if isinstance(model, DenoiserModel):
        return model
    return load_model(model)


def smooth_series(estimate: np.ndarray, rate: float | None) -> np.ndarray:
    """Savitzky-Golay smoothing of (n_frames, n_markers, 3) along time (NaN-free columns only)."""
    from scipy.signal import savgol_filter

    window = int(round(SMOOTH_SECONDS * (rate or 120.0))) | 1
    if window <= SMOOTH_ORDER + 1 or estimate.shape[0] <= window:
        return estimate
    out = estimate.copy()
    ok = np.isfinite(estimate).all(axis=(0, 2))
    if ok.any():
        out[:, ok] = savgol_filter(estimate[:, ok], window, SMOOTH_ORDER, axis=0)
    return out


def network_estimate(positions: np.ndarray, model: DenoiserModel, *, labels: Sequence[str] | None, units: str,
                     rate: float | None) -> np.ndarray:
    """The smoothed per-frame estimate (n_frames, n_markers, 3) of every layout marker in the capture's order and
    units (NaN for markers outside the layout, and in frames without any observed layout marker)."""
    idx = layout_index(model, labels, positions.shape[1])
    mine = to_layout(positions, idx, model, units)
    est = predict_frames(mine, model)
    empty = np.isnan(est).any(axis=2).all(axis=1)
    if empty.any() and not empty.all():  # frames where nothing was seen: interpolate the estimate through them
        flat = est.reshape(len(est), -1)
        est = interpolate_columns(flat, np.repeat(empty[:, None], flat.shape[1], axis=1)).reshape(est.shape)
    return from_layout(smooth_series(est, rate), idx, positions.shape[1], model, units)


def meet_observations(positions: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """``estimate`` (n_frames, n_markers, 3) in each gap of ``positions`` shifted to meet the observations at its
    ends (Ornstein-Uhlenbeck bridge of the residual, :func:`mocapfill.engines.local_pca.edge_shift`)."""
    from ..engines.local_pca import edge_shift

    out = estimate.copy()
    missing = np.isnan(positions).any(axis=2)
    n = len(positions)
    resid = positions - estimate
    for m in range(positions.shape[1]):
        for start, length in runs(missing[:, m]):
            stop = start + length
            rb = resid[start - 1, m] if start > 0 and np.isfinite(resid[start - 1, m]).all() else None
            ra = resid[stop, m] if stop < n and np.isfinite(resid[stop, m]).all() else None
            shift, _ = edge_shift(rb, ra, length, EDGE_TAU)
            out[start:stop, m] = estimate[start:stop, m] + shift
    return out


def fill_learned(
    positions: np.ndarray,
    *,
    model: Any = None,
    seed: int | None = None,
    units: str = "mm",
    labels: Sequence[str] | None = None,
    rate: float | None = None,
) -> FillResult:
    """Fill gaps with a learned denoiser (see the module docstring).

    Parameters
    ----------
    positions : ndarray (n_frames, n_markers, 3), NaN = missing
    model : DenoiserModel or path of a model file (``mocapfill train``); required.
    seed : ignored (inference is deterministic).
    units, labels, rate : the capture's; markers are matched to the model's layout by label (a ``Subject:`` prefix
        aside) and converted to its units.  Markers outside the layout keep their gaps (linear interpolation fills
        them, listed in ``info["fallback"]``).

    Returns
    -------
    FillResult without a std (``info``: the model's layout size, training frames and settings).
    """
    del seed
    net = resolve_model(model)
    positions = np.asarray(positions, dtype=np.float64)
    estimate = network_estimate(positions, net, labels=labels, units=units, rate=rate)
    estimate = meet_observations(positions, estimate)
    missing = np.isnan(positions).any(axis=2)
    outside = np.flatnonzero(np.isnan(estimate).any(axis=2).all(axis=0) & missing.any(axis=0)
                             & ~missing.all(axis=0))
    for m in outside:
        estimate[:, m] = interpolate_columns(positions[:, m], np.repeat(missing[:, m:m + 1], 3, axis=1))
    estimate[:, missing.all(axis=0)] = np.nan  # a marker never observed stays missing (and says so), as everywhere
    info = {"model": {"markers": net.n_markers, "units": net.units, "parameters": net.n_parameters(),
                      "frames": net.settings.get("frames"), "takes": net.settings.get("takes")},
            "fallback": [int(m) for m in outside]}
    return finish(positions, estimate, info=info)
