"""Runs of missing samples ("gaps") per marker, and whole-body blackouts."""

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
