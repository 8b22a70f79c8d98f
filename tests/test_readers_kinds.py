"""Issue 23, the readers: labels in their right columns, C3D parameter names as real writers spell them, and each
point's kind (marker, model point, unlabelled trajectory), built small for every case."""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.errors import DataWarning
from mocapfill.io import c3dfile
from mocapfill.io.labels import match_label_row, point_kinds
from mocapfill.markers import MarkerData


def _trc(label_row: str, n: int, rows: list[list[float]], axis_row: str | None = None) -> str:
    axis_row = axis_row if axis_row is not None else "\t\t" + "\t".join(f"X{k}\tY{k}\tZ{k}" for k in range(1, n + 1))
    lines = ["PathFileType\t4\t(X/Y/Z)\tx.trc",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits",
             f"100\t100\t{len(rows)}\t{n}\tmm", label_row, axis_row, ""]
    lines += ["\t".join([str(t + 1), str(t / 100)] + [repr(v) for v in row]) for t, row in enumerate(rows)]
    return "\n".join(lines) + "\n"


def _rows(n_frames: int, n: int) -> list[list[float]]:
    # marker k sits at x = 100 k (+ t): its column is known from its values
    return [[v for k in range(n) for v in (100.0 * k + t, 10.0, 20.0)] for t in range(n_frames)]


NAMES = ["C7", "T10", "CLAV", "STRN", "LASI"]


@pytest.mark.parametrize("sep", ["\t\t\t", "\t\t", "\t", "\t\t\t\t"])
def test_trc_label_row_spacing_never_moves_a_name(tmp_path, sep):
    text = _trc("Frame#\tTime\t" + sep.join(NAMES), len(NAMES), _rows(4, len(NAMES)))
    path = tmp_path / "x.trc"
    path.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)  # names matched by count: no warning
        data = mocapfill.read(path)
    assert data.labels == NAMES
    assert data.positions[0, :, 0].tolist() == [0.0, 100.0, 200.0, 300.0, 400.0]  # C7 in C7's column
    assert bool(data.notes) == (sep != "\t\t\t")  # irregular spacing is noted


def test_trc_label_row_that_cannot_be_matched_gives_placeholders_and_one_warning(tmp_path):
    # two tabs between names, and one name short: which marker lacks its name cannot be known
    text = _trc("Frame#\tTime\t" + "\t\t".join(NAMES[:4]), len(NAMES), _rows(3, len(NAMES)))
    path = tmp_path / "x.trc"
    path.write_text(text)
    with pytest.warns(DataWarning, match=r"x\.trc: the label row \(line 4\) holds 4 names.*M001-M005"):
        data = mocapfill.read(path)
    assert data.labels == ["M001", "M002", "M003", "M004", "M005"]
    assert not set(NAMES) & set(data.labels)


def test_trc_rows_wider_than_the_labels_keep_unnamed_columns_as_unlabelled(tmp_path):
    rows = _rows(3, 3)
    rows[1] += [900.0, 1.0, 2.0, 950.0, 1.0, 2.0]  # one row holds two more markers (Gait.trc's layout)
    text = _trc("Frame#\tTime\tA\t\t\tB\t\t\tC", 3, rows)
    path = tmp_path / "x.trc"
    path.write_text(text)
    with pytest.warns(DataWarning, match="the rows hold 5 markers, the label row names 3"):
        data = mocapfill.read(path)
    assert data.labels == ["A", "B", "C", "M004", "M005"]
    assert data.kinds == ["marker"] * 3 + ["unlabelled"] * 2
    assert data.positions[1, 3, 0] == 900.0 and np.isnan(data.positions[0, 3]).all()


def test_vicon_csv_label_row_spacing(tmp_path):
    head = "Trajectories\n100\n,,{}\nFrame,Sub Frame," + ",".join("X,Y,Z" for _ in NAMES) + "\n,," + \
        ",".join("mm,mm,mm" for _ in NAMES) + "\n"
    body = "".join(f"{t + 1},0," + ",".join(f"{100 * k + t},1,2" for k in range(len(NAMES))) + "\n" for t in range(3))
    path = tmp_path / "v.csv"
    path.write_text(head.format(",,".join(f"s:{n}" for n in NAMES)) + body)  # two commas instead of three
    data = mocapfill.read(path)
    assert data.labels == [f"s:{n}" for n in NAMES] and data.positions[0, 2, 0] == 200.0


def test_match_label_row_aligned_with_gaps():
    labels, note, matched = match_label_row(["A", "", "", "", "", "", "C", "", ""], 3, "row")
    assert (labels, note, matched) == (["A", "", "C"], None, True)


def test_point_kinds_by_name():
    labels = ["LASI", "PELO", "PELA", "PELL", "PELP", "LFOO", "LHJC", "RKJC_CGM_2.4", "CentreOfMass",
              "CentreOfMassFloor", "*12", "Unlabeled 1003", "sub:*3", "LTHI"]
    assert point_kinds(labels) == ["marker", "model", "model", "model", "model", "marker", "model", "model",
                                   "model", "model", "unlabelled", "unlabelled", "unlabelled", "marker"]


def test_unlabelled_names_with_a_colon_or_an_asterisk():
    # Motive's "Unlabeled:108" is no subject prefix (cut at the colon, "108" looked like a marker); Cortex writes
    # "*Unnamed_60".  A real subject prefix still leaves a marker (or an unlabelled name) behind it.
    labels = ["Unlabeled:108", "*Unnamed_60", "Subject:LASI", "Rigid Body 1:Marker1", "Subject:Unlabeled:3",
              "subject:*Unnamed_2", "*LASI", "Unnamed:LASI"]
    assert point_kinds(labels) == ["unlabelled", "unlabelled", "marker", "marker", "unlabelled", "unlabelled",
                                   "marker", "marker"]


def test_motive_take_keeps_its_colon_named_unlabelled_trajectories_aside(test_data):
    data = mocapfill.read(test_data / "motive_sample_take.csv")
    kinds = dict(zip(data.labels, data.kinds))
    assert kinds["Unlabeled:108"] == kinds["Unlabeled:105"] == "unlabelled"
    assert kinds["Rigid Body 1:Marker1"] == kinds["Rigid Body 1_1"] == "marker"
    assert data.kinds.count("unlabelled") == 6 and data.kinds.count("marker") == 6
    result = CliRunner().invoke(cli, ["info", str(test_data / "motive_sample_take.csv")])
    assert result.exit_code == 0, result.output
    assert "kept aside          6 unlabelled trajectories" in result.stderr


def test_header_only_csv_keeps_an_unlabelled_name_whole(tmp_path):
    path = tmp_path / "u.csv"
    path.write_text("time,male:LKNE_x,male:LKNE_y,male:LKNE_z,Unlabeled:108_x,Unlabeled:108_y,Unlabeled:108_z\n"
                    "0.0,1,2,3,4,5,6\n0.01,1,2,3,4,5,6\n")
    data = mocapfill.read(path)
    assert data.labels == ["LKNE", "Unlabeled:108"] and data.kinds == ["marker", "unlabelled"]
    assert "subject prefix 'male:' removed from the labels" in data.notes


def test_cortex_unnamed_trajectories_kept_aside(shared_data):
    data = mocapfill.read(shared_data / "btk" / "TRCSamples" / "Knee.trc")
    unnamed = [lab for lab in data.labels if lab.startswith("*Unnamed_")]
    assert unnamed and [data.kinds[data.labels.index(lab)] for lab in unnamed] == ["unlabelled"] * len(unnamed)
    assert data.kinds.count("marker") == data.n_markers - len(unnamed)


# --- C3D -----------------------------------------------------------------------------------------------------------

def _pig_like(n_frames: int = 60) -> MarkerData:
    """Plug-in-Gait-like capture: 4 pelvis markers, a foot marker called LFOO, the pelvis axes, a joint centre,
    the centre of mass and an unlabelled trajectory."""
    t = np.arange(n_frames)[:, None]
    base = np.array([[100.0, 0, 900], [-100, 0, 900], [80, -150, 950], [-80, -150, 950], [50, 100, 50]])
    markers = base[None] + np.stack([10.0 * t, 0 * t, 2 * np.sin(t / 5)], axis=2)
    centre = markers[:, :4].mean(axis=1, keepdims=True)
    axes = centre + np.array([[0.0, 0, 0], [0, 80, 0], [80, 0, 0], [0, 0, 80]])[None]
    extra = np.concatenate([centre + 5, centre - 5 * np.array([0, 0, 180.0]), markers[:, :1] + 300], axis=1)
    positions = np.concatenate([markers, axes, extra], axis=1)
    positions[:20, -1] = np.nan  # the ghost is seen only from frame 20 on
    positions[30:40, 0] = np.nan  # and a real gap in LASI
    labels = ["LASI", "RASI", "LPSI", "RPSI", "LFOO", "PELO", "PELA", "PELL", "PELP", "LHJC", "CentreOfMass",
              "*7"]
    return MarkerData(positions, labels, 100.0, "mm")


def test_pig_like_c3d_kinds_and_the_fill_leaves_them_alone(tmp_path):
    path = tmp_path / "pig.c3d"
    mocapfill.write(_pig_like(), path)
    data = mocapfill.read(path)
    assert data.kinds == ["marker"] * 5 + ["model"] * 6 + ["unlabelled"]

    from mocapfill.pipeline import FillSettings, fill_capture, fill_columns

    assert fill_columns(data).tolist() == [0, 1, 2, 3, 4]
    outcome = fill_capture(data, FillSettings(method="spline"))
    out = outcome.output.positions
    assert np.isfinite(out[30:40, 0]).all()  # the marker's gap is filled
    assert np.isnan(out[:20, -1]).all()  # the unlabelled trajectory is not
    assert np.array_equal(out[:, 5:], data.positions[:, 5:], equal_nan=True)  # model points untouched
    assert outcome.result.filled[:, 5:].sum() == 0


def _rename_parameter(raw: bytes, old: bytes, new: bytes) -> bytes:
    assert len(old) == len(new) and raw.count(old) == 1
    return raw.replace(old, new)


def test_c3d_percent_parameter_names_keep_the_chain(tmp_path):
    path = tmp_path / "a.c3d"
    mocapfill.write(_pig_like(), path)
    raw = _rename_parameter(path.read_bytes(), b"GEN_SCALE", b"%RMMAXVAL")  # Vicon Nexus spells names like this
    f = c3dfile.parse(raw, "a.c3d")
    assert f.notes == []
    assert f.param("ANALOG", "%RMMAXVAL") is not None
    assert f.param("MANUFACTURER", "SOFTWARE") is not None  # the parameters after it are read
    data = mocapfill.io.c3d.read_c3d(raw, "a.c3d")
    assert not any("chain" in n for n in data.notes)


def test_c3d_real_break_still_noted(tmp_path):
    path = tmp_path / "a.c3d"
    mocapfill.write(_pig_like(), path)
    raw = bytearray(path.read_bytes())
    at = raw.index(b"GEN_SCALE")
    # the entry's type byte (after the name and its 2-byte offset) becomes 7: neither the stored offset nor the
    # parsed size leads anywhere sensible
    raw[at + 9 + 2] = 7
    f = c3dfile.parse(bytes(raw), "a.c3d")
    assert any("the parameter chain breaks" in n for n in f.notes)
    assert f.param("MANUFACTURER", "SOFTWARE") is None


def test_plausible_entry_is_structural():
    name = b"%RMMAX"
    entry = struct.pack("bb", len(name), 2) + name + struct.pack("<h", 8) + struct.pack("bB", 4, 0) + b"\0\0\0\0" + b"\0"
    assert c3dfile.plausible_entry(entry, 0, len(entry))
    bad_type = bytearray(entry)
    bad_type[2 + len(name) + 2] = 3
    assert not c3dfile.plausible_entry(bytes(bad_type), 0, len(entry))
    assert not c3dfile.plausible_entry(entry, 0, len(entry) - 3)  # data past the section's end


def test_c3d_modeled_markers_parameter_and_points_seen_by_no_camera():
    from mocapfill.io.c3d import c3d_kinds

    class Fake:
        def __init__(self, params):
            self.params = params

        def strings(self, group, name):
            return self.params.get((group, name), [])

    labels = ["A", "B", "C", "VIRT", "JOINT"]
    positions = np.ones((10, 5, 3))
    residual = np.full((10, 5), 2.5)
    residual[:, 3] = 0.0  # VIRT: residual exactly 0 throughout while the others carry camera residuals
    f = Fake({("POINT", "TYPE_GROUPS"): ["ANGLES", "ANGLE", "MODELED_MARKERS", "MODELED_MARKER"],
              ("POINT", "MODELED_MARKERS"): ["JOINT"]})
    kinds, notes = c3d_kinds(f, labels, labels, positions, residual)
    assert kinds == ["marker", "marker", "marker", "model", "model"]
    assert any("seen by no camera" in n for n in notes)
    kinds, _ = c3d_kinds(f, labels, labels, positions, np.zeros((10, 5)))  # no camera data: nothing to judge
    assert kinds == ["marker", "marker", "marker", "marker", "model"]


def test_python_fill_and_evaluate_leave_model_points_and_ghosts_alone(tmp_path):
    path = tmp_path / "pig.c3d"
    mocapfill.write(_pig_like(), path)
    data = mocapfill.read(path)
    result = mocapfill.fill(data, method="spline")
    assert result.positions.shape == data.positions.shape
    assert np.isfinite(result.positions[30:40, 0]).all() and np.isnan(result.positions[:20, -1]).all()
    assert np.array_equal(result.positions[:, 5:], data.positions[:, 5:], equal_nan=True)
    scores = mocapfill.evaluate(data, methods=["linear"], trials=2, seed=0)
    assert scores.data.labels == ["LASI", "RASI", "LPSI", "RPSI", "LFOO"]


def test_motive_unlabeled_and_qtm_unnamed_trajectories(tmp_path):
    motive = ("Format Version,1.23,Export Frame Rate,100,Length Units,Millimeters\n\n"
              ",,Marker,Marker,Marker,Marker,Marker,Marker\n"
              ",,Hand:M1,Hand:M1,Hand:M1,Unlabeled 1000,Unlabeled 1000,Unlabeled 1000\n"
              ",,Position,Position,Position,Position,Position,Position\n"
              "Frame,Time (Seconds),X,Y,Z,X,Y,Z\n0,0,1,2,3,4,5,6\n1,0.01,1,2,3,,,\n")
    path = tmp_path / "m.csv"
    path.write_text(motive)
    data = mocapfill.read(path)
    assert data.labels == ["Hand:M1", "Unlabeled 1000"] and data.kinds == ["marker", "unlabelled"]
    tsv = "NO_OF_FRAMES\t2\nNO_OF_MARKERS\t2\nFREQUENCY\t100\nMARKER_NAMES\t\tB\n1\t0\t1\t2\t3\t4\t5\t6\n2\t0.01\t1\t2\t3\t4\t5\t7\n"
    path = tmp_path / "q.tsv"
    path.write_text(tsv)
    data = mocapfill.read(path)  # QTM lists an unidentified trajectory without a name
    assert data.labels == ["M001", "B"] and data.kinds == ["unlabelled", "marker"]
