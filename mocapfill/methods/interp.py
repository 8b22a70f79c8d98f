"""Per-coordinate interpolation: ``linear`` and ``spline`` (cubic).

Both treat every marker on its own, using only that marker's observed frames:

- Interior gaps (observations on both sides, including whole-body blackouts) are interpolated: straight lines for
  ``linear``; for ``spline`` a piecewise cubic through the observed samples (see :func:`fill_spline`).
- Edge gaps (before the first or after the last observation of a marker) are **held**: the nearest observed value is
  copied.  Nothing is extrapolated, so a fill can never run away from the data; a marker with a single observation
  is held at that value for the whole clip.
- A marker never observed stays NaN (reported in ``info["all_missing"]``).

Shapes: ``positions`` is ``(n_frames, n_markers, 3)`` float64 with NaN = missing, throughout.
"""

from __future__ import annotations

import numpy as np

from ..gaps import all_missing_markers, missing_mask
from .base import FillResult, finish


def interpolate_columns(values: np.ndarray, missing: np.ndarray, *, empty: float | None = None) -> np.ndarray:
    """Linear interpolation down each column over its observed entries, the nearest one held beyond both ends.

    Parameters
    ----------
    values : ndarray, shape (n_frames, m)
        Entries where ``missing`` is True are ignored.
    missing : ndarray of bool, shape (n_frames, m)
    empty : float, optional
        Value for a column with no observation (left as it is when None).

    Returns
    -------
    ndarray, shape (n_frames, m): a copy with the missing entries interpolated.
    """
    out = np.array(values, dtype=np.float64).T.copy()  # columns as contiguous rows
    miss = np.asarray(missing, dtype=bool).T
    frames = np.arange(out.shape[1])
    for j in np.flatnonzero(miss.any(axis=1)):
        seen = ~miss[j]
        if seen.any():
            # np.interp holds the end values outside the observed range: exactly the edge policy we want.
            out[j, ~seen] = np.interp(frames[~seen], frames[seen], out[j, seen])
        elif empty is not None:
            out[j] = empty
    return np.ascontiguousarray(out.T)


def interpolate_linear(positions: np.ndarray) -> np.ndarray:
    """Linear interpolation of every marker over its own observed frames, edges held.

    The initial guess of the iterative methods (MSVD, bilinear) as well as ``linear``'s fill.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing (all three coordinates together).

    Returns
    -------
    ndarray, shape (n_frames, n_markers, 3)
        Every sample of a marker observed at least once is finite; markers never observed stay NaN.
    """
    positions = np.asarray(positions, dtype=np.float64)
    n_frames, n_markers, _ = positions.shape
    missing = np.repeat(missing_mask(positions), 3, axis=1)  # one column per coordinate
    return interpolate_columns(positions.reshape(n_frames, 3 * n_markers), missing).reshape(positions.shape)


def _spline_marker(frames: np.ndarray, seen: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Cubic-spline estimate of one marker on its missing frames inside its observed range, edges held.

    ``frames`` (n_frames,), ``seen`` (n_frames,) bool, ``values`` (n_frames, 3); returns (n_frames, 3) with the
    estimate on the missing frames (observed rows are returned unchanged).
    """
    out = values.copy()
    t_seen = frames[seen]
    first, last = t_seen[0], t_seen[-1]
    gone = ~seen
    if t_seen.size >= 2:
        inside = gone & (frames > first) & (frames < last)
        if inside.any():
            # Not-a-knot through every observed frame: C2 at the gap ends, so the fill leaves each gap with the
            # slope and curvature the marker had when it disappeared (scipy degrades to a parabola / line for 3 / 2
            # observations).
            from scipy.interpolate import CubicSpline  # here: scipy.interpolate costs ~0.3 s to import

            spline = CubicSpline(t_seen, values[seen], axis=0, bc_type="not-a-knot")
            out[inside] = spline(frames[inside])
    out[gone & (frames < first)] = values[seen][0]
    out[gone & (frames > last)] = values[seen][-1]
    return out


def _info(missing: np.ndarray) -> dict:
    dead = all_missing_markers(missing)
    return {"all_missing": [int(m) for m in dead], "edges": "held"}


def fill_linear(positions: np.ndarray, *, seed: int | None = None) -> FillResult:
    """Fill each marker's gaps by linear interpolation per coordinate; edge gaps hold the nearest observation.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    seed : ignored (the method is deterministic); accepted for a uniform interface.

    Returns
    -------
    FillResult
        ``positions`` (n_frames, n_markers, 3); every marker observed at least once is filled completely, including
        whole-body blackout frames; ``info["all_missing"]`` lists markers never observed (left NaN).
    """
    positions = np.asarray(positions, dtype=np.float64)
    missing = missing_mask(positions)
    return finish(positions, interpolate_linear(positions), info=_info(missing))


def fill_spline(positions: np.ndarray, *, seed: int | None = None) -> FillResult:
    """Fill each marker's gaps with a cubic spline through its observed frames; edge gaps hold the nearest one.

    The spline is scipy's not-a-knot cubic through every observed frame of the marker (all three coordinates at
    once), so it is C2 across the gap ends.  Before the first and after the last observation the marker is held at
    that observation (no extrapolation: a cubic run beyond its data is unbounded).

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    seed : ignored (the method is deterministic); accepted for a uniform interface.

    Returns
    -------
    FillResult
        ``positions`` (n_frames, n_markers, 3); every marker observed at least once is filled completely, including
        whole-body blackout frames; ``info["all_missing"]`` lists markers never observed (left NaN).
    """
    positions = np.asarray(positions, dtype=np.float64)
    missing = missing_mask(positions)
    estimate = positions.copy()
    frames = np.arange(positions.shape[0], dtype=np.float64)
    for marker in np.flatnonzero(missing.any(axis=0) & ~missing.all(axis=0)):
        estimate[:, marker] = _spline_marker(frames, ~missing[:, marker], positions[:, marker])
    return finish(positions, estimate, info=_info(missing))
