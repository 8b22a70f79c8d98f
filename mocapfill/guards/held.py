"""Held and frozen samples: observed values that are not measurements (a guard run before the fill).

Some exporters "hold" a marker's last position through an occlusion, and some systems freeze a lost marker where it
was, or write one coordinate as an exact 0.  Such samples look observed; a fill that believes them passes the freeze
on.  The rule, per marker (only on the columns handed in: the capture's markers):

- **held run**: the marker repeats its exact previous position (all three coordinates bit-identical) so that one
  value stands for at least :data:`MIN_HELD_FRAMES` consecutive frames, **while the body moves**: over the run, the
  :data:`NEIGHBOURS` markers that move most rigidly with it (least spread of their distance to it), each over its
  own samples that are not repeats, move by a median of more than :data:`BODY_MOTION_MM` (or
  :data:`BODY_MOTION_QUANTA` storage quanta when the file stores integers) from where they were when the run
  began; and the marker's next observed sample after the run lies farther than that from the held value (it jumps
  to where it really is).  The first frame of the run is a real sample; the repeats after it are held.  A marker
  that truly rests repeats nothing in float data (noise), and where its values do repeat (quantised storage, an
  exact reference point) it never jumps; a slow marker's neighbours creep with it; a static trial has no moving
  body.
- **edge run**: a run that touches the first or the last frame, under the same rule (a run to the last frame: the
  marker moved that far over as many frames before it), repeats the nearest observed value, which is how many
  tools fill edges: reported, never rejected.  One value throughout the capture is a point that never moves.
- **zero run**: a coordinate exactly 0 for at least :data:`MIN_HELD_FRAMES` consecutive frames, reached or left by
  a jump of more than :data:`ZERO_JUMP_MM` in one frame (a lost marker written as 0, not a marker on the floor or
  one crossing 0 slowly).  Rejected at the edges too: a jump to 0 holds no observed value.

:func:`find_held` returns the masks and the runs; the pipeline turns ``held`` samples into gaps (status
``REJECTED_HELD``) unless ``--keep-held``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import warnings

import numpy as np

from ..gaps import runs
from ..units import length_factor

#: Shortest run (frames sharing one value) that counts: two exact repeats in a row never happen in measured float
#: data, and a 3-frame run is still short enough to catch an exporter holding through brief occlusions.
MIN_HELD_FRAMES = 3
#: Neighbours whose motion says whether "the body moves" around a run: the markers that move most rigidly with the
#: marker (least spread of their distance to it: its segment); the median of three ignores one that is lost.
NEIGHBOURS = 3
#: How far (mm) those neighbours must move over a run for the marker's stillness to be a held value: far above
#: measurement noise (0.1-0.5 mm), the creep of a static trial and quantisation, and the scale below which a
#: held value costs less than a fill would gain (a subject standing nearly still: CMU clips hold 10 frames while
#: the waist moves 4 mm).
BODY_MOTION_MM = 10.0
#: The same threshold in storage quanta for integer C3D files (their scale), when that is larger.
BODY_MOTION_QUANTA = 10
#: A run of exact zeros in one coordinate is a lost marker written as 0 only when that coordinate jumps to or from
#: it by more than this (mm) in one frame; a marker crossing 0 slowly reads exactly 0 for frames in integer storage.
ZERO_JUMP_MM = 20.0
#: Fewest sampled frames two markers must share to be ranked as neighbours.
NEIGHBOUR_MIN_FRAMES = 5
#: Frames sampled to rank neighbours by the spread of their distance (enough for a stable ranking, cheap on long takes) ...
NEIGHBOUR_FRAMES = 400
#: ... within this many bytes of float32 distances (fewer frames for captures with hundreds of points).
NEIGHBOUR_BYTES = 64e6


@dataclass
class HeldResult:
    """Held and frozen samples of a capture.

    Attributes
    ----------
    held : ndarray of bool (n_frames, n_markers)
        Samples to reject: the repeats of held runs and the samples of zero runs (edge runs excluded).
    edge : ndarray of bool (n_frames, n_markers)
        Repeats of held runs touching the first or last frame (reported, not rejected).
    runs : list of dict
        One per run: ``marker`` (column), ``start`` (0-based frame of its first sample), ``length`` (frames),
        ``kind`` ("held", "zero" or "edge").
    """

    held: np.ndarray
    edge: np.ndarray
    runs: list[dict] = field(default_factory=list)

    def counts(self) -> dict[str, int]:
        """Runs per kind and samples: ``{"held": n, "zero": n, "edge": n, "held_samples": n, "edge_samples": n}``."""
        out = {kind: sum(1 for r in self.runs if r["kind"] == kind) for kind in ("held", "zero", "edge")}
        out.update(held_samples=int(self.held.sum()), edge_samples=int(self.edge.sum()))
        return out


def _neighbours(positions: np.ndarray, k: int) -> np.ndarray:
    """Indices (n_markers, k) of the markers that move most rigidly with each (the least spread in their distance
    to it over sampled frames; -1 where fewer exist)."""
    n_frames, n_markers, _ = positions.shape
    n_sample = max(1, min(NEIGHBOUR_FRAMES, int(NEIGHBOUR_BYTES // max(4 * n_markers * n_markers, 1))))
    frames = np.unique(np.linspace(0, n_frames - 1, n_sample).astype(int))
    dist = np.empty((frames.size, n_markers, n_markers), dtype=np.float32)
    for i, t in enumerate(frames):
        # NaN where either marker is missing; numpy, not scipy's cdist: scipy.spatial costs ~0.5 s to import
        dist[i] = np.sqrt(((positions[t][:, None, :] - positions[t][None, :, :]) ** 2).sum(axis=2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pairs
        spread = np.nanstd(dist, axis=0).astype(np.float64)
        seen = (np.isfinite(dist).sum(axis=0) >= NEIGHBOUR_MIN_FRAMES)
    median = np.where(seen & np.isfinite(spread), spread, np.inf)
    np.fill_diagonal(median, np.inf)
    order = np.argsort(median, axis=1)[:, :k]
    out = np.where(np.take_along_axis(median, order, axis=1) < np.inf, order, -1)
    if out.shape[1] < k:
        out = np.hstack([out, -np.ones((n_markers, k - out.shape[1]), dtype=int)])
    return out


def find_held(positions: np.ndarray, *, units: str = "mm", quantum: float | None = None,
              min_frames: int = MIN_HELD_FRAMES) -> HeldResult:
    """Held, edge and zero runs of ``positions`` (n_frames, n_markers, 3), NaN = missing (see the module's rule).

    ``quantum`` is the storage step of an integer file in ``units`` (None for float data).
    """
    positions = np.asarray(positions, dtype=np.float64)
    n_frames, n_markers, _ = positions.shape
    held = np.zeros((n_frames, n_markers), dtype=bool)
    edge = np.zeros_like(held)
    found: list[dict] = []
    if n_frames < min_frames or n_markers == 0:
        return HeldResult(held, edge, found)
    mm = length_factor("mm", units)
    threshold = max(BODY_MOTION_MM * mm, BODY_MOTION_QUANTA * (quantum or 0.0))
    observed = np.isfinite(positions).all(axis=2)
    repeat = np.zeros_like(held)  # sample t equals sample t - 1 exactly
    repeat[1:] = (positions[1:] == positions[:-1]).all(axis=2) & observed[1:] & observed[:-1]

    candidates = []
    for k in np.flatnonzero(repeat.any(axis=0)):
        for start, length in runs(repeat[:, k]):
            first = start - 1  # the run's real sample
            if length + 1 >= min_frames:
                candidates.append((int(k), first, length + 1))
    if candidates:
        index = np.where(observed, np.arange(n_frames)[:, None], n_frames)
        next_observed = np.minimum.accumulate(index[::-1], axis=0)[::-1]  # first observed frame >= t, per marker
        neighbours = moving = None  # computed for the first run that passes the marker's own test
        for k, first, length in candidates:
            stop = first + length
            at_edge = first == 0 or stop == n_frames
            if first == 0 and stop == n_frames:
                continue  # one value throughout: a point that never moves
            if stop < n_frames:  # the marker must jump to where it really is after the run
                t = next_observed[stop, k]
                if t >= n_frames or np.linalg.norm(positions[t, k] - positions[first, k]) <= threshold:
                    continue  # it rested (or cannot be judged)
            else:  # a run to the last frame: the marker must have moved before it, over as many frames
                before = positions[max(0, first - length):first, k]
                before = before[np.isfinite(before).all(axis=1)]
                if before.size == 0 or np.sqrt(((before - positions[first, k]) ** 2).sum(axis=1)).max() <= threshold:
                    continue
            if neighbours is None:
                neighbours = _neighbours(positions, NEIGHBOURS)
                moving = np.where(repeat, np.nan, 0.0)[:, :, None] + positions  # repeats do not count as motion
            motions = []
            for j in neighbours[k]:
                if j < 0:
                    continue
                path = moving[first:stop, j]
                ok = np.isfinite(path).all(axis=1)
                if ok.sum() < 2:
                    continue
                path = path[ok]
                motions.append(float(np.sqrt(((path - path[0]) ** 2).sum(axis=1)).max()))
            if len(motions) < 2 or np.median(motions) <= threshold:
                continue  # the body rests too (or cannot be judged): a marker at rest, not a held value
            kind = "edge" if at_edge else "held"
            (edge if at_edge else held)[first + 1:stop, k] = True
            found.append({"marker": k, "start": first + 1, "length": length - 1, "kind": kind})

    jump = ZERO_JUMP_MM * mm
    for k, c in zip(*np.nonzero((observed[:, :, None] & (positions == 0.0)).sum(axis=0) >= min_frames)):
        zero = observed[:, k] & (positions[:, k, c] == 0.0)
        for start, length in runs(zero):
            stop = start + length
            sides = [positions[t, k, c] for t in (start - 1, stop) if 0 <= t < n_frames and observed[t, k]]
            if length >= min_frames and any(abs(v) > jump for v in sides):
                held[start:stop, k] = True
                found.append({"marker": int(k), "start": int(start), "length": int(length), "kind": "zero"})
    edge &= ~held
    found.sort(key=lambda r: (r["marker"], r["start"]))
    return HeldResult(held, edge, found)


def held_summary(result: HeldResult, labels: list[str], first_frame: int = 1) -> dict:
    """JSON-ready counts and runs (labels and the file's frame numbers) for ``info`` and the fill report."""
    counts = result.counts()
    counts["markers"] = sorted({labels[r["marker"]] for r in result.runs if r["kind"] != "edge"})
    counts["runs"] = [{"label": labels[r["marker"]], "kind": r["kind"], "first_frame": first_frame + r["start"],
                       "last_frame": first_frame + r["start"] + r["length"] - 1, "length": r["length"]}
                      for r in result.runs]
    return counts


def held_line(summary: dict) -> str:
    """One line saying what :func:`held_summary` found ("none" when nothing)."""
    parts = []
    if summary["held"]:
        parts.append(f"{summary['held']} held run(s)")
    if summary["zero"]:
        parts.append(f"{summary['zero']} zero run(s)")
    if not parts and not summary["edge"]:
        return "none"
    text = ", ".join(parts) if parts else "no held or zero runs"
    if parts:
        shown = ", ".join(summary["markers"][:6]) + (" ..." if len(summary["markers"]) > 6 else "")
        text += f": {summary['held_samples']} samples of {shown}"
    if summary["edge"]:
        text += f"; {summary['edge']} edge run(s) holding the nearest value ({summary['edge_samples']} samples, kept)"
    return text
