"""Fill one capture end to end: the steps `mocapfill fill` and `mocapfill batch` share.

:class:`FillSettings` holds what a user chooses (method, its options, outlier rejection, short fragments, which gaps
and markers to fill, smoothing); :func:`fill_capture` runs reject outliers -> drop short fragments -> fill -> leave
the gaps not to fill -> smooth on a :class:`~mocapfill.markers.MarkerData` and returns a :class:`FillOutcome`, whose
``status`` (:func:`sample_status`) says what became of every sample; :func:`write_fill_report` writes its JSON or
HTML report and :func:`write_status_csv` its status CSV.  :func:`select_markers` turns ``--markers`` / ``--exclude``
into the markers to fill.  Reading and writing the capture stay with the caller (a command prints notes, a batch
worker records them).
"""

from __future__ import annotations

import dataclasses
import difflib
import fnmatch
import time
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from .errors import MethodError
from .markers import MarkerData
from .status import Status
from .methods import DEFAULT_METHOD, METHODS, get_method
from .methods.base import MARKER_RECORDS, FillResult, check_frames, check_magnitude


#: The report lists at most this many repaired samples (the count is always complete).
REPAIRED_LISTED = 10000


@dataclass(frozen=True)
class FillSettings:
    """What to do to a capture; ``None`` = the method's or step's own default.

    ``bones`` is a path (a bones file from ``estimate-bones``); ``reference`` the paths of reference takes of the
    same marker set (:mod:`mocapfill.references`): their frames train the fill's body model (methods that take
    ``reference_frames``) and the moving ones give ``--reject-outliers`` its distance ranges.  ``model``: a denoiser
    model (``mocapfill train``) for ``--method learned`` and ``denoise``.
    ``max_gap``: gaps longer than this stay missing (frames, or seconds as ``"0.5s"``); ``edges``: ``"fill"`` or
    ``"leave"`` the gaps touching the first or last frame; ``min_fragment``: observed stretches of fewer frames
    between two gaps join the gap around them; ``markers`` / ``exclude``: comma-separated labels or shell patterns of
    the markers to fill / not to fill (:func:`select_markers`).  ``donors``: the donors of ``pattern`` / ``rigid``
    as ``--donors`` writes them (``"MARKER=D1,D2;D3,D4"``, see :mod:`mocapfill.methods.suite`; a list of labels is
    joined).  ``lowpass``: a Butterworth low-pass after the fill, a cutoff in Hz, ``"auto"`` or ``"auto-marker"``
    (:mod:`mocapfill.guards.lowpass`).
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
    keep_held: bool = False
    ik_model: str | None = None  # a scaled OpenSim model, for the kinematic fill (opensim-ik)
    max_gap: str | int | None = None
    edges: str = "fill"
    min_fragment: int | None = None
    markers: str | None = None
    exclude: str | None = None
    donors: str | None = None
    lowpass: str | float | None = None

    def __post_init__(self) -> None:
        if self.donors is not None and not isinstance(self.donors, str):
            object.__setattr__(self, "donors", ",".join(str(d) for d in self.donors))

    def check(self, *, name: Callable[[str], str] = str) -> "FillSettings":
        """Raise MethodError for an unknown method, an option whose step is off or a malformed value; return self.

        ``name`` spells a field in the message (the CLI gives ``--delta`` for ``delta``).
        """
        get_method(self.method)
        if self.denoise and self.model is None:
            raise MethodError(f"{name('denoise')} needs {name('model')} (a model from `mocapfill train`)")
        self.check_values(name=name)
        if self.delta is not None and not self.reject_outliers:
            raise MethodError(f"{name('delta')} only applies with {name('reject_outliers')}")
        for options, step in ((("smooth_window", "smooth_order"), "smooth"),):
            if any(getattr(self, option) is not None for option in options) and not getattr(self, step):
                raise MethodError(f"{name(options[0])} and {name(options[1])} only apply with {name(step)}")
        if self.model is not None and not self.denoise and "model" not in get_method(self.method).parameters():
            # it would be loaded and then ignored: say so rather than fill as if it had been used
            takers = ", ".join(n for n, spec in METHODS.items() if "model" in spec.parameters())
            raise MethodError(f"{name('model')} is used by {name('denoise')} and by the methods {takers}, "
                              f"not {self.method}")
        if self.donors is not None and "donors" not in get_method(self.method).parameters():
            raise MethodError(f"{name('donors')} applies to the methods pattern and rigid, not {self.method}")
        if self.lowpass is not None:
            from .guards.lowpass import parse_cutoff

            parse_cutoff(self.lowpass)
        return self

    def check_values(self, *, name: Callable[[str], str] = str) -> "FillSettings":
        """Raise MethodError for a malformed ``max_gap``, ``edges`` or ``min_fragment``; return self."""
        from .guards.limits import check_edges, duration_form

        check_edges(self.edges, name=name("edges"))
        if self.max_gap is not None:
            duration_form(self.max_gap, name=name("max_gap"))  # the form only: seconds need the file's rate
        if self.min_fragment is not None and int(self.min_fragment) < 1:
            raise MethodError(f"{name('min_fragment')} must be at least 1 frame, got {self.min_fragment}")
        return self

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def select_markers(labels: Sequence[str], kinds: Sequence[str] | None = None, markers: str | Sequence[str] | None
                   = None, exclude: str | Sequence[str] | None = None, *, path: str | None = None) -> np.ndarray:
    """The points to fill: ``--markers`` (default every point of kind ``"marker"``) minus ``--exclude``.

    Parameters
    ----------
    labels : sequence of str, length n_markers
    kinds : sequence of str, length n_markers, or None
        :attr:`MarkerData.kinds` (None: every point is a marker).
    markers, exclude : str (comma-separated) or sequence of str, or None
        Labels or shell-style patterns (``L*``, ``?ASI``, ``[LR]KNE``), each matched against the whole label and
        against the label after a ``Subject:`` prefix.  A pattern reaches markers only; an exact name (tried first,
        so Vicon's unlabelled ``*12`` is a name) also reaches a model point or an unlabelled trajectory.
    path : str or None
        The capture's path, for messages.

    Returns
    -------
    ndarray of bool, shape (n_markers,)

    Raises
    ------
    MethodError
        An item that matches nothing (one line naming it, with the near labels), or a choice that leaves nothing.
    """
    labels = [str(label) for label in labels]
    kinds = ["marker"] * len(labels) if kinds is None else list(kinds)
    is_marker = np.array([kind == "marker" for kind in kinds], dtype=bool)
    chosen = is_marker.copy() if markers is None else _matching(labels, kinds, markers, "--markers", path)
    if exclude is not None:
        chosen &= ~_matching(labels, kinds, exclude, "--exclude", path)
    if (markers is not None or exclude is not None) and labels and not chosen.any():
        raise MethodError(f"{_where(path)}--markers / --exclude leave no marker to fill")
    return chosen


#: Characters that make a ``--markers`` item a shell pattern rather than a name.
PATTERN_CHARS = "*?["


def _where(path: str | None) -> str:
    return f"{path}: " if path else ""


def _items(spec: str | Sequence[str]) -> list[str]:
    parts = spec.split(",") if isinstance(spec, str) else [str(item) for item in spec]
    return [part.strip() for part in parts if part.strip()]


def _matching(labels: list[str], kinds: list[str], spec: str | Sequence[str], option: str, path: str | None
              ) -> np.ndarray:
    """(n_markers,) bool: the points some item of ``spec`` names; MethodError for an item that names none."""
    items = _items(spec)
    if not items:
        raise MethodError(f"{_where(path)}{option} is empty; give labels or patterns, comma-separated")
    bases = [label.rpartition(":")[2] for label in labels]
    out = np.zeros(len(labels), dtype=bool)
    unmatched = []
    for item in items:
        hits = np.array([item in (label, base) for label, base in zip(labels, bases)], dtype=bool)
        if not hits.any() and any(char in item for char in PATTERN_CHARS):  # a name first: Vicon's "*12"
            hits = np.array([kind == "marker" and (fnmatch.fnmatchcase(label, item) or fnmatch.fnmatchcase(base, item))
                             for label, base, kind in zip(labels, bases, kinds)], dtype=bool)
            if not hits.any():
                unmatched.append(item)
        elif not hits.any():
            raise MethodError(f"{_where(path)}{option}: no marker called {item!r}{_near(item, labels, bases)}")
        out |= hits
    if unmatched:
        message = f"{_where(path)}{option}: pattern {unmatched[0]!r} matches no marker"
        if not out.any():  # nothing chosen at all: an error, with the near labels
            raise MethodError(message + _near(unmatched[0], labels, bases))
        # one pattern of several may miss a file of a batch (no right-side markers): said, not fatal
        warnings.warn(message + "".join(f"; nor does {item!r}" for item in unmatched[1:]), UserWarning,
                      stacklevel=3)
    return out


def _near(item: str, labels: list[str], bases: list[str]) -> str:
    """``"; near: A, B"`` listing the labels closest to ``item`` (case-insensitive), or ``""``."""
    names = list(dict.fromkeys(bases + labels))
    lower = {}
    for name in names:
        lower.setdefault(name.lower(), name)
    close = difflib.get_close_matches(item.lower().strip("*?[]"), list(lower), n=5, cutoff=0.5)
    return f"; near: {', '.join(lower[c] for c in close)}" if close else ""


@dataclass
class FillOutcome:
    """One filled capture.

    Attributes
    ----------
    data : MarkerData
        The input as read; positions (n_frames, n_markers, 3).
    work : MarkerData
        What was filled: ``data`` with rejected outliers and dropped fragments turned into gaps.
    result : FillResult
        The fill of ``work``, with the gaps left on request put back to missing.
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
    held : ndarray of bool (n_frames, n_markers) or None
        Samples turned into gaps as held or frozen (:mod:`mocapfill.guards.held`); None with ``keep_held``.
    columns : ndarray of int or None
        The point columns the fill saw (:func:`fill_columns`); the others came back untouched.
    held_summary : dict or None
        What the held-sample guard found (:func:`mocapfill.guards.held.held_summary`, fill columns only), also with
        ``keep_held`` (then nothing was rejected).
    references : list of Reference
        The reference takes as matched and weighed (:mod:`mocapfill.references`), each saying which stage used it.
    repaired : ndarray of bool (n_frames, n_markers) or None
        Observed samples the learned denoiser judged displaced or swapped (``--denoise``), refilled
        (``Status.REPAIRED``); None without it.
    fragments : ndarray of bool (n_frames, n_markers) or None
        Observed samples dropped as short fragments (``--min-fragment``); None when the guard did not run.
    chosen : ndarray of bool (n_markers,) or None
        The points to fill (:func:`select_markers`); a subset of ``columns``.
    left : ndarray of int8 (n_frames, n_markers) or None
        Missing samples left missing on request: the :class:`~mocapfill.status.Status` code of the reason, 0 elsewhere.
    status : ndarray of int8 (n_frames, n_markers) or None
        What became of each sample (:func:`sample_status`; :mod:`mocapfill.status` codes).
    """

    data: MarkerData
    work: MarkerData
    result: FillResult
    output: MarkerData
    rejected: np.ndarray | None
    bones: Any
    settings: dict[str, Any]
    seconds: float
    held: np.ndarray | None = None
    columns: np.ndarray | None = None
    held_summary: dict[str, Any] | None = None
    references: list = dataclasses.field(default_factory=list)
    repaired: np.ndarray | None = None
    fragments: np.ndarray | None = None
    chosen: np.ndarray | None = None
    left: np.ndarray | None = None
    status: np.ndarray | None = None

    def observed_changed(self) -> list[str]:
        """The options that changed or dropped observed samples in this fill, with how many (for the reports);
        empty when none did (what the output's format does to them: :meth:`observed_stored`)."""
        out = []
        for option, mask in (("--reject-outliers", self.rejected), ("held-sample guard", self.held),
                             ("--min-fragment", self.fragments), ("--denoise", self.repaired)):
            if mask is not None and np.asarray(mask).any():
                out.append(f"{option} ({int(np.asarray(mask).sum())} samples)")
        if self.status is not None:
            smoothed = int((self.status == Status.SMOOTHED).sum())
            for key, option in (("smooth", "--smooth"), ("lowpass", "--lowpass")):
                if key in self.settings and smoothed:
                    out.append(f"{option} ({smoothed} samples)")
        return out

    def observed_stored(self, path: Any, format: str | None = None) -> str | None:
        """How writing ``output`` to ``path`` (in ``format``, as :func:`mocapfill.io.write`) stores the observed
        samples this fill returned as they were: :func:`mocapfill.io.storage_change` ("rounded to the TSV's 0.001
        mm"); None when the file holds them exactly, or when options changed them (:meth:`observed_changed`)."""
        from .io import storage_change

        if self.observed_changed():
            return None
        return storage_change(self.output, path, format, samples=~self.data.missing)


def fill_columns(data: MarkerData, chosen: Any = None) -> np.ndarray:
    """The point columns that inform the fill: int array, ascending.

    The points of kind ``"marker"`` (every marker informs the fill, chosen or not), plus the points in ``chosen``:
    the ``--markers`` / ``--exclude`` selection (:func:`select_markers`, a bool mask (n_points,) or indices), which
    brings in a model point or an unlabelled trajectory named exactly.  The others are kept untouched, out of the
    fill and its statistics.  Which of these columns are filled is ``chosen`` (:func:`fill_capture`).
    """
    columns = np.array([k for k, kind in enumerate(data.kinds) if kind == "marker"], dtype=np.int64)
    if chosen is None:
        return columns
    chosen = np.asarray(chosen)
    extra = np.flatnonzero(chosen) if chosen.dtype == bool else chosen.astype(np.int64).reshape(-1)
    return np.union1d(columns, extra).astype(np.int64)


def subset(data: MarkerData, columns: np.ndarray) -> MarkerData:
    """``data`` restricted to ``columns`` (positions (n_frames, len(columns), 3)); the C3D payload is dropped, so
    write the full capture, not this view."""
    columns = np.asarray(columns, dtype=np.int64)
    return MarkerData(data.positions[:, columns], [data.labels[k] for k in columns], data.rate, data.units,
                      data.first_frame, data.source_format, None, data.path, list(data.notes),
                      [data.kinds[k] for k in columns])


def widen_result(result: FillResult, columns: np.ndarray, positions: np.ndarray, labels: list[str]) -> FillResult:
    """A fill of ``positions[:, columns]`` as a result over every column of ``positions`` (n_frames, n_points, 3):
    the other columns as they were, not filled; per-gap records name their marker by label."""
    full = positions.copy()
    full[:, columns] = result.positions
    filled = np.zeros(positions.shape[:2], dtype=bool)
    filled[:, columns] = result.filled
    std = None
    if result.std is not None:
        std = np.where(np.isnan(positions).any(axis=2), np.nan, 0.0)
        std[:, columns] = result.std
    info = dict(result.info)
    if isinstance(info.get("left_missing"), list):  # the stretches left on request, in the full capture's columns
        info["left_missing"] = [dict(r, marker=int(columns[r["marker"]])) for r in info["left_missing"]]
    sub_labels = [labels[k] for k in columns]
    for key in MARKER_RECORDS:  # name each record's marker: indices would point into the fill's columns
        if isinstance(info.get(key), list):
            info[key] = [dict(r, marker=sub_labels[r["marker"]]) if isinstance(r, dict)
                         and isinstance(r.get("marker"), (int, np.integer))
                         and 0 <= r["marker"] < len(sub_labels) else r for r in info[key]]
    for key in MARKER_RECORDS:  # per-marker records' marker_index: a column of the whole capture
        if isinstance(info.get(key), list):
            info[key] = [dict(r, marker_index=int(columns[r["marker_index"]])) if isinstance(r, dict)
                         and isinstance(r.get("marker_index"), (int, np.integer))
                         and 0 <= r["marker_index"] < len(columns) else r for r in info[key]]
    return FillResult(full, filled, std, result.n_iter, result.converged, list(result.objective), info)


def fill_capture(data: MarkerData, settings: FillSettings, *, reference: Any = None,
                 progress: Callable[[int, int, float], None] | None = None, jobs: int = 1) -> FillOutcome:
    """Find held samples, reject outliers (optional), drop short fragments (optional), fill, leave the gaps not to
    fill, smooth (optional) one capture.

    Only the columns of :func:`fill_columns` (the markers, and the points ``--markers`` names) go through these steps
    and inform the fill: the method sees ``positions[:, columns]``; model points and unlabelled trajectories come
    back untouched.  Held and frozen samples (:mod:`mocapfill.guards.held`) become gaps unless
    ``settings.keep_held``.

    Parameters
    ----------
    data : MarkerData
        positions (n_frames, n_markers, 3), NaN = missing.
    settings : FillSettings
    reference : MarkerData, list of MarkerData, or None
        The reference takes named by ``settings.reference``, already read by the caller (positions
        (n, n_markers_ref, 3) each); matched to the filled columns by label (:func:`mocapfill.references.prepare`).
    progress : callable or None
        ``progress(iteration, n_max, objective)``, handed to methods that report progress.
    jobs : int
        Local worker processes a method may use (a long take's windows; 1: here, 0: every core), handed to methods
        that take ``jobs``.  Not a setting: the output does not depend on it.

    Every marker informs the fill; gaps longer than ``max_gap``, at the edges under ``edges="leave"`` and of the
    markers not chosen are put back to missing after it.  A fragment is dropped only when the gap it then belongs
    to is filled.  Observed samples come back bit-identical unless outliers, fragments or smoothing changed them
    (``FillOutcome.observed_changed()`` names which).
    """
    from .guards.limits import apply_limits, leave_reasons, parse_max_gap

    check_frames(data.n_frames, name=data.path)
    chosen = select_markers(data.labels, data.kinds, settings.markers, settings.exclude, path=data.path)
    max_gap = None if settings.max_gap is None else parse_max_gap(settings.max_gap, data.rate)
    if settings.smooth and settings.smooth_window is not None and int(settings.smooth_window) > data.n_frames:
        # every stretch would be shorter than the window and left as it is: a no-op "smoothed" is an error
        raise MethodError(f"{data.path}: --smooth-window {settings.smooth_window} is longer than the take "
                          f"({data.n_frames} frames): nothing would be smoothed")
    if settings.lowpass is not None:  # a cutoff the take cannot carry fails now, not after the fill
        from .guards.lowpass import check_cutoff, parse_cutoff

        cutoff, _ = parse_cutoff(settings.lowpass)
        if not isinstance(cutoff, str):
            check_cutoff(cutoff, data.rate, data.n_frames, path=data.path)
    columns = fill_columns(data, chosen)
    every = columns.size == data.n_markers
    view = data if every else subset(data, columns)
    chosen_view = chosen[columns]
    record: dict[str, Any] = {}
    if not every:
        record["points_kept"] = {kind: sum(1 for k in data.kinds if k == kind) for kind in ("model", "unlabelled")}

    check_magnitude(view.positions, name=data.path, labels=view.labels)  # before the guards square them too
    from .guards.held import find_held, held_summary

    quantum = None
    extra = data.extra
    if getattr(getattr(extra, "file", None), "is_float", True) is False:
        quantum = abs(float(extra.file.scale))
    found = find_held(view.positions, units=data.units, quantum=quantum)
    if not chosen_view.all():  # markers not chosen (--markers / --exclude) are not touched, nor reported
        found = dataclasses.replace(found, held=found.held & chosen_view, edge=found.edge & chosen_view,
                                    runs=[r for r in found.runs if chosen_view[r["marker"]]])
    summary = held_summary(found, view.labels, data.first_frame)
    held = None
    work = view
    if not settings.keep_held:
        held_sub = found.held
        if held_sub.any():
            work = view.with_positions(np.where(held_sub[:, :, None], np.nan, view.positions))
        held = np.zeros((data.n_frames, data.n_markers), dtype=bool)
        held[:, columns] = held_sub
        record["held"] = {"rejected": int(held_sub.sum()), "runs": summary["held"] + summary["zero"]}

    refs = []
    if reference is not None:
        from .references import prepare

        refs = prepare(view, reference if isinstance(reference, (list, tuple)) else [reference])
    model = None
    if settings.model is not None:
        from .engines.denoiser import load_model

        model = load_model(settings.model)
    repaired = None
    if settings.denoise:
        from .guards.denoise import find_displaced

        repaired_sub = find_displaced(work.positions, model, labels=list(view.labels), units=data.units,
                                      rate=data.rate) & chosen_view[None, :]
        work = work.with_positions(np.where(repaired_sub[:, :, None], np.nan, work.positions))
        repaired = np.zeros((data.n_frames, data.n_markers), dtype=bool)
        repaired[:, columns] = repaired_sub
        shown = [{"marker": view.labels[m], "frame": int(f) + data.first_frame}
                 for f, m in zip(*np.nonzero(repaired_sub))][:REPAIRED_LISTED]
        record["denoise"] = {"model": settings.model, "repaired": int(repaired_sub.sum()), "samples": shown}

    rejected = None
    if settings.reject_outliers:
        from .guards.outliers import reject_outliers

        options: dict[str, Any] = {"units": data.units, "labels": list(view.labels), "rate": data.rate}
        if settings.delta is not None:
            options["delta"] = settings.delta
        if refs:
            from .references import outlier_frames

            ranges = outlier_frames(refs)  # moving references only: a static trial's ranges would reject motion
            if ranges is not None:
                # other takes widen the capture's own ranges: none posed every pose of this one
                options.update(reference=ranges, widen_with_self=True)
        outcome = reject_outliers(work.positions, **options)
        rejected_sub = np.asarray(outcome.rejected, dtype=bool) & chosen_view[None, :]  # others are not touched
        work = work.with_positions(np.where(rejected_sub[:, :, None], np.nan, work.positions))
        rejected = np.zeros((data.n_frames, data.n_markers), dtype=bool)
        rejected[:, columns] = rejected_sub
        record["reject_outliers"] = {"delta": 0.1 if settings.delta is None else settings.delta,
                                     "reference": [r.name for r in refs if r.stages.get("reject_outliers", "")
                                                   .endswith("distance ranges")] or None,
                                     "rejected": int(rejected_sub.sum())}

    fragments = None
    if settings.min_fragment is not None:
        from .guards.fragments import count_fragments, short_fragments

        candidates = short_fragments(work.missing, int(settings.min_fragment)) & chosen_view[None, :]
        joined = leave_reasons(work.missing | candidates, max_gap=max_gap, edges=settings.edges, chosen=chosen_view)
        fragments_view = candidates & (joined == 0)  # kept where the gap they would join is left missing
        if fragments_view.any():
            work = work.with_positions(np.where(fragments_view[:, :, None], np.nan, work.positions))
        fragments = np.zeros((data.n_frames, data.n_markers), dtype=bool)
        fragments[:, columns] = fragments_view
        record["min_fragment"] = {"frames": int(settings.min_fragment), "fragments": count_fragments(fragments),
                                  "samples": int(fragments.sum())}
    if max_gap is not None:
        record["max_gap"] = {"given": settings.max_gap, "frames": max_gap}
    if settings.edges != "fill":
        record["edges"] = settings.edges
    if settings.markers is not None or settings.exclude is not None:
        record["markers"] = {"markers": settings.markers, "exclude": settings.exclude,
                             "chosen": int(chosen.sum())}

    bones = None
    if settings.bones is not None:
        from .bones.boneset import load_bones

        bones = load_bones(settings.bones, view.labels, units=data.units)

    accepted = get_method(settings.method).parameters()
    options = {key: value for key, value in (("hidden", settings.hidden), ("max_iter", settings.max_iter),
                                              ("tol", settings.tol), ("seed", settings.seed), ("bones", bones),
                                              ("ik_model", settings.ik_model))
               if value is not None}
    record.update({k: v for k, v in options.items() if k != "bones"})
    if settings.bones is not None:
        record["bones"] = settings.bones
    if settings.donors is not None:
        options["donors"] = settings.donors
        record["donors"] = settings.donors
    if progress is not None and "progress" in accepted:
        options["progress"] = progress
    if "jobs" in accepted:
        options["jobs"] = jobs
    if model is not None and "model" in accepted:
        options["model"] = model
        record["model"] = settings.model
    if refs:
        from .references import method_options

        options.update(method_options(refs, settings.method, accepted))

    from .api import fill

    started = time.perf_counter()
    if columns.size:  # every column of the view is filled as a marker (a point --markers named exactly too)
        result = fill(dataclasses.replace(work, kinds=None), settings.method, **options)
    else:  # nothing to fill: only model points / unlabelled trajectories
        result = FillResult(work.positions.copy(), np.zeros(work.positions.shape[:2], dtype=bool))
    result, left_view = apply_limits(result, work.missing, max_gap=max_gap, edges=settings.edges, chosen=chosen_view)
    seconds = time.perf_counter() - started
    if isinstance(result.info.get("prior"), dict):  # the model as the default's second spatial measurement
        record["model_prior"] = result.info["prior"]
    if refs:
        used = result.info.get("references")
        training = [ref for ref in refs if ref.stages.get("fill", "").endswith(f"weight {ref.weight:.2f}")]
        if isinstance(used, dict) and "models" in used and training:
            if not used["models"]:  # (no local model had a reference frame to train on)
                said = "; but no local model could train on the references' frames"
            else:  # the models keep or leave the references' frames together: one count for all of them
                kept = "kept" if len(training) == 1 else f"kept, with the {len(training) - 1} other reference(s),"
                others = used["models"] - used["used"]
                said = (f"; {kept} by {used['used']} of {used['models']} local models"
                        + (f" (the other {others} fitted the capture better without references)" if others else ""))
            if used.get("completed"):  # (the default completes a reference's gaps first: predictors, never targets)
                n = used["completed"]
                said += f"; the references' {n} missing sample{'s' if n != 1 else ''} completed as predictors"
            for ref in training:
                ref.stages["fill"] += said
        record["references"] = [ref.record(data.units) for ref in refs]
    left = np.zeros((data.n_frames, data.n_markers), dtype=np.int8)
    left[:, columns] = left_view

    if not every:
        full_work = data.positions.copy()
        full_work[:, columns] = work.positions
        result = widen_result(result, columns, data.positions, data.labels)
        if bones is not None:
            bones = dataclasses.replace(bones, pairs=columns[np.asarray(bones.pairs, dtype=np.int64)])
        work = data.with_positions(full_work)
    positions = result.positions
    if settings.smooth:
        from .guards.smooth import savgol_smooth

        smooth_options: dict[str, Any] = {"rate": data.rate}
        if settings.smooth_window is not None:
            smooth_options["window"] = settings.smooth_window
        if settings.smooth_order is not None:
            smooth_options["order"] = settings.smooth_order
        positions = positions.copy()
        smoothed = np.flatnonzero(chosen)  # the chosen markers only
        positions[:, smoothed] = savgol_smooth(positions[:, smoothed], **smooth_options)
        record["smooth"] = {"window": settings.smooth_window, "order": settings.smooth_order}
        _warn_unsmoothed(positions[:, smoothed], [data.labels[k] for k in smoothed], data.first_frame,
                         smooth_options, path=data.path)
    if settings.lowpass is not None:
        from .guards.lowpass import describe, lowpass, parse_cutoff

        cutoff, per = parse_cutoff(settings.lowpass)
        filtered = lowpass(positions[:, columns], data.rate, cutoff, per=per, observed=~work.missing[:, columns])
        positions = positions.copy()
        positions[:, columns] = filtered.positions
        record["lowpass"] = {"asked": str(settings.lowpass), "cutoff_hz": filtered.cutoff, "per": per,
                             "used": describe(filtered.cutoff),
                             "filter": "Butterworth, 2nd order run forward and backward (zero lag, 4th-order "
                                       "response, gain 0.5 at the cutoff)"}

    output = data.with_positions(positions)
    dropped = either(either(either(rejected, held), repaired), fragments)
    if dropped is not None:  # a dropped sample filled again is written as filled, not with its old residual
        from .io.c3d import mark_refilled

        output = mark_refilled(output, dropped)
    outcome = FillOutcome(data, work, result, output, rejected, bones, record, seconds, held=held, columns=columns,
                          held_summary=summary, references=refs, repaired=repaired, fragments=fragments,
                          chosen=chosen, left=left)
    outcome.status = sample_status(outcome)
    return outcome


def _warn_unsmoothed(positions: np.ndarray, labels: list[str], first_frame: int, options: dict[str, Any], *,
                     path: str | None, shown: int = 5) -> None:
    """One warning naming the stretches (of ``positions`` (n_frames, n_smoothed, 3)) that ``--smooth`` left as they
    were, shorter than its window; nothing when every stretch was smoothed."""
    from .guards.smooth import DEFAULT_ORDER, default_window, short_runs

    window = options.get("window") or default_window(options.get("order", DEFAULT_ORDER), options.get("rate"))
    left = short_runs(positions, window)
    if not left:
        return
    items = [f"{labels[m]} {first_frame + start}-{first_frame + start + length - 1}" for m, start, length in left]
    more = f", ... {len(items) - shown} more" if len(items) > shown else ""
    warnings.warn(f"{path or 'the take'}: --smooth left {len(items)} stretch{'es' if len(items) != 1 else ''} "
                  f"shorter than its {window}-frame window unsmoothed: {', '.join(items[:shown])}{more}",
                  UserWarning, stacklevel=2)


def either(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    """``a | b`` of two (n_frames, n_markers) bool masks, either of which may be None; None when neither has a
    True."""
    if a is None or not a.any():
        return b if b is not None and b.any() else None
    return a if b is None else a | b


def sample_status(outcome: FillOutcome) -> np.ndarray:
    """What became of every sample of one fill, as :class:`~mocapfill.status.Status` codes.

    Returns
    -------
    ndarray of int8, shape (n_frames, n_markers)
        ``OBSERVED`` (returned bit-identical), ``FILLED``, ``MISSING_TOO_LONG`` / ``MISSING_EDGE`` /
        ``MISSING_NOT_CHOSEN`` (left on request), ``MISSING_DECLINED`` (the method declined the gap),
        ``MISSING_NEVER_OBSERVED`` (a marker the input never shows, left missing), ``MISSING`` (left for another
        reason), ``REJECTED_OUTLIER`` / ``REJECTED_HELD`` / ``REJECTED_FRAGMENT``
        (observed, dropped by a guard, filled again; a dropped sample left missing gets the reason it was left),
        ``REPAIRED`` (moved by the denoiser), ``SMOOTHED`` (observed, changed by ``--smooth`` / ``--lowpass``),
        ``SUSPECT`` (observed, returned as it was, in a run the default's model judged displaced),
        ``MODEL_POINT`` / ``UNLABELLED`` (every sample of such a point that was not chosen for filling).
    """
    data = outcome.data
    before = data.positions
    after = outcome.output.positions
    was_missing = data.missing
    now_missing = np.isnan(after).any(axis=2)
    status = np.full(was_missing.shape, int(Status.OBSERVED), dtype=np.int8)
    status[was_missing & ~now_missing] = Status.FILLED
    status[now_missing] = Status.MISSING
    status[now_missing & was_missing.all(axis=0)] = Status.MISSING_NEVER_OBSERVED
    with np.errstate(invalid="ignore"):
        changed = ~was_missing & ~now_missing & (after != before).any(axis=2)
    status[changed] = Status.SMOOTHED
    for mask, code in ((outcome.repaired, Status.REPAIRED), (outcome.rejected, Status.REJECTED_OUTLIER),
                       (outcome.held, Status.REJECTED_HELD), (outcome.fragments, Status.REJECTED_FRAGMENT)):
        if mask is not None:
            status[np.asarray(mask, dtype=bool) & ~now_missing] = code
    if isinstance(outcome.result.info, dict):  # the gaps a method declined (the suites' fills)
        from .methods.base import declined_mask, records_mask

        status[declined_mask(outcome.result.info, status.shape) & now_missing] = Status.MISSING_DECLINED
        kept = status == Status.OBSERVED
        status[records_mask(outcome.result.info.get("displaced"), status.shape) & kept] = Status.SUSPECT
    if outcome.left is not None:
        left = np.asarray(outcome.left)
        status[left != 0] = left[left != 0]
    chosen = np.ones(status.shape[1], dtype=bool) if outcome.chosen is None else np.asarray(outcome.chosen)
    for kind, code in (("model", Status.MODEL_POINT), ("unlabelled", Status.UNLABELLED)):
        columns = np.array([k == kind for k in data.kinds], dtype=bool) & ~chosen
        status[:, columns] = code
    return status


#: The header of a status CSV (``fill --status``).
STATUS_COLUMNS = ("frame", "marker", "status")


def write_status_csv(outcome: FillOutcome, path: str) -> None:
    """Write ``outcome.status`` as CSV (atomically): one row per frame and marker, frame-major, with the file's frame
    number, the marker's label and the status text (:data:`mocapfill.status.NAMES`)."""
    from .io.atomic import atomic_write
    from .status import NAMES

    status = outcome.status if outcome.status is not None else sample_status(outcome)
    data = outcome.data
    names = np.array([NAMES[Status(code)] for code in range(max(int(c) for c in Status) + 1)], dtype=object)
    labels = np.array([_csv_field(label) for label in data.labels], dtype=object)
    with atomic_write(path, "w", newline="") as handle:
        handle.write(",".join(STATUS_COLUMNS) + "\n")
        for start in range(0, data.n_frames, 4096):
            block = status[start:start + 4096]
            frames = np.repeat(np.arange(start, start + len(block)) + data.first_frame, data.n_markers)
            rows = [f"{f},{m},{s}\n" for f, m, s in zip(frames.tolist(), np.tile(labels, len(block)),
                                                        names[block.ravel().astype(np.intp)])]
            handle.write("".join(rows))


def _csv_field(text: str) -> str:
    """``text`` quoted for CSV when it needs to be."""
    if any(char in text for char in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def write_fill_report(outcome: FillOutcome, path: str, *, method: str, input_path: str | None,
                      output_path: str | None, smoothed: bool, jobs: int | None = None,
                      stored: str | None = None) -> None:
    """Write the JSON or HTML report (by ``path``'s extension) of one fill (``jobs``: processes an HTML page's
    plots are drawn on, as :func:`~mocapfill.report.write_report`; ``stored``: how the output's format stores the
    observed samples, :func:`mocapfill.io.storage_change`, None = exactly).

    The report's bone-length checks use the given bones, else bones estimated from the observed frames of the
    input (as bone-aware methods do), never from filled samples.
    """
    from .report import build_fill_report, write_report

    columns = outcome.columns if outcome.columns is not None else fill_columns(outcome.data)
    data, work, result = outcome.data, outcome.work, outcome.result
    dropped = either(outcome.rejected, outcome.held)
    fragments, left, chosen = outcome.fragments, outcome.left, outcome.chosen
    bones = outcome.bones
    if columns.size != data.n_markers:  # the report covers the points that were filled, not the ones kept aside
        position = {int(c): i for i, c in enumerate(columns)}
        if bones is not None:
            pairs = np.asarray(bones.pairs, dtype=np.int64)
            bones = dataclasses.replace(bones, pairs=np.vectorize(position.get)(pairs) if pairs.size else pairs)
        data, work = subset(data, columns), subset(work, columns)
        result = FillResult(result.positions[:, columns], result.filled[:, columns],
                            None if result.std is None else result.std[:, columns], result.n_iter,
                            result.converged, list(result.objective), dict(result.info))
        dropped = None if dropped is None else dropped[:, columns]
        fragments = None if fragments is None else fragments[:, columns]
        left = None if left is None else left[:, columns]
        chosen = None if chosen is None else chosen[columns]
    if bones is None:
        from .bones.boneset import estimate_bones

        bones = estimate_bones(work.positions, units=data.units, labels=data.labels)
        if len(bones) == 0:
            bones = None
    report = build_fill_report(data, result, method=method, settings=outcome.settings,
                               seconds=outcome.seconds, input_path=input_path, output_path=output_path,
                               bones=bones, rejected=dropped, smoothed=smoothed, fragments=fragments, left=left,
                               chosen=chosen, edges=outcome.settings.get("edges", "fill"),
                               observed_changed=outcome.observed_changed(), observed_stored=stored)
    report["summary"]["points"] = points_line(outcome.data)
    if outcome.held_summary is not None:
        report["summary"]["held"] = held_report(outcome.held_summary, kept=outcome.held is None)
    write_report(report, path, data=data, result=result, bones=bones, jobs=jobs)


def points_line(data: MarkerData) -> str:
    """One line on the kinds of points: ``"39 markers; 78 model points and 42 unlabelled trajectories kept
    untouched (not filled)"``."""
    counts = {kind: sum(1 for k in data.kinds if k == kind) for kind in ("marker", "model", "unlabelled")}
    aside = [f"{counts['model']} model point(s)" if counts["model"] else "",
             f"{counts['unlabelled']} unlabelled trajectory(ies)" if counts["unlabelled"] else ""]
    aside = [a for a in aside if a]
    line = f"{counts['marker']} marker(s)"
    if aside:
        line += "; " + " and ".join(aside) + " kept untouched (not filled)"
    return line


def held_report(summary: dict[str, Any], *, kept: bool) -> dict[str, Any]:
    """The fill report's record of held samples: the guard's counts and runs, its one line, and whether they were
    kept (``--keep-held``) or filled."""
    from .guards.held import held_line

    return {"line": held_line(summary) + (" (kept: --keep-held)" if kept and summary["held_samples"] else ""),
            "kept": bool(kept), **summary}
