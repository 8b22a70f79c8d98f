"""Render the benchmark tables of ``benchmarks/results/*.json`` into README.md and benchmarks/README.md.

A table lives in a README between two markers, the script's stem and the table's name::

    <!-- results:bench_default/summary -->
    (generated: the table, then the command, date and results file it came from)
    <!-- /results -->

``notitle`` after the name (``<!-- results:bench_default/summary notitle -->``) leaves the table's title out, where
the README's own text introduces it. Run from the repository root::

    python benchmarks/tables.py            # rewrite every block from the latest results
    python benchmarks/tables.py --check    # exit 1 naming each block that differs from the latest results

``tests/test_benchmark_tables.py`` runs the check, so a README cannot drift from the results files.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parent
REPO = BENCHMARKS.parent
RESULTS = BENCHMARKS / "results"
#: The documents whose blocks are generated.
DOCUMENTS = (REPO / "README.md", BENCHMARKS / "README.md")
BLOCK = re.compile(r"<!-- results:(?P<stem>[\w.-]+)/(?P<table>[\w.-]+)(?P<flags>(?: [\w-]+)*) -->\n"
                   r"(?P<body>.*?)<!-- /results -->", re.S)


def load(stem: str, results: Path = RESULTS) -> dict:
    path = results / f"{stem}.json"
    if not path.is_file():
        raise SystemExit(f"{path}: no results file (run benchmarks/{stem}.py)")
    return json.loads(path.read_text())


def cell(value) -> str:
    """A table cell: None as a dash, a float as Python writes it (the digits the script rounded to)."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return repr(value)
    return str(value).replace("|", "\\|")


def render(stem: str, name: str, doc: dict, *, title: bool = True) -> str:
    """The Markdown of table ``name`` of one results document, ending with where it came from."""
    try:
        table = doc["tables"][name]
    except KeyError:
        raise SystemExit(f"benchmarks/results/{stem}.json has no table {name!r}") from None
    out = []
    if title:
        out += [f"*{table['title']}*", ""]
    out.append("| " + " | ".join(cell(c) for c in table["columns"]) + " |")
    out.append("|" + "---|" * len(table["columns"]))
    out += ["| " + " | ".join(cell(c) for c in row) + " |" for row in table["rows"]]
    source = f"`{table.get('command', doc['command'])}` ({table.get('date', doc['date'])}; " \
             f"`benchmarks/results/{stem}.json`)"
    note = table.get("note", "")
    out += ["", f"<sub>From {source}" + (f". {note[:1].upper()}{note[1:]}" if note else "") + ".</sub>"]
    return "\n".join(out) + "\n"


def rendered(text: str, results: Path = RESULTS) -> str:
    """``text`` with every block regenerated from the results files."""
    cache: dict[str, dict] = {}

    def block(match: re.Match) -> str:
        stem, name, flags = match["stem"], match["table"], match["flags"].split()
        doc = cache.setdefault(stem, load(stem, results))
        head = match.group(0).split("\n", 1)[0]
        return f"{head}\n{render(stem, name, doc, title='notitle' not in flags)}<!-- /results -->"

    return BLOCK.sub(block, text)


def stale(path: Path, results: Path = RESULTS) -> list[str]:
    """The blocks of ``path`` that differ from the results files, as ``stem/table``."""
    text = path.read_text()
    fresh = {(m["stem"], m["table"]): m.group(0) for m in BLOCK.finditer(rendered(text, results))}
    return [f"{m['stem']}/{m['table']}" for m in BLOCK.finditer(text) if fresh[m["stem"], m["table"]] != m.group(0)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="only report the blocks that differ (exit 1 if any)")
    args = parser.parse_args(argv)
    bad = 0
    for path in DOCUMENTS:
        if args.check:
            for key in stale(path):
                print(f"{path.relative_to(REPO)}: block {key} differs from benchmarks/results/"
                      f"{key.split('/')[0]}.json (run python benchmarks/tables.py)", file=sys.stderr)
                bad += 1
        else:
            text = path.read_text()
            new = rendered(text)
            if new != text:
                path.write_text(new)
                print(f"{path.relative_to(REPO)}: tables regenerated", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
