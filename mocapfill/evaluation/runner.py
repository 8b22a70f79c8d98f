"""Running trials: corrupt the clean clip, fill it with each method, score against the truth.

One trial is one task (:func:`run_trial`); :func:`run_trials` runs them on an executor (here, local processes, Dask).  Nothing
random happens here: the occlusions are fixed beforehand and each trial passes its own precomputed ``seed`` to the
methods, so that serial and parallel runs give the same numbers (only ``seconds`` differs).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Callable

import numpy as np

from ..errors import MocapfillError
from ..markers import MarkerData
from ..runtime.executor import Executor, make_executor
from .metrics import score
from ..bones.boneset import estimate_bones
from .occlusions import Trial


@dataclass
class TrialScore:
    """One method on one trial.  Errors are in the clip's units; NaN where nothing could be scored."""

    trial: int
    method: str
    rmse: float
    max_error: float
    mse: float
    bone_error: float
    seconds: float
    n_scored: int
    unfilled: int
    n_iter: int = 0
    converged: bool = True
    detected: float | None = None  # fraction of shifted samples the outlier rejection removed (random protocol)
    error: str | None = None  # the MocapfillError message when the method failed on this trial
    warnings: list[str] = field(default_factory=list)
    error_ratio: float = float("nan")  # RMS error per coordinate / RMS std (metrics.py); NaN without a std
    # Joint angles (evaluate with an IK setup; NaN without): over the frames with a scored sample, the RMSE per
    # coordinate of IK on the filled capture against IK on the complete one; median and worst coordinate,
    # rotational (degrees) and translational (the clip's units) apart.
    angle_median: float = float("nan")
    angle_worst: float = float("nan")
    translation_median: float = float("nan")
    translation_worst: float = float("nan")
    ik_seconds: float = float("nan")
    ik_errors: dict[str, float | None] | None = None  # per coordinate (None where IK failed)
    # With reference takes: each one's weight against this trial's corrupted clip ({name: weight}, None where the
    # body fit could not be measured) and, where the method reports it, how many of its local models kept them.
    references: dict[str, Any] | None = None


@dataclass(frozen=True)
class RunConfig:
    """Everything a trial needs besides the clip and the trial itself (picklable)."""

    methods: tuple[str, ...]
    options: dict[str, dict[str, Any]]  # per method: the keyword options for mocapfill.api.fill
    reject_outliers: str | None = None  # None, "self" (the corrupted clip is its own reference) or "clean"
    seeded: frozenset = frozenset()  # methods that take a ``seed``: they get the trial's seed
    references: tuple = ()  # reference takes (MarkerData), never the test capture: matched to each corrupted clip
    referenced: frozenset = frozenset()  # methods that take ``reference_frames``: they get the references
    ik: Any = None  # mocapfill.kinematics.opensim_ik.IKSetup: score joint angles too (needs opensim)
    ik_truth: Any = None  # mocapfill.kinematics.angles.IKAngles of the complete clip
    limits: dict[str, Any] = field(default_factory=dict)  # ``max_gap`` / ``edges`` for every method (api.fill)


#: The pseudo-method of a trial's IK with the hidden markers left out (empty TRC cells), as OpenSim does with gaps.
LEFT_MISSING = "left missing"


def score_angles(entry: TrialScore, data: MarkerData, frames: np.ndarray, config: RunConfig) -> None:
    """IK on ``data`` (the filled or gappy clip, positions (n_frames, n_markers, 3)); the joint-angle errors
    against ``config.ik_truth`` over ``frames`` ((n_frames,) bool) go into ``entry``.  An IK failure becomes a
    warning of the entry, with NaN angles."""
    from ..kinematics.angles import coordinate_errors, summarise_errors
    from ..kinematics.opensim_ik import run_ik

    truth = config.ik_truth
    try:
        angles = run_ik(config.ik, data)
    except MocapfillError as exc:
        entry.warnings.append(f"IK: {exc}")
        return
    errors = coordinate_errors(truth, angles, frames)
    summary = summarise_errors(errors, dict(zip(truth.names, truth.kinds)))
    nan = float("nan")
    entry.angle_median = summary["rotational"]["median"] if summary["rotational"]["n"] else nan
    entry.angle_worst = summary["rotational"]["worst"] if summary["rotational"]["n"] else nan
    entry.translation_median = summary["translational"]["median"] if summary["translational"]["n"] else nan
    entry.translation_worst = summary["translational"]["worst"] if summary["translational"]["n"] else nan
    entry.ik_seconds = angles.seconds
    entry.ik_errors = {k: (v if np.isfinite(v) else None) for k, v in errors.items()}


def _bones(positions: np.ndarray, units: str, labels: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Bones (pairs (B, 2), lengths (B,)) estimated from the occluded input only (:func:`estimate_bones`)."""
    bones = estimate_bones(positions, units=units, labels=labels)
    return bones.pairs, bones.lengths


def copies_hidden_together(positions: np.ndarray, corrupted: np.ndarray, hidden: np.ndarray, shifted: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A trial of a capture whose markers include exact copies (:mod:`mocapfill.guards.copies`): a sample hidden in
    one copy is hidden in all of them (else its twin would give it away), and only the first of each set is scored
    (each error counts once).  positions (n_frames, n_markers, 3) clean; the rest as :meth:`Trial.apply` returns
    them; unchanged without copies."""
    from ..guards.copies import distinct_trajectories

    keep, source = distinct_trajectories(positions)  # (copies whose own gaps differ too)
    if len(keep) == positions.shape[1]:
        return corrupted, hidden, shifted
    together = np.zeros((len(hidden), len(keep)), dtype=bool)
    np.logical_or.at(together.T, source, hidden.T)
    hidden = together[:, source] & ~np.isnan(positions).any(axis=2)
    corrupted = corrupted.copy()
    corrupted[hidden] = np.nan
    first = np.zeros(positions.shape[1], dtype=bool)
    first[keep] = True
    return corrupted, hidden & first, shifted & ~hidden & first


def run_trial(truth: MarkerData, index: int, trial: Trial, method_seed: int, config: RunConfig) -> list[TrialScore]:
    """Corrupt ``truth`` (positions (n_frames, n_markers, 3)) with ``trial``, fill with every method, score."""
    from ..api import fill

    positions = truth.positions
    corrupted, hidden, shifted = trial.apply(positions)
    corrupted, hidden, shifted = copies_hidden_together(positions, corrupted, hidden, shifted)
    detected = None
    if config.reject_outliers:
        from ..guards.outliers import reject_outliers

        # "clean": the clean clip plays Holden's reference take of the same marker set (distance ranges only).
        reference = positions if config.reject_outliers == "clean" else None
        res = reject_outliers(corrupted, reference=reference, units=truth.units, labels=truth.labels,
                              rate=truth.rate)
        corrupted = np.asarray(res.positions, dtype=float)
        rejected = np.asarray(res.rejected, dtype=bool)
        if shifted.any():
            detected = float((rejected & shifted).sum() / shifted.sum())
    scored = hidden | shifted
    pairs, lengths = _bones(corrupted, truth.units, truth.labels)
    data = truth.with_positions(corrupted)
    out = []
    for method in config.methods:
        opts = dict(config.options.get(method, {}))
        if method in config.seeded:
            opts.setdefault("seed", method_seed)
        if config.references and method in config.referenced:
            # matched and weighed against the corrupted clip (what a user has), never the clean one
            opts["reference"] = list(config.references)
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result = fill(data, method, **config.limits, **opts)
            except MocapfillError as exc:
                result, error = None, str(exc)
            else:
                error = None
        seconds = time.perf_counter() - t0
        messages = sorted({str(w.message) for w in caught})
        if result is None:
            out.append(TrialScore(index, method, *(float("nan"),) * 4, seconds, int(scored.sum()),
                                  int(scored.sum()), 0, False, detected, error, messages))
            continue
        m = score(result.positions, positions, scored, hidden, pairs, lengths, result.std)
        out.append(TrialScore(index, method, m["rmse"], m["max_error"], m["mse"], m["bone_error"], seconds,
                              m["n_scored"], m["unfilled"], int(result.n_iter), bool(result.converged), detected,
                              None, messages, m["error_ratio"], references=reference_use(result.info)))
        if config.ik is not None:
            score_angles(out[-1], truth.with_positions(result.positions), scored.any(axis=1), config)
    if config.ik is not None:  # the baseline: OpenSim leaves the hidden markers out where they are missing
        baseline = TrialScore(index, LEFT_MISSING, *(float("nan"),) * 5, int(scored.sum()), int(scored.sum()))
        score_angles(baseline, data, scored.any(axis=1), config)
        out.append(baseline)
    return out


def reference_use(info: dict[str, Any]) -> dict[str, Any] | None:
    """What a fill's ``info`` says of its reference takes: ``{"weights": {name: weight}, "models": n, "used": n}``
    (the last two where the method counts its models), or None without references."""
    takes = info.get("reference_takes")
    if not takes:
        return None
    use: dict[str, Any] = {"weights": {take["name"]: take["weight"] for take in takes}}
    counts = info.get("references") or {}
    if "models" in counts:
        use.update(models=int(counts["models"]), used=int(counts["used"]))
    return use


def run_trials(truth: MarkerData, trials: list[Trial], seeds: list[int], config: RunConfig, *, jobs: int = 1,
               executor: Executor | None = None, progress: Callable[[int, int], None] | None = None
               ) -> list[TrialScore]:
    """Run every trial; scores come back trial-major, methods in ``config.methods`` order, whatever runs them.

    Each trial is one task on ``executor`` (:mod:`mocapfill.runtime.executor`), else on ``jobs`` local processes
    (1: here; 0: every core).  ``progress(done, total)`` is called after each trial.
    """
    # The workers need the positions and labels only, not the format payload (a C3D's parameter section).
    light = MarkerData(truth.positions, truth.labels, truth.rate, truth.units, truth.first_frame, path=truth.path)
    total = len(trials)
    runner = executor if executor is not None else make_executor(jobs, n_tasks=total)
    results: list[list[TrialScore] | None] = [None] * total
    done = 0
    if progress:
        progress(0, total)

    def on_result(task: tuple[int, Trial, int], scores: list[TrialScore]) -> None:
        nonlocal done
        results[task[0]] = scores
        done += 1
        if progress:
            progress(done, total)

    def lost(task: tuple[int, Trial, int], exc: BaseException) -> list[TrialScore]:
        raise MocapfillError(f"{truth.path or 'evaluate'}: the worker running trial {task[0] + 1} died ({exc})")

    tasks = [(i, trial, seed) for i, (trial, seed) in enumerate(zip(trials, seeds))]
    runner.run(partial(run_indexed_trial, light, config), tasks, on_result, on_failure=lost)
    return [s for chunk in results for s in chunk]  # type: ignore[union-attr]


def run_indexed_trial(truth: MarkerData, config: RunConfig, task: tuple[int, Trial, int]) -> list[TrialScore]:
    """:func:`run_trial` on an ``(index, trial, method_seed)`` task (an executor's task)."""
    index, trial, method_seed = task
    return run_trial(truth, index, trial, method_seed, config)
