"""The default fill (``--method auto``) and its parts: local-frame weighted PCA and the bone refinement."""

from __future__ import annotations

import json

import numpy as np
import pytest

import mocapfill
from mocapfill.bones import BoneSet
from mocapfill.errors import MethodError
from mocapfill.methods import get_method
from mocapfill.methods.auto_stack import fill_auto_stack
from mocapfill.bones.refinement import refine_bones
from mocapfill.engines.local_pca import edge_shift, fill_local_pca, kabsch_rotations
from synthetic import tumbling_body


def test_auto_stack_is_registered():
    assert get_method("auto-stack").load() is fill_auto_stack


def test_kabsch_recovers_rotations():
    rng = np.random.default_rng(0)
    ref = rng.normal(size=(5, 3))
    ref -= ref.mean(axis=0)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    shapes = (ref @ q.T)[None]
    rot = kabsch_rotations(shapes, ref, np.ones(5))
    assert np.allclose(shapes[0] @ rot[0], ref, atol=1e-10)


def test_edge_shift_meets_both_ends_and_relaxes_in_long_gaps():
    rb, ra = np.array([1.0, 0.0, 0.0]), np.array([0.0, 2.0, 0.0])
    shift, factor = edge_shift(rb, ra, 200, 10.0)
    assert np.allclose(shift[0], rb * np.exp(-0.1), atol=0.01) and np.allclose(shift[-1], ra * np.exp(-0.1),
                                                                                atol=0.02)
    assert np.abs(shift[100]).max() < 1e-3  # far from both ends the residual is forgotten
    assert factor[0] < 0.2 and factor[100] == pytest.approx(1.0)
    lin, _ = edge_shift(rb, ra, 3, "linear")
    assert np.allclose(lin[1], (rb + ra) / 2)


def test_local_frame_beats_the_published_pca_on_a_tumbling_body():
    truth = tumbling_body()
    pos = truth.copy()
    pos[100:180, 4] = np.nan
    hidden = np.isnan(pos).any(axis=2)
    pca = mocapfill.fill(pos, "pca").positions
    local = fill_local_pca(pos).positions
    err_pca = np.linalg.norm(pca - truth, axis=2)[hidden].max()
    err_local = np.linalg.norm(local - truth, axis=2)[hidden].max()
    assert err_local < 1.0 < err_pca  # mm: rigid in its own frame, so the local fill is near exact


def test_bone_refinement_pulls_a_loose_estimate_onto_a_rigid_bone():
    positions = np.array([[[0.0, 0.0, 0.0], [np.nan] * 3]])  # (1 frame, 2 markers, 3)
    estimate = np.array([[[0.0, 0.0, 0.0], [120.0, 0.0, 0.0]]])
    std = np.array([[0.0, 20.0]])
    out, info = refine_bones(estimate, positions, std, np.array([[0, 1]]), np.array([100.0]), np.array([1.0]),
                             spread_floor=1.0)
    assert np.linalg.norm(out[0, 1]) == pytest.approx(100.0, abs=0.5)  # sure bone, unsure estimate: bone wins
    out2, _ = refine_bones(estimate, positions, np.array([[0.0, 0.1]]), np.array([[0, 1]]), np.array([100.0]),
                           np.array([30.0]), spread_floor=1.0)
    assert np.linalg.norm(out2[0, 1]) == pytest.approx(120.0, abs=0.1)  # sure estimate, loose bone: estimate wins
    assert info["frames"] == 1 and info["bone_error_after"] < info["bone_error_before"]


def test_auto_records_which_method_filled_each_gap(sample_data):
    data = mocapfill.read(sample_data / "kinematics_tennis_serve_nan.c3d")
    res = mocapfill.fill(data, "auto-stack")
    assert res.info["method"] == "auto-stack"
    assert not np.isnan(res.positions).any()
    observed = ~data.missing
    assert np.array_equal(res.positions[observed], data.positions[observed])
    gaps = res.info["gap_methods"]
    assert len(gaps) == len(mocapfill.gaps.find_gaps(data.missing)) == 10
    for rec in gaps:
        assert set(rec) == {"marker", "marker_index", "start", "length", "method", "reason"}
        assert rec["marker"] == data.labels[rec["marker_index"]]
        assert rec["method"] in ("local-pca", "local-pca+bones") and rec["reason"]
    json.dumps(res.info)  # reports embed it
    assert res.std is not None and np.isfinite(res.std[res.filled]).all() and (res.std[res.filled] > 0).all()


def test_fallback_and_never_observed_markers_are_reported():
    pos = tumbling_body(n_markers=5)
    pos[:, 4] = np.nan  # never observed
    pos[50:60] = np.nan  # short blackout (0.1 s): no neighbour to predict from, a spline bridges it
    pos[100:140, 1] = np.nan
    pos[200:280] = np.nan  # long blackout (0.8 s): the dynamics guide (BoLeRO-SC: the body has bones)
    res = fill_auto_stack(pos, labels=["a", "b", "c", "d", "e"], rate=100.0)
    methods = {(r["marker"], r["start"]): r["method"] for r in res.info["gap_methods"]}
    assert methods[("e", 0)] == "none"
    assert methods[("a", 50)] == "spline" and methods[("a", 200)].startswith("bolero-sc")
    assert res.info["fallback_guide"] == "bolero-sc"
    assert methods[("b", 100)].startswith("local-pca")
    assert res.info["spline_max_frames"] == 50
    truth = tumbling_body(n_markers=5)
    spline_err = np.linalg.norm(res.positions[50:60, :4] - truth[50:60, :4], axis=2).max()
    linear = np.linspace(0, 1, 12)[1:-1, None, None]
    straight = (1 - linear) * truth[49, :4] + linear * truth[60, :4]
    assert spline_err < np.linalg.norm(straight - truth[50:60, :4], axis=2).max()
    assert np.isnan(res.positions[:, 4]).all() and np.isfinite(res.positions[:, :4]).all()


def test_bones_option(sample_data):
    data = mocapfill.read(sample_data / "85_02.c3d")
    pos = data.positions[:300].copy()
    pos[100:180, [5, 6]] = np.nan  # knee and shin
    plain = fill_auto_stack(pos, bones=False)
    assert "bone_refinement" not in plain.info and plain.info["bones"] == 0
    given = BoneSet(np.array([[5, 6]]), np.array([np.linalg.norm(data.positions[0, 5] - data.positions[0, 6])]),
                    np.array([2.0]), np.array([300]), "mm")
    res = fill_auto_stack(pos, bones=given)
    assert res.info["bones"] == 1 and res.info["bone_refinement"]["frames"] == 80
    with pytest.raises(MethodError, match="BoneSet"):
        fill_auto_stack(pos, bones=[(5, 6)])
    metres = fill_auto_stack(pos / 1000.0, units="m", bones=given)  # the bones are converted to the data's units
    assert np.allclose(metres.positions * 1000.0, res.positions, atol=1e-3)


def walk_out(seed: int) -> np.ndarray:
    """A wobbling marker cloud (mm, 300 frames at 100 Hz, 9 markers) leaving the volume: marker 0 vanishes at frame
    200, five neighbours at 220, one at 240, the last two at 260, so the local PCA of marker 0 ends up defined by
    only three neighbours.  (n_frames, n_markers, 3), NaN = missing."""
    rng = np.random.default_rng(seed)
    pos = tumbling_body(n_markers=9, seed=seed)
    pos = pos + 0.3 * rng.normal(scale=8.0, size=pos.shape).cumsum(axis=0)  # non-rigid: the PCA is not exact
    pos[200:, 0] = np.nan
    pos[220:, 1:6] = np.nan
    pos[240:, 6] = np.nan
    pos[260:, 7:] = np.nan
    return pos


def _worst_step_ratio(filled: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Per marker (n_markers,): largest frame-to-frame step touching a filled sample over the largest observed one."""
    missing = np.isnan(positions).any(axis=2)
    step = np.linalg.norm(np.diff(filled, axis=0), axis=2)
    touched = missing[1:] | missing[:-1]
    seen = ~touched
    out = np.zeros(positions.shape[1])
    for m in range(positions.shape[1]):
        if touched[:, m].any():
            out[m] = step[touched[:, m], m].max() / step[seen[:, m], m].max()
    return out


def test_markers_vanishing_one_by_one_give_no_jumps():
    # Without the trust check (every PCA sample believed) these fills stepped 2-9x the largest observed step.
    from mocapfill.methods.auto_stack import STEP_BOUND

    for seed in (0, 2):
        pos = walk_out(seed)
        res = fill_auto_stack(pos, rate=100.0)
        assert (_worst_step_ratio(res.positions, pos) < STEP_BOUND).all()
        rec = next(r for r in res.info["gap_methods"] if r["marker_index"] == 0)
        assert "+fallback" in rec["method"] and "blended smoothly" in rec["reason"]
        assert np.isfinite(res.positions[:, :9]).all()


def test_trust_ramps_instead_of_switching():
    from mocapfill.methods.auto_stack import limit_trust_changes

    trust = np.zeros((40, 1))
    trust[:20] = 1.0
    gap = np.ones((40, 1), dtype=bool)
    alpha = limit_trust_changes(trust, np.full((40, 1), 100.0), np.array([10.0]), gap)
    assert alpha[0, 0] == 1.0 and alpha[20:].max() == 0.0
    assert np.abs(np.diff(alpha[:, 0])).max() <= 0.1 + 1e-12  # 10 units per frame over a 100-unit disagreement
    assert (alpha <= trust).all()  # trust is only ever lowered


def test_walk_out_of_the_volume_real_capture(shared_data):
    # VER4C3D: the left toe is last seen at frame 231 of 281 while the other markers vanish one by one; the local
    # PCA, defined by the last few neighbours, jumped by up to 700 mm between frames.
    data = mocapfill.read(shared_data / "c3d-org" / "sample_09" / "VER4C3D.c3d")
    toe = data.labels.index("LTOE")
    pos = data.positions[150:]
    res = fill_auto_stack(pos, labels=data.labels, rate=data.rate)
    assert _worst_step_ratio(res.positions[:, [toe]], pos[:, [toe]])[0] <= 1.5
    rec = next(r for r in res.info["gap_methods"] if r["marker"] == "LTOE" and r["start"] == 232 - 150)
    assert "+fallback" in rec["method"]


def test_the_dynamics_guide_runs_on_gappy_captures_only(sample_data):
    """Short gaps everywhere (Holden's random protocol) run the guide; one marker's long gap does not."""
    from mocapfill.methods.auto_stack import dynamics_guide

    data = mocapfill.read(sample_data / "85_02.c3d")
    positions = data.positions[:240].copy()
    trust = np.ones(positions.shape[:2])
    one = positions.copy()
    one[50:150, 3] = np.nan  # 100 frames of one marker: >= 50 % of the frames stay complete
    gap = np.isnan(one).any(axis=2)
    assert dynamics_guide(one, trust, gap, 50)[2] == "none"
    rng = np.random.default_rng(0)
    gappy = positions.copy()
    for m in range(gappy.shape[1]):
        for start in rng.choice(np.arange(0, 230, 12), size=2, replace=False):  # 2 x 12 frames per marker: 10 %
            gappy[start:start + 12, m] = np.nan
    gap = np.isnan(gappy).any(axis=2)
    assert gap.mean() > 0.07 and (~gap.any(axis=1)).mean() < 0.10
    guide, _, name = dynamics_guide(gappy, np.ones(gap.shape), gap, 50)  # 240 frames > 4 x 50
    assert dynamics_guide(gappy[:200], np.ones((200, gap.shape[1])), gap[:200], 50)[2] == "none"  # too short
    assert name == "dynammo" and np.isfinite(guide[gap]).all()
