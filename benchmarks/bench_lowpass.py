"""Benchmark of the Butterworth low-pass guard (``fill --lowpass``) and its residual analysis (``--lowpass auto``).

What it measures:

- per real capture at hand (``harness.COMPLETE_CLIPS`` and the gappy ``pyomeca/markers_analogs``,
  Vicon Nexus, 100 Hz, whose gaps split the stretches): the cutoff Winter's residual analysis chooses for the take
  and the range of the per-marker cutoffs, and the time of ``lowpass(..., "auto")`` on the whole capture;
- on synthetic 100 Hz takes (sinusoids at 0.7, 2.3 and 4.6 Hz, white noise of 1 % of the largest amplitude, 10
  seeds, two amplitude spectra): the chosen cutoff and the RMS error to the clean signal before and after filtering.

Run from the repository root::

    python benchmarks/bench_lowpass.py

Writes ``benchmarks/results/bench_lowpass.json`` (the house results format) and prints the tables.
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from mocapfill.guards.lowpass import lowpass, residual_cutoff  # noqa: E402
from mocapfill.io import read  # noqa: E402

CAPTURES = {**harness.COMPLETE_CLIPS, "markers_analogs (gappy)": harness.SAMPLE_DATA / "markers_analogs.c3d"}
RATE = 100.0
FREQUENCIES = (0.7, 2.3, 4.6)
SPECTRA = {"falling (100, 50, 25)": (100.0, 50.0, 25.0), "flat (100, 100, 100)": (100.0, 100.0, 100.0)}


def synthetic(seed: int, amplitudes) -> tuple[np.ndarray, np.ndarray]:
    """(noisy, clean), each (1000, 4, 3): per marker and coordinate the three sinusoids with random phases."""
    rng = np.random.default_rng(seed)
    t = np.arange(1000)[:, None, None, None] / RATE
    phases = rng.uniform(0, 2 * np.pi, (4, 3, len(FREQUENCIES)))
    clean = (np.asarray(amplitudes) * np.sin(2 * np.pi * np.asarray(FREQUENCIES) * t + phases)).sum(axis=-1)
    return clean + rng.normal(scale=0.01 * max(amplitudes), size=clean.shape), clean


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    harness.add_results_argument(parser)
    args = parser.parse_args(argv)
    harness.banner(__file__, file=sys.stderr)
    results = harness.Results(__file__, argv, path=args.results, note=args.note)
    captures = []
    for name, path in CAPTURES.items():
        if not path.exists():
            print(f"skipping {name}: {path} not found", file=sys.stderr)
            continue
        data = read(path)
        started = time.perf_counter()
        take = lowpass(data.positions, data.rate, "auto", observed=~data.missing)
        seconds = time.perf_counter() - started
        per = residual_cutoff(data.positions, data.rate, observed=~data.missing, per="marker")
        per = per[np.isfinite(per)]
        row = [name, data.n_frames, data.n_markers, data.rate, round(float(take.cutoff), 2),
               round(float(np.median(per)), 2), round(float(per.min()), 2), round(float(per.max()), 2),
               round(seconds, 3)]
        captures.append(row)
        print(f"{name:24s} {data.n_frames} x {data.n_markers} @ {data.rate:g} Hz: take {row[4]} Hz, per marker "
              f"median {row[5]} ({row[6]} to {row[7]}) Hz, {seconds:.2f} s", file=sys.stderr)

    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
    synth = []
    for label, amplitudes in SPECTRA.items():
        cut, raw, filt = [], [], []
        for seed in range(10):
            noisy, clean = synthetic(seed, amplitudes)
            out = lowpass(noisy, RATE, "auto")
            cut.append(out.cutoff)
            raw.append(rms(noisy - clean))
            filt.append(rms(out.positions - clean))
        synth.append([label, round(min(cut), 2), round(float(np.median(cut)), 2), round(max(cut), 2),
                      round(float(np.median(raw)), 3), round(float(np.median(filt)), 3)])
        print(f"synthetic {label}: cutoff {min(cut):.2f} to {max(cut):.2f} Hz (median {np.median(cut):.2f}), RMS "
              f"error to the clean signal {np.median(raw):.3f} raw -> {np.median(filt):.3f} filtered",
              file=sys.stderr)
        results.figure(f"synthetic_{label.split()[0]}_error_ratio", round(float(np.median(filt) / np.median(raw)), 3),
                       "filtered / raw RMS error")
    results.table("captures", "Residual-analysis cutoffs (Winter) on real captures, observed samples only",
                  ["capture", "frames", "markers", "rate (Hz)", "take cutoff (Hz)", "per-marker median (Hz)",
                   "per-marker min", "per-marker max", "lowpass auto (s)"], captures)
    results.table("synthetic", "Synthetic 100 Hz takes: sinusoids at 0.7, 2.3, 4.6 Hz + white noise 1 % of the "
                  "largest amplitude, 10 seeds", ["amplitudes", "cutoff min (Hz)", "cutoff median", "cutoff max",
                                                  "RMS error raw", "RMS error filtered"], synth)
    results.write()

if __name__ == "__main__":
    main()
