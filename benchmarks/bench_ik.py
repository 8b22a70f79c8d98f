"""Benchmark of issue 24: what the fill methods do to joint angles (OpenSim inverse kinematics), and the kinematic fill.

Data: the public example pipelines of opensim-org/opensim-models (no license file: fetched, never committed).
Get them with ``git clone --depth 1 https://github.com/opensim-org/opensim-models`` and pass ``--models`` (or set
``OPENSIM_MODELS``).  Two captures of different subjects and studies:

- ``gait2354``: ``Pipelines/Gait2354_Simbody/subject01_walk1.trc`` (walking, 41 markers, 151 frames at 60 Hz) with
  ``OutputReference/subject01_simbody.osim`` (scaled gait2354, 23 coordinates) and ``subject01_Setup_IK.xml``.
  ``Pipelines/Gait10dof18musc/ExperimentalData/subject01_walk.trc`` (and Gait2392's) is byte-identical to it: the
  same capture, so it is not a second trial.
- ``hamner``: ``Pipelines/Hamner/subject02_running.trc`` (running, another subject and lab, 41 markers, 600
  frames at 60 Hz), its first 100 frames (``--frames``; IK of the full-body model costs ~60 ms a frame on the
  shared machine) with ``outputReference/subject02_registered.osim`` (37 coordinates, 26 rotational unlocked) and
  ``Setup_IK.xml``.

Each setup is used with its tasks, weights, constraint weight and accuracy, its model given absolutely, and its time
range set to the whole (cropped) capture.  Protocols ``dense`` 10 % and 20 % and ``segment`` (defaults), ``--trials``
seeded draws each; per draw every method fills, OpenSim IK runs on each fill, on the capture with the hidden
markers left missing (empty TRC cells) and once on the complete capture.  Errors per coordinate: RMSE over the
frames with a hidden sample; per draw the median and worst rotational coordinate (degrees); then the median over
draws.  Also: the kinematic fill's mm and degree errors, IK time per trial, wall time of one evaluation on 2 worker
processes against 1, and TRC fidelity (IK on the original TRC against IK on mocapfill's rewrite).

Run from the repository root (CPU-heavy; debug with ``--trials 1 --methods linear,opensim-ik --protocols dense10``)::

    python benchmarks/bench_ik.py --models /path/to/opensim-models [--trials 3] [--jobs 2] \
        [--frames gait2354=150,hamner=100] [--captures gait2354] [--out part.json]
    python benchmarks/bench_ik.py --merge part1.json part2.json     (one capture per process, then one file)

Writes ``benchmarks/results/bench_ik.json``.
"""

from __future__ import annotations

import os

import harness

harness.pin_blas()

import argparse  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]

from mocapfill import evaluate, read  # noqa: E402
from mocapfill.markers import MarkerData  # noqa: E402
from mocapfill.methods import METHODS  # noqa: E402

CAPTURES = {
    "gait2354": ("Pipelines/Gait2354_Simbody/subject01_walk1.trc",
                 "Pipelines/Gait2354_Simbody/OutputReference/subject01_simbody.osim",
                 "Pipelines/Gait2354_Simbody/subject01_Setup_IK.xml"),
    "hamner": ("Pipelines/Hamner/subject02_running.trc",
               "Pipelines/Hamner/outputReference/subject02_registered.osim",
               "Pipelines/Hamner/Setup_IK.xml"),
}
PROTOCOLS = {"dense10": ("dense", {"missing": 0.1}), "dense20": ("dense", {"missing": 0.2}),
             "segment": ("segment", {})}


def setup_copy(setup: Path, model: Path, n_frames: int, rate: float, folder: str) -> str:
    """The setup with its model absolute and its time range the whole capture (written into ``folder``)."""
    text = setup.read_text(encoding="utf-8", errors="replace")
    text = re.sub(r"<model_file>.*?</model_file>", f"<model_file>{model}</model_file>", text, flags=re.S)
    text = re.sub(r"<time_range>.*?</time_range>", f"<time_range>0 {(n_frames - 1) / rate!r}</time_range>", text,
                  flags=re.S)
    out = Path(folder) / setup.name
    out.write_text(text, encoding="utf-8")
    return str(out)


def trc_fidelity(trc: Path, setup: str, data: MarkerData) -> float:
    """Largest |difference| (degrees or model units) between IK on the original TRC and on mocapfill's rewrite."""
    from mocapfill.kinematics.opensim_ik import load_setup, quiet, read_mot, require_opensim, run_ik

    osim = require_opensim()
    ik = load_setup(setup)
    ours = run_ik(ik, data)
    with tempfile.TemporaryDirectory() as tmp, quiet(osim):
        tool = osim.InverseKinematicsTool(setup)
        model = osim.Model(ik.model)  # the tool does not own it: keep a reference while it runs
        tool.setModel(model)
        tool.set_marker_file(str(trc))
        tool.setStartTime(0.0)
        tool.setEndTime((data.n_frames - 1) / data.rate)
        tool.set_output_motion_file(os.path.join(tmp, "o.mot"))
        tool.setResultsDir(tmp)
        tool.set_report_errors(False)
        tool.run()
        names, table = read_mot(os.path.join(tmp, "o.mot"))
    n = min(len(table), len(ours.values))
    rot = [c for c, k in enumerate(ours.kinds) if k == "rotational"]
    cols = [names.index(ours.names[c]) for c in rot]
    return float(np.max(np.abs(table[:n, cols] - ours.values[:n, rot])))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default=str(harness.OPENSIM_MODELS),
                        help="a copy of opensim-org/opensim-models (its Pipelines/ folder is read)")
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--seed", type=int, default=24)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--frames", default="gait2354=150,hamner=100",
                        help="frames of each capture used, from the first (NAME=N,...)")
    parser.add_argument("--methods", default="all")
    parser.add_argument("--protocols", default=",".join(PROTOCOLS))
    parser.add_argument("--captures", default=",".join(CAPTURES))
    parser.add_argument("--no-timing", action="store_true", help="skip the 1-vs-2 worker wall-time run")
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "bench_ik.json"))
    parser.add_argument("--rescore-left", default=None, metavar="JSON",
                        help="re-run the left-missing baseline of the draws where its IK failed in this results file "
                             "(before the TRC writer's last-column fix), replaying their occlusions; rewrite --out")
    parser.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                        help="combine the results files of earlier runs (e.g. one capture each) into --out")
    args = parser.parse_args()
    if args.merge:
        merge(args.merge, args.out)
        return
    frames = {k: int(v) for k, v in (item.split("=") for item in args.frames.split(","))}
    if args.rescore_left:
        rescore_left(args.rescore_left, args.out, Path(args.models), frames)
        return
    methods = list(METHODS) if args.methods == "all" else args.methods.split(",")
    root = Path(args.models)
    tables_rows, check_rows, kin_rows, time_rows = [], [], [], []
    figures: dict[str, dict] = {}
    raw: dict[str, dict] = {}
    tmp = tempfile.mkdtemp(prefix="bench-ik-")
    for name in args.captures.split(","):
        trc, model, setup = (root / p for p in CAPTURES[name])
        full = read(str(trc))
        n = min(frames.get(name, full.n_frames), full.n_frames)
        data = MarkerData(full.positions[:n].copy(), list(full.labels), full.rate, full.units, full.first_frame,
                          path=f"{name}:{trc.name}[:{n}]")
        setup_path = setup_copy(setup, model, n, data.rate, tmp)
        fidelity = trc_fidelity(trc, setup_path, data)
        figures[f"{name}_trc_fidelity"] = {"value": fidelity, "unit": "deg", "better": "lower"}
        print(f"{name}: {data.n_markers} markers, {n} frames at {data.rate:g} Hz, {100 * data.missing.mean():.2f} % "
              f"missing; IK on the original TRC vs mocapfill's rewrite: max {fidelity:.2g} deg", flush=True)
        for proto in args.protocols.split(","):
            protocol, options = PROTOCOLS[proto]
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                result = evaluate(data, methods, protocol, trials=args.trials, seed=args.seed, jobs=args.jobs,
                                  ik=setup_path, ik_model=str(model), **options)
            wall = time.perf_counter() - t0
            summ = result.summary()
            left = result.left_missing_summary()
            raw[f"{name}/{proto}"] = result.to_dict()
            print(f"\n{name} {proto}: {wall:.0f} s wall ({args.jobs} jobs); truth IK {result.ik['truth_seconds']:.1f} s",
                  flush=True)
            print(f"  {'method':14s} {'deg med':>8s} {'deg worst':>9s} {'mm RMSE':>8s} {'fails':>5s}")
            for m in methods + ["(left missing)"]:
                row = left if m == "(left missing)" else summ[m]
                med, worst = row["angle_median"]["median"], row["angle_worst"]["median"]
                mm = None if m == "(left missing)" else row["rmse"]["median"]
                fails = "" if m == "(left missing)" else str(row["failures"])
                print(f"  {m:14s} {med if med is not None else float('nan'):8.2f} "
                      f"{worst if worst is not None else float('nan'):9.2f} "
                      f"{mm if mm is not None else float('nan'):8.1f} {fails:>5s}", flush=True)
                tables_rows.append([name, proto, m, med, worst, mm])
            a_med = summ["auto"]["angle_median"]["median"] if "auto" in summ else None
            a_worst = summ["auto"]["angle_worst"]["median"] if "auto" in summ else None
            if a_med is not None:
                ok = (a_worst <= left["angle_worst"]["median"]) and (a_med < left["angle_median"]["median"])
                check_rows.append([name, proto, a_med, left["angle_median"]["median"], a_worst,
                                   left["angle_worst"]["median"], "yes" if ok else "NO"])
            if "opensim-ik" in summ:
                k = summ["opensim-ik"]
                kin_rows.append([name, proto, k["rmse"]["median"], k["angle_median"]["median"],
                                 k["angle_worst"]["median"], k["error_ratio"]["median"],
                                 result.best_for_angles(), result.ranking("rmse", "median")[0]])
            ik_times = [s.ik_seconds for s in result.scores if np.isfinite(s.ik_seconds)]
            time_rows.append([name, proto, n, result.ik["truth_seconds"], float(np.median(ik_times)) if ik_times
                              else None, wall])
            write(args, tables_rows, check_rows, kin_rows, time_rows, figures, raw)  # after each protocol
    if not args.no_timing:
        name = args.captures.split(",")[0]
        trc, model, setup = (root / p for p in CAPTURES[name])
        full = read(str(trc))
        n = min(frames.get(name, full.n_frames), full.n_frames)
        data = MarkerData(full.positions[:n].copy(), list(full.labels), full.rate, full.units, full.first_frame)
        setup_path = setup_copy(setup, model, n, data.rate, tmp)
        walls = {}
        for jobs in (1, 2):
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                evaluate(data, ["linear", "pca", "opensim-ik"], "dense", trials=4, seed=1, jobs=jobs,
                         ik=setup_path, ik_model=str(model), missing=0.1)
            walls[jobs] = time.perf_counter() - t0
            print(f"timing: {name} dense 10 %, 4 trials, linear + pca + opensim-ik, jobs={jobs}: {walls[jobs]:.1f} s",
                  flush=True)
        figures["wall_1_job_s"] = {"value": walls[1], "unit": "s", "better": "lower"}
        figures["wall_2_jobs_s"] = {"value": walls[2], "unit": "s", "better": "lower"}
        figures["speedup_2_jobs"] = {"value": walls[1] / walls[2], "unit": "x", "better": "higher"}
    write(args, tables_rows, check_rows, kin_rows, time_rows, figures, raw)
    print(f"\nwritten {args.out}")


def write(args, tables_rows, check_rows, kin_rows, time_rows, figures, raw) -> None:
    """The results file (benchmarks/results/bench_ik.json layout)."""
    figures = dict(figures)
    for row in check_rows:
        figures[f"{row[0]}_{row[1]}_auto_angle_median_deg"] = {"value": row[2], "unit": "deg", "better": "lower"}
        figures[f"{row[0]}_{row[1]}_left_missing_angle_median_deg"] = {"value": row[3], "unit": "deg",
                                                                       "better": "lower"}
    run = harness.Results(__file__, path=args.out)  # the header every results file shares; tables written here
    out = {
        "script": run.script,
        "command": run.command,
        "machine": run.machine,
        "date": run.date,
        "tables": {
            "angles": {"title": "joint-angle errors (deg; median over draws of the median / worst rotational "
                                "coordinate, RMSE over frames with a hidden sample) and mm RMSE (median over draws)",
                       "columns": ["capture", "protocol", "method", "deg median coord", "deg worst coord",
                                   "mm RMSE"], "rows": tables_rows},
            "default_vs_left_missing": {"title": "auto against leaving the markers missing (medians over draws)",
                                        "columns": ["capture", "protocol", "auto median", "left median",
                                                    "auto worst", "left worst", "auto <= left"],
                                        "rows": check_rows},
            "kinematic_fill": {"title": "opensim-ik: mm and degree errors (medians over draws)",
                               "columns": ["capture", "protocol", "mm RMSE", "deg median", "deg worst", "err/std",
                                           "best for angles", "best by mm"], "rows": kin_rows},
            "ik_time": {"title": "IK time per run (s) and evaluation wall time (s)",
                        "columns": ["capture", "protocol", "frames", "truth IK s", "median IK s per fill",
                                    "evaluation wall s"], "rows": time_rows},
        },
        "figures": figures,
        "evaluations": raw,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1, allow_nan=False, default=lambda o: None) + "\n")


def rescore_left(path: str, out_path: str, root: Path, frames: dict[str, int]) -> None:
    """Re-run, with the current TRC writer, the left-missing IK of every draw where it failed; rebuild the tables'
    left-missing rows and the default-vs-left check from the patched evaluations."""
    from mocapfill.evaluation import trials_from_spec
    from mocapfill.kinematics.angles import coordinate_errors, summarise_errors
    from mocapfill.kinematics.opensim_ik import load_setup, run_ik

    out = json.loads(Path(path).read_text())
    tmp = tempfile.mkdtemp(prefix="bench-ik-")
    rescored = []
    for key, ev in out["evaluations"].items():
        name, proto = key.split("/")
        failed = [t for t, rec in enumerate(ev["trials"]) if rec["left_missing"]["angle_median"] is None]
        if not failed:
            continue
        trc, model, setup = (root / p for p in CAPTURES[name])
        full = read(str(trc))
        n = min(frames.get(name, full.n_frames), full.n_frames)
        data = MarkerData(full.positions[:n].copy(), list(full.labels), full.rate, full.units, full.first_frame)
        ik = load_setup(setup_copy(setup, model, n, data.rate, tmp))
        truth = run_ik(ik, data)
        kinds = dict(zip(truth.names, truth.kinds))
        trials = trials_from_spec(ev, data)
        for t in failed:
            corrupted, hidden, shifted = trials[t].apply(data.positions)
            angles = run_ik(ik, data.with_positions(corrupted))
            errors = coordinate_errors(truth, angles, (hidden | shifted).any(axis=1))
            summ = summarise_errors(errors, kinds)
            ev["trials"][t]["left_missing"].update(
                angle_median=summ["rotational"]["median"], angle_worst=summ["rotational"]["worst"],
                translation_median=summ["translational"]["median"], translation_worst=summ["translational"]["worst"],
                ik_seconds=angles.seconds, ik_errors=errors,
                warnings=["re-run after the TRC writer's last-column fix (bench_ik.py --rescore-left)"])
            rescored.append(f"{key} draw {t + 1}")
        med = [r["left_missing"]["angle_median"] for r in ev["trials"]]
        worst = [r["left_missing"]["angle_worst"] for r in ev["trials"]]
        left = ev["ik"]["left_missing"]
        left["angle_median"]["median"] = float(np.median([v for v in med if v is not None]))
        left["angle_worst"]["median"] = float(np.median([v for v in worst if v is not None]))
        for row in out["tables"]["angles"]["rows"]:
            if row[0] == name and row[1] == proto and row[2] == "(left missing)":
                row[3], row[4] = left["angle_median"]["median"], left["angle_worst"]["median"]
        for row in out["tables"]["default_vs_left_missing"]["rows"]:
            if row[0] == name and row[1] == proto:
                row[3], row[5] = left["angle_median"]["median"], left["angle_worst"]["median"]
                row[6] = "yes" if row[4] <= row[5] and row[2] < row[3] else "NO"
                out["figures"][f"{name}_{proto}_left_missing_angle_median_deg"]["value"] = row[3]
    out["command"] += f"; python benchmarks/bench_ik.py --rescore-left {path} --out {out_path}"
    out["rescored_left_missing"] = rescored
    Path(out_path).write_text(json.dumps(out, indent=1, allow_nan=False, default=lambda o: None) + "\n")
    print(f"re-ran the left-missing IK of {', '.join(rescored) or 'no draw'}; written {out_path}")


def merge(files: list[str], out_path: str) -> None:
    """Concatenate the tables (and union the figures and evaluations) of several results files into ``out_path``."""
    parts = [json.loads(Path(f).read_text()) for f in files]
    out = parts[0]
    for part in parts[1:]:
        for key, table in part["tables"].items():
            out["tables"][key]["rows"] += table["rows"]
        out["figures"].update(part["figures"])
        out["evaluations"].update(part["evaluations"])
        out["rescored_left_missing"] = out.get("rescored_left_missing", []) + part.get("rescored_left_missing", [])
    out["command"] = "; ".join(p["command"] for p in parts) + f"; python benchmarks/bench_ik.py --merge {' '.join(files)}"
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    Path(out_path).write_text(json.dumps(out, indent=1, allow_nan=False) + "\n")
    print(f"written {out_path}")


if __name__ == "__main__":
    main()
