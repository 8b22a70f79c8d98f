"""Evaluation: hide known samples of a clean capture, fill them with each method, score against the truth.

Public API
----------
- :func:`evaluate` (data, methods, protocol, trials, seed, ...) -> :class:`EvaluationResult`
- :func:`make_occlusions` (data, protocol, trials, seed, ...) -> list of :class:`Trial`: the protocols
  (``marker``, ``limb``, ``blackout``, ``random``, ``dense``, ``segment``; see :mod:`mocapfill.evaluation.occlusions`)
- :func:`load_spec` / :func:`save_spec` / :func:`trials_from_spec` / :func:`spec_of`: replayable occlusion specs
  (see :mod:`mocapfill.evaluation.spec` and ``docs/occlusions.md``)
- metrics in :mod:`mocapfill.evaluation.metrics` (RMSE, max error, the BoLeRO paper's MSE, bone-length error)
"""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import MethodError, MocapfillError
from ..markers import MarkerData
from ..methods.base import check_frames, check_magnitude
from ..report.json_report import jsonable
from .metrics import bone_error, point_errors, score
from .occlusions import (DEFAULT_GAPS, PROTOCOLS, Occlusion, Shift, Trial, gap_range, make_occlusions,
                         parse_length, rigid_partners)
from .runner import LEFT_MISSING, RunConfig, TrialScore, run_trial, run_trials
from .spec import SPEC_FORMAT, load_spec, save_spec, spec_of, trials_from_spec

__all__ = [
    "evaluate", "EvaluationResult", "TrialScore", "METRICS", "make_occlusions", "Trial", "Occlusion", "Shift",
    "PROTOCOLS", "DEFAULT_GAPS", "parse_length", "gap_range", "rigid_partners", "load_spec", "save_spec",
    "spec_of", "trials_from_spec", "SPEC_FORMAT", "score", "point_errors", "bone_error", "run_trial", "run_trials",
    "IK_METRICS", "LEFT_MISSING", "reference_words", "problem_words",
]

#: Metrics per trial and method, all "lower is better".
METRICS = ("rmse", "max_error", "mse", "bone_error", "seconds", "error_ratio")

#: Joint-angle metrics (evaluate with ``ik=``): median / worst coordinate over the model's rotational coordinates
#: (degrees) and translational ones (the clip's units), each the RMSE over the frames with a scored sample.
IK_METRICS = ("angle_median", "angle_worst", "translation_median", "translation_worst", "ik_seconds")

EVALUATION_SCHEMA = "mocapfill-evaluation/1"


def _nan_stat(values: np.ndarray, func) -> float | None:
    values = values[np.isfinite(values)]
    return float(func(values)) if values.size else None


@dataclass
class EvaluationResult:
    """The scores of every method on every trial of one evaluation.

    Attributes
    ----------
    methods : list of str
    protocol : str
        "marker", "limb", "blackout", "random" or "replay".
    trials : list of Trial
    scores : list of TrialScore
        Trial-major, methods in ``methods`` order: ``scores[t * len(methods) + k]``.
    seed : int
        The seed the occlusions and method seeds came from (drawn from the OS when none was given).
    data : MarkerData
        The clean clip (positions (n_frames, n_markers, 3)); labels and frame numbering for the reports.
    settings : dict
        The options of the run (gap range in frames, method options, ...).
    """

    methods: list[str]
    protocol: str
    trials: list[Trial]
    scores: list[TrialScore]
    seed: int | None
    data: MarkerData
    settings: dict[str, Any] = field(default_factory=dict)
    left_missing: list[TrialScore] = field(default_factory=list)
    ik: dict[str, Any] | None = None

    def metrics(self) -> tuple[str, ...]:
        """The metrics of this evaluation: :data:`METRICS`, and :data:`IK_METRICS` when it ran IK."""
        return METRICS + IK_METRICS if self.ik is not None else METRICS

    def values(self, metric: str = "rmse") -> np.ndarray:
        """(n_trials, n_methods) float array of ``metric`` (NaN where a method failed or nothing was scored)."""
        if metric not in self.metrics():
            raise MocapfillError(f"unknown metric {metric!r}; choose one of {', '.join(self.metrics())}")
        arr = np.array([getattr(s, metric) for s in self.scores], dtype=float)
        return arr.reshape(len(self.trials), len(self.methods))

    def left_missing_summary(self) -> dict[str, dict[str, Any]] | None:
        """With IK: ``{metric: {"mean", "median"}}`` over trials for the markers left missing (OpenSim skipping
        them frame by frame), for every metric of :data:`IK_METRICS`; None without IK."""
        if self.ik is None:
            return None
        return {m: {"mean": _nan_stat(np.array([getattr(s, m) for s in self.left_missing], float), np.mean),
                    "median": _nan_stat(np.array([getattr(s, m) for s in self.left_missing], float), np.median)}
                for m in IK_METRICS}

    def best_for_angles(self) -> str | None:
        """The method with the lowest median over trials of the median rotational-coordinate error (ties: the
        worst coordinate); None without IK or when no method has an angle."""
        if self.ik is None:
            return None
        summ = self.summary()
        scored = [m for m in self.methods if summ[m]["angle_median"]["median"] is not None]
        if not scored:
            return None
        return min(scored, key=lambda m: (summ[m]["angle_median"]["median"], summ[m]["angle_worst"]["median"] or 0))

    def summary(self) -> dict[str, dict[str, Any]]:
        """Per method: ``{metric: {"mean": x, "median": x}}`` for every metric, plus ``failures`` (trials where
        the method raised), ``unfilled`` (scored samples left missing, summed) and ``not_converged``."""
        out: dict[str, dict[str, Any]] = {}
        metrics = self.metrics()
        table = {m: self.values(m) for m in metrics}
        for k, method in enumerate(self.methods):
            mine = [s for s in self.scores if s.method == method]
            row: dict[str, Any] = {m: {"mean": _nan_stat(table[m][:, k], np.mean),
                                       "median": _nan_stat(table[m][:, k], np.median)} for m in metrics}
            row["failures"] = sum(1 for s in mine if s.error)
            row["unfilled"] = sum(s.unfilled for s in mine if not s.error)
            row["not_converged"] = sum(1 for s in mine if not s.error and not s.converged)
            used = [s.references for s in mine if s.references]
            if used:
                row["references"] = _reference_summary(used)
            out[method] = row
        return out

    def win_rates(self, metric: str = "rmse") -> dict[str, dict[str, float | None]]:
        """``rates[a][b]``: the fraction of trials where method ``a`` scored lower ``metric`` than ``b`` (ties count
        half; a number beats NaN; trials where both are NaN are left out).  None when no trial compares them."""
        vals = self.values(metric)
        rates: dict[str, dict[str, float | None]] = {}
        for i, a in enumerate(self.methods):
            rates[a] = {}
            for j, b in enumerate(self.methods):
                if i == j:
                    continue
                x, y = vals[:, i], vals[:, j]
                fx, fy = np.isfinite(x), np.isfinite(y)
                both = fx & fy
                n = int((fx | fy).sum())
                if n == 0:
                    rates[a][b] = None
                    continue
                wins = (x[both] < y[both]).sum() + 0.5 * (x[both] == y[both]).sum() + (fx & ~fy).sum()
                rates[a][b] = float(wins / n)
        return rates

    def ranking(self, metric: str = "rmse", statistic: str = "mean") -> list[str]:
        """Methods ordered best first by the ``statistic`` ("mean" or "median") of ``metric``; failing methods last."""
        summ = self.summary()
        key = lambda m: (summ[m][metric][statistic] is None, summ[m][metric][statistic] or 0.0)  # noqa: E731
        return sorted(self.methods, key=key)

    def best(self, metric: str = "rmse", statistic: str = "mean") -> str | None:
        """The method with the lowest ``statistic`` of ``metric``; None when no method has one (every hidden sample
        left unfilled, every trial failed): then no method is best."""
        first = self.ranking(metric, statistic)[0]
        return first if self.summary()[first][metric][statistic] is not None else None

    def trial_records(self) -> list[dict[str, Any]]:
        """Per trial: its occlusions/shifts in the spec layout and per-method scores (JSON-ready)."""
        spec = spec_of(self.trials, self.data)
        n = len(self.methods)
        records = []
        for t, trial_spec in enumerate(spec["trials"]):
            scores = {}
            for s in self.scores[t * n:(t + 1) * n]:
                d = asdict(s)
                d.pop("trial")
                d.pop("method")
                scores[s.method] = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                                    for k, v in d.items()}
            record = {"trial": t + 1, **trial_spec, "scores": scores}
            if self.ik is not None and t < len(self.left_missing):
                base = self.left_missing[t]
                record["left_missing"] = {k: jsonable(getattr(base, k))
                                          for k in IK_METRICS + ("ik_errors", "warnings")}
            records.append(record)
        return records

    def to_dict(self) -> dict[str, Any]:
        """The whole evaluation as a JSON-ready dict; its ``trials`` replay with ``--occlusions``."""
        d = self.data
        return {
            "schema": EVALUATION_SCHEMA,
            "file": d.path,
            "frames": d.n_frames,
            "markers": d.n_markers,
            "rate": d.rate,
            "units": d.units,
            "first_frame": d.first_frame,
            "protocol": self.protocol,
            "seed": self.seed,
            "methods": list(self.methods),
            "settings": jsonable(self.settings),
            "metrics": list(self.metrics()),
            "summary": self.summary(),
            "win_rates": {m: self.win_rates(m) for m in ("rmse", "bone_error")
                          + (("angle_median", "angle_worst") if self.ik is not None else ())},
            **({"ik": jsonable({**self.ik, "left_missing": self.left_missing_summary(),
                                "best_for_angles": self.best_for_angles()})} if self.ik is not None else {}),
            "trials": self.trial_records(),
        }

    def to_csv(self) -> str:
        """One row per trial and method: the hidden markers, where (first frame and length, empty when a trial hides
        several stretches), the number of scored samples, and every metric (empty where not a number)."""
        labels = self.data.labels
        first = self.data.first_frame
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(["trial", "method", "markers", "first_frame", "length", "n_scored", "rmse", "max_error",
                         "mse", "bone_error", "seconds", "unfilled", "n_iter", "converged", "detected", "error",
                         "error_ratio"] + (list(IK_METRICS) if self.ik is not None else []))
        n = len(self.methods)
        for t, trial in enumerate(self.trials):
            occ = trial.occlusions
            markers = ";".join(sorted({labels[m] for o in occ for m in o.markers}))
            if len(occ) == 1:
                where, length = str(first + occ[0].start), str(occ[0].length)
            else:  # several stretches (random protocol): see n_scored, and the JSON output for the details
                where, length = "", ""
            extra = [self.left_missing[t]] if self.ik is not None and t < len(self.left_missing) else []
            for s in self.scores[t * n:(t + 1) * n] + extra:  # IK's left-missing baseline: angles only
                row = [t + 1, s.method, markers, where, length, s.n_scored]
                row += ["" if not math.isfinite(v) else f"{v:.6g}"
                        for v in (s.rmse, s.max_error, s.mse, s.bone_error, s.seconds)]
                row += [s.unfilled, s.n_iter, s.converged, "" if s.detected is None else f"{s.detected:.4g}",
                        s.error or "", "" if not math.isfinite(s.error_ratio) else f"{s.error_ratio:.4g}"]
                if self.ik is not None:
                    row += ["" if not math.isfinite(getattr(s, m)) else f"{getattr(s, m):.6g}" for m in IK_METRICS]
                writer.writerow(row)
        return buf.getvalue()


def _reference_summary(uses: list[dict[str, Any]]) -> dict[str, Any]:
    """Over trials, a method's use of the reference takes (:func:`~.runner.reference_use` per trial): each take's
    lowest and highest weight, and its local models that kept them out of all it fitted (summed)."""
    weights: dict[str, list[float]] = {}
    for use in uses:
        for name, weight in use["weights"].items():
            weights.setdefault(name, []).append(float("nan") if weight is None else float(weight))
    out: dict[str, Any] = {"weights": {name: {"min": _nan_stat(np.array(w), np.min),
                                              "max": _nan_stat(np.array(w), np.max)} for name, w in weights.items()}}
    counted = [use for use in uses if "models" in use]
    if counted:
        out.update(models=sum(use["models"] for use in counted), used=sum(use["used"] for use in counted))
    return out


def reference_words(use: dict) -> str:
    """One method's use of the references over the trials (``EvaluationResult.summary()[method]["references"]``) in
    words: each take's weight (its range over the trials; under the cut, not used) and the local models that kept
    them."""
    from ..references import MIN_WEIGHT

    parts = []
    for name, w in use["weights"].items():
        lo, hi = w["min"], w["max"]
        weight = ("weight not measured" if lo is None else f"weight {lo:.2f}" if f"{lo:.2f}" == f"{hi:.2f}"
                  else f"weight {lo:.2f}-{hi:.2f}")
        if hi is not None and hi < MIN_WEIGHT:
            weight += " (not used: its body differs)"
        parts.append(f"{name} {weight}")
    text = "; ".join(parts)
    if "models" in use:
        text += f"; kept by {use['used']} of the {use['models']} local models it fitted over the trials"
    return text


def problem_words(row: dict) -> str:
    """One method's problems over the trials (an ``EvaluationResult.summary()`` row) in words, "" where none: trials
    it failed, samples it left unfilled, trials it did not converge on."""
    parts = [f"{row['failures']} failed"] if row["failures"] else []
    if row["unfilled"]:
        parts.append(f"{row['unfilled']} samples unfilled")
    if row["not_converged"]:
        parts.append(f"{row['not_converged']} not converged")
    return ", ".join(parts)


def _method_parameters(methods: Sequence[str]) -> dict[str, set[str]]:
    """The keyword options each method takes; fails early, in one line, on unknown or not-importable methods."""
    from ..methods import get_method

    if not methods:
        raise MethodError("no methods to evaluate")
    if len(set(methods)) != len(methods):
        raise MethodError(f"a method is listed twice: {', '.join(methods)}")
    accepted = {}
    for name in methods:
        spec = get_method(name)
        try:
            accepted[name] = spec.parameters()
        except (ImportError, AttributeError) as exc:
            raise MethodError(f"method {name!r} is not available in this build ({exc})") from None
    return accepted


def _check_references(data: MarkerData, reference) -> list[MarkerData]:
    """The reference takes as a list; the test capture itself (same positions) is an error: it would be an oracle."""
    from ..references import holds_frames_of

    if reference is None:
        return []
    refs = list(reference) if isinstance(reference, (list, tuple)) else [reference]
    for ref in refs:
        if not isinstance(ref, MarkerData):
            raise MocapfillError("evaluate: reference takes must be MarkerData (use mocapfill.read)")
        same_path = data.path and ref.path and os.path.abspath(str(ref.path)) == os.path.abspath(str(data.path))
        matched = _matched(data, ref)  # its positions in the capture's labels and units, or None
        if same_path or _same_take(data, ref, matched):
            raise MocapfillError(f"evaluate: {ref.path or 'a reference'} is the test capture itself; a fill that "
                                 "has seen the truth is an oracle, not an evaluation")
        if matched is not None and holds_frames_of(data.positions, matched, data.units):
            raise MocapfillError(f"evaluate: {ref.path or 'a reference'} holds the test capture's frames (the take "
                                 "it was cut from?); a fill that has seen the truth is an oracle, not an evaluation")
    return refs


def _matched(data: MarkerData, ref: MarkerData) -> np.ndarray | None:
    """``ref``'s positions (n_ref_frames, n_markers, 3) matched to the capture's labels and converted to its units
    (:func:`~mocapfill.references.match_reference`, its warnings aside); None when it shares too few labels."""
    from ..references import ReferenceError, match_reference

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return match_reference(data.labels, data.units, ref.positions, ref.labels, ref.units).positions
    except ReferenceError:
        return None


def _same_take(data: MarkerData, ref: MarkerData, matched: np.ndarray | None) -> bool:
    """Whether ``ref`` holds the test capture's samples: as many frames, and its markers, ``matched`` by label and
    converted to the capture's units (:func:`_matched`; None: too few labels shared), within 0.05 mm of the
    capture's wherever both are seen (a copy of the file, the take exported to another format or unit and rounded
    as formats round)."""
    if ref.positions.shape == data.positions.shape and np.array_equal(ref.positions, data.positions, equal_nan=True):
        return True
    if ref.n_frames != data.n_frames or matched is None:
        return False
    from ..units import length_factor

    seen = ~data.missing
    both = seen & ~np.isnan(matched).any(axis=2)
    if both.sum() < 0.5 * seen.sum():
        return False
    return bool(np.max(np.abs(matched[both] - data.positions[both])) <= 0.05 * length_factor("mm", data.units))


def evaluate(data: MarkerData, methods: Sequence[str] = ("linear", "spline"), protocol: str = "marker", *,
             trials: int = 10, seed: int | None = None, occlusions: Sequence[Trial] | str | os.PathLike | dict | None
             = None, occlusion_min=None, occlusion_max=None, jobs: int = 1, options: dict[str, Any] | None = None,
             method_options: dict[str, dict[str, Any]] | None = None, reject_outliers: bool | str | None = None,
             progress: Callable[[int, int], None] | None = None, save_occlusions: str | os.PathLike | None = None,
             reference: Sequence[MarkerData] | MarkerData | None = None,
             ik: str | os.PathLike | None = None, ik_model: str | os.PathLike | None = None,
             max_gap: int | str | None = None, edges: str = "fill", **protocol_options: Any) -> EvaluationResult:
    """Score ``methods`` on ``data`` by hiding known samples and filling them.

    Parameters
    ----------
    data : MarkerData
        A clean capture (few or no gaps), positions (n_frames, n_markers, 3).  Only observed samples are hidden;
        the clip's own gaps are filled too but never scored.
    methods : sequence of str
        Names from :data:`mocapfill.methods.METHODS`.
    protocol : str
        "marker", "limb", "blackout", "random", "dense" or "segment" (see :func:`make_occlusions`); ignored when
        ``occlusions`` is given.
    trials, seed, **protocol_options
        Passed to :func:`make_occlusions` (``limb_size``, ``occlusion_rate``, ``shift_rate``, ``shift_scale``,
        ``missing``, ``radius``, ``events``).
    occlusion_min, occlusion_max
        The length of the occlusions the protocol makes (its ``gap_min`` / ``gap_max``): frames, ``"0.5s"`` or
        ``"10%"``.  (The old names ``gap_min`` / ``gap_max`` are refused, naming these.)
        With ``seed=None`` a seed is drawn and recorded in the result so that the run can be repeated.
    occlusions : list of Trial, spec path, or parsed spec, optional
        Replay exactly these trials instead of drawing them (protocol "replay").
    jobs : int
        Worker processes (1 = in this process; <= 0 = every CPU).  Results do not depend on it.
    options : dict, optional
        Fill options for every method (``max_iter``, ``hidden``, ...); a method that does not take one ignores it.
    method_options : dict of dict, optional
        Per-method options, overriding ``options``.
    reject_outliers : None, "self" (or True) or "clean"
        Run :func:`mocapfill.guards.outliers.reject_outliers` on each corrupted clip before filling (the samples it rejects
        become gaps); ``detected`` then reports the fraction of shifted samples it caught.  "self": the corrupted
        clip is its own reference (what ``fill`` does without a reference); "clean": the clean clip is the reference
        take of Holden's rule (its distance ranges, not its positions): an **oracle** (it has seen the truth), and
        labelled so in the settings and every table.
    reference : MarkerData or sequence of MarkerData, optional
        Reference takes of the same marker set (:mod:`mocapfill.references`) for the methods that train on them
        (``auto``, ``pca``); matched and weighed against each corrupted clip.  The test capture itself is refused
        (identical positions): a fill that has seen the truth is not evaluated.
    progress : callable(done, total), optional
        Called once before the first trial (done = 0) and after each trial.
    save_occlusions : path, optional
        Write the trials as a spec file (:func:`save_spec`) before running them, so that an interrupted run can be
        replayed.
    ik : path of an OpenSim IK setup XML, optional
        Also score joint angles (needs ``opensim``, the extra ``mocapfill[opensim]``): per trial, OpenSim's
        InverseKinematicsTool with this setup on each method's fill, on the clip with the hidden markers left
        missing (the ``left_missing`` baseline) and once on the complete clip; per method the RMSE over the frames
        with a scored sample of each coordinate (:data:`IK_METRICS`).  IK runs inside each trial's task (``jobs``).
    ik_model : path of a scaled OpenSim model (.osim), optional
        The model for ``ik`` where the setup names none (or another), and for the ``opensim-ik`` method.
    max_gap, edges
        Given to every fill (:func:`mocapfill.fill`): gaps longer than ``max_gap`` (frames or ``"0.5s"``) and, with
        ``edges="leave"``, gaps at the clip's edges stay missing, so the hidden samples in them count as
        ``unfilled``: what the limit costs.

    Returns
    -------
    EvaluationResult
    """
    if not isinstance(data, MarkerData):
        raise MocapfillError("evaluate needs a MarkerData (use mocapfill.read)")
    check_frames(data.n_frames, name=data.path)
    renamed = [old for old in ("gap_min", "gap_max") if old in protocol_options]
    if renamed:
        raise MocapfillError(f"{' and '.join(renamed)} are now "
                             f"{' and '.join(old.replace('gap', 'occlusion') for old in renamed)} (the length of the "
                             "occlusions; max_gap limits the fill)")
    limits: dict[str, Any] = {}
    if max_gap is not None or edges != "fill":
        from ..guards.limits import check_edges, parse_max_gap

        limits = {"max_gap": None if max_gap is None else parse_max_gap(max_gap, data.rate, name="max_gap"),
                  "edges": check_edges(edges, name="edges")}
    if any(kind != "marker" for kind in data.kinds):  # scored on the markers: what a fill fills
        from ..pipeline import fill_columns, subset

        data = subset(data, fill_columns(data))
    check_magnitude(data.positions, name=data.path, labels=data.labels)  # once, not as every trial's failure
    methods = list(methods)
    if seed is None:
        seed = int(np.random.SeedSequence().entropy % (2 ** 63))
    seed = int(seed)
    if reject_outliers is True:
        reject_outliers = "self"
    if reject_outliers not in (None, False, "self", "clean"):
        raise MocapfillError(f"reject_outliers must be None, 'self' or 'clean', got {reject_outliers!r}")
    reject_outliers = reject_outliers or None
    from ..methods import get_method

    accepted = _method_parameters(methods)
    references = tuple(_check_references(data, reference))
    ik_setup = None
    if ik is not None:
        from ..kinematics.opensim_ik import load_setup

        ik_setup = load_setup(ik, ik_model)
    per_method: dict[str, dict[str, Any]] = {}
    for name in methods:
        merged = {k: v for k, v in (options or {}).items() if v is not None}
        if "ik_model" in accepted[name]:  # the kinematic fill takes the evaluation's model (and setup's weights)
            if ik_setup is not None:
                merged.setdefault("ik_model", ik_setup.model)
                if ik_setup.setup and "ik_setup" in accepted[name]:
                    merged.setdefault("ik_setup", ik_setup.setup)
            elif ik_model is not None:
                merged.setdefault("ik_model", os.fspath(ik_model))
        merged.update((method_options or {}).get(name, {}))
        ignored = sorted(k for k in merged if k not in accepted[name])
        if ignored:  # once here, not once per trial
            warnings.warn(f"method {name!r} ignores option(s): {', '.join(ignored)}", UserWarning, stacklevel=2)
        per_method[name] = {k: v for k, v in merged.items() if k in accepted[name]}
        for key, value in per_method[name].items():  # here once, not a TypeError deep in every trial
            problem = get_method(name).option_problem(key, value)
            if problem:
                raise MethodError(f"option {key}={value!r}: {problem}")
        required = get_method(name).requires
        if required and per_method[name].get(required) is None:
            raise MethodError(f"method {name!r} needs --{required.replace('_', '-')} (evaluate(..., {required}=...))")
    seeded = frozenset(name for name in methods if "seed" in accepted[name])
    settings: dict[str, Any] = {"options": dict(options or {}), "method_options": dict(method_options or {}),
                                "reject_outliers": reject_outliers,
                                "oracle": reject_outliers == "clean",
                                "references": [getattr(r, "path", None) or f"reference {k + 1}"
                                               for k, r in enumerate(references)]}
    if limits:
        settings.update({"max_gap_frames": limits["max_gap"], "edges": limits["edges"]})
    if occlusions is not None:
        protocol = "replay"
        if isinstance(occlusions, (str, os.PathLike)):
            settings["occlusions"] = os.fspath(occlusions)
            trial_list = load_spec(occlusions, data)
        elif isinstance(occlusions, dict) or (isinstance(occlusions, list) and occlusions
                                              and not isinstance(occlusions[0], Trial)):
            trial_list = trials_from_spec(occlusions, data)
        else:
            trial_list = list(occlusions)
    else:
        if protocol not in PROTOCOLS:
            raise MocapfillError(f"unknown protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}")
        lo, hi = gap_range(protocol, data.n_frames, data.rate, occlusion_min, occlusion_max)
        settings.update({"occlusion_min_frames": lo, "occlusion_max_frames": hi, **protocol_options})
        trial_list = make_occlusions(data, protocol, trials=trials, seed=seed, gap_min=occlusion_min,
                                     gap_max=occlusion_max, **protocol_options)
    if not trial_list:
        raise MocapfillError("no trials to run")
    if save_occlusions is not None:
        # the protocol's own settings (gap range in frames, missing, radius, events, ...) are for the reader only
        source = {"file": data.path, "protocol": protocol, "seed": seed,
                  **{k: v for k, v in settings.items() if k not in ("options", "method_options", "reject_outliers",
                                                                   "occlusions", "max_gap_frames", "edges")}}
        save_spec(trial_list, data, save_occlusions, source=source)
    # Method seeds: one per trial, from a stream independent of the occlusions' streams.
    seeds = [int(s.generate_state(1, np.uint32)[0]) for s in np.random.SeedSequence([seed, 1]).spawn(len(trial_list))]
    ik_record = None
    truth_angles = None
    if ik_setup is not None:
        from ..kinematics.opensim_ik import run_ik

        truth_angles = run_ik(ik_setup, data)
        ik_record = {"setup": ik_setup.setup, "model": ik_setup.model, "time_range": ik_setup.time_range,
                     "truth_seconds": truth_angles.seconds, "frames": int(len(truth_angles.frames)),
                     "coordinates": dict(zip(truth_angles.names, truth_angles.kinds))}
        settings["ik"] = {"setup": ik_setup.setup, "model": ik_setup.model}
    referenced = frozenset(name for name in methods if "reference_frames" in accepted[name])
    config = RunConfig(tuple(methods), per_method, reject_outliers, seeded, references, referenced, ik_setup,
                       truth_angles, limits)
    scores = run_trials(data, trial_list, seeds, config, jobs=jobs, progress=progress)
    left = [s for s in scores if s.method == LEFT_MISSING]
    scores = [s for s in scores if s.method != LEFT_MISSING]
    return EvaluationResult(methods, protocol, trial_list, scores, seed, data, settings, left, ik_record)
