"""C3D reading and writing on real files from several vendors, cross-checked with the `c3d` package."""

from __future__ import annotations

import io
import warnings

import c3d
import numpy as np
import pytest

import mocapfill
from mocapfill.gaps import find_gaps
from mocapfill.errors import DataWarning, FormatError
from mocapfill.io.c3d import C3DExtra, c3d_bytes, read_c3d
from mocapfill.io.c3dfile import DEC, INTEL, MIPS, decode_floats, encode_floats
from mocapfill.markers import MarkerData

# (folder fixture, file, vendor): the round-trip set, at least four vendors and all storage kinds.
ROUND_TRIP = [
    ("sample_data", "markers_analogs.c3d", "Vicon Nexus, Intel float, 38 analog channels"),
    ("sample_data", "85_02.c3d", "CMU (Vicon), Intel float"),
    ("sample_data", "kinematics_tennis_serve_nan.c3d", "OptiTrack Motive, NaN gaps"),
    ("test_data", "Running_0002.c3d", "Qualisys, force plates"),
    ("test_data", "ADemo1_rewrite_c3d_pc_float.c3d", "Codamotion"),
    ("test_data", "newwalk.c3d", "Motion Analysis, DEC integer"),
    ("test_data", "MACsample.c3d", "Motion Analysis, MIPS integer"),
    ("test_data", "Basketball.c3d", "Xsens, Intel integer"),
]


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        return mocapfill.read(path)


def _path(request, folder, name):
    return request.getfixturevalue(folder) / name


def _package_frames(raw: bytes):
    """Points (n_frames, n_points, 5) and analog (n_frames, n_channels, n_samples) from the `c3d` package."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3d.Reader(io.BytesIO(raw))
        frames = list(reader.read_frames())
    points = np.array([p for _, p, _ in frames])
    analog = np.array([a for _, _, a in frames])
    return points, analog


def _fake_fill(data: MarkerData, seed: int = 0) -> np.ndarray:
    """Positions with every missing sample set to a plausible value and one observed sample removed."""
    rng = np.random.default_rng(seed)
    pos = data.positions.copy()
    missing = data.missing
    centre = np.nanmedian(pos.reshape(-1, 3), axis=0) if (~missing).any() else np.zeros(3)
    scale = 100.0 if data.units == "mm" else 0.1
    pos[missing] = centre + scale * rng.random((int(missing.sum()), 3))
    observed = np.argwhere(~missing)
    if len(observed):
        t, k = observed[len(observed) // 2]
        pos[t, k] = np.nan
    return pos


# --- reading -------------------------------------------------------------------------------------------------------

def test_sample_files_facts(sample_data):
    cmu = _read(sample_data / "85_02.c3d")
    assert (cmu.n_frames, cmu.n_markers, cmu.rate, cmu.units) == (810, 41, 120.0, "mm")
    assert not cmu.missing.any()
    assert cmu.source_format == "c3d" and cmu.first_frame == 1

    tennis = _read(sample_data / "kinematics_tennis_serve.c3d")
    assert (tennis.n_frames, tennis.n_markers, tennis.rate, tennis.units) == (1092, 39, 50.0, "m")
    assert not tennis.missing.any()

    nan = _read(sample_data / "kinematics_tennis_serve_nan.c3d")
    assert nan.labels == tennis.labels
    assert int(nan.missing.sum()) == 145
    gaps = find_gaps(nan.missing)
    assert len(gaps) == 10 and max(g.length for g in gaps) == 42
    # Observed samples of the gapped twin are the complete twin's values.
    obs = ~nan.missing
    assert np.array_equal(nan.positions[obs], tennis.positions[obs])

    vicon = _read(sample_data / "markers_analogs.c3d")
    assert (vicon.n_frames, vicon.n_markers, vicon.rate) == (580, 51, 100.0)
    gaps = find_gaps(vicon.missing)
    assert len(gaps) == 34 and max(g.length for g in gaps) == 71
    assert isinstance(vicon.extra, C3DExtra) and vicon.extra.n_analog_channels == 38


@pytest.mark.parametrize("folder,name,vendor", ROUND_TRIP)
def test_positions_agree_with_the_c3d_package(request, folder, name, vendor):
    path = _path(request, folder, name)
    data = _read(path)
    raw = path.read_bytes()
    try:
        points, _ = _package_frames(raw)
    except AssertionError:
        pytest.skip("the c3d package rejects this file")
    pts = points[:, data.extra.marker_points]
    ref = pts[:, :, :3].astype(np.float64)
    missing = (pts[:, :, 3] < 0) | (ref == 0).all(axis=2) | ~np.isfinite(ref).all(axis=2)
    assert np.array_equal(missing, data.missing)
    tol = 0.0 if data.extra.file.is_float else 1e-4 * abs(data.extra.file.scale) * 32768
    np.testing.assert_allclose(data.positions[~missing], ref[~missing], rtol=0, atol=tol)


def test_reads_a_file_the_c3d_package_rejects(test_data):
    raw = (test_data / "kinematics_racing_full.c3d").read_bytes()
    with pytest.raises(Exception):
        _package_frames(raw)
    data = _read(test_data / "kinematics_racing_full.c3d")
    assert (data.n_frames, data.n_markers, data.units) == (700, 46, "m")
    assert 15 < 100 * data.missing.mean() < 25
    assert abs(data.rate - 70) < 0.01


def test_mips_integer_file_with_inconsistent_scale_and_duplicate_labels(test_data):
    with pytest.warns(DataWarning) as record:
        data = mocapfill.read(test_data / "MACsample.c3d")
    assert any("duplicate marker label" in str(w.message) for w in record)
    assert data.extra.file.processor == MIPS and data.extra.storage == "integer"
    assert len(set(data.labels)) == data.n_markers
    assert "RTHI_2" in data.labels
    assert any("renamed 'RTHI_2'" in n for n in data.notes)
    assert any("POINT:SCALE is used" in n for n in data.notes)
    # A human-sized capture in millimetres: the parameter's scale is the right one.
    assert 200 < np.nanmax(np.abs(data.positions)) < 5000


def test_dec_integer_file(test_data):
    data = _read(test_data / "newwalk.c3d")
    assert data.extra.file.processor == DEC and data.extra.storage == "integer"
    assert (data.n_frames, data.n_markers, data.rate) == (360, 25, 60.0)


@pytest.mark.parametrize("processor", [INTEL, DEC, MIPS])
def test_float_codecs_invert(processor):
    values = np.array([0.0, 1.0, -1.5, 1234.5678, -0.001, 3.0e4], dtype=np.float32)
    back = decode_floats(encode_floats(values, processor), processor)
    assert np.array_equal(back, values)


def test_read_from_a_stream_and_stdin(sample_data, monkeypatch):
    raw = (sample_data / "85_02.c3d").read_bytes()
    from_stream = mocapfill.read(io.BytesIO(raw))
    assert from_stream.n_markers == 41 and from_stream.source_format == "c3d"

    class FakeStdin:
        buffer = io.BytesIO(raw)

    monkeypatch.setattr("sys.stdin", FakeStdin())
    from_stdin = mocapfill.read("-")
    assert from_stdin.path == "-"
    assert np.array_equal(from_stdin.positions, from_stream.positions)


# --- writing -------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("folder,name,vendor", ROUND_TRIP)
def test_unchanged_rewrite_is_byte_identical(request, tmp_path, folder, name, vendor):
    path = _path(request, folder, name)
    data = _read(path)
    out = tmp_path / "out.c3d"
    mocapfill.write(data, out)
    assert out.read_bytes() == path.read_bytes()


@pytest.mark.parametrize("folder,name,vendor", ROUND_TRIP)
def test_filled_rewrite_keeps_everything_else(request, tmp_path, folder, name, vendor):
    path = _path(request, folder, name)
    data = _read(path)
    original = path.read_bytes()
    new_positions = _fake_fill(data)
    out = tmp_path / "filled.c3d"
    mocapfill.write(data.with_positions(new_positions), out)
    written = out.read_bytes()
    f = data.extra.file

    # Header and parameter section: the same bytes.  Analog words: the same bytes.
    assert len(written) == len(original)
    assert written[: f.data_offset] == original[: f.data_offset]
    frames_old = np.frombuffer(original, np.uint8, f.n_frames * f.frame_bytes, f.data_offset)
    frames_new = np.frombuffer(written, np.uint8, f.n_frames * f.frame_bytes, f.data_offset)
    point_bytes = 4 * f.n_points * f.word_size
    frames_old = frames_old.reshape(f.n_frames, f.frame_bytes)
    frames_new = frames_new.reshape(f.n_frames, f.frame_bytes)
    assert np.array_equal(frames_old[:, point_bytes:], frames_new[:, point_bytes:])
    assert written[f.data_offset + f.n_frames * f.frame_bytes:] == original[f.data_offset + f.n_frames * f.frame_bytes:]
    # Model outputs and points that are not markers keep their bytes.
    others = np.setdiff1d(np.arange(f.n_points), data.extra.marker_points)
    for p in others:
        sl = slice(4 * p * f.word_size, 4 * (p + 1) * f.word_size)
        assert np.array_equal(frames_old[:, sl], frames_new[:, sl])

    back = _read(out)
    assert back.labels == data.labels and back.rate == data.rate and back.units == data.units
    was_missing = data.missing
    now_missing = np.isnan(new_positions).any(axis=2)
    assert np.array_equal(back.missing, now_missing)
    kept = ~was_missing & ~now_missing
    assert np.array_equal(back.positions[kept], data.positions[kept])  # observed samples: bit-identical
    filled = was_missing & ~now_missing
    tol = 1e-3 * np.abs(new_positions[filled]).max(initial=1) if f.is_float else abs(f.scale) / 2 + 1e-9
    np.testing.assert_allclose(back.positions[filled], new_positions[filled], rtol=0, atol=tol)

    try:
        points, analog = _package_frames(written)
        old_points, old_analog = _package_frames(original)
    except AssertionError:
        return  # the c3d package rejects this vendor's file (checked byte-wise above)
    assert np.array_equal(analog, old_analog)
    mp = data.extra.marker_points
    residual = points[:, mp, 3]
    cameras = points[:, mp, 4]
    assert np.all(residual[filled] == 0) and np.all(cameras[filled] == 0)
    assert np.all(residual[now_missing] < 0)
    np.testing.assert_array_equal(residual[kept], old_points[:, mp, 3][kept])


@pytest.mark.parametrize("folder,name,vendor", ROUND_TRIP)
def test_overridden_rate_is_written_to_header_and_parameters(request, tmp_path, folder, name, vendor):
    path = _path(request, folder, name)
    original = path.read_bytes()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        old = mocapfill.read(path)
        data = mocapfill.read(path, rate=old.rate / 2, override_rate=True)
    out = tmp_path / "slow.c3d"
    mocapfill.write(data.with_positions(_fake_fill(data)), out)
    back = _read(out)
    f, g = old.extra.file, back.extra.file
    assert back.rate == g.number("POINT", "RATE", back.rate) == pytest.approx(old.rate / 2, rel=1e-7)
    assert decode_floats(out.read_bytes()[20:24], g.processor)[0] == np.float32(old.rate / 2)
    # The data section keeps its analog samples per point frame, so ANALOG:RATE (in Hz) keeps its ratio.
    if f.number("ANALOG", "RATE", 0):
        assert g.number("ANALOG", "RATE") == pytest.approx(f.number("ANALOG", "RATE") / 2, rel=1e-7)
    # Nothing else in the header and parameters moved.
    rates = [20] + [prm.offset for key in [("POINT", "RATE"), ("ANALOG", "RATE")] if (prm := f.param(*key))]
    written = bytearray(out.read_bytes()[: f.data_offset])
    for at in rates:
        written[at:at + 4] = original[at:at + 4]
    assert bytes(written) == original[: f.data_offset]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            reader = c3d.Reader(io.BytesIO(out.read_bytes()))
        except AssertionError:
            return  # the c3d package rejects this vendor's file
    assert reader.point_rate == pytest.approx(old.rate / 2, rel=1e-7)


def test_fills_outside_the_integer_storage_range_stay_missing_with_a_warning(test_data, tmp_path):
    data = _read(test_data / "newwalk.c3d")
    pos = data.positions.copy()
    (t, k), (t2, k2) = np.argwhere(data.missing)[:2]
    pos[t, k] = [1e9, 0, 0]  # cannot be stored as int16 x scale
    pos[t2, k2] = [1.0, 2.0, 3.0]  # an ordinary fill
    with pytest.warns(DataWarning, match=f"1 sample.*{data.labels[k]}.*integer storage range"):
        mocapfill.write(data.with_positions(pos), tmp_path / "x.c3d")
    back = _read(tmp_path / "x.c3d")
    assert back.missing[t, k] and not back.missing[t2, k2]
    assert np.allclose(back.positions[t2, k2], [1.0, 2.0, 3.0], atol=abs(back.extra.file.scale))


def test_c3d_to_csv_to_c3d_keeps_positions(sample_data, tmp_path):
    data = _read(sample_data / "markers_analogs.c3d")
    mocapfill.write(data, tmp_path / "a.csv")
    via_csv = mocapfill.read(tmp_path / "a.csv")
    assert np.array_equal(via_csv.positions, data.positions, equal_nan=True)
    mocapfill.write(via_csv, tmp_path / "b.c3d")
    back = _read(tmp_path / "b.c3d")
    assert back.labels == data.labels and back.rate == data.rate and back.units == data.units
    assert back.first_frame == data.first_frame
    # Float C3D storage is float32; these positions came from float32, so the trip is exact.
    assert np.array_equal(back.positions, data.positions, equal_nan=True)
    # Readable by other software.
    points, _ = _package_frames((tmp_path / "b.c3d").read_bytes())
    assert points.shape[:2] == (data.n_frames, data.n_markers)


def test_fresh_c3d_with_many_markers_and_long_labels(tmp_path):
    rng = np.random.default_rng(1)
    n_markers = 300  # more than one LABELS parameter (255 columns at most)
    pos = (rng.normal(size=(20, n_markers, 3)) * 100).astype(np.float32).astype(np.float64)
    pos[3, 5] = np.nan
    labels = [f"subject:marker_with_a_long_name_{k}" for k in range(n_markers)]
    data = MarkerData(pos, labels, 250.0, "mm", first_frame=7)
    mocapfill.write(data, tmp_path / "many.c3d")
    back = _read(tmp_path / "many.c3d")
    assert back.labels == labels and back.first_frame == 7 and back.rate == 250.0
    assert np.array_equal(back.positions, pos, equal_nan=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3d.Reader(io.BytesIO((tmp_path / "many.c3d").read_bytes()))
    assert reader.point_used == n_markers


def test_changed_shape_writes_a_fresh_file_with_a_warning(sample_data, tmp_path):
    data = _read(sample_data / "markers_analogs.c3d")
    half = MarkerData(data.positions[:100], data.labels, data.rate, data.units, extra=data.extra)
    with pytest.warns(DataWarning, match="without the original"):
        raw = c3d_bytes(half, "half.c3d")
    back = read_c3d(raw, "half.c3d")
    assert back.n_frames == 100


def test_write_to_a_stream_and_stdout(sample_data, capfdbinary):
    data = _read(sample_data / "85_02.c3d")
    buf = io.BytesIO()
    mocapfill.write(data, buf, format="c3d")
    assert buf.getvalue() == (sample_data / "85_02.c3d").read_bytes()
    mocapfill.write(data, "-")  # format: the one it was read from
    assert capfdbinary.readouterr().out == buf.getvalue()


# --- broken files --------------------------------------------------------------------------------------------------

def test_truncated_c3d(sample_data, tmp_path):
    raw = (sample_data / "85_02.c3d").read_bytes()
    bad = tmp_path / "cut.c3d"
    bad.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(FormatError, match=r"cut\.c3d: truncated C3D: the data section holds \d+ of 810 frames"):
        mocapfill.read(bad)
    bad.write_bytes(raw[:300])
    with pytest.raises(FormatError, match="not a C3D file"):
        mocapfill.read(bad)
    bad.write_bytes(raw[:700])
    with pytest.raises(FormatError, match="cut.c3d"):
        mocapfill.read(bad)


def test_not_a_c3d(tmp_path):
    bad = tmp_path / "text.c3d"
    bad.write_bytes(b"hello, this is not a motion capture\n" * 40)
    with pytest.raises(FormatError, match=r"text\.c3d: not a C3D file"):
        mocapfill.read(bad)


def test_zero_rate_is_corrupt(tmp_path):
    data = MarkerData(np.ones((5, 2, 3)), ["A", "B"], 0.0)
    bad = tmp_path / "norate.c3d"
    bad.write_bytes(c3d_bytes(data))  # header rate and POINT:RATE both 0
    with pytest.raises(FormatError, match=r"norate\.c3d: corrupt C3D: no valid frame rate"):
        mocapfill.read(bad)


def test_more_than_65535_frames(tmp_path):
    n = 70000
    pos = np.zeros((n, 1, 3))
    pos[:, 0, 0] = np.arange(n, dtype=np.float64) + 1  # never the all-zero "missing" point
    data = MarkerData(pos, ["A"], 1000.0)
    raw = c3d_bytes(data)
    back = read_c3d(raw, "long.c3d")  # the frame count comes from TRIAL:ACTUAL_START/END_FIELD
    assert back.n_frames == n and np.array_equal(back.positions, pos)
    # Without the TRIAL fields the header's capped 65535 gives way to the size of the data section.
    hidden = raw.replace(b"ACTUAL_END_FIELD", b"ACTUAL_END_FIELX")
    with pytest.warns(DataWarning, match="frame count taken from the size of the data section"):
        back = read_c3d(hidden, "long.c3d")
    assert back.n_frames == n and np.array_equal(back.positions, pos)


def test_labels_c3d_cannot_hold_are_named_when_written(tmp_path):
    pos = np.random.default_rng(0).normal(size=(10, 3, 3))
    with pytest.warns(DataWarning, match="2 label.*written with '\\?'.*some now read the same"):
        mocapfill.write(MarkerData(pos, ["Knie_\u811a", "Knie_\u2713", "C"], 100.0, "mm"), tmp_path / "x.c3d")
