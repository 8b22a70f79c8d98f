"""Reaches (:mod:`mocapfill.bones.reach`): the pairs a fill may not stretch past their largest observed distance,
and the bone refinement's one-sided terms that hold them."""

from __future__ import annotations

import numpy as np
import pytest

from mocapfill.bones.reach import reaches
from mocapfill.bones.refinement import refine_bones


def _arm(n=200, seed=0):
    """An elbow at the origin, a wrist 250 mm from it swinging through 120 degrees, a shoulder 300 mm above the
    elbow and a hand 80 mm past the wrist (rigid with it): (n, 4, 3) in mm."""
    rng = np.random.default_rng(seed)
    angle = np.linspace(0.0, 2.0 * np.pi / 3.0, n)
    fore = np.stack([np.cos(angle), np.sin(angle), np.zeros(n)], axis=1)
    elbow = np.zeros((n, 3))
    wrist = 250.0 * fore
    hand = 330.0 * fore
    shoulder = np.tile([0.0, 0.0, 300.0], (n, 1))
    return np.stack([shoulder, elbow, wrist, hand], axis=1) + rng.normal(scale=0.5, size=(n, 4, 3))


def _shells(n=300, seed=1):
    """Marker 0 and three partners about it, each pair turning through half a turn: partner 1 at 100 +- 20 mm (a thick
    shell), partner 2 at 400 +- 4 mm (the thinnest for its size), partner 3 at 200 +- 10 mm: (n, 4, 3) in mm."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, np.pi, n)
    pos = np.zeros((n, 4, 3))
    for j, (radius, wobble, phase) in enumerate(((100.0, 20.0, 0.0), (400.0, 4.0, 1.0), (200.0, 10.0, 2.0)), start=1):
        r = radius + wobble * np.sin(7.0 * t + phase)
        pos[:, j] = r[:, None] * np.stack([np.cos(t + phase), np.sin(t + phase), 0.1 * np.ones(n)], axis=1)
    return pos + rng.normal(scale=0.1, size=pos.shape)


def test_reaches_are_the_tightest_partners_that_are_not_bones_with_their_largest_distance():
    pos = _shells()
    d = np.linalg.norm(pos[:, :, None] - pos[:, None, :], axis=3)
    gapped = pos.copy()
    gapped[:1, 0] = np.nan  # marker 0 has a gap; its partners none (only markers with gaps choose)
    r = reaches(gapped, np.zeros((0, 2), dtype=int), partners=2, turned_deg=0.0)
    assert r.pairs.tolist() == [[0, 2], [0, 3]]  # the thinnest shells for their size, not the nearest
    for (a, b), limit in zip(r.pairs, r.limit):
        assert limit == d[1:, a, b].max()
    # the robust spread of a sinusoid of amplitude A: its 5-95 % range 2 A cos(0.05 pi) over 3.29
    assert np.allclose(r.spread, 2.0 * np.array([4.0, 10.0]) * np.cos(0.05 * np.pi) / 3.29, rtol=0.05)
    assert reaches(gapped, np.array([[0, 2]]), partners=2, turned_deg=0.0).pairs.tolist() == [[0, 1], [0, 3]]
    none = np.zeros((0, 2), dtype=int)
    assert len(reaches(pos, none, partners=3, turned_deg=0.0).pairs) == 0  # no gaps: nothing to hold


def test_a_pair_that_never_turned_is_no_reach():
    """The shoulder and elbow stood still (their largest distance was seen in one pose: no reach); the forearm swept
    120 degrees about the elbow (the 95th percentile of its angle to the mean direction is about 57 degrees)."""
    from mocapfill.bones.reach import turned

    pos = _arm()
    assert turned((pos[:, 0] - pos[:, 1])[:, None])[0] < 1.0
    assert turned((pos[:, 2] - pos[:, 1])[:, None])[0] == pytest.approx(57.0, abs=2.0)
    gapped = pos.copy()
    gapped[:1, 0] = np.nan  # the shoulder has a gap
    assert [0, 1] in reaches(gapped, np.zeros((0, 2), dtype=int), partners=3, turned_deg=0.0).pairs.tolist()
    assert [0, 1] not in reaches(gapped, np.zeros((0, 2), dtype=int), partners=3, turned_deg=45.0).pairs.tolist()


def test_reaches_use_the_frames_both_markers_were_seen_only():
    pos = _arm()
    hidden = pos.copy()
    hidden[:100, 2] = np.nan
    r = reaches(hidden, np.zeros((0, 2), dtype=int), partners=3, turned_deg=0.0)
    k = [i for i, p in enumerate(r.pairs.tolist()) if p == [1, 2]][0]
    assert r.limit[k] == np.linalg.norm(pos[100:, 1] - pos[100:, 2], axis=1).max()
    assert len(reaches(hidden, np.zeros((0, 2), dtype=int), partners=0, turned_deg=0.0).pairs) == 0


def test_a_reach_leaves_a_prediction_within_it_untouched_and_pulls_one_past_it_back():
    pos = _arm(n=40)
    positions = pos.copy()
    positions[:, 2] = np.nan  # the wrist is missing throughout
    estimate = pos.copy()
    far = np.arange(20, 40)
    estimate[far, 2] = estimate[far, 1] + 2.0 * (pos[far, 2] - pos[far, 1])  # 500 mm from the elbow
    std = np.where(np.isnan(positions).any(axis=2), 20.0, 0.0)
    pairs, limit, spread = np.array([[1, 2]]), np.array([252.0]), np.array([5.0])
    out, _ = refine_bones(estimate, positions, std, pairs, limit, spread, spread_floor=1.0,
                          one_sided=np.array([True]))
    assert np.array_equal(out[:20], estimate[:20])  # within reach: a one-sided term adds nothing
    dist = np.linalg.norm(out[far, 2] - out[far, 1], axis=1)
    # pulled back to where the two costs balance: radially (500 - x) / 20^2 = (x - 252) / 5^2, x = 266.6
    assert np.allclose(dist, 266.6, atol=1.0)
    # the same pair as a bone pulls a prediction within reach out to its length
    bone, _ = refine_bones(estimate, positions, std, pairs, limit, spread, spread_floor=1.0)
    assert not np.allclose(bone[:20, 2], estimate[:20, 2])


def test_one_sided_terms_reach_the_minimum_a_general_optimiser_finds():
    from scipy.optimize import minimize

    rng = np.random.default_rng(3)
    pos = _arm(n=30, seed=3)
    positions = pos.copy()
    positions[:, 2:] = np.nan  # wrist and hand missing: the hand's bone to the wrist moves with it
    estimate = pos + np.where(np.isnan(positions), rng.normal(scale=150.0, size=pos.shape), 0.0)
    std = np.where(np.isnan(positions).any(axis=2), 40.0, 0.0)
    pairs = np.array([[2, 3], [1, 2], [0, 2], [1, 3]])
    lengths = np.array([80.0, 252.0, 420.0, 333.0])
    spread = np.array([1.0, 5.0, 20.0, 6.0])
    one_sided = np.array([False, True, True, True])
    out, info = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0, one_sided=one_sided,
                             max_iter=1000)
    # (within the default iteration bound the kink where a reach starts to pull slows a few frames down)
    bounded, _ = refine_bones(estimate, positions, std, pairs, lengths, spread, spread_floor=1.0, one_sided=one_sided)

    def objective(y, t):
        p = estimate[t].copy()
        p[2:] = y.reshape(2, 3)
        prior = (((p[2:] - estimate[t, 2:]) / std[t, 2:, None]) ** 2).sum()
        r = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1) - lengths
        r = np.where(one_sided & (r < 0), 0.0, r)
        # a reach acts at the frames where the estimate stretches it
        acts = ~one_sided | (np.linalg.norm(estimate[t, pairs[:, 0]] - estimate[t, pairs[:, 1]], axis=1) > lengths)
        return prior + ((r / spread) ** 2 * acts).sum()

    for t in range(0, 30, 4):
        ours = objective(out[t, 2:].ravel(), t)
        best = minimize(objective, out[t, 2:].ravel(), args=(t,), method="BFGS", options={"gtol": 1e-9})
        assert ours <= best.fun + 0.1
        assert ours <= objective(estimate[t, 2:].ravel(), t)
        assert objective(bounded[t, 2:].ravel(), t) <= 1.01 * ours
    assert info["unconverged"] == 0


def test_bone_stage_holds_a_prediction_within_reach_and_the_gap_says_so():
    """Stage 2 with a reach and no bone: a wrist predicted twice as far from its observed elbow as it was ever seen
    is pulled back to near the limit, one within reach is left alone, and the gap's reason names the elbow."""
    from mocapfill.bones.boneset import BoneSet
    from mocapfill.methods.auto import bone_stage
    from mocapfill.methods.auto_records import gap_records
    from mocapfill.methods.auto_config import DEFAULT_CONFIG

    pos = _arm(n=60)[:, :3]  # shoulder, elbow, wrist
    gapped = pos.copy()
    gapped[20:40, 2] = np.nan
    pred = np.full_like(pos, np.nan)
    pred[20:30, 2] = pos[20:30, 1] + 0.9 * (pos[20:30, 2] - pos[20:30, 1])  # within reach
    pred[30:40, 2] = pos[30:40, 1] + 2.0 * (pos[30:40, 2] - pos[30:40, 1])  # 500 mm from the elbow
    sd = np.where(np.isnan(gapped).any(axis=2), 20.0, np.nan)
    from mocapfill.bones.reach import Reaches

    none = BoneSet(np.zeros((0, 2), dtype=int), np.zeros(0), np.zeros(0), np.zeros(0, dtype=int), "mm")
    seen = np.isfinite(gapped[:, 2]).all(axis=1)
    reach = Reaches(np.array([[1, 2]]), np.array([np.linalg.norm(pos[seen, 1] - pos[seen, 2], axis=1).max()]),
                    np.array([5.0]))
    stretched = np.zeros((len(pos), 1), dtype=bool)
    out = bone_stage(gapped, pred, sd, none, DEFAULT_CONFIG, 1.0, reach=reach, stretched=stretched)
    assert np.array_equal(out[20:30, 2], pred[20:30, 2])
    dist = np.linalg.norm(out[30:40, 2] - pos[30:40, 1], axis=1)
    # where the two costs balance radially (the prediction's sd scaled by bone_trust): was 500
    w_pred, w_reach = 1.0 / (DEFAULT_CONFIG.bone_trust * 20.0) ** 2, 1.0 / 5.0 ** 2
    assert np.allclose(dist, (500.0 * w_pred + reach.limit[0] * w_reach) / (w_pred + w_reach), atol=2.0)
    assert stretched[30:40, 0].all() and stretched.sum() == 10
    missing = np.isnan(gapped).any(axis=2)
    rec = gap_records(missing, np.where(missing, 5.0, 0.0), missing, np.zeros_like(missing), DEFAULT_CONFIG, 1.0,
                      ["SHO", "ELB", "WRI"], none, reach=reach, stretched=stretched)
    assert len(rec) == 1 and "farther than it was ever seen from: ELB (10 frames)" in rec[0]["reason"]


def test_a_reach_between_two_moved_markers_does_not_act():
    """A reach acts from a fixed end only: between two predictions it would join their problems into one (at several
    times the cost) for a bound between two guesses."""
    pos = _arm(n=20)
    positions = pos.copy()
    positions[:, 1:3] = np.nan  # elbow and wrist both missing
    estimate = pos.copy()
    estimate[:, 2] = estimate[:, 1] + 2.0 * (pos[:, 2] - pos[:, 1])  # 500 mm from the elbow
    std = np.where(np.isnan(positions).any(axis=2), 20.0, 0.0)
    out, info = refine_bones(estimate, positions, std, np.array([[1, 2]]), np.array([252.0]), np.array([5.0]),
                             spread_floor=1.0, one_sided=np.array([True]))
    assert np.array_equal(out, estimate) and info["frames"] == 0
