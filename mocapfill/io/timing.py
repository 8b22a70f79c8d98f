"""The frame rate a text file's time column implies, to the precision the times were written with.

A time column is rounded where it is written: 120 Hz to six decimals is ``0.000000, 0.008333, 0.016667, ...``, whose
steps differ by a unit in the last place and whose median step gives 120.005 Hz; to three decimals the steps differ
by 12 %.  So the times are taken as evenly spaced when one line ``t0 + k step`` (k the row) passes within half a unit
of each time's last written decimal, and the rate is fitted to all of them: a round rate (a usual capture rate, an
integer, an NTSC rate) when one such line has it, else the least-squares slope.  :class:`TimeRate` also carries
every rate the times agree with, so that a caller's rate among them is no contradiction (``io.read``).
"""

from __future__ import annotations

import re
from typing import NamedTuple

import numpy as np

from ..errors import FormatError

__all__ = ["TimeRate", "rate_from_times", "written_half_units"]

#: Rates capture systems run at, tried before any other integer; then NTSC video rates (k * 1000 / 1001).
COMMON_RATES = (24.0, 25.0, 30.0, 50.0, 60.0, 100.0, 120.0, 150.0, 180.0, 200.0, 240.0, 250.0, 300.0, 360.0,
                400.0, 480.0, 500.0, 960.0, 1000.0, 2000.0)
NTSC_RATES = tuple(k * 1000.0 / 1001.0 for k in (24, 30, 60, 120, 240))
_NUMBER = re.compile(r"^[+-]?(\d*)(?:\.(\d*))?(?:[eE]([+-]?\d+))?$")
_NEWTON_PASSES = 100


class TimeRate(NamedTuple):
    """The rate (Hz) a time column gives, and the range (low, high) of rates it agrees with (both ``rate`` where
    the times were too irregular for their precision and were accepted for a step within 1 % of the median)."""

    rate: float
    low: float
    high: float


def written_half_units(cells: list[str]) -> np.ndarray:
    """Half a unit in the last written decimal of each number's text, shape (n,): ``"0.008333"`` -> 5e-7,
    ``"8.3e-3"`` -> 5e-5; 0 for text that is no plain decimal number (its precision is not known).

    A whole number (``"0"``, ``"2"``) is as precise as the coarsest cell with decimals: writers that drop trailing
    zeros write 0.0 as ``0``, and one that writes whole seconds writes them all so (then half a second).
    """
    decimals = np.zeros(len(cells))
    known = np.ones(len(cells), dtype=bool)
    for i, cell in enumerate(cells):
        text = cell.strip()
        if "e" not in text and "E" not in text:
            decimals[i] = len(text.partition(".")[2])  # the common case, without the regular expression
            continue
        match = _NUMBER.match(text)
        known[i] = bool(match and (match.group(1) or match.group(2)))
        if known[i]:
            decimals[i] = len(match.group(2) or "") - int(match.group(3) or 0)
    out = np.where(known, 0.5 * 10.0 ** -decimals, 0.0)
    whole = known & (decimals <= 0)
    if whole.any() and not whole.all():
        out[whole] = np.minimum(out[whole], out[known & ~whole].max(initial=0.0) or 0.5)
    return out


def rate_from_times(times: np.ndarray, name: str, cells: list[str] | None = None) -> TimeRate:
    """The frame rate of a time column (s), one value per row, NaN where a row has none.

    ``cells`` is the column's text (same length as ``times``): each time is then known to half a unit in its last
    written decimal; without it, to float64 precision.  Raises FormatError naming the file when the times do not
    increase or are not evenly spaced.
    """
    times = np.asarray(times, dtype=np.float64)
    rows = np.flatnonzero(np.isfinite(times))
    t = times[rows]
    steps = np.diff(t)
    if steps.size == 0 or np.any(steps < 0) or t[-1] <= t[0]:
        raise FormatError(f"{name}: the time column does not increase; cannot tell the frame rate")
    k = rows.astype(np.float64)
    half = written_half_units([cells[i] for i in rows]) if cells is not None else np.zeros(t.size)
    # Parsing and evaluating the line round too: a few units in the last place of the largest time.
    half = half + 8 * np.finfo(np.float64).eps * np.max(np.abs(t))
    span = _step_range(k, t - half, t + half)
    fitted = _least_squares_step(k, t)
    if span is not None:
        low, high = 1.0 / float(span[1]), 1.0 / float(span[0]) if span[0] > 0 else float("inf")
        return TimeRate(_round_rate(low, high, 1.0 / min(max(fitted, span[0]), span[1])), low, high)
    # Times that jitter (a clock read per frame): evenly spaced enough when every step is within 1 % of the median.
    step = float(np.median(steps))
    if np.any(steps <= 0):
        raise FormatError(f"{name}: the time column does not increase; cannot tell the frame rate")
    if np.max(np.abs(steps - step)) > 0.01 * step + 1e-9:
        raise FormatError(f"{name}: the time column is not evenly spaced; cannot tell the frame rate")
    return TimeRate(1.0 / fitted, 1.0 / fitted, 1.0 / fitted)


def _least_squares_step(k: np.ndarray, t: np.ndarray) -> float:
    dk = k - k.mean()
    return float(np.dot(dk, t - t.mean()) / np.dot(dk, dk))


def _misfit(step: float, k: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[float, float]:
    """How far apart the lowest offset ``low - k step`` needs and the highest ``high - k step`` allows (<= 0: one
    line of this step passes every time's interval), and the slope of that convex function of ``step``."""
    above, below = low - k * step, high - k * step
    i, j = int(np.argmax(above)), int(np.argmin(below))
    return float(above[i] - below[j]), float(k[j] - k[i])


def _step_range(k: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[float, float] | None:
    """The steps (s per row) of the lines through every interval [low_i, high_i] at row k_i, or None if none does.

    The misfit is convex and piecewise linear in the step, so Newton's method from each end of the steps the first
    and last times alone allow reaches the end of where it is <= 0 in a few O(n) passes, never overshooting it; a
    slope that turns before the misfit reaches 0 means no line fits.
    """
    extent = k[-1] - k[0]
    ends = []
    for step, side in ((max((low[-1] - high[0]) / extent, 0.0), -1.0), ((high[-1] - low[0]) / extent, 1.0)):
        for _ in range(_NEWTON_PASSES):
            misfit, slope = _misfit(step, k, low, high)
            if misfit <= 0:
                break
            if slope * side <= 0:
                return None  # past the minimum, which is > 0
            after = step - misfit / slope
            if after == step:
                break  # within rounding of the end
            step = after
        else:
            return None
        ends.append(step)
    return (ends[0], ends[1]) if 0 < ends[1] and ends[0] <= ends[1] else None


def _round_rate(low: float, high: float, fitted: float) -> float:
    """The roundest rate in [low, high] nearest ``fitted`` (itself within): a usual capture rate, else an integer,
    else an NTSC rate, else the decimal of fewest digits."""
    first, last = np.ceil(low), np.floor(high)
    integers = [min(max(float(round(fitted)), first), last)] if first <= last else []
    for candidates in (COMMON_RATES, integers, NTSC_RATES):
        inside = [r for r in candidates if low <= r <= high]
        if inside:
            return float(min(inside, key=lambda r: abs(r - fitted)))
    for digits in range(1, 17):
        near = round(fitted, digits)
        inside = [r for r in (near, near - 10.0 ** -digits, near + 10.0 ** -digits) if low <= r <= high]
        if inside:
            return float(min(inside, key=lambda r: abs(r - fitted)))
    return float(fitted)
