"""Benchmark of `mocapfill batch`: throughput on 1 and 2 local processes and on a 2-worker Dask LocalCluster, peak
memory per worker, and the time of a re-run over a finished batch (issue #11).

The inputs are 20 real gapped captures (``--files``):
- clean captures from ``../shared/data`` (CMU 85_02, the OptiTrack tennis serve, the BTK sprint TRC, the Vicon
  pyorerun example) with gaps made by the evaluation protocols (:func:`mocapfill.evaluation.make_occlusions`:
  ``marker``, ``limb``, ``random`` without shifts; seeded), written back in their own format;
- the captures with real gaps (the tennis serve's NaN twin, pyomeca's Vicon C3D and CSV, BTK's Codamotion gait,
  pyCGM's Plug-in-Gait trial, Kinetics Toolkit's racing, BTS gait and OptiTrack walking captures).

Runs, each into a fresh folder: ``jobs=1`` (in process), ``jobs=2`` (two worker processes, their start-up counted)
and a 2-worker ``LocalCluster`` on 127.0.0.1 (a fresh one per run, started before the clock; one thread per
worker), ``--repeat`` rounds in alternating order (best time per run counts), then ``jobs=1`` over the finished
serial folder (every file skipped).  Outputs of every filling run are compared byte for byte with the serial run's.
Each run also prints where its time went, summed from the rows: per-file CPU seconds (user + kernel of the task's
thread), kernel seconds, minor page faults, per-file wall seconds, and each worker's idle time (the run's wall time
minus the wall time of its files).  ``--without-malloc-fix`` adds a LocalCluster run whose workers keep the
nanny's ``MALLOC_TRIM_THRESHOLD_`` (:mod:`mocapfill.runtime.malloc`): the cause of the old 0.72x.

Run from the repository root (``pip install ".[dask]"`` for the cluster run)::

    python benchmarks/bench_batch.py [--files 20] [--repeat 3] [--method auto] [--no-dask] [--without-malloc-fix]
        [--keep DIR]

Targets: 2 processes >= 1.6x the throughput of 1; the LocalCluster within 15 % of 2 processes; re-run <= 10 % of
the first run's time.  Throughput needs a quiet machine: the load average is printed before and after.
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import mocapfill  # noqa: E402
from mocapfill.evaluation import make_occlusions  # noqa: E402
from mocapfill.runtime.malloc import KEEP_ENV  # noqa: E402

SHARED = harness.SHARED_DATA

#: Clean captures the protocols make gaps in.
CLEAN = ["cmu/85_02.c3d", "kineticstoolkit/kinematics_tennis_serve.c3d", "btk/TRCSamples/SprintMotion.trc",
         "pyorerun/example.c3d"]
PROTOCOLS = [("marker", {}), ("limb", {}), ("random", {"shift_rate": 0.0})]
#: Captures with real gaps, used as they are.
REAL = ["kineticstoolkit/kinematics_tennis_serve_nan.c3d", "pyomeca/markers_analogs.c3d", "pyomeca/markers.csv",
        "btk/C3DSamples/others/ADemo1_rewrite_c3d_pc_float.c3d", "pycgm/Movement_trial.c3d",
        "kineticstoolkit/kinematics_racing_full.c3d", "kineticstoolkit/c3d_sample.c3d",
        "kineticstoolkit/walkingOptiTrack.c3d"]


def make_inputs(folder: Path, n_files: int, seed: int) -> list[Path]:
    """Write ``n_files`` gapped captures into ``folder`` (real-gap files first, then protocol-gapped clean ones)."""
    made: list[Path] = []
    (folder / "real").mkdir(parents=True, exist_ok=True)
    (folder / "made").mkdir(parents=True, exist_ok=True)
    for rel in REAL:
        if len(made) >= n_files // 2:
            break
        src = SHARED / rel
        shutil.copy(src, folder / "real" / src.name)
        made.append(folder / "real" / src.name)
    for round_ in range(n_files):
        for rel in CLEAN:
            for protocol, extra in PROTOCOLS:
                if len(made) >= n_files:
                    return made
                data = mocapfill.read(SHARED / rel)
                trial = make_occlusions(data, protocol, trials=round_ + 1, seed=seed, **extra)[round_]
                positions, _, _ = trial.apply(data.positions)
                path = folder / "made" / f"{Path(rel).stem}-{protocol}-{round_}{Path(rel).suffix}"
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    mocapfill.write(data.with_positions(positions), path)
                made.append(path)
    return made


def outputs(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in (".c3d", ".csv", ".trc")
            and p.name != "mocapfill-batch.csv"}


def peaks(rows) -> str:
    by_worker: dict[str, float] = {}
    for row in rows:
        if row.worker and row.peak_rss_mb is not None:
            by_worker[row.worker] = max(by_worker.get(row.worker, 0.0), row.peak_rss_mb)
    return ", ".join(f"{mb:.0f} MB" for mb in sorted(by_worker.values(), reverse=True)) or "-"


def accounting(rows, seconds: float) -> str:
    """Where the time went: per-file CPU (kernel, page faults), per-file wall, and each worker's idle time."""
    done = [r for r in rows if r.status != "skipped"]
    if not done or any(r.cpu_seconds is None for r in done):
        return ""
    busy: dict[str, float] = {}
    for r in done:
        busy[r.worker] = busy.get(r.worker, 0.0) + r.seconds
    idle = "/".join(f"{seconds - b:.2f}" for b in sorted(busy.values()))
    return (f"    per-file CPU {sum(r.cpu_seconds for r in done):6.2f} s (kernel {sum(r.kernel_seconds for r in done):5.2f} s, "
            f"{sum(r.page_faults for r in done) / 1e3:5.0f} k page faults), per-file wall "
            f"{sum(r.seconds for r in done):6.2f} s; idle per worker {idle} s")


def timed(label: str, inputs, out: Path, **kwargs):
    if out.exists() and label != RERUN:  # every filling run starts from an empty folder
        shutil.rmtree(out)
    start = time.perf_counter()
    rows = mocapfill.batch(inputs, out, **kwargs)
    seconds = time.perf_counter() - start
    statuses = {s: sum(r.status == s for r in rows) for s in ("filled", "skipped", "failed")}
    print(f"{label:<34} {seconds:7.2f} s  {len(rows) / seconds:7.2f} files/s  "
          f"{statuses['filled']} filled {statuses['skipped']} skipped {statuses['failed']} failed  "
          f"peak RSS per worker: {peaks(rows)}", flush=True)
    line = accounting(rows, seconds)
    if line:
        print(line, flush=True)
    for row in rows:
        if row.status == "failed":
            print(f"    failed: {row.error}")
    return seconds, rows


RERUN = "re-run over jobs=1's"


def cluster_run(label: str, inputs, out: Path, method: str, keep_malloc: bool = False):
    """One batch on a fresh 2-worker LocalCluster (started before the clock).  The nanny writes its
    pre-spawn-environ (MALLOC_TRIM_THRESHOLD_=65536 ...) into this process's environment: restored after, so the
    local runs that follow start their workers as before."""
    from distributed import LocalCluster

    saved = dict(os.environ)
    if keep_malloc:
        os.environ[KEEP_ENV] = "1"  # inherited by the workers: they keep the nanny's malloc thresholds
    try:
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None) as cluster:
            return timed(label, inputs, out, method=method, scheduler=cluster.scheduler_address)
    finally:
        os.environ.clear()
        os.environ.update(saved)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--files", type=int, default=20, help="number of gapped captures (default 20)")
    parser.add_argument("--method", default="auto", help="fill method (default auto)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=3,
                        help="rounds of every filling run, in alternating order; the best time counts (default 3)")
    parser.add_argument("--no-dask", action="store_true", help="skip the LocalCluster runs")
    parser.add_argument("--without-malloc-fix", action="store_true",
                        help="also run the LocalCluster with the workers' own malloc thresholds (the cause of the "
                             "old 0.72x)")
    parser.add_argument("--keep", type=Path, default=None, help="work in this folder and keep it")
    harness.add_results_argument(parser)
    args = parser.parse_args()
    if not SHARED.is_dir():
        print(f"needs {SHARED}", file=sys.stderr)
        return 2

    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_batch_"))
    if work.exists() and args.keep:
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    harness.banner(__file__)
    inputs = make_inputs(work / "in", args.files, args.seed)
    sizes = [mocapfill.read(p) for p in inputs]
    print(f"{len(inputs)} inputs, {sum(d.n_frames for d in sizes)} frames, "
          f"{sum(int(d.missing.sum()) for d in sizes)} missing samples; method {args.method}")
    del sizes

    dask = not args.no_dask
    if dask:
        try:
            import distributed
        except ImportError:
            print("LocalCluster runs skipped: pip install 'mocapfill[dask]'")
            dask = False
        else:
            print(f"dask distributed {distributed.__version__}; LocalCluster(n_workers=2, threads_per_worker=1, "
                  "processes=True), started before the clock")
    runs = {"jobs=1 (in process)": lambda out: timed("jobs=1 (in process)", work / "in", out, method=args.method,
                                                     jobs=1),
            "jobs=2 (processes)": lambda out: timed("jobs=2 (processes)", work / "in", out, method=args.method,
                                                    jobs=2)}
    if dask:
        runs["LocalCluster, 2 workers"] = lambda out: cluster_run("LocalCluster, 2 workers", work / "in", out,
                                                                  args.method)
        if args.without_malloc_fix:
            runs["LocalCluster, malloc fix off"] = lambda out: cluster_run(
                "LocalCluster, malloc fix off", work / "in", out, args.method, keep_malloc=True)
    best: dict[str, tuple[float, list]] = {}
    reference = None
    same = True
    for round_ in range(max(1, args.repeat)):
        order = list(runs) if round_ % 2 == 0 else list(runs)[::-1]
        print(f"round {round_ + 1} of {max(1, args.repeat)} (load {os.getloadavg()[0]:.2f})", flush=True)
        for label in order:
            out = work / f"out-{list(runs).index(label)}"
            seconds, rows = runs[label](out)
            produced = outputs(out)
            if reference is None and label.startswith("jobs=1"):
                reference = produced
                shutil.copytree(out, work / "out-serial")
            elif reference is not None:
                same = same and produced == reference
            if label not in best or seconds < best[label][0]:
                best[label] = (seconds, rows)
    if reference is None:  # pragma: no cover - jobs=1 always runs
        return 1
    # Every run was compared with the first serial run once it existed; compare the earlier ones now.
    for label in runs:
        same = same and outputs(work / f"out-{list(runs).index(label)}") == reference

    print(f"best of {max(1, args.repeat)} per run:")
    for label, (seconds, rows) in best.items():
        print(f"  {label:<32} {seconds:7.2f} s  {len(rows) / seconds:6.2f} files/s")
    t1, rows1 = best["jobs=1 (in process)"]
    costs = sorted((row.seconds for row in rows1), reverse=True)
    loads = [0.0, 0.0]
    for cost in costs:  # largest first onto the less loaded worker: what 2 workers can do at best
        loads[loads.index(min(loads))] += cost
    print(f"    per-file seconds (best jobs=1): sum {sum(costs):.2f}, largest {costs[0]:.2f} "
          f"({100 * costs[0] / sum(costs):.0f} %); the best split over 2 workers gives "
          f"{sum(costs) / max(loads):.2f}x", flush=True)
    tr, _ = timed(RERUN, work / "in", work / "out-serial", method=args.method, jobs=1)

    t2 = best["jobs=2 (processes)"][0]
    print(f"outputs of every run byte-identical to jobs=1: {same}")
    print(f"2 processes: {t1 / t2:.2f}x the throughput of 1 (target >= 1.6)")
    if "LocalCluster, 2 workers" in best:
        tc = best["LocalCluster, 2 workers"][0]
        print(f"LocalCluster: {t2 / tc:.2f}x the throughput of 2 processes ({100 * (tc - t2) / t2:+.1f} % time; "
              "target within 15 %)")
    if "LocalCluster, malloc fix off" in best:
        tn = best["LocalCluster, malloc fix off"][0]
        print(f"LocalCluster with the workers' own malloc thresholds: {t2 / tn:.2f}x the throughput of 2 processes")
    print(f"re-run: {100 * tr / t1:.1f} % of the first run's time (target <= 10 %)")
    results = harness.Results(__file__, path=args.results, note=args.note)
    results.table("runs", f"{len(rows1)} inputs, method {args.method}; best of {max(1, args.repeat)} rounds per run",
                  ["run", "seconds", "files per second"],
                  [[label, round(seconds, 2), round(len(rows) / seconds, 2)] for label, (seconds, rows) in best.items()]
                  + [[RERUN, round(tr, 2), round(len(rows1) / tr, 2)]])
    results.figure("processes_2_speedup", round(t1 / t2, 2), "x the throughput of 1", "higher")
    if "LocalCluster, 2 workers" in best:
        results.figure("localcluster_vs_processes", round(t2 / tc, 2), "x the throughput of 2 processes", "higher")
    results.figure("rerun_share", round(100 * tr / t1, 1), "% of the first run's time")
    results.write()
    print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
