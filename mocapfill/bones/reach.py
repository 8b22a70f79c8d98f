"""Reaches: how far apart two markers were ever seen, a distance a fill should not stretch past.

A bone (:mod:`mocapfill.bones.boneset`) is a pair whose distance stays nearly constant.  Most pairs are not bones,
but each still has the range the capture showed it in: a wrist is never farther from its elbow than the forearm
allows, though the two are not rigid (the elbow's skin marker slides as the arm bends; the tennis serve's elbow to
wrist: 257 mm, spread 12.8 mm).  A prediction that puts a missing wrist 570 mm from an observed elbow it was never
seen more than 290 mm from is outside the body.  A *reach* is such a pair with its largest observed distance as its
limit; the bone stage penalises only a distance beyond the limit from a partner it does not move, by how far beyond in
units of the pair's spread (:func:`mocapfill.bones.refinement.refine_bones`, ``one_sided``).  Within reach it adds
nothing, so a prediction that is possible is left where the bones and the model put it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .boneset import P5_P95_TO_STD
from .distances import all_pairs, pair_distance_stats


#: Candidates whose turning is measured at once (a marker's tightest few usually hold it).
_BLOCK = 8


class Reaches(NamedTuple):
    """Reach pairs (R, 2) int (smaller index first), their largest observed distance ``limit`` (R,) and the robust
    spread of their distance ``spread`` (R,) ((p95 - p5) / 3.29), in the data's units."""

    pairs: np.ndarray
    limit: np.ndarray
    spread: np.ndarray


def reaches(positions: np.ndarray, bones: np.ndarray, *, partners: int, turned_deg: float,
            min_frames: int | None = None) -> Reaches:
    """Each marker with gaps held within reach of the ``partners`` other markers that hold it tightest, among those
    that are not its bones and were seen turning about it.

    positions (n_frames, n_markers, 3), NaN = missing; bones (B, 2) the pairs already held as bones (left out).
    Tightest: the smallest spread of the distance (robust, (p95 - p5) / 3.29) relative to its median, over the
    frames where both are observed, in at least ``min_frames`` of them (default half the take's: a pair seen
    together for less has seen too little of the motion to bound it; Walking_Hybrid_1_1's forefoot, seen for a
    quarter of a walk, went 970 mm from the other heel where 540 mm was the most seen): a thin shell about a partner says where a marker is, a thick
    one little (the nearest partners are often on the other foot: a 750 mm pair with a spread of 170 mm, whose
    limit the hidden frames then passed; with the tightest, the short walk's dense 20 % draw 3 20.2 mm, with the
    nearest 24.3, without reaches 21.5).  A pair counts only if its
    direction turned by at least ``turned_deg`` degrees there (:func:`turned`): the largest distance seen is a
    reach only if the pair was seen in many poses; a robot link and a table marker that stood still while both were
    seen (their distance 248 mm, spread 9 mm) moved 330 mm apart once the table marker was hidden.  A pair two
    markers with gaps both choose counts once.  Only the observed samples count, so hidden data never leaks into a
    limit.
    """
    positions = np.asarray(positions, dtype=np.float64)
    n_frames, n_markers, _ = positions.shape
    empty = Reaches(np.zeros((0, 2), dtype=int), np.zeros(0), np.zeros(0))
    missing = np.isnan(positions).any(axis=2)
    gapped = np.flatnonzero(missing.any(axis=0) & ~missing.all(axis=0))
    if partners <= 0 or n_markers < 2 or not len(gapped):
        return empty
    if min_frames is None:
        min_frames = max(n_frames // 2, 2)
    cand = all_pairs(n_markers)
    has_gap = np.zeros(n_markers, dtype=bool)
    has_gap[gapped] = True
    cand = cand[has_gap[cand[:, 0]] | has_gap[cand[:, 1]]]  # (P, 2), smaller index first
    stats = pair_distance_stats(positions, cand, percentiles=(5.0, 50.0, 95.0))
    length = stats.percentiles[:, 1]
    usable = (stats.count >= max(int(min_frames), 2)) & np.isfinite(length) & (length > 0)
    bones = np.sort(np.asarray(bones, dtype=int).reshape(-1, 2), axis=1)
    if len(bones):
        usable &= ~np.isin(cand[:, 0] * n_markers + cand[:, 1], bones[:, 0] * n_markers + bones[:, 1])
    spread = (stats.percentiles[:, 2] - stats.percentiles[:, 0]) / P5_P95_TO_STD
    with np.errstate(divide="ignore", invalid="ignore"):
        tight = spread / length  # how much the distance varied for its size: a thin shell holds a marker best
    angle = np.full(len(cand), np.nan)  # each pair's turning, measured once and only where a marker asks
    chosen = np.zeros(len(cand), dtype=bool)
    for m in gapped:
        mine = np.flatnonzero(usable & ((cand[:, 0] == m) | (cand[:, 1] == m)))
        order = mine[np.argsort(tight[mine], kind="stable")]
        taken = 0
        for start in range(0, len(order), _BLOCK):  # the tightest first, a block of candidates at a time
            block = order[start:start + _BLOCK]
            todo = block[np.isnan(angle[block])]
            if len(todo):
                angle[todo] = turned(positions[:, cand[todo, 0]] - positions[:, cand[todo, 1]])
            for k in block[angle[block] >= turned_deg][:partners - taken]:
                chosen[k] = True
                taken += 1
            if taken == partners:
                break
    idx = np.flatnonzero(chosen)
    return Reaches(cand[idx], stats.max[idx], spread[idx])


def turned(vectors: np.ndarray) -> np.ndarray:
    """How far each pair's direction turned: the 95th percentile of the angle (degrees) between its unit vectors and
    their mean direction, over the frames it was seen.  vectors (n_frames, n_pairs, 3), NaN rows = not seen
    together (left out); returns (n_pairs,), 180 where the directions cancel out, 0 where never seen."""
    seen = np.isfinite(vectors).all(axis=2)  # (n, p)
    v = np.where(seen[..., None], vectors, 0.0)
    norm = np.sqrt((v ** 2).sum(axis=2))
    u = v / np.maximum(norm, 1e-300)[..., None]
    count = seen.sum(axis=0)
    mean = u.sum(axis=0) / np.maximum(count, 1)[:, None]  # (p, 3)
    r = np.sqrt((mean ** 2).sum(axis=1))
    unit = mean / np.where(r > 0, r, 1.0)[:, None]
    angle = np.degrees(np.arccos(np.clip((u * unit[None]).sum(axis=2), -1.0, 1.0)))
    out = _percentile95(np.where(seen, angle, np.inf), count)
    return np.where(count == 0, 0.0, np.where(r > 0, out, 180.0))


def _percentile95(values: np.ndarray, count: np.ndarray) -> np.ndarray:
    """np.percentile(column[:count], 95) of each column of ``values`` (n, p) whose first ``count`` (p,) sorted entries
    are its values (the others +inf), as NumPy's linear method computes it, without its per-column loop."""
    x = np.sort(values, axis=0)
    virtual = (np.maximum(count, 1) - 1) * 0.95
    lo = np.floor(virtual).astype(int)
    hi = np.minimum(lo + 1, np.maximum(count, 1) - 1)
    cols = np.arange(x.shape[1])
    a, b, t = x[lo, cols], x[hi, cols], virtual - lo
    with np.errstate(invalid="ignore"):
        diff = b - a
        return np.where(t >= 0.5, b - diff * (1 - t), a + diff * t)
