"""``--min-fragment``: short observed stretches between two gaps become part of the gap around them.

A marker flickering in and out of view leaves fragments of a few frames between gaps, often with its worst samples
(the cameras saw it at the edge of their view); a fill that must pass through them jerks.  Here a fragment shorter
than ``min_fragment`` frames with a gap on both sides is dropped, and the fill bridges the whole stretch.  This
changes the output at observed samples, so the reports count the fragments and the status array marks them
(:attr:`~mocapfill.status.Status.REJECTED_FRAGMENT`).
"""

from __future__ import annotations

import numpy as np

from ..errors import MethodError
from ..gaps import fragments, runs


def short_fragments(missing: np.ndarray, min_fragment: int) -> np.ndarray:
    """Observed stretches shorter than ``min_fragment`` frames with a gap before and after them.

    Parameters
    ----------
    missing : ndarray of bool, shape (n_frames, n_markers)
    min_fragment : int
        Fragments of fewer frames are returned; 1 returns none.

    Returns
    -------
    ndarray of bool, shape (n_frames, n_markers)
        True on the samples of each such fragment (never on a stretch that touches the first or last frame).
    """
    if int(min_fragment) < 1:
        raise MethodError(f"--min-fragment must be at least 1 frame, got {min_fragment}")
    return fragments(missing, int(min_fragment) - 1)


def count_fragments(fragments: np.ndarray) -> int:
    """The number of fragments (runs of True per marker) in ``fragments`` (n_frames, n_markers) bool."""
    fragments = np.asarray(fragments, dtype=bool)
    return sum(len(runs(fragments[:, m])) for m in range(fragments.shape[1]))
