"""The Python entry point for filling: :func:`fill`."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from .errors import MethodError
from .markers import MarkerData
from .methods import DEFAULT_METHOD, get_method
from .methods.base import FillResult, check_positions

#: Keywords that describe the data rather than tune a method; passed only to methods that accept them.
CONTEXT_KEYS = ("units", "rate", "labels")


def fill(data: MarkerData | np.ndarray, method: str = DEFAULT_METHOD, **options: Any) -> FillResult:
    """Fill the gaps of ``data`` with ``method``.

    Parameters
    ----------
    data : MarkerData or ndarray of shape (n_frames, n_markers, 3)
        The capture; NaN = missing.  Of a MarkerData only the points of kind "marker" inform the fill and are
        filled; model points and unlabelled trajectories come back untouched.  For a bare array, pass ``units=`` (default "mm") and ``rate=`` if the method
        uses them.
    method : str
        A name from :data:`mocapfill.methods.METHODS`.
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
        # Only the markers inform the fill and are filled; model points and unlabelled trajectories come back as
        # they were (the pipeline's rule: mocapfill.pipeline.fill_columns).
        from .pipeline import fill_columns, subset, widen_result

        columns = fill_columns(data)
        if columns.size == 0:
            return FillResult(data.positions.copy(), np.zeros(data.positions.shape[:2], dtype=bool),
                              info={"method": method})
        result = fill(subset(data, columns), method, **options)
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
    positions = check_positions(positions)
    result = func(positions, **kwargs)
    if not isinstance(result, FillResult):  # pragma: no cover - a registry bug, not a user error
        raise MethodError(f"method {method!r} returned {type(result).__name__}, not FillResult")
    result.info.setdefault("method", method)
    if refs:
        result.info["reference_takes"] = [ref.record(context["units"] or "mm") for ref in refs]
    return result


def fill_data(data: MarkerData, method: str = DEFAULT_METHOD, **options: Any) -> tuple[MarkerData, FillResult]:
    """Like :func:`fill`, and also return a copy of ``data`` carrying the filled positions."""
    result = fill(data, method, **options)
    return data.with_positions(result.positions), result
