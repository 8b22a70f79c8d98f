"""The Butterworth low-pass guard: the textbook filter (scipy.signal's 2nd-order design run forward and backward,
gain 0.5 at the cutoff), stretch by stretch, and Winter's residual analysis."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, filtfilt

from mocapfill.errors import MethodError
from mocapfill.guards.lowpass import (MIN_STRETCH, PRECISION, butterworth, check_cutoff, lowest_cutoff, lowpass,
                                      residual_cutoff)

RATE = 100.0


def test_it_is_scipys_second_order_butterworth_run_forward_and_backward():
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(size=(500, 2, 3)), axis=0)
    b, a = butter(2, 6.0, btype="low", fs=RATE)
    np.testing.assert_allclose(butterworth(x, 6.0, RATE), filtfilt(b, a, x, axis=0), rtol=0, atol=1e-12)


@pytest.mark.parametrize("cutoff", [3.0, 6.0, 12.0])
def test_gain_at_the_cutoff_is_one_half(cutoff):
    t = np.arange(4000) / RATE
    x = np.zeros((len(t), 1, 3))
    x[:, 0, 0] = np.sin(2 * np.pi * cutoff * t)
    x[:, 0, 1] = np.sin(2 * np.pi * cutoff / 4 * t)  # well below: passed
    x[:, 0, 2] = np.sin(2 * np.pi * cutoff * 4 * t) if cutoff * 4 < RATE / 2 else 0.0  # well above: stopped
    y = butterworth(x, cutoff, RATE)[1000:-1000, 0]  # away from the ends
    amplitude = np.sqrt(2) * y.std(axis=0)
    assert amplitude[0] == pytest.approx(0.5, abs=0.005)
    assert amplitude[1] == pytest.approx(1.0, abs=0.01)
    assert amplitude[2] < 0.01


def test_each_continuous_stretch_is_filtered_alone_and_gaps_stay():
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(size=(300, 3, 3)), axis=0)
    x[100:130, 0] = np.nan  # a gap left unfilled
    x[:MIN_STRETCH - 1, 1] = np.nan  # leaves a stretch too short to filter ...
    x[2 * MIN_STRETCH - 2:2 * MIN_STRETCH, 1] = np.nan
    out = lowpass(x, RATE, 8.0)
    b, a = butter(2, 8.0, fs=RATE)
    assert np.isnan(out.positions[100:130, 0]).all()
    np.testing.assert_allclose(out.positions[:100, 0], filtfilt(b, a, x[:100, 0], axis=0), atol=1e-12)
    np.testing.assert_allclose(out.positions[130:, 0], filtfilt(b, a, x[130:, 0], axis=0), atol=1e-12)
    short = slice(MIN_STRETCH - 1, 2 * MIN_STRETCH - 2)
    assert np.array_equal(out.positions[short, 1], x[short, 1])  # ... left as it was
    assert not out.changed[short, 1].any() and out.changed[130:, 0].all() and not out.changed[100:130, 0].any()
    assert out.cutoff == 8.0


def synthetic_take(seed: int = 2, amplitudes=(100.0, 50.0, 25.0)) -> tuple[np.ndarray, np.ndarray]:
    """A 100 Hz take of 4 markers: sinusoids at 0.7, 2.3 and 4.6 Hz, white noise 1 % of the largest amplitude.

    Returns (noisy, clean), each (1000, 4, 3).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(1000) / RATE
    clean = np.zeros((len(t), 4, 3))
    for m in range(4):
        for c in range(3):
            phases = rng.uniform(0, 2 * np.pi, 3)
            clean[:, m, c] = sum(a * np.sin(2 * np.pi * f * t + p)
                                 for a, f, p in zip(amplitudes, (0.7, 2.3, 4.6), phases))
    noisy = clean + rng.normal(scale=0.01 * max(amplitudes), size=clean.shape)
    return noisy, clean


@pytest.mark.parametrize("amplitudes", [(100.0, 50.0, 25.0), (100.0, 100.0, 100.0)])
def test_residual_analysis_on_a_synthetic_take(amplitudes):
    noisy, clean = synthetic_take(amplitudes=amplitudes)
    out = lowpass(noisy, RATE, "auto")
    assert 4.6 < out.cutoff < 15.0
    rms = lambda e: np.sqrt(np.mean(e ** 2))  # noqa: E731
    assert rms(out.positions - clean) < rms(noisy - clean)
    per_marker = residual_cutoff(noisy, RATE, per="marker")
    assert per_marker.shape == (4,) and ((per_marker > 4.6) & (per_marker < 15.0)).all()


def test_residual_analysis_uses_observed_samples_only():
    noisy, clean = synthetic_take()
    filled = noisy.copy()
    filled[200:800] = clean[200:800]  # a "filled" stretch without measurement noise
    observed = np.ones(noisy.shape[:2], dtype=bool)
    observed[200:800] = False
    reference = residual_cutoff(noisy, RATE)
    assert residual_cutoff(filled, RATE, observed=observed) == pytest.approx(reference, abs=0.1)
    assert residual_cutoff(filled, RATE) > reference + 0.5  # counting the filled samples understates the noise


def test_bad_cutoffs_fail_in_one_line():
    x = np.zeros((50, 1, 3))
    with pytest.raises(MethodError, match="between 0 and half the frame rate"):
        lowpass(x, RATE, 60.0)
    with pytest.raises(MethodError, match="frame rate"):
        lowpass(x, float("nan"), 6.0)
    with pytest.raises(MethodError, match="'auto'"):
        lowpass(x, RATE, "fast")


def test_a_cutoff_too_low_for_the_rate_or_the_take_fails_in_one_line():
    """1e-8 Hz at 50 Hz made filtfilt's initial-state system singular (LinAlgError); 1e-7 Hz passed it and returned
    positions hundreds of mm off a constant.  The bound comes from the design: sum(a) ~ 4 (pi fc / rate)^2 against
    eps / PRECISION; and a take must hold a period of the cutoff."""
    rate = 50.0
    lowest = lowest_cutoff(rate)
    b, a = butter(2, lowest, fs=rate)
    assert a.sum() == pytest.approx(np.finfo(float).eps / PRECISION, rel=0.01)
    x = np.full((1092, 1, 3), 1000.0)
    x[:, 0, 0] += np.arange(1092) * 0.1
    # at the bound the filter keeps a constant to within PRECISION
    assert np.abs(butterworth(x, lowest, rate)[:, 0, 1] - 1000.0).max() < 1000.0 * PRECISION
    for cutoff in (1e-8, 1e-7, 0.5 * lowest):
        with pytest.raises(MethodError, match=r"too low for a frame rate of 50 Hz"):
            lowpass(x, rate, cutoff)
    assert lowest_cutoff(rate, 1092) == pytest.approx(rate / 1092)
    with pytest.raises(MethodError, match=r"take\.c3d: --lowpass 0\.04 Hz is too low for the take: its 1092 frames"):
        check_cutoff(0.04, rate, 1092, path="take.c3d")
    check_cutoff(0.05, rate, 1092)  # one period fits


def test_fill_lowpass_too_low_is_one_line_before_the_fill(sample_data, tmp_path):
    from click.testing import CliRunner

    from mocapfill.cli import cli

    src = sample_data / "kinematics_tennis_serve_nan.c3d"
    for cutoff, why in (("1e-8", "too low for a frame rate of 50 Hz"), ("0.01", "too low for the take")):
        result = CliRunner().invoke(cli, ["fill", str(src), str(tmp_path / "x.c3d"), "-m", "linear", "--lowpass",
                                          cutoff])
        assert result.exit_code == 1, result.output
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"Error: {src}: --lowpass {float(cutoff):g} Hz is") and \
            why in lines[0]
        assert not (tmp_path / "x.c3d").exists()
