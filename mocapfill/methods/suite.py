"""The capture suites' fills by name: ``woltring``, ``pattern`` and ``rigid``.

A technician who knows Vicon Nexus or Qualisys QTM can predict these fills, which is why they are here; the default
(``auto``) is more accurate.  Each is implemented from its textbook description:

- ``woltring``: an interpolating quintic spline through the marker's own valid frames around each gap (Woltring's
  quintic spline as Nexus's gap-fill pipeline runs it, without smoothing).
- ``pattern``: one donor marker; the donor's trajectory shape plus a straight bridge of the offset between the gapped
  marker and the donor.
- ``rigid``: three or more donors carried as a rigid body: the marker's position in the donors' frame at each end of
  the gap, carried through the gap by a least-squares rigid fit (Kabsch) of the donors, the two ends blended.

Each method **declines** a gap it cannot fill by its rule (too few valid frames, a donor not seen, fewer than three
donors): the gap is left missing (NaN), never filled by something else, and listed in ``info["declined"]`` (one
record per gap: ``marker`` label, ``marker_index``, ``start`` (0-based frame), ``length``, ``reason``;
:func:`mocapfill.methods.base.declined_mask` turns it into a mask).  Every gap
also gets a record in ``info["gap_methods"]`` (what filled it, with which donors, or ``"declined"`` and why).  The
registry marks these methods ``may_decline``.

Donors (``pattern`` and ``rigid``)
----------------------------------
``donors=None`` chooses them per gap: among the markers seen throughout the gap and at its ends (the frame before and
the frame after), those whose distance to the gapped marker varies least (standard deviation over the frames where
both are seen) come first.  ``donors`` may also name them:

- a sequence of labels: the donors of every marker (a marker is never its own donor);
- a mapping ``{marker label: labels}``: per marker (a label or a comma-separated string); markers not named choose
  automatically; the key ``None`` (or ``"*"``) gives the donors of every marker not named;
- a string, as the CLI's ``--donors`` writes it: entries separated by ``;``, each ``MARKER=D1,D2`` or ``D1,D2``.

A label matches exactly, else after a ``Subject:`` prefix on either side; an unknown label raises
:class:`~mocapfill.errors.MethodError` naming it and its nearest labels.  Named donors are taken in the order given:
``pattern`` uses the first of them seen throughout the gap and at its ends, ``rigid`` all of them that are.

Gaps at the capture's edges have one end: ``pattern`` carries the offset of that end unchanged, ``rigid`` that end's
local position; ``woltring`` declines them (a spline would extrapolate).  A marker never observed stays missing
(``info["all_missing"]``) and is not listed as declined.

Shapes: ``positions`` is ``(n_frames, n_markers, 3)`` float64 with NaN = missing, throughout.
"""

from __future__ import annotations

import difflib
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.interpolate import make_interp_spline

from ..engines.local_pca import kabsch_rotations
from ..errors import MethodError
from ..gaps import Gap, all_missing_markers, end_blend, find_gaps, missing_mask
from .base import FillResult, finish

#: Woltring: fewest valid frames on each side of a gap (Nexus's pipeline declines a gap with fewer).
WOLTRING_MIN_SIDE = 5
#: Woltring: frames taken on each side beyond half the gap's length (up to gap // 2 + 5 on a side, as Nexus).
WOLTRING_EXTRA_SIDE = 5
#: Woltring's spline degree (quintic).
WOLTRING_DEGREE = 5
#: Rigid: fewest donors (a rigid fit needs three points not in a line).
RIGID_MIN_DONORS = 3
#: Rigid: donors chosen automatically per gap (three, as the suites' rigid-body fill; 4, 5, 6 reach for markers on
#: other segments: median RMSE equal or worse on 85_02 and the tennis serve, 10 trials of three protocols each).
RIGID_AUTO_DONORS = 3
#: Rigid: donors whose second singular value is below this fraction of the first lie nearly in a line, and a rotation
#: about that line is not determined.
COLLINEAR_RATIO = 0.1
#: Automatic donors: fewest frames where a candidate and the gapped marker are both seen for its distance's spread to
#: count.
MIN_SHARED_FRAMES = 10
#: Automatic donors: the distance spread is measured on at most this many evenly spaced frames (a long take costs
#: no more than a short one).
SPREAD_FRAMES = 4000


# ---------------------------------------------------------------------------------------------------------------
# Donors
# ---------------------------------------------------------------------------------------------------------------

def _bare(label: str) -> str:
    return str(label).split(":")[-1].strip()


def find_label(name: str | int, labels: Sequence[str] | None, *, what: str = "donor") -> int:
    """The index of marker ``name`` in ``labels``: exact, else after a ``Subject:`` prefix; an int is an index.

    Raises MethodError naming the label and its nearest matches when there is none (or more than one).
    """
    if isinstance(name, (int, np.integer)) and not isinstance(name, bool):
        index = int(name)
        n = len(labels) if labels is not None else None
        if index < 0 or (n is not None and index >= n):
            raise MethodError(f"{what} index {index} is out of range")
        return index
    name = str(name).strip()
    if labels is None:
        raise MethodError(f"{what} {name!r} is a label, but the data has no labels (give marker indices)")
    labels = [str(label) for label in labels]
    if name in labels:
        return labels.index(name)
    hits = [i for i, label in enumerate(labels) if _bare(label) == _bare(name)]
    if len(hits) == 1:
        return hits[0]
    if len(hits) > 1:
        raise MethodError(f"{what} {name!r} matches several labels: {', '.join(labels[i] for i in hits)}")
    near = difflib.get_close_matches(name, labels, n=3, cutoff=0.5)
    hint = f"; near: {', '.join(near)}" if near else ""
    raise MethodError(f"unknown {what} label {name!r}{hint}")


def _split(text: str | Sequence) -> list:
    if isinstance(text, str):
        return [part.strip() for part in text.split(",") if part.strip()]
    return list(text)


def parse_donors(donors: Any, labels: Sequence[str] | None, n_markers: int) -> dict[int, list[int]]:
    """Named donors per marker index (see the module docstring for the forms ``donors`` takes).

    Returns ``{marker index: [donor indices, in preference order]}`` for every marker given donors; markers absent
    choose automatically.  A marker's own index is dropped from its list.
    """
    if donors is None:
        return {}
    table: dict[Any, Any]
    if isinstance(donors, str):
        table = {}
        for entry in (part.strip() for part in donors.split(";")):
            if not entry:
                continue
            if "=" in entry:
                marker, _, names = entry.partition("=")
                table[marker.strip()] = names
            else:
                table[None] = entry
    elif isinstance(donors, Mapping):
        table = {(None if key in (None, "*") else key): value for key, value in donors.items()}
    else:
        table = {None: list(donors)}
    out: dict[int, list[int]] = {}
    everyone = table.pop(None, None)
    if everyone is not None:
        common = [find_label(name, labels) for name in _split(everyone)]
        if not common:
            raise MethodError("no donors named")
        for m in range(n_markers):
            out[m] = [d for d in dict.fromkeys(common) if d != m]
    for marker, names in table.items():
        m = find_label(marker, labels, what="marker")
        chosen = [find_label(name, labels) for name in _split(names)]
        if not chosen:
            raise MethodError(f"no donors named for marker {marker!r}")
        out[m] = [d for d in dict.fromkeys(chosen) if d != m]
    return out


def distance_spread(positions: np.ndarray, markers: Sequence[int]) -> np.ndarray:
    """(len(markers), n_markers) standard deviation of each marker's distance to every other marker, over the frames
    where both are seen (at most ``SPREAD_FRAMES`` evenly spaced ones); inf where fewer than ``MIN_SHARED_FRAMES``
    frames are shared and on the diagonal.  ``positions`` (n_frames, n_markers, 3)."""
    n_frames, n_markers, _ = positions.shape
    frames = np.unique(np.linspace(0, n_frames - 1, min(n_frames, SPREAD_FRAMES)).round().astype(int))
    sub = positions[frames]
    out = np.full((len(markers), n_markers), np.inf)
    for row, m in enumerate(markers):
        d = np.linalg.norm(sub - sub[:, m:m + 1], axis=2)  # (n, n_markers), NaN where either is missing
        seen = np.isfinite(d)
        count = seen.sum(axis=0)
        ok = count >= MIN_SHARED_FRAMES
        ok[m] = False
        if ok.any():
            out[row, ok] = np.nanstd(d[:, ok], axis=0)
    return out


class _Donors:
    """Donor candidates per gap: the named ones, else every marker ranked by distance spread."""

    def __init__(self, positions: np.ndarray, donors: Any, labels: Sequence[str] | None) -> None:
        n_markers = positions.shape[1]
        missing = missing_mask(positions)
        gaps = find_gaps(missing)
        self.named = parse_donors(donors, labels, n_markers)
        self.missing = missing
        auto = sorted({g.marker for g in gaps if g.marker not in self.named})
        spread = distance_spread(positions, auto) if auto else np.zeros((0, n_markers))
        self.ranked = {m: [int(d) for d in np.argsort(spread[row], kind="stable") if np.isfinite(spread[row, d])]
                       for row, m in enumerate(auto)}

    def seen_through(self, gap: Gap) -> tuple[list[int], bool]:
        """Candidates seen throughout the gap and at its ends, in preference order; and whether they were named."""
        lo = gap.start if gap.at_start else gap.start - 1
        hi = gap.stop if not gap.at_end else gap.stop - 1
        seen = ~self.missing[lo:hi + 1].any(axis=0)
        named = gap.marker in self.named
        candidates = self.named[gap.marker] if named else self.ranked[gap.marker]
        return [d for d in candidates if seen[d]], named


# ---------------------------------------------------------------------------------------------------------------
# The gap loop shared by the three methods
# ---------------------------------------------------------------------------------------------------------------

def _label(labels: Sequence[str] | None, m: int) -> str | int:
    return str(labels[m]) if labels is not None and m < len(labels) else int(m)


def _record(gap: Gap, labels, method: str, reason: str | None = None, donors: list[int] | None = None) -> dict:
    rec: dict[str, Any] = {"marker": _label(labels, gap.marker), "marker_index": int(gap.marker),
                           "start": int(gap.start), "length": int(gap.length), "method": method}
    if reason is not None:
        rec["reason"] = reason
    if donors is not None:
        rec["donors"] = [_label(labels, d) for d in donors]
    return rec


def _run(positions: np.ndarray, name: str, fill_gap, labels) -> FillResult:
    """Fill every gap with ``fill_gap(gap) -> (values (length, 3), donors) or str (the reason it declines)``."""
    missing = missing_mask(positions)
    dead = set(int(m) for m in all_missing_markers(missing))
    estimate = positions.copy()
    gap_methods, declined = [], []
    for gap in find_gaps(missing):
        if gap.marker in dead:
            continue
        outcome = fill_gap(gap)
        if isinstance(outcome, str):
            declined.append({k: v for k, v in _record(gap, labels, name, outcome).items() if k != "method"})
            gap_methods.append(_record(gap, labels, "declined", outcome))
            continue
        values, donors = outcome
        estimate[gap.start:gap.stop, gap.marker] = values
        reason = None if donors is None else "donors " + ", ".join(str(_label(labels, d)) for d in donors)
        gap_methods.append(_record(gap, labels, name, reason, donors))
    info = {"all_missing": sorted(dead), "declined": declined, "gap_methods": gap_methods}
    return finish(positions, estimate, info=info)


# ---------------------------------------------------------------------------------------------------------------
# woltring
# ---------------------------------------------------------------------------------------------------------------

def woltring_gap(frames_seen: np.ndarray, values_seen: np.ndarray, gap: Gap) -> np.ndarray | str:
    """The interpolating quintic spline of one gap, or the reason it declines.

    ``frames_seen`` (n,) ascending frame indices where the marker is observed, ``values_seen`` (n, 3) its positions
    there; returns (gap.length, 3).
    """
    per_side = gap.length // 2 + WOLTRING_EXTRA_SIDE
    before = np.searchsorted(frames_seen, gap.start)
    after = np.searchsorted(frames_seen, gap.stop)
    left = frames_seen[max(0, before - per_side):before]
    right_index = slice(after, min(len(frames_seen), after + per_side))
    right = frames_seen[right_index]
    if len(left) < WOLTRING_MIN_SIDE:
        return f"{len(left)} valid frames before the gap, fewer than {WOLTRING_MIN_SIDE}"
    if len(right) < WOLTRING_MIN_SIDE:
        return f"{len(right)} valid frames after the gap, fewer than {WOLTRING_MIN_SIDE}"
    t = np.concatenate([left, right]).astype(np.float64)
    y = np.concatenate([values_seen[before - len(left):before], values_seen[right_index]])
    # Centred and scaled frame numbers: the same spline, better conditioned B-spline collocation.
    centre, scale = 0.5 * (t[0] + t[-1]), 0.5 * (t[-1] - t[0])
    spline = make_interp_spline((t - centre) / scale, y, k=WOLTRING_DEGREE, axis=0)  # not-a-knot ends
    return spline((np.arange(gap.start, gap.stop) - centre) / scale)


def fill_woltring(positions: np.ndarray, *, labels: Sequence[str] | None = None, seed: int | None = None
                  ) -> FillResult:
    """Woltring fill: an interpolating quintic spline through the valid frames around each gap.

    For a gap of ``L`` frames the spline passes exactly through up to ``L // 2 + 5`` valid frames (frames where the
    marker is observed, the nearest ones, not necessarily consecutive) on each side; a gap with fewer than 5 valid
    frames on a side (including every gap at the capture's edges) is **declined**: left missing and reported, as
    Nexus's pipeline does.  Each gap gets its own spline, so a fill depends only on the frames around it.

    End conditions: **not-a-knot** (scipy's ``make_interp_spline(k=5)`` default): no knot at the second and third
    fitted frames from each end, so the spline is one quintic over the first three and over the last three intervals
    between fitted frames (the four conditions a quintic interpolant needs beyond the data); every quintic
    polynomial (and lower) lies in the spline space and interpolation is unique, so a marker moving as any quintic
    polynomial of time on both sides of a gap is reproduced exactly (to rounding, tested to 1e-6 of its range).
    Natural end conditions (zero 3rd and 4th derivatives at the ends) would not reproduce it.

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    labels : sequence of str, optional
        Marker labels (n_markers,), to name markers in ``info``.
    seed : ignored (deterministic).

    Returns
    -------
    FillResult
        ``positions`` (n_frames, n_markers, 3): declined gaps and markers never observed stay NaN.  ``info``:
        ``declined`` (per gap: ``marker``, ``marker_index``, ``start``, ``length``, ``reason``), ``gap_methods``,
        ``all_missing``.
    """
    positions = np.asarray(positions, dtype=np.float64)
    missing = missing_mask(positions)
    seen_frames = {}

    def fill_gap(gap: Gap):
        if gap.marker not in seen_frames:
            seen_frames[gap.marker] = np.flatnonzero(~missing[:, gap.marker])
        frames = seen_frames[gap.marker]
        values = woltring_gap(frames, positions[frames, gap.marker], gap)
        return values if isinstance(values, str) else (values, None)

    return _run(positions, "woltring", fill_gap, labels)


# ---------------------------------------------------------------------------------------------------------------
# pattern
# ---------------------------------------------------------------------------------------------------------------

def fill_pattern(positions: np.ndarray, *, donors: Any = None, labels: Sequence[str] | None = None,
                 seed: int | None = None) -> FillResult:
    """Pattern fill: one donor's trajectory shape plus a straight bridge of the offset to it.

    Inside a gap from frame ``a`` (the last observed before it) to ``b`` (the first after), with donor ``d``::

        x(t) = d(t) + (1 - w) (x(a) - d(a)) + w (x(b) - d(b)),   w = (t - a) / (b - a)

    so a marker that moves as its donor translated by a fixed offset is filled exactly.  A gap at the capture's edge
    carries its one end's offset unchanged.  The donor must be seen throughout the gap and at its ends; a gap without
    one is **declined** (left missing, reported in ``info["declined"]``).

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    donors : None, sequence of labels, mapping, or str
        None: per gap, the marker seen throughout it whose distance to the gapped marker varies least.  Named donors
        (see the module docstring): the first of them seen throughout the gap.
    labels : sequence of str, optional
        Marker labels (n_markers,): how donors are named and how ``info`` names markers.
    seed : ignored (deterministic).

    Returns
    -------
    FillResult
        ``positions`` (n_frames, n_markers, 3); ``info``: ``declined``, ``gap_methods`` (with ``donors`` per gap),
        ``all_missing``.
    """
    positions = np.asarray(positions, dtype=np.float64)
    pool = _Donors(positions, donors, labels)

    def fill_gap(gap: Gap):
        candidates, named = pool.seen_through(gap)
        if not candidates:
            if named and not pool.named[gap.marker]:
                return "no donor named besides the marker itself"
            if named:
                names = ", ".join(str(_label(labels, d)) for d in pool.named[gap.marker])
                return f"donor ({names}) missing in the gap or at its ends"
            return "no donor seen throughout the gap and at its ends"
        d = candidates[0]
        x, dn = positions[:, gap.marker], positions[:, d]
        left = None if gap.at_start else x[gap.start - 1] - dn[gap.start - 1]
        right = None if gap.at_end else x[gap.stop] - dn[gap.stop]
        offset = end_blend(left, right, gap.length)
        return dn[gap.start:gap.stop] + offset, [d]

    return _run(positions, "pattern", fill_gap, labels)


# ---------------------------------------------------------------------------------------------------------------
# rigid
# ---------------------------------------------------------------------------------------------------------------

def _spread_ok(points: np.ndarray) -> bool:
    """Whether ``points`` (p, 3) span a plane (not nearly in a line)."""
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return s[0] > 0 and s[1] >= COLLINEAR_RATIO * s[0]


def _choose_rigid(candidates: list[int], named: bool, shape: np.ndarray) -> list[int] | str:
    """The donors of one gap from its candidates (named: all; else the first ``RIGID_AUTO_DONORS`` not in a line);
    ``shape`` (n_markers, 3) the positions at one end of the gap.  A string: why the gap is declined."""
    if len(candidates) < RIGID_MIN_DONORS:
        return (f"{len(candidates)} donor(s) seen throughout the gap and at its ends, fewer than "
                f"{RIGID_MIN_DONORS}")
    if named:
        return candidates if _spread_ok(shape[candidates]) else "the donors lie nearly in a line"
    chosen = candidates[:2]
    for c in candidates[2:]:
        if len(chosen) >= RIGID_AUTO_DONORS:
            break
        if _spread_ok(shape[chosen + [c]]):
            chosen.append(c)
    if len(chosen) < RIGID_MIN_DONORS:
        return "the donors seen throughout the gap lie nearly in a line"
    return chosen


def carry_rigid(donor_path: np.ndarray, donor_end: np.ndarray, marker_end: np.ndarray) -> np.ndarray:
    """Where a point rigidly attached to the donors goes: (n, 3).

    ``donor_path`` (n, p, 3) the donors over the frames to fill, ``donor_end`` (p, 3) and ``marker_end`` (3,) the
    donors and the marker at the frame that fixes the point's local position.  Each frame's least-squares rigid
    motion (Kabsch: the proper rotation and translation that best map ``donor_end`` onto that frame's donors) is
    applied to ``marker_end``.
    """
    centre_end = donor_end.mean(axis=0)
    centre = donor_path.mean(axis=1)  # (n, 3)
    reference = donor_end - centre_end
    rot = kabsch_rotations(donor_path - centre[:, None, :], reference, np.ones(len(donor_end)))
    # Row vectors: shapes[t] @ rot[t] ~ reference, so a reference-frame point p sits at p @ rot[t].T in frame t.
    return np.einsum("c,tdc->td", marker_end - centre_end, rot) + centre


def fill_rigid(positions: np.ndarray, *, donors: Any = None, labels: Sequence[str] | None = None,
               seed: int | None = None) -> FillResult:
    """Rigid-body fill: three or more donors carried as a rigid body.

    At each end of a gap (the last observed frame ``a`` before it, the first ``b`` after) the marker's position
    relative to the donors is fixed; through the gap the donors' least-squares rigid motion from that end (Kabsch,
    per frame) carries it, giving one estimate from each end; they are blended linearly across the gap
    (weight ``(t - a) / (b - a)`` on the estimate from ``b``), so the fill meets the marker at both ends.  A marker
    rigidly attached to its donors is recovered exactly however the body moves.  A gap at the capture's edge uses its
    one end.  A gap without three donors seen throughout it and at its ends (or whose donors lie nearly in a line) is
    **declined** (left missing, reported in ``info["declined"]``).

    Parameters
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3)
        NaN = missing.
    donors : None, sequence of labels, mapping, or str
        None: per gap, the ``RIGID_AUTO_DONORS`` markers seen throughout it whose distances to the gapped marker vary
        least (skipping one that would leave them in a line).  Named donors (see the module docstring): all of them
        seen throughout the gap, at least three.
    labels, seed
        As :func:`fill_pattern`.

    Returns
    -------
    FillResult
        As :func:`fill_pattern`'s.
    """
    positions = np.asarray(positions, dtype=np.float64)
    pool = _Donors(positions, donors, labels)

    def fill_gap(gap: Gap):
        candidates, named = pool.seen_through(gap)
        end = gap.stop if gap.at_start else gap.start - 1
        chosen = _choose_rigid(candidates, named, positions[end])
        if isinstance(chosen, str):
            return chosen
        path = positions[gap.start:gap.stop][:, chosen]
        ends = []
        for frame in ([] if gap.at_start else [gap.start - 1]) + ([] if gap.at_end else [gap.stop]):
            ends.append(carry_rigid(path, positions[frame, chosen], positions[frame, gap.marker]))
        if len(ends) == 1:
            return ends[0], chosen
        w = (np.arange(gap.length) + 1.0)[:, None] / (gap.length + 1.0)
        return (1.0 - w) * ends[0] + w * ends[1], chosen

    return _run(positions, "rigid", fill_gap, labels)
