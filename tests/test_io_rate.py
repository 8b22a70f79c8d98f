"""``rate=`` / ``--rate``: a file without a rate reads with it; a contradicting rate is an error unless overridden."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.errors import FormatError, InputError

BARE = "m1_x,m1_y,m1_z,m2_x,m2_y,m2_z\n1,2,3,4,5,6\n1.5,2,3,,,\n2,2,3,4,5,7\n"


@pytest.fixture()
def bare_csv(tmp_path):
    path = tmp_path / "bare.csv"
    path.write_text(BARE)
    return path


def test_bare_csv_needs_a_rate_and_the_error_names_the_option(bare_csv):
    with pytest.raises(FormatError, match=r"bare\.csv: the file has no frame rate; give it with --rate HZ"):
        mocapfill.read(bare_csv)
    result = CliRunner().invoke(cli, ["info", str(bare_csv)])
    assert result.exit_code == 1
    assert result.stderr.strip().splitlines() == [
        f"Error: {bare_csv}: the file has no frame rate; give it with --rate HZ (rate= in Python)"]


def test_bare_csv_reads_with_a_rate(bare_csv, tmp_path):
    data = mocapfill.read(bare_csv, rate=120)
    assert data.rate == 120.0 and data.positions.shape == (3, 2, 3)
    result = CliRunner().invoke(cli, ["info", "--json", "--rate", "120", str(bare_csv)])
    assert result.exit_code == 0, result.output
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(cli, ["fill", str(bare_csv), str(out), "--rate", "120", "--method", "linear"])
    assert result.exit_code == 0, result.output
    assert mocapfill.read(out).rate == 120.0  # our CSV writes the rate it was given


def test_contradicting_rate_is_an_error_unless_overridden(sample_data):
    path = sample_data / "85_02.c3d"
    assert mocapfill.read(path, rate=120).rate == 120.0  # agreeing is fine
    with pytest.raises(FormatError, match=r"--rate 100 contradicts the file's rate of 120 Hz"):
        mocapfill.read(path, rate=100)
    data = mocapfill.read(path, rate=100, override_rate=True)
    assert data.rate == 100.0 and any("replaced by 100 Hz" in note for note in data.notes)
    result = CliRunner().invoke(cli, ["info", str(path), "--rate", "100"])
    assert result.exit_code == 1 and "--override-rate" in result.stderr
    result = CliRunner().invoke(cli, ["info", "--json", str(path), "--rate", "100", "--override-rate"])
    assert result.exit_code == 0 and '"rate": 100.0' in result.stdout


@pytest.mark.parametrize("bad", [0, -5, float("nan"), "fast"])
def test_bad_rate_values(bare_csv, bad):
    with pytest.raises(InputError, match="bare.csv: --rate"):
        mocapfill.read(bare_csv, rate=bad)


def test_cli_rejects_a_non_positive_rate(bare_csv):
    result = CliRunner().invoke(cli, ["info", str(bare_csv), "--rate", "0"])
    assert result.exit_code == 2


def test_stdin_csv_with_rate(bare_csv):
    result = CliRunner().invoke(cli, ["info", "--json", "-", "--input-format", "csv", "--rate", "50"],
                                input=bare_csv.read_bytes())
    assert result.exit_code == 0, result.output
    assert '"rate": 50.0' in result.stdout


def test_a_rate_within_the_time_columns_precision_agrees(tmp_path):
    """A time column to three decimals at 120 Hz agrees with any rate within about 0.02 Hz of 120."""
    path = tmp_path / "t3.csv"
    path.write_text("frame,time,A_x,A_y,A_z\n" + "".join(f"{i + 1},{i / 120:.3f},{i},2,3\n" for i in range(240)))
    assert mocapfill.read(path).rate == 120.0
    assert mocapfill.read(path, rate=120).rate == 120.0
    data = mocapfill.read(path, rate=119.99)
    assert data.rate == 119.99 and not any("replaced" in note for note in data.notes)
    with pytest.raises(FormatError, match=r"--rate 119.9 contradicts the file's rate of 120 Hz"):
        mocapfill.read(path, rate=119.9)
    result = CliRunner().invoke(cli, ["info", "--json", str(path), "--rate", "120"])
    assert result.exit_code == 0 and '"rate": 120.0' in result.stdout


@pytest.mark.parametrize("suffix", [".c3d", ".trc", ".csv", ".tsv"])
def test_overridden_rate_reaches_every_output_format(sample_data, tmp_path, suffix):
    out = tmp_path / f"ov{suffix}"
    result = CliRunner().invoke(cli, ["fill", str(sample_data / "kinematics_tennis_serve_nan.c3d"), str(out),
                                      "--rate", "100", "--override-rate", "-m", "linear"])
    assert result.exit_code == 0, result.output
    assert mocapfill.read(out).rate == 100.0
