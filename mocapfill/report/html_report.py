"""The HTML fill report: one self-contained page (inline CSS, SVG and the player's script; no network) a technician
opens to see what a fill did to their capture.

Sections: the 3-D player (:mod:`.player`), summary, overview (marker x frame map), gap table, per-marker
trajectories with the filled stretches and the uncertainty band, bone lengths before / after the fill, the objective
per iteration.  Plots are capped (``max_markers``, ``max_bones``; fewer and coarser past ``LONG_TAKE`` frames) and
the page says what was left out.
"""

from __future__ import annotations

import html
from functools import partial
from typing import Any, Callable

import numpy as np

from ..runtime.executor import forked_map
from . import plots
from .json_report import observed_words

#: Points per plotted line; takes longer than LONG_TAKE frames get fewer (about one per two pixels of the page), so
#: that their plots leave the 3-D player room under the page budget (:data:`.player.PAGE_BUDGET`).
PLOT_POINTS = 1000
LONG_TAKE = 20_000
LONG_PLOT_POINTS = 400
#: ... and at most this many trajectory and bone plots each (the player shows every marker; the page says which
#: plots were left out).
LONG_TAKE_PLOTS = 20
#: More gap rows than this are cut from the table (the JSON report has them all).
MAX_TABLE_ROWS = 500
#: Gap tables longer than this are folded under a <details> element, with the longest gaps shown above.
OPEN_TABLE_ROWS = 40

_CSS = """
body { font-family: -apple-system, "Segoe UI", Roboto, Helvetica, Arial, sans-serif; color: #222; margin: 0;
       background: #fafafa; }
main { max-width: 1000px; margin: 0 auto; padding: 1.5em 2em 4em; background: #fff; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; }
h1 small { font-weight: normal; color: #666; font-size: 0.6em; display: block; }
h2 { font-size: 1.2em; border-bottom: 1px solid #ddd; padding-bottom: 0.2em; margin-top: 2em; }
table { border-collapse: collapse; font-size: 0.85em; }
th, td { padding: 0.25em 0.7em; text-align: left; border-bottom: 1px solid #eee; vertical-align: top; }
th { background: #f3f3f3; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
table.summary th { background: none; color: #555; font-weight: normal; white-space: nowrap; }
.alert { padding: 0.6em 1em; margin: 0.6em 0; border-left: 4px solid #D55E00; background: #fff4ec; }
.ok { border-left-color: #009E73; background: #eefaf5; }
.note { color: #666; font-size: 0.85em; }
figure { margin: 1.2em 0; }
figure svg { width: 100%; height: auto; }
figcaption { font-size: 0.85em; color: #555; }
.status-filled { color: #009E73; } .status-partial { color: #D55E00; } .status-unfilled { color: #B00020; }
nav a { margin-right: 1em; font-size: 0.9em; }
details summary { cursor: pointer; color: #0072B2; }
"""


def escape(value: Any) -> str:
    return html.escape("" if value is None else str(value))


def _num(value: Any, digits: int = 4) -> str:
    if value is None:
        return "\u2013"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _frames_mask(records: list[dict], labels: list[str], first: int, shape: tuple[int, int]) -> np.ndarray:
    """(n_frames, n_markers) bool from ``[{"marker": label, "frame": n}]`` records of the report."""
    mask = np.zeros(shape, dtype=bool)
    index = {label: i for i, label in enumerate(labels)}
    for rec in records:
        m = index.get(rec["marker"])
        f = rec["frame"] - first
        if m is not None and 0 <= f < shape[0]:
            mask[f, m] = True
    return mask


def _summary_rows(report: dict) -> list[tuple[str, str]]:
    s = report["summary"]
    shown = {k: v for k, v in s["settings"].items() if k not in ("references", "denoise")}
    settings = ", ".join(f"{k}={v}" for k, v in shown.items()) or "defaults"
    method = s["method"]
    if s["methods_used"]:
        method += f" (gaps filled by: {', '.join(s['methods_used'])})"
    conv = s["convergence"]
    if conv["n_iter"]:
        convergence = f"{conv['n_iter']} iterations, {'converged' if conv['converged'] else 'NOT converged (iteration cap reached)'}"
    else:
        convergence = "direct method (no iterations)"
    duration = f", {s['duration']:.2f} s" if s["duration"] is not None else ""
    rows = [
        ("Input", s["file"] or "\u2013"),
        ("Output", s["output"] or "\u2013"),
        ("Method", method),
        ("Settings", settings),
        ("Frames", f"{s['frames']} at {s['rate']:g} Hz{duration} (first frame {s['first_frame']})"),
        ("Markers", str(s["markers"])),
        ("Units", s["units"]),
        ("Missing", f"{s['missing_samples']} samples ({s['percent_missing']:.2f} % of {s['samples']}) in "
                    f"{s['gap_count']} gaps"),
        ("Filled", f"{s['filled_samples']} samples ({s['percent_filled']:.1f} % of the missing)"),
        ("Left unfilled", str(s["unfilled_samples"])),
    ]
    if s.get("left_missing_gaps"):
        rows.append(("Left missing as asked", f"{s['left_missing_gaps']} gaps ({s['left_missing_samples']} samples), "
                                              "listed below"))
    if s.get("markers_not_chosen"):
        names = s["markers_not_chosen"]
        rows.append(("Not filled (not chosen)", ", ".join(names[:20]) + (f" and {len(names) - 20} more"
                                                                         if len(names) > 20 else "")))
    if "edges" in s and (s["edges"] != "fill" or s["edge_gaps_filled"]):
        filled_at_edges = [f"{g['marker']} {g['first_frame']}-{g['last_frame']}" for g in report["gaps"]
                           if (g["at_start"] or g["at_end"]) and g["status"] == "filled"]
        listed = ", ".join(filled_at_edges[:10]) + (", ..." if len(filled_at_edges) > 10 else "")
        rows.append(("Gaps at the edges", f"--edges {s['edges']}: {s['edge_gaps_filled']} filled"
                     + (f" ({listed})" if listed else "") + f", {s['edge_gaps_left']} left missing"))
    if s.get("fragments") is not None:
        rows.append(("Short fragments", f"{s['fragments']} dropped and filled over ({s['fragment_samples']} samples)"))
    if "observed_changed" in s:
        rows.append(("Observed samples", observed_words(s["observed_changed"], s.get("observed_stored"))))
    rows += [
        ("Outliers rejected" if not s.get("held") else "Rejected (outliers, held)", str(s["rejected_samples"])),
        *[(f"Reference take {k + 1}", f"{r['name']}: {r['frames']} frame{'' if r['frames'] == 1 else 's'}"
                                      f"{' (static trial)' if r['static'] else ''}, "
                                      f"weight {r['weight']}; " + "; ".join(f"{stage}: {text}" for stage, text
                                                                           in r["stages"].items()))
          for k, r in enumerate(s["settings"].get("references", []))],
        *([("Repaired by the denoiser", f"{s['settings']['denoise']['repaired']} observed samples judged displaced "
                                        f"or swapped, refilled")] if "denoise" in s["settings"] else []),
        ("Uncertainty", "yes (per-sample standard deviation)" if s["uncertainty"] else "not given by this method"),
        ("Smoothed after filling", "yes" if s["smoothed"] else "no"),
        ("Time", f"{s['seconds']:.2f} s"),
        ("Convergence", convergence),
        ("Report", f"mocapfill {report['mocapfill_version']}, {report['created']}"),
    ]
    if s.get("points"):
        rows.insert(4, ("Points", s["points"]))
    if s.get("held"):
        at = next(i for i, (key, _) in enumerate(rows) if key.startswith(("Outliers", "Rejected")))
        rows.insert(at + 1, ("Held samples", s["held"]["line"]))
    return rows


def reader_notes(notes: list[str], shown: int = 2) -> str:
    """The reader's notes; past ``shown`` folded, so that a file with dozens of renamed labels does not push the
    player off the screen."""
    text = "; ".join(escape(n) for n in notes[:shown])
    if len(notes) <= shown:
        return f'<p class="note">Reader notes: {text}</p>'
    rest = "; ".join(escape(n) for n in notes[shown:])
    return (f'<details class="note"><summary>Reader notes ({len(notes)}): {text} ...</summary>'
            f"<p>{rest}</p></details>")


def html_table(headers: list[str], rows: list[list[str]], numeric: set[int]) -> str:
    head = "".join(f'<th class="num">{escape(h)}</th>' if i in numeric else f"<th>{escape(h)}</th>"
                   for i, h in enumerate(headers))
    body = []
    for row in rows:
        cells = "".join(f'<td class="num">{c}</td>' if i in numeric else f"<td>{c}</td>" for i, c in enumerate(row))
        body.append(f"<tr>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _figure(svg: str, caption: str, kind: str, name: str) -> str:
    return (f'<figure class="plot {kind}-plot" data-name="{escape(name)}">{svg}'
            f"<figcaption>{caption}</figcaption></figure>")


def _draw(draw: Callable[[], str]) -> str:
    """One plot's SVG (a task of :func:`render_html`'s plots, which may run in another process)."""
    return draw()


def render_html(report: dict[str, Any], *, data, result, bones=None, max_markers: int = 40,
                max_bones: int = 40, player: bool = True, jobs: int | None = None) -> str:
    """The self-contained HTML page of ``report`` (from :func:`build_fill_report`).

    Parameters
    ----------
    report : dict
        The JSON-ready report.
    data : MarkerData
        The input before filling, positions (n_frames, n_markers, 3).
    result : FillResult
        positions (n_frames, n_markers, 3), filled (n_frames, n_markers), std (n_frames, n_markers) or None.
    bones : BoneSet or None
        pairs (B, 2), lengths (B,): the bones touching filled markers get a length-over-time plot.
    max_markers, max_bones : int
        Caps on the number of trajectory and bone plots (at most ``LONG_TAKE_PLOTS`` each past ``LONG_TAKE`` frames).
    player : bool
        Put the 3-D player (:mod:`.player`, the page's only script) near the top.
    jobs : int or None
        Processes the trajectory and bone plots are drawn on (:func:`~mocapfill.runtime.executor.forked_map`; None
        or 1: this one).  Each plot is tenths of a second of matplotlib, a page dozens of them; the page is the same.

    Raises
    ------
    MocapfillError
        matplotlib is not installed.
    """
    plots._matplotlib()  # fail early, with the one-line message, before any work
    s = report["summary"]
    labels = list(data.labels)
    first = int(data.first_frame)
    units = s["units"]
    n_frames, n_markers = data.n_frames, data.n_markers
    frames = first + np.arange(n_frames)
    points = PLOT_POINTS
    if n_frames > LONG_TAKE:
        points = LONG_PLOT_POINTS
        max_markers, max_bones = min(max_markers, LONG_TAKE_PLOTS), min(max_bones, LONG_TAKE_PLOTS)
    rejected = _frames_mask(report["rejected"], labels, first, (n_frames, n_markers))
    # observed samples the fill saw as gaps besides the outliers: short fragments dropped (--min-fragment)
    rejected |= np.asarray(result.filled, dtype=bool) & ~data.missing
    observed = data.positions.copy()
    observed[rejected] = np.nan
    missing = np.isnan(observed).any(axis=2)
    filled = np.asarray(result.filled, dtype=bool) & missing
    unfilled = missing & ~filled
    output = np.asarray(result.positions, dtype=float)
    std = None if result.std is None else np.asarray(result.std, dtype=float)

    title = s["file"] or "capture"
    parts = [f"<h1>mocapfill fill report<small>{escape(title)}</small></h1>"]
    parts.append('<nav>' + ('<a href="#player">Player</a>' if player else '') + '<a href="#summary">Summary</a><a href="#overview">Overview</a><a href="#gaps">Gaps</a>'
                 '<a href="#markers">Markers</a><a href="#bones">Bones</a><a href="#convergence">Convergence</a></nav>')

    # Alerts first: what needs a person's attention.
    alerts = []
    conv = s["convergence"]
    if conv["n_iter"] and not conv["converged"]:
        alerts.append(f"The method stopped at its iteration cap ({conv['n_iter']} iterations) before converging.")
    asked = s.get("left_missing_samples", 0)
    if s["unfilled_samples"] > asked:
        alerts.append(f"{s['unfilled_samples'] - asked} samples are still missing in the output "
                      f"({len(report['unfilled'])} stretches, listed below).")
    if s["missing_samples"] == 0:
        parts.append('<div class="alert ok">The input had no gaps: nothing was filled.</div>')
    elif not alerts and asked:
        parts.append(f'<div class="alert ok">Every gap was filled ({s["filled_samples"]} samples) but the '
                     f'{s["left_missing_gaps"]} left missing as asked (listed below).</div>')
    elif not alerts:
        parts.append(f'<div class="alert ok">Every gap was filled ({s["filled_samples"]} samples).</div>')
    parts.extend(f'<div class="alert">{escape(a)}</div>' for a in alerts)
    review = [g for g in report["gaps"] if g.get("review")]
    if review:
        listed = ", ".join(f'{g["marker"]} {g["first_frame"]}-{g["last_frame"]}' for g in review[:10])
        more = f" and {len(review) - 10} more" if len(review) > 10 else ""
        parts.append(f'<div class="alert">{len(review)} gap{"s" if len(review) != 1 else ""} to review (the method '
                     f'is unsure of the fill; marked \u2691 in the gap table): {escape(listed)}{more}.</div>')
    if s["notes"]:
        parts.append(reader_notes(s["notes"]))
    player_at = len(parts)  # the player goes here, sized last to what the rest of the page leaves (fit_player)

    parts.append('<h2 id="summary">Summary</h2><table class="summary"><tbody>')
    parts.extend(f"<tr><th>{escape(k)}</th><td>{escape(v)}</td></tr>" for k, v in _summary_rows(report))
    parts.append("</tbody></table>")

    # Overview map.
    status = np.zeros((n_frames, n_markers), dtype=np.int8)
    status[filled] = 1
    status[unfilled] = 2
    status[rejected & filled] = 3
    status[rejected & unfilled] = 4
    parts.append('<h2 id="overview">Overview</h2>')
    if n_frames and n_markers:
        parts.append(_figure(plots.gap_map_svg(status, labels, first), "Every marker (rows) over every frame "
                             "(columns): what was observed, filled, rejected or left missing.", "overview", "map"))

    # Gap table.
    gaps = report["gaps"]
    parts.append(f'<h2 id="gaps">Gaps ({len(gaps)})</h2>')
    if gaps:
        has_std = any(g["mean_std"] is not None for g in gaps)
        has_method = any(g["method"] for g in gaps)
        headers = ["marker", "first frame", "last frame", "frames", "seconds", "status"]
        if has_std:
            headers += [f"mean std ({units})", f"max std ({units})"]
        if has_method:
            headers += ["filled by"]
        has_review = any(g.get("review") for g in gaps)
        if has_review:
            headers += ["review"]
        rows = []
        for g in gaps:
            row = [escape(g["marker"]), str(g["first_frame"]), str(g["last_frame"]), str(g["length"]),
                   _num(g["seconds"], 3), f'<span class="status-{g["status"]}">{g["status"]}</span>'
                   + (f' ({g["rejected_samples"]} outliers)' if g["rejected_samples"] else "")]
            if has_std:
                row += [_num(g["mean_std"], 3), _num(g["max_std"], 3)]
            if has_method:
                # The reason (when the method gives one) is a tooltip: a sentence per row would drown the table.
                cell = escape(g["method"] or "\u2013")
                if g.get("reason"):
                    cell = f'<span title="{escape(g["reason"])}">{cell}</span>'
                row += [cell]
            if has_review:
                row += ['<span title="the method is unsure of this fill: check it">\u2691</span>'
                        if g.get("review") else ""]
            rows.append(row)
        numeric = {1, 2, 3, 4} | ({6, 7} if has_std else set())
        if len(gaps) > OPEN_TABLE_ROWS:
            # A long table is folded; the longest gaps, what a person checks first, stay in view.
            longest = sorted(range(len(rows)), key=lambda i: -gaps[i]["length"])[:10]
            parts.append(f"<h3>The {len(longest)} longest gaps</h3>")
            parts.append(html_table(headers, [rows[i] for i in sorted(longest)], numeric))
            shown = "all" if len(gaps) <= MAX_TABLE_ROWS else "the first"
            parts.append(f"<details><summary>Show {shown} {min(len(gaps), MAX_TABLE_ROWS)} of {len(gaps)} gaps"
                         f"</summary>{html_table(headers, rows[:MAX_TABLE_ROWS], numeric)}</details>")
        else:
            parts.append(html_table(headers, rows, numeric))
        if len(gaps) > MAX_TABLE_ROWS:
            parts.append(f'<p class="note">{len(gaps) - MAX_TABLE_ROWS} more gaps not shown; the JSON report '
                         "(--report file.json) lists them all.</p>")
    else:
        parts.append("<p>No gaps.</p>")
    if report.get("left_missing"):
        parts.append(f"<h3>Left missing as asked ({len(report['left_missing'])} gaps)</h3>")
        rows = [[escape(g["marker"]), str(g["first_frame"]), str(g["last_frame"]), str(g["length"]),
                 _num(g["seconds"], 3), escape(g["reason"])] for g in report["left_missing"][:MAX_TABLE_ROWS]]
        parts.append(html_table(["marker", "first frame", "last frame", "frames", "seconds", "reason"], rows,
                                {1, 2, 3, 4}))
    if report["unfilled"]:
        parts.append("<h3>Left unfilled</h3>")
        rows = [[escape(u["marker"]), str(u["first_frame"]), str(u["length"])] for u in report["unfilled"][:MAX_TABLE_ROWS]]
        parts.append(html_table(["marker", "first frame", "frames"], rows, {1, 2}))
    if report["rejected"]:
        per_marker: dict[str, int] = {}
        for rec in report["rejected"]:
            per_marker[rec["marker"]] = per_marker.get(rec["marker"], 0) + 1
        parts.append(f"<h3>Outliers rejected before filling ({len(report['rejected'])} samples)</h3>")
        parts.append(html_table(["marker", "samples"], [[escape(k), str(v)] for k, v in per_marker.items()], {1}))

    # Trajectories of the filled markers.
    counts = filled.sum(axis=0)
    filled_markers = np.flatnonzero(counts)
    parts.append(f'<h2 id="markers">Filled markers ({len(filled_markers)})</h2>')
    if len(filled_markers) > max_markers:
        keep = np.sort(filled_markers[np.argsort(-counts[filled_markers], kind="stable")[:max_markers]])
        left = [labels[m] for m in filled_markers if m not in set(keep.tolist())]
        parts.append(f'<p class="note">Plotted the {max_markers} markers with the most filled samples; '
                     f"{len(left)} more not plotted: {escape(', '.join(left))}.</p>")
    else:
        keep = filled_markers
    if len(keep):
        parts.append('<p class="note">Black: the input; orange: filled samples on shaded stretches'
                     + ("; band: \u00b1 2 standard deviations" if std is not None else "")
                     + "; grey: still missing.</p>")
    outliers = np.where(rejected[..., None], data.positions, np.nan)
    drawings: list[tuple[int, Callable[[], str], str, str, str]] = []  # (place in parts, draw, caption, kind, name)
    for m in keep:
        window = plots.plot_window(filled[:, m] | unfilled[:, m])
        draw = partial(plots.trajectory_svg, frames, observed[:, m], output[:, m], filled[:, m], unfilled[:, m],
                       None if std is None else std[:, m], label=labels[m], units=units,
                       outliers=outliers[:, m] if rejected[:, m].any() else None, window=window, max_points=points)
        n_gaps = sum(1 for g in gaps if g["marker"] == labels[m])
        shown = "" if window is None else f" Frames {frames[window[0]]}-{frames[window[1] - 1]} shown."
        drawings.append((len(parts), draw, f"{escape(labels[m])}: {int(counts[m])} filled samples in {n_gaps} "
                         f"gap(s).{shown}", "marker", labels[m]))
        parts.append("")

    # Bone lengths.
    parts.append('<h2 id="bones">Bone lengths</h2>')
    pairs = np.zeros((0, 2), dtype=int) if bones is None else np.asarray(bones.pairs, dtype=int).reshape(-1, 2)
    lengths = np.zeros(0) if bones is None else np.asarray(bones.lengths, dtype=float).reshape(-1)
    touch = [b for b in range(len(pairs)) if (filled[:, pairs[b, 0]] | filled[:, pairs[b, 1]]).any()]
    if bones is None:
        parts.append("<p>No bones were given or estimated for this fill.</p>")
    elif not touch:
        parts.append(f"<p>None of the {len(pairs)} bones touches a filled marker.</p>")
    else:
        def dist(pos, a, b):
            return np.linalg.norm(pos[:, a] - pos[:, b], axis=1)

        errors = []
        for b in touch:
            a, c = pairs[b]
            either = filled[:, a] | filled[:, c]
            err = np.abs(dist(output, a, c)[either] - lengths[b])
            errors.append(np.nanmax(err) if np.isfinite(err).any() else 0.0)
        order = [touch[i] for i in np.argsort(-np.asarray(errors), kind="stable")]
        parts.append(f'<p class="note">{len(touch)} of {len(pairs)} bones touch a filled marker; the length of a '
                     "rigid pair should stay near its reference (dashed). Worst first.</p>")
        if len(order) > max_bones:
            left = [f"{labels[pairs[b, 0]]}\u2013{labels[pairs[b, 1]]}" for b in order[max_bones:]]
            parts.append(f'<p class="note">{len(left)} more bones not plotted: {escape(", ".join(left))}.</p>')
        for b in order[:max_bones]:
            a, c = pairs[b]
            name = f"{labels[a]} \u2013 {labels[c]}"
            either = filled[:, a] | filled[:, c]
            window = plots.plot_window(either)
            draw = partial(plots.bone_svg, frames, dist(observed, a, c), dist(output, a, c), float(lengths[b]),
                           either, name=name, units=units, window=window, max_points=points)
            shown = "" if window is None else f" Frames {frames[window[0]]}-{frames[window[1] - 1]} shown."
            drawings.append((len(parts), draw, f"Length of {escape(name)} in the input (breaks at gaps) and after "
                             f"the fill.{shown}", "bone", name))
            parts.append("")
    for (at, _, caption, kind, name), svg in zip(drawings, forked_map(_draw, [d[1] for d in drawings], jobs)):
        parts[at] = _figure(svg, caption, kind, name)

    parts.append('<h2 id="convergence">Convergence</h2>')
    objective = conv["objective"]
    if len([v for v in objective if v is not None]) >= 2:
        parts.append(_figure(plots.objective_svg(objective), "Objective per iteration.", "objective", "objective"))
    else:
        parts.append("<p>The method is direct (no objective to plot).</p>")
    info = {k: v for k, v in report["info"].items() if k not in ("gap_methods",)}
    if info:
        rows = [[escape(k), escape(v if not isinstance(v, (list, dict)) or len(str(v)) < 300 else str(v)[:300] + "...")]
                for k, v in info.items()]
        parts.append("<h3>Method details</h3>" + html_table(["key", "value"], rows, set()))

    if player:
        from .player import fit_player

        rest = sum(len(p.encode()) for p in parts)
        parts.insert(player_at, fit_player(data, rest, positions=output, filled=filled, std=std, rejected=rejected,
                                           gaps=report["gaps"], bones=bones))
    return page(title=f"mocapfill report: {title}", body="\n".join(parts), script=player)


def page(*, title: str, body: str, script: bool = False) -> str:
    """One self-contained HTML document around ``body``; ``script``: record script errors (the player's self-test)."""
    from .player import ERROR_HOOK

    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{escape(title)}</title>{ERROR_HOOK if script else ''}<style>{_CSS}</style></head>"
            f"<body><main>\n{body}\n</main></body></html>\n")
