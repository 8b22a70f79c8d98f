"""Butterworth low-pass filtering after the fill (``fill --lowpass HZ|auto``), with Winter's residual analysis.

The filter is the biomechanics textbook's (Winter, *Biomechanics and Motor Control of Human Movement*, ch. 3): a
2nd-order low-pass Butterworth designed by ``scipy.signal.butter`` (bilinear transform, pre-warped so the digital
filter's gain is exactly 1/sqrt(2) at the cutoff) and run forward and backward by ``scipy.signal.filtfilt``: zero
lag, and a 4th-order response ``|H(f)|^2 = 1 / (1 + (f / fc)^4)`` (before pre-warping) whose **gain at the cutoff is
0.5**.  **No cutoff correction is applied**: the cutoff given is where the two-pass filter halves an amplitude; its
-3 dB point lies lower, at 0.802 fc (Winter's correction for a double pass, ``(2^(1/2) - 1)^(1/4)``, would move the
design cutoff up by 1/0.802 to put the -3 dB point at fc; we do not).

Each continuous stretch of a marker (frames where it is finite after the fill) is filtered on its own, its ends
padded by odd reflection (``filtfilt``'s default, ``3 * 3`` frames); gaps left unfilled stay as they are and nothing
is filtered across them; a stretch shorter than ``MIN_STRETCH`` frames is left as it is.  Observed samples change:
the caller reports them (status ``SMOOTHED``).  A cutoff the filter cannot realise is refused in one line
(:func:`check_cutoff`): below :func:`lowest_cutoff`, where the design loses double precision (``PRECISION``) or
the take holds less than one period of it.

``cutoff="auto"``: Winter's residual analysis.  For cutoffs ``fc`` on a grid, the residual ``R(fc)`` is the RMS
difference between the data and the data filtered at ``fc`` (over observed samples only: a filled sample carries no
measurement noise).  At high cutoffs what is removed is noise alone and ``R`` falls on a straight line; that line,
fitted over ``FIT_RANGE`` (fractions of the frame rate) and projected back to ``fc = 0``, meets the axis at the
noise's RMS ``a``; the chosen cutoff is where ``R`` first comes down to ``a`` (linear interpolation on the grid):
below it the filter would remove signal as well as noise.  A capture without a white-noise floor (already smoothed,
or simulated) may never come down to ``a``: the cutoff is then the lowest of the fit range (20 % of the rate), which
leaves it nearly as it is.  Per take (one cutoff) or per marker.

Shapes: ``positions`` (n_frames, n_markers, 3) float64, NaN = missing; masks (n_frames, n_markers) bool.
"""

from __future__ import annotations

from collections import defaultdict
from typing import NamedTuple

import numpy as np
from scipy.signal import butter, filtfilt

from ..errors import MethodError
from ..gaps import runs

#: The design order: 2, run forward and backward (zero lag, 4th-order response, gain 0.5 at the cutoff).
ORDER = 2
#: Shortest stretch filtered (frames): filtfilt's odd-reflection padding of 3 x 3 frames plus one.
MIN_STRETCH = 3 * (ORDER + 1) + 1
#: Residual analysis: the cutoff grid runs from this fraction of the frame rate ...
GRID_LOW = 0.005
#: ... to this one (below the Nyquist frequency, 0.5, where the bilinear design degenerates) ...
GRID_HIGH = 0.45
#: ... in this many steps (0.44 % of the rate: 0.5 Hz at 120 Hz; the crossing is interpolated between them).
GRID_STEPS = 100
#: Residual analysis of a long take: at most this many evenly spaced windows ...
ANALYSIS_WINDOWS = 4
#: ... of this many frames each (a 100,000-frame take costs what a 4,000-frame one does).
ANALYSIS_WINDOW = 1000
#: Largest relative error the filter may add to a coordinate (a micrometre per metre: below any capture's resolution).
#: filtfilt's initial state solves (I - A) z = B, whose determinant is sum(a) = 4 K^2 / (1 + sqrt(2) K + K^2) with
#: K = tan(pi fc / rate): rounding grows as eps / sum(a), so a cutoff below 2.4e-6 of the rate costs more than this,
#: and below about 1e-9 of it the system is singular (LinAlgError).
PRECISION = 1e-6
#: Residual analysis: the straight line of the noise is fitted to the residuals of cutoffs in this range (fractions of
#: the frame rate: 20 % to 40 %, i.e. 24 Hz to 48 Hz at 120 Hz), above the content of human movement (< 15 Hz).
FIT_RANGE = (0.2, 0.4)


class LowpassResult(NamedTuple):
    """``positions`` (n_frames, n_markers, 3) filtered; ``cutoff``: Hz, one float (or (n_markers,) per marker, NaN
    for a marker without enough data to choose one: left as it was); ``changed`` (n_frames, n_markers) bool: samples
    whose value the filter changed."""

    positions: np.ndarray
    cutoff: float | np.ndarray
    changed: np.ndarray


def lowest_cutoff(rate: float, n_frames: int | None = None) -> float:
    """The lowest cutoff (Hz) the filter realises at ``rate``: where double rounding stays within :data:`PRECISION`
    (sum(a) >= eps / PRECISION), and with ``n_frames``, one period of the cutoff within the take (a slower component
    has no amplitude in the take for the filter to halve)."""
    k = np.sqrt(np.finfo(np.float64).eps / (4 * PRECISION))  # 4 K^2 = eps / PRECISION, K small
    lowest = rate / np.pi * np.arctan(k)
    if n_frames:
        lowest = max(lowest, rate / n_frames)
    return float(lowest)


def check_cutoff(cutoff: float, rate: float, n_frames: int | None = None, *, path: str | None = None,
                 name: str = "--lowpass") -> None:
    """Raise MethodError (naming ``path`` and ``name``) for a cutoff of ``cutoff`` Hz the filter cannot realise on a
    take of ``n_frames`` at ``rate`` Hz: not below half the rate, or below :func:`lowest_cutoff`."""
    where = f"{path}: " if path else ""
    if not (rate > 0 and np.isfinite(rate)):
        raise MethodError(f"{where}a low-pass filter needs the frame rate (give --rate)")
    if not (0 < cutoff < rate / 2):
        raise MethodError(f"{where}low-pass cutoff {cutoff:g} Hz must lie between 0 and half the frame rate "
                          f"({rate / 2:g} Hz)")
    if cutoff < lowest_cutoff(rate):
        raise MethodError(f"{where}{name} {cutoff:g} Hz is too low for a frame rate of {rate:g} Hz: the filter's "
                          f"coefficients lose double precision below {lowest_cutoff(rate):.3g} Hz")
    if n_frames and cutoff < lowest_cutoff(rate, n_frames):
        raise MethodError(f"{where}{name} {cutoff:g} Hz is too low for the take: its {n_frames} frames at {rate:g} Hz "
                          f"hold less than one period of it (the lowest is {lowest_cutoff(rate, n_frames):.3g} Hz)")


def _coefficients(cutoff: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    check_cutoff(cutoff, rate, name="low-pass cutoff")
    return butter(ORDER, cutoff, btype="low", fs=rate)


def _stretches(finite: np.ndarray) -> dict[tuple[int, int], list[int]]:
    """Markers per continuous stretch (start, length) of at least MIN_STRETCH frames; ``finite`` (n_frames, n_m)."""
    groups: dict[tuple[int, int], list[int]] = defaultdict(list)
    for m in range(finite.shape[1]):
        for start, length in runs(finite[:, m]):
            if length >= MIN_STRETCH:
                groups[(start, length)].append(m)
    return groups


def butterworth(positions: np.ndarray, cutoff: float | np.ndarray, rate: float) -> np.ndarray:
    """Zero-lag 4th-order Butterworth low-pass of every continuous stretch (see the module docstring).

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    cutoff : float or ndarray of shape (n_markers,)
        Hz, where the two-pass filter's gain is 0.5; per marker a NaN leaves that marker as it is.
    rate : float
        Frame rate, Hz.

    Returns
    -------
    ndarray, shape (n_frames, n_markers, 3): a new array; missing samples and short stretches as given.
    """
    positions = np.asarray(positions, dtype=np.float64)
    n_markers = positions.shape[1]
    cutoffs = np.broadcast_to(np.asarray(cutoff, dtype=np.float64), (n_markers,))
    coefficients = {fc: _coefficients(fc, rate) for fc in {float(c) for c in cutoffs if np.isfinite(c)}}
    out = positions.copy()
    for (start, length), markers in _stretches(np.isfinite(positions).all(axis=2)).items():
        by_cutoff: dict[float, list[int]] = defaultdict(list)
        for m in markers:
            if np.isfinite(cutoffs[m]):
                by_cutoff[float(cutoffs[m])].append(m)
        for fc, ms in by_cutoff.items():
            b, a = coefficients[fc]
            block = np.ascontiguousarray(positions[start:start + length, ms].transpose(1, 2, 0))
            out[start:start + length, ms] = filtfilt(b, a, block, axis=-1).transpose(2, 0, 1)
    return out


def residuals(positions: np.ndarray, rate: float, cutoffs: np.ndarray, *, observed: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Winter's residual per cutoff and marker: RMS of (data - filtered), over ``observed`` samples and coordinates.

    ``positions`` (n_frames, n_markers, 3), ``cutoffs`` (k,) Hz, ``observed`` (n_frames, n_markers) bool (default:
    every finite sample).  Returns ``(sum of squares (k, n_markers), counts (n_markers,))``: a per-take residual is
    ``sqrt(sum over markers / sum of counts)``, a marker's ``sqrt(ss / count)``.
    """
    positions = np.asarray(positions, dtype=np.float64)
    finite = np.isfinite(positions).all(axis=2)
    use = finite if observed is None else (finite & np.asarray(observed, dtype=bool))
    counted = np.zeros_like(use)
    groups = _stretches(finite)
    for (start, length), markers in groups.items():
        counted[start:start + length, markers] = use[start:start + length, markers]
    # Each stretch once as contiguous rows (marker x coordinate, frames): filtering along the last axis is fastest.
    blocks = [(np.ascontiguousarray(positions[start:start + length, markers].transpose(1, 2, 0)),
               np.ascontiguousarray(counted[start:start + length, markers].T), markers)
              for (start, length), markers in groups.items()]
    ss = np.zeros((len(cutoffs), positions.shape[1]))
    for i, fc in enumerate(cutoffs):
        b, a = _coefficients(float(fc), rate)
        for block, weight, markers in blocks:
            diff = block - filtfilt(b, a, block, axis=-1)
            ss[i, markers] += np.einsum("mct,mt->m", diff * diff, weight)
    return ss, 3 * counted.sum(axis=0)


def crossing_cutoff(cutoffs: np.ndarray, residual: np.ndarray, rate: float) -> float:
    """Winter's cutoff from a residual curve ``residual`` (k,) over ``cutoffs`` (k,) Hz ascending (module
    docstring); NaN when the curve is flat zero."""
    fit = (cutoffs >= FIT_RANGE[0] * rate) & (cutoffs <= FIT_RANGE[1] * rate)
    slope, intercept = np.polyfit(cutoffs[fit], residual[fit], 1)
    if not np.isfinite(intercept) or residual.max() <= 0:
        return float("nan")
    below = np.flatnonzero(residual <= intercept)
    if below.size == 0:  # never down to the noise line: the lowest cutoff of the fit range
        return float(cutoffs[fit][0])
    i = int(below[0])
    if i == 0:
        return float(cutoffs[0])
    r0, r1 = residual[i - 1], residual[i]
    w = (r0 - intercept) / (r0 - r1) if r0 != r1 else 1.0
    return float(cutoffs[i - 1] + w * (cutoffs[i] - cutoffs[i - 1]))


def _analysis_frames(positions: np.ndarray, observed: np.ndarray | None
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """A long take cut to ``ANALYSIS_WINDOWS`` evenly spaced windows, joined with a NaN frame between them (so no
    stretch crosses a join); shapes as given, fewer frames."""
    n_frames = positions.shape[0]
    if n_frames <= ANALYSIS_WINDOWS * ANALYSIS_WINDOW:
        return positions, observed
    starts = np.linspace(0, n_frames - ANALYSIS_WINDOW, ANALYSIS_WINDOWS).round().astype(int)
    gap = np.full((1,) + positions.shape[1:], np.nan)
    parts, masks = [], []
    for start in starts:
        parts += [positions[start:start + ANALYSIS_WINDOW], gap]
        if observed is not None:
            masks += [observed[start:start + ANALYSIS_WINDOW], np.zeros((1, positions.shape[1]), dtype=bool)]
    return np.concatenate(parts), (np.concatenate(masks) if observed is not None else None)


def residual_cutoff(positions: np.ndarray, rate: float, *, observed: np.ndarray | None = None,
                    per: str = "take") -> float | np.ndarray:
    """The cutoff (Hz) chosen by Winter's residual analysis, for the take (a float) or per marker ((n_markers,),
    NaN for a marker with no stretch of ``MIN_STRETCH`` observed frames).  Arguments as :func:`residuals`."""
    if per not in ("take", "marker"):
        raise MethodError(f"residual analysis is per 'take' or per 'marker', not {per!r}")
    _coefficients(GRID_LOW * rate, rate)  # checks the rate
    positions, observed = _analysis_frames(np.asarray(positions, dtype=np.float64), observed)
    cutoffs = np.linspace(GRID_LOW, GRID_HIGH, GRID_STEPS) * rate
    ss, counts = residuals(positions, rate, cutoffs, observed=observed)
    if per == "take":
        if counts.sum() == 0:
            raise MethodError("no stretch long enough for a residual analysis")
        return crossing_cutoff(cutoffs, np.sqrt(ss.sum(axis=1) / counts.sum()), rate)
    out = np.full(positions.shape[1], np.nan)
    for m in np.flatnonzero(counts > 0):
        out[m] = crossing_cutoff(cutoffs, np.sqrt(ss[:, m] / counts[m]), rate)
    return out


def parse_cutoff(value: float | str) -> tuple[float | str, str]:
    """``--lowpass``'s value as ``(cutoff, per)``: a number of Hz, ``"auto"`` (one cutoff for the take) or
    ``"auto-marker"`` (one per marker).  Raises MethodError otherwise."""
    text = str(value).strip().lower()
    if text in ("auto", "auto-take"):
        return "auto", "take"
    if text == "auto-marker":
        return "auto", "marker"
    try:
        cutoff = float(text.removesuffix("hz"))
    except ValueError:
        raise MethodError(f"low-pass cutoff must be a frequency in Hz, 'auto' or 'auto-marker', not {value!r}"
                          ) from None
    if not (cutoff > 0 and np.isfinite(cutoff)):
        raise MethodError(f"low-pass cutoff must be a positive frequency in Hz, not {value!r}")
    return cutoff, "take"


def describe(cutoff: float | np.ndarray) -> str:
    """The cutoff used, for people: "6 Hz", or the range of per-marker cutoffs."""
    values = np.atleast_1d(np.asarray(cutoff, dtype=float))
    values = values[np.isfinite(values)]
    if values.size == 0:
        return "no cutoff (nothing filtered)"
    if values.size == 1 or np.ptp(values) == 0:
        return f"{values[0]:.3g} Hz"
    return f"{values.min():.3g} to {values.max():.3g} Hz (median {np.median(values):.3g}) per marker"


def lowpass(positions: np.ndarray, rate: float, cutoff: float | str = "auto", *, per: str = "take",
            observed: np.ndarray | None = None) -> LowpassResult:
    """Low-pass every continuous stretch after a fill: a given cutoff, or ``"auto"`` (residual analysis).

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        The filled capture, NaN where gaps were left.
    rate : float
        Frame rate, Hz.
    cutoff : float or "auto"
        Hz (gain 0.5 there), or chosen by :func:`residual_cutoff`.
    per : "take" or "marker"
        With ``"auto"``: one cutoff for the take or one per marker.
    observed : ndarray of bool, shape (n_frames, n_markers), optional
        The samples observed before the fill: the residual analysis uses only these.

    Returns
    -------
    LowpassResult
    """
    positions = np.asarray(positions, dtype=np.float64)
    if isinstance(cutoff, str):
        if cutoff != "auto":
            raise MethodError(f"low-pass cutoff must be a frequency in Hz or 'auto', not {cutoff!r}")
        chosen: float | np.ndarray = residual_cutoff(positions, rate, observed=observed, per=per)
    else:
        chosen = float(cutoff)
    out = butterworth(positions, chosen, rate)
    changed = (out != positions).any(axis=2) & np.isfinite(positions).all(axis=2)
    return LowpassResult(out, chosen, changed)
