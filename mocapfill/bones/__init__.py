"""Everything about bones: the rigid marker pairs a fill may respect.

- :mod:`.boneset`: :class:`BoneSet`, estimating one from inter-marker distance statistics, loading and saving the
  editable JSON / CSV, and ``resolve_bones`` (what a bone-aware fill uses).
- :mod:`.distances`: vectorised inter-marker distance statistics (bones, outlier ranges and the body frame use them).
- :mod:`.constraints`: BoLeRO's hard and soft bone-length solvers.
- :mod:`.refinement`: moving a fill's markers to the most probable positions given its std and the bones' spread.
"""

from .boneset import (
    BoneSet,
    bones_to_csv,
    bones_to_dict,
    default_min_frames,
    estimate_bones,
    load_bones,
    pair_scores,
    resolve_bones,
    save_bones,
)

__all__ = ["BoneSet", "bones_to_csv", "bones_to_dict", "default_min_frames", "estimate_bones", "load_bones", "pair_scores", "resolve_bones", "save_bones"]
