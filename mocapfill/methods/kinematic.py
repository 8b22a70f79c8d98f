"""The kinematic fill, ``opensim-ik``: fit the user's scaled OpenSim model to the markers seen in each frame, and
read the missing markers off the fitted model (what Nexus and QTM call a kinematic fill).

1. IK on the observed markers of every frame (:func:`mocapfill.kinematics.opensim_ik.track`); frames with too few
   markers, and coordinates none of whose markers is seen, are interpolated in time.
2. Each marker rides on a body: its model marker's body, or, for a capture marker the model does not have, the body
   in whose frame it moves least while it is seen.  In that body's frame a marker is nearly still; its local
   position in a gap is interpolated between the local positions just before and just after the gap (the mean of
   up to :data:`EDGE_FRAMES` frames on each side; held at the take's ends).  So the marker's offset from the model
   marker (the IK residual, soft tissue, placement) is carried through the gap, and only the pose comes from IK.
3. Its std per coordinate is read off the IK marker residuals: the scatter of the marker's local position while it
   is seen, with the frame's RMS IK residual over the markers seen (per coordinate) added in quadrature.

A marker never seen stays missing (no model marker is invented).  Needs ``opensim`` (the extra
``mocapfill[opensim]``) and a model (``ik_model``; the CLI's ``--ik-model``).
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import MethodError
from ..gaps import runs
from .base import FillResult, finish

#: Frames averaged on each side of a gap for the local position it is bridged from: a few frames smooth the marker's
#: jitter, more would let the soft-tissue drift of a moving limb in.
EDGE_FRAMES = 3


def _best_body(local_spread: np.ndarray) -> int:
    """Index of the body with the smallest spread (B,) of a marker's local positions (NaN = unusable)."""
    return int(np.nanargmin(local_spread))


def _to_local(rotation: np.ndarray, origin: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (T, 3) into body frames (rotation (T, 3, 3), origin (T, 3)): R^T (x - o)."""
    return np.einsum("tji,tj->ti", rotation, points - origin)


def _bridge(local: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Local positions (T, 3), known where ``seen`` (T,), bridged linearly across every gap from its edges."""
    out = local.copy()
    n = len(seen)
    for start, length in runs(~seen):
        stop = start + length
        before = np.flatnonzero(seen[max(0, start - 4 * EDGE_FRAMES):start])
        after = np.flatnonzero(seen[stop:stop + 4 * EDGE_FRAMES])
        left = local[max(0, start - 4 * EDGE_FRAMES) + before[-EDGE_FRAMES:]].mean(axis=0) if before.size else None
        right = local[stop + after[:EDGE_FRAMES]].mean(axis=0) if after.size else None
        if left is None and right is None:  # the nearest frames seen are far: their mean, nearest first
            idx = np.flatnonzero(seen)
            near = idx[np.argsort(np.abs(idx - start))[:EDGE_FRAMES]]
            left = right = local[near].mean(axis=0)
        left = right if left is None else left
        right = left if right is None else right
        if start == 0 or stop == n:
            out[start:stop] = left if start > 0 else right
            continue
        w = (np.arange(start, stop) - start + 1) / (stop - start + 1)
        out[start:stop] = (1 - w)[:, None] * left + w[:, None] * right
    return out


def fill_opensim_ik(positions: np.ndarray, *, ik_model: str | os.PathLike | None = None,
                    ik_setup: str | os.PathLike | None = None, labels: list[str] | None = None,
                    units: str = "mm", rate: float | None = None) -> FillResult:
    """Kinematic fill: OpenSim IK on the observed markers, the missing ones from the fitted model.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing; in ``units``.
    ik_model : path
        A scaled OpenSim model (.osim) whose markers carry the capture's labels.
    ik_setup : path, optional
        An IK setup XML: its marker tasks and weights, constraint weight and accuracy are used (its model file is
        not: ``ik_model`` is).
    labels : list of str
        The capture's marker names (required: they name the model's markers).

    Returns
    -------
    FillResult
        ``std`` (n_frames, n_markers) per coordinate; ``info`` holds the markers used, frames solved, and the body
        each marker the model lacks was attached to.
    """
    if ik_model is None:
        raise MethodError("method 'opensim-ik' needs a scaled OpenSim model: give --ik-model MODEL.osim")
    positions = np.asarray(positions, dtype=np.float64)
    n_frames, n_markers, _ = positions.shape
    if labels is None or len(labels) != n_markers:
        raise MethodError("method 'opensim-ik' needs the marker labels (they name the model's markers)")
    missing = np.isnan(positions).any(axis=2)
    if not missing.any():
        return finish(positions, positions, std=np.zeros((n_frames, n_markers)), info={"model": os.fspath(ik_model)})
    from ..kinematics.opensim_ik import load_setup, track

    setup = load_setup(ik_setup, ik_model)
    tracked = track(setup.model, positions, list(labels), units=units, rate=rate,
                    weights=setup.weights or None, constraint_weight=setup.constraint_weight,
                    accuracy=setup.accuracy)
    rotation, origin = tracked.body_rotation, tracked.body_origin
    estimate = np.full_like(positions, np.nan)
    std = np.full((n_frames, n_markers), np.nan)
    frame_var = np.where(np.isfinite(tracked.residual), tracked.residual, np.nanmedian(tracked.residual)) ** 2 / 3.0
    attached: dict[str, str] = {}
    observed = ~missing
    for m in range(n_markers):
        seen = observed[:, m]
        if seen.all() or not seen.any():
            continue
        body = int(tracked.marker_body[m])
        if body < 0:  # a marker the model lacks rides on the body it moves least in
            spread = np.array([np.nanmean(np.linalg.norm(
                (loc := _to_local(rotation[seen, b], origin[seen, b], positions[seen, m]))
                - np.median(loc, axis=0), axis=1)) for b in range(rotation.shape[1])])
            body = _best_body(spread)
            attached[labels[m]] = tracked.bodies[body]
        local = np.full((n_frames, 3), np.nan)
        local[seen] = _to_local(rotation[seen, body], origin[seen, body], positions[seen, m])
        bridged = _bridge(local, seen)
        gap = ~seen
        estimate[gap, m] = np.einsum("tij,tj->ti", rotation[gap, body], bridged[gap]) + origin[gap, body]
        scatter = float(np.mean(np.sum((local[seen] - local[seen].mean(axis=0)) ** 2, axis=1)) / 3.0)
        std[gap, m] = np.sqrt(scatter + frame_var[gap])
    info = {"model": setup.model, "setup": setup.setup, "ik_seconds": tracked.seconds,
            "attached": attached, **tracked.info}
    return finish(positions, estimate, std=std, info=info)
