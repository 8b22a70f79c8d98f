"""The ``dense`` and ``segment`` occlusion protocols (messy captures)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.errors import MocapfillError
from mocapfill.evaluation.occlusions import make_occlusions


@pytest.fixture(scope="module")
def cmu(sample_data):
    return mocapfill.read(sample_data / "85_02.c3d")


@pytest.mark.parametrize("missing", [0.05, 0.1, 0.2, 0.3])
def test_dense_hides_the_asked_fraction_in_single_marker_interior_gaps(cmu, missing):
    trials = make_occlusions(cmu, "dense", trials=3, seed=4, missing=missing)
    n_frames, n_markers = cmu.positions.shape[:2]
    lo, hi = round(0.25 * cmu.rate), round(2 * cmu.rate)
    for trial in trials:
        hidden = trial.hidden_mask(n_frames, n_markers)
        assert abs(hidden.mean() - missing) < 0.002
        for occ in trial.occlusions:
            assert len(occ.markers) == 1 and occ.start >= 1 and occ.stop <= n_frames - 1
            assert occ.length <= hi
        assert sum(occ.length >= lo for occ in trial.occlusions) >= len(trial.occlusions) - 1  # only the last trimmed
    if missing >= 0.2:  # the point of the protocol: (almost) no frame stays complete
        assert hidden.any(axis=1).mean() > 0.95


def test_dense_is_deterministic_and_checks_its_fraction(cmu):
    a = make_occlusions(cmu, "dense", trials=2, seed=1)
    assert a == make_occlusions(cmu, "dense", trials=2, seed=1)
    with pytest.raises(MocapfillError, match="--missing"):
        make_occlusions(cmu, "dense", trials=1, seed=1, missing=0.95)


def test_segment_hides_neighbourhoods_by_median_distance(cmu):
    trials = make_occlusions(cmu, "segment", trials=4, seed=2, events=3)
    pos = cmu.positions
    for trial in trials:
        assert len(trial.occlusions) == 3
        for occ in trial.occlusions:
            assert 0.5 * cmu.rate - 1 <= occ.length <= 3 * cmu.rate + 1
            members = list(occ.markers)
            assert len(members) >= 1
            # every member is within 250 mm (median) of at least one other member or alone
            if len(members) > 1:
                d = np.nanmedian(np.linalg.norm(pos[:, members, None] - pos[:, None, members], axis=-1), axis=0)
                assert (np.sort(d, axis=1)[:, 1] <= 250 + 1e-9).all()


def test_segment_radius_is_unit_aware(sample_data):
    tennis = mocapfill.read(sample_data / "kinematics_tennis_serve.c3d")  # metres
    default = make_occlusions(tennis, "segment", trials=3, seed=5)
    explicit = make_occlusions(tennis, "segment", trials=3, seed=5, radius=0.25)
    assert default == explicit
    assert max(len(o.markers) for t in default for o in t.occlusions) > 1


def test_cli_dense_and_segment(sample_data):
    path = str(sample_data / "85_02.c3d")
    for args in (["-p", "dense", "--missing", "0.1"], ["-p", "segment", "--radius", "0.25m", "--events", "2"]):
        result = CliRunner().invoke(cli, ["evaluate", path, "-m", "linear", "-n", "1", "-s", "1", "--json", "-q",
                                          *args])
        assert result.exit_code == 0, result.output
        assert '"rmse"' in result.stdout
    bad = CliRunner().invoke(cli, ["evaluate", path, "-m", "linear", "-p", "segment", "--radius", "far"])
    assert bad.exit_code == 1 and "--radius" in bad.stderr


@pytest.mark.parametrize("protocol, options", [("dense", {"missing": 0.1}), ("segment", {"events": 2})])
def test_dense_and_segment_replay_from_a_saved_spec(cmu, tmp_path, protocol, options):
    from mocapfill.evaluation import evaluate

    spec = tmp_path / f"{protocol}.json"
    first = evaluate(cmu, ["linear"], protocol, trials=2, seed=3, save_occlusions=spec, **options)
    again = evaluate(cmu, ["linear"], occlusions=spec, seed=3)
    assert again.trials == first.trials
    np.testing.assert_array_equal(again.values("rmse"), first.values("rmse"))
    import json

    source = json.loads(spec.read_text())["source"]
    assert source["protocol"] == protocol and all(source[k] == v for k, v in options.items())
    # the --json output of a run replays too
    replay_json = evaluate(cmu, ["linear"], occlusions=first.to_dict(), seed=3)
    assert replay_json.trials == first.trials
