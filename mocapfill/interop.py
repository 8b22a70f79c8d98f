"""Hand a :class:`MarkerData` to the Python biomechanics stack and take it back: pandas, xarray, kineticstoolkit.

Every conversion keeps the positions (NaN = missing), the labels, the rate, the units and the first frame, so that
``from_x(to_x(data))`` gives the same capture back.  The libraries are optional (``pip install mocapfill[interop]``)
and imported only when a conversion is called; importing mocapfill never imports them.

- **pandas** (:func:`to_dataframe`): one row per frame, index ``frame`` (the file's frame numbers), columns a
  ``(marker, axis)`` MultiIndex with axes ``x``, ``y``, ``z``; ``df.attrs`` holds ``rate``, ``units``,
  ``first_frame`` (pandas keeps ``attrs`` through copies and slices, not through every operation: give ``rate=`` /
  ``units=`` to :func:`from_dataframe` when they were lost).
- **xarray** in pyomeca's ``Markers`` layout (:func:`to_xarray`): dims ``("axis", "channel", "time")``, axis
  coordinates ``x, y, z, ones`` (homogeneous coordinates: 4 rows, the last 1), channel = labels, time in seconds
  from 0, name ``"markers"``, attrs ``rate``, ``units``, ``first_frame``, ``last_frame``.  ``first_frame`` is the
  file's own count (C3D counts from 1; pyomeca's C3D reader stores ezc3d's 0-based number).
- **kineticstoolkit** (:func:`to_timeseries`): a ``TimeSeries`` with time in seconds from 0 and one data key per
  marker holding an ``(n_frames, 4)`` array of homogeneous coordinates (x, y, z, 1; a missing sample is NaN in all
  four), ``info[label]["Unit"]`` = the units and ``info["Time"]["FirstFrame"]`` = the first frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import InputError
from .markers import KNOWN_UNITS, MarkerData

__all__ = ["to_dataframe", "from_dataframe", "to_xarray", "from_xarray", "to_timeseries", "from_timeseries"]

_AXES = ("x", "y", "z")


def _need(module: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(f"this conversion needs {module}: pip install 'mocapfill[interop]'") from None


def _check_units(units: Any, what: str) -> str:
    units = str(units)
    if units not in KNOWN_UNITS:
        raise InputError(f"{what}: units {units!r} are not one of {', '.join(KNOWN_UNITS)} (give units=)")
    return units


def _rate_from_time(time: np.ndarray, what: str) -> float:
    """Rate from an evenly spaced time vector (s); NaN for fewer than two frames."""
    time = np.asarray(time, dtype=np.float64)
    if time.size < 2:
        return float("nan")
    steps = np.diff(time)
    step = float(np.median(steps))
    if not np.all(steps > 0) or np.max(np.abs(steps - step)) > 1e-6 * step + 1e-12:
        raise InputError(f"{what}: the time vector is not evenly spaced; give rate=")
    rate = (time.size - 1) / (time[-1] - time[0])
    # 511 steps of 1 / 200 span 2.5549999999999997 s: the rate meant is 200, not 199.99999999999983
    return float(round(rate)) if abs(rate - round(rate)) < 1e-9 * rate else float(rate)


def _pick(given, stored, what: str, name: str):
    if given is not None:
        return given
    if stored is None:
        raise InputError(f"{what}: no {name} (give {name}=)")
    return stored


def _result(positions, labels, rate, units, first_frame, source) -> MarkerData:
    rate = float(rate)
    if not np.isfinite(rate) or rate <= 0:
        raise InputError(f"{source}: frame rate {rate:g} is not a positive number (give rate=)")
    positions = np.array(positions, dtype=np.float64)
    positions[np.isnan(positions).any(axis=2)] = np.nan
    return MarkerData(positions, list(labels), rate, units, int(first_frame), None, None, source, [])


# pandas ---------------------------------------------------------------------------------------------------------

def to_dataframe(data: MarkerData):
    """``pandas.DataFrame`` (n_frames rows, 3 * n_markers columns ``(marker, axis)``), index = frame numbers."""
    pd = _need("pandas")
    columns = pd.MultiIndex.from_product([list(data.labels), list(_AXES)], names=["marker", "axis"])
    index = pd.RangeIndex(data.first_frame, data.first_frame + data.n_frames, name="frame")
    df = pd.DataFrame(data.positions.reshape(data.n_frames, 3 * data.n_markers).copy(), index=index, columns=columns)
    df.attrs.update(rate=float(data.rate), units=data.units, first_frame=int(data.first_frame))
    return df


def from_dataframe(df, *, rate: float | None = None, units: str | None = None,
                   first_frame: int | None = None) -> MarkerData:
    """MarkerData from a ``(marker, axis)`` column DataFrame (one row per frame).

    ``rate`` / ``units`` / ``first_frame`` default to ``df.attrs`` (as :func:`to_dataframe` writes them); the first
    frame falls back to the first index value when the index is integer, else 1.  Raises InputError naming what is
    missing or malformed.
    """
    what = "DataFrame"
    if getattr(df.columns, "nlevels", 1) != 2:
        raise InputError(f"{what}: columns must be a (marker, axis) MultiIndex")
    labels: list[str] = []
    for marker in df.columns.get_level_values(0):
        if marker not in labels:
            labels.append(marker)
    try:
        frame = df.loc[:, [(m, a) for m in labels for a in _AXES]]
    except KeyError:
        lower = {(m, str(a).lower()): (m, a) for m, a in df.columns}
        missing = [(m, a) for m in labels for a in _AXES if (m, a) not in lower]
        if missing:
            raise InputError(f"{what}: no {missing[0][1]!r} column for marker {missing[0][0]!r}") from None
        frame = df.loc[:, [lower[(m, a)] for m in labels for a in _AXES]]
    values = frame.to_numpy(dtype=np.float64, na_value=np.nan).reshape(len(df), len(labels), 3)
    attrs = dict(getattr(df, "attrs", {}) or {})
    if first_frame is None:
        first_frame = attrs.get("first_frame")
    if first_frame is None:
        index = np.asarray(df.index)
        first_frame = int(index[0]) if index.size and np.issubdtype(index.dtype, np.integer) else 1
    units = _check_units(_pick(units, attrs.get("units"), what, "units"), what)
    rate = _pick(rate, attrs.get("rate"), what, "rate")
    return _result(values, [str(lab) for lab in labels], rate, units, first_frame, what)


# xarray (pyomeca's Markers layout) --------------------------------------------------------------------------------

def to_xarray(data: MarkerData):
    """``xarray.DataArray`` (axis: 4, channel: n_markers, time: n_frames) in pyomeca's ``Markers`` layout."""
    xr = _need("xarray")
    values = np.ones((4, data.n_markers, data.n_frames))
    values[:3] = data.positions.transpose(2, 1, 0)
    attrs = {"rate": float(data.rate), "units": data.units, "first_frame": int(data.first_frame),
             "last_frame": int(data.first_frame + data.n_frames - 1)}
    return xr.DataArray(values, dims=("axis", "channel", "time"), name="markers", attrs=attrs,
                        coords={"axis": ["x", "y", "z", "ones"], "channel": list(data.labels),
                                "time": data.times.copy()})


def from_xarray(array, *, rate: float | None = None, units: str | None = None,
                first_frame: int | None = None) -> MarkerData:
    """MarkerData from a DataArray with dims ``axis`` (x, y, z[, ones]), ``channel`` and ``time`` (pyomeca's).

    ``rate`` defaults to ``attrs["rate"]``, else the time coordinate; ``units`` to ``attrs["units"]``;
    ``first_frame`` to ``attrs["first_frame"]``, else 1.
    """
    what = "DataArray"
    dims = set(array.dims)
    if not {"axis", "channel", "time"} <= dims or len(dims) != 3:
        raise InputError(f"{what}: dims must be ('axis', 'channel', 'time'), got {tuple(array.dims)}")
    array = array.transpose("axis", "channel", "time")
    if "axis" in array.coords:
        names = [str(a).lower() for a in array.coords["axis"].values]
        try:
            rows = [names.index(a) for a in _AXES]
        except ValueError:
            raise InputError(f"{what}: the axis coordinate lacks x, y or z (has {names})") from None
    elif array.sizes["axis"] in (3, 4):
        rows = [0, 1, 2]
    else:
        raise InputError(f"{what}: {array.sizes['axis']} axis rows (expected x, y, z[, ones])")
    values = np.asarray(array.values, dtype=np.float64)[rows]  # (3, n_markers, n_frames)
    n_markers = values.shape[1]
    if "channel" in array.coords:
        labels = [str(c) for c in array.coords["channel"].values]
    else:
        labels = [f"M{k + 1:03d}" for k in range(n_markers)]
    attrs = dict(array.attrs)
    if rate is None:
        rate = attrs.get("rate")
    if rate is None and "time" in array.coords:
        rate = _rate_from_time(array.coords["time"].values, what)
    units = _check_units(_pick(units, attrs.get("units"), what, "units"), what)
    rate = _pick(rate, None, what, "rate")
    if first_frame is None:
        first_frame = attrs.get("first_frame", 1)
    return _result(values.transpose(2, 1, 0), labels, rate, units, first_frame, what)


# kineticstoolkit ------------------------------------------------------------------------------------------------

def to_timeseries(data: MarkerData):
    """``kineticstoolkit.TimeSeries``: one ``(n_frames, 4)`` homogeneous-coordinate array per marker."""
    ktk = _need("kineticstoolkit")
    ts = ktk.TimeSeries(time=data.times.copy())
    missing = data.missing
    for k, label in enumerate(data.labels):
        values = np.ones((data.n_frames, 4))
        values[:, :3] = data.positions[:, k]
        values[missing[:, k]] = np.nan
        ts.data[label] = values
        ts.add_info(label, "Unit", data.units, in_place=True)
    ts.add_info("Time", "FirstFrame", int(data.first_frame), in_place=True)
    return ts


def from_timeseries(ts, *, rate: float | None = None, units: str | None = None,
                    first_frame: int | None = None) -> MarkerData:
    """MarkerData from a kineticstoolkit TimeSeries whose data keys are markers (``(n, 4)`` or ``(n, 3)`` arrays).

    ``units`` defaults to the markers' ``Unit`` info (all must agree); ``rate`` to the time vector; ``first_frame``
    to ``info["Time"]["FirstFrame"]``, else ``round(time[0] * rate) + 1`` (kineticstoolkit's C3D reader starts the
    time at the C3D first frame, counted from 0).
    """
    what = "TimeSeries"
    labels = list(ts.data)
    if not labels:
        raise InputError(f"{what}: no data keys (markers)")
    time = np.asarray(ts.time, dtype=np.float64)
    arrays = []
    for label in labels:
        values = np.asarray(ts.data[label], dtype=np.float64)
        if values.ndim != 2 or values.shape[0] != time.size or values.shape[1] not in (3, 4):
            raise InputError(f"{what}: data {label!r} has shape {values.shape}; expected ({time.size}, 4)")
        arrays.append(values[:, :3])
    info = getattr(ts, "info", {}) or {}
    if units is None:
        found = {str(info.get(label, {}).get("Unit")) for label in labels if info.get(label, {}).get("Unit")}
        if len(found) > 1:
            raise InputError(f"{what}: markers in different units ({', '.join(sorted(found))}); give units=")
        units = found.pop() if found else None
    units = _check_units(_pick(units, None, what, "units"), what)
    if rate is None:
        rate = _rate_from_time(time, what)
    if first_frame is None:
        first_frame = info.get("Time", {}).get("FirstFrame")
    if first_frame is None:
        first_frame = int(round(time[0] * rate)) + 1 if time.size and np.isfinite(rate) else 1
    return _result(np.stack(arrays, axis=1), [str(lab) for lab in labels], rate, units, first_frame, what)
