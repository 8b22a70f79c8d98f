"""BoLeRO-HC / BoLeRO-SC on a small synthetic articulated body: contracts, info, exactness, options."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapfill.bones import BoneSet
from mocapfill.errors import MethodError
from mocapfill.methods.bolero import fill_bolero_hc, fill_bolero_sc
from mocapfill.methods.dynammo import fill_dynammo
from synthetic import moving_body, rot_x, rot_z

# Two rigid segments of three markers each, joined at a hinge, plus a free marker; the whole body drifts.
SEG_A = np.array([[0.0, 0.0, 0.0], [120.0, 10.0, 0.0], [60.0, 80.0, 20.0]])
SEG_B = np.array([[0.0, -150.0, 0.0], [40.0, -300.0, 10.0], [-30.0, -250.0, 30.0]])
BONES = np.array([[0, 1], [0, 2], [1, 2], [3, 4], [3, 5], [4, 5], [2, 3]])


def _body(n_frames=120):
    t = np.arange(n_frames) / 40.0

    def path(t):
        return np.stack([300 * t, 20 * np.sin(3 * t), 900.0 + 0 * t], axis=1)

    segments = moving_body(n_frames, body=np.vstack([SEG_A, SEG_B]), rate=40.0, path=path,
                           hinge=(slice(3, 6), lambda t: rot_x(0.8 * np.sin(2 * np.pi * 0.7 * t)), [0, 0, 0]),
                           rotation=lambda t: rot_z(0.3 * np.sin(2 * np.pi * 0.2 * t)))
    free = path(t) + np.stack([50 * np.cos(5 * t), 400 + 0 * t, 50 * np.sin(4 * t)], axis=1)  # no bone
    return np.concatenate([segments, free[:, None]], axis=1)


def _bones(pos):
    lengths = np.linalg.norm(pos[0, BONES[:, 0]] - pos[0, BONES[:, 1]], axis=1)
    # The hinge pair (2, 3) is not rigid; drop it so only true bones remain.
    keep = np.std(np.linalg.norm(pos[:, BONES[:, 0]] - pos[:, BONES[:, 1]], axis=2), axis=0) < 1e-6
    return BoneSet(BONES[keep], lengths[keep], np.zeros(keep.sum()), np.full(keep.sum(), len(pos)), "mm")


@pytest.fixture(scope="module")
def case():
    truth = _body()
    occluded = truth.copy()
    occluded[30:90, 4] = np.nan  # one marker of segment B
    occluded[50:75, 5] = np.nan  # and a second one of the same segment for part of it
    return truth, occluded, _bones(truth)


def _run(func, occluded, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return func(occluded, max_iter=15, seed=0, **kw)


def test_hc_bones_exact_and_observed_untouched(case):
    truth, occluded, bones = case
    res = _run(fill_bolero_hc, occluded, bones=bones)
    observed = ~np.isnan(occluded).any(axis=2)
    assert np.array_equal(res.positions[observed], occluded[observed])
    assert res.filled.sum() == np.isnan(occluded).any(axis=2).sum()
    assert res.info["bones"] == len(bones)
    assert res.info["bone_error_max_rel"] < 1e-6
    assert res.info["last_solve"]["infeasible_frames"] == 0
    assert res.info["solver_iterations"] > 0 and res.info["constraint_solves"] > 0


def test_hc_holds_the_bones_through_a_whole_body_blackout(case):
    truth, _, bones = case
    occluded = truth.copy()
    occluded[40:70] = np.nan  # every marker, 30 frames
    res = _run(fill_bolero_hc, occluded, bones=bones)
    assert np.isfinite(res.positions).all()
    assert res.info["infeasible_frames"] == 0 and res.info["bone_error_max_rel"] < 1e-6


def test_sc_keeps_bones_better_than_dynammo(case):
    truth, occluded, bones = case
    dyn = _run(fill_dynammo, occluded)
    sc = _run(fill_bolero_sc, occluded, bones=bones)
    hidden = np.isnan(occluded).any(axis=2)

    def bone_err(p):
        active = hidden[:, bones.pairs[:, 0]] | hidden[:, bones.pairs[:, 1]]
        d = np.linalg.norm(p[:, bones.pairs[:, 0]] - p[:, bones.pairs[:, 1]], axis=2)
        return np.abs(d - bones.lengths)[active].mean()

    assert bone_err(sc.positions) < bone_err(dyn.positions) / 3
    # (RMSE against DynaMMo is an accuracy property of real data: tests/test_accuracy_bolero.py.)
    assert sc.info["penalty"] > 0 and sc.info["variant"] == "soft"
    assert sc.info["last_solve"]["violation_after"] < sc.info["last_solve"]["violation_before"]


def test_zero_penalty_is_dynammo(case):
    _, occluded, bones = case
    dyn = _run(fill_dynammo, occluded)
    sc = _run(fill_bolero_sc, occluded, bones=bones, penalty=0.0)
    # The same engine with the same settings (gap-end bridge included); the hook only adds conversions.
    np.testing.assert_allclose(sc.positions, dyn.positions, rtol=0, atol=1e-6)


def test_bones_estimated_from_observed_samples_when_absent(case):
    _, occluded, _ = case
    res = _run(fill_bolero_sc, occluded, units="mm")
    assert res.info["bones"] > 0
    assert res.info["bones_source"].startswith("estimated")


def test_units_do_not_change_the_answer(case):
    _, occluded, bones = case
    mm = _run(fill_bolero_sc, occluded, bones=bones, units="mm")
    metres = BoneSet(bones.pairs, bones.lengths / 1000, bones.spread, bones.n_frames, "m")
    m = _run(fill_bolero_sc, occluded / 1000, bones=metres, units="m")
    np.testing.assert_allclose(m.positions * 1000, mm.positions, rtol=0, atol=1e-4)
    # Bones given in another unit are converted explicitly.
    conv = _run(fill_bolero_sc, occluded, bones=metres, units="mm")
    np.testing.assert_allclose(conv.positions, mm.positions, rtol=0, atol=1e-6)


def test_no_bones_and_blackout(case):
    truth, _, _ = case
    occluded = truth.copy()
    occluded[70:80] = np.nan  # whole-body blackout: bones among missing markers only
    occluded[20:30, 6] = np.nan  # a marker no bone holds
    bones = _bones(truth)
    res = _run(fill_bolero_hc, occluded, bones=bones)
    assert np.isfinite(res.positions).all()
    assert res.info["bone_error_max_rel"] < 1e-6
    empty = BoneSet(np.zeros((0, 2), int), np.zeros(0), np.zeros(0), np.zeros(0, int), "mm")
    res = _run(fill_bolero_sc, occluded, bones=empty)
    assert res.info["bones"] == 0 and np.isfinite(res.positions).all()


def test_marker_missing_throughout_does_not_switch_constraints_off(case):
    _, occluded, bones = case
    occluded = occluded.copy()
    occluded[:, 6] = np.nan  # the free marker, never observed
    res = _run(fill_bolero_hc, occluded, bones=bones)
    assert np.isnan(res.positions[:, 6]).all()
    assert np.isfinite(res.positions[:, :6]).all()
    assert res.info["bone_error_max_rel"] < 1e-6 and res.info["last_solve"]["frames"] > 0


def test_bad_options(case):
    _, occluded, bones = case
    with pytest.raises(MethodError, match="penalty"):
        fill_bolero_sc(occluded, bones=bones, penalty=-1.0)
    bad = BoneSet(np.array([[0, 99]]), [1.0], [0.0], [1], "mm")
    with pytest.raises(MethodError, match="out of range"):
        fill_bolero_hc(occluded, bones=bad)
    with pytest.raises(MethodError, match="project_start"):
        fill_bolero_hc(occluded, bones=bones, project_start=0)


def test_registered_and_callable_through_the_api(case):
    from mocapfill import api

    _, occluded, bones = case
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = api.fill(occluded, method="bolero-hc", bones=bones, max_iter=5, units="mm")
    assert res.info["method"] == "bolero-hc" and np.isfinite(res.positions).all()
