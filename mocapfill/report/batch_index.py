"""The index page of a batch: one self-contained, sortable HTML table of every file (``index.html``).

:func:`render_batch_index` builds the page from the rows :func:`mocapfill.batch` returns; :func:`write_batch_index`
writes it atomically.  Links (outputs, per-file reports) are relative to the page, so the folder can be moved.
"""

from __future__ import annotations

import html
import os
from pathlib import Path
from typing import Any, Sequence

_STYLE = """body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}
table{border-collapse:collapse;font-size:14px}th,td{padding:4px 8px;border-bottom:1px solid #ddd;text-align:left}
th{cursor:pointer;background:#f4f4f4;user-select:none}th:after{content:" \\2195";color:#aaa}
td.n{text-align:right;font-variant-numeric:tabular-nums}.failed{color:#b00020}.skipped{color:#666}
.filled{color:#1b5e20}"""

# Click a header to sort by it; click again to reverse.  Numbers sort as numbers (data-v), empty cells last.
_SCRIPT = """document.querySelectorAll("th").forEach(function(th,col){th.addEventListener("click",function(){
var body=th.closest("table").tBodies[0],rows=Array.from(body.rows),dir=th.dataset.dir==="1"?-1:1;
th.dataset.dir=dir===1?"1":"-1";function key(r){var c=r.cells[col],v=c.dataset.v;
return v===undefined?c.textContent:(v===""?null:parseFloat(v));}
rows.sort(function(a,b){var x=key(a),y=key(b);if(x===null)return 1;if(y===null)return -1;
return (typeof x==="number"?x-y:String(x).localeCompare(String(y)))*dir;});
rows.forEach(function(r){body.appendChild(r);});});});"""

_HEADERS = ("input", "status", "frames", "markers", "missing %", "filled %", "method", "seconds", "output", "report",
            "error")


def _number(value: float | int | None, digits: int) -> str:
    if value is None:
        return '<td class="n" data-v=""></td>'
    return f'<td class="n" data-v="{value}">{value:.{digits}f}</td>'


def _link(path: str, page_dir: Path) -> str:
    if not path:
        return "<td></td>"
    target = os.path.relpath(path, page_dir)
    href = html.escape(Path(target).as_posix(), quote=True)
    return f'<td><a href="{href}">{html.escape(Path(path).name)}</a></td>'


def render_batch_index(rows: Sequence[Any], *, page_dir: str | os.PathLike = ".") -> str:
    """The page for ``rows`` (:class:`mocapfill.batching.BatchRow`); links are made relative to ``page_dir``."""
    page = Path(page_dir)
    counts = {status: sum(row.status == status for row in rows) for status in ("filled", "skipped", "failed")}
    body = []
    for row in rows:
        cells = int(row.frames or 0) * int(row.markers or 0)
        missing = None if row.missing_samples is None or not cells else 100.0 * row.missing_samples / cells
        filled = None
        if row.filled_samples is not None and row.missing_samples:
            filled = 100.0 * row.filled_samples / row.missing_samples
        output = row.output if row.status != "failed" else ""
        body.append("<tr>" + "".join([
            f"<td>{html.escape(row.input)}</td>",
            f'<td class="{html.escape(row.status)}">{html.escape(row.status)}</td>',
            _number(row.frames, 0), _number(row.markers, 0), _number(missing, 2), _number(filled, 1),
            f"<td>{html.escape(row.method)}</td>", _number(row.seconds, 2),
            _link(output, page), _link(row.report if row.status != "failed" else "", page),
            f"<td>{html.escape(row.error)}</td>",
        ]) + "</tr>")
    summary = ", ".join(f"{n} {status}" for status, n in counts.items())
    head = "".join(f"<th>{html.escape(h)}</th>" for h in _HEADERS)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>mocapfill batch</title>"
            f"<style>{_STYLE}</style></head><body><h1>mocapfill batch</h1><p>{len(rows)} files: {summary}. "
            "Click a column header to sort.</p>"
            f"<table><thead><tr>{head}</tr></thead><tbody>\n" + "\n".join(body) +
            f"\n</tbody></table><script>{_SCRIPT}</script></body></html>\n")


def write_batch_index(rows: Sequence[Any], path: str | os.PathLike, *, out_dir: str | os.PathLike | None = None
                      ) -> None:
    """Write :func:`render_batch_index` of ``rows`` to ``path`` atomically (links relative to its folder)."""
    from ..io.atomic import atomic_write

    page_dir = Path(out_dir) if out_dir is not None else Path(path).parent
    with atomic_write(path, "w", encoding="utf-8") as handle:
        handle.write(render_batch_index(rows, page_dir=page_dir))
