"""Fill one capture end to end: the steps `mocapfill fill` and `mocapfill batch` share.

:class:`FillSettings` holds what a user chooses (method, its options, outlier rejection, smoothing);
:func:`fill_capture` runs reject outliers -> fill -> smooth on a :class:`~mocapfill.markers.MarkerData` and returns a
:class:`FillOutcome`; :func:`write_fill_report` writes its JSON or HTML report.  Reading and writing the capture stay
with the caller (a command prints notes, a batch worker records them).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .errors import MethodError
from .markers import MarkerData
from .methods import DEFAULT_METHOD, get_method
from .methods.base import FillResult


#: The report lists at most this many repaired samples (the count is always complete).
REPAIRED_LISTED = 10000


@dataclass(frozen=True)
class FillSettings:
    """What to do to a capture; ``None`` = the method's or step's own default.

    ``bones`` is a path (a bones file from ``estimate-bones``); ``reference`` the paths of reference takes of the
    same marker set (:mod:`mocapfill.references`): their frames train the fill's body model (methods that take
    ``reference_frames``) and the moving ones give ``--reject-outliers`` its distance ranges.
    """

    method: str = DEFAULT_METHOD
    hidden: int | None = None
    max_iter: int | None = None
    tol: float | None = None
    seed: int | None = None
    bones: str | None = None
    reject_outliers: bool = False
    delta: float | None = None
    reference: tuple[str, ...] = ()
    model: str | None = None
    denoise: bool = False
    smooth: bool = False
    smooth_window: int | None = None
    smooth_order: int | None = None

    def check(self, *, name: Callable[[str], str] = str) -> "FillSettings":
        """Raise MethodError for an unknown method or an option whose step is off; return self.

        ``name`` spells a field in the message (the CLI gives ``--delta`` for ``delta``).
        """
        get_method(self.method)
        if self.denoise and self.model is None:
            raise MethodError(f"{name('denoise')} needs {name('model')} (a model from `mocapfill train`)")
        if self.delta is not None and not self.reject_outliers:
            raise MethodError(f"{name('delta')} only applies with {name('reject_outliers')}")
        for options, step in ((("smooth_window", "smooth_order"), "smooth"),):
            if any(getattr(self, option) is not None for option in options) and not getattr(self, step):
                raise MethodError(f"{name(options[0])} and {name(options[1])} only apply with {name(step)}")
        return self

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass
class FillOutcome:
    """One filled capture.

    Attributes
    ----------
    data : MarkerData
        The input as read; positions (n_frames, n_markers, 3).
    work : MarkerData
        What was filled: ``data`` with rejected outliers turned into gaps.
    result : FillResult
        The fill of ``work``.
    output : MarkerData
        ``data`` carrying the output positions (filled, then smoothed when asked).
    rejected : ndarray of bool (n_frames, n_markers) or None
        Samples removed as outliers (None without rejection).
    bones : BoneSet or None
        The bones file's bones, when one was given.
    settings : dict
        The options used, as the report records them.
    seconds : float
        Wall-clock time of the fill step alone.
    references : list of Reference
        The reference takes as matched and weighed (:mod:`mocapfill.references`), each saying which stage used it.
    repaired : ndarray of bool (n_frames, n_markers) or None
        Observed samples the learned denoiser judged displaced or swapped (``--denoise``), refilled
        (``Status.REPAIRED``); None without it.
    """

    data: MarkerData
    work: MarkerData
    result: FillResult
    output: MarkerData
    rejected: np.ndarray | None
    bones: Any
    settings: dict[str, Any]
    seconds: float
    references: list = dataclasses.field(default_factory=list)
    repaired: np.ndarray | None = None


def fill_capture(data: MarkerData, settings: FillSettings, *, reference: Any = None,
                 progress: Callable[[int, int, float], None] | None = None, jobs: int = 1) -> FillOutcome:
    """Reject outliers (optional), fill, smooth (optional) one capture.

    Parameters
    ----------
    data : MarkerData
        positions (n_frames, n_markers, 3), NaN = missing.
    settings : FillSettings
    reference : MarkerData, list of MarkerData, or None
        The reference takes named by ``settings.reference``, already read by the caller (positions
        (n, n_markers_ref, 3) each); matched to ``data`` by label (:func:`mocapfill.references.prepare`).
    progress : callable or None
        ``progress(iteration, n_max, objective)``, handed to methods that report progress.
    jobs : int
        Local worker processes a method may use (a long take's windows; 1: here, 0: every core), handed to methods
        that take ``jobs``.  Not a setting: the output does not depend on it.
    """
    work = data
    rejected = None
    record: dict[str, Any] = {}
    refs = []
    if reference is not None:
        from .references import prepare

        refs = prepare(data, reference if isinstance(reference, (list, tuple)) else [reference])
    model = None
    if settings.model is not None:
        from .engines.denoiser import load_model

        model = load_model(settings.model)
    repaired = None
    if settings.denoise:
        from .guards.denoise import find_displaced

        repaired = find_displaced(data.positions, model, labels=list(data.labels), units=data.units, rate=data.rate)
        positions = data.positions.copy()
        positions[repaired] = np.nan
        work = data.with_positions(positions)
        shown = [{"marker": data.labels[m], "frame": int(f) + data.first_frame}
                 for f, m in zip(*np.nonzero(repaired))][:REPAIRED_LISTED]
        record["denoise"] = {"model": settings.model, "repaired": int(repaired.sum()), "samples": shown}
    if settings.reject_outliers:
        from .guards.outliers import reject_outliers

        options: dict[str, Any] = {"units": data.units, "labels": list(data.labels), "rate": data.rate}
        if settings.delta is not None:
            options["delta"] = settings.delta
        if refs:
            from .references import outlier_frames

            ranges = outlier_frames(refs)  # moving references only: a static trial's ranges would reject motion
            if ranges is not None:
                options["reference"] = ranges
        outcome = reject_outliers(work.positions, **options)
        rejected = np.asarray(outcome.rejected, dtype=bool)
        work = data.with_positions(outcome.positions)
        record["reject_outliers"] = {"delta": 0.1 if settings.delta is None else settings.delta,
                                     "reference": [r.name for r in refs if not r.static] or None,
                                     "rejected": int(rejected.sum())}

    bones = None
    if settings.bones is not None:
        from .bones.boneset import load_bones

        bones = load_bones(settings.bones, data.labels, units=data.units)

    accepted = get_method(settings.method).parameters()
    options = {key: value for key, value in (("hidden", settings.hidden), ("max_iter", settings.max_iter),
                                              ("tol", settings.tol), ("seed", settings.seed), ("bones", bones))
               if value is not None}
    record.update({k: v for k, v in options.items() if k != "bones"})
    if settings.bones is not None:
        record["bones"] = settings.bones
    if progress is not None and "progress" in accepted:
        options["progress"] = progress
    if model is not None and "model" in accepted:
        options["model"] = model
        record["model"] = settings.model
    if refs:
        from .references import method_options

        options.update(method_options(refs, settings.method, accepted))
    if "jobs" in accepted:
        options["jobs"] = jobs

    from .api import fill

    started = time.perf_counter()
    result = fill(work, settings.method, **options)
    seconds = time.perf_counter() - started
    if refs:
        used = result.info.get("references")
        if isinstance(used, dict) and used.get("models"):
            for ref in refs:
                if ref.stages.get("fill", "").endswith(f"weight {ref.weight:.2f}"):
                    ref.stages["fill"] += (f"; kept by {used['used']} of {used['models']} local models (the others "
                                           f"fitted the capture better without references)")
        record["references"] = [ref.record(data.units) for ref in refs]

    positions = result.positions
    if settings.smooth:
        from .guards.smooth import savgol_smooth

        smooth_options: dict[str, Any] = {"rate": data.rate}
        if settings.smooth_window is not None:
            smooth_options["window"] = settings.smooth_window
        if settings.smooth_order is not None:
            smooth_options["order"] = settings.smooth_order
        positions = savgol_smooth(positions, **smooth_options)
        record["smooth"] = {"window": settings.smooth_window, "order": settings.smooth_order}

    output = data.with_positions(positions)
    refilled = rejected if repaired is None else (repaired if rejected is None else rejected | repaired)
    if refilled is not None:  # a rejected sample filled again is written as filled, not with its old residual
        from .io.c3d import mark_refilled

        output = mark_refilled(output, refilled)
    return FillOutcome(data, work, result, output, rejected, bones, record, seconds, refs, repaired)


def write_fill_report(outcome: FillOutcome, path: str, *, method: str, input_path: str | None,
                      output_path: str | None, smoothed: bool) -> None:
    """Write the JSON or HTML report (by ``path``'s extension) of one fill.

    The report's bone-length checks use the given bones, else bones estimated from the observed frames of the
    input (as bone-aware methods do), never from filled samples.
    """
    from .report import build_fill_report, write_report

    bones = outcome.bones
    if bones is None:
        from .bones.boneset import estimate_bones

        bones = estimate_bones(outcome.work.positions, units=outcome.data.units, labels=outcome.data.labels)
        if len(bones) == 0:
            bones = None
    report = build_fill_report(outcome.data, outcome.result, method=method, settings=outcome.settings,
                               seconds=outcome.seconds, input_path=input_path, output_path=output_path,
                               bones=bones, rejected=outcome.rejected, smoothed=smoothed)
    write_report(report, path, data=outcome.data, result=outcome.result, bones=bones)
