"""The default's configuration: every tunable of ``auto``'s model (:mod:`mocapfill.methods.auto`), once.

One line each says why the field is there; ``docs/model-config.md`` has what each does in the model and the
measurements that chose its value, one section per field (``tests/test_auto_config.py`` keeps the two in step).
Lengths in mm and times in seconds, converted where they are used.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ModelConfig:
    """Every tunable of the default's model, once (lengths in mm, times in seconds; converted on use)."""

    #: Widths of the distance weights, one reconstruction each, mixed by inverse CV variance; the last near-global.
    scales_mm: tuple[float, ...] = (150.0, 200.0, 300.0, 3000.0)
    #: The first pass only seeds the refit (stage 4): one width there, a third of the cost on gappy captures.
    seed_scales_mm: tuple[float, ...] = (200.0,)
    #: The first pass's nearest-pose correction (0: none; the refit's prediction is the one that counts).
    seed_knn: int = 0
    #: Blocks held out in turn to choose each local model's components and measure its error (3: worse, 20 % faster).
    cv_folds: int = 5
    #: Cost bound: predictors per width, the nearest (eigendecompositions grow with their cube); 41 markers unchanged.
    max_predictors: int = 40
    #: Width of the alignment (Kabsch) weights on the neighbours that define a local frame.
    align_mm: float = 200.0
    #: The alignment also weighs each neighbour by the inverse variance of its distance (off, as measured: a trade).
    align_rigid: bool = False
    #: Nearest training poses whose mean residual corrects the linear reconstruction (20: the lowest of 5, 10, 20).
    knn: int = 20
    #: How much a pose's leverage grows the spatial sd the smoother weighs (0: high leverage was not worse).
    leverage_weight: float = 0.0
    #: Markers a prediction-less sample rides on rigidly (0: off; the refit does better and stays smooth).
    rigid_nearest: int = 0
    #: Sd of the global PCA where no local model predicts (a marker seen in a few frames moves with the body).
    global_sd_mm: float = 300.0
    #: Unpredicted samples take the body anchor as a weak measurement: a take-end gap comes to rest inside the body.
    anchor: bool = True
    #: Observed frames beside a gap where the smoother learns the spatial model's error.
    edge_frames: int = 3
    #: Correlation time of the spatial prediction's error (the old edge bridge's 30 frames at 120 Hz).
    bias_seconds: float = 1.0
    #: Share of the spatial prediction's variance that is white from frame to frame (the rest correlated).
    white_share: float = 0.2
    #: Factor on the jerk density learnt from observed third differences (a fill may move a little faster).
    jerk_scale: float = 1.0
    #: Window of the body's jerk power that scales the moment's jerk density (a flip is faster than a stand).
    gain_seconds: float = 0.1
    #: Smallest jerk gain: a still moment must not pin a fill that has to move.
    gain_floor: float = 0.05
    #: Relaxation time of velocity and acceleration: far from any measurement a fill comes to rest.
    rest_seconds: float = 0.5
    #: True: acceleration relaxes with the capture's measured memory (off, as measured: dense and segment RMSEs grew).
    measured_acc_memory: bool = False
    #: Sd of an observed sample: sub-millimetre camera noise.
    obs_sd_mm: float = 0.5
    #: Sd of a fragment's sample where its marker has longer runs: flickering samples are often a take's worst.
    fragment_sd_mm: float = 20.0
    #: Longest observed run between two gaps that counts as such a fragment.
    fragment_frames: int = 2
    #: The prediction's bias is drawn anew where the kind of spatial model changes (local PCA, global PCA, anchor).
    bias_per_model: bool = True
    #: Prior odds that an observed run between gaps is displaced whole (a swap or ghost; 0: off).
    displaced_prior: float = 0.05
    #: Sd per axis of such a displacement (Holden's corruption: up to 50 cm per axis).
    displacement_mm: float = 300.0
    #: Smallest jerk density (mm^2/frame^5): a marker that never moved must not pin its fill.
    jerk_floor_mm2: float = 1e-6
    #: A spatial prediction this many sds off the smoothed path is down-weighted (with reweight_passes).
    outlier: float = 3.0
    #: Smoother passes with outliers down-weighted (0: fast true motion looked like outliers).
    reweight_passes: int = 0
    #: The refit's predictors: neighbours filled with an RMS sd within this during the marker's gaps.
    impute_trust_mm: float = 10.0
    #: Refit models per marker over parts where a left-out neighbour is seen (1: one per marker).
    refit_parts: int = 3
    #: Keep the first pass's prediction where the refit has none, where it is sure and fits the frames beside the gap.
    seed_where_no_refit: bool = True
    #: Where the refit trusts < 3 neighbours, a model on every near one (off, as measured: 3x the cost on messy takes).
    refit_untrusted: bool = False
    #: Where no model covers all its gaps, one per group of gaps with the same trusted ones, kept within review_sd_mm.
    refit_by_run: bool = True
    #: Width of the weighted PCA that completes reference frames' gaps, as predictors (0: off: a gap drops a frame).
    reference_pca_mm: float = 200.0
    #: Refits of the spatial model on the completed take (EM-style imputation).
    impute_passes: int = 1
    #: Radius of a marker's segment model in the refit, its markers seen throughout its gaps (0: off).
    segment_mm: float = 120.0
    #: Factor on the spatial sd before the bone refinement weighs it against the bones' spread.
    bone_trust: float = 0.5
    #: Degrees of freedom of the t the predictions miss a holding bone by (0: every bone always holds).
    bone_break_dof: float = 3.0
    #: Partners a marker is held within reach of, as far apart as they were ever seen (0: off).
    reach_partners: int = 3
    #: A pair is a reach only if its direction turned this much while seen: its largest distance was posed.
    reach_turned_deg: float = 45.0
    #: Smallest bone spread in the refinement (a bone is never an exact constraint).
    spread_floor_mm: float = 1.0
    #: A bone's spread grows where its vector leaves the ones that measured it (off: 85_02 one-marker passed its floor).
    bone_extrapolation: bool = False
    #: A gap whose fill's posterior sd (per coordinate) passes this is flagged for review.
    review_sd_mm: float = 25.0
    #: The reported sd grows where the neighbours take poses the model never learnt (the fill unchanged).
    extrapolation_sd: bool = True
    #: The reported sd adds the widths' spread about their mix (the fill unchanged).
    width_spread_sd: bool = True
    #: The reported sd grows by how far the bone stage moved each prediction (the fill unchanged).
    bone_move_sd: bool = True
    #: Frame rate assumed when the capture has none.
    default_rate: float = 100.0
    #: With a learned denoiser: observed frames per marker hidden to learn its estimate's sd.
    prior_frames: int = 200
    #: Factor on the denoiser's learnt sd before the fusion (it underestimates its errors).
    prior_sd_scale: float = 2.0


DEFAULT_CONFIG = ModelConfig()
