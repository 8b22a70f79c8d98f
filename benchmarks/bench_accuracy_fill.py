"""Accuracy of the fill methods on short single-marker gaps and on the tennis serve's real-looking gaps (issue 3).

What it measures:

1. On ``sample_data/85_02.c3d`` (CMU, 41 markers, 810 frames at 120 Hz, mm, jumps and flips) and
   ``sample_data/kinematics_tennis_serve.c3d`` (OptiTrack, 39 markers, 1,092 frames at 50 Hz, m): per seeded trial
   one random marker is hidden for one contiguous segment of 0.5-2 s (uniform), strictly inside the clip; every
   method fills it; RMSE (3-D Euclidean, over the hidden frames) against the truth.  Printed per clip and method:
   median and mean RMSE in mm, the share of trials each method beats ``spline``, median seconds per fill.
2. ``sample_data/kinematics_tennis_serve_nan.c3d`` (the same serve with 10 gaps, 145 marker-frames, longest 42):
   each method fills it and is scored against the complete twin: RMSE and max error in mm over the missing samples.

The trial protocol is the one of ``tests/test_accuracy_fill.py`` (same generator, so the first trials coincide).

Run from the repository root::

    /work/venv/bin/python benchmarks/bench_accuracy_fill.py [--trials 10] [--seed 0] [--methods linear,spline,...]

BLAS threads: pinned to one unless the environment says otherwise (small matrices; threads only add contention on
a shared machine).  The setting, the machine and its load are printed.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import mocapfill  # noqa: E402
from mocapfill.gaps import find_gaps  # noqa: E402
from mocapfill.methods import METHODS  # noqa: E402

CLIPS = {
    "cmu-85_02": REPO / "sample_data" / "85_02.c3d",
    "tennis-serve": REPO / "sample_data" / "kinematics_tennis_serve.c3d",
}
TENNIS_NAN = REPO / "sample_data" / "kinematics_tennis_serve_nan.c3d"
TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}


def occlusion(n_frames: int, n_markers: int, rate: float, rng: np.random.Generator) -> tuple[int, int, int]:
    """(marker, start, length) of one hidden segment of 0.5-2 s strictly inside the clip."""
    marker = int(rng.integers(n_markers))
    length = int(round(rng.uniform(0.5, 2.0) * rate))
    start = int(rng.integers(1, n_frames - length - 1))
    return marker, start, length


def rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Root mean squared 3-D distance; arrays of shape (..., 3)."""
    return float(np.sqrt(np.mean(np.sum((estimate - truth) ** 2, axis=-1))))


def run_fill(data, method: str, seed: int):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        started = time.perf_counter()
        result = mocapfill.fill(data, method, seed=seed)
        return result, time.perf_counter() - started


def machine() -> str:
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    return (f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} CPUs, "
            f"load {' '.join(f'{x:.2f}' for x in load)}, python {platform.python_version()}, numpy {np.__version__}, "
            f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")


def single_gaps(methods: list[str], trials: int, seed: int) -> None:
    for name, path in CLIPS.items():
        data = mocapfill.read(path)
        scale = TO_MM[data.units]
        rng = np.random.default_rng(seed)
        errors = {m: [] for m in methods}
        seconds = {m: [] for m in methods}
        for _ in range(trials):
            marker, start, length = occlusion(data.n_frames, data.n_markers, data.rate, rng)
            hidden = data.positions.copy()
            hidden[start:start + length, marker] = np.nan
            for method in methods:
                result, took = run_fill(data.with_positions(hidden), method, seed)
                errors[method].append(scale * rmse(result.positions[start:start + length, marker],
                                                   data.positions[start:start + length, marker]))
                seconds[method].append(took)
        print(f"\n{name}: {data.n_frames} frames @ {data.rate:g} Hz, {data.n_markers} markers; {trials} trials, "
              f"one marker hidden 0.5-2 s (seed {seed})")
        print(f"{'method':<10} {'median mm':>10} {'mean mm':>10} {'beats spline':>13} {'median s':>9}")
        ref = np.array(errors["spline"]) if "spline" in errors else None
        for method in methods:
            e = np.array(errors[method])
            wins = f"{np.mean(e < ref):.0%}" if ref is not None and method != "spline" else "-"
            print(f"{method:<10} {np.median(e):>10.2f} {np.mean(e):>10.2f} {wins:>13} "
                  f"{np.median(seconds[method]):>9.2f}")


def tennis_nan(methods: list[str], seed: int) -> None:
    gappy = mocapfill.read(TENNIS_NAN)
    truth = mocapfill.read(CLIPS["tennis-serve"])
    scale = TO_MM[gappy.units]
    missing = gappy.missing
    print(f"\nkinematics_tennis_serve_nan.c3d: {int(missing.sum())} missing samples in {len(find_gaps(missing))} "
          "gaps, scored against the complete twin")
    print(f"{'method':<10} {'RMSE mm':>10} {'max mm':>10} {'seconds':>9}")
    for method in methods:
        result, took = run_fill(gappy, method, seed)
        diff = np.linalg.norm(result.positions[missing] - truth.positions[missing], axis=-1) * scale
        print(f"{method:<10} {np.sqrt(np.mean(diff ** 2)):>10.2f} {np.max(diff):>10.2f} {took:>9.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", default=",".join(METHODS))
    args = parser.parse_args()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]

    print(machine())
    single_gaps(methods, args.trials, args.seed)
    tennis_nan(methods, args.seed)


if __name__ == "__main__":
    main()
