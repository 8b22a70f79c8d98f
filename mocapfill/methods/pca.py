"""The registered ``pca`` method: the distance-weighted PCA of Gløersen & Federolf (2016).

The model, its pre-processing and its uncertainty are described in :mod:`mocapfill.engines.weighted_pca`, which
the default's local PCA (:mod:`mocapfill.engines.local_pca`) shares.
"""

from __future__ import annotations

import numpy as np

from ..engines.weighted_pca import reconstruct, weight_width
from ..errors import MethodError
from ..runtime.blas import single_blas_thread
from .base import FillResult, finish


def fill_pca(
    positions: np.ndarray,
    *,
    seed: int | None = None,
    units: str = "mm",
    scale: float | None = None,
    missing_weight: float = 0.02,
    variance: float = 0.99,
    strategy: str = "separate",
    normalise: bool = True,
    reference_frames: np.ndarray | None = None,
    reference_weights: np.ndarray | None = None,
) -> FillResult:
    """Fill gaps with the distance-weighted PCA reconstruction of Gløersen & Federolf (2016).

    Parameters
    ----------
    positions : ndarray (n_frames, n_markers, 3), NaN = missing
    seed : ignored (the method is deterministic); accepted for a uniform signature.
    units : "mm", "cm" or "m"
        Converts the default Gaussian width (200 mm).
    scale : float, optional
        Gaussian width of the distance weights in data units (overrides the unit default).
    missing_weight : float
        Weight of the missing marker while the components are fitted (0.02).
    variance : float
        Fraction of the cumulative singular values the kept components reach (0.99).
    strategy : "separate" or "joint"
        One marker at a time, or all markers missing in a frame together.
    normalise : bool
        Divide each centred coordinate by its training standard deviation before weighting.
    reference_frames, reference_weights : frames of reference takes (n_ref, n_markers, 3), in this capture's units and
        marker order, and their weights (n_ref,): extra training frames (``mocapfill.fill(..., reference=[...])``).

    Returns
    -------
    FillResult with ``std`` (n_frames, n_markers): leave-one-block-out per-coordinate RMS error, inflated by the
    frame's leverage.  Markers that are never observed stay NaN; a gap without usable predictors falls back to
    linear interpolation (listed in ``info["fallback"]``).
    """
    del seed
    if not 0 < variance <= 1:
        raise MethodError(f"pca variance must be in (0, 1], got {variance!r}")
    if not missing_weight > 0:
        raise MethodError(f"pca missing_weight must be positive, got {missing_weight!r}")
    positions = np.asarray(positions, dtype=np.float64)
    width = weight_width(units, scale)
    with single_blas_thread():  # many small decompositions: BLAS threads only add contention
        estimate, std, info = reconstruct(positions, scale=width, missing_weight=missing_weight, variance=variance,
                                          strategy=strategy, normalise=normalise,
                                          reference_frames=reference_frames, reference_weights=reference_weights)
    info.update({"scale": width, "missing_weight": missing_weight, "variance": variance})
    return finish(positions, estimate, std=std, info=info)
