"""OptiTrack Motive CSV: the committed real export (format 1.21: a rigid body, its markers, unlabeled markers,
metres), the newer header layout (``Type`` / ``Name`` / ``ID`` / ``Parent`` labels, ``Time (Seconds)``), detection,
the exact Motive -> CSV round trip, and CSV text the ``csv`` module rejects."""

from __future__ import annotations

import io

import numpy as np
import pytest
from click.testing import CliRunner

from mocapfill.cli import cli
from mocapfill.errors import FormatError
from mocapfill.io import read, write


@pytest.fixture(scope="module")
def take(test_data):
    return test_data / "motive_sample_take.csv"


def test_reads_markers_and_rigid_body_markers(take):
    data = read(take)
    assert data.source_format == "motive-csv"
    assert (data.n_frames, data.n_markers, data.rate, data.units, data.first_frame) == (250, 12, 120, "m", 0)
    # the rigid body's own position / rotation is not a marker; its three markers (and their solved twins) are
    assert data.labels[:3] == ["Rigid Body 1_1", "Rigid Body 1_2", "Rigid Body 1_3"]
    assert "Rigid Body 1" not in data.labels and "Unlabeled:108" in data.labels
    np.testing.assert_array_equal(data.positions[0, 0], [0.009986, 0.019136, 0.009807])
    np.testing.assert_array_equal(data.positions[0, 3], [-0.724127, 0.716956, 2.824065])
    assert data.missing[0, -3:].all() and data.missing.sum() == 750  # empty cells = occluded
    assert data.notes == []


def test_motive_to_csv_round_trip_is_exact(take, tmp_path):
    data = read(take)
    out = tmp_path / "take.plain.csv"
    write(data, out)
    back = read(out)
    assert back.source_format == "csv"
    assert (back.labels, back.rate, back.units, back.first_frame) == (data.labels, 120, "m", 0)
    np.testing.assert_array_equal(back.positions, data.positions)  # NaN where missing, bit-identical elsewhere


def _newer_layout(text: str) -> str:
    """The same export as Motive 2.x writes it: labelled header rows, a Parent row, Time (Seconds), millimetres."""
    lines = text.replace("\r\n", "\n").split("\n")
    lines[0] = lines[0].replace("Format Version,1.21", "Format Version,1.23").replace("Meters", "Millimeters")
    lines[2] = ",Type" + lines[2][1:]
    lines[3] = ",Name" + lines[3][1:]
    lines[4] = ",ID" + lines[4][1:]
    lines.insert(5, ",Parent" + "," * (lines[5].count(",") - 1))
    lines[7] = lines[7].replace("Frame,Time,", "Frame,Time (Seconds),")
    return "\n".join(lines)


def test_newer_header_layout(take):
    text = _newer_layout(take.read_text())
    data = read(io.BytesIO(text.encode()), format="motive-csv")
    old = read(take)
    assert data.labels == old.labels and data.units == "mm" and data.rate == 120
    np.testing.assert_array_equal(data.positions, old.positions)


def test_rate_from_the_time_column_without_a_rate_in_the_header(take):
    # Motive writes times to six decimals (0.008333, 0.016667, ...): the rate they give is 120, not 120.005.
    text = take.read_text().replace("Capture Frame Rate,120.000000", "Capture Frame Rate,").replace(
        "Export Frame Rate,120.000000", "Export Frame Rate,")
    data = read(io.BytesIO(text.encode()), format="motive-csv")
    assert data.rate == 120.0
    assert read(io.BytesIO(text.encode()), format="motive-csv", rate=120).rate == 120.0


def test_detection_by_content_and_stdin(take, tmp_path):
    odd = tmp_path / "export.txt"
    odd.write_bytes(take.read_bytes())
    assert read(odd).source_format == "motive-csv"
    assert read(io.BytesIO(take.read_bytes())).source_format == "motive-csv"
    result = CliRunner().invoke(cli, ["info", "-"], input=take.read_bytes())
    assert result.exit_code == 0, result.output
    assert "250" in result.output
    result = CliRunner().invoke(cli, ["fill", "--input-format", "motive-csv", "-", "-", "--method", "linear"],
                                input=take.read_bytes())
    assert result.exit_code == 0, result.stderr
    assert result.stdout.startswith("# mocapfill csv: units=m rate=120.0 first_frame=0")


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.split("\n", 1)[0], "Frame,Time"),
    (lambda t: t.replace("Export Frame Rate,120.000000", "Export Frame Rate,fast"), "Export Frame Rate"),
    (lambda t: t.replace("Position", "Rotation"), "without marker positions"),
    (lambda t: t.replace("0.716956", "0.71x956", 1), "'0.71x956'"),
])
def test_broken_motive_csv_is_one_clear_error(take, edit, message):
    text = edit(take.read_text().replace("\r\n", "\n"))
    with pytest.raises(FormatError, match=message):
        read(io.BytesIO(text.encode()), format="motive-csv")


@pytest.mark.parametrize("fmt", ["csv", "motive-csv"])
def test_stray_carriage_return_never_escapes_as_csv_error(take, fmt):
    """Fuzzing found a lone carriage return inside a field escaping as ``_csv.Error``: now a line break."""
    text = take.read_text().replace("\r\n", "\n")
    broken = text.replace("0.716956", "0.71\r6956", 1)
    with pytest.raises(FormatError):
        read(io.BytesIO(broken.encode()), format=fmt)
    plain = "frame,time,A_x,A_y,A_z\n1,0.0,1,2\r,3\n"
    with pytest.raises(FormatError):
        read(io.BytesIO(plain.encode()), format="csv")
