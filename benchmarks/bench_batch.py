"""Benchmark of `mocapfill batch`: throughput on 1 and 2 local processes and on a 2-worker Dask LocalCluster, peak
memory per worker, and the time of a re-run over a finished batch (issue #11).

The inputs are 20 real gapped captures (``--files``):
- clean captures from ``../shared/data`` (CMU 85_02, the OptiTrack tennis serve, the BTK sprint TRC, the Vicon
  pyorerun example) with gaps made by the evaluation protocols (:func:`mocapfill.evaluation.make_occlusions`:
  ``marker``, ``limb``, ``random`` without shifts; seeded), written back in their own format;
- the captures with real gaps (the tennis serve's NaN twin, pyomeca's Vicon C3D and CSV, BTK's Codamotion gait,
  pyCGM's Plug-in-Gait trial, Kinetics Toolkit's racing, BTS gait and OptiTrack walking captures).

Runs, each into a fresh folder: ``jobs=1`` (in process), ``jobs=2`` (two worker processes, their start-up counted),
a 2-worker ``LocalCluster`` on 127.0.0.1 (started before the clock; one thread per worker), then ``jobs=1`` again
over the finished first folder (every file skipped).  Outputs of the three filling runs are compared byte for byte.

Run from the repository root (``pip install ".[dask]"`` for the cluster run)::

    python benchmarks/bench_batch.py [--files 20] [--method auto] [--no-dask] [--keep DIR]

Targets: 2 processes >= 1.6x the throughput of 1; the LocalCluster within 15 % of 2 processes; re-run <= 10 % of
the first run's time.  Throughput needs a quiet machine: the load average is printed before and after.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import mocapfill  # noqa: E402
from mocapfill.evaluation import make_occlusions  # noqa: E402

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"

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


def timed(label: str, inputs, out: Path, **kwargs):
    start = time.perf_counter()
    rows = mocapfill.batch(inputs, out, **kwargs)
    seconds = time.perf_counter() - start
    statuses = {s: sum(r.status == s for r in rows) for s in ("filled", "skipped", "failed")}
    print(f"{label:<26} {seconds:8.2f} s  {len(rows) / seconds:7.2f} files/s  "
          f"{statuses['filled']} filled {statuses['skipped']} skipped {statuses['failed']} failed  "
          f"peak RSS per worker: {peaks(rows)}", flush=True)
    for row in rows:
        if row.status == "failed":
            print(f"    failed: {row.error}")
    return seconds, rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--files", type=int, default=20, help="number of gapped captures (default 20)")
    parser.add_argument("--method", default="auto", help="fill method (default auto)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-dask", action="store_true", help="skip the LocalCluster run")
    parser.add_argument("--keep", type=Path, default=None, help="work in this folder and keep it")
    args = parser.parse_args()
    if not SHARED.is_dir():
        print(f"needs {SHARED}", file=sys.stderr)
        return 2

    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_batch_"))
    if work.exists() and args.keep:
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    print(f"{platform.machine()}, {os.cpu_count()} CPUs, load {' '.join(f'{x:.2f}' for x in os.getloadavg())}, "
          f"python {platform.python_version()}, numpy {np.__version__}, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    inputs = make_inputs(work / "in", args.files, args.seed)
    sizes = [mocapfill.read(p) for p in inputs]
    print(f"{len(inputs)} inputs, {sum(d.n_frames for d in sizes)} frames, "
          f"{sum(int(d.missing.sum()) for d in sizes)} missing samples; method {args.method}")
    del sizes

    t1, rows1 = timed("jobs=1 (in process)", work / "in", work / "out1", method=args.method, jobs=1)
    costs = sorted((row.seconds for row in rows1), reverse=True)
    loads = [0.0, 0.0]
    for cost in costs:  # largest first onto the less loaded worker: what 2 workers can do at best
        loads[loads.index(min(loads))] += cost
    print(f"    per-file seconds (jobs=1): sum {sum(costs):.2f}, largest {costs[0]:.2f} "
          f"({100 * costs[0] / sum(costs):.0f} %); the best split over 2 workers gives "
          f"{sum(costs) / max(loads):.2f}x", flush=True)
    t2, _ = timed("jobs=2 (processes)", work / "in", work / "out2", method=args.method, jobs=2)
    results = {"speed-up 2 processes / 1": t1 / t2}
    same = outputs(work / "out2") == outputs(work / "out1")
    tc = None
    if not args.no_dask:
        try:
            from distributed import LocalCluster
        except ImportError:
            print("LocalCluster run skipped: pip install 'mocapfill[dask]'")
        else:
            start = time.perf_counter()
            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=None) as cluster:
                print(f"LocalCluster of 2 workers up in {time.perf_counter() - start:.2f} s (not counted)")
                tc, _ = timed("LocalCluster, 2 workers", work / "in", work / "out3", method=args.method,
                              scheduler=cluster.scheduler_address)
            same = same and outputs(work / "out3") == outputs(work / "out1")
    tr, _ = timed("re-run over jobs=1's", work / "in", work / "out1", method=args.method, jobs=1)

    print(f"outputs of every run byte-identical to jobs=1: {same}")
    print(f"2 processes: {t1 / t2:.2f}x the throughput of 1 (target >= 1.6)")
    if tc is not None:
        print(f"LocalCluster: {t2 / tc:.2f}x the throughput of 2 processes ({100 * (tc - t2) / t2:+.1f} % time; "
              "target within 15 %)")
    print(f"re-run: {100 * tr / t1:.1f} % of the first run's time (target <= 10 %)")
    print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
