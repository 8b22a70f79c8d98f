"""Every capture under ../shared/data: read, or rejected with the project's own error; `info` correct on each.

Skips when ../shared/data is absent (the committed copies in sample_data/ and tests/data/ are tested elsewhere).
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import c3d
import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.errors import DataWarning, FormatError
from mocapfill.gaps import find_gaps
from mocapfill.markers import KNOWN_UNITS

pytestmark = pytest.mark.shared

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
# Tables that are not captures (the BoLeRO authors' scores) are not read.
NOT_CAPTURES = {"bolero/authors-code-results.csv"}
FILES = sorted(str(p.relative_to(SHARED)) for p in SHARED.rglob("*")
               if p.is_file() and p.suffix.lower() in (".c3d", ".csv", ".trc")
               and str(p.relative_to(SHARED)) not in NOT_CAPTURES) if SHARED.is_dir() else []
# Files that carry no frame rate, and the rate their README gives.
RATES = {"bolero/127_07.csv": 120.0, "bolero/132_32.csv": 120.0}
C3D_FILES = [f for f in FILES if f.lower().endswith(".c3d")]

# Files we reject on purpose, with the reason our error gives.
REJECTED: dict[str, str] = {}  # BTK's Gait.trc (rows of 102 ... 318 fields) is read: 33 markers + 72 unnamed

# The data README's table: (frames, rate, markers, percent missing or None, longest gap or None).
FACTS = {
    "cmu/85_02.c3d": (810, 120, 41, 0.0, 0),
    "kineticstoolkit/kinematics_tennis_serve.c3d": (1092, 50, 39, 0.0, 0),
    "kineticstoolkit/kinematics_tennis_serve_nan.c3d": (1092, 50, 39, 0.34, 42),
    "btk/TRCSamples/SprintMotion.trc": (788, 250, 59, 0.0, 0),
    "pyomeca/markers_analogs.c3d": (580, 100, 51, 1.0, 71),
    "pyomeca/markers.csv": (580, 100, 51, 1.0, 71),
    "pyomeca/markers.trc": (93, 100, 51, None, None),
    "pyorerun/Running_0002.c3d": (80, 200, 64, 0.0, 0),
    "pyorerun/example.c3d": (800, 100, 33, 0.0, 0),
    "pycgm/Movement_trial.c3d": (323, 120, 159, 2.0, None),
    "btk/C3DSamples/others/ADemo1_rewrite_c3d_pc_float.c3d": (512, 200, 24, 0.7, 29),
    "kineticstoolkit/kinematics_basket_sprint.c3d": (3678, 120, 26, 39.0, 1760),
    "kineticstoolkit/walkingOptiTrack.c3d": (3361, 160, 12, 7.4, 1007),
    "kineticstoolkit/c3d_sample.c3d": (675, 100, 22, 52.0, None),
    "kineticstoolkit/duplicate_labels.c3d": (1050, 100, 48, 74.0, None),
    "kineticstoolkit/many_analogs.c3d": (710, 100, 32, 0.0, 0),
    "kineticstoolkit/kinematics_racing_full.c3d": (700, 70, 46, 20.0, None),
}


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        return mocapfill.read(path, rate=RATES.get(str(Path(path).relative_to(SHARED))))


@pytest.mark.parametrize("rel", FILES)
def test_read_or_rejected_and_info_agrees(shared_data, rel):
    path = shared_data / rel
    try:
        data = _read(path)
    except FormatError as exc:
        assert rel in REJECTED, f"{rel} rejected: {exc}"
        assert str(exc).startswith(f"{path}: ") and REJECTED[rel] in str(exc)
        result = CliRunner().invoke(cli, ["info", str(path)])
        assert result.exit_code == 1 and result.stderr.startswith(f"Error: {path}: ")
        return
    assert rel not in REJECTED, f"{rel} was expected to be rejected"
    assert data.positions.shape == (data.n_frames, data.n_markers, 3)
    assert data.rate > 0 and data.units in KNOWN_UNITS
    assert len(set(data.labels)) == data.n_markers
    assert not np.isinf(data.positions).any()
    # Missing samples are NaN in all three coordinates together.
    assert np.array_equal(np.isnan(data.positions).any(axis=2), np.isnan(data.positions).all(axis=2))

    rate = ["--rate", str(RATES[rel])] if rel in RATES else []
    result = CliRunner().invoke(cli, ["info", "--json", str(path), *rate])
    assert result.exit_code == 0, result.output
    s = json.loads(result.stdout)
    columns = [k for k, kind in enumerate(data.kinds) if kind == "marker"]  # info counts the markers only
    missing = data.missing[:, columns]
    labels = [data.labels[k] for k in columns]
    gaps = find_gaps(missing)
    assert (s["n_frames"], s["n_markers"], s["rate"], s["units"]) == (data.n_frames, len(columns), data.rate,
                                                                     data.units)
    assert s["model_points"] + s["unlabelled"] == [lab for lab, kind in zip(data.labels, data.kinds)
                                                   if kind == "model"] + [lab for lab, kind in
                                                                          zip(data.labels, data.kinds)
                                                                          if kind == "unlabelled"]
    assert s["n_missing"] == int(missing.sum()) and s["n_gaps"] == len(gaps)
    assert s["longest_gap_frames"] == max((g.length for g in gaps), default=0)
    assert s["blackout_frames"] == int(missing.all(axis=1).sum()) if columns else True
    assert [m["label"] for m in s["markers"]] == labels
    assert s["markers_missing_throughout"] == [labels[k] for k in np.flatnonzero(missing.all(axis=0))] \
        if data.n_frames else True
    table = CliRunner().invoke(cli, ["info", str(path), *rate])
    assert table.exit_code == 0 and "markers" in table.stderr


@pytest.mark.parametrize("rel", sorted(FACTS))
def test_readme_facts(shared_data, rel):
    frames, rate, markers, percent, longest = FACTS[rel]
    data = _read(shared_data / rel)
    assert data.n_frames == frames and round(data.rate) == rate and data.n_markers == markers
    if percent is not None:
        assert abs(100 * data.missing.mean() - percent) < 0.6 + 0.02 * percent
    if longest is not None:
        assert max((g.length for g in find_gaps(data.missing)), default=0) == longest


def test_model_outputs_are_not_markers(shared_data, tmp_path):
    data = _read(shared_data / "pycgm/Movement_trial.c3d")
    assert data.n_markers == 159 and len(data.extra.model_outputs) == 80
    assert not set(data.extra.model_outputs) & set(data.labels)
    assert any(label.endswith("Angles") for label in data.extra.model_outputs)
    # A fill leaves the model outputs' bytes untouched (the whole point block of those points).
    pos = data.positions.copy()
    pos[data.missing] = 1.0
    mocapfill.write(data.with_positions(pos), tmp_path / "m.c3d")
    f = data.extra.file
    old = np.frombuffer(f.raw, np.uint8, f.n_frames * f.frame_bytes, f.data_offset).reshape(f.n_frames, -1)
    new_raw = (tmp_path / "m.c3d").read_bytes()
    new = np.frombuffer(new_raw, np.uint8, f.n_frames * f.frame_bytes, f.data_offset).reshape(f.n_frames, -1)
    outputs = np.setdiff1d(np.arange(f.n_points), data.extra.marker_points)
    cols = (outputs[:, None] * 16 + np.arange(16)).ravel()
    assert np.array_equal(old[:, cols], new[:, cols])


@pytest.mark.parametrize("rel", C3D_FILES)
def test_c3d_unchanged_rewrite_is_identical_and_matches_the_c3d_package(shared_data, rel):
    path = shared_data / rel
    data = _read(path)
    raw = path.read_bytes()
    assert mocapfill.io.c3d.c3d_bytes(data) == raw
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader = c3d.Reader(io.BytesIO(raw))
            points = np.array([p for _, p, _ in reader.read_frames()])
    except Exception:
        return  # the package rejects this file; we read it (the point of our own parser)
    pts = points[:, data.extra.marker_points]
    ref = pts[:, :, :3].astype(np.float64)
    valid = ~data.missing
    tol = 0.0 if data.extra.file.is_float else 1e-3 * abs(data.extra.file.scale) * 100
    np.testing.assert_allclose(data.positions[valid], ref[valid], rtol=1e-6 if tol else 0, atol=tol)
