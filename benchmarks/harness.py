"""The benchmark scripts' shared harness: BLAS set-up, machine banner, units, clips and trials, results JSON.

Every script in ``benchmarks/`` is run from the repository root as ``python benchmarks/bench_x.py``; Python then
puts ``benchmarks/`` first on ``sys.path``, so a script imports this module as ``import harness`` (never another
script). Importing it puts the repository root on ``sys.path`` too, so that ``mocapfill`` is this checkout's when the
package is not installed. It imports nothing heavy: a script that pins BLAS calls :func:`pin_blas` before NumPy is
imported::

    import harness

    harness.pin_blas()

    import numpy as np  # noqa: E402

Results: a script collects its tables and headline figures in a :class:`Results` and writes them to
``benchmarks/results/<script-stem>.json`` (format in ``benchmarks/README.md``); ``benchmarks/tables.py`` renders the
tables into the READMEs and ``benchmarks/compare.py`` names every figure worse than ``benchmarks/results/floor/``.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any, Sequence

BENCHMARKS = Path(__file__).resolve().parent
REPO = BENCHMARKS.parent
RESULTS = BENCHMARKS / "results"
FLOOR = RESULTS / "floor"
SAMPLE_DATA = REPO / "sample_data"
#: The shared real captures (``../shared/data``, or ``$MOCAPFILL_SHARED_DATA``); scripts skip what is absent.
SHARED_DATA = Path(os.environ.get("MOCAPFILL_SHARED_DATA") or REPO.parent / "shared" / "data")
#: A copy of opensim-org/opensim-models (``$OPENSIM_MODELS``, default ``/tmp/osm``): its example pipelines' captures
#: (no license file there: fetched, never committed), read by ``bench_ik.py`` and ``bench_default_captures.py``.
OPENSIM_MODELS = Path(os.environ.get("OPENSIM_MODELS", "/tmp/osm"))
#: The bundled complete clips most scripts measure on: CMU 85_02 (41 markers, 810 frames at 120 Hz, mm) and the
#: OptiTrack tennis serve (39 markers, 1,092 frames at 50 Hz, m).
CLIP_85_02 = SAMPLE_DATA / "85_02.c3d"
CLIP_TENNIS = SAMPLE_DATA / "kinematics_tennis_serve.c3d"
#: The tennis serve with ten real-looking gaps (145 missing samples), the complete twin of :data:`CLIP_TENNIS`.
CLIP_TENNIS_NAN = SAMPLE_DATA / "kinematics_tennis_serve_nan.c3d"

#: Complete real captures by name (no gaps: ground truth to occlude): the two bundled clips and, when
#: ``SHARED_DATA`` is present, Vicon Nexus's arm + robot (33 markers, 800 frames at 100 Hz) and the BTK sprint (59
#: markers, 788 frames at 250 Hz).  Scripts skip the paths that do not exist.
COMPLETE_CLIPS = {
    "85_02": CLIP_85_02,
    "tennis": CLIP_TENNIS,
    "pyorerun-example": SHARED_DATA / "pyorerun" / "example.c3d",
    "sprint": SHARED_DATA / "btk" / "TRCSamples" / "SprintMotion.trc",
}

if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

#: The thread-count variables of the BLAS libraries NumPy may use.
BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def pin_blas() -> None:
    """BLAS on one thread unless the environment says otherwise (call before NumPy is imported).

    The fills work on many small matrices, where BLAS threads only add contention: on the shared 2-core machine two
    threads made the default fill of a many-gaps layout 17.8 s instead of 2.7 s. The setting is in the banner.
    """
    for variable in BLAS_VARIABLES:
        os.environ.setdefault(variable, "1")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what :mod:`platform` knows."""
    try:
        with open("/proc/cpuinfo") as handle:
            return next(line.split(":", 1)[1].strip() for line in handle if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


def machine() -> str:
    """One line: CPU, cores, load average, Python, NumPy, SciPy and the BLAS thread setting."""
    import numpy
    import scipy

    load = " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "?"
    return (f"{cpu_model()} ({platform.machine()}), {os.cpu_count()} cores, load {load}, "
            f"Python {platform.python_version()}, NumPy {numpy.__version__}, SciPy {scipy.__version__}, "
            f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")


def utc_now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())


def git_commit() -> str:
    """The checkout's short commit, with ``+dirty`` when ``mocapfill/`` has uncommitted changes ("unknown" without git):
    what made a cached result."""
    import subprocess

    try:
        head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--", "mocapfill"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def banner(script: str, file=None) -> None:
    """Print the run's first two lines: the script and the time, then :func:`machine`."""
    print(f"# {Path(script).stem}  {utc_now()}\n# machine: {machine()}", file=file or sys.stdout, flush=True)


def mm_per_unit(units: str) -> float:
    """Millimetres per unit of a capture (``mocapfill.units.MM_PER_UNIT``)."""
    from mocapfill.units import MM_PER_UNIT

    return MM_PER_UNIT[units]


def palindrome(positions, n_frames: int, *, repeat_turns: bool):
    """``positions`` (n, n_markers, 3) played forwards, backwards, forwards ... to ``n_frames`` frames.

    ``repeat_turns``: the first and last frames appear twice at each turn (forwards then the whole clip reversed);
    otherwise no frame is repeated (no standstill at the turns). Returns a new (n_frames, n_markers, 3) array.
    """
    import numpy as np

    back = positions[::-1] if repeat_turns else positions[-2:0:-1]
    cycle = np.concatenate([positions, back])
    return np.tile(cycle, (-(-n_frames // len(cycle)), 1, 1))[:n_frames].copy()


def paper_trial(truth, labels: Sequence[str], protocol: str, seed: int):
    """One trial of the BoLeRO paper's protocol (Li et al. 2010, section 4): ``(occluded, hidden)``.

    ``truth`` (n_frames, n_markers, 3); one random marker (``"marker"``), or the two markers of one limb (RKNE +
    RSHN, else RKNE + RTIB: ``"limb"``), hidden for one segment of 10-50 % of the clip; ``"blackout"``: every marker
    for 15-45 frames. ``hidden`` (n_frames, n_markers) bool. Kept as the figures of ``bench_bolero.py`` were
    measured: :func:`mocapfill.evaluation.make_occlusions`' ``marker`` / ``limb`` draw other segments and limbs.
    """
    import numpy as np

    rng = np.random.default_rng(seed)
    n_frames, n_markers, _ = truth.shape
    length = int(rng.integers(int(0.1 * n_frames), int(0.5 * n_frames) + 1))
    start = int(rng.integers(0, n_frames - length + 1))
    if protocol == "blackout":
        length = int(rng.integers(15, 46))
        start = int(rng.integers(1, n_frames - length))
        markers = list(range(n_markers))
    else:
        markers = [int(rng.integers(n_markers))] if protocol == "marker" else list(limb_pair(labels))
    hidden = np.zeros((n_frames, n_markers), dtype=bool)
    hidden[start:start + length, markers] = True
    occluded = truth.copy()
    occluded[hidden] = np.nan
    return occluded, hidden


#: The two markers of one limb hidden together in :func:`paper_trial`, by label suffix, in order of preference.
LIMB_PAIRS = [("RKNE", "RSHN"), ("RKNE", "RTIB")]


def limb_pair(labels: Sequence[str]) -> tuple[int, int]:
    names = [label.split(":")[-1].strip().upper() for label in labels]
    for a, b in LIMB_PAIRS:
        if a in names and b in names:
            return names.index(a), names.index(b)
    raise SystemExit("no limb pair found among the labels")


def occluded_trials(data, protocol: str, **options):
    """``(trial, occluded positions, hidden mask)`` for each trial of :func:`mocapfill.evaluation.make_occlusions`."""
    from mocapfill.evaluation import make_occlusions

    for trial in make_occlusions(data, protocol, **options):
        occluded, hidden, _ = trial.apply(data.positions)
        yield trial, occluded, hidden


class Results:
    """The tables and headline figures of one run, written to ``benchmarks/results/<stem>.json``.

    Format: ``{"script", "command", "machine", "date", "tables": {name: {"title", "columns", "rows", "command",
    "date"}}, "figures": {name: {"value", "unit", "better", "command", "date"}}}``. A run that measures only some
    sections (``--skip``, ``--methods``) replaces only the tables and figures it produced; the others keep the
    command and date of the run that produced them.
    """

    def __init__(self, script: str, argv: Sequence[str] | None = None, path: str | Path | None = None,
                 note: str | None = None):
        self.path = None if path == "-" else Path(path) if path else RESULTS / f"{Path(script).stem}.json"
        self.script = Path(script).name
        self.stem = Path(script).stem
        args = list(sys.argv[1:] if argv is None else argv)
        self.command = " ".join(["python", f"benchmarks/{self.script}", *args])
        self.date = time.strftime("%Y-%m-%d", time.gmtime())
        self.machine = machine()
        self.tables: dict[str, dict] = {}
        self.figures: dict[str, dict] = {}
        self.note = note

    def table(self, name: str, title: str, columns: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        self.tables[name] = {"title": title, "columns": list(columns), "rows": [list(map(plain, r)) for r in rows],
                             "command": self.command, "date": self.date, **({"note": self.note} if self.note else {})}

    def figure(self, name: str, value: float, unit: str, better: str = "lower") -> None:
        """A headline figure; ``better`` is "lower" or "higher" (what ``compare.py`` checks)."""
        if better not in ("lower", "higher"):
            raise ValueError(f"better must be 'lower' or 'higher', not {better!r}")
        self.figures[name] = {"value": plain(value), "unit": unit, "better": better, "command": self.command,
                              "date": self.date}

    def write(self) -> Path | None:
        """Merge this run's tables and figures into the results file (none with ``--results -``)."""
        path = self.path
        if path is None:
            return None
        old = json.loads(path.read_text()) if path.is_file() else {}
        doc = {"script": self.script, "command": self.command, "machine": self.machine, "date": self.date,
               "tables": {**old.get("tables", {}), **self.tables},
               "figures": {**old.get("figures", {}), **self.figures}}
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(dumps(doc))
        tmp.replace(path)
        print(f"# results: {path.relative_to(REPO) if path.is_relative_to(REPO) else path}", file=sys.stderr)
        return path


def dumps(doc: dict) -> str:
    """JSON with one line per table row and per figure (readable diffs of results files)."""
    def compact(value, depth):
        if isinstance(value, dict) and (depth < 2 or "rows" in value):
            inner = ",\n".join(f"{' ' * (depth + 1)}{json.dumps(k)}: {compact(v, depth + 1)}" for k, v in value.items())
            return "{\n" + inner + "\n" + " " * depth + "}" if value else "{}"
        if isinstance(value, list) and value and all(isinstance(row, list) for row in value):
            rows = ",\n".join(" " * (depth + 1) + json.dumps(row) for row in value)
            return "[\n" + rows + "\n" + " " * depth + "]"
        return json.dumps(value)

    return compact(doc, 0) + "\n"


def cmu41_layout() -> list[str]:
    """The CMU 41-marker set: 85_02's labels without their ``Subject:`` prefix."""
    import mocapfill
    from mocapfill.references import bare_label

    return [bare_label(x) for x in mocapfill.read(CLIP_85_02).labels]


def cmu41_clip(name: str, labels: Sequence[str]):
    """A CMU clip of the 41-marker set (``85_02``, a ``bolero/`` CSV at 120 Hz, or a ``cmu-train/`` C3D) restricted
    to ``labels`` (without prefix) in that order: a MarkerData named ``name``."""
    import mocapfill
    from mocapfill.markers import MarkerData
    from mocapfill.references import bare_label

    if name == "85_02":
        data = mocapfill.read(CLIP_85_02)
    elif name in ("127_07", "132_32"):
        data = mocapfill.read(SHARED_DATA / "bolero" / f"{name}.csv", rate=120)
    else:
        data = mocapfill.read(SHARED_DATA / "cmu-train" / f"{name}.c3d")
    bare = [bare_label(x) for x in data.labels]
    idx = [bare.index(x) for x in labels]
    return MarkerData(data.positions[:, idx].copy(), list(labels), data.rate, data.units, path=name)


def add_results_argument(parser) -> None:
    """``--results PATH`` on a script's parser: where :class:`Results` writes (``-``: nowhere)."""
    parser.add_argument("--results", default=None, metavar="PATH",
                        help="results JSON to write (default: benchmarks/results/<script>.json; '-': none)")
    parser.add_argument("--note", default=None, help="a note for every table of this run (e.g. how busy the machine "
                        "was), shown under the table")


def plain(value: Any) -> Any:
    """A JSON-ready cell: NumPy scalars as Python numbers, NaN as None."""
    if hasattr(value, "item") and not isinstance(value, (list, tuple, dict, str)):
        value = value.item()
    if isinstance(value, float) and value != value:
        return None
    return value


#: Where the real captures are looked for (issue 21's "every real capture with gaps").
CAPTURE_ROOTS = (REPO / "sample_data", REPO / "tests" / "data", SHARED_DATA)
CAPTURE_SUFFIXES = (".c3d", ".trc", ".csv", ".tsv")


def capture_name(path: Path) -> str:
    """A capture's path as the tables name it: relative to the repository, or under ``../shared/data/``."""
    for root in CAPTURE_ROOTS:
        if root in path.parents:
            prefix = "../shared/data/" if root == SHARED_DATA else ""
            return prefix + str(path.relative_to(SHARED_DATA if root == SHARED_DATA else REPO))
    return str(path)


def gapped(data):
    """(n_frames, n_markers) bool: the samples a fill has to supply (marker points only; markers missing throughout
    and the blank frames before the first / after the last frame where a marker is observed excluded)."""
    import numpy as np

    missing = np.isnan(data.positions).any(axis=2)
    marker = np.array([k == "marker" for k in (data.kinds or ["marker"] * data.n_markers)])
    seen = ~missing.all(axis=0) & marker
    some = np.flatnonzero((~missing[:, marker]).any(axis=1)) if marker.any() else np.zeros(0, dtype=int)
    frames = np.zeros(missing.shape[0], dtype=bool)
    if some.size:  # between the first and the last frame where a marker is seen (interior blackouts count)
        frames[some[0]:some[-1] + 1] = True
    return missing & seen[None, :] & frames[:, None]


def gapped_captures() -> tuple[list[tuple[Path, str]], list[str]]:
    """(gapped captures as (path, sha256), skipped lines): every readable file with gaps, each content once."""
    import hashlib
    import warnings

    from mocapfill.errors import MocapfillError
    from mocapfill.io import read

    found, skipped, seen = [], [], {}
    for root in CAPTURE_ROOTS:
        if not root.is_dir():
            skipped.append(f"{root}: absent")
            continue
        for path in sorted(p for p in root.rglob("*") if p.suffix.lower() in CAPTURE_SUFFIXES and p.is_file()):
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
            if digest in seen:
                skipped.append(f"{capture_name(path)}: the same file as {capture_name(seen[digest])}")
                continue
            seen[digest] = path
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    data = read(path)  # as `mocapfill fill IN OUT` reads it, without options
            except (MocapfillError, OSError, ValueError) as exc:
                skipped.append(f"{capture_name(path)}: not read without options ({str(exc).splitlines()[0][:90]})")
                continue
            if not gapped(data).any():
                continue
            found.append((path, digest))
    return found, skipped


def speed_bound(duration: float) -> float:
    """Issue 21's bound on a fill's seconds for a capture of ``duration`` seconds: 0.25 x its duration, or 1 s where
    that is larger."""
    return max(0.25 * duration, 1.0)


def cli_jobs() -> int:
    """``mocapfill fill``'s default ``--jobs`` (the processes a fill runs on when the user says nothing)."""
    from mocapfill.cli.fill import fill_command

    return next(p.default for p in fill_command.params if p.name == "jobs")


def config_tag(config: dict | None) -> str:
    """The cache files' suffix for a run of ``auto`` with :class:`~mocapfill.methods.auto_config.ModelConfig` fields
    changed (``--config``): "" for the default, else "_" and a hash of the fields, so a variant's fills are cached
    apart."""
    import hashlib

    return "_" + hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()[:8] if config else ""


@contextlib.contextmanager
def auto_config(config: dict | None):
    """Within the block, ``auto`` fills with those ModelConfig fields changed (None or {}: the default), also where a
    script fills through :func:`mocapfill.pipeline.fill_capture`, as ``mocapfill fill`` does, which takes no config.
    It changes the keyword default of :func:`~mocapfill.methods.auto.fill_auto` and restores it."""
    if not config:
        yield
        return
    from mocapfill.methods import auto
    from mocapfill.methods.auto_config import ModelConfig

    before = auto.fill_auto.__kwdefaults__["config"]
    auto.fill_auto.__kwdefaults__["config"] = ModelConfig(**config)
    try:
        yield
    finally:
        auto.fill_auto.__kwdefaults__["config"] = before


def capture_options(parser, cache: Path) -> None:
    """The options of a script that fills the real captures with gaps one (capture, method) at a time, caching
    each: ``--rerun`` (methods to fill again), ``--only`` (a path substring) and ``--cache`` (default ``cache``)."""
    parser.add_argument("--rerun", default="", help="comma-separated methods to fill again though cached")
    parser.add_argument("--only", default="", help="only files whose path contains this text")
    parser.add_argument("--cache", default=str(cache))
