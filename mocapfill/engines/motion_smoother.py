"""A motion prior for every marker: a damped white-jerk state-space model and its Kalman / RTS smoother.

The model (one per marker; its three axes share the covariances, each has its own mean), per frame t:

    state   z_t = [x_t, v_t, a_t, b_t]      position, velocity (per frame), acceleration (per frame^2), and the
                                            spatial prediction's correlated error b (unit variance)
    dynamics z_{t+1} = F z_t + w_t,  w_t ~ N(0, Q)

        F = [[1, 1, 1/2, 0],              Q = [[q/20, q/8, q/6, 0],
             [0, rho, 1, 0],                   [q/8,  q/3, q/2, 0],
             [0, 0, rho_a, 0],                 [q/6,  q/2, q,   0],
             [0, 0, 0, phi]]                   [0,    0,   0,   1 - phi^2]]

    (x, v, a) is the discretised white-jerk model (jerk spectral density q, data units^2 / frame^5) whose velocity
    relaxes with rho = exp(-1 / tau) (tau frames: far from any measurement a fill comes to rest instead of flying
    off) and acceleration with rho_a (by default rho; optionally exp(-1 / tau_a), tau_a the capture's own
    acceleration memory, :func:`acceleration_memory`: where the observed accelerations are mostly noise, the one
    estimated at a gap's edge is then not carried into it); b is an Ornstein-Uhlenbeck process with phi = exp(-1 / tau_b):
    the error of a spatial prediction is correlated over neighbouring frames, so averaging many of them does not
    make it vanish, and a residual seen next to a gap is carried into it.

    observations   y_t = x_t + e,                e ~ N(0, r_obs)             (an observed sample)
    spatial        p_t = x_t + s_t b_t + e',     e' ~ N(0, r_spatial_t)      (a spatial prediction with std sd_t:
                                                                              s_t^2 + r_spatial_t = sd_t^2)

The fill is the posterior mean of x given every measurement of the take (Rauch-Tung-Striebel smoother), its
uncertainty the posterior standard deviation of x: both from the one model, smooth by construction (the jerk prior
sits inside the estimate).  Heavy-tailed spatial errors (a prediction that jumps) are handled by reweighting:
a measurement whose standardised residual r exceeds ``outlier`` gets its variance multiplied by r^2 / outlier^2
and the smoother runs again (an iteratively reweighted, Huber-type estimate).

Cost: one pass over the frames, vectorised over markers, 4 x 4 matrices: linear in frames x markers.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Order of the state: position, velocity, acceleration, spatial-error bias.
N_STATE = 4
#: Integral of the squared quadratic B-spline: Var(third difference of x) = JERK_GAIN * q for white jerk.
JERK_GAIN = 11.0 / 20.0


class MotionModel(NamedTuple):
    """Parameters of :func:`smooth` (see the module docstring).

    ``q`` (n_series,) jerk spectral density per series (data units^2 / frame^5); ``rho`` velocity relaxation per
    frame; ``rho_acc`` the acceleration's (None: ``rho``); ``phi`` correlation per frame of the spatial error;
    ``r_obs`` variance of an observed sample (data units^2); ``gain`` (n_frames,) or None: the jerk density at frame t is q * gain[t] (the body moves
    faster at some moments than at others).
    """

    q: np.ndarray
    rho: float
    phi: float
    r_obs: float
    gain: np.ndarray | None = None
    rho_acc: float | None = None


def transition(model: MotionModel) -> tuple[np.ndarray, np.ndarray]:
    """F (4, 4) and Q (n_series, 4, 4) of the model."""
    rho, phi = model.rho, model.phi
    rho_a = rho if model.rho_acc is None else model.rho_acc
    F = np.array([[1.0, 1.0, 0.5, 0.0], [0.0, rho, 1.0, 0.0], [0.0, 0.0, rho_a, 0.0], [0.0, 0.0, 0.0, phi]])
    jerk = np.array([[1 / 20, 1 / 8, 1 / 6], [1 / 8, 1 / 3, 1 / 2], [1 / 6, 1 / 2, 1.0]])
    Q = np.zeros((len(model.q), N_STATE, N_STATE))
    Q[:, :3, :3] = np.asarray(model.q, dtype=float)[:, None, None] * jerk
    Q[:, 3, 3] = 1.0 - phi ** 2
    return F, Q


def jerk_density(positions: np.ndarray, missing: np.ndarray, *, floor: float) -> np.ndarray:
    """Per-marker white-jerk density q (n_markers,) from the observed third differences.

    positions (n_frames, n_markers, 3); missing (n_frames, n_markers).  For white jerk, E[(x[t+2] - 3 x[t+1] +
    3 x[t] - x[t-1])^2] = JERK_GAIN q per axis: q is the mean square over runs of four observed frames, divided by
    that; a marker with no such run takes the median of the others; ``floor`` (data units^2 / frame^5) bounds it
    below (a marker that never moved would otherwise pin its fill).
    """
    n_frames, n_markers, _ = positions.shape
    q = np.full(n_markers, np.nan)
    if n_frames >= 4:
        d3 = positions[3:] - 3 * positions[2:-1] + 3 * positions[1:-2] - positions[:-3]  # (T - 3, M, 3)
        ok = ~(missing[3:] | missing[2:-1] | missing[1:-2] | missing[:-3])
        sq = np.where(ok[..., None], np.nan_to_num(d3) ** 2, 0.0).sum(axis=(0, 2))
        count = 3 * ok.sum(axis=0)
        q = np.where(count > 0, sq / np.maximum(count, 1) / JERK_GAIN, np.nan)
    known = np.isfinite(q)
    fill = float(np.median(q[known])) if known.any() else floor
    return np.maximum(np.where(known, q, fill), floor)


def acceleration_memory(positions: np.ndarray, missing: np.ndarray, *, max_lag: int) -> float:
    """How many frames the capture's accelerations persist: the lag (frames, interpolated, at most ``max_lag``) at
    which the autocorrelation of its observed second differences falls to 1/e.

    positions (n_frames, n_markers, 3); missing (n_frames, n_markers).  Pooled over markers and axes, each lag over
    the pairs of second differences whose samples are all observed.  Where the observed accelerations are mostly
    noise (they change sign from frame to frame) this is under a frame: an acceleration estimated at a gap's edge
    is then not carried into the gap.  ``max_lag`` when nothing can be measured.
    """
    n_frames = positions.shape[0]
    if n_frames < 4:
        return float(max_lag)
    acc = positions[2:] - 2 * positions[1:-1] + positions[:-2]
    ok = ~(missing[2:] | missing[1:-1] | missing[:-2])
    acc = np.where(ok[..., None], np.nan_to_num(acc), 0.0)
    prev = 1.0
    power = float((acc ** 2).sum() / max(3 * ok.sum(), 1))
    if power <= 0:
        return float(max_lag)
    for lag in range(1, min(int(max_lag), len(acc) - 1) + 1):
        both = ok[lag:] & ok[:-lag]
        if not both.any():
            break
        corr = float((acc[lag:] * acc[:-lag]).sum() / (3 * both.sum())) / power
        if corr < np.exp(-1.0):
            return lag - 1 + (prev - np.exp(-1.0)) / (prev - corr)
        prev = corr
    return float(max_lag)


def jerk_gain(positions: np.ndarray, missing: np.ndarray, q: np.ndarray, *, window: int, floor: float
              ) -> np.ndarray:
    """How fast the body moves at each frame, relative to its average: gain (n_frames,) for :class:`MotionModel`.

    positions (n_frames, n_markers, 3); missing (n_frames, n_markers); q (n_markers,) from :func:`jerk_density`.
    Each observed third difference's squared norm over 3 JERK_GAIN q_m is that marker's jerk power at that frame
    (mean 1 over its frames); the gain is the median over the markers observed there, averaged over a moving
    ``window`` of frames, scaled to mean 1 over the frames, at least ``floor``; 1 where nothing is observed.
    """
    n_frames = positions.shape[0]
    gain = np.ones(n_frames)
    if n_frames < 4:
        return gain
    d3 = positions[3:] - 3 * positions[2:-1] + 3 * positions[1:-2] - positions[:-3]
    ok = ~(missing[3:] | missing[2:-1] | missing[1:-2] | missing[:-3])
    power = np.where(ok, np.nan_to_num(d3 ** 2).sum(axis=2) / (3.0 * JERK_GAIN * q[None, :]), np.nan)
    per_frame = np.full(n_frames, np.nan)
    seen = ok.any(axis=1)
    with np.errstate(all="ignore"):
        # the median over the markers seen: one glitching marker does not make the whole body fast
        per_frame[2:-1][seen] = np.nanmedian(power[seen], axis=1)
    w = max(int(window), 1)
    kernel = np.ones(w)
    known = np.isfinite(per_frame)
    tot = np.convolve(np.where(known, per_frame, 0.0), kernel, mode="same")
    cnt = np.convolve(known.astype(float), kernel, mode="same")
    gain = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    if np.isfinite(gain).any():
        gain = gain / np.nanmean(gain)  # mean 1 over the frames: q stays the capture's average
    gain = np.where(np.isfinite(gain), gain, 1.0)
    return np.maximum(gain, floor)


def smooth(
    obs: np.ndarray,
    spatial: np.ndarray,
    spatial_sd: np.ndarray,
    bias_sd: np.ndarray,
    model: MotionModel,
    *,
    init: np.ndarray | None = None,
    obs_var: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and standard deviation of the position, given every measurement (RTS smoother).

    Parameters
    ----------
    obs : ndarray (n_frames, n_series, 3)
        Observed samples, NaN where not observed (variance ``model.r_obs``).
    spatial : ndarray (n_frames, n_series, 3)
        Spatial predictions, NaN where there is none.
    spatial_sd : ndarray (n_frames, n_series)
        Per-coordinate standard deviation of the white part of each spatial prediction's error.
    bias_sd : ndarray (n_frames, n_series)
        Scale s_t of the correlated part (total variance spatial_sd^2 + bias_sd^2).
    model : MotionModel
    obs_var : ndarray (n_frames, n_series) or None
        Variance of each observed sample (default ``model.r_obs`` everywhere).
    init : ndarray (n_series, 3) or None
        Prior mean of the first position (default: the first measurement of each series); the prior's variance is
        diffuse (1e6 x the largest squared measurement spread).

    Returns
    -------
    mean (n_frames, n_series, 3), sd (n_frames, n_series): per-coordinate posterior standard deviation.
    """
    T, S, _ = obs.shape
    F, Q = transition(model)
    has_obs = np.isfinite(obs).all(axis=2)
    has_sp = np.isfinite(spatial).all(axis=2) & np.isfinite(spatial_sd) & np.isfinite(bias_sd)
    r_sp = np.where(has_sp, spatial_sd ** 2, np.inf)
    s_sp = np.where(has_sp, bias_sd, 0.0)
    y_obs = np.nan_to_num(obs)
    y_sp = np.nan_to_num(spatial)
    if init is None:
        first = np.where(has_obs[..., None], y_obs, np.where(has_sp[..., None], y_sp, np.nan))
        init = np.zeros((S, 3))
        for s in range(S):
            rows = np.flatnonzero(np.isfinite(first[:, s, 0]))
            if len(rows):
                init[s] = first[rows[0], s]
    vals = np.concatenate([obs[has_obs], spatial[has_sp]]) if (has_obs.any() or has_sp.any()) else np.zeros((1, 3))
    spread = float(np.nanmax(np.nanstd(vals, axis=0))) if len(vals) > 1 else 1.0
    big = 1e6 * max(spread, 1.0) ** 2
    m = np.zeros((S, N_STATE, 3))
    m[:, 0] = init
    P = np.zeros((S, N_STATE, N_STATE))
    P[:, 0, 0] = big
    # velocity and acceleration start from their stationary spread (not diffuse: a gap at the take's start must not
    # be extrapolated backwards through an unbounded velocity)
    q0 = np.asarray(model.q, dtype=float) * (1.0 if model.gain is None else float(np.median(model.gain)))
    rho_a = model.rho if model.rho_acc is None else model.rho_acc
    var_a = q0 / max(1.0 - rho_a ** 2, 1e-9)
    P[:, 2, 2] = var_a
    P[:, 1, 1] = var_a / max(1.0 - model.rho, 1e-9) ** 2
    P[:, 3, 3] = 1.0
    mf = np.empty((T, S, N_STATE, 3))
    Pf = np.empty((T, S, N_STATE, N_STATE))
    mpred = np.empty((T, S, N_STATE, 3))  # predictions from t - 1 (the backward pass reuses them)
    Ppred = np.empty((T, S, N_STATE, N_STATE))
    for t in range(T):
        if t:
            m = mpred[t] = np.einsum("ij,sjc->sic", F, m)
            P = Ppred[t] = F @ P @ F.T + _noise(Q, model.gain, t - 1)
        # observation: H = e_x
        if has_obs[t].any():
            r = model.r_obs if obs_var is None else obs_var[t]
            m, P = _update(m, P, y_obs[t], np.where(has_obs[t], r, np.inf))
        if has_sp[t].any():
            m, P = _update(m, P, y_sp[t], r_sp[t], bias=s_sp[t])
        mf[t], Pf[t] = m, P
    # backward (RTS)
    ms, Ps = mf[-1].copy(), Pf[-1].copy()
    mean = np.empty((T, S, 3))
    var = np.empty((T, S))
    mean[-1], var[-1] = ms[:, 0], Ps[:, 0, 0]
    if T > 1:  # the gains of every frame in one batched solve: G = Pf F^T Pp^-1  <=>  Pp G^T = F Pf
        Pp_all = (Ppred[1:] + np.swapaxes(Ppred[1:], 2, 3)) / 2
        G_all = np.swapaxes(np.linalg.solve(Pp_all, F @ Pf[:-1]), 2, 3)
    for t in range(T - 2, -1, -1):
        G, Pp = G_all[t], Pp_all[t]
        ms = mf[t] + G @ (ms - mpred[t + 1])
        Ps = Pf[t] + G @ (Ps - Pp) @ np.swapaxes(G, 1, 2)
        mean[t], var[t] = ms[:, 0], Ps[:, 0, 0]
    return mean, np.sqrt(np.clip(var, 0.0, None))


def _noise(Q: np.ndarray, gain: np.ndarray | None, t: int) -> np.ndarray:
    """Process noise (S, 4, 4) from frame t to t + 1: the jerk block scaled by gain[t]."""
    if gain is None:
        return Q
    out = Q.copy()
    out[:, :3, :3] *= gain[t]
    return out


def _update(m: np.ndarray, P: np.ndarray, y: np.ndarray, r: np.ndarray, bias: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """One scalar-measurement Kalman update per series (shared by the three axes), H = e_x + bias e_b.

    m (S, 4, 3), P (S, 4, 4), y (S, 3), r (S,) (inf: no measurement, the series is left alone), bias (S,) the
    measurement's loading on the correlated error b (None: 0, an observation of x).  P H, H P H^T and H m are
    computed from the two non-zero entries of H.
    """
    ok = np.isfinite(r)
    s = (np.zeros(len(m)) if bias is None else bias)[:, None]
    PH = P[:, :, 0] + P[:, :, 3] * s  # (S, 4)
    innov_var = (PH[:, 0] + PH[:, 3] * s[:, 0]) + np.where(ok, r, 0.0)
    Hm = m[:, 0] + m[:, 3] * s
    K = np.where(ok[:, None], PH / np.where(ok, innov_var, 1.0)[:, None], 0.0)  # (S, 4)
    resid = y - Hm  # (S, 3)
    resid = np.where(ok[:, None], resid, 0.0)
    m = m + K[:, :, None] * resid[:, None, :]
    # Joseph-free form is fine for scalar updates with r > 0; symmetrise against round-off
    P = P - K[:, :, None] * PH[:, None, :]
    return m, (P + np.swapaxes(P, 1, 2)) / 2
