import warnings

import numpy as np
import pytest

import mocapfill
from mocapfill.errors import MethodError, MocapfillError
from mocapfill.markers import MarkerData
from mocapfill.methods import METHODS, get_method
from mocapfill.methods.base import check_positions, finish


def test_markerdata_validates_shape_and_labels():
    with pytest.raises(MocapfillError, match="shape"):
        MarkerData(np.zeros((3, 2)), ["a", "b"], 100)
    with pytest.raises(MocapfillError, match="labels"):
        MarkerData(np.zeros((3, 2, 3)), ["a"], 100)
    with pytest.raises(MocapfillError, match="unique"):
        MarkerData(np.zeros((3, 2, 3)), ["a", "a"], 100)


def test_markerdata_properties_and_copy():
    pos = np.zeros((4, 2, 3))
    pos[1, 0] = np.nan
    data = MarkerData(pos, ["a", "b"], 100.0)
    assert (data.n_frames, data.n_markers, data.duration) == (4, 2, 0.04)
    assert data.missing.sum() == 1
    assert data.marker_index("b") == 1
    copy = data.with_positions(np.ones((4, 2, 3)))
    assert copy.positions[1, 0, 0] == 1 and np.isnan(data.positions[1, 0, 0])


def test_finish_keeps_observed_bits_and_masks():
    original = np.arange(24, dtype=float).reshape(4, 2, 3) / 7.0
    original[1, 0] = np.nan
    original[2, 1] = np.nan
    estimate = np.full_like(original, 5.0)
    estimate[2, 1, 0] = np.nan  # a method that could not fill this sample
    result = finish(original, estimate, std=np.ones((4, 2)))
    observed = ~np.isnan(original).any(axis=2)
    assert np.array_equal(result.positions[observed].view(np.uint64), original[observed].view(np.uint64))
    assert result.filled.tolist() == [[False, False], [True, False], [False, False], [False, False]]
    assert np.isnan(result.positions[2, 1]).all()
    assert result.std[0, 0] == 0 and result.std[1, 0] == 1 and np.isnan(result.std[2, 1])


def test_check_positions_rejects_inf_and_spreads_nan():
    with pytest.raises(MethodError, match="infinite"):
        check_positions(np.full((2, 1, 3), np.inf))
    pos = np.zeros((2, 1, 3))
    pos[0, 0, 1] = np.nan
    assert np.isnan(check_positions(pos)[0, 0]).all()


def test_coordinates_too_large_to_square_are_refused_where_they_enter_the_fill():
    """|x| > 1e150 overflows a square: one MethodError naming the file and the marker, for every method."""
    from mocapfill.methods.base import MAX_COORDINATE, check_magnitude

    pos = np.zeros((40, 2, 3))
    pos[:, 0, 0] = (-1.0) ** np.arange(40) * 1e308
    pos[10:20, 1] = np.nan
    with pytest.raises(MethodError, match=r"^take\.csv: coordinates too large to fill \(A reaches 1e\+308"):
        check_positions(pos, name="take.csv", labels=["A", "B"])
    for method in ("linear", "spline", "msvd"):
        with pytest.raises(MethodError, match="coordinates too large to fill"):
            mocapfill.fill(pos, method)
    pos[:, 0, 0] = (-1.0) ** np.arange(40) * MAX_COORDINATE  # the bound itself still fills
    check_magnitude(pos)
    assert mocapfill.fill(pos, "spline").filled[10:20, 1].all()


def test_registry_names_and_unknown_method():
    assert {"linear", "spline", "msvd", "dynammo", "bolero-hc", "bolero-sc", "bilinear", "pca", "auto"} <= set(METHODS)
    with pytest.raises(MethodError, match="unknown method 'nope'"):
        get_method("nope")


def test_api_fill_passes_context_and_warns_on_foreign_options():
    pos = np.random.default_rng(0).normal(size=(20, 2, 3))
    pos[5:8, 0] = np.nan
    data = MarkerData(pos, ["a", "b"], 100.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = mocapfill.fill(data, "linear", hidden=4)
    assert any("ignores option(s): hidden" in str(w.message) for w in caught)
    assert result.filled[5:8, 0].all() and result.info["method"] == "linear"


@pytest.mark.parametrize("rate", [0, -120.0, float("nan"), float("inf"), "100"])
def test_api_fill_refuses_a_rate_that_is_no_rate(rate):
    """A bare array's ``rate=`` that is no frame rate is an error, not the model's default rate in silence."""
    pos = np.random.default_rng(0).normal(size=(20, 2, 3))
    pos[5:8, 0] = np.nan
    with pytest.raises(MethodError, match=r"is not a positive frame rate in Hz"):
        mocapfill.fill(pos, "auto", rate=rate)
    assert mocapfill.fill(pos, "auto", rate=np.float32(60)).filled[5:8, 0].all()


def test_import_has_no_side_effects_and_is_lazy():
    import subprocess
    import sys

    code = "import sys, mocapfill; print('mocapfill.io' in sys.modules, 'click' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def test_every_public_name_resolves():
    import mocapfill.cli  # noqa: F401  (imports every subpackage the commands use)

    for name in mocapfill.__all__:
        assert getattr(mocapfill, name) is not None
    assert callable(mocapfill.evaluate) and callable(mocapfill.estimate_bones) and callable(mocapfill.read)
