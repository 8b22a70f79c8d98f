"""The one in-memory representation of a capture: :class:`MarkerData`."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import MocapfillError

KNOWN_UNITS = ("mm", "cm", "m")

#: What a point of a capture is.  Only ``"marker"`` points are filled and enter a fill's statistics by default; a
#: model point (computed by the capture software: segment axes, joint centres, centre of mass) and an unlabelled
#: trajectory (a reconstruction nobody labelled) are kept in the file untouched.
POINT_KINDS = ("marker", "model", "unlabelled")


@dataclass
class MarkerData:
    """Marker trajectories of one capture, plus what a writer needs to write the same file back.

    Attributes
    ----------
    positions : ndarray, shape (n_frames, n_markers, 3), float64
        Marker coordinates in ``units``; NaN marks a missing sample (all three coordinates NaN together).
    labels : list of str, length n_markers
        Unique marker labels.
    rate : float
        Frame rate in Hz.
    units : str
        Length unit of ``positions`` as found in the file ("mm", "cm" or "m"); never converted silently.
    first_frame : int
        Number of the first frame as the file counts it (C3D counts from 1).
    source_format : str or None
        "c3d", "csv", "vicon-csv", "trc", ... : the format the data was read from.
    extra : Any
        Format-specific payload kept so that a rewrite preserves everything a fill did not touch (for C3D: the
        whole parameter section, analog data, events, model outputs, storage scale).  Opaque to the core.
    path : str or None
        Where the data came from ("-" for stdin), used in messages.
    notes : list of str
        Things the reader repaired or ignored (renamed duplicate labels, truncated rows), for reports.
    kinds : list of str, length n_markers
        Each point's kind (:data:`POINT_KINDS`), as the file says; ``"marker"`` where nothing says otherwise.
    rate_range : (float, float) or None
        Where the rate was inferred from a time column: the lowest and highest rates (Hz) the times agree with to
        the precision they were written with (a caller's rate among them is no contradiction); None where the file
        states its rate.
    """

    positions: np.ndarray
    labels: list[str]
    rate: float
    units: str = "mm"
    first_frame: int = 1
    source_format: str | None = None
    extra: Any = None
    path: str | None = None
    notes: list[str] = field(default_factory=list)
    kinds: list[str] | None = None
    rate_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[2] != 3:
            raise MocapfillError(f"positions must have shape (n_frames, n_markers, 3), got {pos.shape}")
        self.positions = pos
        self.labels = [str(label) for label in self.labels]
        if len(self.labels) != pos.shape[1]:
            raise MocapfillError(f"{len(self.labels)} labels for {pos.shape[1]} markers")
        if len(set(self.labels)) != len(self.labels):
            raise MocapfillError("marker labels must be unique")
        self.rate = float(self.rate)
        kinds = ["marker"] * pos.shape[1] if self.kinds is None else [str(k) for k in self.kinds]
        if len(kinds) != pos.shape[1] or not set(kinds) <= set(POINT_KINDS):
            raise MocapfillError(f"kinds must be one of {POINT_KINDS} per point, got {kinds!r}")
        self.kinds = kinds

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def n_markers(self) -> int:
        return self.positions.shape[1]

    @property
    def duration(self) -> float:
        """Seconds from the first to one past the last frame (n_frames / rate)."""
        return self.n_frames / self.rate if self.rate > 0 else float("nan")

    @property
    def times(self) -> np.ndarray:
        """Time of each frame in seconds, shape (n_frames,), starting at 0."""
        return np.arange(self.n_frames) / self.rate

    @property
    def missing(self) -> np.ndarray:
        """Boolean mask of missing samples, shape (n_frames, n_markers)."""
        return np.isnan(self.positions).any(axis=2)

    def marker_index(self, label: str) -> int:
        """Index of the marker called ``label``; raises MocapfillError naming it when absent."""
        try:
            return self.labels.index(label)
        except ValueError:
            raise MocapfillError(f"no marker called {label!r}") from None

    def with_positions(self, positions: np.ndarray) -> "MarkerData":
        """A copy carrying new ``positions`` (same shape) and everything else unchanged."""
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != self.positions.shape:
            raise MocapfillError(f"new positions have shape {positions.shape}, expected {self.positions.shape}")
        return dataclasses.replace(self, positions=positions, notes=list(self.notes))

    # Interop (optional libraries, imported only when called: see mocapfill.interop) ---------------------------

    def to_dataframe(self):
        """pandas DataFrame: one row per frame (index = frame numbers), ``(marker, axis)`` columns, ``attrs`` with
        rate, units, first_frame."""
        from .interop import to_dataframe
        return to_dataframe(self)

    @classmethod
    def from_dataframe(cls, df, *, rate=None, units=None, first_frame=None) -> "MarkerData":
        """MarkerData from a ``(marker, axis)`` DataFrame (rate / units / first frame from ``df.attrs`` or given)."""
        from .interop import from_dataframe
        return from_dataframe(df, rate=rate, units=units, first_frame=first_frame)

    def to_xarray(self):
        """xarray DataArray in pyomeca's ``Markers`` layout: dims (axis: x, y, z, ones; channel; time)."""
        from .interop import to_xarray
        return to_xarray(self)

    @classmethod
    def from_xarray(cls, array, *, rate=None, units=None, first_frame=None) -> "MarkerData":
        """MarkerData from a pyomeca-style ``Markers`` DataArray (axis, channel, time)."""
        from .interop import from_xarray
        return from_xarray(array, rate=rate, units=units, first_frame=first_frame)

    def to_timeseries(self):
        """kineticstoolkit TimeSeries: ``data[label]`` of shape (n_frames, 4), homogeneous coordinates."""
        from .interop import to_timeseries
        return to_timeseries(self)

    @classmethod
    def from_timeseries(cls, ts, *, rate=None, units=None, first_frame=None) -> "MarkerData":
        """MarkerData from a kineticstoolkit TimeSeries of markers."""
        from .interop import from_timeseries
        return from_timeseries(ts, rate=rate, units=units, first_frame=first_frame)
