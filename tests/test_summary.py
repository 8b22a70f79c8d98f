"""summarize / summarize_missing: per-marker gap statistics, blackouts, JSON-readiness."""

from __future__ import annotations

import json
import warnings

import numpy as np

import mocapfill
from mocapfill.errors import DataWarning
from mocapfill.markers import MarkerData
from mocapfill.summary import frame_ranges, summarize, summarize_missing


def _mask():
    # 10 frames, 4 markers: A complete; B gaps at start (0-1) and middle (5-7); C gap at end (8-9); D all missing.
    m = np.zeros((10, 4), dtype=bool)
    m[[0, 1, 5, 6, 7], 1] = True
    m[[8, 9], 2] = True
    m[:, 3] = True
    return m


def test_per_marker_statistics():
    s = summarize_missing(_mask(), rate=20.0, labels=["A", "B", "C", "D"], first_frame=101)
    a, b, c, d = s["markers"]
    assert (a["n_gaps"], a["longest_gap_frames"], a["percent_missing"]) == (0, 0, 0.0)
    assert (b["n_gaps"], b["longest_gap_frames"], b["longest_gap_seconds"]) == (2, 3, 0.15)
    assert b["gap_at_start"] and not b["gap_at_end"]
    assert b["gaps"] == [{"start": 0, "length": 2, "first_frame": 101, "last_frame": 102},
                         {"start": 5, "length": 3, "first_frame": 106, "last_frame": 108}]
    assert c["gap_at_end"] and not c["gap_at_start"] and c["percent_missing"] == 20.0
    assert d["missing_throughout"] and d["gap_at_start"] and d["gap_at_end"] and d["longest_gap_frames"] == 10
    assert s["markers_missing_throughout"] == ["D"]
    assert s["markers_complete"] == 1
    assert s["n_gaps"] == 4 and s["longest_gap_frames"] == 10 and s["longest_gap_seconds"] == 0.5
    assert s["n_missing"] == 5 + 2 + 10
    assert s["percent_missing"] == 100 * 17 / 40
    assert s["blackout_frames"] == 0 and s["blackouts"] == []


def test_blackouts_as_ranges():
    m = _mask()
    m[[0, 1, 5, 6], :] = True
    m[9, :] = True
    s = summarize_missing(m, rate=10.0, first_frame=1)
    assert s["blackout_frames"] == 5
    assert s["blackouts"] == [{"start": 0, "length": 2, "first_frame": 1, "last_frame": 2},
                              {"start": 5, "length": 2, "first_frame": 6, "last_frame": 7},
                              {"start": 9, "length": 1, "first_frame": 10, "last_frame": 10}]
    assert [m["label"] for m in s["markers"]] == ["M1", "M2", "M3", "M4"]


def test_frame_ranges_empty_and_unsorted():
    assert frame_ranges([]) == []
    assert frame_ranges([4, 2, 3], first_frame=0) == [{"start": 2, "length": 3, "first_frame": 2, "last_frame": 4}]


def test_empty_capture():
    s = summarize_missing(np.zeros((0, 3), dtype=bool), rate=100.0)
    assert s["n_frames"] == 0 and s["percent_missing"] == 0.0 and s["markers_missing_throughout"] == []
    s = summarize_missing(np.zeros((5, 0), dtype=bool), rate=100.0)
    assert s["n_markers"] == 0 and s["blackout_frames"] == 0


def test_summarize_real_file_is_json_ready(sample_data):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        data = mocapfill.read(sample_data / "markers_analogs.c3d")
    s = summarize(data)
    text = json.dumps(s, allow_nan=False)
    assert json.loads(text) == s
    assert s["format"] == "c3d" and s["units"] == "mm" and s["rate"] == 100.0
    assert s["duration_seconds"] == 5.8
    assert s["n_gaps"] == 34 and s["longest_gap_frames"] == 71 and s["longest_gap_seconds"] == 0.71
    assert round(s["percent_missing"], 2) == 1.03
    assert s["c3d"] == {"processor": "Intel", "storage": "float", "analog_channels": 38, "model_outputs": []}


def test_summarize_csv_data_has_no_c3d_section():
    data = MarkerData(np.full((4, 1, 3), np.nan), ["A"], 10.0)
    s = summarize(data)
    assert "c3d" not in s
    assert s["blackout_frames"] == 4 and s["markers_missing_throughout"] == ["A"]
