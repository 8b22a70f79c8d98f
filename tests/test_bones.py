"""estimate_bones on real captures (anatomical plausibility) and synthetic rigid bodies; the editable bones file."""

from __future__ import annotations

import json

import numpy as np
import pytest

import mocapfill
from mocapfill.bones import BoneSet, estimate_bones, load_bones, pair_scores, save_bones
from mocapfill.errors import FormatError, MocapfillError
from synthetic import moving_body, rot_z

HEAD = {"LFHD", "RFHD", "LBHD", "RBHD"}
PELVIS = {"LFWT", "RFWT", "LBWT", "RBWT"}
TRUNK = {"CLAV", "STRN", "C7", "T10", "RBAC"}
SHOULDER = {"LSHO", "RSHO"}
UPPER_ARM = {"LUPA", "RUPA", "LELB", "RELB"}
LOWER_ARM = {"LFRM", "RFRM", "LWRA", "LWRB", "RWRA", "RWRB", "LFIN", "RFIN"}
THIGH = {"LTHI", "RTHI", "LKNE", "RKNE"}
SHANK_FOOT = {"LSHN", "RSHN", "LANK", "RANK", "LHEE", "RHEE", "LMT5", "RMT5", "LTOE", "RTOE"}
FOOT = {"LHEE", "RHEE", "LMT5", "RMT5", "LTOE", "RTOE"}
LIMBS = UPPER_ARM | LOWER_ARM | THIGH | SHANK_FOOT


def _short(label: str) -> str:
    return label.rsplit(":", 1)[-1]


def _across_a_moving_joint(a: str, b: str) -> str | None:
    """Why the CMU pair (a, b) would tie markers across a joint that moves in 85_02, else None."""
    ab = {a, b}
    def one_each(s, t):
        return (a in s and b in t) or (a in t and b in s)
    if (a in LIMBS and b in LIMBS) and a[0] != b[0]:
        return "left limb to right limb"
    if len(ab & HEAD) == 1:
        return "head to body (neck)"
    if one_each(LOWER_ARM, SHOULDER | TRUNK | PELVIS | HEAD | {"LUPA", "RUPA"}):
        return "forearm/wrist/hand to shoulder, trunk or upper arm (elbow/shoulder)"
    if one_each(UPPER_ARM, TRUNK | PELVIS | HEAD):
        return "upper arm to trunk (shoulder)"
    if one_each(THIGH | SHANK_FOOT, PELVIS | TRUNK | SHOULDER | HEAD | UPPER_ARM | LOWER_ARM):
        return "leg to pelvis or upper body (hip)"
    if one_each({"LTHI", "RTHI", "LKNE", "RKNE"}, FOOT):
        return "thigh/knee to foot (knee and ankle)"
    if one_each(PELVIS, TRUNK | SHOULDER):
        return "pelvis to thorax (spine)"
    return None


@pytest.fixture(scope="module")
def cmu(sample_data):
    return mocapfill.read(sample_data / "85_02.c3d")


@pytest.fixture(scope="module")
def cmu_bones(cmu):
    return estimate_bones(cmu.positions, units=cmu.units, labels=cmu.labels)


def _named(bones: BoneSet, labels) -> set[frozenset]:
    return {frozenset((_short(labels[i]), _short(labels[j]))) for i, j in bones.pairs}


def test_cmu_pairs_are_anatomically_plausible(cmu, cmu_bones):
    named = _named(cmu_bones, cmu.labels)
    for a, b in [("RKNE", "RSHN"), ("LTHI", "LKNE"), ("RTHI", "RKNE"), ("LWRA", "LWRB"), ("RWRA", "RWRB"),
                 ("LUPA", "LELB"), ("LANK", "LHEE"), ("RANK", "RHEE")]:
        assert frozenset((a, b)) in named, f"{a}-{b} missing"
    # the four head markers: all six pairs
    head = [frozenset((a, b)) for a in HEAD for b in HEAD if a < b]
    assert all(p in named for p in head)
    # the pelvis markers are held together: each has at least two pelvis partners
    for m in PELVIS:
        assert sum(1 for p in named if m in p and len(p & PELVIS) == 2) >= 2, m
    bad = {tuple(sorted(p)): _across_a_moving_joint(*sorted(p)) for p in named}
    bad = {p: why for p, why in bad.items() if why}
    assert not bad, bad


def test_cmu_every_marker_is_held(cmu, cmu_bones):
    degree = cmu_bones.partners(cmu.n_markers)
    alone = [_short(cmu.labels[m]) for m in np.flatnonzero(degree == 0)]
    # LFIN is the left hand's only marker and the left wrist moves in 85_02: nothing rigid holds it
    assert alone == ["LFIN"]
    assert np.median(degree) >= 3


def test_bones_use_observed_frames_only(cmu):
    positions = cmu.positions.copy()
    rng = np.random.default_rng(5)
    knee, shin = cmu.marker_index("Male:RKNE"), cmu.marker_index("Male:RSHN")
    positions[100:400, knee] = np.nan
    positions[rng.random(cmu.n_frames) < 0.1, shin] = np.nan
    bones = estimate_bones(positions, units=cmu.units)
    k = np.flatnonzero((bones.pairs == sorted((knee, shin))).all(1))
    assert k.size == 1
    d = np.linalg.norm(positions[:, knee] - positions[:, shin], axis=1)
    assert bones.n_frames[k[0]] == np.isfinite(d).sum()
    assert bones.lengths[k[0]] == pytest.approx(np.nanmedian(d), rel=1e-12)


def test_units_scale_the_thresholds(sample_data):
    tennis = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")
    assert tennis.units == "m"
    in_m = estimate_bones(tennis.positions, units="m")
    in_mm = estimate_bones(tennis.positions * 1000.0, units="mm")
    np.testing.assert_array_equal(in_m.pairs, in_mm.pairs)
    np.testing.assert_allclose(in_m.lengths * 1000.0, in_mm.lengths, rtol=1e-9)
    assert 30 <= len(in_m) <= 80
    named = _named(in_m, tennis.labels)
    for a, b in [("LFHD", "RFHD"), ("LWRA", "LWRB"), ("RKNE", "RTIB"), ("LASI", "RASI"), ("LHEE", "LTOE")]:
        assert frozenset((a, b)) in named, f"{a}-{b} missing"
    for p in named:
        assert not ({"LWRA", "LWRB", "RWRA", "RWRB"} & p and {"LSHO", "RSHO"} & p), p


def _two_bodies(seed: int, n_frames: int = 300) -> np.ndarray:
    """Two rigid 4-marker bodies joined at a rotating hinge, plus 0.5 mm noise; shape (n_frames, 8, 3) in mm."""
    rng = np.random.default_rng(seed)
    body = rng.normal(0, 60, (4, 3))
    return moving_body(n_frames, rng=rng, body=np.vstack([body, body + [200, 0, 0]]), rate=1.0, noise=0.5,
                       hinge=(slice(4, 8), lambda t: rot_z(t * 4 * np.pi / (n_frames - 1)), [200, 0, 0]),
                       path=lambda t: np.stack([0.5 * t, 0 * t, 0 * t], axis=1))


def test_synthetic_rigid_bodies():
    positions = _two_bodies(0)
    bones = estimate_bones(positions, units="mm")
    same_body = (bones.pairs < 4).all(1) | (bones.pairs >= 4).all(1)
    assert same_body.all() and len(bones) == 12
    assert np.all(bones.spread < 2.0)


def test_min_partners_fallback_respects_relax():
    positions = _two_bodies(1)
    # marker 3 drifts a little: its pairs exceed the strict thresholds but stay under relax x thresholds
    rng = np.random.default_rng(2)
    positions[:, 3] += rng.normal(0, 8.0, (len(positions), 3))
    pairs, lengths, spread, count, score = pair_scores(positions, units="mm")
    of3 = (pairs == 3).any(1) & (pairs < 4).all(1)
    assert (score[of3] > 1).all()
    strict = estimate_bones(positions, units="mm", min_partners=0)
    assert not (strict.pairs == 3).any()
    held = estimate_bones(positions, units="mm", relax=max(score[of3]) + 0.01)
    assert (held.pairs == 3).any(1).sum() == 3
    loose_only = estimate_bones(positions, units="mm", relax=1.0)
    assert not (loose_only.pairs == 3).any()


def test_min_frames_excludes_rarely_seen_pairs():
    positions = _two_bodies(3)
    positions[20:, 0] = np.nan  # marker 0 seen in only 20 frames
    bones = estimate_bones(positions, units="mm", min_frames=50)
    assert not (bones.pairs == 0).any()
    bones = estimate_bones(positions, units="mm", min_frames=10)
    assert (bones.pairs == 0).any()


def test_degenerate_inputs():
    assert len(estimate_bones(np.zeros((10, 1, 3)))) == 0
    assert len(estimate_bones(np.full((10, 4, 3), np.nan))) == 0
    with pytest.raises(MocapfillError):
        estimate_bones(np.zeros((10, 3)))
    with pytest.raises(MocapfillError, match="unknown length unit"):
        estimate_bones(np.zeros((10, 3, 3)), units="in")


# --- the editable file -----------------------------------------------------------------------------------------

LABELS = ["Sub:A", "Sub:B", "Sub:C", "Sub:D"]


def _bones() -> BoneSet:
    return BoneSet(np.array([[0, 1], [2, 1], [0, 3]]), [100.0, 250.5, 80.25], [1.5, 2.0, np.nan], [500, 480, 3],
                   units="mm")


def test_json_round_trip_and_format(tmp_path):
    path = tmp_path / "bones.json"
    save_bones(_bones(), path, labels=LABELS, units="mm")
    doc = json.loads(path.read_text())
    assert doc["units"] == "mm" and doc["format"] == "mocapfill-bones"
    assert doc["bones"][1] == {"a": "Sub:B", "b": "Sub:C", "length": 250.5, "spread": 2.0, "frames": 480}
    assert doc["bones"][2]["spread"] is None
    back = load_bones(path, LABELS)
    np.testing.assert_array_equal(back.pairs, [[0, 1], [1, 2], [0, 3]])
    np.testing.assert_array_equal(back.lengths, [100.0, 250.5, 80.25])
    np.testing.assert_array_equal(back.n_frames, [500, 480, 3])
    assert back.units == "mm" and np.isnan(back.spread[2])


def test_units_are_converted_explicitly(tmp_path):
    path = tmp_path / "bones.json"
    save_bones(_bones(), path, labels=LABELS, units="m")
    assert json.loads(path.read_text())["bones"][0]["length"] == 0.1
    back = load_bones(path, LABELS, units="mm")
    assert back.units == "mm"
    np.testing.assert_allclose(back.lengths, [100.0, 250.5, 80.25])


def test_hand_edited_file_and_prefix_matching(tmp_path):
    path = tmp_path / "edited.json"
    path.write_text(json.dumps({"units": "cm", "bones": [{"a": "A", "b": "D", "length": 8}]}))
    bones = load_bones(path, LABELS, units="mm")
    assert bones.pairs.tolist() == [[0, 3]] and bones.lengths.tolist() == [80.0] and bones.n_frames[0] == 0


def test_ambiguous_short_label(tmp_path):
    path = tmp_path / "b.json"
    path.write_text(json.dumps({"units": "mm", "bones": [{"a": "RKNE", "b": "X:A", "length": 8}]}))
    with pytest.raises(FormatError, match="ambiguous marker 'RKNE'.*X:RKNE, Y:RKNE"):
        load_bones(path, ["X:RKNE", "Y:RKNE", "X:A"])


def test_csv_round_trip(tmp_path):
    path = tmp_path / "bones.csv"
    save_bones(_bones(), path, labels=LABELS)
    assert path.read_text().splitlines()[0] == "marker_a,marker_b,length_mm,spread_mm,frames"
    back = load_bones(path, LABELS)
    np.testing.assert_array_equal(back.lengths, [100.0, 250.5, 80.25])


@pytest.mark.parametrize("content, message", [
    ('{"units": "mm", "bones": [{"a": "Sub:A", "b": "Sub:Q", "length": 5}]}', "unknown marker 'Sub:Q'"),
    ('{"units": "mm", "bones": [{"a": "Sub:A", "b": "Sub:A", "length": 5}]}', "to itself"),
    ('{"units": "mm", "bones": [{"a": "Sub:A", "b": "Sub:B", "length": -5}]}', "positive"),
    ('{"units": "mm", "bones": [{"a": "Sub:A", "b": "Sub:B"}]}', "no length"),
    ('{"units": "mm", "bones": [{"a": "A", "b": "B", "length": 1}, {"a": "B", "b": "A", "length": 2}]}', "repeats"),
    ('{"units": "inch", "bones": []}', "unknown units"),
    ('{"bones": 3}', "bones"),
    ("{not json", "not valid JSON"),
])
def test_bad_files_fail_with_one_line(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(FormatError, match=message) as info:
        load_bones(path, LABELS)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(MocapfillError, match="cannot read"):
        load_bones(tmp_path / "nope.json", LABELS)
