"""mocapfill: repair optical motion-capture marker data.

Public API (imported lazily, so ``import mocapfill`` has no side effects and stays fast):

- :func:`read` / :func:`write`: C3D, CSV (plain, Vicon), TRC; ``"-"`` = stdin / stdout.
- :func:`fill`: fill gaps with a registered method (see :data:`mocapfill.methods.METHODS`).
- :func:`batch`: fill every file of folders / globs into an output folder (local processes or a Dask cluster).
- :func:`estimate_bones`: rigid marker pairs from inter-marker distance statistics.
- :class:`MarkerData`: positions (n_frames, n_markers, 3) float64, NaN = missing, with labels, rate, units.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "read": "mocapfill.io:read",
    "write": "mocapfill.io:write",
    "fill": "mocapfill.api:fill",
    "fill_data": "mocapfill.api:fill_data",
    "estimate_bones": "mocapfill.bones.boneset:estimate_bones",
    "evaluate": "mocapfill.evaluation:evaluate",
    "batch": "mocapfill.batching:batch",
    "MarkerData": "mocapfill.markers:MarkerData",
    "FillResult": "mocapfill.methods.base:FillResult",
    "MocapfillError": "mocapfill.errors:MocapfillError",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    try:
        module_name, attr = _LAZY[name].split(":")
    except KeyError:
        raise AttributeError(f"module 'mocapfill' has no attribute {name!r}") from None
    return getattr(importlib.import_module(module_name), attr)


def __dir__() -> list[str]:
    return sorted(__all__)
