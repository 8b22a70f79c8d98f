"""What the default says it did, gap by gap: the records of ``info["gap_methods"]`` and ``info["displaced"]``.

Stage 6 of :mod:`mocapfill.methods.auto`: each record names the model that filled a gap, why, and whether a person
should review it; every number in a reason comes from the configuration (:class:`ModelConfig`) or from the fill.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..engines.weighted_pca import MIN_CV_FRAMES
from ..gaps import find_gaps, runs
from .auto_config import ModelConfig


def _partners_text(m: int, sl: slice, pairs: np.ndarray, acted: np.ndarray) -> list[tuple[int, int]]:
    """(partner, frames) of each pair of ``pairs`` (P, 2) with marker ``m`` at one end that ``acted`` (n_frames, P)
    marks somewhere in the frames ``sl``."""
    pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
    return [(int(pairs[k, 1] if pairs[k, 0] == m else pairs[k, 0]), int(acted[sl, k].sum()))
            for k in np.flatnonzero((pairs == m).any(axis=1) & acted[sl].any(axis=0))]


def _named(parts: list[tuple[int, int]], labels) -> str:
    return ", ".join(f"{labels[o] if labels is not None else o} ({n} frames)" for o, n in parts)


def broken_text(m: int, sl: slice, boneset, broken: np.ndarray | None, labels) -> str:
    """The reason's words for the bones of marker ``m`` left out during the frames ``sl`` (``broken`` (n_frames,
    n_bones) from :func:`~mocapfill.methods.auto.bone_breaks`; '' where none was)."""
    parts = [] if broken is None or not len(boneset) else _partners_text(m, sl, boneset.pairs, broken)
    return ("; left out where the predictions say the bone did not hold: the bone(s) to " + _named(parts, labels)
            if parts else "")


def stretched_text(m: int, sl: slice, reach, stretched: np.ndarray | None, labels) -> str:
    """The reason's words for the reaches of marker ``m`` its predictions stretched past during the frames ``sl``
    (``reach`` from :func:`mocapfill.bones.reach.reaches`, ``stretched`` (n_frames, n_reaches) from
    :func:`~mocapfill.methods.auto.bone_stage`; '' where none was)."""
    parts = [] if reach is None or stretched is None or not len(reach.pairs) else \
        _partners_text(m, sl, reach.pairs, stretched)
    return ("; pulled back within reach where the predictions put it farther than it was ever seen from: "
            + _named(parts, labels) if parts else "")


def share_text(share: float) -> str:
    """A share (0..1) of a gap's frames as a percentage that never reads 0 % for a part that is there, nor 100 % for
    one that is not whole: '<1%' and '>99%' at the ends."""
    if 0.0 < share < 0.005:
        return "<1%"
    if 0.995 <= share < 1.0:
        return ">99%"
    return f"{share:.0%}"


def on_bone(m: int, boneset) -> bool:
    """Whether marker ``m`` is an end of a bone of ``boneset`` (None or empty: no)."""
    return boneset is not None and bool(len(boneset)) and bool((np.asarray(boneset.pairs) == m).any())


def sd_clause(worst: float, config: ModelConfig, mm: float) -> str:
    """The reason's words for a gap's largest posterior sd ``worst`` (data units; NaN: none), with the review
    threshold where it is above :attr:`ModelConfig.review_sd_mm`."""
    flagged = not np.isfinite(worst) or worst > config.review_sd_mm * mm
    return (f"; largest posterior sd {worst / mm:.1f} mm"
            + (f" > {config.review_sd_mm:g} mm: review this gap" if flagged else ""))


def restate_record(record: dict, std: np.ndarray, *, config: ModelConfig, mm: float) -> dict:
    """A gap's record (:func:`gap_records`) restated for the sd its gap ended up with, ``std`` (length,): a long
    take's windows blend their sds where no window holds a gap whole, and the record is the heaviest window's.
    ``max_std``, the reason's :func:`sd_clause` and ``review`` follow the largest of ``std`` (a review that a run
    judged displaced beside the gap asked for stays); frames without an sd (NaN: no window filled them, e.g. a
    marker lost for good within a window that never sees it) are named and put the gap up for review.  A record
    without an sd, or whose sd is that one throughout, unchanged."""
    old = record.get("max_std")
    std = np.asarray(std, dtype=float)
    if old is None or not np.isfinite(std).any():
        return record
    worst = float(np.nanmax(std))
    left = int(np.sum(~np.isfinite(std)))
    if worst == old and not left:
        return record
    limit = config.review_sd_mm * mm
    out = dict(record, max_std=worst)
    before = sd_clause(old, config, mm)
    reason = record.get("reason")
    if isinstance(reason, str):
        if before in reason:
            reason = reason.replace(before, sd_clause(worst, config, mm), 1)
        if left:
            reason += (f"; {left} of its {len(std)} frames left missing: a long take is filled in windows of "
                       f"frames, and the windows over them never see the marker")
        out["reason"] = reason
    beside = bool(record.get("review")) and not old > limit  # flagged for another reason than its sd
    out["review"] = bool(worst > limit or beside or left)
    return out


def displaced_records(positions: np.ndarray, displaced: np.ndarray, edge: np.ndarray, mm: float, labels
                      ) -> list[dict]:
    """One JSON-ready record per observed run judged displaced (:func:`~mocapfill.methods.auto.displaced_runs`):
    ``marker``, ``marker_index``, ``start``, ``length`` and ``offset_mm``, the mean distance between the run's samples
    and the spatial model's reconstruction there.  positions / edge (n_frames, n_markers, 3), displaced (n_frames,
    n_markers).
    """
    out = []
    for m in np.flatnonzero(displaced.any(axis=0)):
        for start, length in runs(displaced[:, m]):
            sl = slice(start, start + length)
            with np.errstate(invalid="ignore"):
                dist = np.linalg.norm(positions[sl, m] - edge[sl, m], axis=1)
            offset = float(np.nanmean(dist)) / mm if np.isfinite(dist).any() else None
            out.append({"marker": labels[m] if labels is not None else int(m), "marker_index": int(m),
                        "start": int(start), "length": int(length), "offset_mm": offset})
    return out


def gap_records(missing: np.ndarray, sd: np.ndarray, spatial: np.ndarray, outliers: np.ndarray,
                config: ModelConfig, mm: float, labels, boneset, off: np.ndarray | None = None,
                displaced: np.ndarray | None = None, segment: np.ndarray | None = None,
                anchored: np.ndarray | None = None, spread: np.ndarray | None = None,
                broken: np.ndarray | None = None, reach=None, stretched: np.ndarray | None = None,
                globbed: np.ndarray | None = None, moved: np.ndarray | None = None,
                shown_by_references: np.ndarray | None = None) -> list[dict]:
    """Stage 6: one JSON-ready record per gap (run of missing frames of one marker).

    missing / sd / spatial / outliers (n_frames, n_markers): the input's mask, the posterior sd, where the spatial
    model predicted, where its prediction was down-weighted; off (n_frames, n_markers) or None: how far each
    prediction's pose lay off its model's training poses (:func:`~mocapfill.methods.auto.reported_sd`); displaced
    (n_frames, n_markers) or None: observed samples judged displaced (:func:`~mocapfill.methods.auto.displaced_runs`);
    segment (n_frames, n_markers) or None: where a segment model predicted (:attr:`ModelConfig.segment_mm`); anchored
    (n_frames, n_markers) or None: where the body anchor predicted (:func:`~mocapfill.methods.auto.anchor_stage`), not
    counted in ``spatial``; spread (n_frames, n_markers) or None: the variance of the spatial model's widths about
    their mix (:func:`~mocapfill.methods.auto.reported_sd`); broken (n_frames, n_bones) or None: where the bone stage
    left a bone of ``boneset`` out (:func:`~mocapfill.methods.auto.bone_breaks`); globbed (n_frames, n_markers) or
    None: where the global PCA predicted (:func:`~mocapfill.methods.auto.global_stage`), not counted in ``spatial``;
    moved (n_frames, n_markers) or None: how far the refit's bone stage moved each prediction
    (:attr:`ModelConfig.bone_move_sd`); shown_by_references (n_markers,) or None: the weighted reference frames that
    show each marker (what a marker the take never shows could be learnt from).
    ``review`` is True when the gap's largest sd exceeds ``config.review_sd_mm`` (or nothing could be filled) or a
    run judged displaced touches it; every number in ``reason`` comes from ``config`` or from the fill.
    """
    limit = config.review_sd_mm * mm
    out = []
    for gap in find_gaps(missing):
        m, sl = gap.marker, slice(gap.start, gap.stop)
        rec: dict[str, Any] = {"marker": labels[m] if labels is not None else int(m), "marker_index": int(m),
                               "start": int(gap.start), "length": int(gap.length)}
        unseen = bool(missing[:, m].all())
        if unseen and not np.isfinite(sd[sl, m]).any():
            shown = 0 if shown_by_references is None else int(shown_by_references[m])
            why = ("nor from a reference take: none given shows it, or none fits this body" if not shown else
                   f"the reference takes show it in {shown} frame(s), fewer than the {MIN_CV_FRAMES} a model "
                   "cross-validates on")
            rec.update(method="none", reason=f"marker missing in every frame: nothing to learn from ({why})",
                       review=True, max_std=None)
            out.append(rec)
            continue
        worst = float(np.nanmax(sd[sl, m])) if np.isfinite(sd[sl, m]).any() else float("nan")
        share = float(spatial[sl, m].mean())
        by_anchor = 0.0 if anchored is None else float(anchored[sl, m].mean())
        by_global = 0.0 if globbed is None else float(globbed[sl, m].mean())
        anchor_text = ("the body anchor (the position the markers seen with it give by their mean offsets, no "
                       f"rotation) predicted {share_text(by_anchor)} of the frames")
        global_text = (f"the global weighted PCA (the `pca` method, weighed with an sd of {config.global_sd_mm:g} mm) "
                       f"predicted {share_text(by_global)} of the frames")
        others = [text for text, part in ((global_text, by_global), (anchor_text, by_anchor)) if part > 0]
        if share == 0 and others:
            method = "global-pca+motion" if by_global > 0 else "anchor+motion"
            reason = (f"no local model could predict it: {'; '.join(others)}, fused with the white-jerk motion model "
                      f"by the smoother")
            if by_anchor + by_global < 1:
                reason += "; the motion model bridges the rest"
        elif share == 0:
            method = "motion"
            reason = ("no spatial prediction (fewer than 3 observed neighbours or too few training frames): the "
                      "white-jerk motion model bridges the gap from its ends")
        else:
            method = "local-pca+motion"
            reason = (f"local weighted PCA predicted {share_text(share)} of the frames, fused with the white-jerk "
                      f"motion model by the smoother")
            for text in others:
                reason += f"; {text}"
            if share + by_anchor + by_global < 1:
                reason += "; the motion model bridges the rest"
            by_segment = segment is not None and bool(segment[sl, m].any())
            if by_segment:
                reason += (f"; the prediction is its segment model's (the markers within {config.segment_mm:g} mm "
                           f"observed throughout the gap), where the neighbourhood model extrapolated more")
            if on_bone(m, boneset) and not by_segment:  # (a marker on no bone: the bone stage never moves it)
                reason += "; predictions refined with the bone lengths"
                reason += broken_text(m, sl, boneset, broken, labels)
            if not by_segment:
                reason += stretched_text(m, sl, reach, stretched, labels)
            n_out = int(outliers[sl, m].sum())
            if n_out:
                reason += (f"; {n_out} prediction(s) more than {config.outlier:g} sd off the smoothed path "
                           f"down-weighted")
        if unseen:  # filled all the same: reference frames showed the marker
            reason += ("; the frames it was filled in never show this marker: it was learnt from reference frames "
                       "alone (the reference takes; on a long take, its frames that show it), which the take "
                       "cannot check: review this gap")
        uncertain = not np.isfinite(worst) or worst > limit
        far = float(np.nanmax(off[sl, m])) if off is not None and np.isfinite(off[sl, m]).any() else None
        reason += sd_clause(worst, config, mm)
        if uncertain and far is not None and far > 1.0:
            reason += (f" (the neighbours took poses the spatial model never learnt: its sd raised up to "
                       f"{np.sqrt(far):.1f}x)")
        apart = float(np.sqrt(np.nanmax(spread[sl, m]))) if spread is not None and np.isfinite(spread[sl, m]).any() \
            else 0.0
        if uncertain and apart > limit:
            reason += (f" (the spatial model's {len(config.scales_mm)} widths disagree there by up to "
                       f"{apart / mm:.1f} mm per coordinate)")
        pulled = float(np.max(moved[sl, m])) if moved is not None else 0.0
        if uncertain and pulled / np.sqrt(3.0) > limit:
            reason += (f" (the bones and reaches moved its predictions by up to {pulled / mm:.1f} mm, a correction "
                       f"its sd counts as uncertain by as much)")
        # (lengths, not frame numbers: a long take's windows shift the records' starts, not their texts)
        beside = [] if displaced is None else [
            (side, int(np.argmin(np.append(displaced[a::step, m], False))))  # the run's length from its edge
            for side, a, step in (("before", gap.start - 1, -1), ("after", gap.stop, 1))
            if 0 <= a < len(missing) and displaced[a, m]]
        for side, length in beside:
            reason += (f"; the observed run of {length} frame(s) just {side} it lies farther off the spatial model "
                       f"than its sd explains (odds with a {config.displaced_prior:.0%} prior of a displaced run, "
                       f"{config.displacement_mm:g} mm per axis): judged displaced (a swap or ghost marker), kept in "
                       f"the output but not followed by the fill: review it")
        review = uncertain or bool(beside) or unseen  # (a model the take cannot check: an offset its sd misses)
        rec.update(method=method, reason=reason, review=bool(review),
                   max_std=None if not np.isfinite(worst) else worst, extrapolation=far)
        out.append(rec)
    return out
