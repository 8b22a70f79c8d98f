"""The evaluation report: an `evaluate` run as one self-contained HTML page, or as its JSON (by extension).

The page holds the headline (best method by millimetres, and by joint angles when IK ran), one table per method
with the millimetre errors beside the joint-angle errors (medians over trials; degrees for rotational coordinates,
the clip's units for translational ones), the markers-left-missing baseline, and the per-coordinate errors of
each method (median over trials).
"""

from __future__ import annotations

import json
import os

import numpy as np

from . import atomic_write_text
from .html_report import escape, html_table, page


def _cell(value: float | None, digits: int = 3) -> str:
    return "&ndash;" if value is None else f"{value:.{digits}g}" if abs(value) < 100 else f"{value:,.0f}"


def _coordinate_table(result) -> str:
    """Median over trials of each coordinate's RMSE, per method (rows: coordinates; columns: methods)."""
    kinds = result.ik["coordinates"]
    names = [n for n, k in kinds.items() if k in ("rotational", "translational")]
    columns = list(result.methods) + ["(left missing)"]
    per: dict[str, dict[str, float | None]] = {}
    for method in columns:
        entries = result.left_missing if method == "(left missing)" else [s for s in result.scores
                                                                           if s.method == method]
        per[method] = {}
        for n in names:
            vals = np.array([e.ik_errors.get(n) if e.ik_errors and e.ik_errors.get(n) is not None else np.nan
                             for e in entries], dtype=float)
            vals = vals[np.isfinite(vals)]
            per[method][n] = float(np.median(vals)) if vals.size else None
    units = result.data.units
    rows = [[escape(n), "\u00b0" if kinds[n] == "rotational" else escape(units)] + [_cell(per[m][n]) for m in columns]
            for n in names]
    return html_table(["coordinate", "unit"] + columns, rows, set(range(2, 2 + len(columns))))


def render_evaluation_html(result) -> str:
    """The page of an :class:`~mocapfill.evaluation.EvaluationResult` (str, UTF-8 HTML)."""
    data = result.data
    summary = result.summary()
    units = data.units
    ik = result.ik is not None
    ranking = result.ranking("rmse", "mean")
    from ..evaluation import problem_words

    heads = ["method", f"RMSE mean ({units})", f"RMSE median ({units})", f"max error ({units})",
             f"bone error ({units})", "seconds"]
    keys = [("rmse", "mean"), ("rmse", "median"), ("max_error", "mean"), ("bone_error", "mean"), ("seconds", "mean")]
    honesty = any(summary[m]["error_ratio"]["median"] is not None for m in result.methods)
    if honesty:  # (as the terminal table: the median over trials)
        heads.append("err/std")
        keys.append(("error_ratio", "median"))
    fill_columns = len(keys)  # the fills' own columns, which leaving the markers out has none of
    if ik:
        heads += ["angle median (\u00b0)", "angle worst (\u00b0)", f"transl. median ({units})",
                  f"transl. worst ({units})", "IK seconds"]
        keys += [("angle_median", "median"), ("angle_worst", "median"), ("translation_median", "median"),
                 ("translation_worst", "median"), ("ik_seconds", "median")]
    problems = any(problem_words(summary[m]) for m in result.methods)
    rows = [[escape(m)] + [_cell(summary[m][k][stat]) for k, stat in keys]
            + [escape(problem_words(summary[m]))] * problems for m in ranking]
    if ik:
        left = result.left_missing_summary()
        rows.append(["<em>(left missing)</em>"] + ["&ndash;"] * fill_columns
                    + [_cell(left[k][stat]) for k, stat in keys[fill_columns:]] + [""] * problems)
    if problems:
        heads.append("problems")
    parts = [f"<h1>Evaluation of fill methods<small>{escape(data.path)}: {data.n_markers} markers, {data.n_frames} "
             f"frames at {data.rate:g} Hz; protocol {escape(result.protocol)}, {len(result.trials)} trials, seed "
             f"{result.seed}</small></h1>"]
    by_mm = result.best("rmse", "mean")
    headline = [f"Best by mean RMSE: <strong>{escape(by_mm)}</strong>." if by_mm is not None else
                "Best by mean RMSE: none (no method scored any hidden sample)."]
    if ik:
        best = result.best_for_angles()
        left = result.left_missing_summary()
        if best is not None:
            row = summary[best]
            headline.append(f"Best for joint angles: <strong>{escape(best)}</strong> (median coordinate "
                            f"{_cell(row['angle_median']['median'])}\u00b0, worst coordinate "
                            f"{_cell(row['angle_worst']['median'])}\u00b0; leaving the markers missing: "
                            f"{_cell(left['angle_median']['median'])}\u00b0 / "
                            f"{_cell(left['angle_worst']['median'])}\u00b0).")
    parts.append(f'<p class="alert ok">{" ".join(headline)}</p>')
    if result.settings.get("oracle"):
        parts.append('<p class="alert">ORACLE: the outlier ranges came from the clean file itself; these '
                     "scores are not what a user without it gets.</p>")
    parts.append("<h2>Methods</h2>" + html_table(heads, rows, set(range(1, len(heads) - problems))))
    notes = ["Millimetre errors over the hidden samples; mean and median over trials."]
    if honesty:
        notes.append("err/std: the RMS error per coordinate over the hidden samples over the RMS of the std the method "
                     "predicted there, median over trials (1: honest; 2: twice as wrong as it said).")
    if result.settings.get("references"):
        from ..evaluation import reference_words

        notes.append("Reference takes: " + escape(", ".join(result.settings["references"])) + "."
                     + "".join(f" {escape(m)}: {escape(reference_words(summary[m]['references']))}."
                               for m in result.methods if summary[m].get("references")))
    if ik:
        notes.append(f"Joint angles: OpenSim inverse kinematics with {escape(os.path.basename(result.ik['setup'] or ''))}"
                     f" on model {escape(os.path.basename(result.ik['model']))}; per coordinate the RMSE over the "
                     "frames with a hidden sample of IK on the fill against IK on the complete capture; median and "
                     "worst coordinate (rotational in degrees, translational in the capture's units), then the median "
                     "over trials. '(left missing)': the hidden markers left out of IK where they are missing, as "
                     "OpenSim does with empty TRC cells.")
    parts.append("".join(f'<p class="note">{n}</p>' for n in notes))
    if ik:
        parts.append("<h2>Joint-angle error per coordinate</h2><p class=\"note\">RMSE over frames, median over "
                     "trials.</p>" + _coordinate_table(result))
    return page(title=f"mocapfill evaluation: {os.path.basename(str(data.path or ''))}", body="\n".join(parts))


def write_evaluation_report(result, path: str | os.PathLike) -> None:
    """Write ``result`` as ``.json`` (:meth:`EvaluationResult.to_dict`) or as a ``.html`` page, by extension."""
    path = os.fspath(path)
    if path.lower().endswith(".json"):
        text = json.dumps(result.to_dict(), indent=1, allow_nan=False) + "\n"
    else:
        text = render_evaluation_html(result)
    atomic_write_text(path, text)


__all__ = ["render_evaluation_html", "write_evaluation_report"]
