"""One conformance test for every registered fill method (``mocapfill.methods.METHODS``).

Every method must: return the input's shapes; give observed samples back bit-identical; fill every missing sample
of a marker observed at least once (gaps inside the clip, gaps at both edges, and whole-body blackout frames); leave
a marker missing in every frame missing; cope with a single frame; be deterministic under a seed; report a
``filled`` mask consistent with the NaNs; and give a non-negative ``std`` of the right shape when it has one.

Blackouts: every registered method is required to fill them (issue 3 names dynammo, bilinear and spline; linear
and msvd bridge them by interpolation, and the others build on these).  A method that cannot would be listed in
``BLACKOUT_EXEMPT`` with the reason; it is empty.

Methods that may decline a gap (``MethodSpec.may_decline``: the suites' ``woltring``, ``pattern``, ``rigid``) must
fill every fillable sample outside the gaps they list in ``info["declined"]``, leave those gaps missing whole, and
list only real gaps; on the synthetic body they must fill the interior gap its rule can reach.

Iterative methods run with a small iteration cap (``max_iter``) so the whole file takes seconds; the conformance
properties do not depend on convergence.

Methods that need a model (``MethodSpec.requires``: the kinematic fill ``opensim-ik`` and its ``ik_model``) run with
one built in the test through the ``opensim`` API: one body on a free joint carrying the clip's markers (exact for
the synthetic rigid cloud, a rough fit to the tennis serve); they skip where ``opensim`` cannot be imported.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import mocapfill
from mocapfill.methods import METHODS
from synthetic import moving_body, rot_z
from mocapfill.units import length_factor

#: Methods allowed to leave whole-body blackout frames unfilled (name -> reason).  None today.
BLACKOUT_EXEMPT: dict[str, str] = {}

#: The labels the synthetic cloud's markers carry when a method needs them (the model's marker names).
SYNTHETIC_LABELS = [f"M{k + 1}" for k in range(8)]

FAST = {"max_iter": 15}




def _options(name: str, n_markers: int = 8, units: str = "mm", labels=None) -> dict:
    accepted = METHODS[name].parameters()
    options = {k: v for k, v in FAST.items() if k in accepted}
    if "model" in accepted:  # the learned method: a model of the right layout (random weights: the contract only)
        from mocapfill.engines.denoiser import untrained_model

        options["model"] = untrained_model(n_markers, units, labels=labels)
    return options


def _fill(positions: np.ndarray, name: str, *, seed=0, rate=60.0, units="mm", labels=None, request=None,
          clip="synthetic"):
    extra = {}
    if METHODS[name].requires == "ik_model":  # a model built in the test (skips without opensim)
        extra["ik_model"] = request.getfixturevalue("ik_models")[clip]
        if labels is None:
            labels = SYNTHETIC_LABELS[:positions.shape[1]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mocapfill.fill(positions, name, seed=seed, rate=rate, units=units, labels=labels,
                              **_options(name, np.shape(positions)[1], units, labels), **extra)


def synthetic(n_frames: int = 90, n_markers: int = 8, seed: int = 3) -> np.ndarray:
    """A rigid marker cloud walking and turning, in mm: shape (n_frames, n_markers, 3), complete."""
    return moving_body(n_frames, n_markers, seed=seed, rate=60.0,
                       rotation=lambda t: rot_z(0.8 * np.sin(2 * np.pi * 0.5 * t)),
                       path=lambda t: np.stack([800 * t, 100 * np.sin(2 * np.pi * 0.7 * t),
                                                900 + 30 * np.sin(2 * np.pi * 1.3 * t)], axis=1))


def with_gaps(truth: np.ndarray) -> np.ndarray:
    """Interior gap, gaps touching both edges, a short blackout, and one marker missing throughout."""
    pos = truth.copy()
    pos[20:35, 1] = np.nan  # interior
    pos[:6, 2] = np.nan  # at the start
    pos[-7:, 3] = np.nan  # at the end
    pos[50:53] = np.nan  # whole-body blackout
    pos[:, 5] = np.nan  # never observed
    return pos


@pytest.fixture(scope="module")
def real_clip(sample_data):
    """200 frames of the tennis serve (metres, 50 Hz) with two gaps (one touching the end) and a 3-frame blackout."""
    data = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")
    truth = data.positions[300:500].copy()
    pos = truth.copy()
    pos[40:80, 4] = np.nan
    pos[150:200, 20] = np.nan
    pos[100:103] = np.nan
    return pos, data.rate, data.units, list(data.labels)


def declined_mask(original: np.ndarray, result, name: str) -> np.ndarray:
    """(n_frames, n_markers) the samples of the gaps ``result`` declined; checks each is a whole gap, left missing."""
    from mocapfill.gaps import find_gaps
    from mocapfill.methods.base import declined_mask as mask_of

    declined = result.info.get("declined", [])
    if not METHODS[name].may_decline:
        assert not declined, f"{name} declined gaps but is not registered as may_decline"
        return np.zeros(original.shape[:2], dtype=bool)
    gaps = {(g.marker, g.start, g.length) for g in find_gaps(np.isnan(original).any(axis=2))}
    for rec in declined:
        key = (rec["marker_index"], rec["start"], rec["length"])
        assert key in gaps, f"{name} declined {key}, which is not a gap"
        assert isinstance(rec["reason"], str) and rec["reason"]
    mask = mask_of(result.info, original.shape[:2])
    assert np.isnan(result.positions[mask]).all(), f"{name} filled part of a gap it declined"
    return mask


@pytest.fixture(scope="module")
def ik_models(tmp_path_factory, real_clip) -> dict[str, str]:
    """Free-body OpenSim models carrying the synthetic cloud's and the tennis clip's markers (paths by clip)."""
    osim = pytest.importorskip("opensim")
    import osim_models

    osim.Logger.setLevelString("off")
    osim.Logger.removeFileSink()
    folder = tmp_path_factory.mktemp("ik_models")
    cloud = synthetic(n_frames=1)[0]
    osim_models.rigid_model(str(folder / "synthetic.osim"), SYNTHETIC_LABELS, (cloud - cloud.mean(axis=0)) / 1000)
    pos, _, units, labels = real_clip
    complete = pos[np.flatnonzero(~np.isnan(pos).any(axis=(1, 2)))[0]]
    osim_models.rigid_model(str(folder / "real.osim"), labels,
                            (complete - complete.mean(axis=0)) * length_factor(units, "m"))
    return {"synthetic": str(folder / "synthetic.osim"), "real": str(folder / "real.osim")}


def check_contract(original: np.ndarray, result, name: str) -> None:
    """Shapes, bit-identical observed samples, filled mask, std, fills every fillable sample."""
    n_frames, n_markers, _ = original.shape
    assert result.positions.shape == original.shape
    assert result.positions.dtype == np.float64
    assert result.filled.shape == (n_frames, n_markers) and result.filled.dtype == bool
    missing = np.isnan(original).any(axis=2)
    observed = ~missing
    # Bit-identical, not merely close.
    assert np.array_equal(result.positions[observed].view(np.uint64), original[observed].view(np.uint64))
    out_missing = np.isnan(result.positions).any(axis=2)
    assert not np.isinf(result.positions).any()
    assert np.array_equal(result.filled, missing & ~out_missing)
    # Partly filled samples are not allowed: all three coordinates or none.
    assert np.array_equal(np.isnan(result.positions).all(axis=2), out_missing)
    never = missing.all(axis=0)
    assert out_missing[:, never].all(), f"{name} invented a marker that is never observed"
    fillable = missing & ~never[None, :] & ~declined_mask(original, result, name)
    if name in BLACKOUT_EXEMPT:
        fillable &= ~missing.all(axis=1)[:, None]
    assert not out_missing[fillable].any(), f"{name} left {int(out_missing[fillable].sum())} fillable samples"
    if result.std is not None:
        assert result.std.shape == (n_frames, n_markers)
        finite = np.isfinite(result.std)
        assert (result.std[finite] >= 0).all()
        assert (result.std[observed] == 0).all()


@pytest.mark.parametrize("name", list(METHODS))
def test_synthetic_gaps(name, request):
    original = with_gaps(synthetic())
    result = _fill(original, name, request=request)
    check_contract(original, result, name)
    assert not np.isnan(result.positions[20:35, 1]).any(), f"{name} did not fill an interior gap of a rigid body"


@pytest.mark.parametrize("name", list(METHODS))
def test_real_clip(name, real_clip, request):
    original, rate, units, labels = real_clip
    result = _fill(original, name, rate=rate, units=units, labels=labels, request=request, clip="real")
    check_contract(original, result, name)


@pytest.mark.parametrize("name", list(METHODS))
def test_one_frame(name, request):
    original = synthetic(n_frames=1)
    original[0, 2] = np.nan
    result = _fill(original, name, request=request)
    check_contract(original, result, name)
    assert np.isnan(result.positions[0, 2]).all()  # a single frame gives nothing to fill a marker from


@pytest.mark.parametrize("name", list(METHODS))
def test_nothing_missing(name, request):
    original = synthetic(n_frames=30)
    result = _fill(original, name, request=request)
    check_contract(original, result, name)
    assert not result.filled.any()


@pytest.mark.parametrize("name", list(METHODS))
def test_deterministic_under_seed(name, request):
    original = with_gaps(synthetic())
    first = _fill(original, name, seed=7, request=request)
    second = _fill(original, name, seed=7, request=request)
    assert np.array_equal(first.positions, second.positions, equal_nan=True)
    if first.std is not None:
        assert np.array_equal(first.std, second.std, equal_nan=True)
