"""Inter-marker distance statistics over the frames where both markers of a pair are observed.

One module serves bone estimation (:mod:`mocapfill.bones.boneset`: which pairs keep a constant distance) and outlier
rejection (:mod:`mocapfill.guards.outliers`: the distance range each pair normally stays in).

Percentiles are exact (NumPy's default "linear" definition, the same numbers as ``np.nanpercentile``): the
distances of a chunk of pairs are sorted in place, which on NumPy >= 2 uses a vectorised sort and is cheaper than
``np.nanpercentile``'s per-row fallback once rows hold NaN.  Work is chunked over pairs so that memory stays at the
size of the input plus a fixed budget (``chunk_bytes``), whatever the number of pairs.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np

from ..errors import MocapfillError

#: Default percentiles (in percent) computed per pair.
DEFAULT_PERCENTILES = (1.0, 5.0, 50.0, 95.0, 99.0)

#: Default working-memory budget of one chunk (bytes); a chunk holds about four (chunk, n_frames) float64 arrays.
DEFAULT_CHUNK_BYTES = 64 * 2**20


class DistanceStats(NamedTuple):
    """Statistics of the distance between the two markers of each pair, over frames where both are observed.

    Every field is an array over pairs (P = number of pairs); pairs never observed together have ``count`` 0 and
    NaN everywhere else.  ``std`` is the population standard deviation (ddof=0).

    pairs : ndarray int, shape (P, 2)
    count : ndarray int, shape (P,)
    mean, std, min, max : ndarray float64, shape (P,)
    percentiles : ndarray float64, shape (P, k), one column per entry of ``levels``
    levels : ndarray float64, shape (k,), the percentiles (in percent) of the columns of ``percentiles``
    """

    pairs: np.ndarray
    count: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    min: np.ndarray
    max: np.ndarray
    percentiles: np.ndarray
    levels: np.ndarray

    def percentile(self, q: float) -> np.ndarray:
        """The column of ``percentiles`` for level ``q`` (percent), shape (P,); raises if it was not computed."""
        hits = np.flatnonzero(np.isclose(self.levels, q))
        if hits.size == 0:
            raise MocapfillError(f"percentile {q:g} was not computed (have {', '.join(f'{v:g}' for v in self.levels)})")
        return self.percentiles[:, hits[0]]


def all_pairs(n_markers: int) -> np.ndarray:
    """Every unordered marker pair (i < j) in row-major order, shape (n_markers*(n_markers-1)/2, 2) int."""
    i, j = np.triu_indices(n_markers, k=1)
    return np.stack([i, j], axis=1).astype(np.intp)


def pair_index(pairs: np.ndarray, n_markers: int) -> np.ndarray:
    """The row of ``pairs`` (P, 2) for (i, j) and (j, i), as a (n_markers, n_markers) int matrix; -1 if absent."""
    index = np.full((n_markers, n_markers), -1, dtype=np.intp)
    rows = np.arange(len(pairs))
    index[pairs[:, 0], pairs[:, 1]] = rows
    index[pairs[:, 1], pairs[:, 0]] = rows
    return index


def pair_distances(positions: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Distance between the markers of each pair in every frame, shape (n_frames, P); NaN where either is missing.

    Not chunked: meant for a modest number of pairs (bones).  ``positions`` (n_frames, n_markers, 3).
    """
    positions = np.asarray(positions, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    diff = positions[:, pairs[:, 0], :] - positions[:, pairs[:, 1], :]
    return np.sqrt(np.einsum("tpc,tpc->tp", diff, diff))


def _check(positions: np.ndarray, pairs: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise MocapfillError(f"positions must have shape (n_frames, n_markers, 3), got {positions.shape}")
    n_markers = positions.shape[1]
    if pairs is None:
        pairs = all_pairs(n_markers)
    else:
        pairs = np.asarray(pairs)
        if pairs.size == 0:
            pairs = np.zeros((0, 2), dtype=np.intp)
        if pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer):
            raise MocapfillError(f"pairs must be an integer array of shape (P, 2), got {pairs.dtype} {pairs.shape}")
        pairs = pairs.astype(np.intp)
        if pairs.size and (pairs.min() < 0 or pairs.max() >= n_markers):
            raise MocapfillError(f"pair index out of range for {n_markers} markers")
    return positions, pairs


def pair_distance_stats(positions: np.ndarray, pairs: np.ndarray | None = None, *,
                        percentiles: Sequence[float] = DEFAULT_PERCENTILES,
                        chunk: int | None = None, chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                        window: int = 1) -> DistanceStats:
    """Distance statistics per marker pair over the frames where both markers are observed.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing (a sample with any NaN coordinate counts as missing).
    pairs : ndarray int, shape (P, 2), optional
        Marker index pairs; default every pair i < j (see :func:`all_pairs`).
    percentiles : sequence of float, length k
        Percent levels in [0, 100], computed exactly with linear interpolation (as ``np.nanpercentile``).
    chunk : int, optional
        Pairs per chunk; default from ``chunk_bytes``.
    chunk_bytes : int
        Working memory of one chunk; peak memory is about 2 x positions (one transposed copy) plus this.
    window : int
        1 (default): statistics of the distance itself.  An odd ``window`` > 1: statistics of its running median
        over ``window`` consecutive frames (a window with a missing frame is skipped), which ignores spikes shorter
        than ``window // 2 + 1`` frames while keeping any pose held that long; ``count`` then counts windows.

    Returns
    -------
    DistanceStats
    """
    positions, pairs = _check(positions, pairs)
    levels = np.asarray(percentiles, dtype=np.float64).reshape(-1)
    if levels.size and (levels.min() < 0 or levels.max() > 100 or not np.isfinite(levels).all()):
        raise MocapfillError(f"percentiles must lie in [0, 100], got {list(levels)}")
    window = int(window)
    if window < 1 or window % 2 == 0:
        raise MocapfillError(f"window must be a positive odd number of frames, got {window}")
    n_frames, n_markers, _ = positions.shape
    n_pairs = len(pairs)
    if chunk is None:
        # about four (chunk, n_frames) float64 buffers are alive at once, plus the running median's window copy
        chunk = max(1, int(chunk_bytes // ((4 + (window if window > 1 else 0)) * 8 * max(n_frames, 1))))
    chunk = int(max(1, min(chunk, max(n_pairs, 1))))

    count = np.zeros(n_pairs, dtype=np.intp)
    mean = np.full(n_pairs, np.nan)
    std = np.full(n_pairs, np.nan)
    dmin = np.full(n_pairs, np.nan)
    dmax = np.full(n_pairs, np.nan)
    pct = np.full((n_pairs, levels.size), np.nan)
    if n_pairs == 0 or n_frames < window:
        return DistanceStats(pairs, count, mean, std, dmin, dmax, pct, levels)

    # Marker-major copy (3, n_markers, n_frames): gathering a marker's trajectory is then one contiguous row,
    # and each pair's distances come out as a contiguous row ready to be sorted in place.
    coords = np.ascontiguousarray(positions.transpose(2, 1, 0))
    # a sample is missing when any coordinate is NaN: make all three NaN so that the distance is NaN
    bad = np.isnan(coords).any(axis=0)
    if bad.any():
        coords[:, bad] = np.nan
    del bad

    buf_a = np.empty((chunk, n_frames))
    buf_b = np.empty((chunk, n_frames))
    d2 = np.empty((chunk, n_frames))
    for start in range(0, n_pairs, chunk):
        stop = min(start + chunk, n_pairs)
        m = stop - start
        a, b, d = buf_a[:m], buf_b[:m], d2[:m]
        for c in range(3):
            # mode="clip": with the default mode="raise" NumPy buffers `out` (an extra copy); indices are checked
            np.take(coords[c], pairs[start:stop, 0], axis=0, out=a, mode="clip")
            np.take(coords[c], pairs[start:stop, 1], axis=0, out=b, mode="clip")
            if c == 0:
                np.subtract(a, b, out=d)
                np.multiply(d, d, out=d)
            else:
                np.subtract(a, b, out=a)
                np.multiply(a, a, out=a)
                np.add(d, a, out=d)
        np.sqrt(d, out=d)
        if window > 1:
            d = _running_median(d, window)
        # sorted in place; NaN sort to the end of each row, so the first `n` entries are the observed distances
        # and `n` is where the first NaN sits (a binary search per row instead of a pass over the chunk)
        d.sort(axis=1)
        n = np.array([np.searchsorted(row, np.nan) for row in d], dtype=np.intp)
        count[start:stop] = n
        ok = n > 0
        if not ok.any():
            continue
        if not ok.all():
            d, n = d[ok], n[ok]
        rows = len(n)
        width = d.shape[1]
        dmin[start:stop][ok] = d[:, 0]
        dmax[start:stop][ok] = d[np.arange(rows), n - 1]
        # sums over observed entries only: zero the NaN tails (percentiles below read only the first n entries)
        tails = np.flatnonzero(n < width)
        for r in tails:
            d[r, n[r]:] = 0.0
        mu = d.sum(axis=1) / n
        mean[start:stop][ok] = mu
        # two-pass variance for accuracy (distances are large compared with their spread)
        dev = a[:rows, :width]
        np.subtract(d, mu[:, None], out=dev)
        for r in tails:
            dev[r, n[r]:] = 0.0
        np.multiply(dev, dev, out=dev)
        std[start:stop][ok] = np.sqrt(dev.sum(axis=1) / n)
        if levels.size:
            # linear interpolation between order statistics at virtual index q/100 * (n - 1)
            virtual = levels[None, :] / 100.0 * (n[:, None] - 1)
            lo = np.floor(virtual).astype(np.intp)
            hi = np.minimum(lo + 1, n[:, None] - 1)
            frac = virtual - lo
            vlo = np.take_along_axis(d, lo, axis=1)
            vhi = np.take_along_axis(d, hi, axis=1)
            pct[start:stop][ok] = vlo + frac * (vhi - vlo)
    return DistanceStats(pairs, count, mean, std, dmin, dmax, pct, levels)


def _running_median(d: np.ndarray, window: int) -> np.ndarray:
    """Running median along axis 1 of ``d`` (m, n) over ``window`` frames: (m, n - window + 1); NaN if any is NaN."""
    from numpy.lib.stride_tricks import sliding_window_view

    # NaN propagates (np.median, np.minimum, np.maximum), so a window touching a gap is NaN and skipped by the caller
    if window == 3:
        # median of three by min / max: several times faster than partitioning a windowed copy
        x, y, z = d[:, :-2], d[:, 1:-1], d[:, 2:]
        return np.maximum(np.minimum(x, y), np.minimum(np.maximum(x, y), z))
    return np.median(sliding_window_view(d, window, axis=1), axis=2)
