"""The default's configuration: every tunable of ``auto``'s model (:mod:`mocapfill.methods.auto`), once.

Lengths in mm and times in seconds, converted where they are used.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ModelConfig:
    """Every tunable of the default's model, once (lengths in mm, times in seconds; converted on use)."""

    #: Widths of the spatial model's distance weights, one reconstruction each, averaged by inverse CV variance; the
    #: near-global last width lets the model fall back towards a global weighted PCA where that cross-validates
    #: better (biogesta dense-30 pooled 102.5 -> 79.9 mm, pca 98.0: a club marker far from the body; bench_default
    #: 85_02 one-marker 11.82 -> 11.70, tennis limb 6.04 -> 5.92; a 1000 mm width: 11.77, 5.88, club 447 vs 434 mm).
    scales_mm: tuple[float, ...] = (150.0, 200.0, 300.0, 3000.0)
    #: The first pass only seeds the refit on the completed take (stage 4), which makes the prediction: one width and
    #: no nearest-pose correction there (a third of the cost on captures with gaps everywhere).
    seed_scales_mm: tuple[float, ...] = (200.0,)
    seed_knn: int = 0
    #: Contiguous blocks of the training frames held out in turn to choose each local model's number of components
    #: and to measure its error (the spatial sd).  3 measured worse (bench_default_captures vicon-arm limb 11.6 -> 14.4
    #: mm, segment 31.9 -> 40.7, 85_02 dense-30 38.4 -> 43.1) for 20 % less time.
    cv_folds: int = 5
    #: Cost bound: each width of a local model uses at most this many predictors, the nearest (the eigendecompositions
    #: grow with their cube).  Marker sets of up to 41 markers (every accuracy benchmark) are unchanged; on four
    #: captures of 51-105 markers (4 protocols x 3 trials) the mean RMSEs moved within 1 % but markers.csv one-marker
    #: 1.36 -> 1.21 mm and Knee.trc limb 0.09 -> 0.10 mm; Knee.trc 1.07 -> 0.62 s, markers.csv 2.04 -> 1.51 s.
    max_predictors: int = 40
    #: Width of the weights of the local frame's alignment (Kabsch) on the neighbours.
    align_mm: float = 200.0
    #: Nearest training poses whose mean residual corrects the linear reconstruction (0: none; bench_default medians
    #: 85_02 one-marker / limb, tennis one-marker / limb: 5: 12.04/13.27/3.77/5.90, 10: 11.70/12.98/3.71/5.92,
    #: 20: 11.49/12.76/3.69/5.97; biogesta and bench_messy segment unchanged).
    knn: int = 20
    #: How much a frame's leverage grows the spatial std the smoother weighs (85_02 one-marker, 10 trials: median
    #: 13.6 mm with 1, 11.4 with 0: a high-leverage pose is not a worse prediction there, the dynamics were).
    leverage_weight: float = 0.0
    #: Where the local PCA has no prediction (a marker's neighbourhood vanished with it), the marker rides rigidly on
    #: this many of its nearest markers observed at that frame (0: off, as measured: once the refit trusts only
    #: well-known neighbours, it gave 85_02 30 % dense RMSE 28.8 against 31.2 mm, pooled 21.0 against 21.8, segment
    #: unchanged, but basket_sprint's largest filled acceleration 0.20 against 0.054 m/frame^2, observed 0.074).
    rigid_nearest: int = 0
    #: Where the local PCA still has no prediction (a marker seen in too few frames to train a local model), the
    #: global distance-weighted PCA of ``pca`` (Gloersen & Federolf) predicts it with this sd (mm; 0: off), where that
    #: prediction stays inside the body (:func:`global_prediction`).  CMU 16_08 dense 20 % (markers seen in 6 of 239
    #: frames, bridged by the motion alone 1.8 m off): RMSE 348 / 532 mm off, 42 / 44 with 100, 48 / 46 with 300,
    #: pca 66 / 58; 100 made Walking_Hybrid_1_1's fill jerky (66.8 against 36.1 mm/frame^2 observed), 300 does not.
    #: Without the inside-the-body mask, duplicate_labels.c3d (74 % missing) got a marker 40 m off (pca's fill).
    global_sd_mm: float = 300.0
    #: Samples nothing else predicts take the body anchor's prediction (:func:`anchor_stage`), a weak measurement that
    #: keeps a fill inside the body.  Without it the motion model alone carried the last velocity and acceleration
    #: of a gap at a take's end out of the body: 13.6x the body's extent on duplicate_labels.c3d, 4.0x on
    #: c3d_sample.c3d (``bench_messy.py --skip dense,segment``; CHANGELOG).
    anchor: bool = True
    #: Observed frames on either side of a gap where the spatial model's error is measured for the smoother.
    edge_frames: int = 3
    #: Correlation time of the spatial prediction's error (the old edge bridge's 30 frames at 120 Hz).
    bias_seconds: float = 1.0
    #: Share of the spatial prediction's variance that is white from frame to frame (the rest is correlated).
    white_share: float = 0.2
    #: The jerk density learnt from the observed third differences is multiplied by this (a fill may follow the
    #: spatial prediction through motions a little faster than the average observed).
    jerk_scale: float = 1.0
    #: Window over which the body's jerk power sets the moment's jerk density (a flip is faster than a stand).
    gain_seconds: float = 0.1
    #: Smallest jerk gain: a still moment must not pin a fill that has to move.
    gain_floor: float = 0.05
    #: Relaxation time of velocity and acceleration: far from any measurement a fill comes to rest.
    rest_seconds: float = 0.5
    #: True: the acceleration relaxes with the capture's measured memory instead (at most ``rest_seconds``;
    #: :func:`~mocapfill.engines.motion_smoother.acceleration_memory`), so an edge glitch's acceleration is not carried
    #: into a gap.  Off, as measured: VER4C3D then passes the smooth check (1.17x -> 0.86x) and kineticstoolkit
    #: c3d_sample's p99.9 1.55x -> 1.09x, but bench_messy's 85_02 dense medians grow 2-6 % and its segment RMSE
    #: 58.5 -> 65.9 mm (the near-white-acceleration prior bends the interpolant at the measurements).
    measured_acc_memory: bool = False
    #: Standard deviation of an observed sample (mm): sub-millimetre camera noise.
    obs_sd_mm: float = 0.5
    #: Standard deviation of a sample in an observed fragment of at most ``fragment_frames`` frames between missing
    #: ones (mm): such flickering samples are often the worst of a take (the output keeps them; the fill need not
    #: pass through them).
    fragment_sd_mm: float = 20.0
    fragment_frames: int = 2
    #: Prior probability that an observed run between two gaps is displaced as a whole (a swapped or ghost marker the
    #: tracker labelled; outlier rejection cannot see one: it has no step to either side).  With the next, the odds
    #: :func:`displaced_runs` weighs against the spatial model's sd there (0: off).
    displaced_prior: float = 0.05
    #: Standard deviation per axis of such a displacement (mm): Holden's corruption displaces by up to 50 cm per axis
    #: (uniform, sd 289 mm).  A run judged displaced is measured with this sd: the fill no longer bends to it.
    displacement_mm: float = 300.0
    #: Smallest jerk density (mm^2 / frame^5): a marker that never moved must not pin its fill.
    jerk_floor_mm2: float = 1e-6
    #: A spatial prediction more than this many standard deviations off the smoothed path is down-weighted.
    outlier: float = 3.0
    #: Smoother passes with down-weighted outliers after the first (0: measured better; tennis serve at 5 % dense,
    #: a wrist gap: 124 mm largest error without, 171 with outlier 8, 803 with 3: fast true motion looked like
    #: outlying predictions to the jerk prior).
    reweight_passes: int = 0
    #: In the refit on the completed take, a neighbour is a predictor only if its RMS filled std during the marker's
    #: gaps is at most this (mm; 0: every neighbour): one that vanished with the marker does not steer it (segment
    #: protocol: the refit on vanished neighbours' fills made tennis 37.9 mm against 18.2 without the refit).
    impute_trust_mm: float = 10.0
    #: A neighbour left out that way may still be observed during part of the marker's gaps (a thigh marker seen for
    #: the first half of an ankle's gap, missing with it for the second): the refit splits the gap frames into at
    #: most this many parts by which of those neighbours are observed, and a part where one is seen gets a model with
    #: it that predicts there in place of the whole-gap model where its predicted variance (CV rms^2 times the mean
    #: pose-residual factor) is the smaller and it has ``MIN_TRAIN_WANTED`` training frames (on fewer, the two
    #: models' cross-validated errors cannot tell them apart: CMU 07_12, a pelvis marker seen in 30 frames, 17.8 ->
    #: 24.9 mm without that condition) (:func:`~mocapfill.engines.local_pca.refit_parts`; 1: one model per marker).
    #: Measured (2026-11-27, eighth session) against 1: bench_references' same-subject CMU trials with the subject's
    #: other takes as references (their frames are what lets the part models train), median segment 57.3 -> 31.7
    #: mm, dense 30 % 30.8 -> 28.9 (without references 61.5 -> 60.8 and 58.4 -> 54.0); bench_default_captures 7 of
    #: 28 cases better (biogesta dense 20 / 30 % 30.3 / 79.7 -> 28.3 / 73.8, vicon-arm dense 20 % 13.8 -> 12.3) and
    #: 3 worse, all vicon-arm draw 3 through the robot's false bones (dense 5 / 10 / 30 % 3.02 / 3.11 / 16.35 ->
    #: 3.05 / 3.13 / 16.84; without the bone stage that dense-30 draw goes 12.2 -> 9.4 mm).
    refit_parts: int = 3
    #: Where the refit has no model for a marker (fewer than 3 trusted neighbours: on a capture with gaps
    #: everywhere, most markers; kineticstoolkit's basket sprint, every one), keep the first pass's prediction
    #: (:func:`seed_elsewhere`) instead of leaving the gap to the motion model and the global PCA.  Off, as measured
    #: (2026-11-27, ninth session): ``bench_real_hidden.py`` (31 real captures with gaps, 5 % more hidden, 3 draws)
    #: mean pooled RMSE 59.4 -> 40.9 mm, 5 captures better (c3d_sample 376 -> 64, VER4C3D 74 -> 10, Gait.trc 120 ->
    #: 55, Walking_Hybrid_1_1 91 -> 57, duplicate_labels 101 -> 40), none worse, and every accuracy benchmark's clip
    #: unchanged (their refit always has a model); but the fills of VER4C3D, c3d_sample and the basket sprint jerk
    #: (largest filled acceleration 21 -> 63 against 27 observed on VER4C3D: where the first pass predicts some
    #: frames of a gap and not others, the smoother swings between them), and issue 21's smooth check fails on 5
    #: captures instead of 2.
    seed_where_no_refit: bool = False
    #: Where the refit has no trusted model for a marker (fewer than 3 neighbours filled with an sd under
    #: ``impute_trust_mm`` during its gaps), fit one on every near marker instead (the EM step without the trust),
    #: its neighbours read from the first pass's smoother (its posterior mean also at the observed samples it did not
    #: take as exact: a flickering neighbour's one-frame fragment is often the take's worst sample).  Such a model's
    #: neighbours are themselves guesses: it predicts only where one of them is observed, the fill weighs its
    #: extrapolation-grown sd (:func:`reported_sd`), its predictions judge no observed run displaced
    #: (:func:`displaced_runs`) and the white part of their error is measured from their roughness
    #: (:func:`rough_variance`).  Off, as measured (2026-11-27, tenth session): ``bench_real_hidden.py`` mean pooled
    #: RMSE 59.4 -> 35.0 mm, no capture or draw worse (Gait.trc 120 -> 6.0, c3d_sample 376 -> 15.9, VER4C3D 74 ->
    #: 10.9, Walking_Hybrid_1_1 91 -> 17.1, duplicate_labels 101 -> 46, the basket sprint 118 -> 50), behind
    #: ``bolero-sc`` on 2 captures instead of 6; ``bench_default_real``'s smooth verdicts all as without it; but the
    #: fill's CPU time on btk's Gait.c3d 0.77 -> 2.12 s and Gait.trc 1.05 -> 2.02 s (best of 3; the fast bound 1.22
    #: s): a model with four widths and the nearest-pose correction for every marker (one width and no correction:
    #: as fast as without the option, but the basket sprint 118 mm again).  With the body anchor (eleventh session):
    #: mean 24.3 -> 15.6 mm, but duplicate_labels 46 -> 78 (the bones move the forearm's predictions off).
    refit_untrusted: bool = False
    #: Where the refit has no model for a marker over all its gaps (a neighbour trusted in none of them: one that
    #: vanished with it once and was filled with a large sd is untrusted for every gap), fit one per group of its
    #: gaps with the same neighbours trusted over the gap (:func:`~mocapfill.engines.local_pca.trusted_runs`, at
    #: most ``refit_parts`` per marker), as the first pass fits (``seed_scales_mm``, ``seed_knn``), kept where its
    #: cross-validated rms is within ``review_sd_mm`` (a prediction whose gap would need no review; past it the gap
    #: is left to the global PCA and the motion model as before).  Measured (2026-11-28, seventeenth session):
    #: ``bench_real_hidden.py`` mean pooled RMSE 23.11 -> 20.06 mm, 7 captures better, none worse, no draw worse
    #: (Gait.trc 39.5 -> 22.1, now ahead of ``bolero-sc``; Walking_Hybrid_1_1 86.3 -> 54.2; VER4C3D 60.3 -> 41.7;
    #: c3d_sample 70.1 -> 55.9); the accuracy benchmarks' clips unchanged (their refit always has a model).  Kept
    #: within ``impute_trust_mm`` instead: 20.86 (a toe's model at 15.6 mm rms left to the global PCA, 78 mm off).
    #: With the refit's four widths and nearest poses: within ``impute_trust_mm`` 20.46, at four times the cost
    #: (the refit stage of btk's Gait.trc 0.02 -> 0.65 s against 0.15-0.21 s); within 25 mm, duplicate_labels
    #: 45.8 -> 46.7 (a forearm model the bone stage moved 400 mm off); with no bound, the basket sprint 69.8 -> 76.4
    #: as well (a sync marker and a wheelchair's predicted from markers they do not move with, rms 250-300 mm).
    refit_by_run: bool = True
    #: Fit the spatial model again on the completed take (EM-style imputation) this many times.
    impute_passes: int = 1
    #: Radius (mm) of a marker's segment model in the refit: the markers this close that are observed throughout its
    #: gaps (at least 3), with their own local frame.  It predicts in place of the neighbourhood model where that one
    #: extrapolates more and predicts a larger variance (:func:`~mocapfill.engines.local_pca.prefer_segment`), and
    #: the bone stage leaves its predictions alone (the bones would pull them towards the neighbours the segment
    #: model left out: vicon-arm one-marker draw 0 2.75 mm without the bones there, 6.62 with them).  0: off.
    #: Measured (2026-11-27, seventh session) against off: the short walk's dense 5/10/20/30 % pooled RMSE
    #: 16.7/14.6/29.0/41.4 -> 9.2/8.8/25.3/39.2 mm, one-marker, limb and segment unchanged; bench_default_captures
    #: vicon-arm one-marker 3.26 -> 1.55, dense-5 3.78 -> 3.02, dense-10 3.16 -> 3.11, segment 31.7 -> 31.4, the
    #: other 24 cases identical; bench_messy dense 5 % RMSE 9.2 -> 9.0; bench_default identical.
    segment_mm: float = 120.0
    #: The spatial std is multiplied by this before the bone refinement weighs it against the bones' spread.
    bone_trust: float = 0.5
    #: A bone does not hold everywhere (a hand lets go of what it held): where the spatial predictions say a bone broke
    #: more probably than it held, it is left out at that frame (:func:`bone_breaks`), the prior being how often it
    #: broke where both its ends were observed (a bone that always held holds).  The predictions' miss off a bone
    #: that holds follows a Student t with this many degrees of freedom (0: every bone holds everywhere): their
    #: error has heavier tails than their sd says (``bench_default.py``'s err/std reaches 6), and with a Gaussian
    #: miss an overconfident prediction looked like a broken bone.  Why: vicon-arm dense 20 % draw 0, a hand marker
    #: held 414 mm from a robot link (spread 0.6 mm) moved up to 663 mm from it in a gap, and the bone pulled the
    #: hand's fill 80 mm off (19.8 mm RMSE over the draw; 8.1 with this; 15.8 with 2 degrees of freedom, 4.2 with 6
    #: but tennis serve limb's mean 8.71 -> 8.83 mm, 3.9 with 30 and 9.09 mm there).
    bone_break_dof: float = 3.0
    #: Reaches (:mod:`mocapfill.bones.reach`): a marker with gaps is held within reach of this many partners (not its
    #: bones; those whose distance to it varied least for its size, seen with it through at least half the take): at
    #: a frame where the fill puts it farther from such a partner, observed or not moved, than the two were ever seen
    #: apart, the bone stage pulls it back by how far, in units of the distance's spread.  0: off.  Why: the tennis
    #: serve's dense 30 % draw 3 hides the left wrist, hand and forearm through a swing; the refit predicted the wrist
    #: 760 mm off (sd 23 mm), 570 mm from an elbow never seen more than 290 mm from it: the draw's RMSE 30.4 mm against
    #: bolero-sc's 23.4 (the per-draw check's last failure).  Measured (2026-11-28, fourteenth session): CHANGELOG.
    reach_partners: int = 3
    #: A pair counts as a reach only if its direction turned by at least this many degrees (95th percentile of the
    #: angle to its mean direction) over the frames both were seen: only then was its largest distance seen in many
    #: poses.  Why: on vicon-arm's limb draw 2 a table marker and the robot's links (spread 9 mm, turned 10-20 degrees
    #: while both were seen) moved 80 mm past their largest observed distance once the table marker was hidden (19.4
    #: -> 20.3 mm RMSE with every pair a reach); biogesta's dense 30 % draw 1 likewise (118.3 -> 132.7 mm).
    reach_turned_deg: float = 45.0
    #: Smallest bone spread in the refinement (a bone is never an exact constraint).
    spread_floor_mm: float = 1.0
    #: A bone knows where it extrapolates: its spread grows by how far the estimates put its vector off the vectors
    #: that measured it, unless it was seen turning while it kept its length (:func:`bone_spreads`).  Why: bones are
    #: estimated from the frames with both ends observed, and two markers that stood still there look rigid
    #: (vicon-arm dense 20 % draw 0: a hand marker and a robot link 414 mm apart with a spread of 0.6 mm over those
    #: frames moved 250 mm apart in the hidden ones).  Off, as measured (2026-11-27, sixth session): on,
    #: bench_default_captures vicon-arm pooled dense 5/10/20/30 % 3.8/3.2/13.8/16.4 -> 2.8/2.4/9.9/11.3 mm, segment
    #: 31.7 -> 27.6, 7 of 28 cases better and 3 worse (vicon-arm one-marker 3.3 -> 4.0, biogesta dense-20 30.3 ->
    #: 31.1); bench_messy's dense RMSEs 9.2/8.7/14.4/21.9 -> 8.9/8.6/13.2/21.1, segment 31.1 unchanged; calibration
    #: 70 -> 71 of 80; but bench_default's 85_02 one-marker median 11.49 -> 11.66 mm, above its floor of 11.58 (one
    #: trial, RKNE, 11.34 -> 11.68, the median's).
    bone_extrapolation: bool = False
    #: A gap whose fill has a posterior standard deviation above this (per coordinate) is flagged for review.
    review_sd_mm: float = 25.0
    #: The reported sd knows where the spatial model extrapolates: a prediction's variance is multiplied by how far
    #: its neighbours' pose lies off the poses the model learnt from (the predictors' residual off its components
    #: over the held-out rows' mean one, at least 1: the scale of a multivariate t's conditional variance), and the
    #: smoother's posterior sd is computed with it.  The fill's mean keeps the cross-validated sd: letting the
    #: factor reweight the fusion cost accuracy where the dynamics alone are worse still (bench_default 85_02
    #: one-marker 11.5 -> 13.3 mm).  Measured (fills unchanged): bench_default's err/std inside 0.5-2 on 70 of 80
    #: trials (64 without); bench_default_captures' gaps with an RMS error above ``review_sd_mm`` per coordinate
    #: flagged for review: 90 of 153 on four captures (33 without), 40 of 48 on the committed walk (9); with the
    #: converged bone refinement (2026-11-27, fourth session) 87 of 151 and 39 of 47; with displaced runs (fifth
    #: session) 89 of 151.
    extrapolation_sd: bool = True
    #: The reported sd is the mixture's: the refit's widths (``scales_mm``) are averaged into one prediction, whose
    #: variance adds to the members' own the spread of their predictions about the mix (sum_s mix_s |est_s - est|^2
    #: / 3 per coordinate), so where the widths disagree the sd says so.  The fill's mean keeps the sd without it.
    #: Measured (2026-11-28, twelfth session; fills unchanged): bench_default's err/std inside 0.5-2 on 74 of 80
    #: trials (70 without); bench_default_captures' gaps needing review flagged 99 of 155 (88), at 265 flagged in
    #: all (212); the committed walk 37 of 43 (36), 53 flagged (51).
    width_spread_sd: bool = True
    #: The reported sd grows by how far the refit's bone stage moved each prediction (its variance by |move|^2 / 3
    #: per coordinate): a correction drawn from soft bones between uncertain estimates is itself uncertain by about
    #: its size, and a prediction the bones had to pull far was not as sure as its cross-validation said (85_02, a
    #: forearm and wrist gone through a flip: 18-32 mm off per coordinate, reported 3-5, pulled 2-5 mm).  The fill's
    #: mean is unchanged.  Measured (2026-11-28, sixteenth session; fills unchanged): bench_default's err/std inside
    #: 0.5-2 on 75 of 80 trials (74 without); bench_default_captures' gaps needing review flagged 108 of 144 (99), at
    #: 291 flagged in all (260); the committed walk unchanged (37 of 43, 54 flagged).
    bone_move_sd: bool = True
    #: Frame rate assumed when the capture has none.
    default_rate: float = 100.0
    #: With a learned denoiser (``--model``, :func:`prior_stage`): observed frames per marker hidden to learn the
    #: sd of the network's estimate of that marker (a few hundred give the RMS to ~5 %).
    prior_frames: int = 200
    #: The network's learnt sd is multiplied by this before the fusion: it underestimates (its errors run in time and
    #: with the local PCA's).  bench_learned, 3 held-out CMU clips x 4 protocols x 2 trials: x1 segment median 80.6
    #: against 92.9 without but one trial 1.46x, dense 15.5 against 14.9; x2 every median at or below (dense 14.8,
    #: segment 87.6, marker 3.0, random 4.6 against 14.9, 92.9, 3.1, 4.7), worst trial 1.08x.
    prior_sd_scale: float = 2.0


DEFAULT_CONFIG = ModelConfig()
