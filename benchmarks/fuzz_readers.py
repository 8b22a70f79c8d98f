"""Fuzzing of the readers: mutated real files are read, filled and written in memory; only our own errors may escape.

Seeds (every format the package reads): the committed real files in ``tests/data/`` (C3D from six vendors, TRC,
OptiTrack Motive CSV, Qualisys TSV when one is committed), the Vicon Nexus CSV ``sample_data/markers.csv``, and,
for the formats no committed file is in, the real capture ``tests/data/Running_0002.c3d`` (Qualisys) written by
our own writers (plain CSV, and QTM TSV unless a real TSV is committed).

Each case (case ``i`` of seed ``--seed`` is always the same bytes) takes one seed file and applies one to three
mutations: bit flips, truncation, byte splices (a chunk copied over another place, inserted, or deleted), random
bytes inserted, value edits (text: numbers anywhere replaced by 0, -1, a huge value, ``nan``, ``inf``, garbage or
nothing; C3D: data words set to NaN / inf / huge float32) and header edits (text: a number in the first lines
replaced the same way, a line deleted or duplicated, a stray carriage return / quote / tab / NUL; C3D: a 16-bit
word of the header or parameter section set to an extreme value).  The result is read (half the cases with the
seed's format given, half sniffed from the content), filled with ``linear`` and written to memory in every
writable format.

Outcomes: ``ok`` (read, filled, written), ``rejected`` (a :class:`mocapfill.errors.MocapfillError`: the wanted
answer to a broken file), ``crash`` (any other exception) and ``hang`` (over ``--timeout`` seconds; each case runs
in a worker process that is killed and replaced on a hang).  The exit status is 1 when a crash or hang occurred.

Run from the repository root::

    python benchmarks/fuzz_readers.py --n 10000 [--seed 0] [--jobs 1] [--timeout 20] [--save DIR]

``--save DIR`` writes the bytes of each crashing / hanging case there (to reproduce it: ``mocapfill info FILE``).
"""

from __future__ import annotations

import harness

harness.pin_blas()

import argparse  # noqa: E402
import io  # noqa: E402
import multiprocessing as mp  # noqa: E402
import os  # noqa: E402
import queue  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
import warnings  # noqa: E402
from collections import Counter  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from mocapfill.errors import MocapfillError  # noqa: E402

TEST_DATA = harness.REPO / "tests" / "data"
SAMPLE_DATA = harness.SAMPLE_DATA


def seed_files() -> list[tuple[str, str, bytes]]:
    """``(name, format, bytes)`` of every seed, in a fixed order."""
    from mocapfill.io import read
    from mocapfill.io.csv import csv_text
    from mocapfill.io.tsv import tsv_text

    seeds = []
    for path in sorted(TEST_DATA.iterdir()):
        fmt = {".c3d": "c3d", ".trc": "trc", ".tsv": "tsv", ".csv": "csv"}.get(path.suffix.lower())
        if fmt is None:
            continue
        raw = path.read_bytes()
        if fmt == "csv" and raw.lstrip().lower().startswith(b"format version,"):
            fmt = "motive-csv"
        seeds.append((path.name, fmt, raw))
    vicon = SAMPLE_DATA / "markers.csv"
    if vicon.is_file():
        seeds.append((vicon.name, "vicon-csv", vicon.read_bytes()))
    base = read(TEST_DATA / "Running_0002.c3d")
    seeds.append(("Running_0002.csv (written)", "csv", csv_text(base).encode()))
    if not any(fmt == "tsv" for _, fmt, _ in seeds):
        seeds.append(("Running_0002.tsv (written)", "tsv", tsv_text(base).encode()))
    return seeds


_EDITS = [b"0", b"-1", b"99999999999", b"-2147483648", b"nan", b"inf", b"", b"x", b"1e308", b"0.5", b"65535"]
_NUMBER = re.compile(rb"-?\d+(\.\d+)?([eE][-+]?\d+)?")


def _bit_flips(raw: bytearray, rng: np.random.Generator) -> bytearray:
    for _ in range(int(rng.integers(1, 9))):
        if raw:
            i = int(rng.integers(len(raw)))
            raw[i] ^= 1 << int(rng.integers(8))
    return raw


def _truncate(raw: bytearray, rng: np.random.Generator) -> bytearray:
    return raw[:int(rng.integers(0, len(raw) + 1))]


def _splice(raw: bytearray, rng: np.random.Generator) -> bytearray:
    if len(raw) < 2:
        return raw
    n = len(raw)
    a = int(rng.integers(n))
    size = int(rng.integers(1, min(4096, n - a) + 1))
    chunk = raw[a:a + size]
    b = int(rng.integers(n))
    how = int(rng.integers(3))
    if how == 0:
        return raw[:b] + chunk + raw[b + size:]  # overwrite
    if how == 1:
        return raw[:b] + chunk + raw[b:]  # insert
    return raw[:a] + raw[a + size:]  # delete


def _random_bytes(raw: bytearray, rng: np.random.Generator) -> bytearray:
    b = int(rng.integers(len(raw) + 1))
    junk = rng.integers(0, 256, size=int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
    return raw[:b] + junk + raw[b:]


def _header_text(raw: bytearray, rng: np.random.Generator) -> bytearray:
    lines = bytes(raw).split(b"\n")
    k = min(len(lines), 12)
    i = int(rng.integers(k)) if k else 0
    how = int(rng.integers(7))
    if not lines:
        return raw
    line = lines[i]
    if how == 0:
        numbers = list(_NUMBER.finditer(line))
        if numbers:
            m = numbers[int(rng.integers(len(numbers)))]
            line = line[:m.start()] + _EDITS[int(rng.integers(len(_EDITS)))] + line[m.end():]
    elif how == 1:
        del lines[i]
        return bytearray(b"\n".join(lines))
    elif how == 2:
        lines.insert(i, line)
        return bytearray(b"\n".join(lines))
    else:
        at = int(rng.integers(len(line) + 1))
        line = line[:at] + [b"\r", b'"', b"\t", b"\x00"][how - 3] + line[at:]
        if rng.random() < 0.3:
            j = int(rng.integers(len(lines)))
            lines[j] = lines[j][:1] + b"\r" + lines[j][1:]
    lines[i] = line
    return bytearray(b"\n".join(lines))


def _header_c3d(raw: bytearray, rng: np.random.Generator) -> bytearray:
    limit = min(len(raw), 512 * int(rng.integers(1, 12)))
    if limit < 2:
        return raw
    i = int(rng.integers(limit - 1))
    value = int(rng.choice([0, 1, 0x7FFF, 0x8000, 0xFFFF, 0xFF, 0x100, int(rng.integers(65536))]))
    raw[i:i + 2] = value.to_bytes(2, "little")
    return raw


def _values_text(raw: bytearray, rng: np.random.Generator) -> bytearray:
    """A few numbers anywhere in a text file replaced by edge values (0, huge, nan, inf, nothing, ...)."""
    numbers = list(_NUMBER.finditer(bytes(raw[:2_000_000])))
    if not numbers:
        return raw
    out = bytes(raw)
    for k in sorted(rng.choice(len(numbers), size=min(len(numbers), int(rng.integers(1, 6))), replace=False),
                    reverse=True):
        m = numbers[int(k)]
        out = out[:m.start()] + _EDITS[int(rng.integers(len(_EDITS)))] + out[m.end():]
    return bytearray(out)


def _values_c3d(raw: bytearray, rng: np.random.Generator) -> bytearray:
    """A few 4-byte words past the parameter section set to extreme float32 / int patterns."""
    if len(raw) < 2048:
        return raw
    for _ in range(int(rng.integers(1, 6))):
        i = int(rng.integers(1536, len(raw) - 4))
        value = rng.choice([np.float32(np.nan), np.float32(np.inf), np.float32(-1), np.float32(3e38),
                            np.float32(0), np.float32(-1e-40)])
        raw[i:i + 4] = np.float32(value).tobytes()
    return raw


MUTATIONS = {"bitflip": _bit_flips, "truncate": _truncate, "splice": _splice, "random-bytes": _random_bytes,
             "header": None, "values": None}


def make_case(seeds, index: int, seed: int = 0) -> tuple[str, str, list[str], bytes, bool]:
    """Case ``index``: ``(seed name, format, mutations applied, bytes, format given?)``; deterministic."""
    rng = np.random.default_rng([seed, index])
    name, fmt, raw = seeds[int(rng.integers(len(seeds)))]
    data = bytearray(raw)
    applied = []
    for _ in range(int(rng.integers(1, 4))):
        kind = list(MUTATIONS)[int(rng.integers(len(MUTATIONS)))]
        if kind == "header":
            data = _header_c3d(data, rng) if fmt == "c3d" else _header_text(data, rng)
        elif kind == "values":
            data = _values_c3d(data, rng) if fmt == "c3d" else _values_text(data, rng)
        else:
            data = MUTATIONS[kind](data, rng)
        applied.append(kind)
    return name, fmt, applied, bytes(data), bool(rng.random() < 0.5)


def run_case(raw: bytes, fmt: str, give_format: bool) -> str:
    """Read, fill (linear) and write ``raw`` in memory: "ok" or "rejected"; anything else raises."""
    from mocapfill.api import fill
    from mocapfill.io import WRITE_FORMATS, read, write

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            stream = io.BytesIO(raw)
            data = read(stream, format=fmt if give_format else None)
            if data.n_frames and data.n_markers:
                result = fill(data, method="linear")
                data = data.with_positions(result.positions)
            for out_format in WRITE_FORMATS:
                write(data, io.BytesIO(), format=out_format)
        except MocapfillError:
            return "rejected"
    return "ok"


def _worker(seed: int, tasks, results) -> None:
    seeds = seed_files()
    parent = os.getppid()
    while True:
        try:
            index = tasks.get(timeout=1.0)
        except queue.Empty:
            if os.getppid() != parent:
                return  # the driver was killed: do not linger
            continue
        if index is None:
            return
        name, fmt, applied, raw, given = make_case(seeds, index, seed)
        try:
            outcome, detail = run_case(raw, fmt, given), ""
        except BaseException as exc:  # noqa: BLE001 - every escape is the finding
            outcome = "crash"
            detail = f"{type(exc).__name__}: {str(exc)[:200]} | " + \
                     traceback.format_exc().strip().splitlines()[-3].strip()[:200]
        results.put((index, outcome, detail))


class Worker:
    """One case at a time in a child process, killed and replaced when a case exceeds the time limit."""

    def __init__(self, seed: int):
        self.seed = seed
        self.ctx = mp.get_context("spawn")
        self._start()

    def _start(self) -> None:
        self.tasks, self.results = self.ctx.Queue(), self.ctx.Queue()
        self.proc = self.ctx.Process(target=_worker, args=(self.seed, self.tasks, self.results), daemon=True)
        self.proc.start()

    def run(self, index: int, timeout: float, startup: float = 60.0) -> tuple[str, str, float]:
        start = time.perf_counter()
        self.tasks.put(index)
        deadline = start + timeout + (startup if not getattr(self, "_warm", False) else 0.0)
        while True:
            try:
                got, outcome, detail = self.results.get(timeout=0.2)
                break
            except queue.Empty:
                died = not self.proc.is_alive()
                if died or time.perf_counter() > deadline:
                    # a worker that died (segfault, os._exit) crashed; one still running hangs
                    self.proc.kill()
                    self.proc.join()
                    outcome = "crash" if died else "hang"
                    detail = f"worker died (exit code {self.proc.exitcode})" if died else f"over {timeout:g} s"
                    self._start()
                    self._warm = False
                    return outcome, detail, time.perf_counter() - start
        self._warm = True
        return outcome, detail, time.perf_counter() - start

    def close(self) -> None:
        if self.proc.is_alive():
            self.tasks.put(None)
            self.proc.join(5)
            if self.proc.is_alive():
                self.proc.kill()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=1000, help="number of cases")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--start", type=int, default=0, help="first case index (to resume or split a run)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    parser.add_argument("--timeout", type=float, default=20.0, help="seconds a case may take")
    parser.add_argument("--save", type=Path, default=None, help="directory for the bytes of crashing cases")
    harness.add_results_argument(parser)
    args = parser.parse_args(argv)

    seeds = seed_files()
    harness.banner(__file__)
    print(f"fuzz_readers: {args.n} cases from {len(seeds)} seed files, seed {args.seed}, {args.jobs} worker(s), "
          f"{args.timeout:g} s per case", flush=True)
    for name, fmt, raw in seeds:
        print(f"  seed {name} ({fmt}, {len(raw):,} bytes)")
    workers = [Worker(args.seed) for _ in range(max(1, args.jobs))]
    counts: Counter = Counter()
    by_format: dict[str, Counter] = {}
    findings = []
    slowest = (0.0, -1)
    t0 = time.perf_counter()
    pending = list(range(args.start, args.start + args.n))
    if args.save:
        args.save.mkdir(parents=True, exist_ok=True)

    import threading

    lock = threading.Lock()

    def drive(worker: Worker) -> None:
        nonlocal slowest
        while True:
            with lock:
                if not pending:
                    return
                index = pending.pop(0)
            outcome, detail, seconds = worker.run(index, args.timeout)
            name, fmt, applied, raw, given = make_case(seeds, index, args.seed)
            with lock:
                counts[outcome] += 1
                by_format.setdefault(fmt, Counter())[outcome] += 1
                slowest = max(slowest, (seconds, index))
                if outcome in ("crash", "hang"):
                    findings.append((index, outcome, name, "+".join(applied), detail))
                    print(f"  case {index}: {outcome.upper()} {name} [{'+'.join(applied)}] {detail}", flush=True)
                    if args.save:
                        (args.save / f"case{index}-{fmt}.bin").write_bytes(raw)
                done = sum(counts.values())
                if done % 500 == 0:
                    print(f"  {done} cases, {time.perf_counter() - t0:.0f} s: {dict(counts)}", flush=True)

    threads = [threading.Thread(target=drive, args=(w,)) for w in workers]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for w in workers:
        w.close()
    elapsed = time.perf_counter() - t0
    print(f"\n{sum(counts.values())} cases in {elapsed:.0f} s ({elapsed / max(1, sum(counts.values())):.3f} s a case, "
          f"slowest {slowest[0]:.2f} s: case {slowest[1]}); load average {os.getloadavg()[0]:.2f}")
    print(f"{'format':<12} {'cases':>6} {'ok':>6} {'rejected':>9} {'crash':>6} {'hang':>5}")
    for fmt in sorted(by_format):
        c = by_format[fmt]
        print(f"{fmt:<12} {sum(c.values()):>6} {c['ok']:>6} {c['rejected']:>9} {c['crash']:>6} {c['hang']:>5}")
    c = counts
    print(f"{'all':<12} {sum(c.values()):>6} {c['ok']:>6} {c['rejected']:>9} {c['crash']:>6} {c['hang']:>5}")
    print(f"crashes: {c['crash']}, hangs: {c['hang']}")
    results = harness.Results(__file__, argv, args.results, note=args.note)
    OUTCOMES = ("ok", "rejected", "crash", "hang")  # noqa: N806
    results.table("outcomes", f"{sum(c.values())} mutated files (seed {args.seed}), read, filled with `linear` and "
                  f"written in every writable format; {args.timeout:g} s a case at most",
                  ["format", "cases", "ok", "rejected", "crash", "hang"],
                  [[fmt, sum(by_format[fmt].values()), *(by_format[fmt][k] for k in OUTCOMES)]
                   for fmt in sorted(by_format)] + [["all", sum(c.values()), c["ok"], c["rejected"], c["crash"],
                                                     c["hang"]]])
    results.figure("crashes", c["crash"], "cases")
    results.figure("hangs", c["hang"], "cases")
    results.figure("slowest_case", round(slowest[0], 2), "s")
    results.write()
    return 1 if c["crash"] or c["hang"] else 0


if __name__ == "__main__":
    sys.exit(main())
