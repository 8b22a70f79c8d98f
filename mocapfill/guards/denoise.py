"""``fill --denoise``: observed samples a learned denoiser judges displaced or swapped become gaps, to be refilled.

Holden's point is that a network trained on corrupted data repairs outliers without a separate detector.  Here the
network (:mod:`mocapfill.engines.denoiser`) estimates every marker in every frame from what is observed; an
observed sample farther from that estimate than :data:`DISPLACED_FACTOR` times the marker's error (and at least
:data:`DISPLACED_MM`) is judged displaced.  The marker's error is the larger of its held-out error in training and
its typical error on this capture (the median distance over its observed samples, as an RMS): on another subject a
marker placed a little differently sits consistently off the network's estimate, and that is not a displacement
(CMU 02_01, one tidy gap: 343 of its samples were judged displaced with the training error alone, none with this).  Those samples are hidden and the estimate recomputed without them
(:data:`PASSES` times), since a displaced marker also pulls its neighbours' estimates.  The caller (the pipeline)
turns them into gaps, fills them with the chosen method and reports them as ``Status.REPAIRED``.
"""

from __future__ import annotations

import warnings
from typing import Any, Sequence

import numpy as np

from ..units import length_factor

#: An observed sample is displaced when its distance to the network's estimate exceeds this many times the
#: marker's held-out RMS error ...
DISPLACED_FACTOR = 4.0
#: ... and this many mm (Holden's shifts are up to 50 cm per axis; a real marker wobbles by millimetres).
DISPLACED_MM = 60.0
#: Detection passes (each with the samples found so far hidden).
PASSES = 2
#: The RMS of a 3-D Gaussian error is this many times its median distance (sqrt(3) / 1.538): the capture's typical
#: error, read robustly (displaced samples are a minority), on the scale of the training error.
MEDIAN_TO_RMS = 1.126


def find_displaced(positions: np.ndarray, model: Any, *, labels: Sequence[str] | None = None, units: str = "mm",
                   rate: float | None = None) -> np.ndarray:
    """The observed samples the denoiser judges displaced or swapped: (n_frames, n_markers) bool.

    positions (n_frames, n_markers, 3), NaN = missing; ``model`` a DenoiserModel or a model file path.  Markers
    outside the model's layout are never judged.
    """
    from ..engines.denoiser import layout_index
    from ..methods.learned import network_estimate, resolve_model

    net = resolve_model(model)
    positions = np.asarray(positions, dtype=np.float64)
    observed = ~np.isnan(positions).any(axis=2)
    idx = layout_index(net, labels, positions.shape[1])
    scale = np.full(positions.shape[1], np.inf)
    mine = idx >= 0
    scale[mine] = net.residual[idx[mine]] * length_factor(net.units, units)
    bound = np.maximum(DISPLACED_FACTOR * scale, DISPLACED_MM * length_factor("mm", units))
    found = np.zeros(observed.shape, dtype=bool)
    work = positions
    for step in range(PASSES):
        est = network_estimate(work, net, labels=labels, units=units, rate=rate)
        dist = np.linalg.norm(positions - est, axis=2)
        if step == 0:  # the marker's typical error on this capture, once, with every observed sample in
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a marker never observed: NaN, ignored by fmax
                typical = MEDIAN_TO_RMS * np.nanmedian(np.where(observed & np.isfinite(dist), dist, np.nan), axis=0)
            bound = np.fmax(bound, DISPLACED_FACTOR * np.where(mine, typical, np.nan))
        new = observed & np.isfinite(dist) & (dist > bound[None, :]) & ~found
        if not new.any():
            break
        found |= new
        work = positions.copy()
        work[found] = np.nan
    return found
