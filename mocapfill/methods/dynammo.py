"""DynaMMo (Li et al. 2009): fill gaps with a linear dynamical system learned by EM with missing values.

Algorithm (BoLeRO paper section 3.1 and Appendix A; the authors' code as described in IMPLEMENTATION-NOTES.md):

1. Drop markers missing in every frame (they stay NaN).  Initialise the missing entries by per-coordinate linear
   interpolation, holding the nearest observed value before the first and after the last observation (whole-body
   blackouts are bridged the same way).
2. Body frame (``frame``, :mod:`.body_frame`; with >= 3 markers): as in the authors' mocap experiments, each frame
   is moved by a rigid transform into a body-fixed frame: "auto" (default) = a rotation about the vertical axis and
   a translation, fitted to the pelvis and torso markers found from the data (a full rotation instead when they
   tilt beyond 45 degrees: somersaults); occluded frame markers weigh (almost) nothing and fade out over a few
   frames at gap ends.  The missing entries are then interpolated again, linearly in the body frame.  The
   transform is fixed before EM and undone at the end; being rigid it keeps the noise isotropic and inter-marker
   distances exact.  The frame used to be a full rotation fitted to every marker, which lets the arms and legs
   turn it; on the BoLeRO authors' 40 shared trials the "auto" frame cut the median RMSE (one marker / two
   markers) from 53.6 / 94.5 mm to 40.4 / 95.9 with the old start, and from 14.5 / 33.6 to 13.2 / 21.2 with the
   wide start of step 3; to 11.2 / 19.7 once a rigid hand could no longer pass for the pelvis (12 of the 40 trials
   had modelled the body in a hand's frame).  Then ONE mean per axis (over all markers and observed frames) is removed and everything
   is divided by ONE global scalar (the RMS of the observed values), so the isotropic noise model stays isotropic;
   all results are returned in the data's units.  Not centring each column: a column mean over the observed
   frames fixes each marker's offset at its value outside its gap, while in the body frame the offsets are part of
   the shared low-rank model (the authors do not centre); measured on the 40 trials with a wide start, per-column
   centring gave 28.5 / 58.7 mm against 15.3 / 22.7 without.
3. Initialise the parameters from the data, deterministically: ``G`` = the first H principal directions of the
   interpolated data, ``F`` = the least-squares transition of the principal scores; ``Gamma``, ``Lambda`` and
   ``sigma2`` wide (:data:`DEFAULT_INIT_NOISE` x the data's mean square, isotropic), which is what lets EM leave
   the linear interpolation it starts from.  Only when H exceeds the data's rank are the extra columns of ``G``
   drawn from ``seed`` (small values).
4. Repeat: E-step (Kalman filter + RTS smoother, :mod:`.lds`) on the completed data -> objective -> replace the
   missing entries by ``G E[z_t]`` (or by ``project(...)``, BoLeRO's hook, which sees only the frames with a
   missing marker, converted sample by sample) -> stop if converged -> M-step.
5. ``bridge=True`` (the default): add the model's residual at each gap's observed neighbours, blended
   linearly across the gap, so the fill meets the observed trajectory without a jump (an LDS with H = 16 does not
   reproduce 123 coordinates exactly; on CMU 85_02 this cut the RMSE of 0.9-1.7 s gaps by 10-45 %); with a
   ``project`` hook the bridged estimate is projected once more.

Objective and monotonicity: ``objective[k]`` is the negative log-likelihood ``-log p(X_k | Theta_k)`` of the
*completed* data (observed + the imputation current at iteration k), per scalar entry, in the data's units (nats per
coordinate; ``+ log(scale)`` converts from the internal scaling).  It is the EM free energy, and each of the three
steps (E-step, imputation ``x_miss = G E[z]``, M-step) can only lower it, so without ``project`` the trace is
non-increasing (up to rounding).  ``project`` replaces the imputation by something else (bone-length projection) and
voids that guarantee.  Convergence: ``|objective[k] - objective[k-1]| <= tol * max(1, |objective[k-1]|)`` measured
on the internal (unit-RMS) scale, where the objective is O(1); else ``ConvergenceWarning`` at ``max_iter``.

Uncertainty: ``std`` of a filled sample is the predictive standard deviation of the marker's coordinates, in the
data's units.  In gaps of at least :data:`.gap_uncertainty.MIN_FRAMES` frames it is
``sqrt(mean_xyz diag(G_k Cov[z_t | observed] G_k^T) + d_t^2)``: the posterior, treating the missing entries as
*missing* (one extra covariance-only pass, :func:`.lds.missing_data_variance`), plus the squared disagreement
between the fill and a second opinion (:mod:`.gap_uncertainty`: the marker regressed on its nearest markers seen
throughout the gap, bridged to the gap's ends as the fill is, in Brownian-bridge shape over the gap).  The model's
posterior hardly grows inside a gap, its error does, and by how much depends on whether the gap's poses are ones
the capture has shown, which the model cannot know.  In shorter gaps (and with ``uncertainty="model"``) it is
``sqrt(posterior + sigma2 + drift)`` with a Brownian bridge ``drift`` across the gap (:data:`DRIFT_RATE`,
:func:`gap_drift_variance`).

Speed: see :mod:`.lds` (isotropic noise + Woodbury, steady-state covariances, vectorised mean passes).
"""

from __future__ import annotations

import warnings
from typing import Callable, NamedTuple

import numpy as np

from ..errors import ConvergenceWarning, MethodError
from ..gaps import brownian_variance, end_blend, runs
from ..runtime.blas import single_blas_thread
from ..engines import lds
from .base import FillResult, ProgressFn, check_positions, finish
from ..engines.gap_uncertainty import gap_variance
from .interp import interpolate_columns

#: Defaults chosen by measurement.  H = 16 and at most 200 iterations as in the authors' experiments (on the 40
#: shared trials H = 12 / 24 gave 19.7 / 13.9 mm one marker and 32.2 / 33.8 two markers against 13.8 / 22.3 with 16).
#: tol = 1e-5 (the authors' value; our objective is per entry on the unit-RMS scale): with the wide start of
#: DEFAULT_INIT_NOISE, EM keeps improving for a long time, and tol = 1e-4 stopped it after ~60 iterations at 14.4 /
#: 31.2 mm against 13.8 / 22.3 (1e-5, which nearly always runs the 200; 400 iterations: 13.5 / 21.9).
DEFAULT_HIDDEN = 16
DEFAULT_MAX_ITER = 200
DEFAULT_TOL = 1e-5

#: Start EM with wide noise: Gamma = Lambda = sigma2 I = DEFAULT_INIT_NOISE x the data's mean square (internal
#: scale), the PCA directions and transition kept.  The first E-step's posterior covariances then dominate the
#: M-step's second moments, so the first M-step shrinks G and F strongly and EM does not settle at the fixed point
#: its start is tuned to: the PCA of the linearly interpolated data, whose imputation stays near the straight line
#: across each gap.  (The authors start from random F, G and identity noise in metres, a few times the data's mean
#: square.)  Measured on the 40 shared trials of the BoLeRO authors (``benchmarks/bench_authors.py``), median RMSE
#: one marker / two markers: 14.7 / 72.7 mm with the PCA start's own noise estimates, 12.2 / 38.5 with 3, 13.7 /
#: 21.8 with 30, 14.4 / 20.0 with 100, 14.9 / 22.5 with 1000 (no centring, pelvis frame, tol 1e-5).
DEFAULT_INIT_NOISE = 100.0

#: In gaps shorter than :data:`.gap_uncertainty.MIN_FRAMES` (and with ``uncertainty="model"``) ``std`` adds to the
#: model's posterior variance a Brownian bridge across each gap with this rate x sigma2 per frame
#: (:func:`gap_drift_variance`).  Fitted on 34 gaps longer than 1 s of three clips (14 of the authors' trials on
#: 132_32, 10 on CMU 85_02, 10 on the tennis serve): median ratio of actual to predicted RMS error 2.95 with the
#: posterior alone, 1.0 with 0.16.  On five clips it was not fitted to the median ratio was 3.8 and one gap 140, which
#: is why long gaps now ask a second opinion instead (``benchmarks/bench_dynammo.py --uncertainty``).
DRIFT_RATE = 0.16

#: With a ``project`` hook, the objective-change stop test fires from iteration ``project_start + 2`` on, so that it
#: compares two completed data sets the hook has shaped: the objective jumps when the hook starts, and the old test
#: (from iteration 2) could stop EM right when it started, or before (``project_start > 2``).
STOP_TEST_AFTER_PROJECT = 2



class ProjectStep(NamedTuple):
    """What :func:`run_dynammo` hands its ``project`` hook (BoLeRO's constraint solve), one call per EM iteration.

    Only the frames with a missing (modelled) marker are passed, so a hook costs nothing where there is nothing to
    impute.  ``n`` = ``len(frames)``.

    estimate : (n, n_markers, 3) data units: the model's estimate ``G E[z_t]`` at the missing samples (with the
        gap-end residual bridge added in the ``final`` call), the observed data at the observed samples, NaN for
        markers missing throughout.  A fresh array: the hook may modify it and return it.
    frames : (n,) int, ascending: which frames of the input the rows are (the same array at every call).
    missing : (n, n_markers) bool: the input's missing mask at those frames (the same array at every call).
    sigma2 : isotropic observation-noise variance of the current model, data units squared.
    iteration : EM iteration (1-based); in the ``final`` call, the last one.
    final : True for the one call after EM, on the bridged estimate; its answer is the method's output.
    """

    estimate: np.ndarray
    frames: np.ndarray
    missing: np.ndarray
    sigma2: float
    iteration: int
    final: bool


#: ``project(step: ProjectStep) -> ndarray (n, n_markers, 3)`` whose missing samples become the new imputation
#: (see :func:`run_dynammo`).
ProjectFn = Callable[[ProjectStep], np.ndarray]


class _ProjectHook:
    """Calls ``project`` on the missing samples only: internal <-> data conversion of those samples, not of X.

    ``X`` (T, m) is the engine's completed data (internal units, C-contiguous), updated in place at its missing
    entries; the other arguments are the engine's transform (see :func:`_run_dynammo`).
    """

    def __init__(self, project, positions, missing, keep, miss_k, X, scale, centre, rot, shift):
        self.project = project
        self.X = X.reshape(-1)  # a view: writes go to X
        self.frames = np.flatnonzero(miss_k.any(axis=1))
        self.missing = missing[self.frames]
        rows, marks = np.nonzero(miss_k[self.frames])  # missing samples, row-major: the order of X[miss_cols]
        t = self.frames[rows]
        self.idx = (t * X.shape[1] + 3 * marks)[:, None] + np.arange(3)  # (S, 3) flat indices into X
        self.at = (rows, np.flatnonzero(keep)[marks])  # the same samples in the hook's (n, n_markers) arrays
        self.base = positions[self.frames]  # observed samples (and NaN for markers missing throughout)
        self.scale = scale
        self.centre = centre.reshape(-1, 3)[marks]  # (S, 3)
        self.rot = None if rot is None else np.ascontiguousarray(rot[t])  # (S, 3, 3)
        self.shift = None if shift is None else shift[t]  # (S, 3)

    def __call__(self, sigma2: float, iteration: int, *, final: bool) -> None:
        v = self.X[self.idx] * self.scale + self.centre  # (S, 3) body frame, data units
        if self.rot is not None:
            v = np.einsum("sij,sj->si", self.rot, v) + self.shift
        est = self.base.copy()
        est[self.at] = v
        out = np.asarray(self.project(ProjectStep(est, self.frames, self.missing, float(sigma2), int(iteration),
                                                  bool(final))), dtype=np.float64)
        if out.shape != est.shape:
            raise MethodError(f"project returned shape {out.shape}, expected {est.shape}")
        d = out[self.at]
        if self.rot is not None:
            d = np.einsum("sji,sj->si", self.rot, d - self.shift)
        self.X[self.idx] = (d - self.centre) / self.scale


def body_frame_transform(Y: np.ndarray, observed: np.ndarray, frame: str, markers=None
                         ) -> tuple[np.ndarray | None, np.ndarray | None, dict]:
    """The per-frame rigid transform DynaMMo models the data in (see :mod:`.body_frame`).

    Y : (T, M, 3) interpolated (finite) positions; observed : (T, M) bool; ``frame`` one of
    :data:`.body_frame.FRAMES`; ``markers``: indices into M of the frame markers (None: found from the data).
    Returns ``(R, c, info)``: R (T, 3, 3), c (T, 3) with ``world = R @ local + c``; (None, None, info) for "none"
    or fewer than 3 markers.
    """
    from ..engines import body_frame as bf

    T, M, _ = Y.shape
    if frame not in bf.FRAMES:
        raise MethodError(f"frame must be one of {', '.join(bf.FRAMES)}, got {frame!r}")
    if frame == "none" or M < 3:
        return None, None, {"frame": "none"}
    Yn = np.where(observed[:, :, None], Y, np.nan)
    axis = bf.vertical_axis(Yn)
    if markers is None:
        idx = bf.frame_markers(Yn, axis=axis)
    else:
        idx = np.unique(np.asarray(markers, dtype=np.intp).reshape(-1))
        if idx.size < 2 or idx.min() < 0 or idx.max() >= M:
            raise MethodError(f"frame_markers must be at least 2 indices of modelled markers (0..{M - 1})")
    w = bf.fade_weights(observed[:, idx])
    kind = frame
    if frame == "auto":
        kind = "yaw"
        R, c = bf.fit_frames(Y[:, idx], w, axis=None)
        if bf.tilt_percentile(R, axis) > bf.UPRIGHT_TILT_DEG:
            kind = "full"
    if kind == "yaw" or frame != "auto":
        R, c = bf.fit_frames(Y[:, idx], w, axis=axis if kind == "yaw" else None)
    return R, c, {"frame": kind, "frame_markers": [int(k) for k in idx], "vertical_axis": axis}


def _frame_refit(filled: np.ndarray, missing: np.ndarray, frame_info: dict, scale: float):
    """``refit(hidden, lo, hi)`` for :func:`.gap_uncertainty.gap_variance`: frames [lo, hi) of the filled data
    (hi - lo, 3 M) in a body frame fitted as the engine's was but without the ``hidden`` markers, divided by
    ``scale``; None when they are not frame markers (or fewer than 2 would remain).  filled (T, M, 3): the modelled
    markers, data and fill, world frame; missing (T, M)."""
    from ..engines import body_frame as bf

    idx = frame_info.get("frame_markers") or []
    kind = frame_info.get("frame")
    if kind not in ("yaw", "full") or not idx:
        return None

    def refit(hidden: np.ndarray, lo: int, hi: int) -> np.ndarray | None:
        rest = np.setdiff1d(idx, hidden)
        if len(rest) == len(idx) or len(rest) < 2:
            return None
        window = filled[lo:hi]
        R, c = bf.fit_frames(window[:, rest], bf.fade_weights(~missing[lo:hi, rest]), rounds=1,
                             axis=frame_info["vertical_axis"] if kind == "yaw" else None)
        return np.matmul(window - c[:, None, :], R).reshape(hi - lo, -1) / scale

    return refit


def gap_drift_variance(missing: np.ndarray, rate: float) -> np.ndarray:
    """(T, M) variance of a Brownian bridge across each gap, ``rate * d_a * d_b / (L + 1)`` (0 where observed).

    missing : (T, M) bool.  For a gap of length L, d_a and d_b are the distances (frames) of a sample to the observed
    frames before and after it; a gap touching the clip's edge grows as a random walk, ``rate * d``, from its one
    observed end; a marker missing throughout gets 0 (it is not filled).
    """
    T, M = missing.shape
    out = np.zeros((T, M))
    for j in range(M):
        for a, length in runs(missing[:, j]):
            out[a:a + length, j] = rate * brownian_variance(a, length, T)
    return out


def bridge_residuals(X: np.ndarray, Ez: np.ndarray, G: np.ndarray, missing: np.ndarray) -> None:
    """Add the model residual at each gap's observed neighbours to the gap, blended linearly (in place).

    Parameters
    ----------
    X : (T, 3 M) completed data, modified in place at the missing entries.
    Ez : (T, H) smoothed means; G : (3 M, H); missing : (T, M) bool.

    For a gap of marker k over frames [a, b) the residual ``r = x - G_k E[z]`` at frames a - 1 and b (where they
    exist) is added with weights (b - t) / (b - a + 1) and (t - a + 1) / (b - a + 1); a gap touching the first or
    last frame gets its one neighbour's residual held.  A marker missing throughout is left alone.
    """
    T = X.shape[0]
    for j in range(missing.shape[1]):
        cols = slice(3 * j, 3 * j + 3)
        for a, length in runs(missing[:, j]):
            b = a + length
            left = X[a - 1, cols] - G[cols] @ Ez[a - 1] if a > 0 else None
            right = X[b, cols] - G[cols] @ Ez[b] if b < T else None
            blend = end_blend(left, right, length)
            if blend is not None:
                X[a:b, cols] += blend


def choose_hidden(X: np.ndarray, energy: float) -> int:
    """Smallest number of principal components of X (T, m) whose share of the total variance reaches ``energy``."""
    if not 0 < energy <= 1:
        raise MethodError(f"energy must be in (0, 1], got {energy}")
    sv2 = np.linalg.svd(X, compute_uv=False) ** 2
    if sv2.sum() <= 0:
        return 1
    return int(min(np.searchsorted(np.cumsum(sv2) / sv2.sum(), energy - 1e-12) + 1, len(sv2)))


def initial_params(X: np.ndarray, hidden: int, rng: np.random.Generator, *, var_floor: float = 1e-6,
                   noise: float | None = None) -> lds.LDSParams:
    """Deterministic start for EM from the completed, scaled data ``X`` (T, m) (PCA + least squares).

    ``noise``: when given, Gamma, Lambda and sigma2 all start at ``noise`` x mean(X^2) (see
    :data:`DEFAULT_INIT_NOISE`) instead of the residuals' variances.

    Returns LDSParams with G (m, hidden), isotropic Gamma and Lambda, and sigma2 floored at ``var_floor``.
    """
    T, m = X.shape
    H = hidden
    # Principal directions from the m x m scatter matrix (cheap for tall X).
    evals, evecs = np.linalg.eigh(X.T @ X)
    order = np.argsort(evals)[::-1]
    evals, evecs = evals[order], evecs[:, order]
    r = int(min(H, m, max(T, 1), np.sum(evals > 1e-12 * max(evals[0], 1e-300))))
    r = max(r, 1)
    G = np.zeros((m, H))
    G[:, :r] = evecs[:, :r]
    if r < H:  # more hidden dimensions than the data's rank: small random directions, from the seed only
        G[:, r:] = 1e-2 * rng.standard_normal((m, H - r)) / np.sqrt(m)
    Z = X @ evecs[:, :r]
    Zf = np.zeros((T, H))
    Zf[:, :r] = Z
    resid = X - Z @ evecs[:, :r].T
    sigma2 = max(float(np.mean(resid ** 2)), var_floor)
    F = np.eye(H)
    lam = 1e-2
    if T >= 2:
        Z0, Z1 = Zf[:-1], Zf[1:]
        S = Z0.T @ Z0 + 1e-9 * np.eye(H) * max(np.trace(Z0.T @ Z0), 1.0)
        F = lds._chol_solve(S, Z0.T @ Z1).T
        lam = max(float(np.mean((Z1 - Z0 @ F.T) ** 2)), var_floor)
    eye = np.eye(H)
    if noise is not None:  # a wide start: see DEFAULT_INIT_NOISE
        lam = sigma2 = float(noise) * float(np.mean(X ** 2))
    return lds.LDSParams(F, G, Zf[0].copy(), lam * eye, lam * eye, sigma2)


def run_dynammo(
    positions: np.ndarray,
    *,
    hidden: int = DEFAULT_HIDDEN,
    max_iter: int = DEFAULT_MAX_ITER,
    tol: float = DEFAULT_TOL,
    seed: int | None = None,
    progress: ProgressFn | None = None,
    project: ProjectFn | None = None,
    project_start: int = 1,
    energy: float | None = None,
    isotropic: bool = True,
    uncertainty: bool | str = True,
    body_frame: bool = True,
    bridge: bool = True,
    frame: str = "auto",
    frame_markers=None,
    init_noise: float = DEFAULT_INIT_NOISE,
) -> FillResult:
    """The DynaMMo EM engine (reused by BoLeRO through ``project``).

    Parameters
    ----------
    positions : ndarray (n_frames, n_markers, 3), NaN = missing.
    hidden : int
        Hidden dimension H (ignored when ``energy`` is given); at most the observed coordinates, 3 x the markers
        not missing throughout: a larger H is capped there (a UserWarning unless it is the default,
        ``info["hidden_capped"]`` the value asked).
    max_iter, tol : EM cap and the convergence tolerance on the objective (see the module docstring).
    seed : int or None
        Only used when H exceeds the rank of the data (random extra columns of G); otherwise the start is PCA.
    progress : ``progress(iteration, max_iter, objective)`` called once per EM iteration.
    project : ``project(step: ProjectStep) -> ndarray``, optional
        Called after each E-step from iteration ``project_start`` on (iterations count from 1) with a
        :class:`ProjectStep`: the frames with a missing marker only, ``step.estimate`` (n, n_markers, 3) = G E[z_t]
        in the data's units at the missing samples and the data elsewhere; its return value (n, n_markers, 3) at
        the missing samples becomes the new imputation.  With ``bridge`` it is called once more after EM
        (``step.final``) on the bridged estimate, and that answer is the output.  Without it the imputation is
        G E[z_t].
    energy : float in (0, 1], optional
        Choose H as the number of principal components of the interpolated data holding this share of variance.
    isotropic : bool
        Isotropic Gamma and Lambda (the authors' default); ``sigma2`` is always isotropic.
    body_frame : bool
        Model the data in a per-frame body-fixed frame (see the module docstring); needs >= 3 modelled markers.
    bridge : bool
        After EM, add to each filled gap the model's residual ``x - G E[z]`` at the observed frames on either side
        of the gap, blended linearly across it (held at a capture edge), so the fill joins the observed
        trajectory without a jump (:func:`bridge_residuals`); with ``project``, the bridged model estimate goes
        through the hook once more (``final``), so its answer still meets the hook's constraints.  On by default:
        ``fill_dynammo`` and BoLeRO both run the engine with its defaults, so their settings cannot drift.
    uncertainty : True, "model" or False
        Compute ``std`` (one extra covariance pass); gaps of at least :data:`.gap_uncertainty.MIN_FRAMES` frames
        take their error from the disagreement with a second opinion (:mod:`.gap_uncertainty`) unless ``"model"``
        asks for the model's posterior with its drift everywhere; False gives ``std=None``.

    Returns
    -------
    FillResult with ``positions`` (n_frames, n_markers, 3), ``std`` (n_frames, n_markers) (see module docstring),
    ``n_iter``, ``converged``, ``objective`` (per-entry NLL of the completed data, data units), ``info`` with
    ``hidden``, ``sigma2`` (data units^2), ``scale``, ``markers_modelled``, ``markers_all_missing``,
    ``steady_state_frames`` (frames the filter needed to reach its steady state in the last E-step).
    """
    with single_blas_thread():
        return _run_dynammo(positions, hidden=hidden, max_iter=max_iter, tol=tol, seed=seed, progress=progress,
                            project=project, project_start=project_start, energy=energy, isotropic=isotropic,
                            uncertainty=uncertainty, body_frame=body_frame, bridge=bridge, frame=frame,
                            frame_markers=frame_markers, init_noise=init_noise)


def _run_dynammo(positions, *, hidden, max_iter, tol, seed, progress, project, project_start, energy, isotropic,
                 uncertainty, body_frame, bridge, frame, frame_markers, init_noise) -> FillResult:
    """The body of :func:`run_dynammo` (called with OpenBLAS limited to one thread)."""
    positions = check_positions(positions)
    if max_iter < 1:
        raise MethodError(f"max_iter must be at least 1, got {max_iter}")
    if energy is None and (int(hidden) != hidden or hidden < 1):
        raise MethodError(f"hidden must be a positive integer, got {hidden}")
    if tol < 0:
        raise MethodError(f"tol must be >= 0, got {tol}")
    T, M, _ = positions.shape
    missing = np.isnan(positions).any(axis=2)
    keep = ~missing.all(axis=0) if T else np.zeros(M, bool)
    info = {"markers_all_missing": [int(k) for k in np.flatnonzero(~keep)], "markers_modelled": int(keep.sum())}
    if T == 0 or not keep.any() or not missing[:, keep].any():
        std = np.zeros((T, M)) if uncertainty else None
        return finish(positions, positions, std=std, n_iter=0, converged=True, objective=[], info=info)
    rng = np.random.default_rng(seed)

    Mk = int(keep.sum())
    m = 3 * Mk
    miss_k = missing[:, keep]
    miss_cols = np.repeat(miss_k, 3, axis=1)
    Y = interpolate_columns(positions[:, keep, :].reshape(T, m), miss_cols, empty=0.0)
    rot = rot_t = shift = None
    if frame_markers is not None:  # input marker indices -> modelled ones (markers missing throughout dropped)
        fm = np.asarray(frame_markers, dtype=np.intp).reshape(-1)
        if fm.size and (fm.min() < 0 or fm.max() >= M):
            raise MethodError(f"frame_markers must be marker indices in 0..{M - 1}, got {list(fm)}")
        frame_markers = (np.cumsum(keep) - 1)[fm[keep[fm]]]
    rot, shift, frame_info = body_frame_transform(Y.reshape(T, Mk, 3), ~miss_k, frame if body_frame else "none",
                                                  frame_markers)
    info.update(frame_info)
    if rot is not None:
        rot_t = np.ascontiguousarray(rot.transpose(0, 2, 1))  # batched matmul is slow on strided batches
        Y = np.matmul(Y.reshape(T, Mk, 3) - shift[:, None, :], rot).reshape(T, m)
        Y = interpolate_columns(Y, miss_cols, empty=0.0)  # interpolating in the body frame follows the body's turning
    # Mean per axis and RMS over observed entries only, without (T, m) temporaries: totals minus the missing
    # entries.  One mean per axis, not per column: see the module docstring.
    mi, mj = np.nonzero(miss_cols)
    n_obs = T - np.bincount(mj, minlength=m)
    col_sum = Y.sum(axis=0) - np.bincount(mj, weights=Y[mi, mj], minlength=m)
    centre = np.tile(col_sum.reshape(-1, 3).sum(axis=0) / n_obs.reshape(-1, 3).sum(axis=0), Mk)
    X = Y
    X -= centre
    ss = float(np.einsum("ij,ij->", X, X)) - float(np.sum(X[mi, mj] ** 2))
    scale = float(np.sqrt(max(ss, 0.0) / n_obs.sum()))
    if not np.isfinite(scale) or scale <= 0:
        scale = 1.0
    X /= scale
    del Y

    def to_data(Z: np.ndarray) -> np.ndarray:
        """Internal (T, m) -> data units (T, Mk, 3)."""
        out = (Z * scale + centre).reshape(T, Mk, 3)
        if rot is not None:
            out = np.matmul(out, rot_t) + shift[:, None, :]
        return out

    H = choose_hidden(X, energy) if energy is not None else int(hidden)
    if H > m:
        # States beyond the observed coordinates add nothing the data can pin down, and EM's cost grows as H^3
        # (--hidden 1000 ran for minutes); a default the user did not choose is capped quietly.
        if H != DEFAULT_HIDDEN:
            warnings.warn(f"hidden={H} is more than the {m} coordinates of the {Mk} observed markers: capped at {m}",
                          UserWarning, stacklevel=4)
        info["hidden_capped"] = H
        H = m
    params = initial_params(X, H, rng, noise=init_noise)
    log_scale = float(np.log(scale))
    # The imputation touches only the missing entries: per marker, the frames where it is missing.  |x_t|^2 and
    # sum |x|^2 are kept as "observed part (constant) + missing part (updated)".
    rows = [(r, slice(3 * j, 3 * j + 3)) for j in range(Mk) if len(r := np.flatnonzero(miss_k[:, j]))]
    x2_obs = np.einsum("ij,ij->i", X, X) - np.bincount(mi, weights=X[mi, mj] ** 2, minlength=T)

    def row_norms() -> np.ndarray:
        x2 = x2_obs.copy()
        for r, c in rows:
            x2[r] += np.einsum("ij,ij->i", X[r, c], X[r, c])
        return x2

    def impute(Ez: np.ndarray, G: np.ndarray) -> np.ndarray:
        """Missing entries <- G E[z_t]; returns the completed rows' |x_t|^2 (no second pass over X for it)."""
        x2 = x2_obs.copy()
        for r, c in rows:
            v = Ez[r] @ G[c].T
            X[r, c] = v
            x2[r] += np.einsum("ij,ij->i", v, v)
        return x2

    if project is not None:
        hook = _ProjectHook(project, positions, missing, keep, miss_k, X, scale, centre, rot, shift)
    first_test = 2 if project is None else max(2, project_start + STOP_TEST_AFTER_PROJECT)
    objective: list[float] = []
    converged = False
    n_iter = 0
    sm = None
    x2 = row_norms()  # then updated after each imputation: the M-step and the next E-step share it
    for it in range(1, max_iter + 1):
        n_iter = it
        stats, sm, nll = lds.e_step(params, X, x2=x2, rtol=lds.STEADY_RTOL)  # read per call: tests tighten it
        obj = nll / (T * m)  # per entry, internal scale
        objective.append(obj + log_scale)
        if progress is not None:
            progress(it, max_iter, obj + log_scale)
        x2 = impute(stats.Ez, params.G)  # missing entries <- G E[z_t]
        if project is not None and it >= project_start:
            hook(params.sigma2 * scale ** 2, it, final=False)  # ... or the hook's answer
            x2 = row_norms()
        # With a hook, compare only objectives of two completed data the hook has shaped (from project_start + 2):
        # the first one after it starts jumps, and may by chance be close to the last unprojected one.
        if it >= first_test and abs(objective[-1] - objective[-2]) <= tol * max(1.0, abs(objective[-2] - log_scale)):
            converged = True
            break
        if it == max_iter:
            break
        params = lds.m_step(stats, X.T @ stats.Ez, float(x2.sum()), m, params, isotropic=isotropic)
    if bridge:
        if project is not None:
            impute(stats.Ez, params.G)  # bridge the model's estimate, then let the hook have the last word
        bridge_residuals(X, stats.Ez, params.G, miss_k)
        if project is not None:
            hook(params.sigma2 * scale ** 2, n_iter, final=True)
    if not converged:
        warnings.warn(f"DynaMMo stopped at max_iter={max_iter} before the objective changed by less than "
                      f"tol={tol:g}", ConvergenceWarning, stacklevel=4)

    estimate = np.full((T, M, 3), np.nan)
    estimate[:, keep, :] = to_data(X)
    std = None
    if uncertainty:
        posterior = lds.missing_data_variance(params, ~miss_k)
        var = posterior + gap_drift_variance(miss_k, DRIFT_RATE * params.sigma2) + params.sigma2
        if uncertainty != "model":  # long gaps: the disagreement with a second opinion, not the model's belief
            second = gap_variance(X, ~miss_k, _frame_refit(estimate[:, keep], miss_k, frame_info, scale))
            # The bridged fill meets the data at the gap's ends: no observation noise on top of the disagreement.
            var = np.where(np.isnan(second), var, posterior + second)
        std = np.full((T, M), np.nan)
        std[:, keep] = np.sqrt(var) * scale
    info.update(hidden=H, sigma2=float(params.sigma2 * scale ** 2), scale=scale,
                steady_state_frames=int(len(sm.Vhat.head)) if sm is not None else 0, body_frame=rot is not None,
                objective_kind="negative log-likelihood of the completed data per entry (nats, data units)")
    return finish(positions, estimate, std=std, n_iter=n_iter, converged=converged, objective=objective, info=info)


def fill_dynammo(
    positions: np.ndarray,
    *,
    hidden: int = DEFAULT_HIDDEN,
    max_iter: int = DEFAULT_MAX_ITER,
    tol: float = DEFAULT_TOL,
    seed: int | None = None,
    progress: ProgressFn | None = None,
    energy: float | None = None,
) -> FillResult:
    """Fill gaps with DynaMMo (see the module docstring); positions (n_frames, n_markers, 3), NaN = missing.

    Returns a FillResult whose ``std`` (n_frames, n_markers) is each filled sample's predictive standard deviation
    in the data's units.
    """
    return run_dynammo(positions, hidden=hidden, max_iter=max_iter, tol=tol, seed=seed, progress=progress,
                       energy=energy)
