"""The 3-D player of the HTML reports: its compact data, the vertical axis, and (in a real headless Chromium, skipped
when none is installed) that it draws and that its slider moves the frame."""

from __future__ import annotations

import base64
import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mocapfill.cli import cli
from mocapfill.io import read
from mocapfill.markers import MarkerData
from mocapfill.pipeline import FillSettings, fill_capture, write_fill_report
from mocapfill.report.player import MAX_SAMPLES, player_payload, up_axis

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kinematics_tennis_serve_nan.c3d"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _payload_of(page: str) -> dict:
    match = re.search(r'<script type="application/json" class="player-data">(.*?)</script>', page, re.S)
    assert match, "no player data in the page"
    return json.loads(match.group(1))


def _decode(payload: dict) -> tuple[np.ndarray, np.ndarray]:
    n, m = payload["n_shown"], len(payload["labels"])
    q = np.frombuffer(base64.b64decode(payload["positions"]), dtype="<i2").reshape(n, m, 3).astype(float)
    status = np.frombuffer(base64.b64decode(payload["status"]), dtype=np.uint8).reshape(n, m)
    pos = np.asarray(payload["origin"]) + (q + 32767) * payload["scale"]
    pos[q[..., 0] == -32768] = np.nan
    return pos, status


def _capture(n_frames=200, n_markers=5, seed=0, up=2) -> MarkerData:
    rng = np.random.default_rng(seed)
    pos = rng.normal(0, 100, (n_frames, n_markers, 3))
    pos[..., up] = np.abs(pos[..., up]) + np.linspace(0, 1700, n_markers)  # a body standing on a floor at zero
    return MarkerData(pos, [f"M{i}" for i in range(n_markers)], 100.0, "mm")


def test_positions_round_trip_within_the_quantisation_step_and_missing_stays_missing():
    data = _capture()
    data.positions[10:20, 1] = np.nan
    filled = np.zeros((200, 5), bool)
    filled[30:40, 2] = True
    std = np.zeros((200, 5))
    std[30:40, 2] = np.linspace(1, 10, 10)
    payload = player_payload(data, filled=filled, std=std)
    pos, status = _decode(payload)
    assert payload["stride"] == 1
    ok = np.isfinite(data.positions)
    assert np.array_equal(np.isfinite(pos), ok)
    assert np.abs(pos[ok] - data.positions[ok]).max() <= payload["scale"] / 2 + 1e-9
    assert (status[10:20, 1] == 1).all() and (status[30:40, 2] >= 3).all() and (status[:10] == 0).all()
    # the uncertainty comes back on its square-root scale, to within a level
    code = status[30:40, 2].astype(float)
    back = payload["std_max"] * ((code - 3) / payload["std_levels"]) ** 2
    assert np.allclose(back, std[30:40, 2], atol=2 * 10 / payload["std_levels"] * 10 ** 0.5)


def test_long_takes_are_decimated_under_the_sample_cap_and_say_so():
    data = _capture(n_frames=3000, n_markers=10)
    payload = player_payload(data, max_samples=5000)
    assert payload["stride"] == 6 and payload["n_shown"] * 10 <= 5000
    from mocapfill.report.player import player_section

    assert "every 6th frame is shown" in player_section(payload)
    assert MAX_SAMPLES * 7 * 4 / 3 < 6e6  # the embedded arrays of a capped take leave room in 8 MB


@pytest.mark.parametrize("up", [1, 2])
def test_the_vertical_axis_is_found_from_the_markers(up):
    axis, sign, source = up_axis(_capture(up=up))
    assert (axis, sign) == (up, 1) and source.startswith("markers")
    flipped = _capture(up=up)
    flipped.positions[..., up] *= -1
    assert up_axis(flipped)[:2] == (up, -1)


def test_the_vertical_axis_comes_from_the_c3d_parameters_when_present():
    data = read(str(SAMPLE.parent / "markers_analogs.c3d"))
    assert up_axis(data) == (2, 1, "C3D POINT:Y_SCREEN")


@pytest.fixture(scope="module")
def fill_report(tmp_path_factory):
    pytest.importorskip("matplotlib")
    out = tmp_path_factory.mktemp("player")
    data = read(str(SAMPLE))
    outcome = fill_capture(data, FillSettings(method="auto", reject_outliers=True))
    path = out / "r.html"
    write_fill_report(outcome, str(path), method="auto", input_path=str(SAMPLE), output_path=None, smoothed=False)
    return path


@pytest.mark.slow
def test_the_fill_report_holds_a_self_contained_player(fill_report):
    page = fill_report.read_text()
    assert page.index('id="player"') < page.index('id="summary"')
    assert not re.search(r"""\s(src|href)\s*=\s*(?!["']?#)""", page), "external src/href"
    payload = _payload_of(page)
    assert payload["fill"] and payload["gaps"] and payload["bones"]
    assert any(payload["texts"][g[4]].startswith("local-pca") for g in payload["gaps"] if g[4] >= 0)  # for the click info
    _, status = _decode(payload)
    assert (status >= 2).any()


def test_info_report_shows_the_raw_capture(tmp_path):
    path = tmp_path / "take.html"
    result = CliRunner().invoke(cli, ["info", str(SAMPLE), "--report", str(path), "-q"])
    assert result.exit_code == 0, result.output
    payload = _payload_of(path.read_text())
    assert not payload["fill"] and payload["gaps"]
    _, status = _decode(payload)
    assert set(np.unique(status)) <= {0, 1}
    bad = CliRunner().invoke(cli, ["info", str(SAMPLE), "--report", str(tmp_path / "take.pdf")])
    assert bad.exit_code != 0 and not (tmp_path / "take.pdf").exists()


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.mark.slow
def test_the_player_draws_and_its_slider_moves_the_frame_in_headless_chromium(fill_report, tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium installed")
    command = [browser, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=5000",
               "--dump-dom", fill_report.as_uri() + "#player-selftest"]
    try:
        dom = subprocess.run(command, capture_output=True, text=True, timeout=120).stdout
    except subprocess.TimeoutExpired:
        pytest.skip("Chromium did not finish in 120 s (machine too busy)")
    assert 'data-player-errors="' not in dom, "a script error in the page"
    match = re.search(r'data-player-selftest="([^"]*)"', dom)
    assert match, "the player's self-test did not run"
    state = json.loads(html.unescape(match.group(1)))
    assert state["errors"] == []
    n = state["n_shown"]
    assert state["frames"] == [0, (n - 1) // 2]
    assert min(state["drawn"]) > 30  # the tennis serve's 39 markers, but for gaps
    assert min(state["inked"]) > 200  # pixels actually painted
    assert state["labels"][0] != state["labels"][1] and f"frame {(n - 1) // 2 + 1} of" in state["labels"][1]
    assert state["pick_text"].startswith(state["picked"] + " at frame")  # a click on a marker names it
    assert state["played"][1] > state["played"][0] and state["played"][2] == "Pause"  # play moves the frame on


def test_the_player_is_decimated_further_to_keep_the_page_under_its_budget():
    from mocapfill.report.player import fit_player

    data = _capture(n_frames=4000, n_markers=10)
    whole = fit_player(data, 0)
    assert '"stride":1,' in whole
    budget = len(whole.encode()) + 1000
    section = fit_player(data, 300_000, budget=budget)  # the rest of the page takes 300 kB more than is left
    assert len(section.encode()) + 300_000 <= budget and '"stride":1,' not in section


def test_a_capture_with_nothing_observed_still_gets_a_player():
    from mocapfill.report.player import player_section

    data = _capture(n_frames=20, n_markers=3)
    data.positions[:] = np.nan
    payload = player_payload(data)
    _, status = _decode(payload)
    assert (status == 1).all() and 'id="player"' in player_section(payload)
