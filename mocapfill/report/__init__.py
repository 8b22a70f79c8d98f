"""Fill reports: a JSON record of what a fill did, and a self-contained HTML page with plots.

Public API
----------
- :func:`build_fill_report` -> dict: JSON-ready summary, gap table, unfilled gaps, rejected samples, bones
  (validates against ``fill_report.schema.json`` beside this module; see :data:`SCHEMA_PATH`).
- :func:`write_report`: writes that dict as ``.json``, or as a self-contained ``.html`` page with a 3-D player
  (:mod:`.player`) and inline SVG plots (needs matplotlib, the optional extra ``mocapfill[report]``), chosen by the
  path's extension.
- :func:`.capture_html.write_capture_report`: the page of a raw capture (``mocapfill info --report``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import InputError
from .json_report import SCHEMA_PATH, build_fill_report, load_schema, report_json

__all__ = ["build_fill_report", "write_report", "load_schema", "SCHEMA_PATH", "report_json"]


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through a temporary file renamed into place (no half-written report)."""
    from ..io.atomic import atomic_write

    with atomic_write(path, "w", encoding="utf-8") as handle:
        handle.write(text)


def write_report(report: dict[str, Any], path: str | Path, *, data, result, bones=None,
                 max_markers: int = 40, max_bones: int = 40, player: bool = True, jobs: int | None = None) -> None:
    """Write ``report`` (from :func:`build_fill_report`) to ``path``: JSON or HTML by extension.

    Parameters
    ----------
    report : dict
        The JSON-ready report.
    path : str or Path
        Ends in ``.json`` (the report as JSON) or ``.html`` / ``.htm`` (one self-contained page: no network, no
        external assets; plots as inline SVG).
    data : MarkerData
        The input before filling, positions (n_frames, n_markers, 3); used for the HTML plots.
    result : FillResult
        The fill, positions (n_frames, n_markers, 3), ``filled`` and optional ``std`` (n_frames, n_markers).
    bones : BoneSet or None
        Bones (pairs (B, 2), lengths (B,)) whose length-over-time plots go into the HTML page.
    max_markers, max_bones : int
        Caps on the number of trajectory and bone plots in the HTML page; the page says what was left out.
    player : bool
        Put the 3-D player (:mod:`.player`) at the top of the HTML page.
    jobs : int or None
        Processes the HTML page's plots are drawn on (None or 1: this one; 0: every core); the page is the same.
    """
    path_str = str(path)
    suffix = Path(path_str).suffix.lower()
    if suffix == ".json":
        atomic_write_text(path, report_json(report))
    elif suffix in (".html", ".htm"):
        from .html_report import render_html

        atomic_write_text(path, render_html(report, data=data, result=result, bones=bones,
                                             max_markers=max_markers, max_bones=max_bones, player=player,
                                             jobs=jobs))
    else:
        raise InputError(f"report {path_str}: unknown extension {suffix or '(none)'!r}; use .json or .html")
