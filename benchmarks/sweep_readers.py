"""What the readers find in every capture of ../shared/data: markers, model points, unlabelled trajectories, held runs.

    python benchmarks/sweep_readers.py [--data ../shared/data] [--results benchmarks/results/sweep_readers.json]

Prints one row per file (markers / model points / unlabelled / held, zero and edge runs / notes that concern labels
or the parameter chain) and checks the issue's rules: no parameter-chain note anywhere, no held or zero sample in
the complete captures and the static trials (:data:`NO_HELD`).  Exits 1 when a rule fails.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import harness

import mocapfill
from mocapfill.guards.held import find_held, held_summary

#: Tables that are not captures.
NOT_CAPTURES = {"bolero/authors-code-results.csv"}
#: Files without a frame rate, and the rate their README gives.
RATES = {"bolero/127_07.csv": 120.0, "bolero/132_32.csv": 120.0}
#: Complete captures and static trials: the held-sample rule must flag none of their samples.
NO_HELD = ("cmu/85_02.c3d", "kineticstoolkit/kinematics_tennis_serve.c3d", "btk/TRCSamples/SprintMotion.trc",
           "pyorerun/example.c3d", "cmu-train/", "pycgm/Static_trial.c3d",
           "btk/C3DSamples/PiG/PiG_Calibration-FlatFoot-Full.c3d",
           "c3d-org/sample_00/Innovative Sports Training/Static Pose.c3d",
           "c3d-org/sample_26/Standing_Hybrid_1.c3d")
#: Words of a note that says the parameter section is damaged.
CHAIN_WORDS = ("parameter chain", "parameter section ends", "is malformed")
#: Words of a note about labels.
LABEL_WORDS = ("label row", "without a label", "placeholder", "unlabelled trajectories", "names irregularly")


def captures(data_dir: Path) -> list[str]:
    """Relative paths of the captures under ``data_dir``, sorted."""
    return sorted(str(p.relative_to(data_dir)) for p in data_dir.rglob("*")
                  if p.is_file() and p.suffix.lower() in (".c3d", ".csv", ".trc", ".tsv")
                  and str(p.relative_to(data_dir)) not in NOT_CAPTURES)


def sweep_file(path: Path, rel: str) -> dict:
    """One row: counts of each kind, held runs on the markers, the notes that matter, seconds."""
    started = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            data = mocapfill.read(path, rate=RATES.get(rel))
        except mocapfill.MocapfillError as exc:
            return {"file": rel, "error": str(exc)}
    columns = [k for k, kind in enumerate(data.kinds) if kind == "marker"]
    extra = data.extra
    quantum = None
    if getattr(getattr(extra, "file", None), "is_float", True) is False:
        quantum = abs(float(extra.file.scale))
    held = held_summary(find_held(data.positions[:, columns], units=data.units, quantum=quantum),
                        [data.labels[k] for k in columns], data.first_frame)
    texts = list(data.notes) + [str(w.message) for w in caught]
    return {
        "file": rel, "frames": data.n_frames,
        "markers": len(columns),
        "model": sum(1 for k in data.kinds if k == "model"),
        "unlabelled": sum(1 for k in data.kinds if k == "unlabelled"),
        "held_runs": held["held"], "zero_runs": held["zero"], "edge_runs": held["edge"],
        "held_samples": held["held_samples"], "held_markers": held["markers"],
        "chain_notes": sorted({t for t in texts if any(w in t for w in CHAIN_WORDS)}),
        "label_notes": sorted({t for t in data.notes if any(w in t for w in LABEL_WORDS)}),
        "seconds": time.perf_counter() - started,
    }


def check(rows: list[dict]) -> list[str]:
    """The rules each row must meet; one message per failure."""
    failures = []
    for row in rows:
        if "error" in row:
            failures.append(f"{row['file']}: not read: {row['error']}")
            continue
        if row["chain_notes"]:
            failures.append(f"{row['file']}: parameter-chain note: {row['chain_notes'][0]}")
        if row["file"].startswith(NO_HELD) and row["held_samples"]:
            failures.append(f"{row['file']}: {row['held_samples']} held sample(s) flagged in a complete capture or "
                            f"static trial ({', '.join(row['held_markers'])})")
    return failures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(harness.SHARED_DATA))
    harness.add_results_argument(parser)
    args = parser.parse_args(argv)
    data_dir = Path(args.data)
    if not data_dir.is_dir():
        print(f"no data folder {data_dir}", file=sys.stderr)
        return 2
    harness.banner(__file__)
    rows = [sweep_file(data_dir / rel, rel) for rel in captures(data_dir)]
    head = f"{'file':<70} {'mark':>5} {'model':>5} {'unlab':>5} {'held':>4} {'zero':>4} {'edge':>4}  notes"
    print(head)
    for row in rows:
        if "error" in row:
            print(f"{row['file']:<70} error: {row['error']}")
            continue
        notes = "; ".join(row["chain_notes"] + row["label_notes"])
        print(f"{row['file'][:70]:<70} {row['markers']:>5} {row['model']:>5} {row['unlabelled']:>5} "
              f"{row['held_runs']:>4} {row['zero_runs']:>4} {row['edge_runs']:>4}  {notes[:160]}")
    failures = check(rows)
    totals = {key: int(sum(r.get(key, 0) for r in rows)) for key in ("markers", "model", "unlabelled", "held_runs",
                                                                      "zero_runs", "edge_runs", "held_samples")}
    print(f"\n{len(rows)} files: {totals['markers']} markers, {totals['model']} model points, "
          f"{totals['unlabelled']} unlabelled; {totals['held_runs']} held, {totals['zero_runs']} zero, "
          f"{totals['edge_runs']} edge runs ({totals['held_samples']} samples); "
          f"{sum(1 for r in rows if r.get('chain_notes'))} files with a parameter-chain note")
    for failure in failures:
        print(f"FAIL {failure}")
    results = harness.Results(__file__, argv, args.results, note=args.note)
    results.table("files", "What the readers find in ../shared/data (held runs on the markers only)",
                  ["file", "markers", "model points", "unlabelled", "held runs", "zero runs", "edge runs",
                   "held samples", "notes"],
                  [[r["file"], r.get("markers"), r.get("model"), r.get("unlabelled"), r.get("held_runs"),
                    r.get("zero_runs"), r.get("edge_runs"), r.get("held_samples"),
                    "; ".join(r.get("chain_notes", []) + r.get("label_notes", [])) or r.get("error", "")]
                   for r in rows])
    results.figure("files", len(rows), "files", "higher")
    results.figure("chain_notes", sum(1 for r in rows if r.get("chain_notes")), "files")
    results.figure("held_in_complete_or_static", sum(r.get("held_samples", 0) for r in rows
                                                     if r["file"].startswith(NO_HELD)), "samples")
    results.figure("rule_failures", len(failures), "failures")
    results.write()
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
