"""Benchmark of issue 26, part 1: reference takes for the default fill (``fill --reference``).

On the CMU 41-marker layout (``sample_data/85_02.c3d``, ``../shared/data/cmu-train/`` (12 clips, 9 subjects),
``../shared/data/bolero/127_07.csv`` read at 120 Hz), every clip restricted to the 41 markers of 85_02 (matched by
label, a ``Subject:`` prefix aside):

- **same subject**: each clip of CMU subjects 16 (16_07, 16_08, 16_57) and 07 (07_01, 07_12) is a held-out test
  capture; the subject's other clip(s) are its references (one or two takes: the lab's static trial / other takes of
  the session).  The test clip is never a reference of itself.
- **other subjects / motions**: three test clips, each with two clips of other subjects (other motions too).

Protocols (``mocapfill.evaluate``): ``dense`` at 20 % and 30 % missing and ``segment``; ``--trials`` seeded trials per
clip and protocol, the same occlusions with and without references.  Per trial the RMSE over the hidden samples (mm)
of ``auto`` without references and with them; per set and protocol the median over trials of each, the median
reduction and the worst ratio (with / without).  Targets (issue 26): same subject, median >= 30 % lower; other
subjects, median ratio <= 1.05 and no trial above 1.1.  No mode here uses the clean test capture (no oracle).

``--shapes`` measures only the body fit that weighs a reference (:func:`mocapfill.references.shape_difference`), no
fill, in seconds: every ordered pair of the clips (those of ``cmu-train/`` carrying the whole layout, 85_02 and the
two BoLeRO clips), the reference whole and as one-frame static trials (five frames of it, each repeated), same
subject against another; the median absolute pair-length difference that weighs it and the RMS that weighed it
before the twenty-seventh session (written with ``--results benchmarks/results/bench_references_shapes.json``).

``--gapped FRACTION`` hides that fraction of every reference's samples first (``dense`` gaps, seeded per reference)
and ``--lacking LABEL`` removes that marker from every reference: a session's other takes, as a lab has them (written
with ``--results benchmarks/results/bench_references_gapped.json``).

``--force-weight`` sets every reference's weight to 1 (the body-fit weighting off), so that only each local
model's cross-validation on the capture's own frames keeps other subjects' frames out (written with ``--results
benchmarks/results/bench_references_forced.json``).

Run from the repository root (about 40 min on the shared, heavily loaded 2-core machine)::

    python benchmarks/bench_references.py [--trials 2] [--seed 26] [--sets same,other] [--method auto-stack]

(``benchmarks/results/bench_references_auto_next.json`` holds the run of the one-model default, 2026-11-26,
when it was still named ``auto-next``; ``bench_references_auto_stack.json`` the run of 2026-11-25 with the previous
default, now ``auto-stack``.)

Writes ``benchmarks/results/bench_references.json``; tables on stderr.
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

import mocapfill  # noqa: E402
from harness import cmu41_clip as load, cmu41_layout as layout  # noqa: E402

SAME = {"16_07": ["16_08", "16_57"], "16_08": ["16_07", "16_57"], "16_57": ["16_07", "16_08"],
        "07_01": ["07_12"], "07_12": ["07_01"]}
OTHER = {"85_02": ["16_07", "07_01"], "16_08": ["02_01", "82_08"], "127_07": ["133_01", "49_04"]}
PROTOCOLS = [("dense 20 %", "dense", {"missing": 0.2}), ("dense 30 %", "dense", {"missing": 0.3}),
             ("segment", "segment", {})]


def with_gaps(take, missing: float, lacking: list[str], seed: int):
    """``take`` with ``missing`` of its samples hidden in ``dense`` gaps (``seed``) and the ``lacking`` markers removed:
    a reference take as a session holds it."""
    from mocapfill.evaluation import make_occlusions
    from mocapfill.references import bare_label

    positions = take.positions.copy()
    if missing:
        positions = make_occlusions(take, "dense", trials=1, seed=seed, missing=missing)[0].apply(positions)[0]
    bare = [bare_label(x) for x in take.labels]
    for label in lacking:
        positions[:, bare.index(label)] = np.nan
    return take.with_positions(positions)


def run_set(name: str, table: dict[str, list[str]], labels: list[str], trials: int, seed: int, log,
            method: str = "auto", gapped: float = 0.0, lacking: tuple[str, ...] = ()) -> list[list]:
    rows = []
    for test, ref_names in table.items():
        truth = load(test, labels)
        refs = [load(r, labels) for r in ref_names]
        if gapped or lacking:
            refs = [with_gaps(r, gapped, list(lacking), seed=100 + i) for i, r in enumerate(refs)]
        for pname, protocol, opts in PROTOCOLS:
            t0 = time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                plain = mocapfill.evaluate(truth, [method], protocol, trials=trials, seed=seed, **opts)
                t1 = time.process_time()
                withr = mocapfill.evaluate(truth, [method], protocol, trials=trials, seed=seed, reference=refs,
                                           **opts)
                t2 = time.process_time()
            a = plain.values("rmse")[:, 0]
            b = withr.values("rmse")[:, 0]
            for k in range(len(a)):
                rows.append([name, test, "+".join(ref_names), pname, k, round(float(a[k]), 2), round(float(b[k]), 2),
                             round(float(b[k] / a[k]), 3)])
            log(f"{name:5} {test:6} <- {'+'.join(ref_names):14} {pname:10} without {np.median(a):7.1f}  with "
                f"{np.median(b):7.1f} mm  ({t1 - t0:.0f} / {t2 - t1:.0f} CPU s)")
    return rows


def shapes(labels: list[str], log) -> tuple[list[list], list[list]]:
    """Body-fit statistics of every ordered pair of clips (``--shapes``): per-pair rows and a summary per kind."""
    from mocapfill.references import MIN_WEIGHT, SHAPE_SCALE_MM, pair_length_differences

    names = sorted(p.stem for p in (harness.SHARED_DATA / "cmu-train").glob("*.c3d")) + ["85_02", "127_07", "132_32"]
    clips = {}
    for name in names:
        try:
            clips[name] = load(name, labels).positions
        except ValueError as exc:  # a clip lacking a marker of the layout
            log(f"{name}: left out ({exc})")
    rows = []
    for test, capture in clips.items():
        for ref, frames in clips.items():
            if ref == test:
                continue
            takes = [("whole", frames)] + [(f"frame {f}", frames[f:f + 1].repeat(50, axis=0))
                                           for f in np.linspace(0, len(frames) - 1, 5).round().astype(int)]
            for kind, take in takes:
                diff = pair_length_differences(capture, take)
                median = float(np.median(np.abs(diff)))
                rows.append([test, ref, test.split("_")[0] == ref.split("_")[0], kind, len(diff), round(median, 2),
                             round(float(np.sqrt(np.mean(diff ** 2))), 2),
                             round(float(np.exp(-0.5 * (median / SHAPE_SCALE_MM) ** 2)), 3)])
    summary = []
    for same in (True, False):
        for whole in (True, False):
            sel = [r for r in rows if r[2] == same and (r[3] == "whole") == whole]
            med, rms, weight = (np.array([r[k] for r in sel]) for k in (5, 6, 7))
            summary.append(["same subject" if same else "another subject",
                            "whole take" if whole else "one frame (static trial)", len(sel),
                            f"{med.min():.1f} / {np.median(med):.1f} / {med.max():.1f}",
                            f"{rms.min():.1f} / {np.median(rms):.1f} / {rms.max():.1f}",
                            f"{weight.min():.3f} / {np.median(weight):.3f} / {weight.max():.3f}",
                            int((weight < MIN_WEIGHT).sum()),
                            int((np.exp(-0.5 * (rms / 8.0) ** 2) < MIN_WEIGHT).sum())])
            log("  ".join(str(x) for x in summary[-1]))
    return rows, summary


def summarise(rows: list[list]) -> tuple[list[list], dict]:
    out, figures = [], {}
    for name in ("same", "other"):
        for pname, _, _ in PROTOCOLS + [("all", None, None)]:
            sel = [r for r in rows if r[0] == name and (pname == "all" or r[3] == pname)]
            if not sel:
                continue
            a = np.array([r[5] for r in sel])
            b = np.array([r[6] for r in sel])
            ratio = b / a
            out.append([name, pname, len(sel), round(float(np.median(a)), 1), round(float(np.median(b)), 1),
                        round(float(100 * (1 - np.median(b) / np.median(a))), 1),
                        round(float(np.median(ratio)), 3), round(float(ratio.max()), 3)])
            key = f"{name}_{pname.replace(' %', '').replace(' ', '')}"
            if name == "same":
                figures[f"{key}_median_reduction"] = {"value": out[-1][5], "unit": "%", "better": "higher"}
            else:
                figures[f"{key}_median_ratio"] = {"value": out[-1][6], "unit": "x", "better": "lower"}
                figures[f"{key}_max_ratio"] = {"value": out[-1][7], "unit": "x", "better": "lower"}
    return out, figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=2)
    parser.add_argument("--seed", type=int, default=26)
    parser.add_argument("--sets", default="same,other")
    parser.add_argument("--method", default="auto", help="the fill measured with and without references (e.g. "
                        "auto-stack, the previous default)")
    parser.add_argument("--force-weight", action="store_true",
                        help="weight every reference 1 (the body-fit weighting off): what the per-model "
                             "cross-validation alone keeps out")
    parser.add_argument("--gapped", type=float, default=0.0, help="hide this fraction of every reference's "
                        "samples first (dense gaps): a session's takes as a lab has them")
    parser.add_argument("--lacking", default="", help="comma-separated markers every reference lacks")
    parser.add_argument("--shapes", action="store_true", help="only the body fit that weighs a reference, every "
                        "pair of clips, whole and as one-frame static trials (seconds, no fill)")
    harness.add_results_argument(parser)
    args = parser.parse_args()

    def log(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    labels = layout()
    if args.shapes:
        rows, summary = shapes(labels, log)
        results = harness.Results("bench_references.py", path=args.results, note=args.note)
        results.table("shapes", "the body fit that weighs a reference: every ordered pair of the CMU clips "
                      "carrying the whole 41-marker set (14), the reference whole and as one-frame static trials "
                      "(five frames each); min / median / max of the median absolute difference of near-rigid "
                      "pairs' median lengths (the weight's measure, mm), of their RMS (the measure before, mm) and of the weight; "
                      "references left out (weight < 0.05) by each",
                      ["references", "taken as", "pairs of clips", "median |difference| mm", "RMS mm (before)",
                       "weight", "left out", "left out before"], summary)
        results.table("shape_pairs", "every pair: the capture, the reference, same subject, taken as, pairs "
                      "compared, median |difference| (mm), RMS (mm), weight",
                      ["capture", "reference", "same subject", "taken as", "pairs", "median", "RMS", "weight"], rows)
        results.write()
        return
    if args.force_weight:
        import mocapfill.references as references

        def weigh_all(positions, refs, units):
            for ref in refs:
                ref.shape_difference, ref.weight = float("nan"), 1.0

        references.weigh = weigh_all
    rows = []
    started = time.perf_counter()
    for name in args.sets.split(","):
        rows += run_set(name, SAME if name == "same" else OTHER, labels, args.trials, args.seed, log, args.method,
                        args.gapped, tuple(x for x in args.lacking.split(",") if x))
    summary, figures = summarise(rows)
    log("\nset    protocol    trials  without  with (median RMSE, mm)  reduction %  median ratio  max ratio")
    for r in summary:
        log(f"{r[0]:6} {r[1]:11} {r[2]:6} {r[3]:8} {r[4]:8} {r[5]:22} {r[6]:12} {r[7]:10}")
    results = harness.Results("bench_references.py", path=args.results, note=args.note)
    held = (f"; every reference with {100 * args.gapped:g} % of its samples hidden in dense gaps"
            if args.gapped else "")
    held += f"; every reference lacking {args.lacking}" if args.lacking else ""
    results.table("summary", f"{args.method} with and without reference takes{held}: median over trials of the per-trial RMSE (mm); "
                  "reduction of the median; ratio with / without per trial (median, max). No oracle: the test clip "
                  "is never a reference.", ["set", "protocol", "trials", "median RMSE without", "median RMSE with",
                                            "reduction %", "median ratio", "max ratio"], summary)
    results.table("trials", f"every trial: RMSE (mm) of {args.method} without / with the references",
                  ["set", "test clip", "references", "protocol", "trial", "RMSE without", "RMSE with", "ratio"], rows)
    for name, fig in figures.items():
        results.figure(name, fig["value"], fig["unit"], fig["better"])
    results.write()
    log(f"({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
