"""Is a fill physically plausible?  The body's observed extent and each marker's observed speed.

Two checks every fill of the default must pass (issue 9), measured on the input's own observations only:

- **extent**: no filled sample farther from the body's centre (per frame, the coordinate-wise median of the markers
  observed there; interpolated over frames with none) than ``EXTENT`` (1.1) times the farthest any observed marker
  ever is from it;
- **speed**: no frame-to-frame step touching a filled sample longer than ``SPEED`` (1.5) times its marker's largest
  observed step (:func:`observed_speed`).

:func:`implausible` marks the filled samples that break either; the default distrusts its model there and falls back
to something calm (a straight line through the observations, the nearest value held at the clip's edges).
"""

from __future__ import annotations

import numpy as np

from .interp import interpolate_columns

#: Filled samples may reach this multiple of the farthest observed distance from the body's centre ...
EXTENT = 1.1
#: ... and step at most this multiple of their marker's largest observed step.
SPEED = 1.5
#: Observed steps needed to know a marker's speed.
MIN_STEPS = 10


def observed_speed(positions: np.ndarray, missing: np.ndarray, *, floor: float) -> np.ndarray:
    """Each marker's largest observed frame-to-frame step (n_markers,), in data units per frame.

    positions (n_frames, n_markers, 3); missing (n_frames, n_markers).  Markers with fewer than ``MIN_STEPS``
    observed steps (too few to know how fast they move) get the largest over the markers; every value is at least
    ``floor`` and a quarter of the markers' median (a nearly still marker's noise is no speed limit).
    """
    both = ~missing[1:] & ~missing[:-1]
    step = np.where(both, np.linalg.norm(np.nan_to_num(np.diff(positions, axis=0)), axis=2), 0.0)
    speed = step.max(axis=0) if len(step) else np.zeros(positions.shape[1])
    known = both.sum(axis=0) >= MIN_STEPS
    if known.any():
        speed[~known] = speed[known].max()
        lower = 0.25 * np.median(speed[known])
    else:
        speed[:] = floor
        lower = floor
    return np.maximum(speed, max(floor, lower))


def body_centre(positions: np.ndarray, missing: np.ndarray) -> tuple[np.ndarray, float]:
    """Per-frame centre (n_frames, 3) and the farthest observed distance from it (data units).

    positions (n_frames, n_markers, 3), missing (n_frames, n_markers).  The centre is the coordinate-wise median of
    the markers observed in the frame, linearly interpolated (edges held) over frames with none; NaN throughout
    when nothing is observed (the radius is then NaN).
    """
    seen = np.where(missing[..., None], np.nan, positions)
    none = missing.all(axis=1)
    centre = np.full((positions.shape[0], 3), np.nan)
    if (~none).any():
        centre[~none] = np.nanmedian(seen[~none], axis=1)
        centre = interpolate_columns(centre, np.repeat(none[:, None], 3, axis=1))
    dist = np.linalg.norm(seen - centre[:, None, :], axis=2)
    radius = float(np.nanmax(dist)) if np.isfinite(dist).any() else float("nan")
    return centre, radius


def implausible(estimate: np.ndarray, positions: np.ndarray, speed: np.ndarray, *, factor: float = SPEED
                ) -> np.ndarray:
    """Filled samples (n_frames, n_markers) bool that leave the body's extent or step too fast.

    estimate (n_frames, n_markers, 3) the fill; positions (n_frames, n_markers, 3) the input, NaN = missing;
    speed (n_markers,) the largest observed step per marker (:func:`observed_speed`), or (n_frames - 1,
    n_markers) a per-step reference; a step longer than ``factor`` times it marks the filled sample(s) at either
    end of it.
    """
    speed = np.asarray(speed)
    if speed.ndim == 1:
        speed = speed[None, :]
    return _implausible(estimate, positions, factor * speed)


def _implausible(estimate: np.ndarray, positions: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """:func:`implausible` with ``speed`` broadcastable to (n_frames - 1, n_markers)."""
    missing = np.isnan(positions).any(axis=2)
    filled = missing & np.isfinite(estimate).all(axis=2)
    centre, radius = body_centre(positions, missing)
    out = np.zeros_like(filled)
    if np.isfinite(radius):
        far = np.linalg.norm(estimate - centre[:, None, :], axis=2) > EXTENT * radius
        out |= far & filled
    step = np.nan_to_num(np.linalg.norm(np.diff(estimate, axis=0), axis=2), nan=0.0)
    fast = step > speed
    out[1:] |= fast & filled[1:]
    out[:-1] |= fast & filled[:-1]
    return out


def plausibility(estimate: np.ndarray, positions: np.ndarray, *, floor: float = 0.0) -> dict[str, float]:
    """Worst ratios of a fill: ``extent`` (largest filled distance from the centre over the farthest observed) and
    ``speed`` (largest step touching a filled sample over its marker's largest observed step).

    estimate / positions (n_frames, n_markers, 3) as in :func:`implausible`; ``floor`` the slowest speed limit
    (data units per frame).  0 when nothing is filled.
    """
    missing = np.isnan(positions).any(axis=2)
    filled = missing & np.isfinite(estimate).all(axis=2)
    if not filled.any():
        return {"extent": 0.0, "speed": 0.0}
    centre, radius = body_centre(positions, missing)
    dist = np.linalg.norm(estimate - centre[:, None, :], axis=2)
    extent = float(dist[filled].max() / radius) if np.isfinite(radius) and radius > 0 else float("nan")
    speed = observed_speed(positions, missing, floor=floor)
    step = np.linalg.norm(np.diff(estimate, axis=0), axis=2) / speed[None, :]
    touch = (filled[1:] | filled[:-1]) & np.isfinite(step)
    return {"extent": extent, "speed": float(step[touch].max()) if touch.any() else 0.0}
