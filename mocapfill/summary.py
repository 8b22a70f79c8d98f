"""Per-marker gap statistics of a capture, for ``mocapfill info`` and the fill reports.

Pure: arrays in, plain dicts out (JSON-ready: only str, int, float, bool, list, dict; no NaN).  Frame numbers in
the output are given both as 0-based indices (``start``) and as the file's own frame numbers (``first_frame`` /
``last_frame``, which count from ``MarkerData.first_frame``).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .gaps import find_gaps, runs
from .markers import MarkerData

__all__ = ["summarize", "summarize_missing", "frame_ranges"]


def frame_ranges(indices: np.ndarray | Sequence[int], first_frame: int = 1) -> list[dict[str, int]]:
    """Consecutive runs of 0-based frame ``indices`` as ``{"start", "length", "first_frame", "last_frame"}`` dicts."""
    indices = np.asarray(indices, dtype=np.int64)
    if indices.size == 0:
        return []
    mask = np.zeros(int(indices.max()) + 1, dtype=bool)
    mask[indices] = True
    return [{"start": s, "length": n, "first_frame": first_frame + s, "last_frame": first_frame + s + n - 1}
            for s, n in runs(mask)]


def summarize_missing(missing: np.ndarray, *, rate: float, labels: Sequence[str] | None = None,
                      first_frame: int = 1) -> dict[str, Any]:
    """Gap statistics of a missing mask.

    Parameters
    ----------
    missing : ndarray of bool, shape (n_frames, n_markers)
    rate : float
        Frames per second (to express gap lengths in seconds).
    labels : sequence of str, length n_markers (default ``M1``, ``M2`` ...)
    first_frame : int
        The file's number for frame index 0.

    Returns
    -------
    dict with ``n_frames``, ``n_markers``, ``n_missing``, ``percent_missing``, ``n_gaps``, ``longest_gap_frames``,
    ``longest_gap_seconds``, ``markers_missing_throughout`` (labels), ``markers_complete`` (count),
    ``blackout_frames`` (count), ``blackouts`` (ranges, see :func:`frame_ranges`) and ``markers``: one dict per marker
    with ``label``, ``n_missing``, ``percent_missing``, ``n_gaps``, ``longest_gap_frames``, ``longest_gap_seconds``,
    ``gap_at_start``, ``gap_at_end``, ``missing_throughout`` and ``gaps`` (``start``, ``length``, ``first_frame``,
    ``last_frame`` each).
    """
    missing = np.asarray(missing, dtype=bool)
    if missing.ndim != 2:
        raise ValueError(f"missing must have shape (n_frames, n_markers), got {missing.shape}")
    n_frames, n_markers = missing.shape
    labels = list(labels) if labels is not None else [f"M{k + 1}" for k in range(n_markers)]
    seconds = (lambda n: n / rate) if rate and rate > 0 else (lambda n: 0.0)
    per_marker: list[dict[str, Any]] = [
        {"label": labels[k], "n_missing": int(missing[:, k].sum()),
         "percent_missing": 100.0 * float(missing[:, k].mean()) if n_frames else 0.0,
         "n_gaps": 0, "longest_gap_frames": 0, "longest_gap_seconds": 0.0, "gap_at_start": False,
         "gap_at_end": False, "missing_throughout": bool(n_frames) and bool(missing[:, k].all()), "gaps": []}
        for k in range(n_markers)]
    gaps = find_gaps(missing)
    for gap in gaps:
        entry = per_marker[gap.marker]
        entry["n_gaps"] += 1
        entry["gaps"].append({"start": gap.start, "length": gap.length, "first_frame": first_frame + gap.start,
                              "last_frame": first_frame + gap.stop - 1})
        if gap.length > entry["longest_gap_frames"]:
            entry["longest_gap_frames"] = gap.length
            entry["longest_gap_seconds"] = float(seconds(gap.length))
        entry["gap_at_start"] |= gap.at_start
        entry["gap_at_end"] |= gap.at_end
    blackout = np.flatnonzero(missing.all(axis=1)) if n_markers else np.arange(0)
    longest = max((g.length for g in gaps), default=0)
    return {
        "n_frames": int(n_frames),
        "n_markers": int(n_markers),
        "n_missing": int(missing.sum()),
        "percent_missing": 100.0 * float(missing.mean()) if missing.size else 0.0,
        "n_gaps": len(gaps),
        "longest_gap_frames": int(longest),
        "longest_gap_seconds": float(seconds(longest)),
        "markers_missing_throughout": [m["label"] for m in per_marker if m["missing_throughout"]],
        "markers_complete": sum(1 for m in per_marker if m["n_missing"] == 0),
        "blackout_frames": int(blackout.size),
        "blackouts": frame_ranges(blackout, first_frame),
        "markers": per_marker,
    }


def summarize(data: MarkerData) -> dict[str, Any]:
    """Everything ``mocapfill info`` shows about ``data``: the file's facts plus :func:`summarize_missing`.

    Adds ``path``, ``format``, ``rate``, ``duration_seconds``, ``units``, ``first_frame``, ``notes`` and, for a C3D,
    ``c3d`` (processor, storage, analog channels, model outputs).  The gap statistics cover the points of kind
    "marker" only; ``model_points`` and ``unlabelled`` list the others (kept untouched by a fill), and ``held`` is
    what :func:`mocapfill.guards.held.held_summary` finds on the markers; ``copies`` the markers bit-identical to an
    earlier one wherever both are observed (``marker``, ``copy_of``; :mod:`mocapfill.guards.copies`: the default
    fills them once).
    """
    out: dict[str, Any] = {
        "path": data.path,
        "format": data.source_format,
        "rate": float(data.rate),
        "duration_seconds": float(data.duration) if data.rate > 0 else 0.0,
        "units": data.units,
        "first_frame": int(data.first_frame),
    }
    columns = [k for k, kind in enumerate(data.kinds) if kind == "marker"]
    labels = [data.labels[k] for k in columns]
    out.update(summarize_missing(data.missing[:, columns], rate=data.rate, labels=labels,
                                 first_frame=data.first_frame))
    out["model_points"] = [lab for lab, kind in zip(data.labels, data.kinds) if kind == "model"]
    out["unlabelled"] = [lab for lab, kind in zip(data.labels, data.kinds) if kind == "unlabelled"]
    from .guards.held import find_held, held_summary

    extra = data.extra
    quantum = None
    if getattr(getattr(extra, "file", None), "is_float", True) is False:
        quantum = abs(float(extra.file.scale))
    out["held"] = held_summary(find_held(data.positions[:, columns], units=data.units, quantum=quantum), labels,
                               data.first_frame)
    from .guards.copies import distinct_trajectories

    keep, source = distinct_trajectories(data.positions[:, columns])
    out["copies"] = [{"marker": labels[m], "copy_of": labels[int(keep[source[m]])]}
                     for m in range(len(columns)) if keep[source[m]] != m]
    extra = data.extra
    if hasattr(extra, "marker_points") and hasattr(extra, "model_outputs"):
        out["c3d"] = {"processor": extra.processor, "storage": extra.storage,
                      "analog_channels": int(extra.n_analog_channels), "model_outputs": list(extra.model_outputs)}
    out["notes"] = list(data.notes)
    return out
