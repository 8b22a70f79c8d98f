"""CSV: the plain wide layout (read/write), the Vicon Nexus export and header-only wide CSVs (read)."""

from __future__ import annotations

import io
import warnings

import numpy as np
import pytest

import mocapfill
from mocapfill.errors import DataWarning, FormatError
from mocapfill.markers import MarkerData


def _c3d(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        return mocapfill.read(path)


def _write(tmp_path, text, name="x.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_vicon_csv_matches_the_vicon_c3d(sample_data):
    c3d = _c3d(sample_data / "markers_analogs.c3d")
    csv = mocapfill.read(sample_data / "markers.csv")
    assert csv.source_format == "vicon-csv"
    assert (csv.n_frames, csv.n_markers, csv.rate, csv.units, csv.first_frame) == (580, 51, 100.0, "mm", 1)
    assert csv.labels == c3d.labels
    assert np.array_equal(csv.missing, c3d.missing)
    # Vicon prints 6 significant digits (rounded from its own double, not from the C3D's float32), so each value
    # agrees to within one unit in its 6th digit.
    obs = ~c3d.missing
    ref = c3d.positions[obs]
    digit = 10.0 ** (np.floor(np.log10(np.maximum(np.abs(ref), 1e-12))) - 5)
    assert np.all(np.abs(csv.positions[obs] - ref) <= digit)


def test_plain_round_trip_is_exact(sample_data, tmp_path):
    data = _c3d(sample_data / "kinematics_tennis_serve_nan.c3d")
    rng = np.random.default_rng(3)
    pos = data.positions.copy()
    pos[~data.missing] += rng.normal(scale=1e-3, size=pos[~data.missing].shape)  # full float64 precision
    data = data.with_positions(pos)
    mocapfill.write(data, tmp_path / "a.csv")
    text = (tmp_path / "a.csv").read_text()
    assert text.startswith("# mocapfill csv: units=m rate=50.0 first_frame=1\nframe,time,")
    back = mocapfill.read(tmp_path / "a.csv")
    assert back.source_format == "csv" and back.notes == []
    assert back.labels == data.labels and back.rate == data.rate and back.units == "m"
    assert np.array_equal(back.positions, data.positions, equal_nan=True)


def test_plain_without_comment_takes_rate_from_time_and_guesses_units(tmp_path):
    path = _write(tmp_path, "frame,time,A_x,A_y,A_z,B_x,B_y,B_z\n"
                            "11,0.0,100,200,300,1,2,3\n"
                            "12,0.004,101,201,301,,,\n"
                            "13,0.008,102,202,302,1,2,\n")
    data = mocapfill.read(path)
    assert data.rate == pytest.approx(250.0)
    assert data.first_frame == 11
    assert data.labels == ["A", "B"]
    assert data.units == "mm" and any("assumed 'mm'" in n for n in data.notes)
    # A sample with any empty coordinate is missing as a whole.
    assert data.missing.tolist() == [[False, False], [False, True], [False, True]]
    assert np.isnan(data.positions[2, 1]).all()


def test_comment_gives_rate_and_units(tmp_path):
    path = _write(tmp_path, "# mocapfill csv: units=m rate=60 first_frame=5\nA_x,A_y,A_z\n1,2,3\n4,5,6\n")
    data = mocapfill.read(path)
    assert (data.rate, data.units, data.first_frame, data.n_frames) == (60.0, "m", 5, 2)


def test_header_only_wide_with_subject_prefix(tmp_path):
    path = _write(tmp_path, "time,male:LKNE-x,male:LKNE-y,male:LKNE-z,male:RKNE-X,male:RKNE-Y,male:RKNE-Z\n"
                            "0,1,2,3,4,5,6\n0.01,1.5,2.5,3.5,,,\n")
    data = mocapfill.read(path)
    assert data.labels == ["LKNE", "RKNE"]
    assert any("'male:'" in n and "removed" in n for n in data.notes)
    assert data.rate == pytest.approx(100.0)
    assert data.missing.tolist() == [[False, False], [False, True]]


def test_prefix_kept_when_stripping_would_be_ambiguous(tmp_path):
    path = _write(tmp_path, "time,male:LKNE-x,male:LKNE-y,male:LKNE-z,female:LKNE-x,female:LKNE-y,female:LKNE-z\n"
                            "0,1,2,3,4,5,6\n0.5,1,2,3,4,5,6\n")
    data = mocapfill.read(path)
    assert data.labels == ["male:LKNE", "female:LKNE"]


def test_repeated_marker_triplet_is_renamed_visibly(tmp_path):
    path = _write(tmp_path, "time,A_x,A_y,A_z,A_x,A_y,A_z\n0,1,2,3,4,5,6\n0.1,1,2,3,4,5,6\n")
    with pytest.warns(DataWarning, match="duplicate"):
        data = mocapfill.read(path)
    assert data.labels == ["A", "A_2"]
    assert any("renamed 'A_2'" in n for n in data.notes)


def test_duplicate_column_that_cannot_be_resolved(tmp_path):
    path = _write(tmp_path, "time,A_x,A_x,A_y,A_z\n0,1,2,3,4\n")
    with pytest.raises(FormatError, match=r"x\.csv: column 'A_x' appears more than once"):
        mocapfill.read(path)


def test_incomplete_triplet(tmp_path):
    path = _write(tmp_path, "time,A_x,A_y\n0,1,2\n")
    with pytest.raises(FormatError, match="marker 'A' has no z column"):
        mocapfill.read(path)


def test_ragged_row(tmp_path):
    path = _write(tmp_path, "time,A_x,A_y,A_z\n0,1,2,3\n0.1,1,2\n")
    with pytest.raises(FormatError, match=r"x\.csv: line 3 has 3 fields, the header has 4 \(ragged CSV\)"):
        mocapfill.read(path)


def test_trailing_empty_fields_are_not_ragged(tmp_path):
    path = _write(tmp_path, "time,A_x,A_y,A_z,\n0,1,2,3,\n0.1,1,2,3,,\n")
    assert mocapfill.read(path).n_frames == 2


def test_non_numeric_cell(tmp_path):
    path = _write(tmp_path, "time,A_x,A_y,A_z\n0,1,2,3\n0.1,1,oops,3\n")
    with pytest.raises(FormatError, match=r"x\.csv: line 3: 'oops' in column 'A_y' is not a number"):
        mocapfill.read(path)


def test_unknown_column(tmp_path):
    path = _write(tmp_path, "time,A_x,A_y,A_z,speed\n0,1,2,3,4\n")
    with pytest.raises(FormatError, match="column 'speed' is neither"):
        mocapfill.read(path)


def test_no_rate(tmp_path):
    path = _write(tmp_path, "A_x,A_y,A_z\n1,2,3\n")
    with pytest.raises(FormatError, match="no frame rate"):
        mocapfill.read(path)


def test_uneven_time_column(tmp_path):
    path = _write(tmp_path, "time,A_x,A_y,A_z\n0,1,2,3\n0.1,1,2,3\n0.5,1,2,3\n")
    with pytest.raises(FormatError, match="not evenly spaced"):
        mocapfill.read(path)


def _timed_csv(tmp_path, rate, fmt, n=240):
    rows = "".join(f"{i + 1},{fmt.format(i / rate)},{i},2,3\n" for i in range(n))
    return _write(tmp_path, "frame,time,A_x,A_y,A_z\n" + rows)


@pytest.mark.parametrize("fmt", ["{:.3f}", "{:.4f}", "{:.6f}", "{!r}", "{:g}"])
def test_rate_from_a_rounded_time_column_is_the_round_rate(tmp_path, fmt):
    # 120 Hz to six decimals has steps 0.008333 / 0.008334 (1 / median = 120.005 Hz); to three, 0.008 / 0.009.
    assert mocapfill.read(_timed_csv(tmp_path, 120, fmt)).rate == 120.0


@pytest.mark.parametrize("rate, fmt, expected", [(100.5, "{:.6f}", 100.5), (120000 / 1001, "{:.3f}", 120000 / 1001),
                                                 (37.3, "{:.4f}", 37.3)])
def test_rate_from_a_rounded_time_column_that_is_not_an_integer(tmp_path, rate, fmt, expected):
    assert mocapfill.read(_timed_csv(tmp_path, rate, fmt)).rate == expected


def test_rate_from_times_is_fitted_to_all_of_them(tmp_path):
    # Precise times that jitter by 0.1 % of a step still read (as before), at the slope of all of them.
    times = np.arange(500) / 250 + np.random.default_rng(1).normal(scale=0.001 / 250, size=500)
    path = _write(tmp_path, "time,A_x,A_y,A_z\n" + "".join(f"{t!r},1,2,3\n" for t in times.tolist()))
    assert mocapfill.read(path).rate == pytest.approx(1 / np.polyfit(np.arange(500), times, 1)[0], rel=1e-12)
    # A time column whose steps differ by more than its precision explains is still refused.
    path = _write(tmp_path, "time,A_x,A_y,A_z\n0.000,1,2,3\n0.008,1,2,3\n0.018,1,2,3\n0.025,1,2,3\n")
    with pytest.raises(FormatError, match="not evenly spaced"):
        mocapfill.read(path)


def test_empty_file(tmp_path):
    with pytest.raises(FormatError, match="empty CSV"):
        mocapfill.read(_write(tmp_path, "\n\n"))


def test_vicon_without_trajectories(tmp_path):
    path = _write(tmp_path, "Devices\n1000\n,,Force plate\nFrame,Sub Frame,Fx\n,,N\n1,0,3\n")
    with pytest.raises(FormatError, match="without a 'Trajectories' section"):
        mocapfill.read(path)


def test_vicon_section_ends_at_a_blank_line(sample_data, tmp_path):
    text = (sample_data / "markers.csv").read_text()
    path = _write(tmp_path, text.rstrip("\n") + "\n\nModel Outputs\n100\n,,whatever\n")
    assert mocapfill.read(path).n_frames == 580


def test_labels_with_commas_survive(tmp_path):
    data = MarkerData(np.arange(12.0).reshape(2, 2, 3), ["a,b", 'q"uote'], 30.0, "cm")
    mocapfill.write(data, tmp_path / "c.csv")
    back = mocapfill.read(tmp_path / "c.csv")
    assert back.labels == data.labels and back.units == "cm"
    assert np.array_equal(back.positions, data.positions)


def test_write_csv_to_stdout_and_read_from_a_stream(sample_data, capfd):
    data = mocapfill.read(sample_data / "markers.csv")
    mocapfill.write(data, "-")  # vicon-csv data goes out as plain CSV
    out = capfd.readouterr().out
    assert out.startswith("# mocapfill csv:")
    back = mocapfill.read(io.BytesIO(out.encode()))
    assert np.array_equal(back.positions, data.positions, equal_nan=True)


@pytest.mark.parametrize("suffix", [".csv", ".tsv"])
def test_an_empty_label_is_written_as_a_name_its_reader_takes_back(tmp_path, suffix):
    pos = np.random.default_rng(0).normal(size=(10, 3, 3)) * 100
    path = tmp_path / f"x{suffix}"
    mocapfill.write(MarkerData(pos, ["", "B", "C"], 100.0, "mm"), path)
    back = mocapfill.read(path)
    assert back.labels == ["M001", "B", "C"]
    np.testing.assert_allclose(back.positions, pos, atol=1e-3)


def test_an_empty_path_is_named_as_such():
    from mocapfill.errors import InputError

    with pytest.raises(InputError, match="an empty path names no file"):
        mocapfill.read("")
