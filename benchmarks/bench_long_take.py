"""Benchmark: the default fill on a ten-minute take (issue 9, "Long takes").

The take: ``sample_data/85_02.c3d`` (CMU, 41 markers, 810 frames at 120 Hz) played forwards and backwards until it
lasts 72,000 frames (ten minutes).  The ``dense`` protocol hides 5 % of its samples (one-marker gaps of 0.25-2 s,
seed 0).  Each fill runs in its own subprocess, which reports its wall time and its peak resident memory
(``resource.getrusage(RUSAGE_SELF).ru_maxrss``: interpreter, data and fill):

- ``part``: frames 0-4,999 of the take with the same gaps, filled with ``mocapfill.fill(data)`` (the default);
- ``default``: the whole take with ``mocapfill.fill(data)``: whatever ``auto`` is in this checkout (``--method``: that
  registered method instead, in every mode);
- ``windows``: the whole take with ``mocapfill.guards.windows.fill_in_windows(positions, default fill)`` applied
  from the outside (windows of at most 5,000 frames, 400 shared), i.e. what ``auto`` gives once it delegates long
  takes to the windows; ``windows-2jobs``: the same with two windows at a time in worker processes (``jobs=2``).

Errors: the per-sample 3-D error over the hidden samples (mm), median and RMSE.  Targets of the issue: the default
fill of the take in at most 60 s, at most 16x the time of one 5,000-frame part, peak memory at most 1.5 GB, and a
median error at most 1.5x the part's.

Run from the repository root::

    python benchmarks/bench_long_take.py [--frames 72000] [--part 5000] [--modes part,windows,windows-2jobs,default]
        [--method auto-stack]
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from functools import partial  # noqa: E402

import numpy as np  # noqa: E402

CLIP = harness.CLIP_85_02


def build_take(frames: int, missing: float, seed: int):
    """(truth MarkerData (frames, 41, 3), hidden mask (frames, 41)): 85_02 forwards and backwards, dense gaps."""
    import mocapfill
    from mocapfill.evaluation import make_occlusions
    from mocapfill.markers import MarkerData

    clip = mocapfill.read(CLIP)
    take = harness.palindrome(clip.positions, frames, repeat_turns=False)
    truth = MarkerData(take, clip.labels, clip.rate, clip.units)
    trial = make_occlusions(truth, "dense", trials=1, seed=seed, missing=missing)[0]
    return truth, trial.hidden_mask(*take.shape[:2]) & ~np.isnan(take).any(axis=2)


def fill_window(positions: np.ndarray, labels: list, rate: float, units: str, method: str | None = None):
    """The fill (``method``, default the default) of one window (positions (n, n_markers, 3)) of the take:
    picklable, for worker processes."""
    import mocapfill
    from mocapfill.markers import MarkerData

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = MarkerData(positions, labels, rate, units)
        return mocapfill.fill(data) if method is None else mocapfill.fill(data, method)


def worker(mode: str, frames: int, part: int, missing: float, seed: int, window: int, overlap: int,
           method: str | None = None) -> dict:
    """One fill in this process; returns the figures as a dict."""
    import mocapfill
    from mocapfill.markers import MarkerData
    from mocapfill.guards.windows import fill_in_windows

    truth, hidden = build_take(frames, missing, seed)
    if mode == "part":
        truth = MarkerData(truth.positions[:part], truth.labels, truth.rate, truth.units)
        hidden = hidden[:part]
    corrupted = truth.positions.copy()
    corrupted[hidden] = np.nan
    data = truth.with_positions(corrupted)
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if mode in ("windows", "windows-2jobs"):
            # a window is the same capture (labels, rate, units) over fewer frames
            result = fill_in_windows(corrupted, partial(fill_window, labels=data.labels, rate=data.rate,
                                                        units=data.units, method=method),
                                     window=window, overlap=overlap, jobs=2 if mode == "windows-2jobs" else 1)
        else:
            # the processes the figure was measured with (2 cores)
            result = mocapfill.fill(data, jobs=2) if method is None else mocapfill.fill(data, method, jobs=2)
    seconds = time.perf_counter() - t0
    err = np.linalg.norm(result.positions[hidden] - truth.positions[hidden], axis=1)
    return {"mode": mode, "frames": int(truth.n_frames), "markers": int(truth.n_markers),
            "missing": float(hidden.mean()), "seconds": seconds,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "rss_before_mb": rss_before,
            "worker_peak_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
            "median_mm": float(np.nanmedian(err)), "rmse_mm": float(np.sqrt(np.nanmean(err ** 2))),
            "unfilled": int(np.isnan(err).sum()), "windows": len(result.info.get("windows", [])) or 1}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=72_000)
    parser.add_argument("--part", type=int, default=5_000)
    parser.add_argument("--missing", type=float, default=0.05)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--window", type=int, default=5_000)
    parser.add_argument("--overlap", type=int, default=400)
    parser.add_argument("--modes", default="part,windows,windows-2jobs,default")
    parser.add_argument("--method", default=None, help="registered fill method (default: the default)")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    harness.add_results_argument(parser)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, args.frames, args.part, args.missing, args.seed, args.window,
                                args.overlap, args.method)))
        return

    harness.banner(__file__)
    results = harness.Results(__file__, path=args.results, note=args.note)
    print(f"# take: {CLIP.name} forwards and backwards to {args.frames} frames; dense protocol, {args.missing:.0%} "
          f"missing, seed {args.seed}; part = frames 0-{args.part - 1}; windows {args.window} / overlap "
          f"{args.overlap}; method {args.method or 'the default'}")
    rows = {}
    for mode in [m.strip() for m in args.modes.split(",") if m.strip()]:
        cmd = [sys.executable, __file__, "--worker", mode, "--frames", str(args.frames), "--part", str(args.part),
               "--missing", str(args.missing), "--seed", str(args.seed), "--window", str(args.window),
               "--overlap", str(args.overlap)] + (["--method", args.method] if args.method else [])
        out = subprocess.run(cmd, capture_output=True, text=True,
                             env={**os.environ, "PYTHONPATH": str(harness.REPO)})
        if out.returncode:
            print(f"{mode}: failed\n{out.stderr[-2000:]}")
            continue
        row = json.loads(out.stdout.strip().splitlines()[-1])
        rows[mode] = row
        print(f"{mode:>8}: {row['frames']:>6} frames x {row['markers']} markers, {row['missing']:.1%} hidden, "
              f"{row['windows']:>2} window(s): {row['seconds']:7.2f} s, peak RSS {row['peak_rss_mb']:6.0f} MB "
              f"(before the fill {row['rss_before_mb']:.0f} MB), median {row['median_mm']:.2f} mm, RMSE "
              f"{row['rmse_mm']:.2f} mm, unfilled {row['unfilled']}"
              + (f"; each of the 2 worker processes peaked at {row['worker_peak_mb']:.0f} MB"
                 if mode == "windows-2jobs" else ""), flush=True)
    part = rows.get("part")
    table = []
    for mode in ("part", "windows", "windows-2jobs", "default"):
        row = rows.get(mode)
        if not row:
            continue
        peak = row["peak_rss_mb"] + (2 * row["worker_peak_mb"] if mode == "windows-2jobs" else 0.0)
        ratio_t = row["seconds"] / part["seconds"] if part else None
        ratio_e = row["median_mm"] / part["median_mm"] if part else None
        table.append([mode, row["frames"], row["windows"], round(row["seconds"], 1),
                      None if ratio_t is None or mode == "part" else round(ratio_t, 1), round(peak),
                      round(row["median_mm"], 2), round(row["rmse_mm"], 2),
                      None if ratio_e is None or mode == "part" else round(ratio_e, 2)])
        results.figure(f"{mode}/seconds", table[-1][3], "s")
        results.figure(f"{mode}/peak_rss", table[-1][5], "MB")
        results.figure(f"{mode}/median_error", table[-1][6], "mm")
        if mode == "part" or not part:
            continue
        ok = lambda b: "met" if b else "NOT met"  # noqa: E731
        print(f"# {mode}: time {row['seconds']:.1f} s <= 60 s {ok(row['seconds'] <= 60)}; {ratio_t:.1f}x the part "
              f"<= 16x {ok(ratio_t <= 16)}; peak {peak:.0f} MB (all processes) <= 1536 MB {ok(peak <= 1536)}; "
              f"median error {ratio_e:.2f}x the part's <= 1.5x {ok(ratio_e <= 1.5)}")
    results.table("modes", f"{args.method or 'the default'}: {CLIP.name} forwards and backwards to {args.frames} frames x 41 markers, "
                  f"{args.missing:.0%} missing (dense protocol, seed {args.seed}); part = its first {args.part} "
                  "frames; peak RSS over all processes; errors over the hidden samples",
                  ["mode", "frames", "windows", "seconds", "x the part's time", "peak MB", "median mm", "RMSE mm",
                   "median x the part's"], table)
    results.write()


if __name__ == "__main__":
    main()
