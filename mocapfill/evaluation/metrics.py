"""Scores of one fill against the truth, over the samples a trial hid (and shifted).

All errors are in the clip's units.  ``err_t,i = ||x_hat - x_true||`` is the Euclidean error of sample (frame t,
marker i); over the scored samples S:

- ``rmse``      sqrt(mean over S of err^2)
- ``max_error`` max over S of err
- ``mse``       the BoLeRO paper's Eq. 13: the squared error per coordinate averaged over the hidden coordinates,
                sum_{t,i in S} ||x_hat - x||^2 / (3 |S|)  (= rmse^2 / 3; in units squared, the paper used metres)
- ``bone_error`` mean over (bone, frame) of | ||x_hat_u - x_hat_v|| - L | for the bones (u, v) with a hidden end,
                on the frames where an end is hidden; bones and L are estimated from the occluded input only
- ``unfilled``  samples of S the method left missing (they do not enter the errors above)
- ``error_ratio`` how honest the method's uncertainty is: the RMS error per coordinate over S divided by the RMS of
                the method's ``std`` there (1 = honest, 2 = errors twice what it said); NaN for methods without one
"""

from __future__ import annotations

import numpy as np


def point_errors(estimate: np.ndarray, truth: np.ndarray, scored: np.ndarray) -> np.ndarray:
    """Euclidean errors of the scored samples: estimate/truth (n_frames, n_markers, 3), scored (n_frames, n_markers)
    bool; returns (n_scored,) float, NaN where the estimate is missing."""
    diff = estimate[scored] - truth[scored]
    return np.sqrt((diff ** 2).sum(axis=1))


def score(estimate: np.ndarray, truth: np.ndarray, scored: np.ndarray, hidden: np.ndarray,
          bone_pairs: np.ndarray, bone_lengths: np.ndarray, std: np.ndarray | None = None) -> dict[str, float | int]:
    """The metrics of one fill (see the module docstring).

    estimate, truth : (n_frames, n_markers, 3); scored, hidden : (n_frames, n_markers) bool (scored = hidden plus
    shifted samples); bone_pairs : (B, 2) int; bone_lengths : (B,); std : (n_frames, n_markers) the method's
    per-coordinate uncertainty, or None.  Metrics without a sample are NaN.
    """
    err = point_errors(estimate, truth, scored)
    ok = np.isfinite(err)
    good = err[ok]
    out: dict[str, float | int] = {
        "rmse": float(np.sqrt(np.mean(good ** 2))) if good.size else float("nan"),
        "max_error": float(good.max()) if good.size else float("nan"),
        "mse": float(np.mean(good ** 2) / 3.0) if good.size else float("nan"),
        "n_scored": int(scored.sum()),
        "unfilled": int((~ok).sum()),
    }
    out["bone_error"] = bone_error(estimate, hidden, bone_pairs, bone_lengths)
    out["error_ratio"] = float("nan")
    if std is not None:
        sd = std[scored]
        both = ok & np.isfinite(sd)
        if both.any() and np.mean(sd[both] ** 2) > 0:
            out["error_ratio"] = float(np.sqrt(np.mean(err[both] ** 2) / 3.0 / np.mean(sd[both] ** 2)))
    return out


def bone_error(estimate: np.ndarray, hidden: np.ndarray, pairs: np.ndarray, lengths: np.ndarray) -> float:
    """Mean absolute bone-length error of ``estimate`` (n_frames, n_markers, 3) on the frames where a bone (pairs
    (B, 2), lengths (B,)) has a hidden end (hidden (n_frames, n_markers) bool); NaN without such a bone-frame."""
    pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
    if not len(pairs):
        return float("nan")
    a, b = pairs[:, 0], pairs[:, 1]
    touched = hidden[:, a] | hidden[:, b]  # (n_frames, B)
    if not touched.any():
        return float("nan")
    frames, bone = np.nonzero(touched)
    d = np.linalg.norm(estimate[frames, a[bone]] - estimate[frames, b[bone]], axis=1)
    e = np.abs(d - np.asarray(lengths, dtype=float)[bone])
    e = e[np.isfinite(e)]
    return float(e.mean()) if e.size else float("nan")
