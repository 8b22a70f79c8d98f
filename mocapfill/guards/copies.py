"""Markers that are exact copies of another: filled once, copied back.

Some exports repeat every trajectory under several labels (c3d.org's Walking_Hybrid_2: 73 labels, 25 distinct
trajectories, each written three times; btk's Gait.trc: 12 copies).  A copy carries no information of its own, yet a
fill that treats it as a marker pays for it three times (the default's local models grow with the cube of their
predictors) and learns from it as a neighbour that predicts its twin exactly, so every cross-validated error near the
twins' gaps is zero and the fill trusts predictions it has no grounds to trust.  :func:`distinct_markers` finds the
copies (bit-identical samples, gaps included); :func:`widened` turns a fill of the distinct markers back into one of
every marker.  Copies whose gaps differ (a sample missing in one and kept in its twin) are the same trajectory too:
:func:`lent_by_copies` gives each copy its twins' samples first, after which they are bit-identical, gaps included;
:func:`with_lent` records those samples as filled from the copy.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..methods.base import MARKER_RECORDS, FillResult, finish, review_indices


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


#: Frames two markers must both be observed in, bit-identical in every one, to be copies whose gaps differ.
MIN_SHARED_FRAMES = 10
#: Frames spread over the take where :func:`lent_by_copies` looks for markers at the same position (candidates).
_PROBE_FRAMES = 64


def lent_by_copies(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """Each marker's missing samples taken from an exact copy that is observed there.

    positions (n_frames, n_markers, 3), NaN = missing.  Two markers are copies when they are bit-identical in every
    frame where both are observed, and there are at least :data:`MIN_SHARED_FRAMES` such frames (candidates: the
    markers at one position in some of :data:`_PROBE_FRAMES` frames spread over the take).  Returns the positions
    with every set of copies given the union of their samples, the samples taken (n_frames, n_markers) bool, and the
    (marker, copy it took them from) pairs; the input itself where no copy lends anything.
    """
    n_frames, n_markers, _ = positions.shape
    observed = ~np.isnan(positions).any(axis=2)
    parent = list(range(n_markers))

    def root(m: int) -> int:
        while parent[m] != m:
            parent[m] = parent[parent[m]]
            m = parent[m]
        return m

    tried = set()
    for t in np.unique(np.linspace(0, n_frames - 1, min(_PROBE_FRAMES, n_frames)).astype(int)):
        seen = np.flatnonzero(observed[t])
        if len(seen) < 2:
            continue
        _, inverse, counts = np.unique(positions[t, seen], axis=0, return_inverse=True, return_counts=True)
        for g in np.flatnonzero(counts > 1):
            members = seen[inverse.ravel() == g]
            for a, b in ((int(members[0]), int(other)) for other in members[1:]):
                if (a, b) in tried or root(a) == root(b):
                    continue
                tried.add((a, b))
                both = observed[:, a] & observed[:, b]
                if both.sum() >= MIN_SHARED_FRAMES and np.array_equal(positions[both, a], positions[both, b]):
                    parent[root(b)] = root(a)
    out = positions
    lent = np.zeros((n_frames, n_markers), dtype=bool)
    lenders: list[tuple[int, int]] = []
    sets: dict[int, list[int]] = {}
    for m in range(n_markers):
        sets.setdefault(root(m), []).append(m)
    for members in sets.values():
        if len(members) < 2:
            continue
        union = observed[:, members].any(axis=1)
        for m in members:
            take = union & ~observed[:, m]
            if not take.any():
                continue
            if out is positions:
                out = positions.copy()
            for other in members:  # the first copy observed in each frame lends it
                give = take & observed[:, other]
                if give.any():
                    out[give, m] = positions[give, other]
                    lent[give, m] = True
                    lenders.append((m, other))
                    take &= ~give
    return out, lent, lenders


def distinct_trajectories(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`distinct_markers` with copies whose gaps differ counted as copies (read after
    :func:`lent_by_copies`): (keep (k,), source (n_markers,)) for positions (n_frames, n_markers, 3)."""
    return distinct_markers(lent_by_copies(positions)[0])


def with_lent(result: FillResult, original: np.ndarray, lent: np.ndarray, lenders: list[tuple[int, int]],
              labels: Sequence[str] | None) -> FillResult:
    """``result``, the fill of :func:`lent_by_copies`' positions, as the fill of ``original`` (n_frames, n_markers,
    3): the samples ``lent`` (n_frames, n_markers) are filled (sd 0: the trajectory was observed there), each run of
    them with a ``gap_methods`` record naming the copy, and ``info["lent"]`` lists the (marker, copy) pairs."""
    from ..gaps import runs

    name = (lambda m: labels[m] if labels is not None else int(m))
    info: dict[str, Any] = dict(result.info or {})
    by_marker: dict[int, list[int]] = {}
    for m, other in lenders:
        by_marker.setdefault(m, []).append(other)
    records = list(info.get("gap_methods") or [])
    for m in sorted(by_marker):
        copies = ", ".join(str(name(o)) for o in dict.fromkeys(by_marker[m]))
        for start, length in runs(lent[:, m]):
            records.append({"marker": name(m), "marker_index": int(m), "start": int(start), "length": int(length),
                            "method": "copy", "reason": f"taken from its exact copy {copies}, observed there",
                            "review": False, "max_std": 0.0})
    records.sort(key=lambda r: (int(r["marker_index"]), int(r["start"])))
    records = one_record_per_gap(records, np.isnan(original).any(axis=2))
    info["gap_methods"] = records
    info["review"] = review_indices(records)
    info["lent"] = [{"marker": name(m), "marker_index": int(m), "copy": name(o)}
                    for m, o in dict.fromkeys(lenders)]
    return finish(original, result.positions, std=result.std, n_iter=result.n_iter, converged=result.converged,
                  objective=list(result.objective), info=info)


def one_record_per_gap(records: list[dict], missing: np.ndarray) -> list[dict]:
    """``records`` (``marker_index``, ``start``, ``length``, ``method``, ``reason``, ``review``, ``max_std``; sorted by
    marker and start) of the pieces of the gaps of ``missing`` (n_frames, n_markers), one record per gap: a gap
    filled in pieces (partly from a copy, partly by the fill) gets the methods joined by '+', each piece's reason
    after its frames, review if any piece asks for it and the largest sd."""
    from ..gaps import runs

    out: list[dict] = []
    by_marker: dict[int, list[dict]] = {}
    for r in records:
        by_marker.setdefault(int(r["marker_index"]), []).append(r)
    for m, mine in by_marker.items():
        used = [False] * len(mine)
        for start, length in runs(missing[:, m]) if 0 <= m < missing.shape[1] else []:
            parts = [i for i, r in enumerate(mine) if r["start"] < start + length and r["start"] + r["length"] > start]
            for i in parts:
                used[i] = True
            if len(parts) == 1:
                out.append(dict(mine[parts[0]], start=int(start), length=int(length)))
            elif parts:
                pieces = [mine[i] for i in parts]
                sds = [p["max_std"] for p in pieces if p.get("max_std") is not None]
                merged = dict(pieces[0], start=int(start), length=int(length),
                              method="+".join(dict.fromkeys(str(p.get("method")) for p in pieces)),
                              reason="; ".join(f"frames {p['start']}-{p['start'] + p['length'] - 1}: {p.get('reason')}"
                                               for p in pieces),
                              review=any(bool(p.get("review")) for p in pieces), max_std=max(sds) if sds else None)
                offs = [p["extrapolation"] for p in pieces if p.get("extrapolation") is not None]
                if "extrapolation" in merged:
                    merged["extrapolation"] = max(offs) if offs else None
                out.append(merged)
        out.extend(r for r, u in zip(mine, used) if not u)  # (a record of no gap of ``missing``: kept as it was)
    out.sort(key=lambda r: (int(r["marker_index"]), int(r["start"])))
    return out


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
        info["review"] = review_indices(info["gap_methods"])
    if isinstance(info.get("fallback"), list):
        kept = set(int(i) for i in info["fallback"])
        info["fallback"] = [int(m) for m in range(len(source)) if int(source[m]) in kept]
    info["copies"] = [{"marker": name(m), "marker_index": int(m), "copy_of": name(int(keep[source[m]]))}
                      for m in range(len(source)) if keep[source[m]] != m]
    std = None if result.std is None else result.std[:, source]
    return finish(positions, result.positions[:, source], std=std, n_iter=result.n_iter,
                  converged=result.converged, objective=list(result.objective), info=info)
