"""What a fill may touch: gaps longer than ``--max-gap``, gaps at the capture's edges (``--edges leave``) and the
markers ``--markers`` / ``--exclude`` did not choose stay missing.

Every marker still informs the fill (a method sees the whole capture); the gaps a user asked to leave are put back
to missing afterwards (:func:`leave_missing`), so observed samples stay bit-identical and the filled samples of the
other gaps are what the method gave.  Each sample left missing carries its reason as a :class:`~mocapfill.status.Status`
code (:func:`leave_reasons`), which the status array, the reports and the summary read.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

import numpy as np

from ..errors import MethodError
from ..gaps import find_gaps
from ..methods.base import FillResult, review_indices
from ..status import NAMES, Status

#: What ``--edges`` accepts: fill the gaps that touch the first or last frame (today's behaviour), or leave them.
EDGE_CHOICES = ("fill", "leave")

#: The reasons a gap is left missing on request, in the order they win when several apply (a marker not chosen is
#: left whatever its gaps; an edge gap is left under ``--edges leave`` whatever its length).
LEAVE_REASONS = (Status.MISSING_NOT_CHOSEN, Status.MISSING_EDGE, Status.MISSING_TOO_LONG)


def duration_form(value: Any, *, name: str = "--max-gap") -> tuple[float, bool]:
    """(number, in seconds?) of a duration given as ``40`` / ``"40"`` (frames) or ``"0.5s"`` (seconds).

    Raises MethodError naming ``name`` and the value for anything else, for a fraction of a frame and for zero.
    """
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        number, seconds = float(value), False
    else:
        text = str(value).strip().lower()
        match = re.fullmatch(r"([0-9]*\.?[0-9]+(?:e[-+]?[0-9]+)?)\s*(s|f|frames?)?", text)
        if not match:
            raise MethodError(f"{name} {value!r}: expected frames (40) or seconds (0.5s)")
        number, seconds = float(match.group(1)), match.group(2) == "s"
    if not seconds and number != int(number):
        raise MethodError(f"{name} {value!r}: a number of frames must be whole (or give seconds: 0.5s)")
    if not number > 0:
        raise MethodError(f"{name} {value!r}: must be more than zero")
    return number, seconds


def parse_max_gap(value: Any, rate: float | None, *, name: str = "--max-gap") -> int:
    """A gap length in frames from ``40`` / ``"40"`` (frames) or ``"0.5s"`` (seconds at ``rate``, rounded to the
    nearest frame, at least one).

    Raises MethodError naming ``name`` and the value for a malformed value (:func:`duration_form`) or for seconds
    without a frame rate.
    """
    number, seconds = duration_form(value, name=name)
    if not seconds:
        return int(number)
    if rate is None or not rate > 0 or not math.isfinite(rate):
        raise MethodError(f"{name} {value!r}: the capture has no frame rate to convert seconds")
    return max(1, int(math.floor(number * rate + 0.5)))


def check_edges(edges: str, *, name: str = "--edges") -> str:
    """``edges`` when it is one of :data:`EDGE_CHOICES`; MethodError otherwise."""
    if edges not in EDGE_CHOICES:
        raise MethodError(f"{name} {edges!r}: choose one of {', '.join(EDGE_CHOICES)}")
    return edges


def leave_reasons(missing: np.ndarray, *, max_gap: int | None = None, edges: str = "fill",
                  chosen: np.ndarray | None = None) -> np.ndarray:
    """Which missing samples to leave missing, and why.

    Parameters
    ----------
    missing : ndarray of bool, shape (n_frames, n_markers)
        The gaps the fill sees (the input's, with rejected samples).
    max_gap : int or None
        Gaps longer than this many frames are left (:attr:`Status.MISSING_TOO_LONG`); None = no limit.
    edges : "fill" or "leave"
        "leave": gaps touching the first or last frame are left (:attr:`Status.MISSING_EDGE`).
        (A marker missing in every frame is neither: nothing can fill it, and it is reported as never observed.)
    chosen : ndarray of bool, shape (n_markers,), or None
        The markers to fill; the gaps of the others are left (:attr:`Status.MISSING_NOT_CHOSEN`).  None = all.

    Returns
    -------
    ndarray of int8, shape (n_frames, n_markers)
        0 where a sample is observed or its gap is to be filled, else the reason's :class:`Status` code.
    """
    missing = np.asarray(missing, dtype=bool)
    check_edges(edges)
    reasons = np.zeros(missing.shape, dtype=np.int8)
    if chosen is not None:
        chosen = np.asarray(chosen, dtype=bool).reshape(missing.shape[1])
        reasons[:, ~chosen] = np.where(missing[:, ~chosen], int(Status.MISSING_NOT_CHOSEN), 0)
    if max_gap is None and edges == "fill":
        return reasons
    for gap in find_gaps(missing):
        if chosen is not None and not chosen[gap.marker]:
            continue
        if gap.length == missing.shape[0]:  # a marker never observed: no limit left it (it stays MISSING)
            continue
        if edges == "leave" and (gap.at_start or gap.at_end):
            reasons[gap.start:gap.stop, gap.marker] = Status.MISSING_EDGE
        elif max_gap is not None and gap.length > max_gap:
            reasons[gap.start:gap.stop, gap.marker] = Status.MISSING_TOO_LONG
    return reasons


def leave_missing(result: FillResult, reasons: np.ndarray) -> FillResult:
    """``result`` with the samples ``reasons`` marks (non-zero, (n_frames, n_markers)) put back to missing.

    Positions become NaN there, ``filled`` False and ``std`` NaN; observed samples are not touched (``reasons`` is
    non-zero only on missing samples).  ``info["left_missing"]`` lists the stretches left, one
    ``{"marker": index, "start": 0-based frame, "length": frames, "reason": text}`` each.
    """
    reasons = np.asarray(reasons)
    left = reasons != 0
    info = dict(result.info)
    info["left_missing"] = left_records(reasons)
    if not left.any():
        return dataclasses.replace(result, info=info)
    if isinstance(info.get("gap_methods"), list):  # a gap left is not filled: its record says so, not how it was
        info["gap_methods"] = [_left_record(rec, reasons) for rec in info["gap_methods"]]
        if "review" in info:
            info["review"] = review_indices(info["gap_methods"])
    positions = result.positions.copy()
    positions[left] = np.nan
    filled = np.asarray(result.filled, dtype=bool) & ~left
    std = None
    if result.std is not None:
        std = np.array(result.std, dtype=np.float64)
        std[left] = np.nan
    return dataclasses.replace(result, positions=positions, filled=filled, std=std, info=info)


def _left_record(rec: Any, reasons: np.ndarray) -> Any:
    """A fill's record of one gap (``{"marker_index", "start", "length", ...}``, e.g. ``auto``'s ``gap_methods``) as
    it stands once ``reasons`` ((n_frames, n_markers) :class:`Status` codes) left that gap missing: method "none",
    the reason's name, nothing to review; records of gaps filled, and anything else, unchanged."""
    try:
        m, start, length = int(rec["marker_index"]), int(rec["start"]), int(rec["length"])
    except (KeyError, TypeError, ValueError):
        return rec
    codes = reasons[start:start + length, m] if 0 <= m < reasons.shape[1] else np.zeros(0)
    if not length or len(codes) != length or not (codes != 0).all():
        return rec
    out = {k: v for k, v in rec.items() if k not in ("extrapolation",)}
    out.update(method="none", reason=f"{NAMES[Status(int(codes[0]))]}: not filled", review=False, max_std=None)
    return out


def left_records(reasons: np.ndarray) -> list[dict[str, Any]]:
    """The stretches of ``reasons`` ((n_frames, n_markers) int8 :class:`Status` codes, 0 = not left): one
    ``{"marker", "start", "length", "reason"}`` each, ordered by marker then frame."""
    reasons = np.asarray(reasons)
    out = []
    for gap in find_gaps(reasons != 0):
        code = Status(int(reasons[gap.start, gap.marker]))
        out.append({"marker": gap.marker, "start": gap.start, "length": gap.length, "reason": NAMES[code]})
    return out


def apply_limits(result: FillResult, missing: np.ndarray, *, max_gap: int | None = None, edges: str = "fill",
                 chosen: np.ndarray | None = None) -> tuple[FillResult, np.ndarray]:
    """:func:`leave_reasons` of ``missing`` (n_frames, n_markers) and :func:`leave_missing` of ``result``;
    returns (the result, the reasons (n_frames, n_markers) int8)."""
    reasons = leave_reasons(missing, max_gap=max_gap, edges=edges, chosen=chosen)
    return leave_missing(result, reasons), reasons
