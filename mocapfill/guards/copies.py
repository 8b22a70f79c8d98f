"""Markers that are exact copies of another: filled once, copied back.

Some exports repeat every trajectory under several labels (c3d.org's Walking_Hybrid_2: 73 labels, 25 distinct
trajectories, each written three times; btk's Gait.trc: 12 copies).  A copy carries no information of its own, yet a
fill that treats it as a marker pays for it three times (the default's local models grow with the cube of their
predictors) and learns from it as a neighbour that predicts its twin exactly, so every cross-validated error near the
twins' gaps is zero and the fill trusts predictions it has no grounds to trust.  :func:`distinct_markers` finds the
copies (bit-identical samples, gaps included); :func:`widened` turns a fill of the distinct markers back into one of
every marker.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..methods.base import MARKER_RECORDS, FillResult, finish


def distinct_markers(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(keep (k,), source (n_markers,)): the first of each set of bit-identical markers of ``positions`` (n_frames,
    n_markers, 3), ascending, and for every marker the position in ``keep`` of the one it copies (itself if none).
    A marker missing in every frame copies nothing (its own entry)."""
    first: dict[Any, int] = {}
    source = np.empty(positions.shape[1], dtype=np.intp)
    keep = []
    empty = np.isnan(positions).all(axis=(0, 2))
    for m in range(positions.shape[1]):
        key = ("empty", m) if empty[m] else np.ascontiguousarray(positions[:, m]).tobytes()
        if key not in first:
            first[key] = len(keep)
            keep.append(m)
        source[m] = first[key]
    return np.asarray(keep, dtype=np.intp), source


def bones_on_distinct(bones, source: np.ndarray):
    """A BoneSet on every marker moved onto the distinct ones (``source`` from :func:`distinct_markers`): each bone
    between the originals of its ends, once; a bone between two copies of one trajectory dropped."""
    from ..bones.boneset import BoneSet

    pairs = np.sort(source[np.asarray(bones.pairs, dtype=np.intp)], axis=1)
    ok = pairs[:, 0] != pairs[:, 1]
    _, first = np.unique(pairs[ok], axis=0, return_index=True)
    idx = np.flatnonzero(ok)[np.sort(first)]
    return BoneSet(pairs[idx], bones.lengths[idx], bones.spread[idx], bones.n_frames[idx], bones.units)


def widened(positions: np.ndarray, result: FillResult, keep: np.ndarray, source: np.ndarray,
            labels: Sequence[str] | None) -> FillResult:
    """The fill of every marker of ``positions`` (n_frames, n_markers, 3) from ``result``, the fill of
    ``positions[:, keep]``: each copy takes its original's samples and std, and the per-marker records of
    ``result.info`` (:data:`~mocapfill.methods.base.MARKER_RECORDS`, ``fallback``; ``review`` re-indexed) are
    repeated for each copy under its own label and index; ``info["copies"]`` lists the copies (``marker``,
    ``marker_index``, ``copy_of``)."""
    name = (lambda m: labels[m] if labels is not None else int(m))
    info: dict[str, Any] = dict(result.info or {})
    for key in MARKER_RECORDS:
        records = info.get(key)
        if isinstance(records, list) and all(isinstance(r, dict) and "marker_index" in r for r in records):
            by_marker: dict[int, list[dict]] = {}
            for r in records:
                by_marker.setdefault(int(r["marker_index"]), []).append(r)
            info[key] = [dict(r, marker=name(m), marker_index=int(m))
                         for m in range(len(source)) for r in by_marker.get(int(source[m]), [])]
    if isinstance(info.get("gap_methods"), list):
        info["review"] = [i for i, r in enumerate(info["gap_methods"]) if r.get("review")]
    if isinstance(info.get("fallback"), list):
        kept = set(int(i) for i in info["fallback"])
        info["fallback"] = [int(m) for m in range(len(source)) if int(source[m]) in kept]
    info["copies"] = [{"marker": name(m), "marker_index": int(m), "copy_of": name(int(keep[source[m]]))}
                      for m in range(len(source)) if keep[source[m]] != m]
    std = None if result.std is None else result.std[:, source]
    return finish(positions, result.positions[:, source], std=std, n_iter=result.n_iter,
                  converged=result.converged, objective=list(result.objective), info=info)
