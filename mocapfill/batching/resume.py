"""The resume record: ``out_dir/.mocapfill-batch.jsonl``, per finished output the SHA-256 of its input's content
and of the settings; a re-run skips an input whose output exists and whose two hashes are unchanged."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import MocapfillError

if TYPE_CHECKING:
    from .task import BatchRow, FileTask

STATE_NAME = ".mocapfill-batch.jsonl"


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's content (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def settings_digest(task: FileTask) -> str:
    """SHA-256 of everything that shapes an output but the input's content (files named by settings included).

    The same for every task of a batch: it names the report's kind, not its path.
    """
    from .. import __version__

    report = None if task.report is None else Path(task.report).suffix
    doc: dict[str, Any] = {"mocapfill": __version__, "fill": task.settings.as_dict(), "report": report,
                           "status": task.status is not None,
                           "reading": [task.input_format, task.rate, task.override_rate],
                           "format": task.output_format}
    for name in ("bones", "reference", "model"):
        value = getattr(task.settings, name)
        paths = [value] if isinstance(value, str) else list(value or ())
        for k, path in enumerate(paths):
            try:
                doc[f"{name}_sha256_{k}"] = file_digest(path)
            except OSError:
                doc[f"{name}_sha256_{k}"] = None  # the task will fail and say why
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def load_state(path: Path) -> dict[str, dict[str, Any]]:
    """Entries by output key; a torn last line (an interrupted append) is ignored."""
    state: dict[str, dict[str, Any]] = {}
    if not path.is_file():
        return state
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            entry = json.loads(line)
            state[entry["output"]] = entry
        except (ValueError, KeyError, TypeError):
            continue
    return state


def row_from_state(entry: dict[str, Any], task: FileTask, seconds: float) -> BatchRow | None:
    try:
        known = {k: entry["row"][k] for k in ("frames", "markers", "missing_samples", "filled_samples")}
    except (KeyError, TypeError):
        return None
    from .task import BatchRow

    return BatchRow(task.input, task.output, "skipped", method=task.settings.method, seconds=seconds,
                    report=task.report or "", left_samples=entry["row"].get("left_samples"),
                    status_csv=task.status or "", references=entry["row"].get("references") or "", **known)


def compact_state(path: Path, state: dict[str, dict[str, Any]]) -> None:
    """Rewrite the resume record with one line per output (re-runs append; this keeps it from growing)."""
    from ..io.atomic import atomic_write

    with contextlib.suppress(MocapfillError, OSError):
        with atomic_write(path, "w") as handle:
            for entry in state.values():
                handle.write(json.dumps(entry) + "\n")
