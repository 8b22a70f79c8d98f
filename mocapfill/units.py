"""Length units: the one table every unit-aware default (bone thresholds, PCA widths, outlier margins) converts by."""

from __future__ import annotations

from .errors import MethodError

#: Millimetres per unit, for the units a capture may be in.
MM_PER_UNIT = {"mm": 1.0, "cm": 10.0, "m": 1000.0}


def length_factor(from_units: str, to_units: str) -> float:
    """Factor converting a length in ``from_units`` to ``to_units`` ("mm", "cm" or "m").

    An unknown unit is a bad option value, hence :class:`MethodError` (a :class:`MocapfillError`).
    """
    for unit in (from_units, to_units):
        if unit not in MM_PER_UNIT:
            raise MethodError(f"unknown length unit {unit!r} (units must be one of {', '.join(MM_PER_UNIT)})")
    return MM_PER_UNIT[from_units] / MM_PER_UNIT[to_units]
