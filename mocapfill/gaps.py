"""Runs of missing samples ("gaps") per marker, whole-body blackouts, and the shapes fills take across a gap."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Gap(NamedTuple):
    """One run of consecutive missing frames of one marker.

    ``start`` is a 0-based frame index, ``length`` a number of frames; ``at_start`` / ``at_end`` say whether the
    gap touches the first / last frame of the capture (so there is no observation on that side).
    """

    marker: int
    start: int
    length: int
    at_start: bool
    at_end: bool

    @property
    def stop(self) -> int:
        """One past the last missing frame (0-based)."""
        return self.start + self.length


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True in a 1-D boolean array, as (start, length) pairs in order."""
    mask = np.asarray(mask, dtype=bool)
    if mask.size == 0:
        return []
    padded = np.concatenate(([False], mask, [False]))
    edges = np.flatnonzero(padded[1:] != padded[:-1])
    starts, stops = edges[0::2], edges[1::2]
    return [(int(a), int(b - a)) for a, b in zip(starts, stops)]


def fragments(missing: np.ndarray, longest: int) -> np.ndarray:
    """(n_frames, n_markers) bool: the observed samples in runs of at most ``longest`` frames with a missing sample
    right before and right after them (``missing`` (n_frames, n_markers) bool).  A run touching the first or last
    frame is not between gaps and is never marked."""
    missing = np.asarray(missing, dtype=bool)
    out = np.zeros(missing.shape, dtype=bool)
    n_frames = missing.shape[0]
    for m in np.flatnonzero(missing.any(axis=0)):
        for start, length in runs(~missing[:, m]):
            if length <= longest and start > 0 and start + length < n_frames:
                out[start:start + length, m] = True
    return out


def brownian_variance(start: int, length: int, n_frames: int) -> np.ndarray:
    """(length,) variance per unit rate of a random walk across the gap [start, start + length) of a capture of
    ``n_frames``, pinned at the observed frame on either side: ``d_a d_b / (length + 1)`` with d_a, d_b the distances
    (frames) to them; from its one observed end at a capture edge, ``d``; zeros with no observed end."""
    t = np.arange(length, dtype=np.float64)
    if start > 0 and start + length < n_frames:
        return (t + 1.0) * (length - t) / (length + 1.0)
    if start > 0:
        return t + 1.0
    if start + length < n_frames:
        return length - t
    return np.zeros(length)


def end_blend(left: np.ndarray | None, right: np.ndarray | None, length: int) -> np.ndarray | None:
    """(length, d) the straight blend across a gap from ``left`` (d,), the value at the frame before it, to ``right``,
    at the frame after it: weights ``(i + 1) / (length + 1)``.  A missing end (None: the gap touches the capture's
    edge) holds the other; None when both are missing."""
    if left is None and right is None:
        return None
    left = right if left is None else left
    right = left if right is None else right
    w = (np.arange(length) + 1.0)[:, None] / (length + 1.0)
    return (1.0 - w) * left + w * right


def find_gaps(missing: np.ndarray) -> list[Gap]:
    """All gaps of a missing mask.

    Parameters
    ----------
    missing : ndarray of bool, shape (n_frames, n_markers)
        True where a marker's sample is missing (see :attr:`MarkerData.missing`).

    Returns
    -------
    list of Gap, ordered by marker then start frame.
    """
    missing = np.asarray(missing, dtype=bool)
    n_frames = missing.shape[0]
    gaps = []
    for marker in range(missing.shape[1]):
        for start, length in runs(missing[:, marker]):
            gaps.append(Gap(marker, start, length, start == 0, start + length == n_frames))
    return gaps


def missing_mask(positions: np.ndarray) -> np.ndarray:
    """Missing mask of ``positions`` (n_frames, n_markers, 3): True where any coordinate is NaN."""
    return np.isnan(positions).any(axis=2)


def blackout_frames(missing: np.ndarray) -> np.ndarray:
    """Indices of frames where every marker is missing; ``missing`` has shape (n_frames, n_markers)."""
    missing = np.asarray(missing, dtype=bool)
    if missing.shape[1] == 0:
        return np.arange(0)
    return np.flatnonzero(missing.all(axis=1))


def all_missing_markers(missing: np.ndarray) -> np.ndarray:
    """Indices of markers missing in every frame; ``missing`` has shape (n_frames, n_markers)."""
    missing = np.asarray(missing, dtype=bool)
    if missing.shape[0] == 0:
        return np.arange(missing.shape[1])
    return np.flatnonzero(missing.all(axis=0))


def unique_rows(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct rows of a boolean matrix (n, p): (patterns (u, p), inverse (n,), counts (u,)).

    The same as ``np.unique(mask, axis=0, return_inverse=True, return_counts=True)`` (rows in lexicographic order,
    False before True), which sorts the rows as opaque byte strings and took a tenth of a messy capture's fill.
    Here each row is packed into big-endian 64-bit words, whose numeric order is the rows' lexicographic order.
    """
    mask = np.asarray(mask, dtype=bool)
    n = mask.shape[0]
    packed = np.packbits(mask, axis=1)
    pad = (-packed.shape[1]) % 8
    if pad or packed.shape[1] == 0:
        packed = np.concatenate([packed, np.zeros((n, pad or 8), dtype=np.uint8)], axis=1)
    words = packed.view(">u8")  # (n, n_words)
    order = np.lexsort(words.T[::-1])  # stable: each pattern's first row comes first
    ordered = words[order]
    new = np.ones(n, dtype=bool)
    new[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    inverse = np.empty(n, dtype=np.intp)
    inverse[order] = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    return mask[order[starts]], inverse, np.diff(np.append(starts, n))


def members(inverse: np.ndarray, n_groups: int) -> list[np.ndarray]:
    """Indices (ascending) of each group's rows, ``[np.flatnonzero(inverse == g) for g in range(n_groups)]``
    without a pass over every row per group."""
    order = np.argsort(inverse, kind="stable")
    bounds = np.searchsorted(inverse[order], np.arange(n_groups + 1))
    return [order[bounds[g]:bounds[g + 1]] for g in range(n_groups)]
