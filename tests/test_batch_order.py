"""`mocapfill batch`'s task order: longest expected fill first, from a bounded scan of the missing samples
(``mocapfill.batching.order.longest_first`` on ``mocapfill.io.peek.peek``).  The order only schedules; outputs are covered by tests/test_batch.py."""

from __future__ import annotations

import os
import sys
import types

import numpy as np
import pytest

import mocapfill
from mocapfill.batching import order
from mocapfill.io.peek import peek


def _longest_first(tasks):
    return order.longest_first(tasks, [t.input for t in tasks])


def _samples_hint(path) -> int:
    return peek(path, scan=False).samples or 0


def _scan_missing(path):
    found = peek(path)
    return None if found.missing is None else (found.missing, found.samples)


def _task(path) -> types.SimpleNamespace:
    return types.SimpleNamespace(input=str(path))


def _gapped(data, n_frames: int, fraction: float, seed: int) -> mocapfill.MarkerData:
    """The first ``n_frames`` of ``data`` with about ``fraction`` of its samples missing (seeded), as a new capture."""
    positions = data.positions[:n_frames].copy()
    drop = np.random.default_rng(seed).random(positions.shape[:2]) < fraction
    positions[drop] = np.nan
    return mocapfill.MarkerData(positions, list(data.labels), data.rate, data.units)


@pytest.fixture()
def two_captures(tmp_path, sample_data):
    """A small capture with half its samples missing, and a larger one (all frames) barely gapped."""
    data = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")
    small, large = _gapped(data, 300, 0.5, 0), _gapped(data, data.n_frames, 0.01, 1)
    return small, large


def test_a_heavily_gapped_small_c3d_goes_before_a_barely_gapped_larger_one(two_captures, tmp_path):
    small, large = two_captures
    mocapfill.write(small, tmp_path / "small.c3d")
    mocapfill.write(large, tmp_path / "large.c3d")
    tasks = [_task(tmp_path / "large.c3d"), _task(tmp_path / "small.c3d")]
    # The header alone (frames x markers) puts the larger file first ...
    assert _samples_hint(tasks[0].input) > _samples_hint(tasks[1].input)
    # ... the scan of its residual words counts what the reader reads as missing (every frame of the small file,
    # every other frame of the large one: more than SCAN_FRAMES).
    for data, name, tolerance in ((small, "small.c3d", 1e-12), (large, "large.c3d", 0.003)):
        fraction, samples = _scan_missing(str(tmp_path / name))
        assert samples == data.n_frames * data.n_markers
        assert fraction == pytest.approx(mocapfill.read(tmp_path / name).missing.mean(), abs=tolerance)
    assert [t.input for t in _longest_first(tasks)] == [tasks[1].input, tasks[0].input]


@pytest.mark.parametrize("ext", ["trc", "csv", "tsv"])
def test_text_captures_get_a_missing_fraction(two_captures, tmp_path, ext):
    small, large = two_captures
    mocapfill.write(small, tmp_path / f"small.{ext}")
    mocapfill.write(large, tmp_path / f"large.{ext}")
    fraction, samples = _scan_missing(str(tmp_path / f"small.{ext}"))
    assert samples > 0 and fraction == pytest.approx(small.missing.mean(), abs=0.05)
    tasks = [_task(tmp_path / f"large.{ext}"), _task(tmp_path / f"small.{ext}")]
    assert [t.input for t in _longest_first(tasks)] == [tasks[1].input, tasks[0].input]


def test_the_scan_never_raises_and_never_blocks(tmp_path, sample_data):
    raw = (sample_data / "kinematics_tennis_serve_nan.c3d").read_bytes()
    bad = {"empty.c3d": b"", "header-only.c3d": raw[:512], "cut.c3d": raw[: len(raw) // 2],
           "garbage.c3d": b"\x02\x50" + bytes(range(256)) * 8, "noise.trc": os.urandom(3000),
           "binary.csv": b"\x00\xff" * 5000}
    for name, content in bad.items():
        (tmp_path / name).write_bytes(content)
    paths = [tmp_path / name for name in bad] + [tmp_path / "absent.c3d", tmp_path]
    if sys.platform != "win32":
        os.mkfifo(tmp_path / "pipe.c3d")  # opening it would wait for a writer
        paths.append(tmp_path / "pipe.c3d")
    for path in paths:
        scan = _scan_missing(str(path))
        assert scan is None or (0.0 <= scan[0] <= 1.0 and scan[1] >= 0), path
    assert _scan_missing(str(tmp_path / "cut.c3d")) is None  # truncated: the reader rejects it too
    ordered = _longest_first([_task(p) for p in paths])
    assert sorted(t.input for t in ordered) == sorted(str(p) for p in paths)


def test_past_the_time_box_files_are_costed_from_their_headers(two_captures, tmp_path, monkeypatch):
    small, large = two_captures
    mocapfill.write(small, tmp_path / "small.c3d")
    mocapfill.write(large, tmp_path / "large.c3d")
    monkeypatch.setattr(order, "SCAN_SECONDS", 0.0)

    def header_only(path, *, scan=True):
        assert not scan, "scanned past the time box"
        return peek(path, scan=False)

    monkeypatch.setattr(order, "peek", header_only)
    tasks = [_task(tmp_path / "small.c3d"), _task(tmp_path / "large.c3d")]
    assert [t.input for t in _longest_first(tasks)] == [tasks[1].input, tasks[0].input]
