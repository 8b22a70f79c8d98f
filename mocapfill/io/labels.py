"""Helpers shared by the readers: unique marker labels and unit names."""

from __future__ import annotations

import re

import numpy as np

_UNIT_NAMES = {
    "mm": "mm", "millimeter": "mm", "millimeters": "mm", "millimetre": "mm", "millimetres": "mm",
    "cm": "cm", "centimeter": "cm", "centimeters": "cm", "centimetre": "cm", "centimetres": "cm",
    "m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m",
}


#: How a reader's note of a renamed duplicate label begins (the CLI prints many of them as one line).
RENAMED_NOTE = "duplicate label "


def rename_notes(renamed: list[tuple[str, str]]) -> list[str]:
    """The reader's note for each (old, new) rename :func:`make_unique` made: "duplicate label 'A' renamed 'A_2'"."""
    return [f"{RENAMED_NOTE}{old!r} renamed {new!r}" for old, new in renamed]


def named_by_place(labels: list[str]) -> list[str]:
    """``labels`` with each empty one named by its place, ``M001`` for the first marker: what the readers call an
    unnamed column, and what the writers write for an empty label (no reader takes an empty name back)."""
    return [label or f"M{k + 1:03d}" for k, label in enumerate(labels)]


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


#: Names capture software gives trajectories nobody labelled: Vicon ``*12``, Motive ``Unlabeled 1000`` /
#: ``Unlabeled:108``, Cortex ``Unlabel#3`` / ``*Unnamed_60``, QTM ``Unidentified 4`` / ``Unnamed 4`` (matched on the
#: whole label and on the part after each colon: see :func:`is_unlabelled_name`).
UNLABELLED_NAME = re.compile(r"^(\*\d+|\*?(unlabel(l)?ed([ _#:-]*\d+)?|unlabel#?\d+|unidentified([ _#:-]*\d+)?"
                             r"|unnamed( marker)?([ _#:-]*\d+)?))$", re.IGNORECASE)
#: Names of points that modelling software computes (never a marker on the skin): joint centres (``LHJC``,
#: ``RKJC_CGM_2.4``, ``LeftHipCenter``), the centre of mass and its floor projection, the CGM's ``_CGM_`` outputs,
#: global / segment axes written as ``AXISX...`` / ``ORIGIN...`` points, arch heights.
MODEL_NAME = re.compile(r"(^[LR]?[A-Za-z]{0,4}JC\d*(_|$)|_CGM_?\d|^cent(re|er)of(mass|gravity)"
                        r"|^(left|right)?(hip|knee|ankle|joint|shoulder|elbow|wrist)cent(er|re)"
                        r"|^(axis[xyz]|origin)[A-Za-z]|arch.?height)", re.IGNORECASE)
#: The points Plug-in Gait, the CGM and the Oxford foot model write for each segment's axes: the origin, anterior,
#: lateral and proximal points, ``<segment>O`` / ``A`` / ``L`` / ``P`` (``PELO PELA PELL PELP``,
#: ``LFEMUR_CGM_2.4O`` ...).  A name is taken as one only when all four of its segment are in the file (a lone
#: ``LFOO`` is a foot marker in some marker sets).
AXIS_SUFFIXES = ("O", "A", "L", "P")


def bare_label(label: str) -> str:
    """A label without its ``subject:`` prefix (Vicon writes ``subject:LASI``)."""
    return str(label).rsplit(":", 1)[-1].strip()


def is_unlabelled_name(label: str) -> bool:
    """Does ``label`` name an unlabelled trajectory (:data:`UNLABELLED_NAME`), with or without a ``subject:`` prefix?

    The whole label is tried before the part after each colon: in Motive's ``Unlabeled:108`` the colon belongs to
    the name (cut at it, only ``108`` is left), in ``subject:*12`` it ends a prefix.
    """
    parts = str(label).split(":")
    return any(UNLABELLED_NAME.match(":".join(parts[i:]).strip()) for i in range(len(parts)))


def point_kinds(labels: list[str]) -> list[str]:
    """Each label's kind ("marker", "model" or "unlabelled") as its name says; "marker" where nothing does.

    Unlabelled: :func:`is_unlabelled_name`.  Model points: :data:`MODEL_NAME`, and the four points of a segment's
    axes (:data:`AXIS_SUFFIXES`) when all four are present.
    """
    bare = [bare_label(label) for label in labels]
    present = set(bare)
    kinds = []
    for label, name in zip(labels, bare):
        if is_unlabelled_name(label):
            kinds.append("unlabelled")
        elif MODEL_NAME.search(name) or _segment_axis(name, present):
            kinds.append("model")
        else:
            kinds.append("marker")
    return kinds


def _segment_axis(name: str, present: set[str]) -> bool:
    if len(name) < 4 or name[-1] not in AXIS_SUFFIXES:
        return False
    base = name[:-1]
    return len(base) >= 3 and all(base + s in present for s in AXIS_SUFFIXES)


def kind_counts(kinds: list[str]) -> dict[str, int]:
    """How many points of each kind: ``{"marker": n, "model": n, "unlabelled": n}``."""
    return {kind: sum(1 for k in kinds if k == kind) for kind in ("marker", "model", "unlabelled")}


def match_label_row(cells: list[str], n_markers: int, where: str) -> tuple[list[str], str | None, bool]:
    """Names for ``n_markers`` x/y/z triplets from a label row's cells (after its leading columns).

    The non-empty names are read in place when each stands at the start of a triplet (every third cell), or in
    order when their number is ``n_markers`` whatever the spacing.  Otherwise the row cannot be matched to the
    columns and every marker gets "" (the caller names them ``M###``): never a name that may be another marker's.
    Returns ``(labels, note, matched)``: ``labels`` has at least ``n_markers`` entries ("" = no name; more when an
    aligned row names more triplets than ``n_markers``), ``note`` says what was done when the spacing was irregular
    (``where`` names the row in it).
    """
    fields = [(j, c.strip()) for j, c in enumerate(cells) if c.strip()]
    names = [c for _, c in fields]
    if all(j % 3 == 0 for j, _ in fields):
        labels = [""] * max(n_markers, fields[-1][0] // 3 + 1 if fields else 0)
        for j, c in fields:
            labels[j // 3] = c
        return labels, None, True
    if len(names) == n_markers:
        return names, f"{where} spaces its {len(names)} names irregularly; they were taken in order", True
    shown = "M001" if n_markers == 1 else f"M001-M{n_markers:03d}"
    return ([""] * n_markers, f"{where} holds {len(names)} names, irregularly spaced, for {n_markers} markers: they "
            f"cannot be matched to the columns; markers {shown} got placeholder names", False)
