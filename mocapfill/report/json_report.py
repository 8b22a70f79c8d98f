"""The JSON fill report: what a fill did to a capture, as a plain dict that validates against the schema.

The document layout is specified by ``fill_report.schema.json`` (JSON Schema, draft 2020-12) beside this module.
Frames are given in the file's numbering (``data.first_frame + index``) so that a technician finds them in their
capture software; markers by label.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..gaps import find_gaps, runs
from ..guards.fragments import count_fragments

#: Identifies the document layout; bump on incompatible changes.
SCHEMA_ID = "mocapfill-fill-report/1"
#: The JSON Schema of the report.
SCHEMA_PATH = Path(__file__).with_name("fill_report.schema.json")


def load_schema() -> dict[str, Any]:
    """The report's JSON Schema as a dict."""
    return json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))


def jsonable(value: Any, *, max_list: int = 10_000) -> Any:
    """``value`` converted to plain JSON types: numpy scalars/arrays to numbers/lists, non-finite floats to None,
    paths and unknown objects to strings.  Arrays longer than ``max_list`` elements become a short description."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.ndarray):
        if value.size > max_list:
            return f"<array of shape {list(value.shape)}>"
        return jsonable(value.tolist(), max_list=max_list)
    if isinstance(value, dict):
        return {str(k): jsonable(v, max_list=max_list) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        items = list(value)
        if len(items) > max_list:
            return f"<{len(items)} items>"
        return [jsonable(v, max_list=max_list) for v in items]
    if isinstance(value, Path):
        return str(value)
    text = repr(value)
    return text if len(text) <= 200 else text[:197] + "..."


def report_json(report: dict[str, Any]) -> str:
    """The report as indented JSON text (strict: no NaN/Infinity), ending in a newline."""
    return json.dumps(jsonable(report), indent=2, allow_nan=False) + "\n"


def _gap_method_records(info: dict[str, Any], labels: list[str], first_frame: int
                        ) -> list[tuple[int, int, int, str, str | None, bool]]:
    """Per-gap method records from ``info["gap_methods"]`` as (marker index, start index, length, method, reason,
    review).

    Accepted record layout (what the ``auto`` method writes): a list of dicts with ``marker`` (index or label),
    ``start`` (0-based frame index) or ``first_frame`` (file numbering), optional ``length`` (default 1),
    ``method`` (str), optional ``reason`` (str) and optional ``review`` (bool: the method asks a person to check the
    gap).  Malformed records are skipped: the report is informative, never
    a reason to fail a fill.
    """
    out = []
    records = info.get("gap_methods") if isinstance(info, dict) else None
    if not isinstance(records, (list, tuple)):
        return out
    for rec in records:
        if not isinstance(rec, dict) or "method" not in rec:
            continue
        marker = rec.get("marker")
        if isinstance(marker, str):
            if marker not in labels:
                continue
            marker = labels.index(marker)
        try:
            marker = int(marker)
            if "start" in rec:
                start = int(rec["start"])
            elif "first_frame" in rec:
                start = int(rec["first_frame"]) - first_frame
            else:
                continue
            length = max(1, int(rec.get("length", 1)))
        except (TypeError, ValueError):
            continue
        reason = rec.get("reason")
        out.append((marker, start, length, str(rec["method"]), None if reason is None else str(reason),
                    rec.get("review") is True))
    return out


def _bone_records(positions_in: np.ndarray, positions_out: np.ndarray, filled: np.ndarray, bones,
                  labels: list[str]) -> dict[str, Any] | None:
    """Length errors of the bones that touch a filled sample.

    ``positions_in`` / ``positions_out`` have shape (n_frames, n_markers, 3), ``filled`` (n_frames, n_markers).
    The error is measured on the frames where either end of the bone was filled and both ends are finite.
    """
    if bones is None:
        return None
    pairs = np.asarray(getattr(bones, "pairs", np.zeros((0, 2))), dtype=int).reshape(-1, 2)
    lengths = np.asarray(getattr(bones, "lengths", np.zeros(len(pairs))), dtype=float).reshape(-1)
    touching = []
    for (a, b), ref in zip(pairs, lengths):
        frames = filled[:, a] | filled[:, b]
        if not frames.any():
            continue
        seg = positions_out[frames][:, [a, b]]
        ok = np.isfinite(seg).all(axis=(1, 2))
        dist = np.linalg.norm(seg[ok, 0] - seg[ok, 1], axis=1)
        err = np.abs(dist - ref)
        touching.append({
            "markers": [labels[a], labels[b]],
            "length": float(ref),
            "filled_frames": int(frames.sum()),
            "mean_error": float(err.mean()) if err.size else None,
            "max_error": float(err.max()) if err.size else None,
        })
    return {"total": int(len(pairs)), "touching_filled": touching}


def observed_words(changed: list[str], stored: str | None) -> str:
    """What became of the observed samples, for the summary line and the report page: "changed by: <options>" (the
    summary's ``observed_changed``), else "returned as the output format stores them: <how>" (``observed_stored``),
    else "returned bit-identical"."""
    if changed:
        return "changed by: " + ", ".join(changed)
    if stored:
        return f"returned as the output format stores them: {stored}"
    return "returned bit-identical"


def build_fill_report(data, result, *, method: str, settings: dict[str, Any] | None, seconds: float,
                      input_path: str | None, output_path: str | None, bones=None, rejected: np.ndarray | None = None,
                      smoothed: bool = False, fragments: np.ndarray | None = None, left: np.ndarray | None = None,
                      chosen: np.ndarray | None = None, edges: str = "fill",
                      observed_changed: list[str] | None = None,
                      observed_stored: str | None = None) -> dict[str, Any]:
    """The JSON-ready record of one fill.

    Parameters
    ----------
    data : MarkerData
        The input before filling; positions (n_frames, n_markers, 3), NaN = missing.
    result : FillResult
        The fill: positions (n_frames, n_markers, 3), filled (n_frames, n_markers), std (n_frames, n_markers) or
        None, n_iter, converged, objective, info (``info["gap_methods"]``, when present, names the method that filled
        each gap: a list of ``{"marker": label or index, "start": 0-based frame, "length": n, "method": name}``).
    method : str
        The method asked for.
    settings : dict or None
        The options used (made JSON-safe here).
    seconds : float
        Wall-clock time of the fill.
    input_path, output_path : str or None
        Where the data came from and went to.
    bones : BoneSet or None
        Bones (pairs (B, 2) int, lengths (B,)); the report lists the length errors of those touching filled samples.
    rejected : ndarray of bool, shape (n_frames, n_markers), optional
        Outlier samples removed before filling (they count as missing).
    smoothed : bool
        Whether the output was smoothed after filling.
    fragments : ndarray of bool, shape (n_frames, n_markers), optional
        Short observed fragments dropped before filling (``--min-fragment``; they count as missing).
    left : ndarray of int8, shape (n_frames, n_markers), optional
        Missing samples left missing on request: the :class:`~mocapfill.status.Status` code of the reason
        (``--max-gap``, ``--edges leave``, markers not chosen), 0 elsewhere.
    chosen : ndarray of bool, shape (n_markers,), optional
        The markers chosen for filling (``--markers`` / ``--exclude``).
    edges : "fill" or "leave"
        What the fill did with the gaps touching the first or last frame.
    observed_changed : list of str, optional
        The options that changed or dropped observed samples, with counts (empty: none changed them).
    observed_stored : str, optional
        How the output's format stores the observed samples ("rounded to the TSV's 0.001 mm"); None: exactly (with
        no ``observed_changed``, bit-identical).

    Returns
    -------
    dict
        Keys ``schema``, ``mocapfill_version``, ``created``, ``summary``, ``gaps``, ``unfilled``, ``left_missing``,
        ``rejected``, ``bones``, ``info``; see ``fill_report.schema.json``.
    """
    from ..status import NAMES, Status

    from .. import __version__

    labels = list(data.labels)
    n_frames, n_markers = data.n_frames, data.n_markers
    first = int(data.first_frame)
    rate = float(data.rate)
    missing = data.missing.copy()
    rej = np.zeros_like(missing) if rejected is None else np.asarray(rejected, dtype=bool).reshape(missing.shape)
    missing |= rej
    frag = np.zeros_like(missing) if fragments is None else np.asarray(fragments, dtype=bool).reshape(missing.shape)
    missing |= frag
    reasons = np.zeros(missing.shape, dtype=np.int8) if left is None else np.asarray(left).reshape(missing.shape)
    filled = np.asarray(result.filled, dtype=bool) & missing
    unfilled = missing & ~filled
    std = None if result.std is None else np.asarray(result.std, dtype=float)
    gap_methods = _gap_method_records(result.info, labels, first)

    gaps = []
    for gap in find_gaps(missing):
        sl = slice(gap.start, gap.stop)
        n_filled = int(filled[sl, gap.marker].sum())
        status = "filled" if n_filled == gap.length else ("unfilled" if n_filled == 0 else "partial")
        mean_std = max_std = None
        if std is not None and n_filled:
            vals = std[sl, gap.marker][filled[sl, gap.marker]]
            vals = vals[np.isfinite(vals)]
            if vals.size:
                mean_std, max_std = float(vals.mean()), float(vals.max())
        hits = [(m, why, rev) for (mk, s, ln, m, why, rev) in gap_methods
                if mk == gap.marker and s < gap.stop and s + ln > gap.start]
        names = sorted({m for m, _, _ in hits})
        why_text = list(dict.fromkeys(why for _, why, _ in hits if why))
        left_code = int(reasons[gap.start, gap.marker])
        gaps.append({
            "marker": labels[gap.marker],
            "first_frame": first + gap.start,
            "last_frame": first + gap.stop - 1,
            "length": int(gap.length),
            "seconds": gap.length / rate if rate > 0 else None,
            "status": status,
            "filled_samples": n_filled,
            "rejected_samples": int(rej[sl, gap.marker].sum()),
            "at_start": bool(gap.at_start),
            "at_end": bool(gap.at_end),
            "mean_std": mean_std,
            "max_std": max_std,
            "method": "+".join(names) if names else None,
            "reason": "; ".join(why_text) if why_text else None,
            # a gap nothing filled has no fill to check: it is listed in ``left_missing`` (too long, at an edge,
            # not chosen: as asked) or in ``unfilled`` (never observed, declined), with the summary's alert
            "review": n_filled > 0 and any(rev for _, _, rev in hits),
            "left": NAMES[Status(left_code)] if left_code else None,
            "fragment_samples": int(frag[sl, gap.marker].sum()),
        })

    unfilled_runs = [
        {"marker": labels[m], "first_frame": first + start, "length": length}
        for m in range(n_markers) for start, length in runs(unfilled[:, m])
    ]
    left_missing = [{"marker": g["marker"], "first_frame": g["first_frame"], "last_frame": g["last_frame"],
                     "length": g["length"], "seconds": g["seconds"], "reason": g["left"]}
                    for g in gaps if g["left"]]
    edge_gaps = [g for g in gaps if g["at_start"] or g["at_end"]]
    rej_f, rej_m = np.nonzero(rej.T)[::-1]  # ordered by marker, then frame
    rejected_list = [{"marker": labels[m], "frame": first + int(f)} for f, m in zip(rej_f, rej_m)]

    n_total = n_frames * n_markers
    n_missing = int(missing.sum())
    n_filled = int(filled.sum())
    objective = [jsonable(v) for v in (result.objective or [])]
    summary = {
        "file": None if input_path is None else str(input_path),
        "output": None if output_path is None else str(output_path),
        "method": str(method),
        "methods_used": sorted({g["method"] for g in gaps if g["method"]}),
        "settings": jsonable(dict(settings or {})),
        "frames": int(n_frames),
        "markers": int(n_markers),
        "rate": rate,
        "units": str(data.units),
        "first_frame": first,
        "duration": n_frames / rate if rate > 0 else None,
        "samples": int(n_total),
        "missing_samples": n_missing,
        "filled_samples": n_filled,
        "unfilled_samples": int(unfilled.sum()),
        "rejected_samples": int(rej.sum()),
        "percent_missing": 100.0 * n_missing / n_total if n_total else 0.0,
        "percent_filled": 100.0 * n_filled / n_missing if n_missing else 100.0,
        "gap_count": len(gaps),
        "review_gaps": sum(1 for g in gaps if g["review"]),
        "seconds": float(seconds),
        "uncertainty": std is not None,
        "smoothed": bool(smoothed),
        "left_missing_gaps": len(left_missing),
        "left_missing_samples": int((reasons != 0).sum()),
        "edges": str(edges),
        "edge_gaps_filled": sum(1 for g in edge_gaps if g["status"] == "filled"),
        "edge_gaps_left": sum(1 for g in edge_gaps if g["left"]),
        "fragments": count_fragments(frag) if fragments is not None else None,
        "fragment_samples": int(frag.sum()),
        "markers_not_chosen": [] if chosen is None else [labels[m] for m in np.flatnonzero(~np.asarray(chosen))],
        "observed_changed": [str(c) for c in (observed_changed or [])],
        "observed_stored": observed_stored,
        "convergence": {
            "n_iter": int(result.n_iter),
            "converged": bool(result.converged),
            "objective": objective,
        },
        "notes": [str(n) for n in (data.notes or [])],
    }
    return {
        "schema": SCHEMA_ID,
        "mocapfill_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat(),
        "summary": summary,
        "gaps": gaps,
        "unfilled": unfilled_runs,
        "left_missing": left_missing,
        "rejected": rejected_list,
        "bones": _bone_records(data.positions, np.asarray(result.positions), filled, bones, labels),
        "info": jsonable({k: v for k, v in (result.info or {}).items()}),
    }
