"""The default's configuration (:mod:`mocapfill.methods.auto_config`): every field with its one-line reason in the
code and its section, with the code's default, in ``docs/model-config.md``."""

from __future__ import annotations

import ast
import dataclasses
import re
from pathlib import Path

from mocapfill.methods import auto_config
from mocapfill.methods.auto_config import DEFAULT_CONFIG, ModelConfig

ROOT = Path(__file__).resolve().parents[1]


def _reasons() -> dict[str, list[str]]:
    """Each field of ModelConfig -> the ``#:`` comment lines just above it in the source."""
    lines = Path(auto_config.__file__).read_text().splitlines()
    out, pending = {}, []
    for line in lines:
        if line.startswith("    #:"):
            pending.append(line)
            continue
        m = re.match(r"    (\w+): .+ = ", line)
        if m:
            out[m.group(1)] = pending
        pending = []
    return out


def test_every_field_has_one_line_of_reason():
    reasons = _reasons()
    names = [f.name for f in dataclasses.fields(ModelConfig)]
    assert list(reasons) == names
    assert {name: len(lines) for name, lines in reasons.items() if len(lines) != 1} == {}


def test_every_field_has_its_section_in_the_docs_with_the_codes_default():
    text = (ROOT / "docs" / "model-config.md").read_text()
    sections = dict(re.findall(r"^## `(\w+)` = `(.+)`$", text, flags=re.MULTILINE))
    fields = {f.name: f.default for f in dataclasses.fields(ModelConfig)}
    assert sorted(sections) == sorted(fields)
    assert {name: raw for name, raw in sections.items() if ast.literal_eval(raw) != fields[name]} == {}


def test_the_default_config_is_the_dataclass_default_and_frozen():
    assert DEFAULT_CONFIG == ModelConfig()
    try:
        DEFAULT_CONFIG.knn = 1  # type: ignore[misc]
    except dataclasses.FrozenInstanceError:
        return
    raise AssertionError("ModelConfig is not frozen")
