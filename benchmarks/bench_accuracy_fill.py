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

    python benchmarks/bench_accuracy_fill.py [--trials 10] [--seed 0] [--methods linear,spline,...]

BLAS threads: pinned to one unless the environment says otherwise (small matrices; threads only add contention on
a shared machine).  The setting, the machine and its load are printed.
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

import mocapfill  # noqa: E402
from mocapfill.gaps import find_gaps  # noqa: E402
from mocapfill.methods import METHODS  # noqa: E402

CLIPS = {"cmu-85_02": harness.CLIP_85_02, "tennis-serve": harness.CLIP_TENNIS}


def occlusion(n_frames: int, n_markers: int, rate: float, rng: np.random.Generator) -> tuple[int, int, int]:
    """(marker, start, length) of one hidden segment of 0.5-2 s strictly inside the clip.

    Kept as the figures were measured (and as ``tests/test_accuracy_fill.py`` draws them): the ``marker`` protocol of
    :func:`mocapfill.evaluation.make_occlusions` draws its segments otherwise.
    """
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


def single_gaps(methods: list[str], trials: int, seed: int, results: harness.Results) -> dict:
    """Per clip the one-marker trials; returns {clip: {method: median RMSE mm}}."""
    medians, rows = {}, []
    for name, path in CLIPS.items():
        data = mocapfill.read(path)
        scale = harness.mm_per_unit(data.units)
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
            medians.setdefault(name, {})[method] = round(float(np.median(e)), 1)
            rows.append([name, method, round(float(np.median(e)), 2), round(float(np.mean(e)), 2),
                         round(100 * float(np.mean(e < ref))) if ref is not None and method != "spline" else None,
                         round(float(np.median(seconds[method])), 2)])
            results.figure(f"{name}/{method}/median_rmse", rows[-1][2], "mm")
    results.table("single_gaps", f"one marker hidden for 0.5-2 s, {trials} trials per clip (seed {seed}): RMSE (mm) "
                  "over the hidden samples", ["clip", "method", "median", "mean", "beats spline %", "median s"], rows)
    return medians


def tennis_nan(methods: list[str], seed: int, results: harness.Results) -> dict:
    """The tennis serve's real-looking gaps against its twin; returns {method: (RMSE, max) mm}."""
    gappy = mocapfill.read(harness.CLIP_TENNIS_NAN)
    truth = mocapfill.read(CLIPS["tennis-serve"])
    scale = harness.mm_per_unit(gappy.units)
    out = {}
    missing = gappy.missing
    print(f"\nkinematics_tennis_serve_nan.c3d: {int(missing.sum())} missing samples in {len(find_gaps(missing))} "
          "gaps, scored against the complete twin")
    print(f"{'method':<10} {'RMSE mm':>10} {'max mm':>10} {'seconds':>9}")
    for method in methods:
        result, took = run_fill(gappy, method, seed)
        diff = np.linalg.norm(result.positions[missing] - truth.positions[missing], axis=-1) * scale
        print(f"{method:<10} {np.sqrt(np.mean(diff ** 2)):>10.2f} {np.max(diff):>10.2f} {took:>9.2f}")
        out[method] = (round(float(np.sqrt(np.mean(diff ** 2))), 2), round(float(np.max(diff)), 2))
        results.figure(f"tennis_nan/{method}/rmse", out[method][0], "mm")
        results.figure(f"tennis_nan/{method}/max_error", out[method][1], "mm")
    results.table("tennis_nan", "`kinematics_tennis_serve_nan.c3d` (145 missing samples in 10 gaps) scored against "
                  "its complete twin, mm", ["method", "RMSE", "max"], [[m, *v] for m, v in out.items()])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", default=",".join(METHODS))
    harness.add_results_argument(parser)
    args = parser.parse_args()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]

    harness.banner(__file__)
    results = harness.Results(__file__, path=args.results, note=args.note)
    medians = single_gaps(methods, args.trials, args.seed, results)
    nan = tennis_nan(methods, args.seed, results)
    order = sorted(methods, key=lambda m: medians["cmu-85_02"].get(m, float("inf")))
    results.table("summary", f"median RMSE (mm): one marker hidden for 0.5-2 s ({args.trials} trials per clip); "
                  "the tennis serve's ten real-looking gaps against its complete twin (RMSE / max)",
                  ["method", "CMU 85_02, 0.5-2 s", "tennis, 0.5-2 s", "`kinematics_tennis_serve_nan.c3d` vs twin"],
                  [[f"`{m}`", medians["cmu-85_02"][m], medians["tennis-serve"][m], f"{nan[m][0]:.1f} / {nan[m][1]:.1f}"]
                   for m in order])
    results.write()


if __name__ == "__main__":
    main()
