"""The 3-D player of the HTML reports: every marker in perspective, frame by frame, drawn by inline JavaScript.

:func:`player_payload` packs a capture compactly for the page: positions quantised to int16 on one global grid
(the step is the largest extent / 65534, a tenth of a millimetre on a 6 m volume), one status byte per sample
(observed, missing, filled, filled with its uncertainty on a square-root scale), decimated in time to at most
:data:`MAX_SAMPLES` frame x marker samples so that a 10-minute take stays a few megabytes; base64 in a JSON block.
:func:`player_section` returns the HTML section (``id="player"``): canvas, controls, the data and the script
(``player.js`` beside this module, no library, no network).
"""

from __future__ import annotations

import base64
import html
import json
from importlib import resources
from typing import Any, Sequence

import numpy as np

from ..gaps import find_gaps
from ..units import length_factor
from . import plots

#: Most frame x marker samples embedded (7 bytes each before base64): about 5.6 MB of base64 at the cap.
MAX_SAMPLES = 600_000
#: A page with the player stays under this many bytes (the issue's limit is 8 MB; the rest is margin).
PAGE_BUDGET = 7_500_000
#: Status bytes: 0 observed, 1 missing (not drawn), 2 filled without an uncertainty, 3..255 filled with one.
OBSERVED, MISSING, FILLED_NO_STD, STD0 = 0, 1, 2, 3
STD_LEVELS = 252
#: Most gaps listed for the click-info and the gap buttons (the gap table and the JSON report have them all).
MAX_GAPS = 20_000
#: Most rejected samples whose original position is marked.
MAX_REJECTED = 20_000


def _floor_evidence(pos: np.ndarray) -> dict[tuple[int, int], float]:
    """Axes along which the markers of ``pos`` (n_frames, n_markers, 3) stay on one side of zero, as
    ``{(axis, sign): distance of the lowest markers from zero / extent}``: a capture's floor is almost always at zero
    with the subject above it, so a small value says "this axis points up"."""
    out = {}
    for axis in range(3):
        values = pos[..., axis][np.isfinite(pos[..., axis])]
        if values.size < 2:
            continue
        low, high = np.percentile(values, [1, 99])
        extent = max(high - low, 1e-12)
        if low >= -0.05 * extent:
            out[(axis, 1)] = max(low, 0.0) / extent
        elif high <= 0.05 * extent:
            out[(axis, -1)] = max(-high, 0.0) / extent
    return out


def up_axis(data) -> tuple[int, int, str]:
    """The vertical axis of ``data`` as (axis 0/1/2, sign +1/-1, where it came from).

    The axis from the C3D parameter POINT:Y_SCREEN (the axis pointing up the screen) when the file has it, its sign
    too unless the markers clearly stand above zero on the other side.  Without it, from the positions
    (n_frames, n_markers, 3): among the axes along which the markers stay on one side of zero (a floor at zero), the
    one whose lowest markers come nearest to it; failing that, the axis along which the markers of one frame spread
    most (a standing body is taller than wide), pointing to where most markers cluster (the upper body).
    """
    pos = np.asarray(data.positions, dtype=float)
    sample = pos[:: max(1, pos.shape[0] // 500)]
    evidence = _floor_evidence(sample)
    c3d = getattr(getattr(data, "extra", None), "file", None)
    strings = getattr(c3d, "strings", None)
    if callable(strings):
        values = strings("POINT", "Y_SCREEN")
        text = (values[0] if values else "").strip().upper()
        if len(text) == 2 and text[0] in "+-" and text[1] in "XYZ":
            axis, sign = "XYZ".index(text[1]), 1 if text[0] == "+" else -1
            if (axis, -sign) in evidence:
                return axis, -sign, "C3D POINT:Y_SCREEN for the axis; the markers, all on one side, for its sign"
            return axis, sign, "C3D POINT:Y_SCREEN"
    if evidence:
        axis, sign = min(evidence, key=evidence.get)
        return axis, sign, "markers: the floor at zero"
    seen = np.isfinite(sample).all(axis=2)
    rows = seen.sum(axis=1) >= 2
    if not rows.any():
        return 2, 1, "default (too few markers)"
    lo = np.where(seen[..., None], sample, np.inf).min(axis=1)[rows]
    hi = np.where(seen[..., None], sample, -np.inf).max(axis=1)[rows]
    axis = int(np.argmax(np.median(hi - lo, axis=0)))
    low, mid, high = np.percentile(sample[..., axis][seen], [1, 50, 99])
    sign = 1 if (high - mid) <= (mid - low) else -1
    return axis, sign, "markers: the body's longest extent"


def _round(value, digits: int = 4):
    return None if value is None else float(f"{float(value):.{digits}g}")


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<")).tobytes()).decode()


def _nice(x: float) -> float:
    """A round grid step near ``x`` (1, 2 or 5 times a power of ten)."""
    if not np.isfinite(x) or x <= 0:
        return 1.0
    p = 10 ** np.floor(np.log10(x))
    return float(min((m * p for m in (1, 2, 5, 10)), key=lambda s: abs(s - x)))


def player_payload(data, *, positions: np.ndarray | None = None, filled: np.ndarray | None = None,
                   std: np.ndarray | None = None, rejected: np.ndarray | None = None,
                   gaps: Sequence[dict] | None = None, bones=None, max_samples: int = MAX_SAMPLES) -> dict[str, Any]:
    """The JSON-ready data of the player.

    Parameters
    ----------
    data : MarkerData
        The capture as read; positions (n_frames, n_markers, 3), NaN = missing.
    positions : ndarray (n_frames, n_markers, 3) or None
        What to draw (the fill's output); default ``data.positions``.
    filled : ndarray of bool (n_frames, n_markers) or None
        Samples the fill supplied (drawn in the fill colour).
    std : ndarray (n_frames, n_markers) or None
        Uncertainty of the filled samples (data units; NaN = unknown).
    rejected : ndarray of bool (n_frames, n_markers) or None
        Outliers removed before filling; their original positions are marked.
    gaps : list of dict or None
        Gap records as the fill report lists them (``marker`` label, ``first_frame``, ``last_frame`` and optional
        ``status``, ``method``, ``mean_std``, ``max_std``, ``reason``); default: the gaps of ``data``.
    bones : BoneSet or None
        Marker pairs (B, 2) drawn as lines.
    max_samples : int
        Cap on the embedded frame x marker samples; beyond it every k-th frame is kept.
    """
    labels = list(data.labels)
    n_frames, n_markers = data.n_frames, data.n_markers
    first = int(data.first_frame)
    pos = np.asarray(data.positions if positions is None else positions, dtype=float)
    stride = max(1, -(-n_frames * max(n_markers, 1) // max(int(max_samples), 1)))
    keep = np.arange(0, n_frames, stride)
    pos_k = pos[keep]
    finite = np.isfinite(pos_k).all(axis=2)

    status = np.where(finite, OBSERVED, MISSING).astype(np.uint8)
    std_max = 0.0
    if filled is not None:
        fill_k = np.asarray(filled, dtype=bool)[keep] & finite
        status[fill_k] = FILLED_NO_STD
        if std is not None:
            s = np.asarray(std, dtype=float)[keep]
            has = fill_k & np.isfinite(s)
            if has.any():
                std_max = float(s[has].max())
                if std_max > 0:
                    code = STD0 + np.rint(STD_LEVELS * np.sqrt(np.clip(s[has] / std_max, 0, 1)))
                    status[has] = code.astype(np.uint8)

    every = pos[np.isfinite(pos).all(axis=2)]
    if every.size:
        origin = every.min(axis=0)
        extent = float((every.max(axis=0) - origin).max())
    else:
        origin, extent = np.zeros(3), 1.0
    scale = max(extent, 1e-9) / 65534.0
    q = np.full(pos_k.shape, -32768, dtype=np.int16)
    q[finite] = (np.rint((pos_k[finite] - origin) / scale) - 32767).astype(np.int16)

    unit_mm = length_factor("mm", data.units) if data.units in ("mm", "cm", "m") else 1.0
    axis, sign, up_source = up_axis(data)
    if every.size:
        lo = np.percentile(every, 1, axis=0)
        hi = np.percentile(every, 99, axis=0)
        up_values = every[:, axis] * sign
        floor = float(np.percentile(up_values, 0.5)) * sign
    else:
        lo, hi, floor = np.zeros(3), np.ones(3), 0.0

    # The size of the body in one frame (median over frames of the observed markers' bounding-box diagonal; a fill
    # gone astray must not push the camera away): the camera that follows the subject stands a few body sizes away,
    # whatever the size of the capture volume.
    sample = np.asarray(data.positions, dtype=float)[keep][:: max(1, len(keep) // 500)]
    seen = np.isfinite(sample).all(axis=2)
    sizes = [float(np.linalg.norm(np.ptp(frame_pos[ok], axis=0))) for frame_pos, ok in zip(sample, seen) if ok.sum() >= 2]
    body = float(np.median(sizes)) if sizes else 0.0

    gap_rows = []
    index = {label: i for i, label in enumerate(labels)}
    if gaps is None:
        gaps = [{"marker": labels[g.marker], "first_frame": first + g.start, "last_frame": first + g.stop - 1,
                 "status": "missing"} for g in find_gaps(np.asarray(data.missing))]
    texts: dict[str, int] = {}  # status, method and reason strings repeat over thousands of gaps: stored once

    def text(value) -> int:
        return -1 if value is None else texts.setdefault(str(value), len(texts))

    for g in list(gaps)[:MAX_GAPS]:
        m = index.get(g.get("marker"))
        if m is None:
            continue
        gap_rows.append([m, int(g["first_frame"]) - first, int(g["last_frame"]) - first, text(g.get("status")),
                         text(g.get("method")), _round(g.get("mean_std")), _round(g.get("max_std")),
                         text(g.get("reason"))])

    rej_rows = []
    if rejected is not None:
        original = np.asarray(data.positions, dtype=float)
        rej = np.asarray(rejected, dtype=bool)[keep]
        frames_r, markers_r = np.nonzero(rej)
        for f, m in list(zip(frames_r.tolist(), markers_r.tolist()))[:MAX_REJECTED]:
            p = original[keep[f], m]
            if np.isfinite(p).all():
                rej_rows.append([f, m] + [round(float(v), 3) for v in p])

    pairs = [] if bones is None else np.asarray(getattr(bones, "pairs", []), dtype=int).reshape(-1, 2).tolist()
    return {
        "labels": labels,
        "rate": float(data.rate) if np.isfinite(data.rate) and data.rate > 0 else 0.0,
        "first_frame": first,
        "n_frames": int(n_frames),
        "stride": int(stride),
        "n_shown": int(len(keep)),
        "units": str(data.units),
        "origin": [float(v) for v in origin],
        "scale": float(scale),
        "positions": _b64(q),
        "status": _b64(status),
        "std_max": std_max,
        "std_levels": STD_LEVELS,
        "up": [axis, sign],
        "up_source": up_source,
        "floor": floor,
        "box": [[float(v) for v in lo], [float(v) for v in hi]],
        "grid": _nice(500.0 * unit_mm),
        "body": body,
        "bones": pairs,
        "gaps": gap_rows,
        "texts": list(texts),
        "gaps_total": len(gaps),
        "rejected": rej_rows,
        "colours": {"observed": "#4a4a4a", "filled": plots.FILLED, "band": plots.BAND, "rejected": plots.REJECTED,
                    "bone": "#9aa7b0", "selected": plots.REFERENCE,
                    "axes": ["#B03A2E", "#1E8449", "#2E5FA8"]},  # x red, y green, z blue, as 3-D programs draw them
        "fill": filled is not None,
    }


def _script() -> str:
    return resources.files(__package__).joinpath("player.js").read_text(encoding="utf-8")


_CSS = """
#player .stage { position: relative; }
#player canvas.view { width: 100%; height: 520px; display: block; background: #f7f8fa; border: 1px solid #ddd;
  cursor: grab; touch-action: none; }
#player canvas.strip { width: 100%; height: 14px; display: block; margin-top: 4px; cursor: pointer; }
#player .controls { display: flex; flex-wrap: wrap; gap: 0.4em; align-items: center; margin-top: 0.4em;
  font-size: 0.9em; }
#player .controls input[type=range] { flex: 1 1 200px; }
#player .frame { font-variant-numeric: tabular-nums; }
#player .pick { min-height: 2.6em; font-size: 0.9em; margin-top: 0.3em; }
#player .legend span { margin-right: 1.2em; }
#player .dot { display: inline-block; width: 0.8em; height: 0.8em; border-radius: 50%; vertical-align: -0.1em;
  margin-right: 0.3em; }
"""


def player_section(payload: dict[str, Any], *, heading: str = "Player") -> str:
    """The HTML ``<section id="player">`` for ``payload`` (from :func:`player_payload`), script included."""
    # "<" escaped so that no label can close the script element early.
    blob = json.dumps(payload, allow_nan=False, separators=(",", ":")).replace("<", "\\u003c")
    c = payload["colours"]
    legend = [f'<span><i class="dot" style="background:{c["observed"]}"></i>observed</span>']
    if payload["fill"]:
        legend.append(f'<span><i class="dot" style="background:{c["filled"]}"></i>filled '
                      f'(halo: its uncertainty, 1 std)</span>')
        if payload["rejected"]:
            legend.append(f'<span style="color:{c["rejected"]}">&#x2715; rejected outlier (original position)</span>')
    legend.append("<span>missing markers are left out</span>")
    notes = []
    if payload["stride"] > 1:
        notes.append(f"Decimated for the page: every {payload['stride']}th frame is shown "
                     f"({payload['n_shown']} of {payload['n_frames']} frames); gaps shorter than that may fall "
                     "between shown frames.")
    axis, sign = payload["up"]
    notes.append(f"Vertical axis: {'+' if sign > 0 else '-'}{'XYZ'[axis]} (from the {html.escape(payload['up_source'])}"
                 f"); grid step {payload['grid']:g} {html.escape(payload['units'])}. Drag to rotate, wheel to zoom, "
                 "click a marker for its name; with the view focused, space plays and the arrow keys step.")
    if payload["gaps_total"] > len(payload["gaps"]):
        notes.append(f"The gap buttons know the first {len(payload['gaps'])} of {payload['gaps_total']} gaps.")
    return (
        f'<section id="player"><h2>{html.escape(heading)}</h2><style>{_CSS}</style>'
        '<div class="stage"><canvas class="view" width="960" height="520" tabindex="0" aria-label="3-D view of the markers">'
        "</canvas></div>"
        '<canvas class="strip" width="960" height="14" aria-label="where the gaps are over the take"></canvas>'
        '<div class="controls">'
        '<button type="button" class="play" title="play / pause">Play</button>'
        '<label>speed <select class="speed"><option value="0.1">0.1x</option><option value="0.25">0.25x</option>'
        '<option value="0.5">0.5x</option><option value="1" selected>1x</option><option value="2">2x</option>'
        '<option value="4">4x</option></select></label>'
        '<button type="button" class="prev-gap" title="jump to the previous gap">&#xAB; previous gap</button>'
        '<button type="button" class="next-gap" title="jump to the next gap">next gap &#xBB;</button>'
        f'<input type="range" class="slider" min="0" max="{max(payload["n_shown"] - 1, 0)}" value="0" step="1" '
        'aria-label="frame">'
        '<span class="frame"></span></div><div class="controls">'
        '<button type="button" class="reset" title="reset the view">reset view</button>'
        '<label title="keep the subject in the middle of the view"><input type="checkbox" class="follow" checked> '
        "follow the subject</label>"
        '<label><input type="checkbox" class="names"> marker names</label>'
        "</div>"
        f'<div class="pick note"></div><p class="legend note">{"".join(legend)}</p>'
        + "".join(f'<p class="note">{n}</p>' for n in notes)
        + f'<script type="application/json" class="player-data">{blob}</script>'
        f"<script>{_script()}</script></section>"
    )


def fit_player(data, rest_bytes: int, *, budget: int = PAGE_BUDGET, **payload_options) -> str:
    """:func:`player_section` of :func:`player_payload` (``payload_options``), decimated further when needed so that
    it and the ``rest_bytes`` of the page stay under ``budget`` bytes."""
    samples = MAX_SAMPLES
    for _ in range(4):
        section = player_section(player_payload(data, max_samples=samples, **payload_options))
        size = len(section.encode())
        if rest_bytes + size <= budget:
            break
        # what the samples take (9.4 bytes each in base64) shrinks in proportion; the rest of the section stays
        per_sample = 28 / 3
        shown = data.n_markers * -(-data.n_frames // max(1, -(-data.n_frames * data.n_markers // samples)))
        fixed = size - per_sample * shown
        samples = max(data.n_markers, int((budget - rest_bytes - fixed) / per_sample * 0.95))
    return section


#: A tiny first script: errors of any later script (the player's included) are recorded for the self-test.
ERROR_HOOK = ("<script>window.__playerErrors=[];window.addEventListener('error',function(e){"
              "window.__playerErrors.push(String(e.message||e));"
              "document.documentElement.setAttribute('data-player-errors',JSON.stringify(window.__playerErrors));"
              "});</script>")
