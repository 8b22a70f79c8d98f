"""pandas, xarray (pyomeca's Markers layout) and kineticstoolkit conversions, each against the real library: units,
rate, first frame and NaN-as-missing survive every round trip; importing mocapfill imports none of them."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from mocapfill.errors import InputError
from mocapfill.io import read
from mocapfill.markers import MarkerData


@pytest.fixture(scope="module")
def motive(test_data) -> MarkerData:
    """Real OptiTrack take: metres, 120 Hz, first frame 0, 25 % missing."""
    return read(test_data / "motive_sample_take.csv")


@pytest.fixture(scope="module")
def coda(test_data) -> MarkerData:
    """Real Codamotion capture: mm, 200 Hz, first frame 1, real gaps."""
    return read(test_data / "ADemo1_rewrite_c3d_pc_float.c3d")


def same(a: MarkerData, b: MarkerData) -> None:
    assert b.labels == a.labels
    assert (b.rate, b.units, b.first_frame) == (a.rate, a.units, a.first_frame)
    np.testing.assert_array_equal(b.missing, a.missing)
    np.testing.assert_array_equal(b.positions, a.positions)


def test_import_mocapfill_imports_no_optional_library():
    code = ("import sys, mocapfill, mocapfill.cli, mocapfill.markers; "
            "print(sorted(m for m in ('pandas', 'xarray', 'kineticstoolkit', 'pyomeca') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


@pytest.mark.parametrize("name", ["motive", "coda"])
def test_dataframe_round_trip(name, request):
    pd = pytest.importorskip("pandas")
    data = request.getfixturevalue(name)
    df = data.to_dataframe()
    assert df.shape == (data.n_frames, 3 * data.n_markers)
    assert list(df.columns[:3]) == [(data.labels[0], a) for a in "xyz"] and df.columns.names == ["marker", "axis"]
    assert df.index[0] == data.first_frame and df.index.name == "frame"
    assert df.attrs == {"rate": data.rate, "units": data.units, "first_frame": data.first_frame}
    assert df[data.labels[0]]["y"].iloc[0] == data.positions[0, 0, 1] or np.isnan(data.positions[0, 0, 1])
    same(data, MarkerData.from_dataframe(df))
    # attrs lost (e.g. by a concat): given explicitly, or an error naming what is missing
    bare = pd.DataFrame(df.to_numpy(), index=df.index, columns=df.columns)
    with pytest.raises(InputError, match="units"):
        MarkerData.from_dataframe(bare)
    same(data, MarkerData.from_dataframe(bare, rate=data.rate, units=data.units))


@pytest.mark.parametrize("name", ["motive", "coda"])
def test_xarray_round_trip_in_pyomeca_layout(name, request):
    pytest.importorskip("xarray")
    data = request.getfixturevalue(name)
    array = data.to_xarray()
    assert array.dims == ("axis", "channel", "time") and array.name == "markers"
    assert list(array.axis.values) == ["x", "y", "z", "ones"] and (array.sel(axis="ones") == 1).all()
    assert list(array.channel.values) == data.labels and array.time.values[1] == 1 / data.rate
    assert array.attrs["rate"] == data.rate and array.attrs["units"] == data.units
    assert array.attrs["first_frame"] == data.first_frame
    same(data, MarkerData.from_xarray(array))


def test_pyomeca_markers_both_ways(coda):
    pyomeca = pytest.importorskip("pyomeca")
    array = coda.to_xarray()
    # pyomeca's own processing works on it (its accessor), and a Markers built by pyomeca comes back
    assert np.isfinite(array.meca.norm(dim="axis").values).any()
    built = pyomeca.Markers(coda.positions.transpose(2, 1, 0), channels=coda.labels, time=coda.times)
    same(coda, MarkerData.from_xarray(built, units="mm", first_frame=coda.first_frame))


@pytest.mark.parametrize("name", ["motive", "coda"])
def test_kineticstoolkit_round_trip(name, request):
    ktk = pytest.importorskip("kineticstoolkit")
    data = request.getfixturevalue(name)
    ts = data.to_timeseries()
    assert isinstance(ts, ktk.TimeSeries)
    values = ts.data[data.labels[0]]
    assert values.shape == (data.n_frames, 4)
    seen = ~data.missing[:, 0]
    assert (values[seen, 3] == 1).all() and np.isnan(values[~seen]).all()
    assert ts.info[data.labels[0]]["Unit"] == data.units and ts.get_sample_rate() == pytest.approx(data.rate)
    same(data, MarkerData.from_timeseries(ts))


def test_kineticstoolkit_c3d_reading_comes_back(test_data):
    """A TimeSeries kineticstoolkit reads itself (its time starts at the C3D's 0-based first frame)."""
    ktk = pytest.importorskip("kineticstoolkit")
    path = test_data / "kinematics_racing_full.c3d"
    points = ktk.read_c3d(str(path), convert_point_unit=False)["Points"]
    ours = read(path)
    back = MarkerData.from_timeseries(points)
    assert back.rate == pytest.approx(ours.rate, rel=1e-12)  # a float32 rate in the file: 69.99261474609375 Hz
    assert back.units == ours.units and back.first_frame == ours.first_frame
    k = back.labels.index(ours.labels[0])
    np.testing.assert_allclose(back.positions[:, k], ours.positions[:, 0], rtol=1e-6)
