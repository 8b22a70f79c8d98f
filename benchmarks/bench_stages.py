"""Issue 21, "fast": where the default's time goes, stage by stage, on every real capture with gaps.

For each real capture with gaps (``harness.gapped_captures``: ``sample_data/``, ``tests/data/``, ``../shared/data``;
``--only`` a path substring), the default fills it as ``mocapfill fill`` does (:func:`mocapfill.pipeline.fill_capture`
on ``mocapfill fill``'s default processes, ``--fill-jobs`` to choose), once to warm up and ``--repeat`` times more.
For the fastest of those fills: its wall time against issue 21's bound (0.25 x the capture's duration, or 1 s where
that is larger) and the wall time of each stage of :mod:`mocapfill.methods.auto` in it (the outermost calls of the
stage functions, so a stage that calls itself counts once; ``rest``: the fill's time outside them).  The stages run
their local models and bone problems on the fill's processes, so a stage's wall time is what the user waits for.

The stages (the module docstring of :mod:`mocapfill.methods.auto` says what each does): ``spatial`` (stage 1's local
PCA and the body stage), ``take`` (the global PCA's prediction and the bone set, its break rates and the reaches,
once per fill, at once), ``anchor``, ``bone`` (stage 2, both passes), ``temporal`` (stage 3, both passes),
``refit`` (stage 4's models), ``records`` (the gap records).

Run from the repository root, nothing else running (it measures time)::

    python benchmarks/bench_stages.py [--only sample_26] [--repeat 2]

Writes ``benchmarks/results/bench_stages.json`` (table ``stages``).

``--against DIR`` (another checkout of the repository, e.g. a ``git worktree`` of the commit before a change) times
instead the default's fill of each capture with this checkout's ``mocapfill`` and with that one's, in turn (A B A B
...), each fill in a process of its own (``--repeat`` pairs, after a warm-up fill in each process), and tables each
capture's median fill seconds with both and the median of the pairs' ratios: a speed change measured within one
run, on a machine whose speed drifts between runs (``benchmarks/results/bench_stages_against.json``, table
``against``).
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import contextlib  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

from mocapfill.io import read  # noqa: E402
from mocapfill.pipeline import FillSettings, fill_capture  # noqa: E402
from mocapfill.runtime.blas import single_blas_thread  # noqa: E402
from mocapfill.runtime.executor import resolve_jobs  # noqa: E402

#: Column -> the functions timed for it, as (module, attribute): the stage functions of ``mocapfill.methods.auto``
#: (model_fill looks them up as module globals when it calls them).
STAGES: dict[str, tuple[tuple[str, str], ...]] = {
    "spatial": (("mocapfill.methods.auto", "spatial_stage"),),
    "take": (("mocapfill.methods.auto", "take_stage"),),
    "anchor": (("mocapfill.methods.auto", "anchor_stage"),),
    "bone": (("mocapfill.methods.auto", "bone_stage"),),
    "temporal": (("mocapfill.methods.auto", "temporal_stage"),),
    "refit": (("mocapfill.methods.auto", "impute_stage"),),
    "records": (("mocapfill.methods.auto", "gap_records"),),
}


@contextlib.contextmanager
def stage_clock(seconds: dict[str, float]):
    """Within the block, each function of :data:`STAGES` adds its wall time to ``seconds[column]`` (outermost calls
    only: a stage called inside a timed one, or inside itself, is not counted twice); restored on exit."""
    import importlib

    depth = [0]
    saved = []

    def timed(column: str, func):
        def wrapper(*args, **kwargs):
            if depth[0]:
                return func(*args, **kwargs)
            depth[0] += 1
            start = time.perf_counter()
            try:
                return func(*args, **kwargs)
            finally:
                seconds[column] = seconds.get(column, 0.0) + time.perf_counter() - start
                depth[0] -= 1
        return wrapper

    for column, targets in STAGES.items():
        for module_name, attr in targets:
            module = importlib.import_module(module_name)
            saved.append((module, attr, getattr(module, attr)))
            setattr(module, attr, timed(column, getattr(module, attr)))
    try:
        yield
    finally:
        for module, attr, func in reversed(saved):
            setattr(module, attr, func)


def measure(path: Path, repeat: int, fill_jobs: int) -> dict:
    """The fastest of ``repeat`` fills (after one to warm up) of one capture, with its stages' seconds."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = read(path)
    settings = FillSettings(method="auto").check()
    best: dict | None = None
    for attempt in range(repeat + 1):
        seconds: dict[str, float] = {}
        with warnings.catch_warnings(), single_blas_thread(), stage_clock(seconds):
            warnings.simplefilter("ignore")
            outcome = fill_capture(data, settings, jobs=fill_jobs)
        if attempt and (best is None or outcome.seconds < best["fill"]):
            best = {"fill": outcome.seconds, **seconds}
    duration = data.n_frames / data.rate
    assert best is not None
    best["rest"] = max(best["fill"] - sum(best.get(c, 0.0) for c in STAGES), 0.0)
    return {"file": harness.capture_name(path), "frames": data.n_frames, "markers": data.n_markers,
            "duration": duration, "bound": harness.speed_bound(duration), **best}


#: A fill's wall time in a new process started in the checkout's root, whose ``mocapfill`` it imports (``python -c``
#: puts the working directory first on ``sys.path``); BLAS is pinned by the environment inherited.
_TIMED = """
import sys, warnings
from mocapfill.io import read
from mocapfill.pipeline import FillSettings, fill_capture
from mocapfill.runtime.blas import single_blas_thread
warnings.simplefilter("ignore")
data = read(sys.argv[1])
settings = FillSettings(method="auto").check()
with single_blas_thread():
    fill_capture(data, settings, jobs=int(sys.argv[2]))  # (a warm-up)
    print(fill_capture(data, settings, jobs=int(sys.argv[2])).seconds)
"""


def timed_in(checkout: Path, path: Path, fill_jobs: int) -> float:
    """The default's fill of ``path`` (seconds, after a warm-up) in a new process on ``checkout``'s ``mocapfill``."""
    out = subprocess.run([sys.executable, "-c", _TIMED, str(Path(path).resolve()), str(fill_jobs)], cwd=checkout,
                         capture_output=True, text=True)
    if out.returncode:
        last = (out.stderr.strip().splitlines() or ["no message"])[-1]
        raise SystemExit(f"--against: the fill of {path} with {checkout}'s package failed: {last}")
    return float(out.stdout.split()[-1])


def against(captures: list, other: Path, repeat: int, fill_jobs: int, results) -> None:
    """The table ``against``: each capture's fill with this checkout's package and with ``other``'s, in turn."""
    if not (other / "mocapfill" / "__init__.py").is_file():
        raise SystemExit(f"--against: {other} holds no mocapfill package")
    if not captures:
        raise SystemExit("--against: no capture to time (see --only)")
    rows = []
    print(f"{'capture':44s} {'this s':>8s} {'other s':>8s} {'ratio':>6s}", file=sys.stderr)
    for path, _ in captures:
        pairs = [(timed_in(harness.REPO, path, fill_jobs), timed_in(other, path, fill_jobs)) for _ in range(repeat)]
        this, theirs = (statistics.median(p[i] for p in pairs) for i in (0, 1))
        ratio = statistics.median(a / b for a, b in pairs)
        rows.append([harness.capture_name(path), round(this, 3), round(theirs, 3), round(ratio, 3)])
        print(f"{rows[-1][0][-44:]:44s} {this:8.3f} {theirs:8.3f} {ratio:6.3f}", file=sys.stderr, flush=True)
    rows.sort(key=lambda r: r[3])
    results.table("against", f"The default's fill seconds with this checkout and with another (median of {repeat} "
                  f"fill(s) each, in turn, each in its own process after a warm-up, on {resolve_jobs(fill_jobs)} "
                  "process(es)) and the median of the pairs' ratios",
                  ["capture", "this s", "other s", "this / other"], rows)
    median = statistics.median(r[3] for r in rows)
    results.figure("against_median_ratio", median, "ratio")
    print(f"median ratio {median:.3f} over {len(rows)} captures", file=sys.stderr)
    results.write()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="", help="only files whose path contains this text")
    parser.add_argument("--repeat", type=int, default=1, help="timed fills per capture after a warm-up (best kept)")
    parser.add_argument("--fill-jobs", type=int, default=None,
                        help="processes of each fill (default: mocapfill fill's default, 0 = every core)")
    parser.add_argument("--against", default="", help="another checkout: time this one's fills against its own")
    harness.add_results_argument(parser)
    args = parser.parse_args(argv)
    if args.repeat < 1:
        raise SystemExit("--repeat must be at least 1")
    fill_jobs = harness.cli_jobs() if args.fill_jobs is None else args.fill_jobs
    # (the comparison has a results file of its own: the stage table's stays as it was)
    path = args.results or (harness.RESULTS / "bench_stages_against.json" if args.against else None)
    results = harness.Results(__file__, argv, path, note=args.note)
    print(f"# {Path(__file__).name} ({harness.machine()})", file=sys.stderr)
    captures, _ = harness.gapped_captures()
    if args.only:
        captures = [(p, d) for p, d in captures if args.only in str(p)]
    if args.against:
        against(captures, Path(args.against).resolve(), args.repeat, fill_jobs, results)
        return
    rows = []
    columns = ["fill", *STAGES, "rest"]
    print(f"{'capture':44s} {'x bound':>7s} " + " ".join(f"{c:>8s}" for c in columns), file=sys.stderr)
    for path, _ in captures:
        r = measure(path, args.repeat, fill_jobs)
        rows.append(r)
        print(f"{r['file'][-44:]:44s} {r['fill'] / r['bound']:7.2f} "
              + " ".join(f"{r.get(c, 0.0):8.3f}" for c in columns), file=sys.stderr, flush=True)
    rows.sort(key=lambda r: -r["fill"] / r["bound"])
    results.table(
        "stages",
        f"The default's wall time by stage (seconds; the fastest of {args.repeat} fill(s) after a warm-up, on "
        f"{resolve_jobs(fill_jobs)} process(es)), captures by their fill's share of issue 21's bound",
        ["capture", "frames x markers", "bound s", "fill s", "x bound", *STAGES, "rest"],
        [[r["file"], f"{r['frames']} x {r['markers']}", round(r["bound"], 2), round(r["fill"], 2),
          round(r["fill"] / r["bound"], 2), *(round(r.get(c, 0.0), 2) for c in STAGES), round(r["rest"], 2)]
         for r in rows])
    total = sum(r["fill"] for r in rows)
    results.figure("fills_seconds", total, "s")
    results.figure("over_bound", sum(r["fill"] > r["bound"] for r in rows), "captures")
    print(f"{len(rows)} captures, {total:.1f} s of fills; over the bound: "
          + (", ".join(r["file"] for r in rows if r["fill"] > r["bound"]) or "none"), file=sys.stderr)
    for column in columns[1:]:
        share = sum(r.get(column, 0.0) for r in rows) / total if total else 0.0
        print(f"  {column:9s} {100 * share:5.1f} % of the fills' time", file=sys.stderr)
    results.write()


if __name__ == "__main__":
    main()
