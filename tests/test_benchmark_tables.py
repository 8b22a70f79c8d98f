"""The READMEs' benchmark tables are the results files' (no benchmark runs here): every block between
``<!-- results:stem/table -->`` markers equals what ``benchmarks/tables.py`` renders from
``benchmarks/results/<stem>.json``; the results files keep their format; ``compare.py`` names what got worse."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _module(name: str):
    if str(BENCHMARKS) not in sys.path:  # the scripts import the harness as they do when run from benchmarks/
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(f"benchmarks_{name}", BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


tables = _module("tables")
compare = _module("compare")


@pytest.mark.parametrize("document", tables.DOCUMENTS, ids=lambda p: p.name if p.parent.name != "benchmarks"
                         else "benchmarks/README.md")
def test_readme_tables_match_the_latest_results(document):
    assert tables.BLOCK.search(document.read_text()), f"{document}: no generated table"
    assert tables.stale(document) == [], f"{document}: run python benchmarks/tables.py"


def test_every_block_names_a_table_of_a_results_file():
    for document in tables.DOCUMENTS:
        for match in tables.BLOCK.finditer(document.read_text()):
            doc = json.loads((tables.RESULTS / f"{match['stem']}.json").read_text())
            assert match["table"] in doc["tables"], (document.name, match.group(0).splitlines()[0])


@pytest.mark.parametrize("path", sorted(tables.RESULTS.glob("*.json")) + sorted((tables.RESULTS / "floor").glob(
    "*.json")), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_results_files_keep_the_format(path):
    doc = json.loads(path.read_text())
    assert {"script", "command", "machine", "date", "tables", "figures"} <= set(doc)
    assert (BENCHMARKS / doc["script"]).is_file()
    for name, table in doc["tables"].items():
        assert {"title", "columns", "rows"} <= set(table), name
        assert all(len(row) == len(table["columns"]) for row in table["rows"]), name
    for name, figure in doc["figures"].items():
        assert figure["better"] in ("lower", "higher"), name
        assert isinstance(figure["value"], (int, float)), name


def test_every_script_has_a_floor():
    floors = {p.stem for p in (tables.RESULTS / "floor").glob("*.json")}
    scripts = {p.stem for p in BENCHMARKS.glob("*.py")} - {"harness", "tables", "compare"}
    assert scripts - floors == set()


def test_render_quotes_the_command():
    doc = {"command": "python benchmarks/bench_x.py", "date": "2026-11-25",
           "tables": {"t": {"title": "T", "columns": ["a", "b"], "rows": [[1.5, None]]}}}
    text = tables.render("bench_x", "t", doc)
    assert "| 1.5 | - |" in text and "`python benchmarks/bench_x.py` (2026-11-25" in text
    assert tables.render("bench_x", "t", doc, title=False).startswith("| a | b |")


def test_compare_names_every_worse_figure():
    floor = {"command": "c", "figures": {"rmse": {"value": 10.0, "better": "lower", "unit": "mm"},
                                         "wins": {"value": 90, "better": "higher", "unit": "%"},
                                         "gone": {"value": 1.0, "better": "lower", "unit": "s"}}}
    new = {"figures": {"rmse": {"value": 10.5, "better": "lower"}, "wins": {"value": 95, "better": "higher"}}}
    bad, missing = compare.compare(floor, new)
    assert [line.split(":")[0] for line in bad] == ["rmse"] and missing == ["gone"]
    assert compare.compare(floor, new, rtol=0.1)[0] == []
    new["figures"]["wins"]["value"] = 80
    assert [line.split(":")[0] for line in compare.compare(floor, new)[0]] == ["rmse", "wins"]


def test_a_partial_run_keeps_the_other_tables(tmp_path):
    harness = _module("harness")
    path = tmp_path / "bench_x.json"
    first = harness.Results("bench_x.py", ["--all"], path)
    first.table("a", "A", ["x"], [[1]])
    first.table("b", "B", ["x"], [[2]])
    first.figure("f", 1.0, "s")
    first.write()
    second = harness.Results("bench_x.py", ["--skip", "b"], path)
    second.table("a", "A", ["x"], [[3]])
    second.write()
    doc = json.loads(path.read_text())
    assert doc["tables"]["a"]["rows"] == [[3]] and doc["tables"]["a"]["command"].endswith("--skip b")
    assert doc["tables"]["b"]["rows"] == [[2]] and doc["tables"]["b"]["command"].endswith("--all")
    assert doc["figures"]["f"]["value"] == 1.0


def test_scripts_share_the_harness_and_import_no_other_script():
    for path in sorted(BENCHMARKS.glob("*.py")):
        text = path.read_text()
        assert "sys.path.insert" not in text or path.name == "harness.py", path.name
        assert not any(line.lstrip().startswith(("import bench_", "from bench_", "import fuzz_readers"))
                       for line in text.splitlines()), path.name
        if path.stem not in ("harness", "tables", "compare"):
            assert "import harness" in text and "harness.Results(" in text, path.name


def test_auto_config_changes_the_default_fill_for_the_block_only():
    harness = _module("harness")
    from mocapfill.methods import auto

    before = auto.fill_auto.__kwdefaults__["config"]
    assert harness.config_tag({}) == "" and harness.config_tag(None) == ""
    assert harness.config_tag({"knn": 5}) != harness.config_tag({"knn": 6})
    with harness.auto_config({"knn": 5}):
        assert auto.fill_auto.__kwdefaults__["config"].knn == 5
    assert auto.fill_auto.__kwdefaults__["config"] is before
    with pytest.raises(RuntimeError), harness.auto_config({"knn": 5}):
        raise RuntimeError("a failing fill")
    assert auto.fill_auto.__kwdefaults__["config"] is before


def test_compare_takes_the_floor_of_the_results_files_own_name(tmp_path, monkeypatch):
    """A script's run written under another name (``--out``, other inputs) is held to the floor of that name, and a
    file without one to its script's."""
    floor = tmp_path / "floor"
    floor.mkdir()
    fig = {"rmse": {"value": 10.0, "better": "lower", "unit": "mm"}}
    (floor / "bench_x.json").write_text(json.dumps({"command": "c", "figures": fig}))
    (floor / "bench_x_other.json").write_text(json.dumps({"command": "c", "figures": {"rmse": {**fig["rmse"],
                                                                                            "value": 20.0}}}))
    monkeypatch.setattr(compare, "FLOOR", floor)
    new = {"script": "bench_x.py", "figures": {"rmse": {"value": 15.0, "better": "lower"}}}
    for name, worse in (("bench_x_other.json", 0), ("scratch.json", 1)):
        (tmp_path / name).write_text(json.dumps(new))
        assert compare.main([str(tmp_path / name)]) == worse
