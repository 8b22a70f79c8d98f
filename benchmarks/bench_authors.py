"""Our `linear`, `dynammo`, `bolero-sc`, `bolero-hc` against the DynaMMo / BoLeRO authors' own code, trial by trial.

Data: ``../shared/data/bolero/`` (two of the BoLeRO paper's CMU clips at 120 Hz, the 40 fixed occlusion trials of
``occlusions.json`` and ``authors-code-results.csv``, what the authors' MATLAB code gave on exactly those trials).
Every trial hides its markers over its span; each method fills the occluded clip (bones only from the observed
samples) and is scored like the authors' figures: RMSE over the hidden coordinates, mm (:func:`rmse_hidden`).  Time is the
CPU time of each fill (our fills run BLAS on one thread; on a shared machine wall time is mostly waiting), with the
methods' modules imported beforehand (importing SciPy is a once-per-process cost); the authors' ``seconds`` is their
learner's wall time on a quiet 2-core VM, one BLAS thread.

    python benchmarks/bench_authors.py                   # all 40 trials, the four methods
    python benchmarks/bench_authors.py --methods dynammo --clips 127_07 --protocols P1

Prints the per-trial table, then medians per protocol next to the authors', our win fraction against the authors'
method of the same name, and the speed ratio (the authors' seconds / ours, median over trials).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
import warnings
from collections import defaultdict
from pathlib import Path

import harness

import numpy as np

DATA = harness.SHARED_DATA / "bolero"
#: Our method -> the authors' method of the same algorithm in their CSV.
AUTHORS = {"linear": "linear", "dynammo": "dynammo", "bolero-sc": "bolero_sc", "bolero-hc": "bolero_hc"}


def load_authors(path: Path) -> dict:
    """{(clip, protocol, trial, method): (rmse_mm, seconds)} from the authors' results CSV."""
    out = {}
    with open(path, newline="") as handle:
        for row in csv.DictReader(handle):
            out[(row["clip"], row["protocol"], int(row["trial"]), row["method"])] = (
                float(row["rmse_mm"]), float(row["seconds"]))
    return out


def rmse_hidden(filled: np.ndarray, truth: np.ndarray, hidden: np.ndarray) -> float:
    """The authors' score: sqrt(mean squared error over the hidden coordinates), the data's units.

    That is the 3-D RMSE over the hidden samples divided by sqrt(3) (``mocapfill evaluate``'s ``rmse`` is the 3-D
    one): with it our linear interpolation agrees with theirs to the last digit on all 40 trials.
    """
    err = (filled - truth)[hidden]
    return float(np.sqrt(np.mean(err ** 2)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DATA), help="folder with the clips, occlusions.json and the authors' CSV")
    ap.add_argument("--methods", default="linear,dynammo,bolero-sc,bolero-hc")
    ap.add_argument("--clips", default=None, help="comma list (default: all)")
    ap.add_argument("--protocols", default="P1,P2")
    ap.add_argument("--quiet", action="store_true", help="medians only")
    harness.add_results_argument(ap)
    args = ap.parse_args(argv)

    import mocapfill
    from mocapfill.api import fill
    from mocapfill.methods import get_method

    data_dir = Path(args.data)
    if not (data_dir / "occlusions.json").is_file():
        raise SystemExit(f"{data_dir}: no occlusions.json (the shared BoLeRO data is not present)")
    trials = json.loads((data_dir / "occlusions.json").read_text())["trials"]
    authors = load_authors(data_dir / "authors-code-results.csv")
    methods = args.methods.split(",")
    clips = None if args.clips is None else set(args.clips.split(","))
    protocols = set(args.protocols.split(","))
    trials = [t for t in trials if (clips is None or t["clip"] in clips) and t["protocol"] in protocols]

    harness.banner(__file__)
    for m in methods:  # import each method's modules now: a one-off cost of the process, not of the first trial
        get_method(m).load()
    clips_data = {}
    ours: dict = defaultdict(dict)  # method -> {(clip, protocol, trial): (rmse, seconds)}
    header = f"{'clip':7s} {'P':2s} {'#':>2s} {'markers':11s} {'frames':>9s}"
    for m in methods:
        header += f" | {m:>9s} {'authors':>8s}"
    if not args.quiet:
        print(header)
    for t in trials:
        clip = t["clip"]
        if clip not in clips_data:
            clips_data[clip] = mocapfill.read(data_dir / f"{clip}.csv", rate=120.0)
        data = clips_data[clip]
        truth = data.positions
        labels = list(data.labels)
        idx = [labels.index(name) for name in t["markers"]]
        hidden = np.zeros(truth.shape[:2], dtype=bool)
        hidden[t["start"]:t["start"] + t["length"], idx] = True
        occluded = truth.copy()
        occluded[hidden] = np.nan
        key = (clip, t["protocol"], int(t["trial"]))
        line = f"{clip:7s} {t['protocol']:2s} {t['trial']:2d} {'+'.join(t['markers']):11s} " \
               f"{t['start']:4d}+{t['length']:<4d}"
        for m in methods:
            t0 = time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = fill(occluded, m, units=data.units, rate=data.rate, labels=labels, seed=int(t["trial"]))
            secs = time.process_time() - t0
            r = rmse_hidden(res.positions, truth, hidden)
            ours[m][key] = (r, secs)
            a = authors.get(key + (AUTHORS[m],))
            line += f" | {r:9.2f} {a[0] if a else float('nan'):8.2f}"
        if not args.quiet:
            print(line, flush=True)

    print("\n# medians (RMSE mm over the hidden samples); wins = trials where ours <= the authors'; speed = median (min) "
          "of the authors' seconds / ours per trial")
    print(f"{'method':10s} {'protocol':8s} {'n':>3s} {'ours':>8s} {'authors':>8s} {'wins':>6s} {'speed':>8s} "
          f"{'min':>6s} {'our s':>7s}")
    results = harness.Results(__file__, argv, args.results, note=args.note)
    table = []
    for m in methods:
        for p in sorted(protocols) + ["all"]:
            keys = [k for k in ours[m] if p == "all" or k[1] == p]
            ks = [k for k in keys if k + (AUTHORS[m],) in authors]
            if not keys:
                continue
            our = np.array([ours[m][k][0] for k in keys])
            msg = f"{m:10s} {p:8s} {len(keys):3d} {np.median(our):8.2f}"
            row = [m, p, len(keys), round(float(np.median(our)), 2), None, None, None, None,
                   round(float(np.median([ours[m][k][1] for k in keys])), 3), None]
            results.figure(f"{m}/{p}/median_rmse", row[3], "mm")
            if ks:
                a = np.array([authors[k + (AUTHORS[m],)][0] for k in ks])
                o = np.array([ours[m][k][0] for k in ks])
                ratios = [authors[k + (AUTHORS[m],)][1] / ours[m][k][1] for k in ks]
                msg += (f" {np.median(a):8.2f} {100 * np.mean(o <= a):5.0f}% {np.median(ratios):7.0f}x"
                        f" {np.min(ratios):5.0f}x")
                row[4:8] = [round(float(np.median(a)), 2), round(100 * float(np.mean(o <= a))),
                            round(float(np.median(ratios))), round(float(np.min(ratios)))]
                results.figure(f"{m}/{p}/wins", row[5], "% of trials", "higher")
                results.figure(f"{m}/{p}/speed_median", row[6], "x the authors' code", "higher")
                results.figure(f"{m}/{p}/speed_min", row[7], "x the authors' code", "higher")
            else:
                msg += f" {'-':>8s} {'-':>6s} {'-':>8s} {'-':>6s}"
            msg += f" {np.median([ours[m][k][1] for k in keys]):7.3f}"
            if ks and len(ks) != len(keys):
                msg += f"  (the authors ran {len(ks)} of these; ours there {np.median(o):.2f})"
                row[9] = f"the authors ran {len(ks)}; ours there {np.median(o):.2f}"
            table.append(row)
            print(msg)
    results.table("medians", "median RMSE (mm over the hidden samples, the authors' score) against the authors' "
                  "code on their trials; wins = trials where ours <= theirs; speed = the authors' CPU seconds / ours",
                  ["method", "protocol", "trials", "ours", "authors", "wins %", "speed (median)", "speed (min)",
                   "our s", "note"], table)
    results.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
