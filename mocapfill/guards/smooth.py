"""Optional output smoothing: a Savitzky-Golay filter per coordinate, run by run.

Holden (2018) smooths the solved motion with a Savitzky-Golay filter to remove frame-to-frame jitter.  Here it is
an opt-in last step (``fill --smooth``): it changes observed samples too, so reports must say it was applied.

NaN-aware: each run of consecutive finite samples of a marker is filtered on its own (edges by polynomial fit,
SciPy's ``mode="interp"``), so nothing is smoothed across a gap; runs shorter than the window are left as they are.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

from ..errors import MocapfillError
from ..gaps import runs

#: Default polynomial order (3 keeps peaks better than 2 for the same window).
DEFAULT_ORDER = 3
#: Default window when the frame rate is unknown (frames).
DEFAULT_WINDOW = 7
#: Default window duration when the rate is known: 1/15 s (9 frames at 120 Hz, 7 at 100 Hz, 5 at 50 Hz).
DEFAULT_WINDOW_SECONDS = 1.0 / 15.0


def default_window(order: int = DEFAULT_ORDER, rate: float | None = None) -> int:
    """The default window in frames: odd, about ``DEFAULT_WINDOW_SECONDS`` at ``rate``, at least ``order + 2``."""
    if rate is None or not rate > 0:
        window = DEFAULT_WINDOW
    else:
        window = int(round(rate * DEFAULT_WINDOW_SECONDS))
    window = max(window, order + 2)
    return window if window % 2 == 1 else window + 1


def short_runs(positions: np.ndarray, window: int) -> list[tuple[int, int, int]]:
    """The runs :func:`savgol_smooth` leaves as they are: ``(marker, start, length)`` of every run of finite samples
    of ``positions`` (n_frames, n_markers, 3) shorter than ``window`` frames (none when ``window`` is 1)."""
    if window <= 1:
        return []
    finite = np.isfinite(positions).all(axis=2)
    return [(m, start, length) for m in range(finite.shape[1]) for start, length in runs(finite[:, m])
            if length < window]


def savgol_smooth(positions: np.ndarray, *, window: int | None = None, order: int = DEFAULT_ORDER,
                  rate: float | None = None) -> np.ndarray:
    """Savitzky-Golay smoothing of every coordinate, each observed run separately.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing (a sample with any NaN coordinate counts as missing and is returned as given).
    window : int, optional
        Window length in frames, odd and > ``order``.  Default from ``rate`` (see :func:`default_window`).
    order : int
        Polynomial order, >= 0.
    rate : float, optional
        Frame rate in Hz, only used for the default window.

    Returns
    -------
    ndarray, shape (n_frames, n_markers, 3)
        A new array: runs of at least ``window`` finite samples smoothed, everything else as given.

    Raises
    ------
    MocapfillError
        ``window`` even, not larger than ``order``, or ``order`` negative.
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise MocapfillError(f"positions must have shape (n_frames, n_markers, 3), got {positions.shape}")
    if order < 0:
        raise MocapfillError(f"Savitzky-Golay order must be >= 0, got {order}")
    if window is None:
        window = default_window(order, rate)
    if window < 1 or window % 2 == 0 or window <= order:
        raise MocapfillError(f"Savitzky-Golay window must be an odd number of frames larger than the order "
                             f"({order}), got {window}")
    out = positions.copy()
    if window == 1:
        return out
    finite = np.isfinite(positions).all(axis=2)
    for m in range(positions.shape[1]):
        for start, length in runs(finite[:, m]):
            if length >= window:
                out[start:start + length, m] = savgol_filter(positions[start:start + length, m], window, order,
                                                             axis=0, mode="interp")
    return out
