"""Issue 21, "never behind the plain methods", on the real captures with gaps: hide more, score what was hidden.

The accuracy benchmarks run on complete clips with gaps drawn at random.  A user's captures already have gaps, often
everywhere, and that is where the default must hold too.  For every capture of ``bench_default_real.py`` (every real
capture with gaps under ``sample_data/``, ``tests/data/`` and ``../shared/data``, read as ``mocapfill fill`` reads it;
its marker points only) and each of ``--draws`` seeded draws, the ``dense`` protocol hides ``--missing`` (5 %) of
the samples in random single-marker gaps of 0.25-2 s, on top of the real gaps (only samples that were observed count
as hidden; a sample hidden in one exact copy of a marker is hidden in every copy and scored once, as ``evaluate``
hides them); each ``--methods`` fills the result and is scored on the hidden samples: the RMSE of the 3-D error (mm),
per draw, and pooled over the draws.

Tables: per capture and method the pooled RMSE and the draws'; per method the median over captures of the pooled
RMSE and how many captures each method is best on; the check that the default's pooled RMSE is at most ``pca``'s and
``bolero-sc``'s on every capture.  Results are cached per (file content, method, draw) in ``--cache``; ``--rerun
auto`` fills again with the default only.

``--config JSON`` fills ``auto`` with those :class:`~mocapfill.methods.auto_config.ModelConfig` fields changed (e.g.
``'{"seed_where_no_refit": true}'``), cached apart from the default's.

Run from the repository root (``--jobs 2``: a draw per worker; nothing here is timed)::

    python benchmarks/bench_real_hidden.py [--methods auto,pca,bolero-sc] [--draws 3] [--jobs 2] [--rerun auto]
        [--config JSON]
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from mocapfill import fill  # noqa: E402
from mocapfill.errors import MocapfillError  # noqa: E402
from mocapfill.evaluation.occlusions import make_occlusions  # noqa: E402
from mocapfill.evaluation.runner import copies_hidden_together  # noqa: E402
from mocapfill.io import read  # noqa: E402
from mocapfill.pipeline import fill_columns, subset  # noqa: E402
from mocapfill.runtime.executor import make_executor  # noqa: E402
from mocapfill.units import length_factor  # noqa: E402

SCRIPT = Path(__file__).name
RESULTS = harness.REPO / "benchmarks" / "results" / f"{Path(__file__).stem}.json"
CACHE = harness.REPO / "benchmarks" / ".cache" / Path(__file__).stem


def hidden_draw(data, draw: int, missing: float) -> tuple[np.ndarray, np.ndarray]:
    """The observed samples of ``data`` (its marker points) that draw ``draw`` hides, and those it scores, each
    (n_frames, n_markers) bool.  A sample hidden in one exact copy of a marker (an export that writes a trajectory
    several times) is hidden in all of them and scored once, as ``evaluate`` does
    (:func:`~mocapfill.evaluation.runner.copies_hidden_together`): its twin would give it away."""
    trial = make_occlusions(data, "dense", trials=1, seed=draw, missing=missing)[0]
    observed = ~np.isnan(data.positions).any(axis=2)
    hidden = trial.hidden_mask(data.n_frames, data.n_markers) & observed
    cut = data.positions.copy()
    cut[hidden] = np.nan
    cut, scored, _ = copies_hidden_together(data.positions, cut, hidden, np.zeros_like(hidden))
    return np.isnan(cut).any(axis=2) & observed, scored


def run_one(task: tuple) -> dict:
    """Fill one draw of one capture with one method; the RMSE (mm) over the hidden samples."""
    path, digest, method, draw, missing, cache, config = task
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = read(path)
        data = subset(data, fill_columns(data))
        hidden, scored = hidden_draw(data, draw, missing)
        cut = data.positions.copy()
        cut[hidden] = np.nan
        record = {"file": harness.capture_name(Path(path)), "sha256": digest, "method": method, "draw": draw,
                  "missing": missing, "hidden": int(scored.sum()), "error": None}
        try:
            options = {}
            if method == "auto" and config:
                from mocapfill.methods.auto_config import ModelConfig

                options["config"] = ModelConfig(**config)
            out = fill(data.with_positions(cut), method, **options)
        except MocapfillError as exc:
            record["error"] = str(exc)
        else:
            err = np.linalg.norm(out.positions[scored] - data.positions[scored], axis=1) * length_factor(data.units,
                                                                                                     "mm")
            record["unfilled"] = int(np.isnan(err).sum())
            record["sq_sum"] = float(np.nansum(err ** 2))
            record["rmse"] = float(np.sqrt(np.nanmean(err ** 2))) if np.isfinite(err).any() else None
    record["config"] = config if method == "auto" else {}
    _cache_file(cache, digest, method, draw, missing, record["config"]).write_text(json.dumps(record))
    return record


def _cache_file(cache, digest: str, method: str, draw: int, missing: float, config: dict | None = None) -> Path:
    Path(cache).mkdir(parents=True, exist_ok=True)
    # ("_c": copies hidden together; a record from before that rule is not read)
    return Path(cache) / f"{digest[:16]}_{method}{harness.config_tag(config)}_{draw}_{missing:g}_c.json"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--methods", default="auto,pca,bolero-sc", help="comma-separated registered methods")
    parser.add_argument("--draws", type=int, default=3)
    parser.add_argument("--missing", type=float, default=0.05, help="share of the samples the dense draw hides")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    harness.capture_options(parser, CACHE)
    parser.add_argument("--results", default=str(RESULTS))
    parser.add_argument("--config", default="", help="JSON: ModelConfig fields changed for auto")
    args = parser.parse_args(argv)
    harness.banner(SCRIPT, file=sys.stderr)
    methods = [m for m in args.methods.split(",") if m]
    config = json.loads(args.config) if args.config else {}
    if config and args.results == str(RESULTS):  # a variant's figures are not the default's
        print("--config: no results file written unless --results names one", file=sys.stderr)
        args.results = "-"
    rerun = set(m for m in args.rerun.split(",") if m)
    captures, _ = harness.gapped_captures()
    captures = [c for c in captures if args.only in harness.capture_name(c[0])]
    tasks, records = [], {}
    for path, digest in captures:
        for method in methods:
            for draw in range(args.draws):
                f = _cache_file(args.cache, digest, method, draw, args.missing, config if method == "auto" else None)
                if f.exists() and method not in rerun:
                    records[(digest, method, draw)] = json.loads(f.read_text())
                else:
                    tasks.append((str(path), digest, method, draw, args.missing, args.cache, config))
    print(f"{len(captures)} captures, {len(tasks)} fills to run ({len(records)} cached)", file=sys.stderr)

    def done(task, record):
        records[(task[1], task[2], task[3])] = record
        print(f"  {record['file']} {record['method']} draw {record['draw']}: "
              f"{record.get('rmse') if record['error'] is None else record['error']}", file=sys.stderr, flush=True)

    make_executor(args.jobs, n_tasks=len(tasks)).run(run_one, tasks, done, on_failure=lambda t, e: {
        "file": harness.capture_name(Path(t[0])), "method": t[2], "draw": t[3], "error": f"worker lost: {e}"})

    rows, pooled = [], {m: {} for m in methods}
    for path, digest in captures:
        name = harness.capture_name(path)
        for method in methods:
            recs = [records.get((digest, method, d)) for d in range(args.draws)]
            ok = [r for r in recs if r and r.get("error") is None and r.get("rmse") is not None]
            if len(ok) < args.draws:
                rows.append([name, method, None, "failed or unfilled" if any(recs) else "-", None])
                continue
            total = sum(r["sq_sum"] for r in ok) / max(sum(r["hidden"] - r["unfilled"] for r in ok), 1)
            pooled[method][name] = float(np.sqrt(total))
            rows.append([name, method, round(pooled[method][name], 2),
                         " / ".join(f"{r['rmse']:.1f}" for r in ok), sum(r["unfilled"] for r in ok)])
    summary, checks = [], []
    names = [harness.capture_name(p) for p, _ in captures]
    scored = [n for n in names if all(n in pooled[m] for m in methods)]
    for method in methods:
        vals = [pooled[method][n] for n in scored]
        best = sum(1 for n in scored if pooled[method][n] <= min(pooled[m][n] for m in methods))
        summary.append([method, round(float(np.median(vals)), 2) if vals else None,
                        round(float(np.mean(vals)), 2) if vals else None, best, len(scored)])
    default = methods[0]
    for peer in methods[1:]:
        behind = [f"{n} ({pooled[default][n]:.1f} > {pooled[peer][n]:.1f})" for n in scored
                  if pooled[default][n] > pooled[peer][n]]
        checks.append([f"pooled RMSE of {default} <= {peer}'s on every capture", "PASS" if not behind else "FAIL",
                       len(behind), "; ".join(behind)])
    print(f"\n{'capture':60s} {'method':10s} {'pooled':>8s}  draws", file=sys.stderr)
    for r in rows:
        print(f"{r[0][-60:]:60s} {r[1]:10s} {r[2] if r[2] is not None else '-':>8}  {r[3]}", file=sys.stderr)
    for r in summary:
        print(f"{r[0]:10s} median over captures {r[1]}  mean {r[2]}  best on {r[3]} of {r[4]}", file=sys.stderr)
    for c in checks:
        print(f"{c[1]}  {c[0]}  {c[3]}", file=sys.stderr)
    results = harness.Results(SCRIPT, argv, args.results)
    results.table("captures", f"RMSE (mm) over the samples hidden on top of each capture's real gaps (dense, "
                  f"{args.missing:.0%} of the samples, {args.draws} seeded draws), pooled over the draws and per draw",
                  ["capture", "method", "pooled RMSE", "RMSE per draw", "hidden samples left unfilled"], rows)
    results.table("summary", "per method: the pooled RMSE's median and mean over the captures every method filled, "
                  "and on how many it is the lowest", ["method", "median", "mean", "best on", "captures"], summary)
    results.table("checks", "the default against the plain methods, capture by capture",
                  ["check", "result", "failing", "captures"], checks)
    for r in summary:
        results.figure(f"{r[0]} median pooled RMSE over captures", r[1], "mm", "lower")
    results.write()


if __name__ == "__main__":
    main()
