"""The report's plots, each drawn with matplotlib into an SVG string for inlining in the HTML page.

matplotlib is optional (the extra ``mocapfill[report]``) and imported only inside these functions.  Figures are made
with :class:`matplotlib.figure.Figure` directly, never through ``pyplot``, so no global state (backend, open
figures) is touched; rc settings apply only inside :func:`_rc`.  Long clips are decimated for drawing (at most
``max_points`` points per line) so that a page stays a few megabytes at most.
"""

from __future__ import annotations

import contextlib
import io
import re
from typing import Iterator, Sequence

import numpy as np

from ..errors import MocapfillError

#: Colours (colour-blind safe: Okabe-Ito) shared by the plots and the HTML legend.
OBSERVED = "#222222"
FILLED = "#D55E00"
BAND = "#E69F00"
UNFILLED = "#999999"
REJECTED = "#CC79A7"
REFERENCE = "#0072B2"
AXIS_COLOURS = ("#0072B2", "#009E73", "#D55E00")  # x, y, z in the gap map legend only

MISSING_MESSAGE = "HTML reports need matplotlib: pip install 'mocapfill[report]'"


def _matplotlib():
    try:
        import matplotlib
        from matplotlib.figure import Figure
    except ImportError:
        raise MocapfillError(MISSING_MESSAGE) from None
    return matplotlib, Figure


@contextlib.contextmanager
def _rc() -> Iterator[type]:
    """Temporary rc settings for report figures; yields the Figure class."""
    matplotlib, Figure = _matplotlib()
    settings = {
        "svg.fonttype": "none",  # text stays text: smaller, searchable, rendered by the browser's fonts
        "svg.hashsalt": "mocapfill",  # deterministic element ids
        "font.size": 9,
        "axes.spines.top": False,
        "axes.spines.right": False,
        "axes.grid": True,
        "grid.alpha": 0.3,
        "path.simplify": True,
    }
    with matplotlib.rc_context(settings):
        yield Figure


_GEOMETRY = re.compile(r'\s(?:d|x|y|x1|x2|y1|y2|width|height)="[^"]*"')
_DECIMALS = re.compile(r"(\d\.\d)\d+")


def svg_of(fig, *, tight: bool = False) -> str:
    """The SVG markup of ``fig`` without the XML prolog, ready to inline in HTML.

    ``tight`` crops to the drawn content, at the cost of a second draw; the time-series plots use fixed margins
    instead because a report draws dozens of them.
    """
    buf = io.StringIO()
    # (no date in the metadata: the same fill draws the same page, wherever and whenever it is drawn)
    fig.savefig(buf, format="svg", bbox_inches="tight" if tight else None, metadata={"Date": None})
    text = buf.getvalue()
    # Coordinates to 0.1 pt (a tenth of a screen pixel) in path data and positions: about half the size.
    text = _GEOMETRY.sub(lambda m: _DECIMALS.sub(r"\1", m.group(0)), text)
    text = re.sub(r"<\?xml[^>]*\?>\s*", "", text)
    text = re.sub(r"<!DOCTYPE[^>]*>\s*", "", text, flags=re.S)
    return text.strip()


def _stride(n: int, max_points: int) -> int:
    return max(1, -(-n // max_points))


def _spans(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the runs of True in a 1-D mask."""
    from ..gaps import runs

    return [(s, s + n) for s, n in runs(mask)]


def _shade(ax, frames: np.ndarray, mask: np.ndarray, colour: str, alpha: float, label: str | None = None) -> None:
    """Shade the frames of the runs of ``mask`` (shape (n,)) on ``ax``; each run spans half a frame either side.

    One collection for all runs (not one patch per run): a clip with hundreds of gaps stays quick to draw."""
    from matplotlib.collections import PolyCollection

    spans = _spans(mask)
    if not spans:
        return
    verts = [[(frames[a] - 0.5, 0), (frames[a] - 0.5, 1), (frames[b - 1] + 0.5, 1), (frames[b - 1] + 0.5, 0)]
             for a, b in spans]
    ax.add_collection(PolyCollection(verts, transform=ax.get_xaxis_transform(), facecolors=colour, alpha=alpha,
                                     linewidths=0, label=label), autolim=False)


def _margins(fig, *, top: float) -> None:
    """Fixed margins for the time-series figures (room for y tick labels such as "-1,500" and the legend row)."""
    fig.subplots_adjust(left=0.09, right=0.985, bottom=0.2 if top < 0.9 else 0.1, top=top, hspace=0.12)


#: The +-2 std band is an envelope, not the fill: at most ``max_points // BAND_FRACTION`` points of it per plot (its
#: polygon was three quarters of a trajectory plot's bytes, 68 of 91 KB, on a capture filled in long stretches).
BAND_FRACTION = 4


def band_outline(frames: np.ndarray, centre: np.ndarray, sd: np.ndarray, max_points: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The +-2 ``sd`` band around ``centre`` for :meth:`fill_between`, thinned to about ``max_points`` points.

    frames, centre, sd : (n,), sd NaN outside the filled samples.  Every filled stretch keeps its first and last
    sample (a stretch of one frame stays a dot-wide band); stretches are separated by NaN.  Returns x, centre and
    half-width (2 sd) arrays.
    """
    spans = _spans(np.isfinite(sd) & np.isfinite(centre))
    step = _stride(sum(b - a for a, b in spans), max_points)
    pieces = [np.unique(np.r_[np.arange(a, b, step), b - 1]) for a, b in spans]
    if not pieces:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    gap = np.array([-1])  # a NaN between stretches: fill_between leaves it open
    idx = np.concatenate([np.r_[p, gap] for p in pieces])[:-1]
    take = np.where(idx >= 0, idx, 0)
    x = np.where(idx >= 0, frames[take].astype(float), np.nan)
    return x, np.where(idx >= 0, centre[take], np.nan), np.where(idx >= 0, 2.0 * sd[take], np.nan)


def trajectory_svg(frames: np.ndarray, observed: np.ndarray, output: np.ndarray, filled: np.ndarray,
                   unfilled: np.ndarray, std: np.ndarray | None, *, label: str, units: str,
                   outliers: np.ndarray | None = None, window: tuple[int, int] | None = None,
                   max_points: int = 1000) -> str:
    """x, y, z of one marker over time: input observed in black, filled samples in orange on shaded stretches,
    a +-2 std band where ``std`` is given, still-missing stretches in grey, rejected outliers as pink crosses.

    frames : (n,) frame numbers; observed / output : (n, 3) input and output positions (NaN = missing);
    filled / unfilled : (n,) bool; std : (n,) or None; outliers : (n, 3) rejected input samples (NaN elsewhere) or
    None; window : (start, stop) indices to show (default the whole clip).
    """
    if window is not None:
        sl = slice(*window)
        frames, observed, output, filled, unfilled = (a[sl] for a in (frames, observed, output, filled, unfilled))
        std = None if std is None else std[sl]
        outliers = None if outliers is None else outliers[sl]
    with _rc() as Figure:
        fig = Figure(figsize=(9.0, 4.6))
        axes = fig.subplots(3, 1, sharex=True)
        step = _stride(len(frames), max_points)
        # The filled curve is drawn at full resolution (it is what the reader checks) and joined to its observed
        # neighbours so that a short gap shows as a line, not a dot; the input is decimated on long clips.
        edge = filled | np.r_[filled[1:], False] | np.r_[False, filled[:-1]]
        filled_curve = np.where(edge[:, None], output, np.nan)
        band = None
        if std is not None:
            s = np.where(filled, std, np.nan)
            if np.isfinite(s).any():
                band = s
        # Only when the filled samples themselves are too many to draw one by one are they decimated too.
        fstep = _stride(int(edge.sum()), max_points)
        band_points = max(max_points // BAND_FRACTION, 2)
        has_outliers = outliers is not None and np.isfinite(outliers).any()
        for k, ax in enumerate(axes):
            first = k == 0
            _shade(ax, frames, filled, FILLED, 0.10, "filled stretch" if first else None)
            _shade(ax, frames, unfilled, UNFILLED, 0.25, "left unfilled" if first else None)
            if band is not None:
                x, mid, half = band_outline(frames, output[:, k], band, band_points)
                ax.fill_between(x, mid - half, mid + half, color=BAND, alpha=0.35, lw=0,
                                label="filled \u00b1 2 std" if first else None)
            ax.plot(frames[::step], observed[::step, k], color=OBSERVED, lw=0.9, label="input" if first else None)
            ax.plot(frames[::fstep], filled_curve[::fstep, k], color=FILLED, lw=1.3,
                    label="filled" if first else None)
            if has_outliers:
                ax.plot(frames, outliers[:, k], ls="none", marker="x", ms=4, color=REJECTED,
                        label="rejected outlier" if first else None)
            ax.set_ylabel(f"{'xyz'[k]} ({units})")
            ax.margins(x=0)
        axes[-1].set_xlabel("frame")
        axes[0].set_title(label, loc="left", fontsize=10, fontweight="bold")
        axes[0].legend(loc="lower right", fontsize=7, ncol=5, frameon=False, bbox_to_anchor=(1.0, 1.0))
        _margins(fig, top=0.92)
        return svg_of(fig)


def plot_window(mask: np.ndarray, *, min_margin: int = 30, max_fraction: float = 0.6) -> tuple[int, int] | None:
    """Frames to show for a marker whose filled samples are ``mask`` (n,) bool: the span of the filled stretches
    with a margin of one longest-stretch (at least ``min_margin`` frames) each side, or None (the whole clip) when
    that span covers more than ``max_fraction`` of the clip anyway."""
    idx = np.flatnonzero(mask)
    n = len(mask)
    if not idx.size:
        return None
    longest = max(stop - start for start, stop in _spans(mask))
    margin = max(min_margin, longest)
    start, stop = max(0, idx[0] - margin), min(n, idx[-1] + 1 + margin)
    if stop - start > max_fraction * n:
        return None
    return int(start), int(stop)


def bone_svg(frames: np.ndarray, before: np.ndarray, after: np.ndarray, reference: float, filled: np.ndarray, *,
             name: str, units: str, window: tuple[int, int] | None = None, max_points: int = 1000) -> str:
    """Length of one bone over time: in the input (breaks at gaps) and in the output, against its reference length
    (the BoLeRO paper's Figures 1 and 3).  frames, before, after : (n,); filled : (n,) bool (either end filled);
    window : (start, stop) indices to show (default the whole clip)."""
    if window is not None:
        sl = slice(*window)
        frames, before, after, filled = frames[sl], before[sl], after[sl], filled[sl]
    with _rc() as Figure:
        fig = Figure(figsize=(9.0, 2.4))
        ax = fig.subplots()
        step = _stride(len(frames), max_points)
        _shade(ax, frames, filled, FILLED, 0.10, "filled stretch")
        ax.plot(frames[::step], after[::step], color=FILLED, lw=1.1, label="after fill")
        ax.plot(frames[::step], before[::step], color=OBSERVED, lw=1.1, label="input")
        if np.isfinite(reference):
            ax.axhline(reference, color=REFERENCE, lw=1.0, ls="--", label=f"reference {reference:.4g} {units}")
        ax.set_ylabel(f"length ({units})")
        ax.set_xlabel("frame")
        ax.margins(x=0)
        ax.set_title(name, loc="left", fontsize=10, fontweight="bold")
        ax.legend(loc="lower right", fontsize=7, ncol=4, frameon=False, bbox_to_anchor=(1.0, 1.0))
        _margins(fig, top=0.85)
        return svg_of(fig)


def objective_svg(objective: Sequence[float | None]) -> str:
    """The objective per iteration (e.g. DynaMMo's negative expected log-likelihood); non-finite values skipped."""
    values = np.array([np.nan if v is None else float(v) for v in objective], dtype=float)
    with _rc() as Figure:
        fig = Figure(figsize=(6.0, 2.6))
        ax = fig.subplots()
        ax.plot(np.arange(1, len(values) + 1), values, color=REFERENCE, lw=1.2, marker="." if len(values) < 60 else None)
        ax.set_xlabel("iteration")
        ax.set_ylabel("objective")
        return svg_of(fig, tight=True)


def gap_map_svg(status: np.ndarray, labels: Sequence[str], first_frame: int, *, max_columns: int = 1500) -> str:
    """Overview of the whole capture: one row per marker, one column per frame, coloured by what the fill did.

    status : (n_frames, n_markers) int, 0 observed, 1 filled, 2 left unfilled, 3 rejected outlier then filled,
    4 rejected and left unfilled.  Columns are max-pooled (the worst status wins) down to ``max_columns``.
    """
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    n_frames, n_markers = status.shape
    step = _stride(n_frames, max_columns)
    if step > 1:
        pad = (-n_frames) % step
        padded = np.pad(status, ((0, pad), (0, 0)))
        # Worst status per block: unfilled beats rejected beats filled beats observed.
        rank = np.array([0, 1, 4, 2, 3])[padded]
        pooled = rank.reshape(-1, step, n_markers).max(axis=1)
        status = np.array([0, 1, 3, 4, 2])[pooled]
    colours = ["#F2F2F2", FILLED, UNFILLED, REJECTED, "#7A3B69"]
    cmap = ListedColormap(colours)
    with _rc() as Figure:
        height = min(0.16 * n_markers + 1.2, 14.0)
        fig = Figure(figsize=(9.0, height))
        ax = fig.subplots()
        ax.imshow(status.T, aspect="auto", interpolation="nearest", cmap=cmap, vmin=-0.5, vmax=4.5,
                  extent=(first_frame - 0.5, first_frame + n_frames - 0.5, n_markers - 0.5, -0.5))
        ax.grid(False)
        if n_markers <= 80:
            ax.set_yticks(range(n_markers))
            ax.set_yticklabels(labels, fontsize=6 if n_markers > 40 else 7)
        else:
            ax.set_ylabel("marker")
        ax.set_xlabel("frame")
        handles = [Patch(color=c, label=t) for c, t in
                   zip(colours, ["observed", "filled", "left unfilled", "outlier, filled", "outlier, unfilled"])]
        present = sorted(set(np.unique(status).tolist()) | {0})
        ax.legend(handles=[handles[i] for i in present], loc="lower left", bbox_to_anchor=(0, 1.0), ncol=5,
                  fontsize=7, frameon=False)
        return svg_of(fig, tight=True)
