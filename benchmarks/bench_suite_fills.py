"""Benchmark of the suites' fills by name (``rigid``, ``pattern``, ``woltring``) beside ``auto`` and ``linear``.

What it measures, on the same occlusions for every method (drawn by :func:`mocapfill.evaluation.make_occlusions`,
errors by :func:`mocapfill.evaluation.point_errors`), on the real complete captures at hand:

- ``sample_data/85_02.c3d`` (CMU, 41 markers, 810 frames at 120 Hz, jumps and flips),
- ``sample_data/kinematics_tennis_serve.c3d`` (OptiTrack, 39 markers, 1,092 frames at 50 Hz),
- ``../shared/data/pyorerun/example.c3d`` (Vicon Nexus, arm + robot, 33 markers, 800 frames at 100 Hz) and
  ``../shared/data/btk/TRCSamples/SprintMotion.trc`` (59 markers, 788 frames at 250 Hz), when present;

three protocols: ``dense 10%`` (random single-marker gaps of 0.25 s to 2 s until 10 % of the samples are hidden),
``short 10%`` (the same with gaps of 0.05 s to 0.25 s, the gaps a technician fills with Woltring) and ``marker``
(one marker, one gap of 10 % to 50 % of the clip, at most 1 s); per clip, protocol and method:

- ``declined %``: the share of hidden samples the method left missing (the suites' fills decline gaps their rule
  cannot fill; ``auto`` and ``linear`` never do);
- ``RMSE own``: median over trials of the RMSE (mm) on the samples the method filled;
- ``RMSE common``: median over trials of the RMSE (mm) on the samples every method filled (a fair comparison);
- ``auto better``: the share of trials where ``auto``'s RMSE on the common samples is lower than the method's;
- ``seconds``: median and largest wall time of one fill (the whole capture).

Run from the repository root::

    python benchmarks/bench_suite_fills.py [--trials 10] [--seed 0] [--clips 85_02,tennis]

Writes ``benchmarks/results/bench_suite_fills.json`` (the house results format) and prints the tables.  Timing on
a shared machine is noisy; compare methods within one run.
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from mocapfill import api  # noqa: E402
from mocapfill.evaluation import make_occlusions, point_errors  # noqa: E402
from mocapfill.io import read  # noqa: E402
from mocapfill.units import length_factor  # noqa: E402

CLIPS = harness.COMPLETE_CLIPS
METHODS = ("auto", "linear", "woltring", "pattern", "rigid")
PROTOCOLS = {
    "dense 10%": {"protocol": "dense", "missing": 0.1},
    "short 10%": {"protocol": "dense", "missing": 0.1, "gap_min": "0.05s", "gap_max": "0.25s"},
    "marker": {"protocol": "marker"},
}


def run_clip(name: str, path: Path, trials: int, seed: int) -> list[dict]:
    data = read(path)
    to_mm = length_factor(data.units, "mm")
    rows = []
    for label, spec in PROTOCOLS.items():
        options = dict(spec)
        protocol = options.pop("protocol")
        occlusions = make_occlusions(data, protocol, trials=trials, seed=seed, **options)
        per = {m: {"own": [], "common": [], "declined": [], "seconds": []} for m in METHODS}
        auto_better = {m: [] for m in METHODS}
        for trial in occlusions:
            corrupted, hidden, _ = trial.apply(data.positions)
            errors = {}
            for method in METHODS:
                started = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    result = api.fill(data.with_positions(corrupted), method)
                per[method]["seconds"].append(time.perf_counter() - started)
                errors[method] = point_errors(result.positions, data.positions, hidden) * to_mm  # NaN = unfilled
            common = np.all([np.isfinite(e) for e in errors.values()], axis=0)
            for method, e in errors.items():
                filled = np.isfinite(e)
                per[method]["declined"].append(100.0 * (~filled).sum() / e.size)
                per[method]["own"].append(float(np.sqrt(np.mean(e[filled] ** 2))) if filled.any() else np.nan)
                per[method]["common"].append(float(np.sqrt(np.mean(e[common] ** 2))) if common.any() else np.nan)
            for method in METHODS:
                a, b = per["auto"]["common"][-1], per[method]["common"][-1]
                if np.isfinite(a) and np.isfinite(b):
                    auto_better[method].append(1.0 if a < b else 0.5 if a == b else 0.0)
        for method in METHODS:
            p = per[method]
            rows.append({
                "clip": name, "protocol": label, "method": method, "trials": len(occlusions),
                "declined_pct": float(np.mean(p["declined"])),
                "rmse_own_mm": float(np.nanmedian(p["own"])) if np.isfinite(p["own"]).any() else None,
                "rmse_common_mm": float(np.nanmedian(p["common"])) if np.isfinite(p["common"]).any() else None,
                "auto_better": float(np.mean(auto_better[method])) if auto_better[method] and method != "auto"
                else None,
                "seconds_median": float(np.median(p["seconds"])), "seconds_max": float(np.max(p["seconds"])),
            })
            r = rows[-1]
            print(f"{name:17s} {label:9s} {method:9s} declined {r['declined_pct']:5.1f} %  RMSE own "
                  f"{_f(r['rmse_own_mm'])} common {_f(r['rmse_common_mm'])} mm  auto better "
                  f"{_f(r['auto_better'], 2)}  {r['seconds_median']:.3f} s (max {r['seconds_max']:.3f})",
                  file=sys.stderr, flush=True)
    return rows


def _f(value, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--clips", default=",".join(CLIPS), help="comma-separated names of " + ", ".join(CLIPS))
    harness.add_results_argument(parser)
    args = parser.parse_args(argv)
    harness.banner(__file__, file=sys.stderr)
    results = harness.Results(__file__, argv, path=args.results, note=args.note)
    rows = []
    for name in args.clips.split(","):
        path = CLIPS[name]
        if not path.exists():
            print(f"skipping {name}: {path} not found", file=sys.stderr)
            continue
        rows += run_clip(name, path, args.trials, args.seed)

    columns = ["clip", "protocol", "method", "trials", "declined %", "RMSE own (mm)", "RMSE common (mm)",
               "auto better (share of trials)", "median s", "max s"]
    table = [[r["clip"], r["protocol"], r["method"], r["trials"], round(r["declined_pct"], 2),
              None if r["rmse_own_mm"] is None else round(r["rmse_own_mm"], 2),
              None if r["rmse_common_mm"] is None else round(r["rmse_common_mm"], 2),
              None if r["auto_better"] is None else round(r["auto_better"], 2),
              round(r["seconds_median"], 4), round(r["seconds_max"], 4)] for r in rows]
    for r in rows:
        if r["clip"] == "85_02" and r["protocol"] == "dense 10%" and r["method"] in ("rigid", "pattern"):
            results.figure(f"{r['method']}_85_02_dense10_max_seconds", round(r["seconds_max"], 4), "s")
        if r["method"] in ("rigid", "pattern", "woltring") and r["rmse_common_mm"] is not None:
            results.figure(f"{r['method']}_{r['clip']}_{r['protocol'].split()[0]}_rmse_common",
                           round(r["rmse_common_mm"], 2), "mm")
    results.table("suite_fills", "The suites' fills beside auto and linear, same occlusions "
                  f"({args.trials} trials per clip and protocol, seed {args.seed})", columns, table)
    results.write()


if __name__ == "__main__":
    main()
