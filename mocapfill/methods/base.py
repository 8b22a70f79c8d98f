"""What every fill method returns, and the shared step that guarantees observed samples come back untouched."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

#: Progress callback a method may call once per iteration: ``progress(iteration, n_max, objective)``.
ProgressFn = Callable[[int, int, float], None]


@dataclass
class FillResult:
    """The outcome of one fill.

    Attributes
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3), float64
        Input positions with the gaps the method could fill filled; observed samples are bit-identical to the input;
        samples the method could not fill stay NaN.
    filled : ndarray of bool, shape (n_frames, n_markers)
        True for samples missing in the input and finite in ``positions``.
    std : ndarray, shape (n_frames, n_markers), or None
        Per-sample standard deviation (data units) of a filled sample where the method has one (0 on observed
        samples, NaN where unknown); None when the method gives no uncertainty.
    n_iter : int
        Iterations run (0 for direct methods).
    converged : bool
        Whether an iterative method met its tolerance (True for direct methods).
    objective : list of float
        The objective per iteration (e.g. DynaMMo's negative expected log-likelihood); empty for direct methods.
    info : dict
        Method-specific facts for reports (chosen rank, hidden dimension, bones used, which sub-method filled each
        gap, ...).  JSON-serialisable values only.
    """

    positions: np.ndarray
    filled: np.ndarray
    std: np.ndarray | None = None
    n_iter: int = 0
    converged: bool = True
    objective: list[float] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)


def finish(
    original: np.ndarray,
    estimate: np.ndarray,
    *,
    std: np.ndarray | None = None,
    n_iter: int = 0,
    converged: bool = True,
    objective: list[float] | None = None,
    info: dict[str, Any] | None = None,
) -> FillResult:
    """Build a :class:`FillResult`: copy observed samples back bit-for-bit and compute the filled mask.

    Parameters
    ----------
    original : ndarray, shape (n_frames, n_markers, 3)
        The method's input, NaN = missing.
    estimate : ndarray, shape (n_frames, n_markers, 3)
        The method's reconstruction; its values at observed samples are ignored.  A missing sample whose estimate
        has any non-finite coordinate stays missing (all three coordinates NaN).
    std : ndarray, shape (n_frames, n_markers), optional
        Per-sample standard deviation; forced to 0 on observed samples and NaN on samples left missing.
    """
    original = np.asarray(original, dtype=np.float64)
    estimate = np.asarray(estimate, dtype=np.float64)
    missing = np.isnan(original).any(axis=2)
    usable = np.isfinite(estimate).all(axis=2)
    filled = missing & usable
    out = original.copy()
    out[filled] = estimate[filled]
    out[missing & ~usable] = np.nan
    if std is not None:
        std = np.array(std, dtype=np.float64)
        std[~missing] = 0.0
        std[~filled & missing] = np.nan
    return FillResult(
        positions=out,
        filled=filled,
        std=std,
        n_iter=int(n_iter),
        converged=bool(converged),
        objective=[float(v) for v in (objective or [])],
        info=dict(info or {}),
    )


#: ``info`` keys whose values list per-marker records (``marker_index``, ``start``, ...): what must follow a marker
#: when a fill's columns are mapped onto another capture's (``pipeline.widen_result``, ``guards.copies.widened``).
MARKER_RECORDS = ("gap_methods", "declined", "displaced")


def review_indices(records: Any) -> list[int]:
    """``info["review"]``: the indices of the per-gap ``records`` (``info["gap_methods"]``) that ask for review."""
    return [i for i, rec in enumerate(records or []) if rec.get("review")]


def records_mask(records: Any, shape: tuple[int, int]) -> np.ndarray:
    """(n_frames, n_markers) bool: the samples covered by a list of per-run records (dicts with ``marker_index``,
    ``start`` (0-based frame) and ``length``; malformed ones skipped), as ``info`` lists them: the gaps a method
    declined (:func:`declined_mask`), the observed runs ``auto`` judged displaced (``info["displaced"]``, status
    ``SUSPECT``).  ``shape`` is (n_frames, n_markers); all False for None or an empty list."""
    mask = np.zeros(shape, dtype=bool)
    for rec in records or []:
        try:
            m, start, length = int(rec["marker_index"]), int(rec["start"]), int(rec["length"])
        except (KeyError, TypeError, ValueError):
            continue
        mask[start:start + length, m] = True
    return mask


def declined_mask(info: dict[str, Any] | None, shape: tuple[int, int]) -> np.ndarray:
    """(n_frames, n_markers) bool: the samples of the gaps a method declined (``info["declined"]``: one record per
    gap with ``marker_index``, ``start`` (0-based frame) and ``length``, as the suites' fills write it); their status
    is ``Status.MISSING_DECLINED``.  ``shape`` is (n_frames, n_markers); all False when nothing was declined."""
    return records_mask((info or {}).get("declined"), shape)


#: Largest coordinate a fill takes.  Methods square coordinates (distances, covariances, sums of squares over
#: frames); past ~1.3e154 a square overflows to inf, and each method then fails its own way (a spline's "dydx must
#: be finite", an SVD that does not converge, a fill quietly left missing).  1e150 leaves 1e8 squares of headroom.
MAX_COORDINATE = 1e150


def check_magnitude(positions: np.ndarray, *, name: str | None = None, labels: Sequence[str] | None = None) -> None:
    """Raise MethodError, naming ``name`` (the file) and the first marker at fault (from ``labels``), when a
    coordinate of ``positions`` (n_frames, n_markers, 3; NaN = missing) exceeds :data:`MAX_COORDINATE` in size."""
    from ..errors import MethodError

    large = np.abs(np.nan_to_num(positions)) > MAX_COORDINATE  # NaN counts as missing; inf is caught as infinite
    if not large.any():
        return
    frame, marker, axis = np.argwhere(large)[0]
    where = f"{name}: " if name else ""
    who = labels[marker] if labels is not None and marker < len(labels) else f"marker {marker + 1}"
    raise MethodError(f"{where}coordinates too large to fill ({who} reaches {positions[frame, marker, axis]:g}; a "
                      f"fill squares coordinates, and past {MAX_COORDINATE:g} its arithmetic overflows)")


def check_frames(n_frames: int, *, name: str | None = None) -> None:
    """Raise InputError, naming ``name`` (the file), when a capture has no frames (a header without rows).

    Called where a capture enters a fill (``api.fill``, ``pipeline.fill_capture``, ``evaluate``): an empty fill
    would write a 0-frame file and call it a success."""
    from ..errors import InputError

    if n_frames == 0:
        raise InputError(f"{name}: no frames (a header only): nothing to fill" if name
                         else "positions hold no frames: nothing to fill")


def check_positions(positions: np.ndarray, *, name: str | None = None,
                    labels: Sequence[str] | None = None) -> np.ndarray:
    """Validate and return ``positions`` as float64 (n_frames, n_markers, 3); a partly-NaN sample becomes all-NaN.

    Infinite values, and coordinates too large to square (:func:`check_magnitude`, naming ``name`` and ``labels``),
    raise MethodError."""
    from ..errors import MethodError

    positions = np.array(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise MethodError(f"positions must have shape (n_frames, n_markers, 3), got {positions.shape}")
    if np.isinf(positions).any():
        raise MethodError("positions contain infinite values")
    check_magnitude(positions, name=name, labels=labels)
    positions[np.isnan(positions).any(axis=2)] = np.nan
    return positions
