"""The installed console script runs in a subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def _script() -> Path:
    bindir = Path(sys.executable).parent
    for name in ("mocapfill", "mocapfill.exe"):
        if (bindir / name).exists():
            return bindir / name
    raise AssertionError(f"the mocapfill console script is not installed next to {sys.executable}")


def test_installed_help():
    result = subprocess.run([str(_script()), "--help"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "Usage: mocapfill" in result.stdout
    assert "info" in result.stdout


def test_installed_info_json_and_error(tmp_path):
    sample = Path(__file__).resolve().parents[1] / "sample_data" / "85_02.c3d"
    env = dict(os.environ, COLUMNS="120")
    ok = subprocess.run([str(_script()), "info", "--json", str(sample)], capture_output=True, text=True,
                        timeout=60, env=env)
    assert ok.returncode == 0, ok.stderr
    assert '"n_markers": 41' in ok.stdout
    bad = subprocess.run([str(_script()), "info", str(tmp_path / "nope.c3d")], capture_output=True, text=True,
                         timeout=60, env=env)
    assert bad.returncode == 1
    assert bad.stderr.strip() == f"Error: {tmp_path / 'nope.c3d'}: no such file"
