"""Name every figure of a new results file that got worse than the floor (``benchmarks/results/floor/``).

    python benchmarks/compare.py benchmarks/results/bench_default.json [--floor FLOOR.json] [--rtol 0.05]

Each figure of the floor says whether lower or higher is better; a figure is worse when it moved the wrong way by
more than ``--rtol`` of the floor's value (default 0: any worsening; give a tolerance for seconds, which are noisy on
a shared machine). A figure of the floor that the new run did not produce is listed as missing (a partial run:
``--skip``, ``--methods``). Exit status 1 when anything got worse.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

FLOOR = Path(__file__).resolve().parent / "results" / "floor"


def worse(old: dict, new: dict, rtol: float = 0.0) -> bool:
    """Whether figure ``new`` is worse than ``old`` (both {"value", "better", ...}) by more than ``rtol``."""
    a, b = old["value"], new["value"]
    if a is None or b is None:
        return False
    slack = rtol * abs(a)
    return b > a + slack if old.get("better", "lower") == "lower" else b < a - slack


def compare(floor: dict, new: dict, rtol: float = 0.0) -> tuple[list[str], list[str]]:
    """(lines naming each worse figure, names of the floor's figures the new run lacks)."""
    bad, missing = [], []
    for name, old in floor.get("figures", {}).items():
        fig = new.get("figures", {}).get(name)
        if fig is None:
            missing.append(name)
        elif worse(old, fig, rtol):
            unit = old.get("unit", "")
            bad.append(f"{name}: {fig['value']} {unit} against the floor's {old['value']} {unit} "
                       f"({old.get('better', 'lower')} is better; floor from `{old.get('command', floor['command'])}`)")
    return bad, missing


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("new", type=Path, help="a results JSON written by a benchmark script")
    parser.add_argument("--floor", type=Path, default=None,
                        help="default: benchmarks/results/floor/<the file's name>, else <its script's name>")
    parser.add_argument("--rtol", type=float, default=0.0, help="relative tolerance (default 0)")
    args = parser.parse_args(argv)
    new = json.loads(args.new.read_text())
    # a results file of its own name (a script's run on other inputs, ``--out``) has its own floor where one exists
    own = FLOOR / f"{args.new.stem}.json"
    floor_path = args.floor or (own if own.is_file() else FLOOR / f"{Path(new.get('script', args.new.name)).stem}.json")
    floor = json.loads(floor_path.read_text())
    bad, missing = compare(floor, new, args.rtol)
    for line in bad:
        print(f"worse: {line}")
    if missing:
        print(f"not in {args.new}: {len(missing)} of the floor's figures ({', '.join(missing[:8])}"
              f"{', ...' if len(missing) > 8 else ''})", file=sys.stderr)
    print(f"{len(bad)} of {len(floor.get('figures', {}))} figures worse than {floor_path}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
