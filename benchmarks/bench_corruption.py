"""Benchmark: outlier rejection, then the fill, under Holden's corruption (issue 9, "The full pipeline").

What ``mocapfill evaluate FILE -p random --reject-outliers self`` runs, on real complete clips: per trial, Holden's
corruption with stretches (``random`` protocol: up to 10 % of each marker's samples hidden and up to 10 % displaced
by one uniform +-50 cm offset per stretch, stretches of 0.05-0.5 s), then
:func:`mocapfill.guards.outliers.reject_outliers` with the corrupted clip as its own reference (what ``fill
--reject-outliers`` does), then each fill method; the scored samples are the hidden and the displaced ones (a
displaced sample that is not caught pays its whole displacement).

Reported per clip:

- detection: the fraction of displaced samples caught (median, min over trials), of those displaced by more than
  100 mm, and the precision (caught / rejected); the number of samples rejected in the *uncorrupted* clip;
- where the misses are: displaced stretches bounded by two steps, by a gap and a step, by another displaced
  stretch, ...;
- per method: median and mean trial RMSE (mm) of the whole pipeline, and the same with a perfect detector (every
  displaced sample hidden): what the fill alone costs.

Clips: ``sample_data/85_02.c3d`` (CMU, 120 Hz), ``sample_data/kinematics_tennis_serve.c3d`` (OptiTrack, 50 Hz,
metres) and the BoLeRO authors' CSVs in ``../shared/data/bolero`` (CMU 127_07, 132_32; read with rate=120) when
present.

Run from the repository root::

    python benchmarks/bench_corruption.py [--trials 10] [--seed 0] [--methods auto,bolero-sc,linear]
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections import Counter  # noqa: E402

import numpy as np  # noqa: E402

import mocapfill  # noqa: E402
from mocapfill.evaluation import evaluate, make_occlusions  # noqa: E402
from mocapfill.gaps import runs  # noqa: E402
from mocapfill.guards.outliers import reject_outliers  # noqa: E402
from mocapfill.units import length_factor  # noqa: E402

SHARED = harness.SHARED_DATA
CLIPS = [
    ("cmu-85_02", harness.CLIP_85_02, None),
    ("tennis-serve", harness.CLIP_TENNIS, None),
    ("bolero-127_07", SHARED / "bolero" / "127_07.csv", 120.0),
    ("bolero-132_32", SHARED / "bolero" / "132_32.csv", 120.0),
]


def _edge(m: int, t: int, observed: np.ndarray, shifted: np.ndarray) -> str:
    """What bounds a displaced stretch of marker m at frame t (just outside it): a gap, another shift, or a step
    (a clean sample); observed, shifted (n_frames, n_markers) bool."""
    if t < 0 or t >= observed.shape[0] or not observed[t, m]:
        return "gap"
    if shifted[t, m]:
        return "shift"
    return "step"


def detection(data, trials) -> dict:
    """Recall, precision and where the misses are, over ``trials`` of ``data`` (positions (n_frames, n_markers, 3))."""
    mm = length_factor("mm", data.units)
    recall, recall_big, precision = [], [], []
    kinds, caught = Counter(), Counter()
    for trial in trials:
        corrupted, _, shifted = trial.apply(data.positions)
        rejected = reject_outliers(corrupted, units=data.units, labels=data.labels, rate=data.rate).rejected
        offsets = corrupted - data.positions
        big = shifted & (np.linalg.norm(np.nan_to_num(offsets), axis=2) > 100 * mm)
        recall.append((rejected & shifted).sum() / max(shifted.sum(), 1))
        recall_big.append((rejected & big).sum() / max(big.sum(), 1))
        precision.append((rejected & shifted).sum() / max(rejected.sum(), 1))
        observed = ~np.isnan(corrupted).any(axis=2)
        for m in range(data.n_markers):
            for start, length in runs(shifted[:, m]):
                # split where the offset changes (overlapping stretches of one marker)
                o = offsets[start:start + length, m]
                tol = 1e-6 * max(1.0, float(np.abs(o).max()))  # (x + offset) - x is the offset up to rounding
                cuts = [0] + [i for i in range(1, length) if np.abs(o[i] - o[i - 1]).max() > tol] + [length]
                for a, b in zip(cuts[:-1], cuts[1:]):
                    left = "shift" if a > 0 else _edge(m, start + a - 1, observed, shifted)
                    right = "shift" if b < length else _edge(m, start + b, observed, shifted)
                    kind = "-".join(sorted((left, right)))
                    kinds[kind] += b - a
                    caught[kind] += int(rejected[start + a:start + b, m].sum())
    return {"recall": np.array(recall), "recall_big": np.array(recall_big), "precision": np.array(precision),
            "kinds": kinds, "caught": caught}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", default="auto,bolero-sc,linear")
    parser.add_argument("--clips", default=",".join(name for name, _, _ in CLIPS))
    parser.add_argument("--oracle", action=argparse.BooleanOptionalAction, default=True,
                        help="also fill with a perfect detector (default on)")
    harness.add_results_argument(parser)
    args = parser.parse_args()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    harness.banner(__file__)
    results = harness.Results(__file__, path=args.results, note=args.note)
    summary_rows, detail_rows = [], []
    print(f"# protocol random (Holden's corruption with stretches), {args.trials} trials, seed {args.seed}; "
          f"reject_outliers self-referenced, then the fill; errors in mm over hidden + displaced samples")
    for name, path, rate in CLIPS:
        if name not in args.clips.split(","):
            continue
        if not path.exists():
            print(f"\n{name}: {path} not present, skipped")
            continue
        data = mocapfill.read(path, rate=rate) if rate else mocapfill.read(path)
        to_mm = length_factor(data.units, "mm")
        clean = int(reject_outliers(data.positions, units=data.units, labels=data.labels, rate=data.rate)
                    .rejected.sum())
        trials = make_occlusions(data, "random", trials=args.trials, seed=args.seed)
        t0 = time.perf_counter()
        det = detection(data, trials)
        det_seconds = (time.perf_counter() - t0) / len(trials)
        print(f"\n{name}: {data.n_frames} frames x {data.n_markers} markers at {data.rate:g} Hz ({data.units}); "
              f"uncorrupted clip: {clean} of {int((~data.missing).sum())} samples rejected")
        r, rb, p = det["recall"], det["recall_big"], det["precision"]
        print(f"  displaced samples caught: median {np.median(r):.3f}, min {r.min():.3f}, pooled "
              f"{sum(det['caught'].values()) / max(sum(det['kinds'].values()), 1):.3f}; displaced > 100 mm: median "
              f"{np.median(rb):.3f}, min {rb.min():.3f}; precision median {np.median(p):.3f}, min {p.min():.3f} "
              f"({det_seconds:.2f} s per rejection)")
        for kind, total in sorted(det["kinds"].items(), key=lambda kv: -kv[1]):
            print(f"    stretches bounded by {kind:12s}: {total:6d} samples, caught {det['caught'][kind] / total:.3f}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = evaluate(data, methods, occlusions=trials, seed=args.seed, reject_outliers="self")
            oracle = None
            if args.oracle:
                # a perfect detector: the displaced samples hidden with the gaps, nothing displaced left
                from mocapfill.evaluation import Occlusion, Trial

                perfect = [Trial(t.occlusions + tuple(Occlusion((s.marker,), s.start, s.length) for s in t.shifts))
                           for t in trials]
                oracle = evaluate(data, methods, occlusions=perfect, seed=args.seed)
        print(f"  {'method':10s} {'median RMSE':>12s} {'mean RMSE':>10s} {'perfect detector: median':>25s} "
              f"{'mean':>7s} {'s/fill':>7s}")
        summary = res.summary()
        best = {}
        caught = round(100 * float(np.median(r)), 1)
        summary_row = [name, caught]
        results.figure(f"{name}/caught_median", caught, "% of displaced samples", "higher")
        results.figure(f"{name}/precision_median", round(float(np.median(p)), 3), "", "higher")
        for method in methods:
            row = summary[method]
            med, mean = row["rmse"]["median"] * to_mm, row["rmse"]["mean"] * to_mm
            best[method] = med
            line = f"  {method:10s} {med:12.1f} {mean:10.1f}"
            detail = [name, f"`{method}`", round(med, 1), round(mean, 1), None, None,
                      round(row["seconds"]["median"], 2)]
            cell = f"{med:.1f}"
            results.figure(f"{name}/{method}/median_rmse", round(med, 1), "mm")
            if oracle is not None:
                orow = oracle.summary()[method]
                line += f" {orow['rmse']['median'] * to_mm:25.1f} {orow['rmse']['mean'] * to_mm:7.1f}"
                detail[4:6] = [round(orow["rmse"]["median"] * to_mm, 1), round(orow["rmse"]["mean"] * to_mm, 1)]
                cell += f" ({orow['rmse']['median'] * to_mm:.1f})"
            line += f" {row['seconds']['median']:7.2f}"
            print(line)
            summary_row.append(cell)
            detail_rows.append(detail)
        summary_rows.append(summary_row)
        if "auto" in best and "bolero-sc" in best:
            ok = best["auto"] <= 50 and best["auto"] < best["bolero-sc"]
            print(f"  target (auto median <= 50 mm and below bolero-sc): {'met' if ok else 'NOT met'} "
                  f"({best['auto']:.1f} vs {best['bolero-sc']:.1f})")
    results.table("summary", f"{args.trials} trials of `evaluate -p random --reject-outliers self` per clip: up to "
                  "10 % of every marker hidden and up to 10 % displaced by up to 50 cm per axis, in stretches of "
                  "0.05-0.5 s; "
                  "displaced samples caught (median over trials); median trial RMSE (mm) over the hidden and displaced "
                  "samples, in brackets with a perfect detector",
                  ["clip", "displaced samples caught %", *(f"`{m}`" for m in methods)], summary_rows)
    results.table("detail", "per clip and method: median and mean trial RMSE (mm) of the whole pipeline, the same "
                  "with a perfect detector, median seconds per fill",
                  ["clip", "method", "median", "mean", "perfect: median", "perfect: mean", "s per fill"], detail_rows)
    results.write()


if __name__ == "__main__":
    main()
