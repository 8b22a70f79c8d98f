"""The default fill's accuracy promise, asserted on the benchmark's own trials.

The benchmark (``benchmarks/bench_default.py``) runs 20 seeded trials per clip and protocol and then an ablation and
a speed test; this module runs only the accuracy part for ``pca`` and ``auto`` (the same 20 trials: seed 0,
``make_occlusions`` draws trial i from the i-th stream spawned from the seed) on both real clips (CMU flips in mm at
120 Hz, a tennis serve in metres at 50 Hz) and both protocols with gaps of 10-50 % of the clip (given explicitly:
evaluate's defaults cap them at 1 s / 5 s on long takes), and asserts issue 6's thresholds per clip:

- limb protocol: the default's median RMSE at least 20 % lower than the published PCA's;
- one-marker protocol: no worse than the published PCA;
- bone-length error on the filled frames (bones estimated from the occluded input by ``evaluate``) lower.

Why not fewer trials: per-trial errors spread from 2 to 250 mm, so the median of a handful of trials is too noisy for
a 20 % margin: the first 5 trials put the CMU limb ratio auto/pca at 0.84 and the first 8 the tennis limb ratio just
above 0.80 (10 or 12 trials: 0.79), although the default wins 95 % of the 20 limb trials of each clip and its 20-trial
medians are 30 % (tennis) and 63 % (CMU) lower.  The 160 fills take about 20 s (the fills run their BLAS on one
thread, see :mod:`mocapfill.runtime.blas`).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import mocapfill
from mocapfill.evaluation import evaluate

#: Accuracy thresholds on real captures: not in a bare `pytest`; `pytest -m accuracy` (and .ci/run) runs them.
pytestmark = pytest.mark.accuracy

TRIALS = 20
SEED = 0


@pytest.fixture(scope="module", params=["85_02.c3d", "kinematics_tennis_serve.c3d"])
def clip(request, sample_data):
    return mocapfill.read(sample_data / request.param)


def _run(data, protocol):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = evaluate(data, ["pca", "auto"], protocol, trials=TRIALS, seed=SEED, occlusion_min="10%", occlusion_max="50%")
    return np.nanmedian(res.values("rmse"), axis=0), np.nanmedian(res.values("bone_error"), axis=0)


def test_limb_gaps_at_least_20_percent_better_than_pca(clip):
    (pca, auto), (bone_pca, bone_auto) = _run(clip, "limb")
    assert auto <= 0.8 * pca, f"{clip.path}: auto {auto:.4g} vs pca {pca:.4g}"
    assert bone_auto < bone_pca


def test_one_marker_gaps_no_worse_than_pca(clip):
    (pca, auto), (bone_pca, bone_auto) = _run(clip, "marker")
    assert auto <= pca, f"{clip.path}: auto {auto:.4g} vs pca {pca:.4g}"
    assert bone_auto < bone_pca
