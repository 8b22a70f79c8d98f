"""Qualisys QTM TSV: the header (rate, labels, first frame), the ways QTM writes missing samples, variants of the
layout, the writer, detection (extension, content, --input-format, stdin) and the TSV -> C3D -> TSV round trip.

The committed real export ``tests/data/qtm_JaneDoe_Dynamic_2.tsv`` (Qualisys' own PAF example, MIT) settles how QTM
writes a missing sample: ``0.000 0.000 0.000`` (R_HEAD, its last 7 frames), while a single coordinate at 0.000 is a
real value (L_FAX, frame 191).  Variants of the layout are built at run time from a real Codamotion capture with
real gaps, laid out as QTM lays out its export.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.errors import FormatError
from mocapfill.io import read, write
from mocapfill.io.tsv import tsv_text


def qtm_text(positions, labels, rate=100, first_frame=1, missing="zeros", column_names=True, frame_time=True,
             file_version=False, events=(), n_frames=None) -> str:
    """A TSV laid out as QTM exports 3-D data; ``positions`` (n, m, 3) in mm, NaN = missing."""
    n, m = positions.shape[:2]
    head = ["FILE_VERSION\t2.0.0"] if file_version else []
    head += [f"NO_OF_FRAMES\t{n if n_frames is None else n_frames}", "NO_OF_CAMERAS\t10", f"NO_OF_MARKERS\t{m}",
             f"FREQUENCY\t{rate}", "NO_OF_ANALOG\t0", "ANALOG_FREQUENCY\t0", "DESCRIPTION\t--",
             "TIME_STAMP\t2026-01-19, 10:19:43.755\t2063631.96175450", "DATA_INCLUDED\t3D"]
    head += [f"EVENT\t{name}\t{frame}\t{frame / 100:.3f}" for name, frame in events]
    head += ["MARKER_NAMES\t" + "\t".join(labels), "TRAJECTORY_TYPES\t" + "\t".join(["Measured"] * m)]
    if column_names:
        head.append("\t".join((["Frame", "Time"] if frame_time else []) +
                              [f"{lab} {a}" for lab in labels for a in "XYZ"]) + "\t")
    token = {"zeros": "0.000", "empty": "", "nan": "NaN"}[missing]
    rows = []
    for t in range(n):
        step = 1 / rate if isinstance(rate, (int, float)) else 0.01
        cells = [f"{first_frame + t}", f"{t * step:.5f}"] if frame_time else []
        for k in range(m):
            p = positions[t, k]
            cells += [token] * 3 if np.isnan(p).any() else [f"{v:.3f}" for v in p]
        rows.append("\t".join(cells))
    return "\n".join(head + rows) + "\n"


@pytest.fixture(scope="module")
def qtm(test_data):
    return test_data / "qtm_JaneDoe_Dynamic_2.tsv"


def test_real_qtm_export(qtm):
    data = read(qtm)
    assert data.source_format == "tsv" and data.notes == []
    assert (data.n_frames, data.n_markers, data.rate, data.units, data.first_frame) == (229, 53, 100, "mm", 1)
    assert data.labels[:3] == ["L_HEAD", "R_HEAD", "SGL"]
    head = data.labels.index("R_HEAD")
    assert data.missing.sum() == 7 and data.missing[222:, head].all()  # frames 223-229 written as 0.000 triplets
    fax = data.labels.index("L_FAX")
    np.testing.assert_array_equal(data.positions[190, fax], [-719.005, 0.0, 460.595])  # one zero: observed
    np.testing.assert_array_equal(data.positions[0, 0], [float(v) for v in qtm.read_text().splitlines()[11]
                                                         .split("\t")[2:5]])


def test_real_qtm_export_round_trips_through_tsv_and_c3d(qtm, tmp_path):
    """TSV -> TSV and TSV -> C3D -> TSV give back every data row of QTM's file, character for character."""
    original = [line for line in qtm.read_text().splitlines() if line[:1].isdigit()]
    again = tmp_path / "again.tsv"
    write(read(qtm), again)
    assert [line for line in again.read_text().splitlines() if line[:1].isdigit()] == original
    c3d, back = tmp_path / "take.c3d", tmp_path / "back.tsv"
    write(read(qtm), c3d)
    write(read(c3d), back)
    assert [line for line in back.read_text().splitlines() if line[:1].isdigit()] == original
    assert again.read_text().splitlines() == qtm.read_text().splitlines()  # header too: the same file back


def test_real_qtm_export_fills_to_c3d(qtm, tmp_path):
    result = CliRunner().invoke(cli, ["fill", str(qtm), str(tmp_path / "filled.c3d"), "--method", "linear"])
    assert result.exit_code == 0, result.output
    before, after = read(qtm), read(tmp_path / "filled.c3d")
    assert not after.missing.any() and after.labels == before.labels and after.rate == 100
    seen = ~before.missing
    np.testing.assert_allclose(after.positions[seen], before.positions[seen], atol=1e-4)  # float32 C3D


@pytest.fixture(scope="module")
def coda(test_data):
    """Real Codamotion gait capture with real gaps: 512 frames, 24 markers, mm, rounded to QTM's 3 decimals."""
    data = read(test_data / "ADemo1_rewrite_c3d_pc_float.c3d")
    return np.round(data.positions, 3), data.labels


@pytest.mark.parametrize("missing", ["zeros", "empty", "nan"])
def test_reads_header_and_every_way_qtm_writes_missing(coda, missing, tmp_path):
    positions, labels = coda
    path = tmp_path / "take.tsv"
    path.write_text(qtm_text(positions, labels, rate=200, first_frame=7, missing=missing, file_version=True,
                             events=[("Start", 10), ("Stop", 400)]))
    data = read(path)
    assert data.source_format == "tsv" and data.units == "mm"
    assert data.rate == 200 and data.first_frame == 7 and data.labels == labels
    assert data.notes == []
    np.testing.assert_array_equal(data.missing, np.isnan(positions).any(axis=2))
    assert data.missing.sum() == 85
    np.testing.assert_allclose(data.positions[~data.missing], positions[~data.missing], atol=5e-4)


@pytest.mark.parametrize("frame_time", [True, False])
def test_reads_exports_without_the_column_name_row(coda, frame_time):
    positions, labels = coda
    text = qtm_text(positions[:50], labels, column_names=False, frame_time=frame_time, first_frame=3)
    data = read(io.BytesIO(text.encode()), format="tsv")
    assert data.n_frames == 50 and data.n_markers == len(labels)
    assert data.first_frame == (3 if frame_time else 1)
    np.testing.assert_allclose(data.positions[~data.missing], positions[:50][~data.missing], atol=5e-4)


def test_external_timebase_needs_a_rate_and_truncation_is_noted(coda):
    positions, labels = coda
    text = qtm_text(positions[:20], labels, rate="EXT")
    with pytest.raises(FormatError, match="no frame rate"):
        read(io.BytesIO(text.encode()), format="tsv")
    assert read(io.BytesIO(text.encode()), format="tsv", rate=150).rate == 150
    short = qtm_text(positions[:20], labels, n_frames=30)
    with pytest.warns(mocapfill.errors.DataWarning):
        data = read(io.BytesIO(short.encode()), format="tsv")
    assert data.n_frames == 20 and any("30 frames" in note for note in data.notes)


@pytest.mark.parametrize("text, message", [
    ("NO_OF_FRAMES\t1\nDATA_INCLUDED\t6D\nBODY_NAMES\tb\n", "6D"),
    ("NO_OF_FRAMES\t1\nNO_OF_MARKERS\t1\nFREQUENCY\t100\nMARKER_NAMES\tA\nFrame\tTime\tA X\tA Y\tA Z\n"
     "1\t0.0\t1.0\t2.0\n", "fields"),
    ("NO_OF_FRAMES\t1\nFREQUENCY\t-5\nMARKER_NAMES\tA\n1\t0\t1\t2\t3\n", "FREQUENCY"),
    ("NO_OF_FRAMES\t1\nFREQUENCY\t100\nMARKER_NAMES\tA\nFrame\tTime\tA X\tA Y\tA W\n", "marker 'A'"),
    ("NO_OF_FRAMES\t1\nFREQUENCY\t100\nMARKER_NAMES\tA\n1\t0\t1\tabc\t3\n", "'abc'"),
])
def test_broken_tsv_is_one_clear_error(text, message):
    with pytest.raises(FormatError, match=message):
        read(io.BytesIO(text.encode()), format="tsv")


def test_writer_is_qtm_layout_and_reads_back(test_data):
    data = read(test_data / "Running_0002.c3d")
    text = tsv_text(data)
    lines = text.splitlines()
    assert [line.split("\t")[0] for line in lines[:12]] == [
        "NO_OF_FRAMES", "NO_OF_CAMERAS", "NO_OF_MARKERS", "FREQUENCY", "NO_OF_ANALOG", "ANALOG_FREQUENCY",
        "DESCRIPTION", "TIME_STAMP", "DATA_INCLUDED", "MARKER_NAMES", "TRAJECTORY_TYPES", "Frame"]
    assert lines[3] == "FREQUENCY\t200" and lines[12].startswith(f"{data.first_frame}\t2.21000\t")  # QTM: time from frame 1
    back = read(io.BytesIO(text.encode()), format="tsv")
    assert back.labels == data.labels and back.rate == data.rate and back.first_frame == data.first_frame
    np.testing.assert_array_equal(back.missing, data.missing)
    np.testing.assert_allclose(back.positions[~back.missing], data.positions[~data.missing], atol=5e-4)


def test_writer_converts_to_mm_and_refuses_labels_it_cannot_hold(test_data):
    data = read(test_data / "Running_0002.c3d")
    in_m = data.with_positions(data.positions / 1000)
    in_m.units = "m"
    back = read(io.BytesIO(tsv_text(in_m).encode()), format="tsv")
    assert back.units == "mm"
    np.testing.assert_allclose(back.positions[~back.missing], data.positions[~data.missing], atol=5e-4)
    bad = data.with_positions(data.positions)
    bad.labels = ["a\tb"] + bad.labels[1:]
    with pytest.raises(FormatError, match="tab"):
        write(bad, io.BytesIO(), format="tsv")


def test_tsv_to_c3d_to_tsv_keeps_every_observed_sample(coda, tmp_path):
    positions, labels = coda
    src = tmp_path / "take.tsv"
    src.write_text(qtm_text(positions, labels, rate=200))
    c3d, back = tmp_path / "take.c3d", tmp_path / "back.tsv"
    write(read(src), c3d)
    write(read(c3d), back)
    rows = lambda path: [line for line in path.read_text().splitlines() if line[:1].isdigit()]  # noqa: E731
    assert rows(back) == rows(src)  # every sample, to the file's three decimals, and the zeros of missing ones
    assert read(back).labels == labels and read(back).rate == 200


def test_tsv_rewrite_keeps_the_header_and_types_filled_markers_mixed(coda, tmp_path):
    positions, labels = coda
    src = tmp_path / "take.tsv"
    src.write_text(qtm_text(positions, labels, rate=200, file_version=True, events=[("Start", 10)]))
    result = CliRunner().invoke(cli, ["fill", str(src), str(tmp_path / "out.tsv"), "--method", "linear"])
    assert result.exit_code == 0, result.output
    head = (tmp_path / "out.tsv").read_text().splitlines()[:14]
    assert head[0] == "FILE_VERSION\t2.0.0" and "NO_OF_CAMERAS\t10" in head and "EVENT\tStart\t10\t0.100" in head
    assert "TIME_STAMP\t2026-01-19, 10:19:43.755\t2063631.96175450" in head
    types = next(line for line in head if line.startswith("TRAJECTORY_TYPES")).split("\t")[1:]
    had_gaps = np.isnan(positions).any(axis=2).any(axis=0)
    assert types == ["Mixed" if gap else "Measured" for gap in had_gaps] and had_gaps.any()


def test_qtm_take_2000_frames_15_markers_reads_and_fills_to_c3d(coda, tmp_path):
    """The issue's hidden-file shape: 2,000 frames, 15 markers, 100 Hz (a real clip run forth and back)."""
    positions, labels = coda
    clip = np.concatenate([positions, positions[::-1]] * 2)[:2000, :15]
    src = tmp_path / "Measurement1.tsv"
    src.write_text(qtm_text(clip, labels[:15], rate=100))
    result = CliRunner().invoke(cli, ["fill", str(src), str(tmp_path / "filled.c3d"), "--method", "linear"])
    assert result.exit_code == 0, result.output
    before, after = read(src), read(tmp_path / "filled.c3d")
    assert (before.n_frames, before.n_markers, before.rate) == (2000, 15, 100)
    assert before.missing.any() and not after.missing.any()
    assert after.labels == before.labels and after.rate == 100 and after.first_frame == 1
    seen = ~before.missing
    np.testing.assert_allclose(after.positions[seen], before.positions[seen], atol=1e-4)  # float32 C3D


def test_detection_by_content_extension_override_and_stdin(coda, tmp_path):
    positions, labels = coda
    text = qtm_text(positions[:30], labels)
    odd = tmp_path / "take.txt"  # unknown extension: the content says TSV
    odd.write_text(text)
    assert read(odd).source_format == "tsv"
    assert read(odd, format="tsv").n_frames == 30
    runner = CliRunner()
    result = runner.invoke(cli, ["info", "-"], input=text)
    assert result.exit_code == 0, result.output
    assert "30" in result.output
    result = runner.invoke(cli, ["fill", "-", "-", "--method", "linear"], input=text)
    assert result.exit_code == 0, result.stderr
    assert result.stdout.startswith("NO_OF_FRAMES\t30\n")  # written back as TSV
    result = runner.invoke(cli, ["info", "--input-format", "tsv", "-"], input="Frame,Time\n1,2\n")
    assert result.exit_code == 1 and "not a QTM TSV" in result.output
