"""Fill a long take in overlapping windows of frames, with any fill function, and blend the overlaps.

Why: a fill whose cost or memory grows faster than the number of frames (a model learnt from every frame, nearest
poses searched over the whole take) gets slow and loses accuracy on a ten-minute take; the motion it needs to fill
a gap is near that gap.  Windows of a few thousand frames keep the time linear in frames and the memory bounded by
one window, and each window is a take of the length the fill was tuned on.

How (:func:`fill_in_windows`):

1. **Windows.**  ``ceil((n - overlap) / (window - overlap))`` windows of one length (at most ``window`` frames),
   spread evenly so that neighbours share ``overlap`` frames.  Each inner edge then moves, by at most a quarter of the
   overlap, to the frame where the fewest markers are missing, so that few gaps are cut by an edge.
2. **Fill** every window on its own with ``fill(positions[start:stop]) -> result`` (anything with ``positions``
   (n, n_markers, 3), optional ``std`` (n, n_markers) and ``info``, e.g. a :class:`FillResult`).
3. **Blend.**  Each window weighs its frames by a raised cosine over the overlaps (strictly positive inside the
   window, so every frame has a weight): ``w(t) = sin^2(pi/2 (t + 1/2) / overlap)`` on the first overlap frames,
   its mirror on the last, 1 between.  A gap that a window sees *cut* (it runs into the window's edge where the take
   goes on, so that window filled it with context on one side only) gets that window's weight times 1e-12: the
   window that holds the whole gap with an observed frame on each side decides it, and where two windows both hold
   it whole their fills cross-fade within the gap (an average of two fills, a little more accurate than either:
   CHANGELOG, twenty-sixth session).  Only when no window holds a gap whole (a gap longer than the overlap across an
   edge) does the plain cross-fade decide.  A window that left a sample NaN gives it no weight.  ``std`` blends with
   the same weights (NaN where no window gave one).  Observed samples come back bit-identical
   (:func:`mocapfill.methods.base.finish`).
4. **Info.**  Per-gap lists (``info`` values that are lists of dicts with ``start`` and ``marker_index``, such as
   ``auto``'s ``gap_methods``) keep, for each gap of the take, the entry of the window that holds it with the most
   weight, its ``start`` in the take's frames (a gap no window filled: the first window's entry; ``restate``
   restates each entry for the sd its gap ended up with); lists of observed runs (:data:`RUN_LISTS`) keep each
   run from the window whose share of the take holds its start; values every window agrees on are kept; the others
   are listed per window under ``info["windows"]``, with each window's ``start`` and ``stop``.

Memory: the take, two accumulators of its size, and one window's fill.  Time: the fill's time on ``window``
frames, times the number of windows (about ``n / (window - overlap)``), plus a linear blend.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from ..errors import MethodError
from ..gaps import runs
from ..methods.base import FillResult, finish
from ..runtime.executor import Executor, InProcess, make_executor

#: Defaults: windows of at most 5,000 frames (the length the default fill is measured on), 400 shared (3.3 s at
#: 120 Hz: longer than most gaps, so that one window holds each gap whole).
DEFAULT_WINDOW = 5000
DEFAULT_OVERLAP = 400
#: ``info`` keys whose values list observed runs, not gaps (``auto``'s runs judged displaced): each record is kept from
#: the window whose share of the take holds its start, its ``start`` shifted to the take's frames.
RUN_LISTS = ("displaced",)
#: Weight factor of a window on a gap it sees cut by its own edge.
CUT_WEIGHT = 1e-12


def window_bounds(missing: np.ndarray, window: int = DEFAULT_WINDOW, overlap: int = DEFAULT_OVERLAP
                  ) -> list[tuple[int, int]]:
    """The windows ``[(start, stop), ...]`` of a take whose missing mask is ``missing`` (n_frames, n_markers) bool.

    One window ``(0, n_frames)`` when the take fits in ``window`` frames.  Otherwise the fewest windows of at most
    ``window`` frames that share ``overlap`` frames with their neighbours, all of one length (so no more overlap
    than asked), spread evenly; then each inner edge moves by at most ``overlap // 4`` to the frame with the fewest
    markers missing (nearest the nominal edge on ties), so neighbours share at least ``overlap // 2`` frames.
    """
    missing = np.asarray(missing, dtype=bool)
    n = missing.shape[0]
    window, overlap = int(window), int(overlap)
    if overlap < 2 or window < 2 * overlap:
        raise MethodError(f"windows need overlap >= 2 frames and window >= 2 x overlap (got window {window}, "
                          f"overlap {overlap})")
    if n <= window:
        return [(0, n)]
    count = math.ceil((n - overlap) / (window - overlap))
    # as short as the count allows (no more overlap than asked): the time is the fill's on `length` frames, x count
    length = min(window, math.ceil((n + (count - 1) * overlap) / count))
    starts = [round(k * (n - length) / (count - 1)) for k in range(count)]
    per_frame = missing.sum(axis=1)
    slack = overlap // 4

    def best(nominal: int, lo: int, hi: int, frame_of) -> int:
        """The edge in [lo, hi] whose frame ``frame_of(edge)`` has the fewest missing markers, nearest ``nominal``."""
        edges = np.arange(max(lo, 0), min(hi, n) + 1)
        cost = per_frame[[frame_of(e) for e in edges]] if edges.size else np.zeros(0)
        if not edges.size:
            return nominal
        key = cost * (n + 1) + np.abs(edges - nominal)
        return int(edges[np.argmin(key)])

    bounds = []
    for k, s in enumerate(starts):
        e = s + length
        if k > 0:  # the window's first frame should have every marker observed (context before each gap)
            s = best(s, s - slack, s + slack, lambda f: f)
        if k < count - 1:  # and its last frame too (context after each gap)
            e = best(e, e - slack, e + slack, lambda f: f - 1)
        bounds.append((s, min(e, n)))
    return bounds


def _ramp(length: int, start: int, stop: int, n: int, overlaps: tuple[int, int]) -> np.ndarray:
    """Cross-fade weights (length,) of a window [start, stop) of a take of n frames: a raised cosine over the
    ``overlaps`` (frames shared with the window before, after), strictly positive, 1 elsewhere."""
    w = np.ones(length)
    before, after = overlaps
    if start > 0 and before > 0:
        k = min(before, length)
        w[:k] = np.sin(0.5 * np.pi * (np.arange(k) + 0.5) / before) ** 2
    if stop < n and after > 0:
        k = min(after, length)
        w[length - k:] *= np.sin(0.5 * np.pi * (np.arange(k)[::-1] + 0.5) / after) ** 2
    return w


def _overlaps(bounds: list[tuple[int, int]], k: int) -> tuple[int, int]:
    """Frames window ``k`` shares with the window before and the one after (0 where there is none)."""
    start, stop = bounds[k]
    return (bounds[k - 1][1] - start if k > 0 else 0, stop - bounds[k + 1][0] if k + 1 < len(bounds) else 0)


def _cut_gaps(missing: np.ndarray, at_take_start: bool, at_take_end: bool) -> np.ndarray:
    """(n, n_markers) bool: samples of a window's gaps that run into one of its edges where the take goes on."""
    cut = np.zeros_like(missing)
    for m in range(missing.shape[1]):
        for start, length in runs(missing[:, m]):
            touches_start = start == 0 and not at_take_start
            touches_end = start + length == missing.shape[0] and not at_take_end
            if touches_start or touches_end:
                cut[start:start + length, m] = True
    return cut


class _WithKeywords:
    """``fill(window, **keywords)`` of a ``(window, keywords)`` task (picklable when ``fill`` is)."""

    def __init__(self, fill: Callable) -> None:
        self.fill = fill

    def __call__(self, task: tuple[np.ndarray, dict]) -> Any:
        return self.fill(task[0], **task[1])


def _window_results(positions: np.ndarray, bounds: list[tuple[int, int]], fill: Callable, executor: Executor,
                    keywords: Callable[[int, int], dict] | None = None):
    """The fills of the windows, in order: here one after the other (memory: one window's fill at a time), or on
    the executor's workers (every window's fill is held until the blend); ``keywords(start, stop)``, formed here,
    are passed to each window's fill."""
    extra = (lambda start, stop: {}) if keywords is None else keywords
    if isinstance(executor, InProcess):
        for start, stop in bounds:
            yield fill(positions[start:stop], **extra(start, stop))
        return
    yield from executor.results(_WithKeywords(fill), [(positions[start:stop], extra(start, stop))
                                                      for start, stop in bounds])


def fill_in_windows(positions: np.ndarray, fill: Callable[[np.ndarray], Any], *, window: int = DEFAULT_WINDOW,
                    overlap: int = DEFAULT_OVERLAP, jobs: int = 1, executor: Executor | None = None,
                    restate: Callable[[dict, np.ndarray], dict] | None = None,
                    keywords: Callable[[int, int], dict] | None = None) -> FillResult:
    """Fill ``positions`` (n_frames, n_markers, 3), NaN = missing, window by window with ``fill`` (see the module
    docstring).

    Parameters
    ----------
    positions : ndarray (n_frames, n_markers, 3)
    fill : callable
        ``fill(window_positions (n, n_markers, 3)) -> result`` with ``result.positions`` (n, n_markers, 3) and
        optionally ``result.std`` (n, n_markers) or None, ``result.info`` (dict), ``result.n_iter``,
        ``result.converged``.  Bind options with a lambda or :func:`functools.partial`.
    window, overlap : int
        Frames per window and shared by neighbours (``window >= 2 * overlap``, ``overlap >= 2``).  A take of at
        most ``window`` frames is filled in one call (its result passed through :func:`finish`).
    jobs : int
        Windows filled at once in local worker processes (1, the default: here, one after the other; 0: every core),
        when no ``executor`` is given.
    executor : Executor or None
        Where the windows run (:mod:`mocapfill.runtime.executor`: local processes or a Dask cluster); each window is
        one task.  Off this process, ``fill`` must be picklable (a module-level function or a
        :func:`functools.partial` of one, not a lambda), and a script needs the ``if __name__ == "__main__":`` guard
        (workers are spawned).
    restate : callable or None
        ``restate(record, std) -> record``: each merged per-gap record (the heaviest window's) given the blended
        ``std`` (length,) over its gap, for a fill whose records quote their sd (``auto``'s
        :func:`~mocapfill.methods.auto_records.restate_record`); None: the records as the windows gave them.
    keywords : callable or None
        ``keywords(start, stop) -> dict``: keyword arguments for the fill of the window ``[start, stop)``, formed in
        this process (``auto``: frames of the rest of the take that show a marker the window never does).

    Returns
    -------
    FillResult
        ``positions`` with observed samples bit-identical, ``std`` (n_frames, n_markers) or None when no window
        gave one, ``n_iter`` the most of any window, ``converged`` when every window converged, ``info`` merged
        (``windows``: one dict per window with ``start``, ``stop`` and what differs between windows).
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise MethodError(f"positions must have shape (n_frames, n_markers, 3), got {positions.shape}")
    n, n_markers, _ = positions.shape
    missing = np.isnan(positions).any(axis=2)
    bounds = window_bounds(missing, window, overlap)
    runner = executor if executor is not None else make_executor(jobs, n_tasks=len(bounds))
    if len(bounds) == 1:
        res = fill(positions)
        return finish(positions, res.positions, std=getattr(res, "std", None), n_iter=getattr(res, "n_iter", 0),
                      converged=getattr(res, "converged", True), info=dict(getattr(res, "info", None) or {}))

    total = np.zeros((n, n_markers, 3))
    weight = np.zeros((n, n_markers))
    var_sum = np.zeros((n, n_markers))
    var_weight = np.zeros((n, n_markers))
    infos, n_iter, converged = [], 0, True
    # per sample, the window with the most weight there: its entry describes the gap in the merged info
    owner_weight = np.zeros((n, n_markers))
    owner = np.full((n, n_markers), -1, dtype=np.intp)
    for k, ((start, stop), res) in enumerate(zip(bounds, _window_results(positions, bounds, fill, runner,
                                                                                     keywords))):
        part = positions[start:stop]
        est = np.asarray(res.positions, dtype=np.float64)
        if est.shape != part.shape:
            raise MethodError(f"the fill returned shape {est.shape} for a window of shape {part.shape}")
        w = np.repeat(_ramp(stop - start, start, stop, n, _overlaps(bounds, k))[:, None], n_markers, axis=1)
        w[_cut_gaps(missing[start:stop], start == 0, stop == n)] *= CUT_WEIGHT
        usable = np.isfinite(est).all(axis=2) & missing[start:stop]
        w = np.where(usable, w, 0.0)
        total[start:stop] += w[:, :, None] * np.where(usable[:, :, None], est, 0.0)
        weight[start:stop] += w
        std = getattr(res, "std", None)
        if std is not None:
            std = np.asarray(std, dtype=np.float64)
            ok = usable & np.isfinite(std)
            var_sum[start:stop] += np.where(ok, w * np.where(ok, std, 0.0) ** 2, 0.0)
            var_weight[start:stop] += np.where(ok, w, 0.0)
        heavier = w > owner_weight[start:stop]
        owner_weight[start:stop][heavier] = w[heavier]
        owner[start:stop][heavier] = k
        infos.append(dict(getattr(res, "info", None) or {}))
        n_iter = max(n_iter, int(getattr(res, "n_iter", 0) or 0))
        converged = converged and bool(getattr(res, "converged", True))
        del res, est, part
    with np.errstate(invalid="ignore", divide="ignore"):
        blended = total / weight[:, :, None]
        std_out = np.sqrt(var_sum / var_weight) if var_weight.any() else None
    blended[weight == 0] = np.nan
    if std_out is not None:
        std_out[var_weight == 0] = np.nan
    info = _merge_info(infos, bounds, missing, owner)
    if restate is not None and std_out is not None:
        for key, value in info.items():
            if key not in RUN_LISTS and _is_gap_list(value):
                info[key] = [restate(e, std_out[e["start"]:e["start"] + int(e.get("length", 1)), e["marker_index"]])
                             for e in value]
    return finish(positions, blended, std=std_out, n_iter=n_iter, converged=converged, info=info)


def _is_gap_list(value: Any) -> bool:
    return (isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)
            and all("start" in v and "marker_index" in v for v in value))


def _merge_info(infos: list[dict], bounds: list[tuple[int, int]], missing: np.ndarray, owner: np.ndarray
                ) -> dict[str, Any]:
    """One info dict from the windows' (see the module docstring); ``owner`` (n, n_markers) is the window with the
    most weight at each sample (-1 where none)."""
    keys = list(dict.fromkeys(key for info in infos for key in info))
    merged: dict[str, Any] = {}
    per_window = [{"start": int(a), "stop": int(b)} for a, b in bounds]
    for key in keys:
        values = [info.get(key) for info in infos]
        if key in RUN_LISTS:
            merged[key] = _merge_run_lists(values, bounds)
        elif any(_is_gap_list(v) for v in values if v):
            merged[key] = _merge_gap_lists(values, bounds, missing, owner)
        elif all(_same(v, values[0]) for v in values[1:]):
            merged[key] = values[0]
        else:
            for row, value in zip(per_window, values):
                row[key] = value
    merged["windows"] = per_window
    return merged


def _merge_run_lists(values: list, bounds: list[tuple[int, int]]) -> list[dict]:
    """Records of observed runs (``start``, ``length``, ``marker_index``; :data:`RUN_LISTS`) in the take's frames:
    each from the window whose share of the take (up to the middle of its overlaps) holds the run's start."""
    out = []
    for k, ((a, b), entries) in enumerate(zip(bounds, values)):
        lo = a if k == 0 else (a + bounds[k - 1][1]) // 2
        hi = b if k == len(bounds) - 1 else (bounds[k + 1][0] + b) // 2
        for e in entries or []:
            if isinstance(e, dict) and lo <= a + int(e.get("start", -1)) < hi:
                out.append(dict(e, start=a + int(e["start"])))
    return sorted(out, key=lambda e: (e.get("marker_index", 0), e["start"]))


def _same(a: Any, b: Any) -> bool:
    try:
        return bool(a == b)
    except (ValueError, TypeError):  # arrays and the like: not comparable as one truth value
        return False


def _merge_gap_lists(values: list, bounds: list[tuple[int, int]], missing: np.ndarray, owner: np.ndarray
                     ) -> list[dict]:
    """For every gap of the take (marker m, frames [start, start + length)), the entry of its owning window whose
    gap overlaps it, with ``start`` and ``length`` in the take's frames; sorted by marker, then start."""
    out = []
    for m in range(missing.shape[1]):
        for start, length in runs(missing[:, m]):
            ks, counts = np.unique(owner[start:start + length, m], return_counts=True)
            if (ks >= 0).any():
                order = [int(ks[ks >= 0][np.argmax(counts[ks >= 0])])]
            else:  # no window filled it (a marker never observed): the first window that says why
                order = [k for k, (a, b) in enumerate(bounds) if a < start + length and start < b]
            local = []
            for k in order:
                w0 = bounds[k][0]
                local = [e for e in values[k] or [] if e.get("marker_index") == m
                         and e["start"] < start + length - w0 and e["start"] + e.get("length", 1) > start - w0]
                if local:
                    break
            if not local:
                continue
            entry = dict(local[0])
            entry["start"], entry["length"] = int(start), int(length)
            if len(local) > 1:  # the window split this gap (a cut edge): say which methods filled its pieces
                entry["method"] = "+".join(dict.fromkeys(str(e.get("method")) for e in local))
            out.append(entry)
    return out
