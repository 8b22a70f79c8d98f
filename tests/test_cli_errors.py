"""Every input / output error: one line `Error: <file>: <problem>`, exit status 1, no traceback."""

from __future__ import annotations

import os

import pytest
from click.testing import CliRunner

from mocapfill.errors import InputError
from mocapfill.io import atomic_write, check_output_path
from mocapfill.cli import cli


def _info_error(path) -> str:
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f"Error: {path}: ")
    return lines[0]


def test_missing_file(tmp_path):
    assert _info_error(tmp_path / "nope.c3d").endswith(": no such file")


def test_directory_instead_of_file(tmp_path):
    (tmp_path / "d.c3d").mkdir()
    assert "is a directory" in _info_error(tmp_path / "d.c3d")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root reads any file")
def test_unreadable_file(tmp_path):
    path = tmp_path / "secret.c3d"
    path.write_bytes(b"\0" * 1024)
    path.chmod(0)
    try:
        assert "cannot read: Permission denied" in _info_error(path)
    finally:
        path.chmod(0o600)


def test_unknown_extension(tmp_path):
    path = tmp_path / "capture.xyz"
    path.write_text("1,2,3\n")
    assert "unknown file extension '.xyz'" in _info_error(path)
    path = tmp_path / "capture"
    path.write_text("1,2,3\n")
    assert "no file extension" in _info_error(path)


def test_truncated_c3d(sample_data, tmp_path):
    path = tmp_path / "cut.c3d"
    raw = (sample_data / "85_02.c3d").read_bytes()
    path.write_bytes(raw[:-20000])
    assert "truncated C3D: the data section holds" in _info_error(path)


def test_corrupt_c3d(tmp_path):
    path = tmp_path / "junk.c3d"
    path.write_bytes(bytes(range(1, 11)) + b"\x00" * 3000)  # byte 1 is not 0x50, the C3D signature
    assert "not a C3D file" in _info_error(path)


def test_ragged_csv(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("time,A_x,A_y,A_z\n0,1,2,3\n0.1,1,2,3,4\n")
    assert "line 3 has 5 fields, the header has 4 (ragged CSV)" in _info_error(path)


def test_non_numeric_csv(tmp_path):
    path = tmp_path / "n.csv"
    path.write_text("time,A_x,A_y,A_z\n0,1,2,3\n0.1,1,two,3\n")
    assert "'two' in column 'A_y' is not a number" in _info_error(path)


def test_duplicate_csv_columns(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("time,A_x,A_y,A_y,A_z\n0,1,2,3,4\n")
    assert "column 'A_y' appears more than once" in _info_error(path)


def test_binary_file_with_a_text_extension(sample_data, tmp_path):
    path = tmp_path / "b.csv"
    path.write_bytes((sample_data / "85_02.c3d").read_bytes())
    assert "binary content" in _info_error(path)


def test_coordinates_too_large_to_fill(tmp_path):
    """±1e308 around a gap: spline raised "dydx must contain only finite values", msvd an SVD that did not converge,
    evaluate failed every trial; now one line naming the file where the data enter the fill."""
    path = tmp_path / "huge.csv"
    rows = ["time,A_x,A_y,A_z,B_x,B_y,B_z"]
    for t in range(30):
        b = "" if 10 <= t < 20 else f"{(-1) ** t * 1e308},1,2"
        rows.append(f"{t / 100},{(-1) ** t * 1e308},0,0,{b or ',,'}")
    path.write_text("\n".join(rows) + "\n")
    for args in (["fill", str(path), str(tmp_path / "o.csv"), "-m", "spline"],
                 ["fill", str(path), str(tmp_path / "o.csv"), "-m", "msvd", "--reject-outliers"],
                 ["evaluate", str(path), "-m", "linear", "-n", "1", "-s", "1"]):
        result = CliRunner().invoke(cli, args + ["--rate", "100"])
        assert result.exit_code == 1, result.output
        lines = [x for x in result.stderr.splitlines() if x.strip() and not x.startswith("note: ")]  # units assumed
        assert len(lines) == 1 and lines[0].startswith(f"Error: {path}: coordinates too large to fill (A reaches ")
        assert "Traceback" not in result.output


def test_header_only_file_is_refused_by_fill_evaluate_and_batch(tmp_path):
    """A CSV of labels and no rows: `fill` wrote a 0-frame file and called it done; now one line naming the file
    (info still shows its 0 frames)."""
    path = tmp_path / "hdr.csv"
    path.write_text("frame,time,A_x,A_y,A_z,B_x,B_y,B_z\n")
    for args in (["fill", str(path), str(tmp_path / "o.csv"), "-m", "linear"],
                 ["evaluate", str(path), "-m", "linear", "-n", "1", "-s", "1"],
                 ["batch", str(path), "-o", str(tmp_path / "out"), "-m", "linear"]):
        result = CliRunner().invoke(cli, args + ["--rate", "100"])
        assert result.exit_code == 1, result.output
        assert "Traceback" not in result.output
        lines = [x for x in result.stderr.splitlines() if x.strip() and not x.startswith("note: ")]  # units assumed
        assert f"{path}: no frames (a header only): nothing to fill" in lines[0], result.stderr
    assert not (tmp_path / "o.csv").exists()
    shown = CliRunner().invoke(cli, ["info", str(path), "--rate", "100"])
    assert shown.exit_code == 0 and "0 (first frame 1)" in shown.stderr


# --- output paths (exercised through `fill` by its owner; tested here directly) ----------------------------------

def test_output_equal_to_input(tmp_path):
    src = tmp_path / "a.c3d"
    src.write_bytes(b"x")
    with pytest.raises(InputError, match=r"a\.c3d: output is the same file as the input"):
        check_output_path(src, src)
    with pytest.raises(InputError, match="same file"):
        check_output_path(tmp_path / "sub" / ".." / "a.c3d", "other.csv", src)
    link = tmp_path / "link.c3d"
    link.symlink_to(src)
    with pytest.raises(InputError, match="same file"):
        check_output_path(link, src)
    check_output_path(tmp_path / "b.c3d", src)  # different: fine
    check_output_path("-", "-")  # stdout never clashes with stdin
    check_output_path(None, src)


def test_unwritable_output_directory(tmp_path):
    with pytest.raises(InputError, match=r"missing/out\.c3d: cannot write: .* does not exist"):
        with atomic_write(tmp_path / "missing" / "out.c3d") as fh:
            fh.write(b"x")
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="is not a directory"):
        with atomic_write(tmp_path / "file" / "out.c3d"):
            pass
    with pytest.raises(InputError, match="is a directory"):
        with atomic_write(tmp_path):
            pass


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes anywhere")
def test_read_only_directory(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(InputError, match="cannot write: Permission denied"):
            with atomic_write(ro / "out.c3d"):
                pass
    finally:
        ro.chmod(0o700)


def test_failed_write_leaves_no_file_and_keeps_the_old_one(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old content")
    with pytest.raises(RuntimeError):
        with atomic_write(target, "w") as fh:
            fh.write("half of the new")
            raise RuntimeError("boom")
    assert target.read_text() == "old content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]
    with atomic_write(target, "w") as fh:
        fh.write("new")
    assert target.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_atomic_write_keeps_permissions(tmp_path):
    target = tmp_path / "out.c3d"
    target.write_bytes(b"")
    target.chmod(0o640)
    with atomic_write(target) as fh:
        fh.write(b"data")
    assert (target.stat().st_mode & 0o777) == 0o640


def test_atomic_write_follows_a_symlink(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    (real / "target.csv").write_text("old content")
    link = tmp_path / "link.csv"
    link.symlink_to(real / "target.csv")
    with atomic_write(link, "w") as fh:
        fh.write("new")
    assert link.is_symlink() and (real / "target.csv").read_text() == "new"
    assert sorted(p.name for p in real.iterdir()) == ["target.csv"]  # the temporary file went where the target is
    dangling = tmp_path / "dangling.csv"
    dangling.symlink_to(real / "new.csv")
    with atomic_write(dangling, "w") as fh:
        fh.write("made")
    assert dangling.is_symlink() and (real / "new.csv").read_text() == "made"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_atomic_write_streams_into_a_fifo(tmp_path):
    import stat

    fifo = tmp_path / "ff.csv"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader first, so opening the write end does not block
    try:
        with atomic_write(fifo, "w") as fh:
            fh.write("frame,A\n")
        assert os.read(reader, 100) == b"frame,A\n"
    finally:
        os.close(reader)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ff.csv"]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_atomic_write_to_a_device_behind_a_symlink(tmp_path):
    import stat

    sink = tmp_path / "sink.csv"
    sink.symlink_to(os.devnull)
    with atomic_write(sink, "w") as fh:
        fh.write("anything")
    full = tmp_path / "full.csv"
    full.symlink_to("/dev/full")
    for text in ("anything", "x" * (1 << 20)):  # refused at the flush, or already at the write
        with pytest.raises(InputError, match=r"full\.csv: cannot write: No space left on device"):
            with atomic_write(full, "w") as fh:
                fh.write(text)
    for link, device in ((sink, os.devnull), (full, "/dev/full")):
        assert link.is_symlink() and os.readlink(link) == device
        assert stat.S_ISCHR(os.stat(device).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full.csv", "sink.csv"]


def test_write_refuses_to_overwrite_the_input(sample_data, tmp_path):
    import shutil

    import mocapfill

    src = tmp_path / "in.c3d"
    shutil.copy(sample_data / "85_02.c3d", src)
    data = mocapfill.read(src)
    with pytest.raises(InputError, match=r"in\.c3d: output is the same file as the input"):
        mocapfill.write(data, src)
    assert src.read_bytes() == (sample_data / "85_02.c3d").read_bytes()


def test_a_caught_warning_is_worded_once_with_its_category():
    import warnings

    from mocapfill.errors import DataWarning, warning_line

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.warn("take.c3d: 3 sample(s)\n  not written", DataWarning)
    assert warning_line(caught[0]) == "DataWarning: take.c3d: 3 sample(s) not written"
