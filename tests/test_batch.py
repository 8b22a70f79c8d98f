"""`mocapfill batch` / `mocapfill.batch`: rows and exit status on a mixed folder with a corrupt file, outputs equal
across serial / local processes / a Dask LocalCluster, a killed worker, resuming, --force, Ctrl-C."""

from __future__ import annotations

import csv
import multiprocessing
import os
import shutil
import signal
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.batching import COLUMNS, INDEX_NAME, RESULTS_NAME, STATE_NAME
from mocapfill.cli import cli
from mocapfill.runtime.executor import WORKER_NAME
from mocapfill.errors import MocapfillError

GOOD = {"serve.c3d": 1092, "vicon.csv": 580, "sub/T.trc": 89, "sub/deeper/racing.c3d": 700}


@pytest.fixture()
def session(tmp_path, sample_data, test_data):
    """A folder with C3D, CSV and TRC captures (some in subfolders) and one corrupt C3D."""
    root = tmp_path / "session"
    (root / "sub" / "deeper").mkdir(parents=True)
    shutil.copy(sample_data / "kinematics_tennis_serve_nan.c3d", root / "serve.c3d")
    shutil.copy(sample_data / "markers.csv", root / "vicon.csv")
    shutil.copy(test_data / "T.trc", root / "sub" / "T.trc")
    shutil.copy(test_data / "kinematics_racing_full.c3d", root / "sub" / "deeper" / "racing.c3d")
    (root / "sub" / "broken.c3d").write_bytes(b"this is not a C3D file\n" * 10)
    (root / "notes.txt").write_text("not a capture: ignored\n")
    return root


def _table(out_dir):
    with open(out_dir / RESULTS_NAME, newline="", encoding="utf-8") as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames) == COLUMNS
        return {os.path.relpath(row["input"], out_dir.parent / "session"): row for row in reader}


def test_mixed_folder_rows_exit_status_and_outputs(session, tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["batch", str(session), "--out-dir", str(out), "-m", "linear",
                                      "--report", "json"])
    assert result.exit_code == 1, result.output
    assert result.stdout == ""
    assert "broken.c3d" in result.stderr and "4 filled" in result.stderr and "Traceback" not in result.output

    rows = _table(out)
    assert set(rows) == set(GOOD) | {"sub/broken.c3d"}
    bad = rows["sub/broken.c3d"]
    assert bad["status"] == "failed" and "broken.c3d" in bad["error"] and "\n" not in bad["error"]
    assert bad["frames"] == "" and not (out / "sub" / "broken.c3d").exists()
    for rel, frames in GOOD.items():
        row = rows[rel]
        assert row["status"] == "filled" and row["error"] == "" and row["method"] == "linear"
        assert int(row["frames"]) == frames and float(row["seconds"]) >= 0
        source, filled = mocapfill.read(session / rel), mocapfill.read(out / rel)
        assert row["output"] == str(out / rel) and (out / f"{rel}.report.json").is_file()
        assert int(row["markers"]) == source.n_markers
        assert int(row["missing_samples"]) == int(source.missing.sum())
        never = np.isnan(source.positions).all(axis=0).any(axis=1)  # markers never observed stay empty
        assert int(row["filled_samples"]) == int(source.missing[:, ~never].sum())
        assert not filled.missing[:, ~never].any()
        seen = ~source.missing
        np.testing.assert_allclose(filled.positions[seen], source.positions[seen], rtol=1e-6, atol=1e-6)
    index = (out / INDEX_NAME).read_text()
    assert index.count("<tr>") == 1 + 5 and 'href="sub/T.trc.report.json"' in index and "failed" in index
    assert not list(out.rglob("*.tmp"))


def test_batch_report_says_how_the_output_format_stores_observed_samples(sample_data, tmp_path):
    """A TSV output rounds to 0.001 mm (converted from metres here): the report says so, not bit-identical."""
    import json

    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["batch", str(sample_data / "kinematics_tennis_serve_nan.c3d"), "--out-dir",
                                      str(out), "-m", "linear", "--format", "tsv", "--report", "json"])
    assert result.exit_code == 0, result.output
    (report,) = out.rglob("*.report.json")
    assert json.loads(report.read_text())["summary"]["observed_stored"] == \
        "converted from m to mm and rounded to the TSV's 0.001 mm"


def test_rerun_skips_changed_input_or_settings_redo_and_force_redoes(session, tmp_path):
    out = tmp_path / "out"
    first = mocapfill.batch(session, out, method="linear")
    assert [r.status for r in first].count("filled") == 4
    stamp = {rel: (out / rel).stat().st_mtime_ns for rel in GOOD}

    again = {os.path.relpath(r.input, session): r for r in mocapfill.batch(session, out, method="linear")}
    assert {rel: r.status for rel, r in again.items()} == {**dict.fromkeys(GOOD, "skipped"), "sub/broken.c3d": "failed"}
    assert again["serve.c3d"].frames == 1092 and again["serve.c3d"].filled_samples == 145
    assert {rel: (out / rel).stat().st_mtime_ns for rel in GOOD} == stamp
    assert sum(1 for _ in open(out / RESULTS_NAME)) == 1 + 5

    # New content in one input, another fill option: redone; --force: everything redone.
    data = mocapfill.read(session / "sub" / "T.trc")
    data.positions[5:9, 0] = np.nan
    mocapfill.write(data.with_positions(data.positions), session / "sub" / "T2.trc")
    os.replace(session / "sub" / "T2.trc", session / "sub" / "T.trc")
    changed = {os.path.relpath(r.input, session): r.status for r in mocapfill.batch(session, out, method="linear")}
    assert changed["sub/T.trc"] == "filled" and changed["serve.c3d"] == "skipped"
    other = {r.status for r in mocapfill.batch(session, out, method="linear", seed=3) if "broken" not in r.input}
    assert other == {"filled"}
    result = CliRunner().invoke(cli, ["batch", str(session), "-o", str(out), "-m", "linear", "--seed", "3",
                                      "--force", "-q"])
    # -q: nothing on stderr but the errors, the one failed file
    assert result.exit_code == 1 and result.stderr.splitlines() == [next(
        line for line in result.stderr.splitlines() if line.startswith(f"failed {session / 'sub' / 'broken.c3d'}: "))]
    assert {row["status"] for rel, row in _table(out).items() if rel != "sub/broken.c3d"} == {"filled"}
    assert len((out / STATE_NAME).read_text().splitlines()) == 4  # compacted: one line per output


def _outputs(out):
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.name not in (RESULTS_NAME, STATE_NAME)}


@pytest.mark.slow
def test_two_local_processes_give_the_serial_outputs(session, tmp_path):
    serial = mocapfill.batch(session, tmp_path / "serial", method="pca")
    parallel = mocapfill.batch(session, tmp_path / "jobs2", method="pca", jobs=2)
    assert [(r.status, r.filled_samples) for r in parallel] == [(r.status, r.filled_samples) for r in serial]
    assert len({r.worker for r in parallel}) == 2
    assert _outputs(tmp_path / "jobs2") == _outputs(tmp_path / "serial") and len(_outputs(tmp_path / "serial")) == 4


@pytest.mark.slow
def test_dask_local_cluster_gives_the_serial_outputs(session, tmp_path):
    distributed = pytest.importorskip("distributed")
    mocapfill.batch(session, tmp_path / "serial", method="pca", format="csv")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        result = CliRunner().invoke(cli, ["batch", str(session), "-o", str(tmp_path / "dask"), "-m", "pca",
                                          "--format", "csv", "--scheduler", cluster.scheduler_address, "-q"])
    assert result.exit_code == 1, result.output
    rows = _table(tmp_path / "dask")
    assert rows["sub/broken.c3d"]["status"] == "failed" and rows["serve.c3d"]["output"].endswith("serve.csv")
    assert _outputs(tmp_path / "dask") == _outputs(tmp_path / "serial")


@pytest.mark.slow
def test_an_unreachable_scheduler_is_a_one_line_error(session, tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr("mocapfill.runtime.executor.CONNECT_TIMEOUT", "1s")
    result = CliRunner().invoke(cli, ["batch", str(session), "-o", str(tmp_path / "o"), "--scheduler",
                                      "tcp://127.0.0.1:9", "-m", "linear"])
    assert result.exit_code == 1 and "Dask scheduler" in result.stderr and "Traceback" not in result.output


def test_quiet_batch_still_names_a_failed_file_and_warnings_reach_stderr(tmp_path, test_data):
    """-q prints nothing but errors: a failed file is one; a truncated TRC's read warning is printed (it said
    only "1 filled" while the file held 2 of its 89 frames)."""
    folder = tmp_path / "takes"
    folder.mkdir()
    (folder / "take.trc").write_bytes((test_data / "T.trc").read_bytes()[:3000])
    (folder / "empty.c3d").write_bytes(b"")
    quiet = CliRunner().invoke(cli, ["batch", str(folder), "-o", str(tmp_path / "q"), "-m", "linear", "-q"])
    assert quiet.exit_code == 1 and f"failed {folder / 'empty.c3d'}: not a C3D file" in quiet.stderr
    assert "warning" not in quiet.stderr
    loud = CliRunner().invoke(cli, ["batch", str(folder), "-o", str(tmp_path / "l"), "-m", "linear"])
    assert f"warning DataWarning: {folder / 'take.trc'}: header says 89 frames, the file holds 2" in loud.stderr


def test_an_input_that_now_fails_takes_its_earlier_output_with_it(tmp_path, test_data):
    """An output of content that no longer holds is not left beside a failed row (a collector would take it)."""
    folder, out = tmp_path / "takes", tmp_path / "out"
    folder.mkdir()
    good = (test_data / "MACsample.c3d").read_bytes()
    (folder / "a.c3d").write_bytes(good)
    assert [r.status for r in mocapfill.batch(folder, out, method="linear", report="json")] == ["filled"]
    (folder / "a.c3d").write_bytes(good[:5000])  # truncated since
    (row,) = mocapfill.batch(folder, out, method="linear", report="json")
    assert row.status == "failed" and not (out / "a.c3d").exists() and not (out / "a.c3d.report.json").exists()
    assert any("the earlier run's a.c3d, a.c3d.report.json removed" in w for w in row.warnings)
    assert (out / STATE_NAME).read_text() == ""


def test_a_killed_worker_fails_only_its_file(session, tmp_path):
    # A FIFO nobody writes to: the worker that opens it blocks until we kill it (as the OOM killer would).
    stuck = tmp_path / "stuck.c3d"
    os.mkfifo(stuck)
    inputs = [session / "serve.c3d", session / "vicon.csv", stuck]

    def kill_when_only_the_stuck_file_is_left(done, total, row):
        if done == total - 1:
            for child in multiprocessing.active_children():
                if child.name == WORKER_NAME:
                    os.kill(child.pid, signal.SIGKILL)

    rows = mocapfill.batch(inputs, tmp_path / "out", method="linear", jobs=2,
                           progress=kill_when_only_the_stuck_file_is_left)
    assert [r.status for r in rows] == ["filled", "filled", "failed"]
    assert "died" in rows[2].error and "SIGKILL" in rows[2].error and "stuck.c3d" in rows[2].error
    assert (tmp_path / "out" / "serve.c3d").is_file() and (tmp_path / "out" / "vicon.csv").is_file()


@pytest.mark.slow
def test_a_killed_dask_worker_fails_only_its_file(session, tmp_path):
    dask = pytest.importorskip("dask")
    distributed = pytest.importorskip("distributed")
    stuck = tmp_path / "stuck.c3d"
    os.mkfifo(stuck)
    # Dask retries a task whose worker died (allowed-failures, default 3); no retry keeps the test short.
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
            distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                     dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        def kill_when_only_the_stuck_file_is_left(done, total, row):
            if done == total - 1:
                for pid in client.run(os.getpid).values():
                    os.kill(pid, signal.SIGKILL)

        rows = mocapfill.batch([session / "serve.c3d", session / "vicon.csv", stuck], tmp_path / "out",
                               method="linear", scheduler=client, progress=kill_when_only_the_stuck_file_is_left)
    assert [r.status for r in rows] == ["filled", "filled", "failed"]
    assert "Dask worker died" in rows[2].error and "stuck.c3d" in rows[2].error


@pytest.mark.slow
def test_ctrl_c_keeps_finished_outputs_and_leaves_nothing_half_written(session, tmp_path):
    out = tmp_path / "out"

    def interrupt(done, total, row):
        if done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        mocapfill.batch(session, out, method="linear", jobs=2, progress=interrupt)
    rows = _table(out)
    assert len(rows) == 1
    assert not list(out.rglob("*.tmp")) and not list(out.rglob(".*.tmp"))
    for path in out.rglob("*"):
        if path.is_file() and path.name not in (RESULTS_NAME, STATE_NAME):
            mocapfill.read(path)  # every output present is complete
    resumed = mocapfill.batch(session, out, method="linear")
    assert [r.status for r in resumed].count("failed") == 1
    assert sum(r.status == "skipped" for r in resumed) >= 1


def test_globs_format_and_output_clashes(session, tmp_path):
    rows = mocapfill.batch(str(session / "**" / "*.trc"), tmp_path / "g", method="linear", format="csv")
    assert [os.path.relpath(r.output, tmp_path / "g") for r in rows] == ["sub/T.csv"]
    twin = tmp_path / "twin"
    twin.mkdir()
    shutil.copy(session / "serve.c3d", twin / "vicon.c3d")
    with pytest.raises(MocapfillError, match="would both be written"):
        mocapfill.batch([session / "vicon.csv", twin / "vicon.c3d"], tmp_path / "o", format="csv")
    with pytest.raises(MocapfillError, match="no file matches"):
        mocapfill.batch(str(session / "*.xyz"), tmp_path / "o")
    with pytest.raises(MocapfillError, match="unknown option"):
        mocapfill.batch(session, tmp_path / "o", hiden=3)


def test_output_folder_inside_the_input_folder_is_not_searched(session, tmp_path):
    out = session / "filled"
    first = mocapfill.batch(session, out, method="linear")
    again = mocapfill.batch(session, out, method="linear")
    assert len(first) == len(again) == 5


def test_a_per_file_report_or_status_that_cannot_be_written_fails_its_file_before_the_fill(tmp_path, test_data,
                                                                                          monkeypatch):
    import mocapfill.pipeline
    from mocapfill.errors import InputError

    src = tmp_path / "s"
    src.mkdir()
    shutil.copy(test_data / "T.trc", src / "T.trc")
    out = tmp_path / "o"
    (out / "T.trc.report.json").mkdir(parents=True)  # a folder where the report goes
    (out / "T.trc.status.csv").mkdir()
    filled = mocapfill.pipeline.fill_capture
    monkeypatch.setattr(mocapfill.pipeline, "fill_capture", lambda *a, **k: pytest.fail("the fill ran"))
    for options in ({"report": "json"}, {"status": True}):
        [row] = mocapfill.batch(src, out, method="linear", **options)
        assert row.status == "failed" and "is a directory, cannot write a file there" in row.error
        assert not (out / "T.trc").exists() and row.report == "" and row.status_csv == ""

    def refuse(outcome, path):  # a write that fails after the check: the output and report already written go
        raise InputError(f"{path}: cannot write: No space left on device")

    monkeypatch.setattr(mocapfill.pipeline, "fill_capture", filled)
    monkeypatch.setattr(mocapfill.pipeline, "write_status_csv", refuse)
    [row] = mocapfill.batch(src, tmp_path / "o2", method="linear", report="json", status=True)
    assert row.status == "failed" and "No space left on device" in row.error
    assert not (tmp_path / "o2" / "T.trc").exists() and not (tmp_path / "o2" / "T.trc.report.json").exists()


def test_a_search_skips_earlier_batch_outputs_and_their_bookkeeping(tmp_path, test_data, monkeypatch):
    from mocapfill.batching import find_inputs

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s1").mkdir()
    shutil.copy(test_data / "T.trc", tmp_path / "s1" / "T.trc")
    runner = CliRunner()
    first = runner.invoke(cli, ["batch", "s1", "-o", "s1/filled", "-m", "linear", "--status", "--report", "json"])
    assert first.exit_code == 0, first.output
    assert {"mocapfill-batch.csv", "T.trc", "T.trc.status.csv"} <= {p.name for p in (tmp_path / "s1/filled").iterdir()}
    again = runner.invoke(cli, ["batch", "s1", "-o", "o2", "-m", "linear"])
    assert again.exit_code == 0 and "1 filled, 0 skipped, 0 failed" in again.stderr, again.output
    assert [os.path.relpath(r["input"]) for r in csv.DictReader(open("o2/" + RESULTS_NAME))] == ["s1/T.trc"]

    found = lambda *items: [p.as_posix() for p, _ in find_inputs(items)]  # noqa: E731
    assert found("s1/**/*.trc") == found("s1/*") == found("s1/**") == ["s1/T.trc"]
    # Named explicitly, an earlier output folder is searched (its bookkeeping is not) and a file is kept.
    assert found("s1/filled") == found("s1/filled/*") == ["s1/filled/T.trc"]
    assert found("s1/filled/T.trc.status.csv") == ["s1/filled/T.trc.status.csv"]
    (tmp_path / "s1" / "walk.status.csv").write_text("frame,marker,status\n")  # no output beside it: a capture
    assert "s1/walk.status.csv" in found("s1")


def test_fill_options_are_shared_with_fill(session, tmp_path):
    runner = CliRunner()
    assert runner.invoke(cli, ["batch", str(session), "-o", str(tmp_path / "o"), "--delta", "0.2"]).exit_code == 2
    assert runner.invoke(cli, ["batch", str(session), "-o", str(tmp_path / "o"), "-j", "2", "--scheduler",
                               "tcp://127.0.0.1:9"]).exit_code == 2
    help_batch = runner.invoke(cli, ["batch", "--help"]).output
    help_fill = runner.invoke(cli, ["fill", "--help"]).output
    for flag in ("--method", "--hidden", "--max-iter", "--tol", "--seed", "--bones", "--reject-outliers",
                 "--delta", "--reference", "--smooth", "--smooth-window", "--smooth-order"):
        assert flag in help_batch and flag in help_fill


def test_tasks_are_ordered_by_samples_read_from_the_headers(session, tmp_path):
    from mocapfill.io.peek import TEXT_BYTES_PER_SAMPLE, peek

    def _samples_hint(path):
        return peek(path, scan=False).samples or 0

    for rel in ("serve.c3d", "sub/T.trc", "sub/deeper/racing.c3d"):
        data = mocapfill.read(session / rel)
        assert _samples_hint(str(session / rel)) == data.n_frames * data.n_markers, rel
    csv_path = session / "vicon.csv"
    assert _samples_hint(str(csv_path)) == csv_path.stat().st_size // TEXT_BYTES_PER_SAMPLE
    broken = session / "sub" / "broken.c3d"
    assert _samples_hint(str(broken)) == broken.stat().st_size // TEXT_BYTES_PER_SAMPLE
    assert _samples_hint(str(tmp_path / "absent.c3d")) == 0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc thresholds and per-thread rusage")
def test_rows_account_cpu_and_tasks_undo_a_fixed_malloc_threshold(session, tmp_path):
    import subprocess

    rows = mocapfill.batch(session, tmp_path / "o", method="linear")
    for row in rows:
        assert row.cpu_seconds is not None and 0 <= row.kernel_seconds <= row.cpu_seconds
        assert row.page_faults >= 0 and row.started > 0
    # A Dask nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536: every 1 MB temporary is then a fresh mmap
    # whose pages fault in one by one.  Inside roomy_malloc they come from the heap again.
    script = (
        "import resource, numpy as np\n"
        "from mocapfill.runtime.malloc import roomy_malloc\n"
        "def faults(fix):\n"
        "    import contextlib\n"
        "    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
        "    with (roomy_malloc() if fix else contextlib.nullcontext()):\n"
        "        for _ in range(200):\n"
        "            np.ones(1 << 17).sum()\n"
        "    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before\n"
        "print(faults(False), faults(True))\n")
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536", "PYTHONPATH": os.pathsep.join(sys.path)}
    env.pop("MOCAPFILL_KEEP_MALLOC", None)
    fixed, roomy = map(int, subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                                           check=True).stdout.split())
    assert fixed > 200 * 100 and roomy < fixed / 10, (fixed, roomy)
