"""The HTML page of a raw capture (``mocapfill info --report take.html``): the 3-D player without fill colours, the
capture's figures and its gaps per marker, so that a user can look at a take before deciding to repair it.

Needs no matplotlib: the page's only drawing is the player's canvas.
"""

from __future__ import annotations

from typing import Any

from .html_report import escape, html_table, page, reader_notes
from .player import player_payload, player_section

#: Bones for the player's lines are estimated on at most this many frames (evenly spaced): enough for stable
#: distance statistics, and a 10-minute take costs no more than a short one.
BONE_FRAMES = 5000


def _bones(data):
    from ..bones.boneset import estimate_bones
    from ..errors import MocapfillError

    step = max(1, -(-data.n_frames // BONE_FRAMES))
    try:
        bones = estimate_bones(data.positions[::step], units=data.units, labels=data.labels)
    except MocapfillError:  # lines help the eye; a capture they cannot be estimated for still gets its page
        return None
    return bones if len(bones) else None


def render_capture_html(data, summary: dict[str, Any]) -> str:
    """The self-contained page of one capture.

    Parameters
    ----------
    data : MarkerData
        positions (n_frames, n_markers, 3), NaN = missing.
    summary : dict
        :func:`mocapfill.summary.summarize` of ``data``.
    """
    title = summary.get("path") or data.path or "capture"
    rate = summary["rate"]
    rows = [
        ("File", title),
        ("Format", str(summary.get("format"))),
        ("Frames", f"{summary['n_frames']} at {rate:g} Hz ({summary['duration_seconds']:.2f} s, first frame "
                   f"{summary['first_frame']})"),
        ("Units", summary["units"]),
        ("Markers", f"{summary['n_markers']} ({summary['markers_complete']} complete)"),
        ("Missing", f"{summary['percent_missing']:.2f} % of marker samples ({summary['n_missing']} samples, "
                    f"{summary['n_gaps']} gaps)"),
        ("Longest gap", f"{summary['longest_gap_frames']} frames" if summary["n_gaps"] else "none"),
        ("Missing throughout", ", ".join(summary["markers_missing_throughout"]) or "none"),
        ("Blackout frames (every marker missing)", str(summary["blackout_frames"])),
    ]
    for key, what in (("model_points", "Model points (kept aside)"), ("unlabelled", "Unlabelled (kept aside)")):
        if summary.get(key):
            rows.append((what, f"{len(summary[key])}: {', '.join(summary[key][:30])}"
                         + (" ..." if len(summary[key]) > 30 else "")))
    if summary.get("held"):
        from ..guards.held import held_line

        rows.append(("Held samples", held_line(summary["held"])))
    parts = [f"<h1>mocapfill capture report<small>{escape(title)}</small></h1>",
             '<nav><a href="#player">Player</a><a href="#summary">Summary</a><a href="#markers">Markers</a></nav>']
    if summary["notes"]:
        parts.append(reader_notes(summary["notes"]))
    parts.append(player_section(player_payload(data, bones=_bones(data)), heading="Player (the raw capture)"))
    parts.append('<h2 id="summary">Summary</h2><table class="summary"><tbody>')
    parts.extend(f"<tr><th>{escape(k)}</th><td>{escape(v)}</td></tr>" for k, v in rows)
    parts.append("</tbody></table>")
    parts.append(f'<h2 id="markers">Markers ({summary["n_markers"]})</h2>')
    table = [[escape(m["label"]), f"{m['percent_missing']:.1f}", str(m["n_gaps"]),
              str(m["longest_gap_frames"]) if m["n_gaps"] else "", "yes" if m["gap_at_start"] else "",
              "yes" if m["gap_at_end"] else ""]
             for m in sorted(summary["markers"], key=lambda m: -m["percent_missing"])]
    parts.append('<p class="note">Most missing first.</p>')
    parts.append(html_table(["marker", "missing %", "gaps", "longest gap (frames)", "gap at start", "gap at end"],
                        table, {1, 2, 3}))
    return page(title=f"mocapfill capture: {title}", body="\n".join(parts), script=True)


def write_capture_report(data, summary: dict[str, Any], path: str) -> None:
    """Write :func:`render_capture_html` to ``path`` atomically (nothing half-written)."""
    from . import atomic_write_text

    atomic_write_text(path, render_capture_html(data, summary))


__all__ = ["render_capture_html", "write_capture_report"]
