"""Per-sample status codes: what became of each sample of a capture, in every output format.

``status`` arrays have shape (n_frames, n_markers) and dtype int8; C3D keeps its residuals as well, the other formats
get ``--status FILE.csv`` (one row per frame and marker, the code's :data:`NAMES` text) and Python gets the array.
The codes are stable: files written by one version are read by the next.
"""

from __future__ import annotations

from enum import IntEnum


class Status(IntEnum):
    """What became of one sample (frame, marker)."""

    OBSERVED = 0  #: seen in the input and returned as it was (bit-identical)
    FILLED = 1  #: missing (or rejected) in the input and filled
    MISSING_TOO_LONG = 2  #: left missing: its gap is longer than ``--max-gap``
    MISSING_EDGE = 3  #: left missing: its gap touches the first or last frame and ``--edges leave``
    MISSING_DECLINED = 4  #: left missing: the method declined the gap (too few frames or donors)
    MISSING_NOT_CHOSEN = 5  #: left missing: the marker was not chosen by ``--markers`` / ``--exclude``
    MISSING = 6  #: left missing for another reason (no method could fill it)
    REJECTED_OUTLIER = 7  #: observed, rejected as an outlier (``--reject-outliers``), then filled
    REJECTED_HELD = 8  #: observed, a held or frozen sample (the held-sample guard), then filled
    REJECTED_FRAGMENT = 9  #: observed, a fragment shorter than ``--min-fragment``, then filled
    REPAIRED = 10  #: observed, moved by the learned denoiser (``--denoise``) as displaced or swapped
    MODEL_POINT = 11  #: a model point (computed by the capture software), kept untouched
    UNLABELLED = 12  #: an unlabelled trajectory, kept untouched
    SMOOTHED = 13  #: observed, changed by ``--smooth`` or ``--lowpass``
    SUSPECT = 14  #: observed and returned as it was, but ``auto`` judged its run between two gaps displaced: review
    MISSING_NEVER_OBSERVED = 15  #: left missing: the input never shows the marker (a reference that does can fill it)


#: The text each code is written as in a status CSV.
NAMES = {
    Status.OBSERVED: "observed",
    Status.FILLED: "filled",
    Status.MISSING_TOO_LONG: "left missing (too long)",
    Status.MISSING_EDGE: "left missing (at an edge)",
    Status.MISSING_DECLINED: "left missing (declined)",
    Status.MISSING_NOT_CHOSEN: "left missing (not chosen)",
    Status.MISSING: "left missing",
    Status.REJECTED_OUTLIER: "rejected (outlier)",
    Status.REJECTED_HELD: "rejected (held)",
    Status.REJECTED_FRAGMENT: "rejected (fragment)",
    Status.REPAIRED: "repaired (denoised)",
    Status.MODEL_POINT: "model point",
    Status.UNLABELLED: "unlabelled",
    Status.SMOOTHED: "smoothed",
    Status.SUSPECT: "observed (judged displaced)",
    Status.MISSING_NEVER_OBSERVED: "left missing (never observed)",
}
