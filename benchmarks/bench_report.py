"""Issue 13: size and build time of the HTML reports (with the 3-D player) for the bundled samples and a 72,000-frame
take (sample_data/85_02.c3d tiled forwards and backwards; it has no gaps, so 0.5-2 s gaps are hidden in it, seeded,
until ``--long-missing`` percent of its samples are missing).

For each capture: the fill (``auto`` unless ``--method``; not counted), then the fill report (``write_fill_report``:
bones estimated, JSON record, plots, player) drawn in one process and on every core (``jobs=0``, what ``mocapfill
fill --report`` does; the pages are the same; in turn, the best of two each) and the raw capture's page (``info
--report``): seconds and megabytes, the player's share of the page and its decimation.  Prints a Markdown table on
stdout.

    python benchmarks/bench_report.py [--method auto] [--long-frames 72000] [--skip-long] [MORE.c3d ...]
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import tempfile
import time
import warnings
from pathlib import Path

import harness

import numpy as np

from mocapfill.runtime.blas import single_blas_thread
from mocapfill.io import read
from mocapfill.markers import MarkerData
from mocapfill.pipeline import FillSettings, fill_capture, write_fill_report
from mocapfill.report.capture_html import write_capture_report
from mocapfill.runtime.executor import resolve_jobs
from mocapfill.summary import summarize

MB = 1e6


def tiled(data, n_frames: int, missing: float, seed: int = 0):
    """``data`` played forwards, backwards, forwards ... up to ``n_frames`` frames, with gaps of 0.5-2 s hidden at
    random (``seed``) until ``missing`` percent of the samples are missing."""
    pos = harness.palindrome(data.positions, n_frames, repeat_turns=True)
    rng = np.random.default_rng(seed)
    hidden = np.zeros(pos.shape[:2], dtype=bool)
    target = missing / 100 * hidden.size
    while hidden.sum() < target:
        length = int(rng.integers(int(0.5 * data.rate), int(2 * data.rate) + 1))
        start = int(rng.integers(0, n_frames - length))
        hidden[start:start + length, int(rng.integers(0, pos.shape[1]))] = True
    pos[hidden] = np.nan
    # no C3D payload: it describes the short file
    return MarkerData(pos, list(data.labels), data.rate, data.units, data.first_frame, None, None,
                      f"{Path(data.path).name} tiled to {n_frames} frames")


def player_share(page: str) -> tuple[float, str]:
    match = re.search(r'<section id="player">.*?</section>', page, re.S)
    size = len(match.group(0).encode()) / MB if match else 0.0
    stride = re.search(r'"stride":(\d+)', page)
    return size, stride.group(1) if stride else "?"


def measure(name: str, data, method: str, out: Path) -> dict:
    started = time.perf_counter()
    outcome = fill_capture(data, FillSettings(method=method))
    fill_seconds = time.perf_counter() - started
    path = out / "fill.html"
    seconds = [np.inf, np.inf]
    for _ in range(2):  # one process, then every core (the command line's default), in turn: the best of two each
        for i, jobs in enumerate((1, 0)):
            started = time.perf_counter()
            write_fill_report(outcome, str(path), method=method, input_path=data.path, output_path=None,
                              smoothed=False, jobs=jobs)
            seconds[i] = min(seconds[i], time.perf_counter() - started)
    report_seconds, report_cores_seconds = seconds
    page = path.read_text()
    player_mb, stride = player_share(page)
    info_path = out / "info.html"
    started = time.perf_counter()
    write_capture_report(data, summarize(data), str(info_path))
    info_seconds = time.perf_counter() - started
    return {"name": name, "frames": data.n_frames, "markers": data.n_markers,
            "missing": 100 * float(data.missing.mean()), "fill_s": fill_seconds, "report_s": report_seconds,
            "report_cores_s": report_cores_seconds,
            "report_mb": len(page.encode()) / MB, "player_mb": player_mb, "stride": stride,
            "info_s": info_seconds, "info_mb": info_path.stat().st_size / MB}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--method", default="auto")
    parser.add_argument("--long-frames", type=int, default=72_000)
    parser.add_argument("--long-missing", type=float, default=10.0)
    parser.add_argument("--long-method", default=None, help="fill method of the long take (default: --method)")
    parser.add_argument("--skip-long", action="store_true")
    parser.add_argument("extra", nargs="*", help="more captures to measure (after the bundled samples)")
    harness.add_results_argument(parser)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    harness.banner(__file__)
    print(f"# fill method {args.method}")
    paths = sorted(glob.glob(str(harness.SAMPLE_DATA / "*.c3d"))) + list(args.extra)
    captures = [(Path(p).name, read(p)) for p in paths]
    if not args.skip_long:
        base = read(str(harness.CLIP_85_02))
        captures.append((f"85_02 tiled, {args.long_frames} frames, {args.long_missing:g} % hidden",
                         tiled(base, args.long_frames, args.long_missing)))
    rows = []
    with single_blas_thread(), tempfile.TemporaryDirectory() as tmp:
        for k, (name, data) in enumerate(captures):
            method = args.long_method if (args.long_method and k == len(captures) - 1 and not args.skip_long) \
                else args.method
            rows.append(measure(name, data, method, Path(tmp)))
            rows[-1]["method"] = method
    print()
    cores = resolve_jobs(0)
    print(f"| capture | frames x markers | missing % | method | fill s (not counted) | fill report s | on {cores} "
          "processes | fill report MB | of it the player MB | frames shown | info report s | info report MB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        shown = "all" if r["stride"] == "1" else f"every {r['stride']}th"
        print(f"| {r['name']} | {r['frames']} x {r['markers']} | {r['missing']:.1f} | {r['method']} | {r['fill_s']:.2f} | "
              f"{r['report_s']:.2f} | {r['report_cores_s']:.2f} | {r['report_mb']:.2f} | {r['player_mb']:.2f} | "
              f"{shown} | {r['info_s']:.2f} | {r['info_mb']:.2f} |")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\nload average {load:.1f} (1 min) at the end")
    results = harness.Results(__file__, path=args.results, note=args.note)
    table = []
    for r in rows:
        shown = "all" if r["stride"] == "1" else f"every {r['stride']}th"
        table.append([r["name"], f"{r['frames']} x {r['markers']}", round(r["missing"], 1), round(r["report_s"], 2),
                      round(r["report_cores_s"], 2), round(r["report_mb"], 2), round(r["player_mb"], 2), shown,
                      round(r["info_s"], 2), round(r["info_mb"], 2)])
        results.figure(f"{r['name']}/fill_report", table[-1][5], "MB")
        results.figure(f"{r['name']}/info_report", table[-1][9], "MB")
    results.table("reports", "HTML report size and build time (the fill not counted): the fill report "
                  "(`write_fill_report`: bones, JSON record, plots, player) and the raw capture's page "
                  "(`info --report`)",
                  ["capture", "frames x markers", "missing %", "fill report s", f"on {cores} processes s",
                   "fill report MB", "of it the player MB", "frames shown", "info report s", "info report MB"], table)
    results.write()


if __name__ == "__main__":
    main()
