"""The learned denoiser (issue 26, after Holden 2018): training in seconds, the model file, fill, --denoise."""

from __future__ import annotations

import builtins
import json

import numpy as np
import pytest
from click.testing import CliRunner

import mocapfill
from mocapfill.cli import cli
from mocapfill.engines.denoiser import (ModelError, body_frames, corrupt, kabsch, load_model, predict_frames,
                                        save_model, to_local, to_world, untrained_model)
from mocapfill.errors import MocapfillError


@pytest.fixture(scope="module")
def cmu(sample_data):
    return mocapfill.read(sample_data / "85_02.c3d")


@pytest.fixture(scope="module")
def tiny(cmu, tmp_path_factory):
    """A tiny model trained on the CMU take (its last 10 % held out; about 10 s on one core).  Tests check the
    mechanics in-sample; how a model generalises to other takes is benchmarks/bench_learned.py's question."""
    pytest.importorskip("jax")
    pytest.importorskip("optax")
    from mocapfill.engines.denoiser_training import train

    labels = [x.split(":")[-1] for x in cmu.labels]
    model = train([cmu.positions], labels, "mm", steps=400, hidden=128, blocks=1, batch=128, seed=0,
                  learning_rate=3e-3)
    path = tmp_path_factory.mktemp("model") / "cmu.model"
    save_model(model, path)
    return model, path


def test_kabsch_body_frame_round_trip(cmu):
    model = untrained_model(cmu.n_markers)
    model.frame_markers = np.arange(6)
    model.template = cmu.positions[0, :6] - cmu.positions[0, :6].mean(axis=0)
    R, c = body_frames(cmu.positions[:50], model)
    assert np.allclose(np.einsum("tij,tkj->tik", R, R), np.eye(3), atol=1e-9)
    local = to_local(cmu.positions[:50], R, c)
    np.testing.assert_allclose(to_world(local, R, c), cmu.positions[:50], atol=1e-9)
    np.testing.assert_allclose(local[0, :6], model.template, atol=1e-6)  # frame 0 lands on its own shape
    R2, c2 = kabsch(cmu.positions[:5, :6], model.template, np.ones((5, 6)))
    assert np.allclose(R2, R[:5]) and np.allclose(c2, c[:5])


def test_corruption_follows_holden(cmu):
    rng = np.random.default_rng(0)
    clean = cmu.positions[:400]
    bad = corrupt(clean, rng, sigma_o=0.1, sigma_s=0.1, shift=500.0, noise=0.0, swap=0.0)
    occluded = np.isnan(bad).any(axis=2)
    assert 0.02 < occluded.mean() < 0.2  # E|N(0, 0.1)| = 0.08, capped at 0.2
    moved = np.linalg.norm(np.nan_to_num(bad - clean), axis=2) > 1.0
    assert 0.02 < moved.mean() < 0.2 and np.nanmax(np.abs(bad - clean)) <= 500.0


@pytest.mark.slow
def test_training_is_quick_and_the_model_file_records_everything(tiny, cmu):
    model, path = tiny
    back = load_model(path)
    assert back.labels == model.labels and back.units == "mm" and len(back.labels) == cmu.n_markers
    s = back.settings
    assert s["steps"] == 400 and s["hidden"] == 128 and s["corruption"]["shift_mm"] == 500.0
    assert s["frames"] == 729 and s["loss_curve"][-1][1] < s["loss_curve"][0][1]  # it learnt something
    x = cmu.positions[700:720]
    np.testing.assert_allclose(predict_frames(x, back), predict_frames(x, model), atol=1e-3)


@pytest.mark.slow
def test_learned_fill_keeps_observed_samples_and_beats_the_mean_pose(tiny, cmu):
    model, path = tiny
    gappy = cmu.positions.copy()
    gappy[650:680, 30] = np.nan
    data = cmu.with_positions(gappy)
    result = mocapfill.fill(data, "learned", model=str(path))
    observed = ~np.isnan(gappy).any(axis=2)
    assert np.array_equal(result.positions[observed], gappy[observed])
    assert result.filled[650:680, 30].all()
    error = np.linalg.norm(result.positions[650:680, 30] - cmu.positions[650:680, 30], axis=1)
    assert np.sqrt(np.mean(error ** 2)) < 150.0  # a tiny model, but the gap's ends pin it


@pytest.mark.slow
def test_denoise_marks_a_displaced_marker_repaired(tiny, cmu, tmp_path):
    model, path = tiny
    shifted = cmu.positions.copy()
    shifted[300:320, 12] += np.array([400.0, -300.0, 250.0])
    src = tmp_path / "shifted.c3d"
    mocapfill.write(cmu.with_positions(shifted), src)
    report = tmp_path / "r.json"
    result = CliRunner().invoke(cli, ["fill", str(src), str(tmp_path / "o.c3d"), "-m", "learned", "--model",
                                      str(path), "--denoise", "--report", str(report)])
    assert result.exit_code == 0, result.output
    assert "displaced samples repaired by the denoiser" in result.stderr
    doc = json.loads(report.read_text())["summary"]["settings"]["denoise"]
    hit = {(s["marker"], s["frame"] - cmu.first_frame) for s in doc["samples"]}
    assert len(hit & {(cmu.labels[12], f) for f in range(300, 320)}) >= 15
    out = mocapfill.read(tmp_path / "o.c3d")
    assert np.linalg.norm(out.positions[300:320, 12] - cmu.positions[300:320, 12], axis=1).max() < 300.0


@pytest.mark.slow
def test_a_marker_placed_differently_is_not_displaced(tiny, cmu):
    """A marker that sits off the network's estimate all take long (another body, another placement) is judged
    against its typical error on this capture, not its training error; a displaced stretch still stands out."""
    from mocapfill.guards.denoise import find_displaced

    model, _ = tiny
    labels = [x.split(":")[-1] for x in cmu.labels]
    moved = cmu.positions.copy()
    moved[:, 20] += np.array([250.0, 0.0, 0.0])  # placed 25 cm off, in every frame
    moved[300:320, 12] += np.array([400.0, -300.0, 250.0])
    found = find_displaced(moved, model, labels=labels, units=cmu.units, rate=cmu.rate)
    assert found[:, 20].sum() <= 0.01 * cmu.n_frames
    assert found[300:320, 12].sum() >= 15
    assert found[:, 12].sum() - found[300:320, 12].sum() <= 0.01 * cmu.n_frames


@pytest.mark.slow
def test_train_command(cmu, tmp_path, sample_data):
    pytest.importorskip("jax")
    out = tmp_path / "layout.model"
    result = CliRunner().invoke(cli, ["train", str(sample_data / "85_02.c3d"), "-o", str(out), "--steps", "20",
                                      "--hidden", "16", "--blocks", "0", "--batch", "32"])
    assert result.exit_code == 0, result.output
    assert "trained on 729 frames of 1 take(s), 41 markers" in result.stderr
    assert load_model(out).settings["takes"] == [str(sample_data / "85_02.c3d")]


def test_train_on_a_capture_with_nothing_observed_names_it(cmu, tmp_path, sample_data):
    """Every sample missing: one line naming the take (it was a zero-size reduction in the body frame)."""
    pytest.importorskip("jax")
    empty = tmp_path / "empty.csv"
    mocapfill.write(cmu.with_positions(np.full_like(cmu.positions, np.nan)), empty)
    result = CliRunner().invoke(cli, ["train", str(empty), "-o", str(tmp_path / "t.model")])
    assert result.exit_code == 1
    assert result.stderr.strip().splitlines() == [f"Error: {empty}: nothing observed to train on (every sample of "
                                                  "the layout's markers is missing)"]
    # two takes observing different markers share nothing to train on
    first, second = cmu.positions.copy(), cmu.positions.copy()
    first[:, 20:], second[:, :20] = np.nan, np.nan
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    mocapfill.write(cmu.with_positions(first), a)
    mocapfill.write(cmu.with_positions(second), b)
    result = CliRunner().invoke(cli, ["train", str(a), str(b), "-o", str(tmp_path / "t.model")])
    assert result.exit_code == 1 and "no marker is observed in every take" in result.stderr
    assert "Traceback" not in result.output and not (tmp_path / "t.model").exists()


def test_without_the_extra_train_says_which(monkeypatch, sample_data, tmp_path):
    real_import = builtins.__import__

    def no_jax(name, *args, **kwargs):
        if name == "jax" or name.startswith("jax."):
            raise ImportError("No module named 'jax'", name="jax")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_jax)
    result = CliRunner().invoke(cli, ["train", str(sample_data / "85_02.c3d"), "-o", str(tmp_path / "m.model")])
    assert result.exit_code == 1
    assert result.stderr.strip().splitlines() == [
        "Error: training a denoiser needs the learn extra (JAX, optax): pip install 'mocapfill[learn]' "
        "(jax is not installed)"]


def test_bad_model_files_and_missing_model(tmp_path, cmu):
    bad = tmp_path / "x.model"
    bad.write_bytes(b"not a model")
    with pytest.raises(ModelError, match=r"x\.model: not a readable mocapfill model"):
        load_model(bad)
    with pytest.raises(MocapfillError, match="needs a model"):
        mocapfill.fill(cmu, "learned")
    other = untrained_model(5, labels=["A", "B", "C", "D", "E"])
    with pytest.raises(ModelError, match="trained on another layout"):
        mocapfill.fill(cmu, "learned", model=other)
    result = CliRunner().invoke(cli, ["fill", str(bad), str(tmp_path / "o.c3d"), "--denoise"])
    assert result.exit_code == 2 and "--denoise needs --model" in result.output
    # a model the method would ignore is an error, not a silent no-op (with --denoise any method may follow it)
    result = CliRunner().invoke(cli, ["fill", str(bad), str(tmp_path / "o.c3d"), "-m", "pca", "--model", str(bad)])
    assert result.exit_code == 2 and "--model is used by --denoise and by the methods auto, learned, not pca" in \
        result.output
    assert not (tmp_path / "o.c3d").exists()


def test_truncated_and_empty_model_files_are_one_line_errors(tmp_path, sample_data):
    """A damaged model file fails in zipfile, zlib or NumPy's parser, anywhere: one line naming it (fill and batch),
    never a traceback or click's bare "Aborted!" (an empty file's EOFError)."""
    whole = tmp_path / "whole.model"
    save_model(untrained_model(41), whole)
    cut, empty, other = tmp_path / "t100.model", tmp_path / "empty.model", tmp_path / "other.model"
    cut.write_bytes(whole.read_bytes()[:100])
    empty.write_bytes(b"")
    model = untrained_model(41)
    model.layers[0] = (model.layers[0][0][:-1], model.layers[0][1])  # unpacks, but the network does not chain
    save_model(model, other)
    for bad, why in ((cut, "BadZipFile"), (empty, "the file is empty"), (other, "layer 0 has shapes")):
        with pytest.raises(ModelError, match=f"{bad.name}: not a readable mocapfill model .*{why}"):
            load_model(bad)
    src = sample_data / "85_02.c3d"
    for bad in (cut, empty):
        result = CliRunner().invoke(cli, ["fill", str(src), str(tmp_path / "o.c3d"), "-m", "learned", "--model",
                                          str(bad)])
        assert result.exit_code == 1
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"Error: {bad}: not a readable mocapfill model (")
    result = CliRunner().invoke(cli, ["batch", str(src), "-o", str(tmp_path / "out"), "-m", "learned", "--model",
                                      str(cut)])
    assert result.exit_code == 1
    assert f"failed {cut}: not a readable mocapfill model (BadZipFile" in " ".join(result.stderr.split())
    assert "Traceback" not in result.output


@pytest.mark.slow
def test_the_model_is_a_prior_of_the_default(tiny, cmu, tmp_path):
    """``fill --model M`` with the candidate default: the network's estimate joins the spatial model (its sd learnt
    from hiding observed samples with a gap frame's missing markers), the observed samples come back bit-identical and the report says so."""
    from mocapfill.methods.auto import prior_estimate
    from mocapfill.methods.auto_config import DEFAULT_CONFIG

    model, path = tiny
    gappy = cmu.positions.copy()
    gappy[650:680, 30] = np.nan
    gappy[:, 5] = np.nan  # never observed: no prior either
    labels = list(cmu.labels)
    est, sd = prior_estimate(gappy, model, labels=labels, units="mm", rate=cmu.rate, config=DEFAULT_CONFIG)
    assert est.shape == gappy.shape and sd.shape == (cmu.n_markers,)
    assert sd[30] > 0 and np.isnan(np.delete(sd, 30)).all()  # only a marker with gaps (never observed: none)
    src = tmp_path / "gappy.c3d"
    mocapfill.write(cmu.with_positions(gappy), src)
    report = tmp_path / "r.json"
    result = CliRunner().invoke(cli, ["fill", str(src), str(tmp_path / "o.c3d"), "--model",
                                      str(path), "--report", str(report)])
    assert result.exit_code == 0, result.output
    settings = json.loads(report.read_text())["summary"]["settings"]
    assert settings["model"] == str(path) and settings["model_prior"]["markers"] == 1
    out = mocapfill.read(tmp_path / "o.c3d")
    observed = ~np.isnan(gappy).any(axis=2)
    assert np.array_equal(out.positions[observed], gappy[observed])
    assert np.isfinite(out.positions[650:680, 30]).all()
