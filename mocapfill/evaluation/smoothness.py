"""How smooth a fill is: its accelerations against the accelerations the capture itself shows (issue 21).

Acceleration of marker i at frame t (1 <= t <= n_frames - 2) is the 3-D norm of the second difference
``a_t,i = ||x[t+1] - 2 x[t] + x[t-1]||`` (file units per frame squared).  With ``missing`` the samples that were
missing or rejected in the input (the samples the fill had to supply):

- ``filled``:   at least one of the three samples x[t-1], x[t], x[t+1] was missing;
- ``observed``: all three were observed.

Second differences that involve an observed *fragment* of at most :data:`SHORT_FRAGMENT` frames between missing ones
(``MoM``, ``MooM``) are left out of both: such a sample is often the worst of the take and a model may distrust it.
Differences that are not finite (a sample left missing by the fill) are counted apart (``n_unfilled``).

The rule of issue 21 (:func:`smooth_enough`): no filled acceleration above the largest observed one, and, where at
least :data:`MIN_FILLED_FOR_PERCENTILE` samples were filled, the 99.9th percentile of the filled accelerations at most
:data:`PERCENTILE_FACTOR` times the observed one.

Pure NumPy; no reading, no printing.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..gaps import fragments, runs

__all__ = ["SHORT_FRAGMENT", "PERCENTILE", "PERCENTILE_FACTOR", "MIN_FILLED_FOR_PERCENTILE", "GUARD_MASKS",
           "Smoothness", "accelerations", "short_fragments", "smoothness", "smooth_enough", "outcome_smoothness",
           "least_max_filled", "outcome_mask"]

#: Observed runs of at most this many frames between missing samples are left out (issue 21: "a fragment of one or
#: two frames"); such samples are often the worst of the take.
SHORT_FRAGMENT = 2
#: The percentile the rule compares (issue 21: the 99.9th), so one bad frame does not decide it.
PERCENTILE = 99.9
#: Allowed ratio of the filled to the observed 99.9th percentile (issue 21).
PERCENTILE_FACTOR = 1.5
#: The percentile rule applies only where at least this many samples were filled (issue 21): on fewer the 99.9th
#: percentile is the maximum, which the first rule already bounds.
MIN_FILLED_FOR_PERCENTILE = 1000


@dataclass(frozen=True)
class Smoothness:
    """Accelerations of one fill (file units per frame squared; NaN where there is none to measure).

    Attributes
    ----------
    max_observed, max_filled : float
        The largest observed / filled acceleration.
    p_observed, p_filled : float
        Their :data:`PERCENTILE`-th percentiles.
    n_observed, n_filled : int
        Second differences counted as observed / filled.
    n_fragment : int
        Second differences left out because they involve a short observed fragment.
    n_unfilled : int
        Second differences with a missing sample in the output (not finite), left out.
    filled_samples : int
        Samples missing in the input and finite in the output (what the percentile rule's 1,000 counts).
    worst_frame, worst_marker : int
        Where the largest filled acceleration is (its middle frame, 0-based; marker index); -1 without one.
    """

    max_observed: float
    max_filled: float
    p_observed: float
    p_filled: float
    n_observed: int
    n_filled: int
    n_fragment: int
    n_unfilled: int
    filled_samples: int
    worst_frame: int = -1
    worst_marker: int = -1

    @property
    def ratio_max(self) -> float:
        """max_filled / max_observed (NaN without either)."""
        return _ratio(self.max_filled, self.max_observed)

    @property
    def ratio_percentile(self) -> float:
        """p_filled / p_observed (NaN without either)."""
        return _ratio(self.p_filled, self.p_observed)

    def scaled(self, factor: float) -> "Smoothness":
        """The same figures with every acceleration multiplied by ``factor`` (a unit conversion)."""
        d = asdict(self)
        for key in ("max_observed", "max_filled", "p_observed", "p_filled"):
            d[key] = d[key] * factor
        return Smoothness(**d)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (NaN -> None), with the two ratios."""
        d = asdict(self)
        d["ratio_max"], d["ratio_percentile"] = self.ratio_max, self.ratio_percentile
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


def _ratio(a: float, b: float) -> float:
    if not (np.isfinite(a) and np.isfinite(b)) or b <= 0:
        return float("nan")
    return float(a / b)


def accelerations(positions: np.ndarray) -> np.ndarray:
    """(n_frames - 2, n_markers) float: ``||x[t+1] - 2 x[t] + x[t-1]||`` for t = 1 .. n_frames - 2 (row t - 1).

    positions : (n_frames, n_markers, 3), NaN = missing (NaN propagates).
    """
    x = np.asarray(positions, dtype=float)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"positions must be (n_frames, n_markers, 3), got {x.shape}")
    if x.shape[0] < 3:
        return np.zeros((0, x.shape[1]))
    return np.linalg.norm(x[2:] - 2.0 * x[1:-1] + x[:-2], axis=2)


def short_fragments(missing: np.ndarray, longest: int = SHORT_FRAGMENT) -> np.ndarray:
    """(n_frames, n_markers) bool: observed samples in a run of at most ``longest`` observed frames between missing
    ones (:func:`mocapfill.gaps.fragments`, with the measure's default length)."""
    return fragments(missing, longest)


def smoothness(output: np.ndarray, missing: np.ndarray, *, points: np.ndarray | None = None,
               longest_fragment: int = SHORT_FRAGMENT, percentile: float = PERCENTILE) -> Smoothness:
    """The acceleration figures of a fill (see the module docstring).

    Parameters
    ----------
    output : (n_frames, n_markers, 3) float
        The filled capture (observed samples as in the input).
    missing : (n_frames, n_markers) bool
        Samples missing or rejected in the input: those the fill supplied.
    points : (n_markers,) bool, optional
        The points to measure (e.g. ``kinds == "marker"``); default all.
    longest_fragment : int
        Observed runs of at most this many frames between missing samples are left out.
    percentile : float
        The percentile reported as ``p_observed`` / ``p_filled``.
    """
    x = np.asarray(output, dtype=float)
    miss = np.asarray(missing, dtype=bool)
    if miss.shape != x.shape[:2]:
        raise ValueError(f"missing {miss.shape} does not match output {x.shape}")
    if points is not None:
        keep = np.asarray(points, dtype=bool)
        x, miss = x[:, keep], miss[:, keep]
        index = np.flatnonzero(keep)
    else:
        index = np.arange(x.shape[1])
    acc = accelerations(x)
    filled_samples = int((miss & np.isfinite(x).all(axis=2)).sum())
    if acc.shape[0] == 0:
        return Smoothness(*(float("nan"),) * 4, 0, 0, 0, 0, filled_samples)
    touched = miss[2:] | miss[1:-1] | miss[:-2]
    frag = short_fragments(miss, longest_fragment) if longest_fragment > 0 else np.zeros_like(miss)
    involved = frag[2:] | frag[1:-1] | frag[:-2]
    finite = np.isfinite(acc)
    observed = ~touched & ~involved & finite
    filled = touched & ~involved & finite
    n_unfilled = int((touched & ~involved & ~finite).sum())
    a_obs, a_fill = acc[observed], acc[filled]

    def stat(values: np.ndarray, func) -> float:
        return float(func(values)) if values.size else float("nan")

    worst_frame = worst_marker = -1
    if a_fill.size:
        t, m = np.unravel_index(np.argmax(np.where(filled, acc, -np.inf)), acc.shape)
        worst_frame, worst_marker = int(t) + 1, int(index[m])
    return Smoothness(stat(a_obs, np.max), stat(a_fill, np.max),
                      stat(a_obs, lambda v: np.percentile(v, percentile)),
                      stat(a_fill, lambda v: np.percentile(v, percentile)),
                      int(observed.sum()), int(filled.sum()), int((touched & involved).sum()), n_unfilled,
                      filled_samples, worst_frame, worst_marker)


def least_max_filled(positions: np.ndarray, missing: np.ndarray, *, points: np.ndarray | None = None,
                     longest_fragment: int = SHORT_FRAGMENT, longest_gap: int = 20) -> tuple[float, int, int]:
    """A lower bound on the largest filled acceleration of *any* fill that keeps the observed samples.

    positions (n_frames, n_markers, 3): the observed samples (read where ``missing`` is False); missing
    (n_frames, n_markers) bool and points as :func:`smoothness` takes them.  Per gap and axis, a linear programme finds the
    fill values that make the largest |second difference| touching the gap smallest, the observed samples fixed and
    differences involving a short fragment left out (as :func:`smoothness` leaves them out); the 3-D norm is at
    least any one axis'.  A difference that needs a sample of another gap is dropped, and gaps longer than
    ``longest_gap`` frames count 0, so the result stays a lower bound.  Returns (bound, marker, frame of the gap's
    start), (0.0, -1, -1) when nothing binds.  Where the bound exceeds the largest observed acceleration, no fill
    that keeps the observed samples passes :func:`smooth_enough`'s first rule: an edge sample is too far off.
    """
    from scipy.optimize import linprog  # the measure's only use of scipy: keep importing this module cheap

    x = np.asarray(positions, dtype=float)
    miss = np.asarray(missing, dtype=bool)
    markers = np.arange(x.shape[1]) if points is None else np.flatnonzero(np.asarray(points, dtype=bool))
    frag = short_fragments(miss, longest_fragment) if longest_fragment > 0 else np.zeros_like(miss)
    best = (0.0, -1, -1)
    n = x.shape[0]
    for m in markers:
        for start, length in runs(miss[:, m]):
            if length > longest_gap or start == 0 or start + length == n:
                continue  # a gap at the take's edge can be extrapolated with no acceleration at all
            rows, consts = [], []
            for t in range(max(start - 1, 1), min(start + length + 1, n - 1)):  # differences touching the gap
                idx = (t - 1, t, t + 1)
                if any(frag[i, m] or (miss[i, m] and not start <= i < start + length) for i in idx):
                    continue
                coef = np.zeros(length + 1)
                const = np.zeros(3)
                for i, c in zip(idx, (1.0, -2.0, 1.0)):
                    if start <= i < start + length:
                        coef[i - start] += c
                    else:
                        const += c * x[i, m]
                rows.append(coef)
                consts.append(const)
            if not rows:
                continue
            a = np.array(rows)
            a[:, -1] = -1.0  # |coef . y + const| <= s  <=>  coef . y - s <= -const and -coef . y - s <= const
            a_ub = np.concatenate([a, a * np.r_[-np.ones(length), 1.0]])
            cost = np.zeros(length + 1)
            cost[-1] = 1.0
            consts = np.array(consts)  # (n_differences, 3)
            for axis in range(3):
                c = consts[:, axis]
                res = linprog(cost, A_ub=a_ub, b_ub=np.concatenate([-c, c]), bounds=[(None, None)] * (length + 1),
                              method="highs")
                if res.status == 0 and res.fun > best[0]:
                    best = (float(res.fun), int(m), int(start))
    return best


def smooth_enough(s: Smoothness, *, factor: float = PERCENTILE_FACTOR,
                  min_filled: int = MIN_FILLED_FOR_PERCENTILE) -> tuple[bool, list[str]]:
    """Issue 21's rule on one fill: (passes, the reasons it does not, as short sentences).

    No filled acceleration above the largest observed one; where at least ``min_filled`` samples were filled, the
    filled percentile at most ``factor`` times the observed one.  Nothing filled passes; filled accelerations with
    no observed one to compare fail.
    """
    reasons = []
    if s.n_filled:
        if not np.isfinite(s.max_observed):
            reasons.append("no observed acceleration to compare with")
        elif s.max_filled > s.max_observed:
            reasons.append(f"largest filled acceleration {s.max_filled:.3g} > largest observed {s.max_observed:.3g}")
        if s.filled_samples >= min_filled and np.isfinite(s.p_observed) and s.p_filled > factor * s.p_observed:
            reasons.append(f"filled {PERCENTILE:g}th percentile {s.p_filled:.3g} > {factor:g} x observed "
                           f"{s.p_observed:.3g}")
    return not reasons, reasons


#: The masks a :class:`mocapfill.pipeline.FillOutcome` may carry for observed samples a guard turned into gaps.
GUARD_MASKS = ("rejected", "held", "fragments", "repaired")


def outcome_smoothness(outcome: Any, **options: Any) -> Smoothness:
    """:func:`smoothness` of a fill as ``mocapfill fill`` makes it (a :class:`mocapfill.pipeline.FillOutcome`).

    Missing: the samples missing in the capture read, or turned into gaps by a guard (the outcome's
    :data:`GUARD_MASKS` that are set, each (n_frames, n_markers) bool); measured: the points of kind "marker".
    ``options`` go to :func:`smoothness`.  File units.
    """
    missing, points = outcome_mask(outcome)
    return smoothness(outcome.output.positions, missing, points=points, **options)


def outcome_mask(outcome: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """(missing (n_frames, n_markers) bool, points (n_markers,) bool or None) of a fill as :func:`outcome_smoothness`
    measures it: the samples the fill had to supply, and the points of kind "marker"."""
    data = outcome.data
    missing = np.isnan(np.asarray(data.positions, dtype=float)).any(axis=2)
    missing |= np.isnan(np.asarray(outcome.work.positions, dtype=float)).any(axis=2)
    for name in GUARD_MASKS:
        mask = getattr(outcome, name, None)
        if mask is not None:
            missing |= np.asarray(mask, dtype=bool)
    kinds = getattr(data, "kinds", None)
    points = None if kinds is None else np.array([k == "marker" for k in kinds])
    return missing, points
