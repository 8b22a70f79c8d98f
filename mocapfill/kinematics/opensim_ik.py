"""OpenSim inverse kinematics: the InverseKinematicsTool on a TRC mocapfill writes, and the IK solver per frame.

``opensim`` (the extra ``mocapfill[opensim]``) is imported inside the functions that need it.  OpenSim logs to
stdout and to ``opensim.log`` in the working directory; every call here runs with its logger off, no log file,
and the process's stdout (file descriptor 1) sent to the null device, so that stdout stays data only.

Units: OpenSim models are in metres; the TRC carries the capture's units in its header and the tool converts.
Translational coordinates and positions come back in the capture's units, rotational coordinates in degrees.
Time: frame ``k`` of the capture is at ``k / rate`` seconds (the TRC's Time column), and a setup's ``time_range`` is
read on that clock (0 s at the capture's first frame).
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from ..errors import InputError, MethodError, MocapfillError
from ..markers import MarkerData
from ..units import length_factor
from .angles import IKAngles

#: What a user installs to get OpenSim (named in every "not installed" message).
EXTRA = "mocapfill[opensim]"
#: The IK solver's default accuracy, as OpenSim's own tool sets it.
DEFAULT_ACCURACY = 1e-5
#: Frames with fewer observed model markers than this are not solved: a pose needs three points per rigid body to be
#: determined, and a whole model a few more; their coordinates are interpolated in time from the solved frames.
MIN_MARKERS = 4


def require_opensim():
    """The ``opensim`` module, or a one-line :class:`MocapfillError` naming the extra to install."""
    try:
        import opensim  # noqa: PLC0415
    except (ImportError, OSError) as exc:
        raise MocapfillError(f"OpenSim is not available ({str(exc).splitlines()[0] if str(exc) else 'not installed'});"
                             f" install the extra: pip install '{EXTRA}'") from None
    return opensim


@contextlib.contextmanager
def quiet(osim) -> Iterator[None]:
    """Run OpenSim without a log file and without writing to stdout (its model summaries go to ``std::cout``).

    The logger's level is restored afterwards; its file sink (``opensim.log`` in the working directory) stays off.
    """
    level = osim.Logger.getLevelString()
    osim.Logger.setLevelString("off")
    osim.Logger.removeFileSink()
    sys.stdout.flush()
    libc = ctypes.CDLL(None)
    saved = os.dup(1)
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    try:
        yield
    finally:
        osim.Logger.setLevelString(level)  # OpenSim says so on stdout: while it is still the null device
        libc.fflush(None)
        os.dup2(saved, 1)
        os.close(saved)
        os.close(null)


@dataclass(frozen=True)
class IKSetup:
    """An IK setup as mocapfill uses it (picklable: paths and numbers only).

    Attributes
    ----------
    setup : str or None
        Absolute path of the InverseKinematicsTool XML (None: a model alone, every marker of weight 1).
    model : str
        Absolute path of the scaled model (.osim).
    time_range : (float, float) or None
        The setup's time range in seconds on the capture's clock; None = the whole capture.
    weights : dict of str -> float
        The marker tasks the setup applies, with their weights (empty: every model marker, weight 1).
    constraint_weight : float
    accuracy : float
    """

    setup: str | None
    model: str
    time_range: tuple[float, float] | None = None
    weights: dict[str, float] = field(default_factory=dict)
    constraint_weight: float = math.inf
    accuracy: float = DEFAULT_ACCURACY


def _resolve(path: str, base: str) -> str:
    path = path.strip()
    return path if os.path.isabs(path) else os.path.normpath(os.path.join(base, path))


def load_setup(setup: str | os.PathLike | None, model: str | os.PathLike | None = None) -> IKSetup:
    """Read an InverseKinematicsTool setup XML; ``model`` (a path) overrides the model file it names.

    Relative paths in the setup are taken from the setup's folder.  Raises :class:`InputError` in one line when the
    setup or the model is missing or unreadable, naming ``--ik-model`` when the setup names no model.
    """
    if setup is None:
        if model is None:
            raise InputError("IK needs a model: give --ik-model MODEL.osim")
        path = os.path.abspath(os.fspath(model))
        if not os.path.isfile(path):
            raise InputError(f"{model}: no such model file")
        return IKSetup(None, path)
    osim = require_opensim()
    setup = os.path.abspath(os.fspath(setup))
    if not os.path.isfile(setup):
        raise InputError(f"{setup}: no such IK setup file")
    with quiet(osim):
        try:
            tool = osim.InverseKinematicsTool(setup)
        except RuntimeError as exc:
            raise InputError(f"{setup}: not an OpenSim IK setup ({_first_line(exc)})") from None
        base = os.path.dirname(setup)
        if model is None:
            named = tool.get_model_file().strip()
            if not named or named == "Unassigned":
                raise InputError(f"{setup}: names no model file; give --ik-model MODEL.osim")
            model_path = _resolve(named, base)
            if not os.path.isfile(model_path):
                raise InputError(f"{setup}: its model {named!r} is not at {model_path}; give --ik-model MODEL.osim")
        else:
            model_path = os.path.abspath(os.fspath(model))
            if not os.path.isfile(model_path):
                raise InputError(f"{model}: no such model file")
        weights = {}
        tasks = tool.getIKTaskSet()
        for i in range(tasks.getSize()):
            task = osim.IKMarkerTask.safeDownCast(tasks.get(i))
            if task is not None and task.getApply():
                weights[task.getName()] = float(task.getWeight())
        start, end = float(tool.getStartTime()), float(tool.getEndTime())
        time_range = (start, end) if math.isfinite(start) and math.isfinite(end) and end > start else None
        return IKSetup(setup, model_path, time_range, weights, float(tool.get_constraint_weight()),
                       float(tool.get_accuracy()))


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def coordinate_kinds(osim, model) -> dict[str, str]:
    """Per coordinate of ``model``: "rotational", "translational", "coupled" or "locked" (locked by default)."""
    kinds = {}
    coords = model.getCoordinateSet()
    for i in range(coords.getSize()):
        c = coords.get(i)
        motion = c.getMotionType()
        kind = {osim.Coordinate.Rotational: "rotational", osim.Coordinate.Translational: "translational"}.get(
            motion, "coupled")
        kinds[c.getName()] = "locked" if c.getDefaultLocked() else kind
    return kinds


def _ik_frames(n_frames: int, rate: float, time_range: tuple[float, float] | None) -> tuple[int, int]:
    """First and last capture frame (inclusive) the setup's time range covers, clipped to the capture."""
    if time_range is None:
        return 0, n_frames - 1
    first = max(0, int(math.ceil(time_range[0] * rate - 1e-6)))
    last = min(n_frames - 1, int(math.floor(time_range[1] * rate + 1e-6)))
    if last < first:
        raise InputError(f"the IK setup's time range {time_range[0]:g}-{time_range[1]:g} s holds no frame of the "
                         f"capture (0-{(n_frames - 1) / rate:g} s)")
    return first, last


def read_mot(path: str) -> tuple[list[str], np.ndarray]:
    """Column names and values (rows, columns) of an OpenSim .mot / .sto file."""
    with open(path, encoding="utf-8", errors="replace") as handle:
        lines = handle.read().splitlines()
    try:
        end = next(i for i, line in enumerate(lines) if line.strip().lower() == "endheader")
    except StopIteration:
        raise MethodError(f"{path}: OpenSim wrote no 'endheader'") from None
    names = [n.strip() for n in lines[end + 1].split("\t")]
    rows = [[float(v) for v in line.split()] for line in lines[end + 2:] if line.strip()]
    return names, np.array(rows, dtype=float).reshape(len(rows), len(names))


def run_ik(setup: IKSetup, data: MarkerData) -> IKAngles:
    """OpenSim's InverseKinematicsTool on ``data`` (positions (n_frames, n_markers, 3), NaN = missing).

    The capture is written as TRC by :func:`mocapfill.io.write` (missing samples as empty cells: OpenSim leaves
    those markers out of the frames where they are missing), the tool runs with the setup's tasks and weights on its
    time range clipped to the capture, and the coordinates it writes are read back.

    Returns
    -------
    IKAngles
        values (T, C): degrees for rotational coordinates, the capture's units for translational ones.
    """
    osim = require_opensim()
    from ..io import write

    if not data.rate or not math.isfinite(data.rate):
        raise InputError(f"{data.path}: IK needs the capture's frame rate (give --rate)")
    first, last = _ik_frames(data.n_frames, data.rate, setup.time_range)
    light = MarkerData(data.positions, list(data.labels), data.rate, data.units, data.first_frame)
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="mocapfill-ik-") as tmp, quiet(osim):
        trc = os.path.join(tmp, "markers.trc")
        write(light, trc, format="trc")
        tool = osim.InverseKinematicsTool(setup.setup) if setup.setup else osim.InverseKinematicsTool()
        if setup.setup is None:
            tool.set_constraint_weight(setup.constraint_weight)
            tool.set_accuracy(setup.accuracy)
        else:
            named = tool.get_coordinate_file().strip()
            if named and named != "Unassigned":
                tool.set_coordinate_file(_resolve(named, os.path.dirname(setup.setup)))
        model = osim.Model(setup.model)
        tool.setModel(model)
        tool.set_marker_file(trc)
        tool.setStartTime(first / data.rate)
        tool.setEndTime(last / data.rate)
        motion = os.path.join(tmp, "ik.mot")
        tool.set_output_motion_file(motion)
        tool.setResultsDir(tmp)
        tool.set_report_errors(False)
        tool.set_report_marker_locations(False)
        try:
            ok = tool.run()
        except RuntimeError as exc:
            raise MethodError(f"OpenSim IK failed on {data.path or 'the capture'}: {_first_line(exc)}") from None
        if not ok or not os.path.isfile(motion):
            raise MethodError(f"OpenSim IK failed on {data.path or 'the capture'}")
        names, table = read_mot(motion)
        kinds = coordinate_kinds(osim, model)
    seconds = time.perf_counter() - started
    frames = np.rint(table[:, 0] * data.rate).astype(int)
    names = names[1:]
    values = table[:, 1:].copy()
    to_units = length_factor("m", data.units)
    kind_list = [kinds.get(n, "coupled") for n in names]
    for c, kind in enumerate(kind_list):
        if kind == "translational":
            values[:, c] *= to_units
    return IKAngles(names, kind_list, values, frames, seconds)


@dataclass
class Tracked:
    """The IK solver run frame by frame on observed markers (:func:`track`).

    Attributes
    ----------
    coordinates : list of str
        Model coordinate names (C).
    q : ndarray, shape (n_frames, C)
        Coordinate values (radians, metres) per frame; frames not solved are interpolated in time.
    solved : ndarray of bool, shape (n_frames,)
        Frames IK solved (at least :data:`MIN_MARKERS` observed model markers).
    bodies : list of str
        Body names (B).
    body_rotation : ndarray, shape (n_frames, B, 3, 3)
        Each body's orientation in ground (columns: its axes).
    body_origin : ndarray, shape (n_frames, B, 3)
        Each body's origin in ground, in the capture's units.
    marker_body : ndarray of int, shape (n_markers,)
        Per capture marker the index of the body its model marker sits on, -1 when the model has no such marker.
    model_markers : ndarray, shape (n_frames, n_markers, 3)
        The model marker of each capture marker in ground, capture units (NaN where the model has none).
    residual : ndarray, shape (n_frames,)
        RMS over the observed model markers of |observed - model| (capture units; NaN on frames not solved).
    seconds : float
    """

    coordinates: list[str]
    q: np.ndarray
    solved: np.ndarray
    bodies: list[str]
    body_rotation: np.ndarray
    body_origin: np.ndarray
    marker_body: np.ndarray
    model_markers: np.ndarray
    residual: np.ndarray
    seconds: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)


def _vec(v) -> list[float]:
    return [v.get(0), v.get(1), v.get(2)]


def _support(osim, model, marker_bodies: dict[str, str]) -> dict[str, set[str]]:
    """Per coordinate, the model markers on the bodies its joint moves (the joint's child and every body below)."""
    joints = model.getJointSet()
    children: dict[str, list[str]] = {}
    coord_child: dict[str, str] = {}
    for i in range(joints.getSize()):
        j = joints.get(i)
        parent = j.getParentFrame().findBaseFrame().getName()
        child = j.getChildFrame().findBaseFrame().getName()
        children.setdefault(parent, []).append(child)
        for k in range(j.numCoordinates()):
            coord_child[j.get_coordinates(k).getName()] = child
    out = {}
    for name, child in coord_child.items():
        below, stack = set(), [child]
        while stack:
            b = stack.pop()
            if b not in below:
                below.add(b)
                stack.extend(children.get(b, []))
        out[name] = {m for m, b in marker_bodies.items() if b in below}
    return out


def _interpolate_rows(values: np.ndarray, good: np.ndarray) -> np.ndarray:
    """Linear interpolation in time of the rows of ``values`` (T, C) where ``good`` (T,) is False; ends held."""
    out = values.copy()
    if good.all() or not good.any():
        return out
    t = np.arange(len(values))
    for c in range(values.shape[1]):
        out[~good, c] = np.interp(t[~good], t[good], values[good, c])
    return out


def track(model_path: str | os.PathLike, positions: np.ndarray, labels: list[str], *, units: str = "mm",
          rate: float | None = None, weights: dict[str, float] | None = None,
          constraint_weight: float = math.inf, accuracy: float = DEFAULT_ACCURACY) -> Tracked:
    """IK on the observed markers of every frame with OpenSim's InverseKinematicsSolver.

    Parameters
    ----------
    model_path : path
        A scaled OpenSim model whose markers are named like ``labels``.
    positions : ndarray, shape (n_frames, n_markers, 3)
        The capture in ``units``, NaN = missing (a missing marker is left out of that frame's IK).
    labels : list of str
    weights : dict of str -> float, optional
        Marker weights (the IK setup's tasks: only these markers are used); default every model marker, weight 1.

    Frames with fewer than :data:`MIN_MARKERS` observed markers are not solved, and a coordinate none of whose
    markers (on the bodies it moves) is observed in a frame is not trusted there: both take values interpolated in
    time from the frames where they were determined.
    """
    osim = require_opensim()
    positions = np.asarray(positions, dtype=float)
    n_frames, n_markers, _ = positions.shape
    rate = float(rate) if rate and math.isfinite(rate) and rate > 0 else 1.0
    to_m = length_factor(units, "m")
    from_m = 1.0 / to_m
    started = time.perf_counter()
    with quiet(osim):
        try:
            model = osim.Model(os.fspath(model_path))
            state = model.initSystem()
        except RuntimeError as exc:
            raise InputError(f"{model_path}: OpenSim cannot load this model ({_first_line(exc)})") from None
        markerset = model.getMarkerSet()
        model_names = [markerset.get(i).getName() for i in range(markerset.getSize())]
        marker_bodies = {n: markerset.get(n).getParentFrame().findBaseFrame().getName() for n in model_names}
        usable = [lab for lab in labels if lab in marker_bodies and (weights is None or weights.get(lab, 0) > 0)]
        if not usable:
            raise MethodError(f"{model_path}: none of the capture's markers is a model marker "
                              f"(the model has {', '.join(model_names[:5])}{', ...' if len(model_names) > 5 else ''})")
        index = {lab: k for k, lab in enumerate(labels)}
        columns = [index[lab] for lab in usable]
        observed = ~np.isnan(positions).any(axis=2)
        times = np.arange(n_frames) / rate
        table = osim.TimeSeriesTableVec3()
        table.setColumnLabels(list(usable))
        metres = positions[:, columns] * to_m
        for t in range(n_frames):
            row = osim.RowVectorVec3(len(usable))
            for j in range(len(usable)):
                x = metres[t, j]
                row[j] = osim.Vec3(float(x[0]), float(x[1]), float(x[2]))
            table.appendRow(float(times[t]), row)
        marker_weights = osim.SetMarkerWeights()
        for lab in usable:
            marker_weights.cloneAndAppend(osim.MarkerWeight(lab, float(1.0 if weights is None else weights[lab])))
        reference = osim.MarkersReference(table, marker_weights)
        solver = osim.InverseKinematicsSolver(model, reference, osim.SimTKArrayCoordinateReference(),
                                              float(constraint_weight))
        solver.setAccuracy(float(accuracy))

        coords = model.getCoordinateSet()
        names = [coords.get(i).getName() for i in range(coords.getSize())]
        locked = np.array([coords.get(i).getDefaultLocked() for i in range(coords.getSize())])
        bodyset = model.getBodySet()
        bodies = [bodyset.get(i).getName() for i in range(bodyset.getSize())]
        enough = observed[:, columns].sum(axis=1) >= min(MIN_MARKERS, len(usable))
        q = np.full((n_frames, len(names)), np.nan)
        assembled = False
        for t in np.flatnonzero(enough):
            state.setTime(float(times[t]))
            try:
                if not assembled:
                    solver.assemble(state)
                    assembled = True
                else:
                    solver.track(state)
            except RuntimeError:
                enough[t] = False
                continue
            q[t] = [coords.get(i).getValue(state) for i in range(len(names))]
        if not enough.any():
            raise MethodError(f"{model_path}: IK solved no frame (fewer than {MIN_MARKERS} model markers observed "
                              "in every frame)")

        # Coordinates none of whose markers is seen in a frame keep IK's last value there: interpolate them instead.
        support = _support(osim, model, {lab: marker_bodies[lab] for lab in usable})
        seen = {lab: observed[:, index[lab]] for lab in usable}
        trusted = np.repeat(enough[:, None], len(names), axis=1)
        for c, name in enumerate(names):
            marks = support.get(name)
            if marks:
                trusted[:, c] &= np.any([seen[m] for m in marks], axis=0)
        final = q.copy()
        for c in range(len(names)):
            good = trusted[:, c] & np.isfinite(q[:, c])
            if good.any():
                final[:, c] = _interpolate_rows(q[:, [c]], good)[:, 0]
            else:
                final[:, c] = _interpolate_rows(q[:, [c]], np.isfinite(q[:, c]))[:, 0]

        # Pose every frame at the final coordinates; read bodies and model markers.
        has_constraints = model.getConstraintSet().getSize() > 0
        rotation = np.zeros((n_frames, len(bodies), 3, 3))
        origin = np.zeros((n_frames, len(bodies), 3))
        model_markers = np.full((n_frames, n_markers, 3), np.nan)
        marker_objs = [(index[lab], markerset.get(lab)) for lab in labels if lab in marker_bodies]
        for t in range(n_frames):
            state.setTime(float(times[t]))
            for c in range(len(names)):
                if not locked[c]:
                    coords.get(c).setValue(state, float(final[t, c]), False)
            if has_constraints:
                model.assemble(state)
            model.realizePosition(state)
            for b in range(len(bodies)):
                tr = bodyset.get(b).getTransformInGround(state)
                rot = tr.R()
                rotation[t, b] = [[rot.get(i, j) for j in range(3)] for i in range(3)]
                origin[t, b] = _vec(tr.p())
            for k, marker in marker_objs:
                model_markers[t, k] = _vec(marker.getLocationInGround(state))
        body_index = {b: i for i, b in enumerate(bodies)}
        marker_body = np.array([body_index.get(marker_bodies.get(lab, ""), -1) for lab in labels], dtype=int)
    origin *= from_m
    model_markers *= from_m
    diff = np.where(observed[:, columns, None], positions[:, columns] - model_markers[:, columns], np.nan)
    with np.errstate(invalid="ignore"):
        sq = np.nansum(diff ** 2, axis=2)
        count = observed[:, columns].sum(axis=1)
        residual = np.where(enough & (count > 0), np.sqrt(sq.sum(axis=1) / np.maximum(count, 1)), np.nan)
    return Tracked(names, final, enough, bodies, rotation, origin, marker_body, model_markers, residual,
                   time.perf_counter() - started,
                   {"markers_used": len(usable), "frames_solved": int(enough.sum()),
                    "coordinates_interpolated": int((~trusted & enough[:, None]).sum())})
