"""Joint-angle errors: what a fill does to the coordinates IK finds (pure NumPy, no OpenSim).

A coordinate's error is the RMSE over frames of (IK on the filled capture) - (IK on the complete capture).  Over a
set of coordinates the summary is the median and the worst coordinate, rotational coordinates (degrees) apart from
translational ones (the capture's length units).  Locked coordinates (kind ``"locked"``) and coupled ones
(``"coupled"``: neither an angle nor a length) never enter a summary.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: The kinds of coordinate a summary reports, each in its own unit.
SUMMARY_KINDS = ("rotational", "translational")


@dataclass
class IKAngles:
    """The generalised coordinates IK found for a capture.

    Attributes
    ----------
    names : list of str
        Coordinate names, as the model calls them (C of them).
    kinds : list of str
        Per coordinate: "rotational" (values in degrees), "translational" (values in the capture's length units),
        "coupled" or "locked" (values as IK wrote them; never summarised).
    values : ndarray, shape (T, C), float64
        One row per solved frame.
    frames : ndarray, shape (T,), int
        The capture's frame index (0-based) of each row.
    seconds : float
        Wall-clock time of the IK run.
    """

    names: list[str]
    kinds: list[str]
    values: np.ndarray
    frames: np.ndarray
    seconds: float = 0.0


def coordinate_errors(truth: IKAngles, test: IKAngles, frames: np.ndarray | None = None) -> dict[str, float]:
    """RMSE over frames of ``test - truth`` per coordinate named in both.

    Parameters
    ----------
    truth, test : IKAngles
        IK of the complete and of the filled (or gappy) capture.
    frames : ndarray of bool, shape (n_frames,), optional
        The capture's frames to score (e.g. those with a hidden sample); default every frame both solved.

    Returns
    -------
    dict of str -> float
        NaN for a coordinate with no common frame, or where ``test`` is not finite (IK failed there).
    """
    common, ti, si = np.intersect1d(truth.frames, test.frames, return_indices=True)
    if frames is not None:
        keep = np.asarray(frames, dtype=bool)[common]
        ti, si = ti[keep], si[keep]
    column = {name: c for c, name in enumerate(test.names)}
    out: dict[str, float] = {}
    for c, name in enumerate(truth.names):
        if name not in column or ti.size == 0:
            out[name] = float("nan")
            continue
        diff = test.values[si, column[name]] - truth.values[ti, c]
        out[name] = float(np.sqrt(np.mean(diff ** 2))) if np.isfinite(diff).all() else float("nan")
    return out


def summarise_errors(errors: dict[str, float], kinds: dict[str, str]) -> dict[str, Any]:
    """Median and worst coordinate of ``errors`` per kind in :data:`SUMMARY_KINDS`.

    Parameters
    ----------
    errors : dict of str -> float
        Per-coordinate RMSE (:func:`coordinate_errors`).
    kinds : dict of str -> str
        Per coordinate its kind (:attr:`IKAngles.kinds`).

    Returns
    -------
    dict
        ``{"rotational": {"median": x, "worst": x, "worst_coordinate": name, "n": k}, "translational": {...}}``;
        a kind with no coordinate (or only NaN errors) gives None values.
    """
    out: dict[str, Any] = {}
    for kind in SUMMARY_KINDS:
        names = [n for n, e in errors.items() if kinds.get(n) == kind and np.isfinite(e)]
        if not names:
            out[kind] = {"median": None, "worst": None, "worst_coordinate": None, "n": 0}
            continue
        vals = np.array([errors[n] for n in names])
        worst = int(np.argmax(vals))
        out[kind] = {"median": float(np.median(vals)), "worst": float(vals[worst]), "worst_coordinate": names[worst],
                     "n": len(names)}
    return out
