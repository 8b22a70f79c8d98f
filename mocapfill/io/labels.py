"""Helpers shared by the readers: unique marker labels and unit names."""

from __future__ import annotations

import numpy as np

_UNIT_NAMES = {
    "mm": "mm", "millimeter": "mm", "millimeters": "mm", "millimetre": "mm", "millimetres": "mm",
    "cm": "cm", "centimeter": "cm", "centimeters": "cm", "centimetre": "cm", "centimetres": "cm",
    "m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m",
}


def make_unique(labels: list[str]) -> tuple[list[str], list[tuple[str, str]]]:
    """Stripped labels made unique by suffixing repeats ``_2``, ``_3`` ...; also returns the (old, new) renames.

    A suffix already taken by another label is skipped, so the result is always unique.
    """
    labels = [str(label).strip() for label in labels]
    taken = set(labels)
    seen: set[str] = set()
    out, renamed = [], []
    for label in labels:
        if label not in seen:
            seen.add(label)
            out.append(label)
            continue
        k = 2
        while f"{label}_{k}" in taken:
            k += 1
        new = f"{label}_{k}"
        taken.add(new)
        seen.add(new)
        out.append(new)
        renamed.append((label, new))
    return out, renamed


def unit_name(text: str) -> str | None:
    """"mm", "cm" or "m" for a unit string in any case / spelling, else None."""
    return _UNIT_NAMES.get(str(text).strip().strip(".").lower())


def normalise_units(text: str, positions: np.ndarray | None = None) -> tuple[str, str | None]:
    """Normalised units and a note when they had to be guessed.

    When ``text`` is not a known length unit the units are guessed from the size of the coordinates (a human-scale
    capture in metres rarely exceeds 20 in absolute value; in millimetres it does), and the note says so.
    """
    name = unit_name(text)
    if name is not None:
        return name, None
    guess = "mm"
    if positions is not None:
        finite = np.abs(positions[np.isfinite(positions)])
        if finite.size and np.percentile(finite, 90) < 20:
            guess = "m"
    shown = repr(text.strip()) if str(text).strip() else "missing"
    return guess, f"units {shown}; assumed {guess!r} from the size of the coordinates"
