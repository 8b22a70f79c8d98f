"""Benchmark of issue 9: the default fill (``auto``) on messy captures, against every registered method.

What it measures, on real complete clips from two labs (``sample_data/85_02.c3d``: CMU, 41 markers, 810 frames at
120 Hz, jumps and flips; ``sample_data/kinematics_tennis_serve.c3d``: OptiTrack, 39 markers, 1,092 frames at 50 Hz,
metres; ``../shared/data/bolero/132_32.csv``: CMU as the BoLeRO authors ship it, 644 frames, read at 120 Hz;
``../shared/data/pyorerun/example.c3d``: pyorerun's example, 33 markers, 800 frames at 100 Hz), with the occlusion
protocols of :func:`mocapfill.evaluation.occlusions.make_occlusions`:

- ``dense`` at 5, 10, 20 and 30 % of the samples missing (random single-marker gaps of 0.25-2 s): per method, the
  median and the RMSE of the PER-SAMPLE 3-D error (mm) pooled over the hidden samples of every trial of every clip
  (the issue's figures), and per clip;
- ``segment`` (a marker and every marker within 250 mm median distance vanish together, 3 events of 0.5-3 s): the
  median over trials of the per-trial RMSE (mm), per clip and over all trials;
- plausibility: every capture with real gaps in ``sample_data/``, ``tests/data/`` and ``../shared/data`` filled
  by the default, and the worst ratios of :func:`mocapfill.guards.plausibility.plausibility`: the largest filled
  distance from the body's median centre over the farthest observed marker (must stay <= 1.1) and the largest
  filled step over its marker's largest observed step (the issue asks <= 1.5), plus the same step over the larger
  of that and the body's largest step at that frame (what the default guards).

Run from the repository root (about 20 min on the shared 2-core machine; bolero-hc / bolero-sc dominate)::

    python benchmarks/bench_messy.py [--trials 1] [--seed 0] [--methods all] [--skip dense,segment,plausibility]

or, one clip per process, then the pooled tables::

    python benchmarks/bench_messy.py --skip segment,plausibility --clips cmu-85_02 --dump /tmp/messy  (per clip)
    python benchmarks/bench_messy.py --skip segment,plausibility --merge /tmp/messy
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from mocapfill import api  # noqa: E402
from mocapfill.errors import MocapfillError  # noqa: E402
from mocapfill.evaluation.occlusions import make_occlusions  # noqa: E402
from mocapfill.io import read  # noqa: E402
from mocapfill.methods import METHODS  # noqa: E402
from mocapfill.methods.auto_stack import MIN_SPEED_MM, step_reference  # noqa: E402
from mocapfill.pipeline import fill_columns, subset  # noqa: E402
from mocapfill.guards.plausibility import (body_centre, observed_speed, plausibility,  # noqa: E402
                                            project_plausible)
from mocapfill.units import length_factor  # noqa: E402

REPO = harness.REPO
SHARED = harness.SHARED_DATA
CLIPS = {
    "cmu-85_02": (harness.CLIP_85_02, {}),
    "tennis-serve": (harness.CLIP_TENNIS, {}),
    "bolero-132_32": (SHARED / "bolero" / "132_32.csv", {"rate": 120.0}),
    "pyorerun-example": (SHARED / "pyorerun" / "example.c3d", {}),
}
DENSITIES = (0.05, 0.10, 0.20, 0.30)


def _clips() -> dict:
    out = {}
    for name, (path, kw) in CLIPS.items():
        if path.exists():
            out[name] = read(path, **kw)
        else:
            print(f"  (skipping {name}: {path} absent)", file=sys.stderr)
    return out


def _errors(data, method: str, trial, seed: int) -> tuple[np.ndarray, float]:
    """Per-sample 3-D errors (mm) over the trial's hidden samples, and the fill's seconds."""
    pos, hidden, _ = trial.apply(data.positions)
    t0 = time.perf_counter()
    res = api.fill(data.with_positions(pos), method=method, seed=seed)
    sec = time.perf_counter() - t0
    err = np.linalg.norm(res.positions[hidden] - data.positions[hidden], axis=1) * length_factor(data.units, "mm")
    return np.where(np.isfinite(err), err, np.nan), sec


def _row(err: np.ndarray) -> str:
    return f"{np.nanmedian(err):7.1f} / {np.sqrt(np.nanmean(err ** 2)):6.1f}"


def _cell(err: np.ndarray) -> str:
    return f"{np.nanmedian(err):.1f} / {np.sqrt(np.nanmean(err ** 2)):.1f}"


def dense(clips: dict, methods: list[str], trials: int, seed: int, results: harness.Results, dump: str = "",
          merge: str = "") -> None:
    print("\n## dense: median / RMSE of the per-sample 3-D error (mm), pooled over the hidden samples", file=sys.stderr)
    print(f"{trials} trial(s) per clip and density, clips: {', '.join(clips)}", file=sys.stderr)
    pooled = {(m, f): [] for m in methods for f in DENSITIES}
    per_clip = {}
    seconds = {m: [] for m in methods}
    if merge:  # tables from the errors that --dump runs (one clip each, in parallel) saved
        clips = {}
        for path in sorted(Path(merge).glob("dense-*.npz")):
            saved = np.load(path)
            name = path.stem[len("dense-"):]
            clips[name] = None
            for key in saved.files:
                kind, m, frac = key.split("|")
                if m not in methods:
                    continue
                if kind == "err":
                    pooled[m, float(frac)].append(saved[key])
                    per_clip.setdefault((name, m, float(frac)), []).append(saved[key])
                else:
                    seconds[m].append(float(saved[key]))
        print(f"merged from {merge}: {', '.join(clips)}", file=sys.stderr)
    for name, data in clips.items() if not merge else ():
        store = {}
        for frac in DENSITIES:
            for trial in make_occlusions(data, "dense", trials=trials, seed=seed, missing=frac):
                for m in methods:
                    err, sec = _errors(data, m, trial, seed)
                    pooled[m, frac].append(err)
                    per_clip.setdefault((name, m, frac), []).append(err)
                    seconds[m].append(sec)
                    store[f"err|{m}|{frac}"] = np.concatenate(per_clip[name, m, frac])
                    store[f"sec|{m}|{frac}"] = sec
            print(f"  {name} {frac:.0%} done", file=sys.stderr, flush=True)
            if dump:
                Path(dump).mkdir(parents=True, exist_ok=True)
                np.savez(Path(dump) / f"dense-{name}.npz", **store)
    head = "| method | " + " | ".join(f"{f:.0%}" for f in DENSITIES) + " | s per fill |"
    print("\nAll clips pooled:\n" + head + "\n|---|" + "---|" * (len(DENSITIES) + 1), file=sys.stderr)
    columns = ["method", *(f"{f:.0%}" for f in DENSITIES)]
    rows = []
    for m in methods:
        cells = " | ".join(_row(np.concatenate(pooled[m, f])) for f in DENSITIES)
        print(f"| {m} | {cells} | {np.median(seconds[m]):.2f} |", file=sys.stderr)
        rows.append([f"`{m}`", *(_cell(np.concatenate(pooled[m, f])) for f in DENSITIES),
                     round(float(np.median(seconds[m])), 2)])
        for f in DENSITIES:
            err = np.concatenate(pooled[m, f])
            results.figure(f"dense/{m}/{f:.0%}/median", round(float(np.nanmedian(err)), 1), "mm")
            results.figure(f"dense/{m}/{f:.0%}/rmse", round(float(np.sqrt(np.nanmean(err ** 2))), 1), "mm")
    results.table("dense", f"random 0.25-2 s single-marker gaps until 5-30 % of the samples are hidden ({trials} "
                  f"trial(s) per clip and density; clips: {', '.join(clips)}): median / RMSE of the per-sample 3-D "
                  "error (mm), pooled over the hidden samples", [*columns, "s per fill"], rows)
    for name in clips:
        results.table(f"dense_{name}", f"as `dense`, {name} only", columns,
                      [[f"`{m}`", *(_cell(np.concatenate(per_clip[name, m, f])) for f in DENSITIES)]
                       for m in methods])
        print(f"\n{name}:\n" + head.replace(" s per fill |", "") + "\n|---|" + "---|" * len(DENSITIES),
              file=sys.stderr)
        for m in methods:
            cells = " | ".join(_row(np.concatenate(per_clip[name, m, f])) for f in DENSITIES)
            print(f"| {m} | {cells} |", file=sys.stderr)
    if "auto" in methods:
        print("\nTargets (pooled):", file=sys.stderr)
        auto = {f: np.concatenate(pooled["auto", f]) for f in DENSITIES}
        for f in DENSITIES:
            med, rmse = np.nanmedian(auto[f]), np.sqrt(np.nanmean(auto[f] ** 2))
            worse = [m for m in methods if m != "auto" and not (
                med < np.nanmedian(np.concatenate(pooled[m, f]))
                and rmse < np.sqrt(np.nanmean(np.concatenate(pooled[m, f]) ** 2)))]
            print(f"  {f:.0%}: auto beats every other method on median and RMSE: {not worse}"
                  + (f" (not: {', '.join(worse)})" if worse else ""), file=sys.stderr)
        ratio = np.nanmedian(auto[0.20]) / np.nanmedian(auto[0.05])
        results.figure("dense/auto/median_20_over_5", round(float(ratio), 2), "x")
        print(f"  auto median at 20 % / at 5 %: {ratio:.2f} (target <= 2)", file=sys.stderr)


def segment(clips: dict, methods: list[str], trials: int, seed: int, results: harness.Results) -> None:
    print("\n## segment (250 mm, 3 events of 0.5-3 s): median of the per-trial RMSE (mm)", file=sys.stderr)
    print(f"{trials} trials per clip", file=sys.stderr)
    rmse = {}
    for name, data in clips.items():
        for trial in make_occlusions(data, "segment", trials=trials, seed=seed):
            for m in methods:
                err, _ = _errors(data, m, trial, seed)
                rmse.setdefault((name, m), []).append(np.sqrt(np.nanmean(err ** 2)))
        print(f"  {name} done", file=sys.stderr, flush=True)
    print("\n| method | " + " | ".join(clips) + " | all trials |\n|---|" + "---|" * (len(clips) + 1),
          file=sys.stderr)
    rows = []
    for m in methods:
        cells = " | ".join(f"{np.median(rmse[name, m]):.1f}" for name in clips)
        every = np.concatenate([rmse[name, m] for name in clips])
        print(f"| {m} | {cells} | {np.median(every):.1f} |", file=sys.stderr)
        rows.append([f"`{m}`", *(round(float(np.median(rmse[name, m])), 1) for name in clips),
                     round(float(np.median(every)), 1)])
        results.figure(f"segment/{m}/median_rmse", rows[-1][-1], "mm")
    results.table("segment", f"a marker and every marker within 250 mm vanish together, 3 events of 0.5-3 s "
                  f"({trials} trials per clip): median of the per-trial RMSE (mm)", ["method", *clips, "all trials"],
                  rows)
    if {"auto", "pca", "bolero-sc"} <= set(methods):
        med = {m: np.median(np.concatenate([rmse[name, m] for name in clips])) for m in ("auto", "pca", "bolero-sc")}
        print(f"\nTargets (all trials): auto / pca = {med['auto'] / med['pca']:.2f} (<= 0.6); auto "
              f"{med['auto']:.1f} < bolero-sc {med['bolero-sc']:.1f}: {med['auto'] < med['bolero-sc']}",
              file=sys.stderr)


def _captures() -> list[Path]:
    roots = [REPO / "sample_data", REPO / "tests" / "data", SHARED]
    found = []
    for root in roots:
        if root.exists():
            found += sorted(p for p in root.rglob("*") if p.suffix.lower() in (".c3d", ".trc", ".csv"))
    return found


def plausibility_scan(results: harness.Results, only: str = "", all_points: bool = False) -> None:
    """``only``: comma-separated substrings of the captures to scan (default all); ``all_points``: fill every point
    as the default did before model points and unlabelled trajectories were kept aside (issue 23)."""
    print("\n## plausibility of the default's fills on every capture with real gaps", file=sys.stderr)
    print("extent: largest filled distance from the body's median centre / farthest observed; step: largest step "
          "touching a filled sample / its marker's largest observed step (own), or / the larger of that and the "
          "body's largest observed step then (own, body: what `auto` bounds at 1.5); 'forced': filled samples in "
          "runs whose observed ends are too far apart for the bounds (the straight line between them breaks one), "
          "left out of the ratios after the bar", file=sys.stderr)
    print("| capture | frames x markers | missing | extent (<= 1.1) | step / own | step / max(own, body) (<= 1.5) | "
          "forced samples | extent, step / max(own, body) without them | s |\n|---|---|---|---|---|---|---|---|---|",
          file=sys.stderr)
    worst = {"extent": 0.0, "speed": 0.0, "body": 0.0, "extent_free": 0.0, "body_free": 0.0}
    rows = []
    wanted = [w for w in only.split(",") if w]
    for path in _captures():
        if wanted and not any(w in str(path) for w in wanted):
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                data = read(path, rate=120.0) if path.suffix.lower() == ".csv" else read(path)
        except (MocapfillError, OSError, ValueError):
            continue
        kept = 0
        if all_points:  # every point a marker: fill model points and unlabelled trajectories too (the old default)
            data = dataclasses.replace(data, kinds=["marker"] * data.n_markers)
        else:  # what `fill` fills: the markers (model points and unlabelled trajectories kept aside)
            columns = fill_columns(data)
            kept = data.n_markers - columns.size
            if kept:
                data = subset(data, columns)
        pos = data.positions
        missing = np.isnan(pos).any(axis=2)
        gaps = missing & ~missing.all(axis=0) & (~missing).any(axis=1)[:, None]
        if not gaps.any():
            continue
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = api.fill(data, method="auto")
        sec = time.perf_counter() - t0
        floor = MIN_SPEED_MM * length_factor("mm", data.units)
        ratios = plausibility(res.positions, pos, floor=floor)
        speed = observed_speed(pos, missing, floor=floor)
        body = step_reference(pos, missing, speed)
        _, _, forced = project_plausible(res.positions, pos, body)  # the fill is final: only forced runs remain
        filled = missing & np.isfinite(res.positions).all(axis=2)
        centre, radius = body_centre(pos, missing)
        dist = np.linalg.norm(res.positions - centre[:, None, :], axis=2) / radius
        step = np.linalg.norm(np.diff(res.positions, axis=0), axis=2) / body
        touch = (filled[1:] | filled[:-1]) & np.isfinite(step)
        free = filled & ~forced
        touch_free = touch & ~forced[1:] & ~forced[:-1]
        body_ratio = float(step[touch].max()) if touch.any() else 0.0
        ext_free = float(dist[free].max()) if free.any() else 0.0
        body_free = float(step[touch_free].max()) if touch_free.any() else 0.0
        for key, value in (("extent", ratios["extent"]), ("speed", ratios["speed"]), ("body", body_ratio),
                           ("extent_free", ext_free), ("body_free", body_free)):
            worst[key] = max(worst[key], value)
        rel = path.relative_to(SHARED) if SHARED in path.parents else path.relative_to(REPO)
        shape = f"{pos.shape[0]} x {pos.shape[1]}" + (f" (+{kept} kept)" if kept else "")
        print(f"| {rel} | {shape} | {missing.mean():.1%} | {ratios['extent']:.2f} | "
              f"{ratios['speed']:.2f} | {body_ratio:.2f} | {int(forced.sum())} of {int(filled.sum())} | "
              f"{ext_free:.2f}, {body_free:.2f} | {sec:.2f} |", file=sys.stderr, flush=True)
        rows.append([str(rel), f"{pos.shape[0]} x {pos.shape[1]}", f"{missing.mean():.1%}",
                     round(float(ratios["extent"]), 2), round(float(ratios["speed"]), 2), round(body_ratio, 2),
                     f"{int(forced.sum())} of {int(filled.sum())}", f"{ext_free:.2f}, {body_free:.2f}"])
    print(f"\nWorst: extent {worst['extent']:.2f}, step / own {worst['speed']:.2f}, step / max(own, body) "
          f"{worst['body']:.2f}; without forced runs: extent {worst['extent_free']:.2f}, step / max(own, body) "
          f"{worst['body_free']:.2f}", file=sys.stderr)
    results.table("plausibility", "the default's fills of every capture with real gaps: extent = largest filled "
                  "distance from the body's median centre / farthest observed (<= 1.1); step = largest step touching a "
                  "filled sample / its marker's largest observed step (own), or / the larger of that and the body's "
                  "(<= 1.5); forced = filled samples in runs whose observed ends are too far apart for the bounds",
                  ["capture", "frames x markers", "missing", "extent", "step / own", "step / max(own, body)",
                   "forced samples", "extent, step / max(own, body) without them"], rows)
    results.figure("plausibility/worst_extent_unforced", round(worst["extent_free"], 2), "x")
    results.figure("plausibility/worst_step_unforced", round(worst["body_free"], 2), "x")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=1, help="dense trials per clip and density")
    parser.add_argument("--segment-trials", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", default="all", help="comma-separated registered methods (auto first), or all")
    parser.add_argument("--clips", default="", help="comma-separated clip names (default: all present)")
    parser.add_argument("--dump", default="", help="directory: save each clip's dense errors there (npz)")
    parser.add_argument("--merge", default="", help="directory: dense tables from the errors --dump runs saved")
    parser.add_argument("--skip", default="", help="comma-separated sections to skip: dense,segment,plausibility")
    parser.add_argument("--without-auto", action="store_true",
                        help="run only the named methods (auto is otherwise added first, as the reference)")
    parser.add_argument("--only", default="", help="plausibility: comma-separated substrings of the captures to scan")
    parser.add_argument("--all-points", action="store_true",
                        help="plausibility: fill model points and unlabelled trajectories too (as before issue 23)")
    harness.add_results_argument(parser)
    args = parser.parse_args(argv)
    methods = list(METHODS) if args.methods == "all" else args.methods.split(",")
    if not args.without_auto:
        methods = ["auto"] + [m for m in methods if m != "auto"]
    skip = set(filter(None, args.skip.split(",")))
    harness.banner(__file__, file=sys.stderr)
    results = harness.Results(__file__, argv, "-" if args.dump else args.results, note=args.note)
    clips = _clips()
    if args.clips:
        clips = {k: v for k, v in clips.items() if k in args.clips.split(",")}
    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    if "dense" not in skip:
        dense(clips, methods, args.trials, args.seed, results, args.dump, args.merge)
    if "segment" not in skip:
        segment(clips, methods, args.segment_trials, args.seed, results)
    if "plausibility" not in skip:
        plausibility_scan(results, args.only, args.all_points)
    results.write()
    print(f"\n{time.perf_counter() - t0:.0f} s in all; load now {os.getloadavg()[0]:.2f}", file=sys.stderr)


if __name__ == "__main__":
    main()
