"""Issue 21, "fast" and "smooth": each method on every real capture with gaps, as ``mocapfill fill`` runs it.

For every capture under ``sample_data/``, ``tests/data/`` and ``../shared/data`` (C3D, TRC, CSV, TSV; the same file
found twice is run once) that ``mocapfill fill`` reads without options and that has gaps (a missing sample of a
marker point that is observed elsewhere, in a frame where another marker is observed), and for each ``--methods``
(default ``auto,pca``):

- **fast**: the fill's own seconds (:func:`mocapfill.pipeline.fill_capture`, the step ``mocapfill fill`` runs between
  reading and writing: ``outcome.seconds``, wall time of :func:`mocapfill.fill`; reading and writing are not counted)
  over the capture's duration; the issue's bound is 0.25 x the duration or 1 s, whichever is larger.  Each fill runs
  on the processes ``mocapfill fill`` gives it (its ``--jobs`` default, 0: every core; ``--fill-jobs`` to choose;
  the table's ``processes``).  The CPU seconds of all its processes are shown too (the machine is shared: wall time
  is inflated by the other load, CPU time less so; with one process they are what one core would take).
- **smooth** (:mod:`mocapfill.evaluation.smoothness`): the largest acceleration (mm / frame^2) of the filled samples
  against the largest observed in the capture, and their 99.9th percentiles; the rule: no filled acceleration above
  the largest observed, and where at least 1,000 samples are filled, the filled 99.9th percentile at most 1.5 x the
  observed one (second differences touching an observed fragment of 1-2 frames between gaps are left out).
  Where a fill fails, the capture's least possible largest filled acceleration is computed too
  (:func:`~mocapfill.evaluation.smoothness.least_max_filled`: a lower bound over every fill that keeps the observed
  samples); where it is above the largest observed, no such fill passes, and the second smooth check leaves the
  capture out (the first, the issue's rule, keeps it).

Results are cached per (file content, method) in ``--cache``; ``--rerun auto`` fills again with the default only.
Writes ``benchmarks/results/bench_default_real.json``.  ``--config JSON`` fills ``auto`` with those
:class:`~mocapfill.methods.auto_config.ModelConfig` fields changed (e.g. ``'{"refit_untrusted": true}'``), cached apart,
and writes no results file unless ``--out`` names one.

Run from the repository root (a single process measures the fills one at a time; keep ``--jobs 1`` for timing)::

    python benchmarks/bench_default_real.py [--methods auto,pca] [--jobs 1] [--rerun auto] [--only kineticstoolkit]
"""

from __future__ import annotations

import harness

harness.pin_blas()

import os  # noqa: E402
import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from dataclasses import fields  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = harness.REPO
machine = harness.machine
from mocapfill.errors import MocapfillError  # noqa: E402
from mocapfill.evaluation.smoothness import (Smoothness, least_max_filled, outcome_mask,  # noqa: E402
                                            outcome_smoothness, smooth_enough)
from mocapfill.io import read  # noqa: E402
from mocapfill.methods import METHODS  # noqa: E402
from mocapfill.pipeline import FillSettings, fill_capture  # noqa: E402
from mocapfill.runtime.blas import single_blas_thread  # noqa: E402
from mocapfill.runtime.executor import can_fork, resolve_jobs  # noqa: E402
from mocapfill.units import length_factor  # noqa: E402

SCRIPT = Path(__file__).name
RESULTS = REPO / "benchmarks" / "results" / f"{Path(__file__).stem}.json"
CACHE = REPO / "benchmarks" / ".cache" / Path(__file__).stem


def _cpu_seconds() -> float:
    """CPU seconds of this process and of its children that have ended (the fill's forked workers)."""
    import resource

    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime


def run_one(task: tuple) -> dict:
    """Fill one capture with one method as ``mocapfill fill`` does; time it and measure its smoothness."""
    path, digest, method, cache, commit, config, fill_jobs = task
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = read(path)
    need = harness.gapped(data)
    to_mm = length_factor(data.units, "mm")
    record = {"file": harness.capture_name(Path(path)), "sha256": digest, "method": method, "commit": commit,
              "date": datetime.date.today().isoformat(), "frames": data.n_frames, "markers": data.n_markers,
              "rate": data.rate, "duration": data.n_frames / data.rate, "units": data.units,
              "missing": float(np.isnan(data.positions).any(axis=2).mean()), "to_fill": int(need.sum()),
              "error": None, "config": config,
              # (a method without ``jobs`` fills in this process, as fill_capture hands it none)
              "processes": resolve_jobs(fill_jobs) if can_fork() and "jobs" in METHODS[method].parameters() else 1}
    cpu0 = _cpu_seconds()
    try:
        with warnings.catch_warnings(), single_blas_thread(), harness.auto_config(config):
            warnings.simplefilter("ignore")
            outcome = fill_capture(data, FillSettings(method=method).check(), jobs=fill_jobs)
    except MocapfillError as exc:
        record["error"] = str(exc)
        _save(cache, record)
        return record
    record["cpu_seconds"] = _cpu_seconds() - cpu0
    record["seconds"] = outcome.seconds
    s = outcome_smoothness(outcome)
    ok, reasons = smooth_enough(s)
    record["smooth"] = s.scaled(to_mm).to_dict()
    record["smooth_ok"] = ok
    record["smooth_reasons"] = [r + " (file units)" for r in reasons]
    if s.worst_marker >= 0:
        record["worst"] = f"{data.labels[s.worst_marker]} @ frame {data.first_frame + s.worst_frame}"
    record["left_missing"] = int((need & np.isnan(outcome.output.positions).any(axis=2)).sum())
    if not ok:  # is any fill that keeps the observed samples smooth enough here?
        missing, points = outcome_mask(outcome)
        least, where_m, where_t = least_max_filled(data.positions, missing, points=points)
        record["least_max_filled"] = least * to_mm
        if where_m >= 0:
            record["least_at"] = f"{data.labels[where_m]}, gap at frame {data.first_frame + where_t}"
    _save(cache, record)
    return record


def only_max_rule_fails(smooth: dict) -> bool:
    """Whether a record's fill (``record["smooth"]``, :meth:`Smoothness.to_dict`) would pass :func:`smooth_enough` if
    its largest filled acceleration were the largest observed: the percentile rule holds."""
    values = {f.name: np.nan if smooth[f.name] is None else smooth[f.name] for f in fields(Smoothness)}
    capped = Smoothness(**{**values, "max_filled": min(values["max_filled"], values["max_observed"])})
    return smooth_enough(capped)[0]


def _cache_file(cache: str | Path, digest: str, method: str, config: dict | None = None) -> Path:
    return Path(cache) / f"{digest[:16]}__{method}{harness.config_tag(config)}.json"


def _save(cache: str | Path, record: dict) -> None:
    path = _cache_file(cache, record["sha256"], record["method"], record.get("config"))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(record))
    os.replace(tmp, path)


def _f(x, digits: int = 2) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{digits}f}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--methods", default="auto,pca", help="comma-separated registered methods")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (1: timing in one process)")
    harness.capture_options(parser, CACHE)
    parser.add_argument("--out", default=str(RESULTS))
    parser.add_argument("--report", action="store_true", help="no fills: tables from the cache")
    parser.add_argument("--config", default="", help="JSON: ModelConfig fields changed for auto")
    parser.add_argument("--fill-jobs", type=int, default=None,
                        help="processes of each fill (default: mocapfill fill's default, 0 = every core)")
    args = parser.parse_args(argv)
    fill_jobs = harness.cli_jobs() if args.fill_jobs is None else args.fill_jobs
    config = json.loads(args.config) if args.config else {}
    if config and args.out == str(RESULTS):  # a variant's figures are not the default's
        print("--config: no results file written unless --out names one", file=sys.stderr)
        args.out = "-"
    methods = [m for m in args.methods.split(",") if m]
    rerun = {m for m in args.rerun.split(",") if m}
    bad = [m for m in [*methods, *rerun] if m not in METHODS]
    if bad:
        raise SystemExit(f"unknown method(s): {', '.join(bad)}; choose from {', '.join(METHODS)}")
    methods += [m for m in rerun if m not in methods]
    command = "python benchmarks/" + SCRIPT + (" " + " ".join(argv if argv is not None else sys.argv[1:])).rstrip()
    print(f"# {SCRIPT} ({machine()})", file=sys.stderr)
    captures, skipped = harness.gapped_captures()
    if args.only:
        captures = [(p, d) for p, d in captures if args.only in str(p)]
    print(f"{len(captures)} captures with gaps; skipped: " + "; ".join(skipped), file=sys.stderr)
    cache = Path(args.cache)

    def cfg(method: str) -> dict:
        return config if method == "auto" else {}

    if not args.report:
        commit = harness.git_commit()
        tasks = [(str(p), d, m, str(cache), commit, cfg(m), fill_jobs) for p, d in captures for m in methods
                 if m in rerun or not _cache_file(cache, d, m, cfg(m)).exists()]
        print(f"{len(tasks)} fill(s) to run on {args.jobs} process(es)", file=sys.stderr, flush=True)
        from mocapfill.runtime.executor import make_executor

        started = time.perf_counter()

        def on_result(task, r: dict | None) -> None:
            if r is None:  # the worker was lost (on_failure said so)
                return
            if r.get("error"):
                print(f"  {r['file']} {r['method']}: FAILED {r['error']}", file=sys.stderr, flush=True)
                return
            print(f"  [{time.perf_counter() - started:.0f} s] {r['file']} {r['method']}: {r['seconds']:.2f} s "
                  f"({r['seconds'] / r['duration']:.2f}x), filled max {_f(r['smooth']['max_filled'])} / observed "
                  f"{_f(r['smooth']['max_observed'])} mm/frame^2", file=sys.stderr, flush=True)

        def on_failure(task, exc: BaseException) -> None:
            print(f"  worker lost ({exc}) on {task[0]} {task[2]}", file=sys.stderr, flush=True)

        make_executor(args.jobs, n_tasks=max(1, len(tasks))).run(run_one, tasks, on_result, on_failure=on_failure)
    rows, missing = [], []
    fails_fast, fails_cpu, fails_smooth, fails_attainable = ({m: [] for m in methods} for _ in range(4))
    worst_ratio = {m: 0.0 for m in methods}
    worst_acc = {m: 0.0 for m in methods}
    for path, digest in captures:
        for m in methods:
            f = _cache_file(cache, digest, m, cfg(m))
            if not f.exists():
                missing.append(f"{harness.capture_name(path)} {m}")
                continue
            r = json.loads(f.read_text())
            if r.get("error"):
                rows.append([r["file"], m, f"{r['frames']} x {r['markers']}", r["rate"], round(r["duration"], 2),
                             round(100 * r["missing"], 1), r["to_fill"], *["-"] * 14, "FAILED: " + r["error"]])
                for fails in (fails_fast, fails_cpu, fails_smooth, fails_attainable):
                    fails[m].append(r["file"])
                continue
            s = r["smooth"]
            bound = harness.speed_bound(r["duration"])
            fast = r["seconds"] <= bound
            ratio = r["seconds"] / r["duration"]
            worst_ratio[m] = max(worst_ratio[m], ratio)
            if s["ratio_max"] is not None:
                worst_acc[m] = max(worst_acc[m], s["ratio_max"])
            if not fast:
                fails_fast[m].append(f"{r['file']} ({ratio:.2f}x, {r['seconds']:.1f} s)")
            if r["cpu_seconds"] > bound:
                fails_cpu[m].append(f"{r['file']} ({r['cpu_seconds'] / r['duration']:.2f}x, {r['cpu_seconds']:.1f} s)")
            note = ""
            if not r["smooth_ok"]:
                fails_smooth[m].append(f"{r['file']} (max {_f(s['max_filled'], 1)} vs {_f(s['max_observed'], 1)}; "
                                       f"p99.9 {_f(s['p_filled'], 1)} vs {_f(s['p_observed'], 1)} mm/frame^2)")
                least = r.get("least_max_filled")
                unattainable = (least is not None and s["max_observed"] is not None and least > s["max_observed"]
                                and only_max_rule_fails(s))
                if unattainable:
                    note = (f"no fill that keeps the observed samples is smooth here: its largest filled acceleration "
                            f"is at least {least:.1f} ({r.get('least_at', '')})")
                else:
                    fails_attainable[m].append(fails_smooth[m][-1])
            rows.append([r["file"], m, f"{r['frames']} x {r['markers']}", round(r["rate"], 2),
                         round(r["duration"], 2), round(100 * r["missing"], 1), s["filled_samples"],
                         round(r["seconds"], 3), r.get("processes", 1), round(r["cpu_seconds"], 3), round(ratio, 3),
                         "PASS" if fast else "FAIL", _f(s["max_observed"]), _f(s["max_filled"]),
                         _f(s["ratio_max"]), _f(s["p_observed"]), _f(s["p_filled"]), _f(s["ratio_percentile"]),
                         "PASS" if r["smooth_ok"] else "FAIL", r.get("worst", ""), r.get("left_missing", 0), note])
    columns = ["capture", "method", "frames x markers", "Hz", "s", "missing %", "filled samples", "fill s",
               "processes", "CPU s", "fill / duration", "fast", "max acc observed", "max acc filled", "ratio",
               "p99.9 observed", "p99.9 filled", "ratio", "smooth", "worst filled at", "left missing", "note"]
    print("\n## Speed and smoothness on the real gapped captures (accelerations in mm / frame^2)")
    print("| " + " | ".join(columns) + " |\n|" + "---|" * len(columns))
    for row in rows:
        print("| " + " | ".join(str(x) for x in row) + " |")
    if missing:
        print(f"\n(not in the cache, left out: {'; '.join(missing)})")
    print("\n## Checks (issue 21)")
    check_rows = []
    for m in methods:
        for what, fails in (("fast: fill <= 0.25 x duration or 1 s", fails_fast[m]),
                            ("fast in CPU seconds (the wall-time bound on the CPU time of all the fill's processes: "
                             "the fill on one core of a quiet machine)", fails_cpu[m]),
                            ("smooth: max filled <= max observed; p99.9 <= 1.5 x where >= 1000 filled",
                             fails_smooth[m]),
                            ("smooth, where a fill that keeps the observed samples can be (the failing captures "
                             "whose least possible largest filled acceleration is below the largest observed)",
                             fails_attainable[m])):
            print(f"{'PASS' if not fails else 'FAIL'}: {m} {what}"
                  + ("" if not fails else f" -- {len(fails)} capture(s): {'; '.join(fails)}"))
            check_rows.append([m, what, "PASS" if not fails else "FAIL", len(fails), "; ".join(fails)])
    figures = {}
    for m in methods:
        figures[f"{m} worst fill / duration"] = {"value": round(worst_ratio[m], 3), "unit": "x", "better": "lower"}
        figures[f"{m} captures failing fast"] = {"value": len(fails_fast[m]), "unit": "captures", "better": "lower"}
        figures[f"{m} captures failing fast (CPU s)"] = {"value": len(fails_cpu[m]), "unit": "captures",
                                                        "better": "lower"}
        figures[f"{m} captures failing smooth"] = {"value": len(fails_smooth[m]), "unit": "captures",
                                                   "better": "lower"}
        figures[f"{m} captures failing smooth where attainable"] = {"value": len(fails_attainable[m]),
                                                                   "unit": "captures", "better": "lower"}
        figures[f"{m} worst max filled / max observed acceleration"] = {"value": round(worst_acc[m], 2), "unit": "x",
                                                                        "better": "lower"}
    results = harness.Results(SCRIPT, command.split()[2:], args.out)
    results.table("captures", "speed and smoothness per capture and method (accelerations in mm / frame^2); skipped: "
                  + "; ".join(skipped), columns, rows)
    results.table("checks", "issue 21's fast and smooth checks", ["method", "check", "result", "failing", "captures"],
                  check_rows)
    for name, f in figures.items():
        results.figure(name, f["value"], f["unit"], f["better"])
    results.write()



if __name__ == "__main__":
    main()
