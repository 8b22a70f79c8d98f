"""`mocapfill info`: the tables on stderr, --json on stdout, stdin."""

from __future__ import annotations

import json

from click.testing import CliRunner

from mocapfill.cli import cli


def test_info_table_on_stderr(sample_data):
    result = CliRunner().invoke(cli, ["info", str(sample_data / "markers_analogs.c3d")])
    assert result.exit_code == 0, result.output
    assert result.stdout == ""  # stdout carries data only
    err = result.stderr
    for text in ("580 (first frame 1)", "100 Hz", "5.800 s", "mm", "51 (38 complete)", "1.03 %", "34 gaps",
                 "71 frames (0.71 s)", "38 analog channels", "boite:gauche_ext", "Daphnee:STERr"):
        assert text in err, text


def test_info_lists_blackouts_and_markers_missing_throughout(tmp_path):
    path = tmp_path / "b.csv"
    path.write_text("# mocapfill csv: units=mm rate=10 first_frame=1\nframe,time,A_x,A_y,A_z,B_x,B_y,B_z\n"
                    "1,0,,,,,,\n2,0.1,1,2,3,,,\n3,0.2,,,,,,\n4,0.3,,,,,,\n5,0.4,1,2,3,,,\n")
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 0, result.output
    assert "blackout frames" in result.stderr and "3: 1, 3-4" in result.stderr
    assert "B (missing throughout)" in result.stderr


def test_info_json_on_stdout(sample_data):
    result = CliRunner().invoke(cli, ["info", "--json", str(sample_data / "kinematics_tennis_serve_nan.c3d")])
    assert result.exit_code == 0, result.output
    s = json.loads(result.stdout)
    assert (s["n_frames"], s["n_markers"], s["rate"], s["units"]) == (1092, 39, 50.0, "m")
    assert s["n_missing"] == 145 and s["n_gaps"] == 10 and s["longest_gap_frames"] == 42
    assert s["longest_gap_seconds"] == 0.84
    assert sum(m["n_gaps"] for m in s["markers"]) == 10
    assert result.stderr == ""


def test_info_reads_stdin(sample_data):
    raw = (sample_data / "85_02.c3d").read_bytes()
    result = CliRunner().invoke(cli, ["info", "--json", "-"], input=raw)
    assert result.exit_code == 0, result.output
    s = json.loads(result.stdout)
    assert s["path"] == "-" and s["format"] == "c3d" and s["n_markers"] == 41 and s["percent_missing"] == 0.0


def test_info_vicon_csv_from_stdin_with_format(sample_data):
    raw = (sample_data / "markers.csv").read_bytes()
    result = CliRunner().invoke(cli, ["info", "--json", "--input-format", "vicon-csv", "-"], input=raw)
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["n_gaps"] == 34


def test_info_quiet_prints_nothing(sample_data):
    result = CliRunner().invoke(cli, ["info", "-q", str(sample_data / "85_02.c3d")])
    assert result.exit_code == 0 and result.output == ""


def test_info_notes_shown(test_data):
    result = CliRunner().invoke(cli, ["info", str(test_data / "markers.trc")])
    assert result.exit_code == 0, result.output
    assert "note: header says 652 frames, the file holds 93" in result.stderr


def test_info_tables_uncut_when_stderr_is_not_a_terminal(tmp_path):
    # rich lays a pipe's output out in 80 columns and cut these cells with an ellipsis
    label = "Subject_With_A_Rather_Long_Name:LEFT_ANTERIOR_SUPERIOR_ILIAC_SPINE"
    rows = ["# mocapfill csv: units=mm rate=120 first_frame=1",
            "frame,time," + ",".join(f"{m}_{c}" for m in (label, "B") for c in "xyz")]
    for i in range(400):
        a = ",," if 50 <= i < 300 else f"{i},{i},{i}"
        rows.append(f"{i + 1},{i / 120},{a},{i},{i + 1},{i + 2}")
    path = tmp_path / "long.csv"
    path.write_text("\n".join(rows) + "\n")
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 0, result.output
    assert label in result.stderr and "250 (2.08 s)" in result.stderr and "missing %" in result.stderr
    assert "…" not in result.stderr


def test_console_keeps_rich_width_on_a_terminal():
    from rich.console import Console

    from mocapfill.cli.common import UNBOUNDED_WIDTH, _StderrConsole

    assert _StderrConsole(stderr=True, force_terminal=True).width == Console(stderr=True, force_terminal=True).width
    assert _StderrConsole(stderr=True, force_terminal=False, width=80).width == UNBOUNDED_WIDTH  # COLUMNS=80 too
