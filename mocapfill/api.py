"""The Python entry point for filling: :func:`fill`."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np

from .errors import MethodError
from .markers import MarkerData
from .methods import DEFAULT_METHOD, get_method
from .methods.base import FillResult, check_frames, check_positions

#: Keywords that describe the data rather than tune a method; passed only to methods that accept them.
CONTEXT_KEYS = ("units", "rate", "labels")


def fill(data: MarkerData | np.ndarray, method: str = DEFAULT_METHOD, *, max_gap: int | str | None = None,
         edges: str = "fill", markers: str | list[str] | None = None, exclude: str | list[str] | None = None,
         **options: Any) -> FillResult:
    """Fill the gaps of ``data`` with ``method``.

    Parameters
    ----------
    data : MarkerData or ndarray of shape (n_frames, n_markers, 3)
        The capture; NaN = missing.  Of a MarkerData only the points of kind "marker" (and those ``markers``
        names exactly) inform the fill and are filled; model points and unlabelled trajectories come back
        untouched.  For a bare array, pass ``units=`` (default "mm") and ``rate=`` if the method uses them.
    method : str
        A name from :data:`mocapfill.methods.METHODS`.
    max_gap : int, str or None
        Gaps longer than this stay missing: frames (``40``) or seconds (``"0.5s"``, needs the rate).
    edges : "fill" or "leave"
        Whether gaps touching the first or last frame are filled.
    markers, exclude : str (comma-separated) or list of str, or None
        Labels or shell patterns (``"L*,R*"``) of the markers to fill / not to fill (see
        :func:`mocapfill.pipeline.select_markers`; a bare array needs ``labels=``).  Every marker still informs
        the fill.  The stretches left missing by these four are listed in ``result.info["left_missing"]``.
    **options
        Method options (``hidden``, ``max_iter``, ``tol``, ``seed``, ``bones``, ``progress``, ...).  An option the
        method does not take is ignored with a warning, so one command line can drive any method.
        ``reference=[...]``: reference takes of the same marker set (MarkerData or paths; a single one is fine),
        matched by label and weighed by :func:`mocapfill.references.prepare` (``data`` must then be a MarkerData);
        a method that takes ``reference_frames`` (``auto``, ``pca``) trains on them, and ``result.info
        ["references"]`` says how much each was used.

    Returns
    -------
    FillResult
        ``positions`` of shape (n_frames, n_markers, 3) with observed samples bit-identical to the input.  When
        ``data`` is a MarkerData, ``result.info["data"]`` is not set; use ``data.with_positions(result.positions)``
        (or :func:`fill_data`) for a writable copy.
    """
    if isinstance(data, MarkerData) and any(kind != "marker" for kind in data.kinds):
        # Only the markers (and points --markers names exactly) inform the fill; model points and unlabelled
        # trajectories come back as they were (the pipeline's rule: mocapfill.pipeline.fill_columns).
        from .pipeline import fill_columns, select_markers, subset, widen_result

        chosen = None
        if markers is not None or exclude is not None:
            chosen = select_markers(data.labels, data.kinds, markers, exclude, path=data.path)
        columns = fill_columns(data, chosen)
        if columns.size == 0:
            return FillResult(data.positions.copy(), np.zeros(data.positions.shape[:2], dtype=bool),
                              info={"method": method})
        # the view's columns are all filled as markers; the choice is handed on as exact names
        names = None if chosen is None else [data.labels[k] for k in np.flatnonzero(chosen)]
        view = dataclasses.replace(subset(data, columns), kinds=None)
        result = fill(view, method, max_gap=max_gap, edges=edges, markers=names, **options)
        return widen_result(result, columns, data.positions, data.labels)
    spec = get_method(method)
    func = spec.load()
    accepted = spec.parameters()
    if isinstance(data, MarkerData):
        context = {"units": data.units, "rate": data.rate, "labels": list(data.labels)}
        positions = data.positions
    else:
        context = {"units": options.pop("units", "mm"), "rate": options.pop("rate", None),
                   "labels": options.pop("labels", None)}
        positions = data
        rate = context["rate"]
        if rate is not None and not (isinstance(rate, (int, float, np.number)) and np.isfinite(rate) and rate > 0):
            # (a method would otherwise assume its default rate, in silence)
            raise MethodError(f"rate={rate!r} is not a positive frame rate in Hz")
    kwargs = {k: v for k, v in context.items() if k in accepted and v is not None}
    ignored = []
    for key, value in options.items():
        if key in accepted:
            kwargs[key] = value
        elif value is not None:
            ignored.append(key)
    refs = []
    reference = options.get("reference")
    if reference is not None:
        ignored = [key for key in ignored if key != "reference"]
        kwargs.pop("reference", None)
        if not isinstance(data, MarkerData):
            raise MethodError("reference= needs the capture as a MarkerData (labels and units to match them by)")
        from .references import method_options, prepare

        refs = prepare(data, reference if isinstance(reference, (list, tuple)) else [reference])
        kwargs.update(method_options(refs, method, accepted))
    if ignored:
        warnings.warn(f"method {method!r} ignores option(s): {', '.join(sorted(ignored))}", UserWarning,
                      stacklevel=2)
    name = data.path if isinstance(data, MarkerData) else None
    positions = check_positions(positions, name=name, labels=context["labels"])
    check_frames(positions.shape[0], name=name)
    limits = None
    if max_gap is not None or edges != "fill" or markers is not None or exclude is not None:
        from .guards.limits import check_edges, parse_max_gap
        from .pipeline import select_markers

        check_edges(edges, name="edges")
        n_markers = positions.shape[1]
        labels = context["labels"] if context["labels"] is not None else [f"M{k + 1}" for k in range(n_markers)]
        kinds = data.kinds if isinstance(data, MarkerData) else None
        path = data.path if isinstance(data, MarkerData) else None
        limits = {"max_gap": None if max_gap is None else parse_max_gap(max_gap, context["rate"], name="max_gap"),
                  "edges": edges, "chosen": select_markers(labels, kinds, markers, exclude, path=path)}
    result = func(positions, **kwargs)
    if not isinstance(result, FillResult):  # pragma: no cover - a registry bug, not a user error
        raise MethodError(f"method {method!r} returned {type(result).__name__}, not FillResult")
    result.info.setdefault("method", method)
    if refs:
        result.info["reference_takes"] = [ref.record(context["units"] or "mm") for ref in refs]
    if limits is not None:
        from .guards.limits import apply_limits

        result, _ = apply_limits(result, np.isnan(positions).any(axis=2), **limits)
    return result


def fill_data(data: MarkerData, method: str = DEFAULT_METHOD, **options: Any) -> tuple[MarkerData, FillResult]:
    """Like :func:`fill`, and also return a copy of ``data`` carrying the filled positions."""
    result = fill(data, method, **options)
    return data.with_positions(result.positions), result
