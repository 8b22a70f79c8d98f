"""Outlier rejection by inter-marker distance ranges (Holden 2018, "Robust solving of optical motion capture data by
denoising", Runtime / Outlier Removal).

The rule
--------
For every marker pair a distance range ``[Dmin, Dmax]`` (``Drange = Dmax - Dmin``) is taken from a reference.  In
each frame, a pair *violates* when its distance ``D`` satisfies ``D < Dmin - m`` or ``D > Dmax + m`` with margin
``m = max(delta * Drange, min_margin)`` (``min_margin`` only keeps pairs that never changed length in the
reference, e.g. two markers of one rigid plate, from flagging sub-millimetre noise).  Then, frame by frame, the
marker that violates "the most" is removed, and this repeats until no pair of remaining markers violates.

"The most" is measured by the **number of violated pairs** the marker belongs to; ties are broken by the marker's
**mean strain**: over all its observed pairs, ``|D - centre| / (half range + margin)`` (> 1 = violated), weighted by
``1 / (Drange + 2 m)`` so that rigid pairs speak loudest.  A marker thrown 5-50 cm away breaks every pair it has
with rigid partners while each partner breaks only its pair with it, so the count settles most frames; when two
markers share their only violated pair, the one that was displaced also strains its other pairs.

The reference
-------------
- ``reference=`` a clean capture of the same marker set, ``(n_ref_frames, n_markers, 3)``: ``Dmin``/``Dmax`` are the
  exact minimum and maximum over its frames (as Holden does with his training data).
- ``reference=None``: the file itself.  Its own minimum and maximum would include the outliers, and plain
  percentiles would flag clean frames (with 1st/99th percentiles and ``delta`` 0.1, 13 % of the frames of the
  clean CMU clip 85_02 break some pair) or, trimmed further, be polluted by the outliers themselves.  Errors come
  as single-frame spikes and as stretches (a label swap lasts until the tracker recovers, a ghost or a bumped
  marker for a while), and clean extremes are neither; so, in three steps:

  0. stretches (:func:`shifted_runs`, ``runs=True``): a marker displaced for up to ``max_run`` seconds (default
     0.5) steps away and back in one frame each, against its stiffest partners, where clean motion changes those
     distances smoothly.  What it finds is rejected and treated as missing below.  (A longer running median does
     not do this: on 85_02, windows of 31-91 frames reject 144-10,120 clean samples, since they clip the clean
     extremes of every moving pair.)
  1. robust ranges: the ``percentile`` / ``100 - percentile`` percentiles (default 0: min and max) of each pair's
     distance after a running median over ``window`` frames (default 3, which ignores a spike of one frame but
     keeps any pose held for two), widened by ``robust_delta`` (default 0.5) of their width, reject the gross
     outliers; this repeats (``stage1_passes``, default 3) with the rejected samples blanked out, so that a pair hit
     in two of three consecutive frames stops widening its own range;
  2. the exact minimum and maximum of the raw distances over the samples that survived stage 1 become
     ``Dmin`` / ``Dmax``, and the rule is applied afresh with ``delta``.  A clean extreme that stage 1 flagged
     comes back unless it lies beyond all the kept samples by more than the margin.

  Measured with ``python benchmarks/bench_distances.py --outliers 20 --outliers-only`` (20 seeds per corruption;
  "runs": 8 stretches of 2-30 frames at 120 Hz, one marker moved 5-50 cm throughout; "swaps": 8 stretches where two
  markers >= 5 cm apart exchange positions; "long": 1-60 frames).  CMU 85_02 (120 Hz): uncorrupted, nothing
  rejected; single frames (the paper's corruption) precision >= 0.98 and recall >= 0.98 in every seed; runs
  precision 1.000, recall median 1.000, min 0.860 (16 of 20 seeds >= 0.95 on both); swaps precision >= 0.949,
  recall median 1.000, min 0.916 (18/20); long runs recall median 1.000, min 0.782 (16/20); ``mocapfill evaluate
  --protocol random`` trials (many markers displaced at once, 0.05-0.5 s, overlapping gaps and other shifts)
  shifted samples found median 0.994, min 0.919, precision >= 0.98 (without step 0: none found; without its
  one-step rule, 4.: median 0.867, min 0.736, and 4-9 % of the stretches that begin or end at a gap).  The misses
  are stretches during the clip's acrobatics (frames 430-720), where the stiff partners' distances change by
  several centimetres within the stretch, stretches whose partners are displaced at the same time, and overlapping
  swaps.  The "complete" tennis serve (50 Hz) loses 11 of its 42,588 samples uncorrupted: the racket arm at the
  serves, several inside vendor-interpolated stretches (equal steps) that do break its bone lengths, and two
  head-marker samples; corrupted, precision over the other samples >= 0.967 and recall median 1.000 (min 0.78-0.97
  by corruption; random protocol median 0.988).  Give a clean
  ``reference`` when the file may hold errors longer than ``max_run`` or when even these few clean extremes must
  stay.

Pairs seen together in fewer than ``min_frames`` reference frames have no range and never violate.
Everything is vectorised across frames (chunks of frames x pairs of about ``chunk_bytes``); the greedy loop runs
once per removed marker, over the frames that still violate.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple, Sequence

import numpy as np

from ..bones.boneset import default_min_frames
from ..units import length_factor
from ..bones.distances import pair_distance_stats
from ..errors import MocapfillError

#: Default margin floor (mm, converted to the data's units).
DEFAULT_MIN_MARGIN_MM = 1.0


class OutlierResult(NamedTuple):
    """Outcome of :func:`reject_outliers`.

    positions : ndarray, shape (n_frames, n_markers, 3)
        The input with rejected samples set to NaN (a copy; other samples bit-identical).
    rejected : ndarray bool, shape (n_frames, n_markers)
        True where an observed sample was removed.
    dmin, dmax : ndarray float64, shape (P,)
        The distance range per pair used by the final pass (NaN = unconstrained pair).
    pairs : ndarray int, shape (P, 2)
        The pairs of ``dmin`` / ``dmax``.
    """

    positions: np.ndarray
    rejected: np.ndarray
    dmin: np.ndarray | None = None
    dmax: np.ndarray | None = None
    pairs: np.ndarray | None = None


def _ranges(positions: np.ndarray, percentile: float, min_frames: int, window: int = 1
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pairs (P, 2), lo (P,), hi (P,)) over the observed frames; NaN where seen together < min_frames times."""
    levels = (percentile, 100.0 - percentile)
    stats = pair_distance_stats(positions, percentiles=levels, window=window)
    lo, hi = stats.percentiles[:, 0].copy(), stats.percentiles[:, 1].copy()
    few = stats.count < max(min_frames, 1)
    lo[few] = np.nan
    hi[few] = np.nan
    return stats.pairs, lo, hi


def pair_strain(positions: np.ndarray, pairs: np.ndarray, dmin: np.ndarray, dmax: np.ndarray, *, delta: float,
                min_margin: float) -> np.ndarray:
    """Strain of every pair in every frame, shape (n_frames, P); NaN where a marker is missing.

    ``u = |D - c| / (h + m)`` with ``c`` the middle and ``h`` half the width of ``[dmin, dmax]`` and
    ``m = max(delta * (dmax - dmin), min_margin)`` the margin: ``u > 1`` exactly when the pair violates
    ``D < dmin - m`` or ``D > dmax + m``.  ``positions`` (n_frames, n_markers, 3); ``pairs`` (P, 2);
    ``dmin``, ``dmax`` (P,) finite.
    """
    span = dmax - dmin
    half = 0.5 * span + np.maximum(delta * span, min_margin)
    a, b = pairs[:, 0], pairs[:, 1]
    # one coordinate at a time from a contiguous (n_frames, n_markers) copy: column gathers and in-place
    # arithmetic on (n_frames, P), instead of a (n_frames, P, 3) gather with stride 3
    d = None
    for c in range(3):
        x = np.ascontiguousarray(positions[:, :, c])
        diff = np.take(x, a, axis=1)
        diff -= np.take(x, b, axis=1)
        diff *= diff
        if d is None:
            d = diff
        else:
            d += diff
    np.sqrt(d, out=d)
    d -= 0.5 * (dmin + dmax)
    np.abs(d, out=d)
    d /= half
    return d


def _greedy(strain: np.ndarray, weight: np.ndarray, pairs: np.ndarray, n_markers: int, min_count: int = 1
            ) -> np.ndarray:
    """Greedy removal per frame.

    ``strain`` (F, P) from :func:`pair_strain` (NaN = unobserved pair); ``weight`` (P,) how much a pair says about
    its markers (1 / width of its widened range: rigid pairs speak loudest).  A frame stops when its worst marker
    holds fewer than ``min_count`` violated pairs.  Returns removed (F, n_markers) bool.
    """
    n_frames = strain.shape[0]
    removed = np.zeros((n_frames, n_markers), dtype=bool)
    observed = ~np.isnan(strain)
    strain = np.where(observed, strain, 0.0)
    violated = strain > 1.0
    active = np.flatnonzero(violated.any(axis=1))
    a, b = pairs[:, 0], pairs[:, 1]
    by_marker = _PerMarkerSum(pairs, n_markers)
    while active.size:
        va, oa = violated[active], observed[active]
        counts = by_marker(va.astype(np.float64))  # (F', n_markers) violated pairs per marker
        # tie-break: the weighted mean strain over all the marker's observed pairs.  Two markers whose only violated
        # pair is the one they share tie on the count; the one displaced also strains its other pairs.
        w = np.where(oa, weight[None, :], 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_strain = by_marker(w * strain[active]) / by_marker(w)
        mean_strain = np.nan_to_num(mean_strain, nan=0.0)
        # lexicographic (count, mean strain): mean_strain / (1 + mean_strain) < 1 keeps the order of counts
        worst = np.argmax(counts + mean_strain / (1.0 + mean_strain), axis=1)
        if min_count > 1:
            enough = counts[np.arange(len(active)), worst] >= min_count
            active, worst, va, oa = active[enough], worst[enough], va[enough], oa[enough]
        removed[active, worst] = True
        # pairs touching the removed marker no longer count in that frame
        gone = (a[None, :] == worst[:, None]) | (b[None, :] == worst[:, None])
        va &= ~gone
        oa &= ~gone
        violated[active] = va
        observed[active] = oa
        active = active[va.any(axis=1)]
    return removed


class _PerMarkerSum:
    """Sums over the pairs touching each marker: ``(F, P) -> (F, n_markers)`` in O(F P), not a dense (P, M) product."""

    def __init__(self, pairs: np.ndarray, n_markers: int) -> None:
        ends = np.concatenate([pairs[:, 0], pairs[:, 1]])
        order = np.argsort(ends, kind="stable")
        self.columns = order % len(pairs)  # the pair behind each end, grouped by marker
        sorted_ends = ends[order]
        self.starts = np.flatnonzero(np.r_[True, sorted_ends[1:] != sorted_ends[:-1]])
        self.markers = sorted_ends[self.starts]
        self.n_markers = n_markers

    def __call__(self, values: np.ndarray) -> np.ndarray:
        out = np.zeros((values.shape[0], self.n_markers))
        if values.shape[0]:
            out[:, self.markers] = np.add.reduceat(values[:, self.columns], self.starts, axis=1)
        return out


def _apply(positions: np.ndarray, pairs: np.ndarray, dmin: np.ndarray, dmax: np.ndarray, *, delta: float,
           min_margin: float, chunk_bytes: int) -> np.ndarray:
    """Rejected mask (n_frames, n_markers) of the greedy rule, chunked over frames."""
    n_frames, n_markers, _ = positions.shape
    known = np.isfinite(dmin) & np.isfinite(dmax)
    pairs, dmin, dmax = pairs[known], dmin[known], dmax[known]
    rejected = np.zeros((n_frames, n_markers), dtype=bool)
    if len(pairs) == 0 or n_frames == 0:
        return rejected
    span = dmax - dmin
    weight = 1.0 / (span + 2.0 * np.maximum(delta * span, min_margin))
    # about six (frames, P) float64 temporaries (diff is three of them)
    step = max(1, int(chunk_bytes // (6 * 8 * len(pairs))))
    for start in range(0, n_frames, step):
        stop = min(n_frames, start + step)
        strain = pair_strain(positions[start:stop], pairs, dmin, dmax, delta=delta, min_margin=min_margin)
        rejected[start:stop] = _greedy(strain, weight, pairs, n_markers)
    return rejected


def _pair_dist(positions: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Distances (n_frames, P) of ``pairs`` (P, 2) in ``positions`` (n_frames, n_markers, 3); NaN where missing."""
    diff = positions[:, pairs[:, 0], :] - positions[:, pairs[:, 1], :]
    return np.sqrt(np.einsum("tpc,tpc->tp", diff, diff))


def _jump_scale(positions: np.ndarray, pairs: np.ndarray, chunk_bytes: int, most: int = 20_000) -> np.ndarray:
    """Robust scale (1.4826 MAD) of each pair's frame-to-frame distance change, shape (P,); NaN if never seen.

    A median needs no more than ``most`` jumps: longer takes are sampled at evenly spaced frames.
    """
    n_frames = positions.shape[0]
    t = np.arange(n_frames - 1)
    if t.size > most:
        t = t[np.linspace(0, t.size - 1, most).astype(np.intp)]
    now, nxt = positions[t], positions[t + 1]
    scale = np.full(len(pairs), np.nan)
    step = max(1, int(chunk_bytes // (6 * 8 * max(t.size, 1))))
    for start in range(0, len(pairs), step):
        chunk = pairs[start:start + step]
        jump = np.abs(_pair_dist(nxt, chunk) - _pair_dist(now, chunk))
        ok = ~np.isnan(jump).all(axis=0)
        if ok.any():
            scale[start:start + step][ok] = 1.4826 * np.nanmedian(jump[:, ok], axis=0)
    return scale


def _stiff_pairs(pairs: np.ndarray, n_markers: int, spread: np.ndarray, k: int) -> np.ndarray:
    """Each marker's ``k`` partners with the smallest ``spread`` (P,; NaN = never seen together), as rows of
    ``pairs`` (P, 2): shape (n_markers, k) int, -1 where a marker has fewer partners."""
    cost = np.full((n_markers, n_markers), np.inf)
    row = np.full((n_markers, n_markers), -1, dtype=np.intp)
    spread = np.where(np.isnan(spread), np.inf, spread)
    cost[pairs[:, 0], pairs[:, 1]] = cost[pairs[:, 1], pairs[:, 0]] = spread
    row[pairs[:, 0], pairs[:, 1]] = row[pairs[:, 1], pairs[:, 0]] = np.arange(len(pairs))
    k = min(k, n_markers - 1)
    best = np.argsort(cost, axis=1, kind="stable")[:, :k]
    picked = row[np.arange(n_markers)[:, None], best]
    return np.where(np.isfinite(cost[np.arange(n_markers)[:, None], best]), picked, -1)


LOCAL_K = 5.0


def _median5(x: np.ndarray) -> np.ndarray:
    """Running median over five frames along axis 0 of ``x`` (F, P), edges mirrored (a step in the first jump
    is not repeated into its own window)."""
    from numpy.lib.stride_tricks import sliding_window_view

    padded = np.pad(x, ((2, 2), (0, 0)), mode="reflect" if x.shape[0] >= 3 else "edge")
    return np.median(sliding_window_view(padded, 5, axis=0), axis=2)


#: A piece with a step at one end is displaced when its deviation (in bands) exceeds ``STEP_RATIO`` times that of
#: the piece across the step plus ``STEP_MARGIN``.
STEP_RATIO = 2.0
STEP_MARGIN = 1.0


def _stepped_pieces(dev: np.ndarray, ok: np.ndarray, events: np.ndarray, longest: int,
                    displaced: np.ndarray | None = None) -> np.ndarray:
    """Displaced pieces of one marker's timeline that are bounded by a step on one side only.

    ``dev`` (n_frames, P_m): ``|D - median| / band`` of the marker's stiff pairs (NaN where unobserved); ``ok``
    (n_frames,) bool: observed and not yet found; ``events`` (E,) int: steps between frames ``e`` and ``e + 1``;
    ``displaced`` (n_frames,) bool, optional: stretches already found displaced.
    The timeline splits into *pieces* at gaps and steps.  A piece of at most ``longest`` frames is displaced when,
    across one of its steps, the neighbouring piece lies much nearer the pair's usual distances: the piece's
    deviation (median over frames, then over pairs) exceeds ``STEP_RATIO`` times the neighbour's plus
    ``STEP_MARGIN``; of such a piece, the frames are displaced unless their own deviation (median over pairs) is
    within half a margin of the neighbour's (two missed spikes with clean frames between them).  A step says where a displacement begins or ends, the deviation says which side is displaced;
    a piece that only gaps bound is left alone (no step: no evidence beyond the distance ranges).
    Returns (n_frames,) bool.
    """
    n = len(ok)
    out = np.zeros(n, dtype=bool)
    cut = np.zeros(n + 1, dtype=bool)  # cut[t]: a step between frames t - 1 and t
    cut[events + 1] = True
    starts = np.flatnonzero(ok & (~np.r_[False, ok[:-1]] | cut[:n]))
    if starts.size < 2:
        return out
    stops = np.r_[starts[1:], n]
    for i, s in enumerate(starts):  # a piece ends at the first frame that is not ok, or at the next start
        bad = np.flatnonzero(~ok[s:stops[i]])
        if bad.size:
            stops[i] = s + bad[0]
    level = np.full(len(starts), np.nan)
    for i, (s, t) in enumerate(zip(starts, stops)):
        seen = np.isfinite(dev[s:t])
        if seen.any():  # pairs whose partner is missing throughout the piece have no say
            per_pair = np.nanmedian(dev[s:t][:, seen.any(axis=0)], axis=0)
            level[i] = np.median(per_pair)
    # the marker's usual level: over all its pieces, weighted by length (most of a marker's samples are clean)
    lengths = stops - starts
    seen = np.isfinite(level)
    usual = float(np.median(np.repeat(level[seen], lengths[seen]))) if seen.any() else np.nan
    for i, (s, t) in enumerate(zip(starts, stops)):
        if t - s > longest or not np.isfinite(level[i]):
            continue
        neighbours = []
        if i > 0 and cut[s] and stops[i - 1] == s:  # a step right before, into the previous piece
            neighbours.append(level[i - 1])
        if i + 1 < len(starts) and cut[t] and starts[i + 1] == t:
            neighbours.append(level[i + 1])
        # next to a stretch already found displaced (another offset, overlapping shifts): the usual level decides
        if displaced is not None and ((s > 0 and displaced[s - 1]) or (t < n and displaced[t])):
            neighbours.append(usual)
        refs = [q for q in neighbours if np.isfinite(q)]
        if refs and level[i] > STEP_RATIO * min(refs) + STEP_MARGIN:
            # frame by frame too: a piece that holds two missed spikes is not displaced between them
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # frames where every partner is missing
                frame_level = np.nanmedian(dev[s:t], axis=1)
            out[s:t] = ~(frame_level <= min(refs) + 0.5 * STEP_MARGIN)
    return out


def _held(positions: np.ndarray, pairs: np.ndarray, weight: np.ndarray, first: int, last: int,
          before: np.ndarray, after: np.ndarray, steps: np.ndarray, share: float = 0.8) -> bool:
    """Whether the stretch of frames ``first + 1 .. last`` stays displaced from its surroundings.

    Two short spikes of one marker, the first's way back missed, would look like one stretch from the first's
    step to the second's way back; the frames between them sit where the marker belongs.  A displaced stretch
    keeps its stiff distances (``pairs`` (P_m, 2), each times ``weight`` (P_m,)) away from the line joining
    ``before`` and ``after`` (P_m,: the weighted distances at ``first`` and ``last + 1``) in at least ``share`` of
    its frames, by at least a tenth of ``steps`` (P_m,: the sizes of the two steps) summed over the pairs.
    """
    inside = weight * _pair_dist(positions[first + 1:last + 1], pairs)  # (L, P_m)
    w = (np.arange(1, last - first + 1) / (last - first + 1))[:, None]
    off = np.abs(inside - ((1 - w) * before + w * after))
    ok = ~np.isnan(steps)
    away = np.nansum(np.where(ok, off, 0.0), axis=1)
    return bool((away > 0.1 * np.nansum(steps[ok])).mean() >= share)


def shifted_runs(positions: np.ndarray, *, rate: float, max_run: float = 0.5, units: str = "mm",
                 jump_k: float = 8.0, jump_floor_mm: float = 5.0, min_pairs: int = 3, partners: int = 6,
                 cancel: float = 0.3, passes: int = 3, chunk_bytes: int = 64 * 2**20, one_sided: bool = True
                 ) -> np.ndarray:
    """Markers displaced for a stretch of frames (label swaps, ghosts, bumped markers), shape (n_frames, n_markers).

    A displaced stretch starts and ends with a *step*: in one frame the marker's distances to its stiffest
    partners all change by far more than they ever change between two clean frames, and at the end of the stretch
    they come back.  Clean motion, even fast, changes those distances smoothly (several consecutive large changes,
    going one way), and soft tissue moves one pair at a time.  So:

    1. jumps: ``J = D[t+1] - D[t]`` for each marker's ``partners`` stiffest pairs (narrowest 10th-90th percentile
       band of ``D``); a pair jumps when ``|J| > jump_k * s + jump_floor_mm``, ``s`` the robust scale of its ``J``
       (1.4826 x the median of ``|J|``);
    2. the greedy rule of :func:`reject_outliers` on those jumps, with a marker blamed only while it holds at least
       ``min_pairs`` jumping pairs: an *event* of that marker between frames t and t+1;
    3. a stretch from an event to a later one at most ``max_run`` seconds away is displaced when the marker comes
       back: summed over its stiff pairs, ``|D[end + 1] - D[start - 1]|`` is below ``cancel`` times the two steps'
       sizes, and the frames inside stay away from the line joining those two levels (:func:`_held`).  Shortest
       stretches first; a longer one may not reuse their events or frames.
    4. one step only (``one_sided``): a stretch that begins or ends at a gap, or runs into another displaced
       stretch (overlapping shifts with different offsets), has no way back to pair with.  The marker's timeline is
       cut into pieces at its gaps and events; a piece of at most ``max_run`` seconds is displaced when, across one
       of its events, the neighbouring piece lies much nearer the usual distances of the stiff pairs (the side a
       step leads *away* from the body's geometry is the displaced one; :func:`_stepped_pieces`).  On the ``random``
       protocol's 85_02 trials this took the stretches that begin or end at a gap from 4-9 % caught to 92-95 %,
       and all shifted samples from median 0.867 to 0.994 (``benchmarks/bench_corruption.py``).

    When many markers are displaced at once (``mocapfill evaluate --protocol random``), a marker's partners are
    displaced too and blur its steps: up to ``passes`` times (default 3), what was found is blanked out and the
    search runs again (on that protocol's 85_02 trials, recall of the shifted samples median 0.81 after one pass,
    0.87 after three; nothing more on clean files).

    ``positions`` (n_frames, n_markers, 3), NaN = missing; ``rate`` in Hz.  Single-frame spikes come out too
    (a stretch of one frame).  Returns bool (n_frames, n_markers), True on displaced observed samples.
    """
    options = dict(rate=rate, max_run=max_run, units=units, jump_k=jump_k, jump_floor_mm=jump_floor_mm,
                   min_pairs=min_pairs, partners=partners, cancel=cancel, chunk_bytes=chunk_bytes,
                   one_sided=one_sided)
    found = _shifted_once(positions, **options)
    for _ in range(max(1, int(passes)) - 1):
        if not found.any():
            break
        kept = positions.copy()
        kept[found] = np.nan
        more = _shifted_once(kept, **options)
        if not more.any():
            break
        found |= more
    return found


def _shifted_once(positions: np.ndarray, *, rate: float, max_run: float, units: str, jump_k: float,
                  jump_floor_mm: float, min_pairs: int, partners: int, cancel: float, chunk_bytes: int,
                  one_sided: bool = True) -> np.ndarray:
    """One pass of :func:`shifted_runs` (same arguments and result)."""
    n_frames, n_markers, _ = positions.shape
    found = np.zeros((n_frames, n_markers), dtype=bool)
    if n_frames < 3 or n_markers < 2:
        return found
    floor = jump_floor_mm * length_factor("mm", units)
    # stiff = the distance keeps within a narrow band over the clip (10th to 90th percentile: a stretch displaced
    # in a few percent of the frames does not widen it)
    stats = pair_distance_stats(positions, percentiles=(10.0, 50.0, 90.0), chunk_bytes=chunk_bytes)
    spread = stats.percentiles[:, 2] - stats.percentiles[:, 0]
    own = _stiff_pairs(stats.pairs, n_markers, spread, partners)  # (n_markers, partners) rows of stats.pairs
    sel = np.unique(own[own >= 0])
    if sel.size == 0:
        return found
    pairs = stats.pairs[sel]
    own = np.where(own >= 0, np.searchsorted(sel, own), -1)  # now rows of `pairs`
    tol = jump_k * _jump_scale(positions, pairs, chunk_bytes) + floor
    # a marker's partners are not all rigid (a wrist's sixth stiffest may be across the elbow): in the return test
    # each pair counts in units of its own band, so a rigid partner's step outweighs an elbow's swing
    weight = 1.0 / (spread[sel] + floor)
    # events[t, m]: marker m steps between frames t and t + 1; chunks of frames (P' <= n_markers * partners)
    events = np.zeros((n_frames - 1, n_markers), dtype=bool)
    step = max(2, int(chunk_bytes // (8 * 8 * len(pairs))))
    for start in range(0, n_frames - 1, step):
        stop = min(n_frames - 1, start + step)
        lo, hi = max(0, start - 2), min(n_frames - 1, stop + 2)  # two jumps of context on each side
        jump = np.abs(np.diff(_pair_dist(positions[lo:hi + 1], pairs), axis=0))
        # fast clean motion moves stiff distances several frames running; a step is one frame (two for a spike),
        # which a running median of five ignores: the threshold rises with that local level
        level = _median5(np.where(np.isnan(jump), 0.0, jump))
        strain = jump / (tol + LOCAL_K * level)
        cut = slice(start - lo, start - lo + stop - start)
        events[start:stop] = _greedy(strain[cut], 1.0 / tol, pairs, n_markers, min_count=min_pairs)
    longest = max(1, int(round(max_run * rate)))
    observed = ~np.isnan(positions).any(axis=2)
    centre = stats.percentiles[sel, 1]
    for m in np.flatnonzero(events.any(axis=0)):
        rows = own[m][own[m] >= 0]
        mine, w = pairs[rows], weight[rows]  # the return test listens to m's own stiffest partners only
        e = np.flatnonzero(events[:, m])
        # distances of m's stiff pairs just before and just after every event: (n_events, P_m) each
        before, after = w * _pair_dist(positions[e], mine), w * _pair_dist(positions[e + 1], mine)
        size = np.abs(after - before)
        # every pair of events (k, q) at most `longest` apart whose second brings the marker back is a candidate;
        # events in between are the displaced marker's own distances changing fast (no longer stiff while it is
        # displaced).  The shortest candidates win and the others may not share their events or frames, so that a
        # clean event before a displaced stretch cannot borrow that stretch's first step as its way back.
        candidates = []
        for k in range(len(e) - 1):
            for q in range(k + 1, len(e)):
                if e[q] - e[k] > longest:
                    break
                back = np.abs(after[q] - before[k])
                steps = size[k] + size[q]
                ok = ~(np.isnan(back) | np.isnan(steps))
                if ok.sum() >= 4:
                    # a partner displaced itself at one end (another swap, a ghost) must not veto: drop the pair
                    # that comes back least
                    ok[np.argmax(np.where(ok, back, -np.inf))] = False
                if ok.any() and back[ok].sum() < cancel * steps[ok].sum():
                    candidates.append((e[q] - e[k], k, q))
        used = np.zeros(len(e), dtype=bool)
        for _, k, q in sorted(candidates):
            if used[k] or used[q] or found[e[k] + 1:e[q] + 1, m].any():
                continue
            if _held(positions, mine, w, e[k], e[q], before[k], after[q], size[k] + size[q]):
                found[e[k] + 1:e[q] + 1, m] = True
                used[k] = used[q] = True
        if one_sided:
            # stretches with a step at one end only (the other end is a gap, or another displaced stretch)
            dev = np.abs(_pair_dist(positions, mine) - centre[rows]) * w  # (n_frames, P_m), in bands
            found[:, m] |= _stepped_pieces(dev, observed[:, m] & ~found[:, m], e, longest, found[:, m])
    return found & observed


def _align(reference: np.ndarray, labels: Sequence[str] | None, reference_labels: Sequence[str] | None,
           n_markers: int) -> np.ndarray:
    reference = np.asarray(reference, dtype=np.float64)
    if reference.ndim != 3 or reference.shape[2] != 3:
        raise MocapfillError(f"reference must have shape (n_frames, n_markers, 3), got {reference.shape}")
    if reference_labels is None or labels is None:
        if reference.shape[1] != n_markers:
            raise MocapfillError(f"reference has {reference.shape[1]} markers, the data {n_markers}; "
                                 "give labels and reference_labels to match them by name")
        return reference
    where = {str(label): k for k, label in enumerate(reference_labels)}
    short = {}
    for k, label in enumerate(reference_labels):
        short.setdefault(str(label).rsplit(":", 1)[-1], []).append(k)
    aligned = np.full((reference.shape[0], n_markers, 3), np.nan)
    found = 0
    for m, label in enumerate(labels):
        k = where.get(str(label))
        if k is None:
            hits = short.get(str(label).rsplit(":", 1)[-1], [])
            k = hits[0] if len(hits) == 1 else None
        if k is not None:
            aligned[:, m] = reference[:, k]
            found += 1
    if found < 2:
        raise MocapfillError(f"the reference shares {found} marker label(s) with the data; need at least 2")
    return aligned


def reject_outliers(positions: np.ndarray, *, reference: np.ndarray | None = None, delta: float = 0.1,
                    units: str = "mm", percentile: float = 0.0, robust_delta: float = 0.5,
                    min_margin: float | None = None, min_frames: int | None = None,
                    labels: Sequence[str] | None = None, reference_labels: Sequence[str] | None = None,
                    reference_units: str | None = None, chunk_bytes: int = 64 * 2**20, window: int = 3,
                    two_stage: bool = True, stage1_passes: int = 3, rate: float | None = None,
                    runs: bool = True, max_run: float = 0.5, widen_with_self: bool = False) -> OutlierResult:
    """Remove markers that break the inter-marker distance ranges (Holden's rule; see the module docstring).

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    reference : ndarray, shape (n_ref_frames, n_ref_markers, 3), optional
        A clean capture of the same marker set, in ``units`` unless ``reference_units`` says otherwise (exact min /
        max are used).  Default: the file itself (two stages).
    delta : float
        Margin as a fraction of each pair's range (Holden: 0.1).
    units : str
        Units of ``positions``; scales ``min_margin``'s default (1 mm).
    percentile : float
        Stage-1 robust range of the self-reference: the ``percentile`` and ``100 - percentile`` percentiles of the
        running-median distance (default 0: its min and max).
    robust_delta : float
        Stage-1 margin as a fraction of that robust range (default 0.5).
    window : int
        Running-median window (odd, frames) of stage 1 (default 3; 1 = none).
    two_stage : bool
        False: use the stage-1 ranges directly as ``Dmin`` / ``Dmax`` (with ``delta``).
    stage1_passes : int
        Most repetitions of stage 1 with the samples found so far blanked out (default 3).
    min_margin : float, optional
        Smallest margin, in ``units`` (default 1 mm converted).
    min_frames : int, optional
        Pairs seen together in fewer reference frames are unconstrained (default as for bones:
        ``max(10, min(100, n_frames // 2))``).
    labels, reference_labels : sequence of str, optional
        When both are given the reference's markers are matched to the data's by label (exact, else without a
        ``Subject:`` prefix); markers absent from the reference are unconstrained.
    reference_units : str, optional
        Units of ``reference`` when they differ from ``units``: it is converted (mm / cm / m).
    chunk_bytes : int
        Working-memory budget of one chunk of frames x pairs.
    rate : float, optional
        Frame rate in Hz (default 120), for ``max_run``.
    runs : bool
        Self-reference only: first find markers displaced for a stretch of frames with :func:`shifted_runs`
        (default True); they are rejected and left out of the ranges.
    max_run : float
        Longest displaced stretch looked for, in seconds (default 0.5).
    widen_with_self : bool
        With a ``reference``: each pair's range is the span of the reference's and the file's own (two-stage)
        range.  For a reference that is another take of the subject rather than a clean copy of this one: it did not
        pose every pose of this take, and alone it would reject them (16_07 against 16_08: 7,120 of 17,302 samples).

    Returns
    -------
    OutlierResult
        ``positions`` with rejected samples NaN, ``rejected`` (n_frames, n_markers) bool, and the final ranges.
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise MocapfillError(f"positions must have shape (n_frames, n_markers, 3), got {positions.shape}")
    length_factor(units, "mm")  # an unknown unit fails here, before any work
    if not (delta >= 0 and robust_delta >= 0 and 0 <= percentile < 50):
        raise MocapfillError(f"delta and robust_delta must be >= 0 and percentile in [0, 50) "
                             f"(got {delta}, {robust_delta}, {percentile})")
    n_frames, n_markers, _ = positions.shape
    if min_margin is None:
        min_margin = DEFAULT_MIN_MARGIN_MM * length_factor("mm", units)
    observed = ~np.isnan(positions).any(axis=2)
    original, displaced = positions, None
    if n_markers < 2 or n_frames == 0:
        return OutlierResult(positions.copy(), np.zeros((n_frames, n_markers), dtype=bool))
    if reference is None or widen_with_self:
        if runs:
            # displaced stretches would widen the ranges they should break: find them first, then treat them as gaps
            displaced = shifted_runs(positions, rate=120.0 if rate is None else float(rate), max_run=max_run,
                                     units=units, chunk_bytes=chunk_bytes)
            if displaced.any():
                positions = positions.copy()
                positions[displaced] = np.nan
        mf = default_min_frames(n_frames) if min_frames is None else min_frames
        pairs, lo, hi = _ranges(positions, percentile, mf, window)
        if two_stage:
            kept = positions
            first = np.zeros((n_frames, n_markers), dtype=bool)
            for _ in range(max(1, int(stage1_passes))):
                found = _apply(positions, pairs, lo, hi, delta=robust_delta, min_margin=min_margin,
                               chunk_bytes=chunk_bytes)
                if np.array_equal(found, first):
                    break
                first = found
                kept = positions.copy()
                kept[first] = np.nan
                # outliers hit the same pair in two of three frames now and then, which the running median cannot
                # ignore: with what was found blanked out, those windows drop out of the ranges
                _, lo, hi = _ranges(kept, percentile, mf, window)
            _, dmin, dmax = _ranges(kept, 0.0, mf)
        else:
            dmin, dmax = lo, hi
    if reference is not None:
        ref = _align(reference, labels, reference_labels, n_markers)
        if reference_units is not None and reference_units != units:
            ref = ref * length_factor(reference_units, units)
        mf = default_min_frames(ref.shape[0]) if min_frames is None else min_frames
        ref_pairs, rmin, rmax = _ranges(ref, 0.0, mf)
        if widen_with_self:  # the same pairs in the same order (every pair of the n_markers)
            with np.errstate(invalid="ignore"):
                dmin, dmax = np.fmin(dmin, rmin), np.fmax(dmax, rmax)
        else:
            pairs, dmin, dmax = ref_pairs, rmin, rmax
    rejected = _apply(positions, pairs, dmin, dmax, delta=delta, min_margin=min_margin, chunk_bytes=chunk_bytes)
    if displaced is not None:
        rejected |= displaced
        positions = original
    rejected &= observed
    out = positions.copy()
    out[rejected] = np.nan
    return OutlierResult(out, rejected, dmin, dmax, pairs)
