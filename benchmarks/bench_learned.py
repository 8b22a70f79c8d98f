"""Benchmark of issue 26, part 2: the learned denoiser (Holden 2018) against the default, at three training sizes.

On the CMU 41-marker layout (clips restricted to 85_02's markers, as in ``bench_references.py``):

- **training**: three nested sets of clips that never include a test clip (``SIZES``), one model each
  (``mocapfill.engines.denoiser_training.train``, the same settings for all three); training time, frames, model file
  size and parameters.
- **test clips** (held out): 16_08 (walk), 07_12 and 02_01.  Per clip ``--trials`` seeded trials of
  ``evaluate``'s ``random`` protocol (Holden's corruption: stretches hidden and stretches displaced by up to 50 cm;
  outliers not pre-rejected) and of its ``marker`` protocol (tidy one-marker gaps, nothing displaced).  Scored over
  the hidden and displaced samples (RMSE, mm):

  - ``auto``: the default as it is (displaced samples stay in, and are scored);
  - ``auto --reject-outliers``: Holden's distance-range rule on the capture itself first (``self``);
  - ``learned --denoise``: the model's own detection (:func:`mocapfill.guards.denoise.find_displaced`), then the
    learned fill; on the marker protocol ``learned`` alone;
  - ``auto --denoise``: the largest model's detection, then the default (``fill --model M --denoise``), on both
    protocols (on tidy gaps it shows what false detections cost); and how many samples it judged displaced.

  No mode uses the clean test clip (no oracle).
  - ``auto --model``: the largest model's estimate as a second
    spatial measurement of the default (:func:`mocapfill.methods.auto.prior_stage`), after its detection on the
    random protocol.  (``--protocols dense,segment`` too: 20 % hidden, body segments hidden.)
- **speed**: the learned fill's time per 1,000 frames (the largest model, one test clip).

Run from the repository root (about 30 min on the shared, loaded 2-core machine)::

    python benchmarks/bench_learned.py [--trials 3] [--steps 2000] [--seed 26] [--method auto-stack]
        [--sizes small,medium,large] [--protocols random,marker]

Writes ``benchmarks/results/bench_learned.json``; tables on stderr.
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import mocapfill  # noqa: E402
from harness import cmu41_clip as load, cmu41_layout as layout  # noqa: E402
from mocapfill.engines.denoiser import save_model  # noqa: E402
from mocapfill.evaluation.occlusions import make_occlusions  # noqa: E402
from mocapfill.guards.denoise import find_displaced  # noqa: E402
from mocapfill.guards.outliers import reject_outliers  # noqa: E402
from mocapfill.methods import get_method  # noqa: E402

TESTS = ["16_08", "07_12", "02_01"]
#: evaluate's protocols this benchmark knows, with their options (dense: 20 % of the samples hidden).
PROTOCOLS = {"random": {}, "marker": {}, "dense": {"missing": 0.2}, "segment": {}}
SIZES = {"small": ["16_07", "07_01", "75_01"],
         "medium": ["16_07", "07_01", "75_01", "85_02", "49_04", "77_02"],
         "large": ["16_07", "07_01", "75_01", "85_02", "49_04", "77_02", "16_57", "111_28", "133_01", "82_08",
                   "127_07"]}


def rmse(estimate: np.ndarray, truth: np.ndarray, scored: np.ndarray) -> float:
    d = np.linalg.norm(estimate - truth, axis=2)[scored]
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--hidden", type=int, default=256)
    parser.add_argument("--blocks", type=int, default=2)
    parser.add_argument("--seed", type=int, default=26)
    parser.add_argument("--method", default="auto", help="the default measured beside the learned fill (e.g. "
                        "auto-stack, the previous default)")
    parser.add_argument("--sizes", default=",".join(SIZES), help="training sizes to train (the largest given is the "
                        "model of the --denoise and --model columns)")
    parser.add_argument("--protocols", default="random,marker",
                        help=f"comma-separated, of {', '.join(PROTOCOLS)}")
    harness.add_results_argument(parser)
    args = parser.parse_args()
    from mocapfill.engines.denoiser_training import train

    def log(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    labels = layout()
    method = args.method
    sizes = {k: SIZES[k] for k in args.sizes.split(",")}
    protocols = args.protocols.split(",")
    assert set(protocols) <= set(PROTOCOLS), protocols
    largest = list(sizes)[-1]
    assert not set(TESTS) & {c for clips in SIZES.values() for c in clips}
    started = time.perf_counter()
    models, size_rows = {}, []
    tmp = Path(tempfile.mkdtemp())
    for size, clips in sizes.items():
        takes = [load(c, labels).positions for c in clips]
        model = train(takes, labels, "mm", steps=args.steps, hidden=args.hidden, blocks=args.blocks, seed=args.seed,
                      names=clips)
        path = tmp / f"{size}.model"
        save_model(model, path)
        models[size] = model
        s = model.settings
        size_rows.append([size, len(clips), s["frames"], s["seconds"], round(path.stat().st_size / 1024, 1),
                          model.n_parameters(), round(s["validation_loss"], 4),
                          round(float(np.median(model.residual)), 1)])
        log(f"trained {size}: {len(clips)} clips, {s['frames']} frames, {s['seconds']:.0f} s, "
            f"{path.stat().st_size / 1024:.0f} KiB, validation loss {s['validation_loss']:.3f}")

    trial_rows = []
    for clip in TESTS:
        truth = load(clip, labels)
        for protocol in protocols:
            trials = make_occlusions(truth, protocol, trials=args.trials, seed=args.seed, **PROTOCOLS[protocol])
            for k, trial in enumerate(trials):
                corrupted, hidden, shifted = trial.apply(truth.positions)
                scored = hidden | shifted
                data = truth.with_positions(corrupted)
                row = [clip, protocol, k]
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    row.append(rmse(mocapfill.fill(data, method).positions, truth.positions, scored))
                    if protocol == "random":
                        res = reject_outliers(corrupted, units="mm", labels=labels, rate=truth.rate)
                        row.append(rmse(mocapfill.fill(truth.with_positions(res.positions), method).positions,
                                        truth.positions, scored))
                    else:
                        row.append(float("nan"))
                    for size in sizes:
                        work = corrupted
                        if protocol == "random":
                            found = find_displaced(corrupted, models[size], labels=labels, units="mm",
                                                   rate=truth.rate)
                            work = corrupted.copy()
                            work[found] = np.nan
                        out = mocapfill.fill(truth.with_positions(work), "learned", model=models[size])
                        row.append(rmse(out.positions, truth.positions, scored))
                    # the default after the large model's detection (`fill --model M --denoise`), both protocols
                    found = find_displaced(corrupted, models[largest], labels=labels, units="mm", rate=truth.rate)
                    work = corrupted.copy()
                    work[found] = np.nan
                    row.append(rmse(mocapfill.fill(truth.with_positions(work), method).positions, truth.positions,
                                    scored))
                    # the model as the default's prior (`fill --model M`, and with --denoise on the random protocol)
                    prior = "model" in get_method(method).parameters()
                    row.append(rmse(mocapfill.fill(truth.with_positions(work if protocol == "random" else corrupted),
                                                   method, model=models[largest]).positions, truth.positions, scored)
                               if prior else float("nan"))
                    row.append(float(found.sum()))
                trial_rows.append([row[0], row[1], row[2]] + [round(v, 2) if np.isfinite(v) else None
                                                              for v in row[3:]])
                log(f"{clip} {protocol} {k}: " + " ".join(f"{v:7.1f}" for v in row[3:]))

    summary = []
    heads = ([method, f"{method} --reject-outliers"] + [f"learned {size}" for size in sizes]
             + [f"{method} --denoise ({largest})", f"{method} --model ({largest}; --denoise on random)",
                "samples judged displaced"])
    for protocol in protocols:
        sel = np.array([[np.nan if v is None else v for v in r[3:]] for r in trial_rows if r[1] == protocol],
                       dtype=float)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # the marker protocol has no reject-outliers column
            med = np.nanmedian(sel, axis=0) if len(sel) else [float("nan")] * len(heads)
        summary.append([protocol, len(sel)] + [None if not np.isfinite(v) else round(float(v), 1) for v in med])
    # speed: the large model on the longest test clip
    truth = load(TESTS[0], labels)
    gappy = truth.positions.copy()
    gappy[50:90, 10] = np.nan
    t0 = time.perf_counter()
    for _ in range(3):
        mocapfill.fill(truth.with_positions(gappy), "learned", model=models[largest])
    per_1000 = (time.perf_counter() - t0) / 3 / truth.n_frames * 1000
    log("\ntraining: size clips frames seconds KiB parameters validation-loss residual-mm")
    for r in size_rows:
        log("  " + " ".join(str(x) for x in r))
    log("median RMSE (mm): protocol trials " + " | ".join(heads))
    for r in summary:
        log("  " + " ".join(str(x) for x in r))
    log(f"learned fill: {per_1000:.3f} s per 1,000 frames")
    results = harness.Results("bench_learned.py", path=args.results, note=args.note)
    results.table("training", f"nested training sets (no test clip), {args.steps} steps, hidden {args.hidden}, "
                  f"{args.blocks} blocks", ["size", "clips", "frames", "training seconds", "model KiB", "parameters",
                                            "validation loss (L1, normalised)", "median held-out residual (mm)"],
                  size_rows)
    results.table("summary", "median over trials of the per-trial RMSE (mm) over the hidden and displaced samples; "
                  "random: Holden's corruption, outliers not pre-rejected (learned: --denoise); marker: tidy "
                  "one-marker gaps; dense: 20 % hidden; segment: body segments hidden.  --model: the largest model "
                  "as the default's prior (a second spatial measurement).  No oracle.", ["protocol", "trials"] + heads, summary)
    results.table("trials", "every trial, RMSE (mm)", ["clip", "protocol", "trial"] + heads, trial_rows)
    results.figure("learned_fill_seconds_per_1000_frames", round(per_1000, 4), "s")
    results.figure(f"training_seconds_{largest}", size_rows[-1][3], "s")
    results.figure("model_kib", size_rows[-1][4], "KiB")
    for row in summary:
        for i, h in enumerate(heads[:-1]):
            if row[2 + i] is not None:
                results.figure(f"{row[0]}_median_{re.sub('[^a-z]+', '_', h).strip('_')}", row[2 + i], "mm")
    results.write()
    log(f"({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
