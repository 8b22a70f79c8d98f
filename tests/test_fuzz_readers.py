"""A fast seeded slice of ``benchmarks/fuzz_readers.py``: mutated real files (every format) are read, filled and
written in memory, in this process; anything but a MocapfillError fails.  The full run (10,000 cases, each in a
worker process with a time limit) is the benchmark."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "fuzz_readers.py"
if str(_PATH.parent) not in sys.path:  # the script imports the benchmarks' harness, as when run from benchmarks/
    sys.path.insert(0, str(_PATH.parent))


@pytest.fixture(scope="module")
def fuzz():
    spec = importlib.util.spec_from_file_location("fuzz_readers", _PATH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module, module.seed_files()


def test_every_format_is_seeded(fuzz):
    module, seeds = fuzz
    assert {fmt for _, fmt, _ in seeds} == {"c3d", "csv", "vicon-csv", "trc", "tsv", "motive-csv"}
    for name, fmt, raw in seeds:  # unmutated, each seed reads, fills and writes
        assert module.run_case(raw, fmt, True) == "ok", name


@pytest.mark.slow
@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(index=st.integers(min_value=0, max_value=10**9))
def test_mutated_files_raise_only_our_errors(fuzz, index):
    module, seeds = fuzz
    name, fmt, applied, raw, given_format = module.make_case(seeds, index, seed=12)
    assert module.run_case(raw, fmt, given_format) in ("ok", "rejected")


def test_header_only_files_write_in_every_format(fuzz):
    """Found by fuzzing (seed 1, case 1997): a TSV truncated to its header crashed the writers (a reshape of 0 rows)."""
    module, _ = fuzz
    text = "NO_OF_FRAMES\t0\nNO_OF_MARKERS\t2\nFREQUENCY\t100\nMARKER_NAMES\tA\tB\n"
    assert module.run_case(text.encode(), "tsv", True) == "ok"
    assert module.run_case(b"frame,time,A_x,A_y,A_z\n", "csv", True) in ("ok", "rejected")


def test_frame_numbers_and_rates_that_are_not_numbers_are_our_errors(fuzz, tmp_path):
    """Found by fuzzing (seed 0, cases 2030 and 3864): ``first_frame=nan`` in our CSV comment line escaped as
    ValueError; a rate of 1e308 Hz escaped from the C3D writer as OverflowError (float32 field)."""
    module, _ = fuzz
    body = "frame,time,A_x,A_y,A_z\n1,0.0,1,2,3\n2,0.01,1,2,3\n"
    nan_frame = "# mocapfill csv: units=mm rate=100.0 first_frame=nan\n" + body
    assert module.run_case(nan_frame.encode(), "csv", True) == "rejected"
    huge_rate = "# mocapfill csv: units=mm rate=1e308 first_frame=1\n" + body
    assert module.run_case(huge_rate.encode(), "csv", True) == "rejected"
    for empty_first in ("frame,time,A_x,A_y,A_z\n,0.0,1,2,3\n", "PathFileType\t4\n"):
        assert module.run_case(empty_first.encode(), None, False) in ("ok", "rejected")
