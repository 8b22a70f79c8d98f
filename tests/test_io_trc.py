"""TRC read and write: real exports (tab and comma, CRLF, truncated) and exact round trips."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import mocapfill
from mocapfill.errors import DataWarning, FormatError
from mocapfill.markers import MarkerData


def test_truncated_trc_reads_what_is_there(test_data):
    with pytest.warns(DataWarning, match="header says 652 frames, the file holds 93"):
        data = mocapfill.read(test_data / "markers.trc")
    assert (data.n_frames, data.n_markers, data.rate, data.units, data.first_frame) == (93, 51, 100.0, "mm", 1)
    assert any("truncated" in n for n in data.notes)
    assert data.labels[:2] == ["ASISl", "ASISr"]
    np.testing.assert_allclose(data.positions[0, 0], [733.7041, 80.9832, 191.8668])
    assert not data.missing.any()


def test_tab_separated_crlf_trc(test_data):
    data = mocapfill.read(test_data / "T.trc")
    assert (data.n_frames, data.n_markers, data.rate, data.units) == (89, 41, 30.0, "mm")
    assert data.labels[:3] == ["RFHD", "LBHD", "RBHD"]
    assert data.source_format == "trc"


def test_round_trip_is_exact(sample_data, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        data = mocapfill.read(sample_data / "markers_analogs.c3d")
    mocapfill.write(data, tmp_path / "a.trc")
    back = mocapfill.read(tmp_path / "a.trc")
    assert back.labels == data.labels and back.rate == data.rate and back.units == data.units
    assert back.first_frame == data.first_frame and back.notes == []
    assert np.array_equal(back.positions, data.positions, equal_nan=True)
    header = (tmp_path / "a.trc").read_text().splitlines()[:3]
    assert header[0].startswith("PathFileType\t4\t(X/Y/Z)\ta.trc")
    assert header[2].split("\t")[2:5] == ["580", "51", "mm"]


def test_missing_samples_and_short_rows(tmp_path):
    text = ("PathFileType\t4\t(X/Y/Z)\tx.trc\n"
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
            "60\t60\t3\t2\tm\t60\t1\t3\n"
            "Frame#\tTime\tA\t\t\tB\n"
            "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
            "\n"
            "1\t0\t1\t2\t3\t4\t5\t6\n"
            "2\t0.0167\t1\t2\t3\n"
            "3\t0.0333\t\t\t\t4\t5\t6\n")
    path = tmp_path / "x.trc"
    path.write_text(text)
    data = mocapfill.read(path)
    assert data.units == "m" and data.labels == ["A", "B"]
    assert data.missing.tolist() == [[False, False], [False, True], [True, False]]


def test_origin_point_is_not_missing_in_trc(tmp_path):
    data = MarkerData(np.zeros((2, 1, 3)), ["ORIGIN"], 100.0)
    mocapfill.write(data, tmp_path / "o.trc")
    assert not mocapfill.read(tmp_path / "o.trc").missing.any()


def test_not_a_trc(tmp_path):
    path = tmp_path / "x.trc"
    path.write_text("frame,time\n1,0\n")
    with pytest.raises(FormatError, match=r"x\.trc: not a TRC file"):
        mocapfill.read(path)


def test_ragged_long_rows(tmp_path):
    text = ("PathFileType\t4\t(X/Y/Z)\tx.trc\n"
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\n"
            "60\t60\t2\t1\tmm\n"
            "Frame#\tTime\tA\n"
            "\t\tX1\tY1\tZ1\n"
            "1\t0\t1\t2\t3\t4\t5\t6\n"
            "2\t0.0167\t1\t2\t3\t4\t5\t6\t7\t8\t9\t10\n")
    path = tmp_path / "x.trc"
    path.write_text(text)
    with pytest.raises(FormatError, match=r"x\.trc: line 7 has 12 fields.*inside a marker.*ragged TRC"):
        mocapfill.read(path)


def test_non_numeric_trc_cell(tmp_path):
    text = ("PathFileType\t4\t(X/Y/Z)\tx.trc\n"
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\n"
            "60\t60\t1\t1\tmm\n"
            "Frame#\tTime\tA\n"
            "\t\tX1\tY1\tZ1\n"
            "1\t0\t1\tbad\t3\n")
    path = tmp_path / "x.trc"
    path.write_text(text)
    with pytest.raises(FormatError, match=r"line 6: 'bad' in column 'A_y' is not a number"):
        mocapfill.read(path)
