"""Benchmark: pair_distance_stats on 200 markers x 72,000 frames (19,900 pairs): wall time and peak memory.

Usage::

    python benchmarks/bench_distances.py [--markers 200] [--frames 72000] [--missing 0.05]
    python benchmarks/bench_distances.py --outliers 20     # also: outlier-rejection precision / recall, 20 seeds
    python benchmarks/bench_distances.py --outliers 20 --outliers-only   # only those

Each measurement runs in a fresh subprocess, so the peak resident set size (``ru_maxrss`` of the child) is that of
one call (including the input array itself and the interpreter, about 30 MB), not of this driver.  The synthetic
capture is 200 markers moving as a smooth random walk around a body with ``--missing`` of the samples set to NaN
in runs (as real gaps are), so that pairs have different counts of common frames (the costly case for exact
percentiles).  Target: <= 1.5 GB and <= 60 s on the project's 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import harness

CHILD = r"""
import json, resource, sys, time
import numpy as np
from mocapfill.bones.distances import pair_distance_stats
positions = np.load(sys.argv[1])
rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0, c0 = time.perf_counter(), time.process_time()
stats = pair_distance_stats(positions)
seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"seconds": seconds, "cpu_seconds": cpu, "peak_rss_mb": rss / 1024,
                  "rss_after_input_mb": rss_before / 1024,
                  "input_mb": positions.nbytes / 2**20, "pairs": int(len(stats.pairs)),
                  "min_count": int(stats.count.min()), "max_count": int(stats.count.max())}))
"""


def synthetic(n_markers: int, n_frames: int, missing: float, seed: int):
    """A (n_frames, n_markers, 3) capture in mm: a body's smooth random walk, per-marker offsets, gaps in runs."""
    import numpy as np

    rng = np.random.default_rng(seed)
    positions = np.empty((n_frames, n_markers, 3))
    body = np.cumsum(rng.normal(0, 1.0, (n_frames, 3)), axis=0)
    for m in range(n_markers):
        positions[:, m] = body + rng.normal(0, 300.0, 3) + np.cumsum(rng.normal(0, 0.05, (n_frames, 3)), axis=0)
        lost = 0
        while lost < missing * n_frames:  # runs of 10-200 missing frames, as real gaps come
            length = int(rng.integers(10, 200))
            start = int(rng.integers(0, max(1, n_frames - length)))
            positions[start:start + length, m] = np.nan
            lost += length
    return positions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--markers", type=int, default=200)
    parser.add_argument("--frames", type=int, default=72_000)
    parser.add_argument("--missing", type=float, default=0.05, help="fraction of samples missing (default 0.05)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--outliers", type=int, default=0, metavar="SEEDS",
                        help="also score reject_outliers on the sample captures with SEEDS corruption seeds")
    parser.add_argument("--outliers-only", action="store_true", help="skip the pair_distance_stats timing")
    harness.add_results_argument(parser)
    args = parser.parse_args()
    harness.banner(__file__)
    import numpy

    results = harness.Results(__file__, path=args.results, note=args.note)
    if args.outliers_only:
        outlier_trials(max(1, args.outliers), results)
        results.write()
        return
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "positions.npy")
        numpy.save(path, synthetic(args.markers, args.frames, args.missing, args.seed))
        out = subprocess.run([sys.executable, "-c", CHILD, path], capture_output=True, text=True, check=True,
                             env={**os.environ, "PYTHONPATH": str(harness.REPO)})
    result = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"pair_distance_stats: {args.markers} markers x {args.frames} frames ({result['pairs']} pairs, "
          f"{args.missing:.0%} missing, common frames per pair {result['min_count']}-{result['max_count']})")
    print(f"  wall time     {result['seconds']:.1f} s (CPU time {result['cpu_seconds']:.1f} s; "
          f"load average before the run {load[0]:.1f})")
    print(f"  peak RSS      {result['peak_rss_mb']:.0f} MB (input array {result['input_mb']:.0f} MB, "
          f"process before the call {result['rss_after_input_mb']:.0f} MB)")
    results.table("pair_distance_stats", f"`pair_distance_stats` on {args.markers} markers x {args.frames} frames "
                  f"({result['pairs']} pairs, {args.missing:.0%} missing), in a fresh process",
                  ["wall s", "CPU s", "peak RSS MB", "input array MB"],
                  [[round(result["seconds"], 1), round(result["cpu_seconds"], 1), round(result["peak_rss_mb"]),
                    round(result["input_mb"])]])
    results.figure("pair_distance_stats/seconds", round(result["seconds"], 1), "s")
    results.figure("pair_distance_stats/peak_rss", round(result["peak_rss_mb"]), "MB")
    if args.outliers:
        outlier_trials(args.outliers, results)
    results.write()


def corrupt(positions, seed: int, kind: str, scale: float, rate: float):
    """One corrupted copy of ``positions`` (n_frames, n_markers, 3) and its truth mask (n_frames, n_markers).

    ``single``: Holden's corruption (3 % of the frames, 1-3 markers each thrown 5-50 cm).  ``runs``: 8 stretches of
    2-30 frames at 120 Hz (the same duration at other rates), one marker moved by one 5-50 cm offset throughout.
    ``swaps``: 8 such stretches where two markers at least 5 cm apart exchange positions.  ``long``: as ``runs``
    with 1-60 frames (to 0.5 s).  Lengths in mm are multiplied by ``scale`` (the file's units per mm).
    """
    import numpy as np

    rng = np.random.default_rng(seed)
    out = positions.copy()
    n_frames, n_markers, _ = positions.shape
    truth = np.zeros((n_frames, n_markers), dtype=bool)
    if kind == "single":
        for t in rng.choice(n_frames, int(round(0.03 * n_frames)), replace=False):
            for m in rng.choice(n_markers, rng.integers(1, 4), replace=False):
                direction = rng.normal(size=3)
                out[t, m] += direction / np.linalg.norm(direction) * rng.uniform(50, 500) * scale
                truth[t, m] = True
        return out, truth
    shortest, longest = (1, 60) if kind == "long" else (2, 30)
    shortest = max(1, round(shortest * rate / 120.0))
    longest = max(shortest, round(longest * rate / 120.0))
    done = 0
    while done < 8:
        length = int(rng.integers(shortest, longest + 1))
        t0 = int(rng.integers(1, n_frames - length - 1))
        span = slice(t0, t0 + length)
        if kind == "swaps":
            a, b = rng.choice(n_markers, 2, replace=False)
            if np.linalg.norm(positions[span, a] - positions[span, b], axis=1).min() < 50 * scale:
                continue
            out[span, a], out[span, b] = positions[span, b], positions[span, a]
            truth[span, [a, b]] = True
        else:
            m = rng.integers(n_markers)
            direction = rng.normal(size=3)
            out[span, m] = positions[span, m] + direction / np.linalg.norm(direction) * rng.uniform(50, 500) * scale
            truth[span, m] = True
        done += 1
    return out, truth


def outlier_trials(n_seeds: int, results: harness.Results) -> None:
    """reject_outliers (self-reference) on the complete sample captures: clean, and four corruptions x seeds."""
    import time

    import numpy as np

    import mocapfill
    from mocapfill.units import length_factor
    from mocapfill.guards.outliers import reject_outliers

    root = harness.SAMPLE_DATA
    rows = []
    print(f"reject_outliers (self-reference, defaults, the file's frame rate), {n_seeds} seeds per corruption")
    for name in ("85_02.c3d", "kinematics_tennis_serve.c3d"):
        data = mocapfill.read(root / name)
        scale = length_factor("mm", data.units)
        t0 = time.perf_counter()
        clean_mask = reject_outliers(data.positions, units=data.units, rate=data.rate).rejected
        clean = clean_mask.sum()
        seconds = time.perf_counter() - t0
        print(f"  {name}: {data.n_frames} frames x {data.n_markers} markers at {data.rate:g} Hz; uncorrupted file: "
              f"{clean} of {data.n_frames * data.n_markers} samples rejected ({seconds:.2f} s per call)")
        for kind in ("single", "runs", "swaps", "long"):
            precision, recall, beyond, passed = [], [], [], []
            for seed in range(n_seeds):
                corrupted, truth = corrupt(data.positions, seed, kind, scale, data.rate)
                rejected = reject_outliers(corrupted, units=data.units, rate=data.rate).rejected
                tp = (rejected & truth).sum()
                precision.append(tp / max(rejected.sum(), 1))
                recall.append(tp / truth.sum())
                # precision over the samples the uncorrupted file keeps: what the corruption itself costs
                beyond.append(tp / max((rejected & ~clean_mask).sum(), 1))
                if precision[-1] >= 0.95 and recall[-1] >= 0.95:
                    passed.append(seed)
            p, r = np.array(precision), np.array(recall)
            print(f"    {kind:6s} precision min {p.min():.3f} median {np.median(p):.3f}; recall min {r.min():.3f} "
                  f"median {np.median(r):.3f}; seeds with both >= 0.95: {int(((p >= 0.95) & (r >= 0.95)).sum())}"
                  f"/{n_seeds} {passed}; precision without the uncorrupted file's rejects min {min(beyond):.3f}")
            rows.append([name, kind, round(float(p.min()), 3), round(float(np.median(p)), 3), round(float(r.min()), 3),
                         round(float(np.median(r)), 3), f"{len(passed)}/{n_seeds}", round(float(min(beyond)), 3)])
            results.figure(f"{name}/{kind}/seeds_passed", len(passed), f"of {n_seeds} seeds", "higher")
        # `mocapfill evaluate --protocol random`: up to 10 % of each marker's samples hidden and 10 % shifted, in
        # stretches of 0.05-0.5 s, many markers at once; shifts uniform in +-50 cm per axis
        from mocapfill.evaluation.occlusions import make_occlusions

        recall, precision = [], []
        for trial in make_occlusions(data, "random", trials=n_seeds, seed=0):
            corrupted, _, shifted = trial.apply(data.positions)
            rejected = reject_outliers(corrupted, units=data.units, rate=data.rate).rejected
            recall.append((rejected & shifted).sum() / max(shifted.sum(), 1))
            precision.append((rejected & shifted).sum() / max(rejected.sum(), 1))
        print(f"    evaluate --protocol random ({n_seeds} trials, seed 0): shifted samples found median "
              f"{np.median(recall):.3f} min {min(recall):.3f}; precision median {np.median(precision):.3f} "
              f"min {min(precision):.3f}")
        rows.append([name, "evaluate -p random (shifted samples)", round(float(min(precision)), 3),
                     round(float(np.median(precision)), 3), round(float(min(recall)), 3),
                     round(float(np.median(recall)), 3), None, None])
        results.figure(f"{name}/random/recall_median", round(float(np.median(recall)), 3), "", "higher")
        results.figure(f"{name}/clean_rejected", int(clean), "samples")
    results.table("outliers", f"`reject_outliers` (self-reference, defaults) on corrupted copies, {n_seeds} seeds per "
                  "corruption: precision and recall, seeds with both >= 0.95, precision without the samples the "
                  "uncorrupted file loses", ["capture", "corruption", "precision min", "precision median",
                                             "recall min", "recall median", "seeds >= 0.95", "precision, clean rejects "
                                             "left out (min)"], rows)


if __name__ == "__main__":
    main()
