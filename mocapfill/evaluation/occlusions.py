"""Occlusion protocols: which samples of a clean capture to hide (and, for ``random``, to shift) in each trial.

Every protocol draws trial ``i`` from its own random stream, spawned from ``seed`` (``numpy.random.SeedSequence``),
so that a trial is the same whether it runs alone, in a serial loop or in a worker process.  Gaps are interior:
each hidden stretch leaves at least one observed frame before and after it, as in the BoLeRO paper's protocol (a
fill is an interpolation problem; extrapolation past the clip's edges is another question).

Protocols
---------
``marker``   one random marker, one contiguous gap of a random length in [gap_min, gap_max] (BoLeRO's statistical
             test).  Default length 10 % to 50 % of the clip, capped at 1 s and 5 s on long takes.
``limb``     ``limb_size`` (default 2) markers of one limb chain share one gap: a random marker, then a walk along
             its most rigid partners (smallest spread of the inter-marker distance over the clip), so neighbours on
             one body segment or across a joint (knee and shin) go missing together without a fixed marker set.
             Default length as for ``marker``.
``blackout`` every marker, one short span (default 0.05 s to 0.25 s).
``dense``    messy captures: random single-marker gaps (default 0.25 s to 2 s) are drawn until a fraction
             ``missing`` (default 0.2) of the observed marker samples is hidden; at 20 % no frame stays complete.
``segment``  a body segment vanishes: a random marker and every marker whose median distance to it is within
             ``radius`` (default 250 mm, in the file's units) are hidden together, ``events`` times per trial
             (default 3), each 0.5 s to 3 s.
``random``   Holden's corruption, with contiguous stretches instead of single samples: per trial draw
             ``a_o ~ U(0, occlusion_rate)`` and ``a_s ~ U(0, shift_rate)`` (both 0.1 by default, as in Holden 2018);
             every marker gets Poisson(a_o * n_frames / mean_length) gaps and Poisson(a_s * n_frames / mean_length)
             shifted stretches (lengths in [gap_min, gap_max], default 0.05 s to 0.5 s), so that about a fraction
             a_o of its samples are hidden and a_s are displaced.  A shifted stretch moves the marker by one random
             offset, uniform in [-shift_scale, shift_scale] per axis (default 50 cm in the file's units).  Shifted
             samples stay in the input; they are scored like hidden ones, so a pipeline that does not detect them
             pays their full displacement.

Lengths (``gap_min``, ``gap_max``) are frames (``40``), seconds (``"0.5s"``) or percent of the clip (``"10%"``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import MocapfillError
from ..units import length_factor

PROTOCOLS = ("marker", "limb", "blackout", "random", "dense", "segment")

#: Default gap-length range per protocol, as accepted by :func:`parse_length`.
DEFAULT_GAPS = {
    "marker": ("10%", "50%"),
    "limb": ("10%", "50%"),
    "blackout": ("0.05s", "0.25s"),
    "random": ("0.05s", "0.5s"),
    "dense": ("0.25s", "2s"),
    "segment": ("0.5s", "3s"),
}

#: Caps on the percent defaults of ``marker`` and ``limb`` (seconds), so that a long take is not tested with
#: minutes-long gaps: the BoLeRO protocol was designed on clips of a few seconds.
DEFAULT_CAPS_SECONDS = (1.0, 5.0)

#: Holden's default shift scale (50 cm) and the segment protocol's default radius (250 mm), in millimetres.
DEFAULT_SHIFT_SCALE_MM = 500.0
DEFAULT_RADIUS_MM = 250.0


@dataclass(frozen=True)
class Occlusion:
    """Markers hidden together over one stretch: marker indices, 0-based first frame, length in frames."""

    markers: tuple[int, ...]
    start: int
    length: int

    @property
    def stop(self) -> int:
        return self.start + self.length


@dataclass(frozen=True)
class Shift:
    """One marker displaced by ``offset`` (3,) in file units over a stretch (0-based start, length in frames)."""

    marker: int
    start: int
    length: int
    offset: tuple[float, float, float]


@dataclass(frozen=True)
class Trial:
    """What one trial hides and shifts; masks are built for a clip of a given shape."""

    occlusions: tuple[Occlusion, ...]
    shifts: tuple[Shift, ...] = field(default=())

    def hidden_mask(self, n_frames: int, n_markers: int) -> np.ndarray:
        """(n_frames, n_markers) bool: True where the trial hides a sample."""
        mask = np.zeros((n_frames, n_markers), dtype=bool)
        for occ in self.occlusions:
            mask[occ.start:occ.stop, list(occ.markers)] = True
        return mask

    def shift_field(self, n_frames: int, n_markers: int) -> np.ndarray:
        """(n_frames, n_markers, 3) float: the displacement added to each sample (0 where none; hidden wins)."""
        out = np.zeros((n_frames, n_markers, 3))
        for sh in self.shifts:
            out[sh.start:sh.start + sh.length, sh.marker] = sh.offset
        out[self.hidden_mask(n_frames, n_markers)] = 0.0
        return out

    def apply(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Corrupt clean ``positions`` (n_frames, n_markers, 3).

        Returns (corrupted positions (n_frames, n_markers, 3), hidden mask, shifted mask), masks (n_frames,
        n_markers) bool; only samples observed in ``positions`` count as hidden or shifted.
        """
        n_frames, n_markers, _ = positions.shape
        observed = ~np.isnan(positions).any(axis=2)
        hidden = self.hidden_mask(n_frames, n_markers) & observed
        offsets = self.shift_field(n_frames, n_markers)
        shifted = (offsets != 0).any(axis=2) & observed & ~hidden
        out = positions + np.where(shifted[..., None], offsets, 0.0)
        out[hidden] = np.nan
        return out, hidden, shifted


def parse_length(value: str | int | float, n_frames: int, rate: float, *, name: str = "length") -> int:
    """A length in frames from ``40`` (frames), ``"0.5s"`` (seconds) or ``"10%"`` (percent of ``n_frames``).

    Rounded to the nearest frame, at least 1.  Raises MocapfillError naming ``name`` and the value otherwise.
    """
    text = str(value).strip().lower()
    match = re.fullmatch(r"([0-9]*\.?[0-9]+(?:e[-+]?[0-9]+)?)\s*(s|%|f|frames?)?", text)
    if not match:
        raise MocapfillError(f"{name} {value!r}: expected frames (40), seconds (0.5s) or percent of the clip (10%)")
    number, unit = float(match.group(1)), match.group(2)
    if unit == "s":
        if not rate or rate <= 0:
            raise MocapfillError(f"{name} {value!r}: the clip has no frame rate to convert seconds")
        frames = number * rate
    elif unit == "%":
        frames = number / 100.0 * n_frames
    else:
        if number != int(number):
            raise MocapfillError(f"{name} {value!r}: a number of frames must be whole (or use 's' or '%')")
        frames = number
    return max(1, int(math.floor(frames + 0.5)))


def gap_range(protocol: str, n_frames: int, rate: float, gap_min=None, gap_max=None) -> tuple[int, int]:
    """(min, max) gap length in frames for ``protocol``, clipped so an interior gap fits in ``n_frames``."""
    lo_default, hi_default = DEFAULT_GAPS[protocol]
    lo = parse_length(lo_default if gap_min is None else gap_min, n_frames, rate, name="--occlusion-min")
    hi = parse_length(hi_default if gap_max is None else gap_max, n_frames, rate, name="--occlusion-max")
    if protocol in ("marker", "limb") and rate and rate > 0:
        if gap_min is None:
            lo = min(lo, max(1, round(DEFAULT_CAPS_SECONDS[0] * rate)))
        if gap_max is None:
            hi = min(hi, max(1, round(DEFAULT_CAPS_SECONDS[1] * rate)))
    longest = n_frames - 2
    if longest < 1:
        raise MocapfillError(f"the clip has {n_frames} frames: too short to hide an interior gap")
    if gap_min is not None and lo > longest:
        raise MocapfillError(f"--occlusion-min {gap_min} is {lo} frames, longer than the {longest} an interior gap can "
                             f"have in a {n_frames}-frame clip")
    if gap_min is not None and gap_max is not None and lo > hi:
        raise MocapfillError(f"--occlusion-min {gap_min} ({lo} frames) is longer than --occlusion-max {gap_max} "
                             f"({hi} frames)")
    hi = min(hi, longest)
    lo = min(lo, hi)
    return lo, hi


def rigid_partners(positions: np.ndarray, *, k: int = 3) -> np.ndarray:
    """Each marker's ``k`` most rigid partners: the markers whose distance to it varies least over the clip.

    positions : (n_frames, n_markers, 3), NaN = missing.  Returns (n_markers, k) int, the most rigid first; pairs
    never observed together rank last.  The spread is the standard deviation of the distance.
    """
    from ..bones.distances import pair_distance_stats

    n_markers = positions.shape[1]
    k = max(1, min(k, n_markers - 1))
    stats = pair_distance_stats(positions, percentiles=())
    spread = np.full((n_markers, n_markers), np.inf)
    std = np.where(np.isfinite(stats.std), stats.std, np.inf)
    spread[stats.pairs[:, 0], stats.pairs[:, 1]] = std
    spread[stats.pairs[:, 1], stats.pairs[:, 0]] = std
    return np.argsort(spread, axis=1, kind="stable")[:, :k]


def _interior_start(rng: np.random.Generator, n_frames: int, length: int) -> int:
    """A start leaving at least one frame before and after a gap of ``length``."""
    return int(rng.integers(1, n_frames - length))  # start in [1, n_frames - length - 1]


def _trial_rngs(seed, trials: int) -> list[np.random.Generator]:
    children = np.random.SeedSequence(seed).spawn(trials)
    return [np.random.default_rng(child) for child in children]


def make_occlusions(data, protocol: str = "marker", *, trials: int = 10, seed: int | None = None,
                    gap_min=None, gap_max=None, limb_size: int = 2, occlusion_rate: float = 0.1,
                    shift_rate: float = 0.1, shift_scale: float | None = None, missing: float = 0.2,
                    radius: float | None = None, events: int = 3) -> list[Trial]:
    """Draw ``trials`` occlusion trials for ``data`` with ``protocol`` (see the module docstring).

    Parameters
    ----------
    data : MarkerData
        The clean capture, positions (n_frames, n_markers, 3); its rate converts lengths in seconds, its units the
        default shift scale, its positions choose limb chains.
    protocol : "marker", "limb", "blackout", "random", "dense" or "segment"
    trials : int
        Number of trials.
    seed : int or None
        Trial ``i`` uses the ``i``-th stream spawned from ``SeedSequence(seed)``.
    gap_min, gap_max : int, float or str
        Gap lengths: frames, ``"0.5s"`` or ``"10%"``; defaults per protocol in :data:`DEFAULT_GAPS`.
    limb_size : int
        Markers per ``limb`` trial (at least 2).
    occlusion_rate, shift_rate, shift_scale :
        ``random`` protocol: Holden's sigma_o, sigma_s (fractions of samples) and beta (file units; default 50 cm).
    missing : float
        ``dense`` protocol: the fraction of observed marker samples to hide, in (0, 0.9].
    radius, events :
        ``segment`` protocol: markers within ``radius`` (file units; default 250 mm) of the chosen one, by median
        distance over the clip, vanish with it; ``events`` such stretches per trial.

    Returns
    -------
    list of Trial
    """
    if protocol not in PROTOCOLS:
        raise MocapfillError(f"unknown protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}")
    trials = int(trials)
    if trials < 1:
        raise MocapfillError(f"--trials must be at least 1, got {trials}")
    n_frames, n_markers = data.positions.shape[:2]
    if n_markers < 1:
        raise MocapfillError("the clip has no markers")
    lo, hi = gap_range(protocol, n_frames, data.rate, gap_min, gap_max)
    # Markers never observed have nothing to hide: trials pick among the others.
    seen = np.flatnonzero(~np.isnan(data.positions).any(axis=2).all(axis=0))
    if not seen.size:
        raise MocapfillError("every marker is missing in every frame: nothing to hide")
    rngs = _trial_rngs(seed, trials)
    out: list[Trial] = []
    if protocol == "marker":
        for rng in rngs:
            length = int(rng.integers(lo, hi + 1))
            out.append(Trial((Occlusion((int(seen[rng.integers(seen.size)]),),
                                        _interior_start(rng, n_frames, length), length),)))
    elif protocol == "blackout":
        everyone = tuple(range(n_markers))
        for rng in rngs:
            length = int(rng.integers(lo, hi + 1))
            out.append(Trial((Occlusion(everyone, _interior_start(rng, n_frames, length), length),)))
    elif protocol == "limb":
        size = int(limb_size)
        if size < 2:
            raise MocapfillError(f"limb_size must be at least 2, got {limb_size}")
        if size > n_markers:
            raise MocapfillError(f"limb_size {size} is more than the clip's {n_markers} markers")
        partners = rigid_partners(data.positions, k=min(n_markers - 1, 2 * size))
        for rng in rngs:
            chain = [int(seen[rng.integers(seen.size)])]
            while len(chain) < size:
                # Walk from the last marker to one of its two most rigid partners not already chosen; fall back to
                # any partner of the chain so far, so the walk cannot get stuck.
                options = [int(p) for p in partners[chain[-1]] if p not in chain][:2]
                if not options:
                    options = [int(p) for m in chain for p in partners[m] if p not in chain][:2]
                chain.append(options[int(rng.integers(len(options)))])
            length = int(rng.integers(lo, hi + 1))
            out.append(Trial((Occlusion(tuple(sorted(chain)), _interior_start(rng, n_frames, length), length),)))
    elif protocol == "dense":
        out = [_dense_trial(rng, data.positions, lo, hi, missing) for rng in rngs]
    elif protocol == "segment":
        if int(events) < 1:
            raise MocapfillError(f"--events must be at least 1, got {events}")
        if radius is None:
            radius = DEFAULT_RADIUS_MM * length_factor("mm", str(data.units))
        if not np.isfinite(radius) or radius < 0:
            raise MocapfillError(f"--radius must be a non-negative length, got {radius}")
        near = _neighbourhoods(data.positions, float(radius))
        for rng in rngs:
            occs = []
            for _ in range(int(events)):
                centre = int(seen[rng.integers(seen.size)])
                length = int(rng.integers(lo, hi + 1))
                occs.append(Occlusion(tuple(int(m) for m in near[centre]), _interior_start(rng, n_frames, length),
                                      length))
            out.append(Trial(tuple(occs)))
    else:  # random
        if not 0 <= occlusion_rate <= 1 or not 0 <= shift_rate <= 1:
            raise MocapfillError("occlusion_rate and shift_rate must lie in [0, 1]")
        scale = shift_scale
        if scale is None:
            scale = DEFAULT_SHIFT_SCALE_MM * length_factor("mm", str(data.units))
        mean_len = (lo + hi) / 2.0
        for rng in rngs:
            a_o = rng.uniform(0, occlusion_rate)
            a_s = rng.uniform(0, shift_rate)
            occs, shifts = [], []
            for m in range(n_markers):
                for _ in range(int(rng.poisson(a_o * n_frames / mean_len))):
                    length = int(rng.integers(lo, hi + 1))
                    occs.append(Occlusion((m,), _interior_start(rng, n_frames, length), length))
                for _ in range(int(rng.poisson(a_s * n_frames / mean_len))):
                    length = int(rng.integers(lo, hi + 1))
                    offset = tuple(float(v) for v in rng.uniform(-scale, scale, 3))
                    shifts.append(Shift(m, _interior_start(rng, n_frames, length), length, offset))
            if not occs:  # every trial hides something, so every trial scores the fill
                length = int(rng.integers(lo, hi + 1))
                occs.append(Occlusion((int(rng.integers(n_markers)),), _interior_start(rng, n_frames, length),
                                      length))
            out.append(Trial(tuple(occs), tuple(shifts)))
    return out


def _dense_trial(rng: np.random.Generator, positions: np.ndarray, lo: int, hi: int, missing: float) -> Trial:
    """Single-marker gaps of [lo, hi] frames, drawn until ``missing`` of the observed samples are hidden.

    positions : (n_frames, n_markers, 3).  The last gap is shortened so the fraction is met closely; a marker
    never observed is never chosen.
    """
    if not 0 < float(missing) <= 0.9:
        raise MocapfillError(f"--missing must lie in (0, 0.9] (a fraction of the samples), got {missing}")
    n_frames = positions.shape[0]
    observed = ~np.isnan(positions).any(axis=2)
    candidates = np.flatnonzero(observed.sum(axis=0) > 2)
    hidden = np.zeros_like(observed)
    target = int(round(float(missing) * observed.sum()))
    occs: list[Occlusion] = []
    # Each draw adds at most hi samples; the cap keeps a pathological clip (few observed samples) from looping.
    for _ in range(50 * (target // max(lo, 1) + 1)):
        done = int((hidden & observed).sum())
        if done >= target or not candidates.size:
            break
        marker = int(candidates[rng.integers(candidates.size)])
        length = int(rng.integers(lo, hi + 1))
        start = _interior_start(rng, n_frames, length)
        new = int((observed[start:start + length, marker] & ~hidden[start:start + length, marker]).sum())
        if new > target - done:  # trim the last gap so the fraction is met, not overshot
            keep = np.cumsum(observed[start:start + length, marker] & ~hidden[start:start + length, marker])
            length = max(1, int(np.searchsorted(keep, target - done) + 1))
        hidden[start:start + length, marker] = True
        occs.append(Occlusion((marker,), start, length))
    return Trial(tuple(occs))


def _neighbourhoods(positions: np.ndarray, radius: float) -> list[np.ndarray]:
    """Per marker, itself and every marker whose median distance to it over the clip is within ``radius``.

    positions : (n_frames, n_markers, 3).  Pairs never observed together are not neighbours.
    """
    from ..bones.distances import pair_distance_stats

    n_markers = positions.shape[1]
    stats = pair_distance_stats(positions, percentiles=(50,))
    median = np.full((n_markers, n_markers), np.inf)
    values = stats.percentile(50)
    values = np.where(np.isfinite(values), values, np.inf)
    median[stats.pairs[:, 0], stats.pairs[:, 1]] = values
    median[stats.pairs[:, 1], stats.pairs[:, 0]] = values
    np.fill_diagonal(median, 0.0)
    return [np.flatnonzero(median[m] <= radius) for m in range(n_markers)]
