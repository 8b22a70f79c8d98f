"""``fill --denoise``: observed samples a learned denoiser judges displaced or swapped become gaps, to be refilled.

Holden's point is that a network trained on corrupted data repairs outliers without a separate detector.  Here the
network (:mod:`mocapfill.engines.denoiser`) estimates every marker in every frame from what is observed; an
observed sample farther from that estimate than :data:`DISPLACED_FACTOR` times the marker's held-out error in
training (and at least :data:`DISPLACED_MM`) is a suspect.  The suspects are hidden and the estimate recomputed
(a displaced marker also pulls its neighbours' estimates); then the verdict: on another body a marker placed a
little differently sits off the estimate by a steady offset, so each marker's median offset on this capture is taken
out, and a sample is displaced when what remains exceeds :data:`DISPLACED_FACTOR` times the larger of the training
error and the marker's typical remaining error here (CMU 02_01, a thigh marker 96 mm off in every frame: with the
training error alone all 343 of its samples were judged displaced on a tidy one-marker gap; none now).  The caller
(the pipeline) turns them into gaps, fills them with the chosen method and reports them as ``Status.REPAIRED``.
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
#: Network passes: suspects by the training error (each pass with those found so far hidden), then the verdict.
PASSES = 2
#: The capture's typical error of a marker is read from this percentile of its distances to the estimate made with
#: the suspects hidden (the median: robust while displaced samples are fewer than half the marker's; a lower
#: percentile under-reads the heavy tail of the network's error where many markers are missing: 3 CMU clips x 2
#: trials, dense 20 %, nothing displaced: 392 samples judged displaced with the 25th, 232 with the median) ...
TYPICAL_PERCENTILE = 50.0
#: ... and made an RMS with this factor: a 3-D Gaussian error's RMS over its median distance (sqrt(3) / 1.538, the
#: chi distribution with 3 degrees of freedom), on the scale of the training error.
PERCENTILE_TO_RMS = 1.126


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
        off = positions - est  # (n_frames, n_markers, 3), NaN where not observed (or not estimated)
        off[~observed] = np.nan
        if step == PASSES - 1:
            # The estimate with the suspects hidden.  A marker placed differently on this body sits off it by a
            # steady offset: its median offset is taken out, and what remains is judged against the larger of the
            # training error and the marker's typical remaining error on this capture.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a marker never observed: NaN, ignored by fmax
                dist = np.linalg.norm(off - np.nanmedian(off, axis=0), axis=2)
                typical = PERCENTILE_TO_RMS * np.nanpercentile(dist, TYPICAL_PERCENTILE, axis=0)
            bound = np.fmax(bound, DISPLACED_FACTOR * np.where(mine, typical, np.nan))
            return np.nan_to_num(dist, nan=-1.0) > bound[None, :]
        new = np.nan_to_num(np.linalg.norm(off, axis=2), nan=-1.0) > bound[None, :]
        if not (new & ~found).any():
            break  # no (more) suspects
        found |= new
        work = positions.copy()
        work[found] = np.nan
    return found
