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
    make it vanish, and a residual seen next to a gap is carried into it.  Where the predictions pass to another
    model (``smooth(reset=)``), b is drawn anew (phi = 0 for that step): one model's error is not the next one's.

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
#: Process noise of (x, v, a) over one frame per unit jerk density.
_JERK = np.array([[1 / 20, 1 / 8, 1 / 6], [1 / 8, 1 / 3, 1 / 2], [1 / 6, 1 / 2, 1.0]])


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
    Q = np.zeros((len(model.q), N_STATE, N_STATE))
    Q[:, :3, :3] = np.asarray(model.q, dtype=float)[:, None, None] * _JERK
    Q[:, 3, 3] = 1.0 - phi ** 2
    return F, Q


def jerk_density(positions: np.ndarray, missing: np.ndarray, *, floor: float) -> np.ndarray:
    """Per-marker white-jerk density q (n_markers,) from the observed third differences.

    positions (n_frames, n_markers, 3); missing (n_frames, n_markers).  For white jerk, E[(x[t+2] - 3 x[t+1] +
    3 x[t] - x[t-1])^2] = JERK_GAIN q per axis: q is the mean square over runs of four observed frames, divided by
    that; a marker with no such run takes the median of the others; ``floor`` (data units^2 / frame^5) bounds it
    below (a marker that never moved would otherwise pin its fill).  Where no marker has four observed frames in a
    row (every other frame dropped, a capture upsampled with empty frames), the third differences of frames s apart
    measure it, E[...^2] = JERK_GAIN q s^5, at the smallest stride s that has any: without them q was the floor,
    and the fill a stiff path tens of millimetres off the observed frames it passes between, with a tiny sd.
    """
    n_frames, n_markers, _ = positions.shape
    q = np.full(n_markers, np.nan)
    # no four observed frames s apart exist past a third of a marker's observed span (and none without four frames)
    seen = ~missing
    span = np.where(seen.sum(axis=0) >= 4, n_frames - 1 - np.argmax(seen[::-1], axis=0) - np.argmax(seen, axis=0), 0)
    for stride in range(1, int(span.max(initial=0)) // 3 + 1):
        q = _strided_jerk(positions, missing, stride)
        if np.isfinite(q).any():
            break
    known = np.isfinite(q)
    fill = float(np.median(q[known])) if known.any() else floor
    return np.maximum(np.where(known, q, fill), floor)


def _strided_jerk(positions: np.ndarray, missing: np.ndarray, stride: int) -> np.ndarray:
    """q (n_markers,) from the third differences of frames ``stride`` apart whose four frames are observed (NaN where
    a marker has none): their mean square per axis / (JERK_GAIN stride^5)."""
    s = int(stride)
    if positions.shape[0] < 3 * s + 1:
        return np.full(positions.shape[1], np.nan)
    end = positions.shape[0]
    d3 = positions[3 * s:] - 3 * positions[2 * s:end - s] + 3 * positions[s:end - 2 * s] - positions[:end - 3 * s]
    ok = ~(missing[3 * s:] | missing[2 * s:end - s] | missing[s:end - 2 * s] | missing[:end - 3 * s])
    sq = np.where(ok[..., None], np.nan_to_num(d3) ** 2, 0.0).sum(axis=(0, 2))
    count = 3 * ok.sum(axis=0)
    return np.where(count > 0, sq / np.maximum(count, 1) / (JERK_GAIN * float(s) ** 5), np.nan)


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
        mean = np.nanmean(gain)
        # mean 1 over the frames: q stays the capture's average (where nothing moved, no moment is faster: 1)
        gain = gain / mean if mean > 0 else np.ones(n_frames)
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
    reset: np.ndarray | None = None,
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
    reset : ndarray (n_frames, n_series) bool or None
        Frames where the spatial predictions come from another model than before: the bias b is drawn anew from its
        prior there (b_t ~ N(0, 1), independent of b_{t-1}: the transition's phi is 0 for that step), so one
        model's error is not read as the next one's.

    Returns
    -------
    mean (n_frames, n_series, 3), sd (n_frames, n_series): per-coordinate posterior standard deviation.

    The cost is the per-frame overhead of NumPy calls on small arrays, not arithmetic, so each frame does as few
    calls as possible, on contiguous arrays: the states of all series are the columns of one array, predicted
    (process noise included) by one matrix product; a frame's observation or spatial prediction is one scalar update
    per series (the series that have both, rare, take the spatial one in a second update); what does not depend on
    the recursion is computed for many frames at once (the measurement schedule; the smoother's gains, by chunks).
    """
    T, S, _ = obs.shape
    F = transition(model)[0]
    has_obs = np.isfinite(obs).all(axis=2)
    has_sp = np.isfinite(spatial).all(axis=2) & np.isfinite(spatial_sd) & np.isfinite(bias_sd)
    y_obs = np.nan_to_num(obs)
    y_sp = np.nan_to_num(spatial)
    if init is None:  # the first measurement of each series (0: none)
        seen = has_obs | has_sp
        t0, cols = np.argmax(seen, axis=0), np.arange(S)
        init = np.where(has_obs[t0, cols, None], y_obs[t0, cols], y_sp[t0, cols])
        init[~seen[t0, cols]] = 0.0
    vals = np.concatenate([obs[has_obs], spatial[has_sp]]) if (has_obs.any() or has_sp.any()) else np.zeros((1, 3))
    spread = float(np.max(np.std(vals, axis=0))) if len(vals) > 1 else 1.0  # (vals are finite)
    big = 1e6 * max(spread, 1.0) ** 2
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

    # the measurements as (at most) two scalar updates per frame and series: H = e_x + s e_b, variance r (inf: none)
    r_o = np.full((T, S), model.r_obs, dtype=float) if obs_var is None else np.asarray(obs_var, dtype=float)
    has_obs &= np.isfinite(r_o)  # (an observed sample without a variance is not used)
    both = has_obs & has_sp
    r1 = np.where(has_obs, r_o, np.where(has_sp, spatial_sd ** 2, np.inf))
    s1 = np.where(has_obs | ~has_sp, 0.0, np.nan_to_num(bias_sd))
    y1 = np.where(has_obs[..., None], y_obs, y_sp)
    r2 = np.where(both, spatial_sd ** 2, np.inf)
    s2 = np.where(both, np.nan_to_num(bias_sd), 0.0)
    do1 = np.isfinite(r1).any(axis=1).tolist()
    do2 = both.any(axis=1).tolist()

    # The forward pass holds each series' state in a column: its [P | m] (4 x 7) row by row, then q gain[t] and 1,
    # through which the prediction adds the process noise (the update leaves both alone).  Component-major: every
    # operation of a frame is on a few contiguous rows of n_series values.
    Xf = np.empty((T, _NA, S))  # filtered
    Xf[:, _NX] = np.asarray(model.q, dtype=float)[None, :] * (
        1.0 if model.gain is None else np.asarray(model.gain, dtype=float)[:T, None])
    Xf[:, _NX + 1] = 1.0
    X0 = Xf[0, :_NX].reshape(N_STATE, _NC, S)
    X0[:, :N_STATE] = np.moveaxis(P, 0, -1)
    X0[:, N_STATE:] = 0.0
    X0[0, N_STATE:] = np.asarray(init, dtype=float).T
    Xp = np.empty((T, _NX, S))  # predicted from t - 1 (the backward pass reuses them)
    # a prediction, then the entries the update reads: [P[:, 0], m[0]] and [P[:, 3], m[3]] (H = e_x + s e_b)
    pred = np.empty((_NA + 2 * _NC, S))
    A = _transition_rows(F, model.phi).T.copy()
    y1 = np.ascontiguousarray(np.swapaxes(y1, 1, 2))
    W = np.empty((_NC, S))  # the update's right factor: [P H, H m - y]
    outer = np.empty((N_STATE, _NC, S))
    redraw = None if reset is None else np.asarray(reset, dtype=bool)  # where b is drawn anew
    redraw_at = [False] * T if redraw is None else redraw.any(axis=1).tolist()
    for t in range(T):
        X = Xf[t, :_NX]
        if t:
            np.matmul(A, Xf[t - 1], out=pred)
            if redraw_at[t]:
                _redraw_bias(pred, redraw[t])
            Xp[t] = pred[:_NX]
            if do1[t]:
                _update(pred[:_NX], pred[_NA:_NA + _NC], pred[_NA + _NC:], X, W, outer, y1[t], r1[t], s1[t])
            else:
                X[...] = pred[:_NX]
        elif do1[t]:
            _update(X, X[_HX], X[_HB], X, W, outer, y1[t], r1[t], s1[t])
        if t % 16 == 15:  # see _TINY
            X[np.abs(X) < _TINY] = 0.0
        if do2[t]:  # the spatial prediction after the observation (both, rare): P symmetrised in between
            Pt = X.reshape(N_STATE, _NC, S)[:, :N_STATE]
            Pt[...] = (Pt + np.swapaxes(Pt, 0, 1)) / 2
            _update(X, X[_HX], X[_HB], X, W, outer, y_sp[t].T, r2[t], s2[t])
    # backward (RTS) on the (T, 4, 7, S) [P | m] blocks; the smoothed ones overwrite the filtered ones
    B = Xf[:, :_NX].reshape(T, N_STATE, _NC, S)
    Pf = B[:, :, :N_STATE]
    for i in range(N_STATE):  # symmetrised against round-off after the updates
        for j in range(i + 1, N_STATE):
            np.multiply(Pf[:, i, j] + Pf[:, j, i], 0.5, out=Pf[:, i, j])
            Pf[:, j, i] = Pf[:, i, j]
    Bp = Xp.reshape(T, N_STATE, _NC, S)
    D = np.empty((N_STATE, _NC, S))
    E = np.empty((N_STATE, _NC, S))
    Dv, Ev = np.moveaxis(D, 2, 0), np.moveaxis(E, 2, 0)
    for stop in range(T - 1, 0, -_CHUNK):
        start = max(stop - _CHUNK, 0)
        # the gains of a chunk of frames at once (frames below stop are still filtered):
        # G = Pf F^T Pp^-1  <=>  Pp G^T = F Pf
        FPf = np.zeros((stop - start, N_STATE, N_STATE, S))
        for i, k in zip(*np.nonzero(F)):
            FPf[:, i] += F[i, k] * Pf[start:stop, k]
        if redraw is not None:  # the frames whose next frame draws b anew: F's b row is 0 for that step
            FPf[:, _B] *= ~redraw[start + 1:stop + 1, None, :]
        Gt_all = _solve_spd(Bp[start + 1:stop + 1, :, :N_STATE], FPf)  # G^T (in FPf's place)
        G_all = np.moveaxis(Gt_all, 3, 1).swapaxes(2, 3)  # the per-frame products batched over the series
        for t in range(stop - 1, start - 1, -1):
            if t % 16 == 0:  # see _TINY
                Bt = B[t + 1]
                Bt[np.abs(Bt) < _TINY] = 0.0
            np.subtract(B[t + 1], Bp[t + 1], out=D)
            G = G_all[t - start]
            np.matmul(G, Dv, out=Ev)  # [G (Ps - Pp), G (ms - mp)]
            np.matmul(Ev[:, :, :N_STATE], np.swapaxes(G, 1, 2), out=Ev[:, :, :N_STATE])  # [G (Ps - Pp) G^T, ..]
            B[t] += E
    return np.moveaxis(B[:, 0, N_STATE:], 1, 2).copy(), np.sqrt(np.clip(B[:, 0, 0], 0.0, None))


#: Layout of a series' state in :func:`smooth`: [P | m] (4 x 7) row by row, then q gain and 1.
_NC = N_STATE + 3
_NX = N_STATE * _NC
_NA = _NX + 2
#: Where [P[:, 0], m[0]] and [P[:, 3], m[3]] are in it.
_HX = np.array([0, _NC, 2 * _NC, 3 * _NC, 4, 5, 6])
_HB = np.array([3, _NC + 3, 2 * _NC + 3, 3 * _NC + 3, _NX - 3, _NX - 2, _NX - 1])
#: The bias b's index in the state, and the entries of a prediction (the [P | m] rows, then the copies of
#: [P[:, 0], m[0]] and [P[:, 3], m[3]] the update reads) that :func:`_redraw_bias` sets to 0: b's covariances with x,
#: v and a (both halves) and its mean.
_B = N_STATE - 1
_B_ZERO = np.array([i * _NC + _B for i in range(_B)] + [_B * _NC + j for j in range(_B)]
                   + [_B * _NC + N_STATE + c for c in range(3)] + [_NA + _B]
                   + [_NA + _NC + i for i in range(_B)] + [_NA + _NC + N_STATE + c for c in range(3)])
#: ... and those set to 1: b's variance (in P and in the copy of P[:, 3]).
_B_ONE = np.array([_B * _NC + _B, _NA + _NC + _B])
#: Entries of the state below this are set to 0: the correlations of b with x, v, a shrink by a factor at every
#: observed frame and would otherwise become subnormal numbers (each costing ~100 cycles per arithmetic operation)
#: in long observed stretches; at 1e-150 they are far below the round-off of anything they are combined with.
_TINY = 1e-150
#: Frames whose smoother gains are computed at once (batched over frames and series, a bounded working set).
_CHUNK = 512


def _transition_rows(F: np.ndarray, phi: float) -> np.ndarray:
    """A (30, 44): a row of the forward pass (see :func:`smooth`) times A is the prediction of the next frame,
    P -> F P F^T + Q, m -> F m, q gain and 1 kept (the caller sets q gain per frame), then the entries the update
    reads (_HX, _HB) again.

    P is read as (P + P^T) / 2, so the round-off of the update's two halves is averaged (as symmetrising would),
    and P F^T's two halves come from the same coefficients: the prediction is exactly symmetric."""
    A = np.zeros((_NA, _NA))
    for i in range(N_STATE):
        for j in range(N_STATE):
            for k in range(N_STATE):
                for l in range(N_STATE):
                    A[k * _NC + l, i * _NC + j] = 0.5 * (F[i, k] * F[j, l] + F[i, l] * F[j, k])
            for c in range(3):
                A[j * _NC + N_STATE + c, i * _NC + N_STATE + c] = F[i, j]
    jerk = np.zeros((N_STATE, _NC))
    jerk[:3, :3] = _JERK
    A[_NX, :_NX] = jerk.ravel()
    A[_NX + 1, (N_STATE - 1) * (_NC + 1)] = 1.0 - phi ** 2
    A[_NX, _NX] = A[_NX + 1, _NX + 1] = 1.0
    return np.concatenate([A, A[:, _HX], A[:, _HB]], axis=1)


def _redraw_bias(pred: np.ndarray, cols: np.ndarray) -> None:
    """In a prediction (the forward pass's layout, :func:`_transition_rows`), draw b anew from its prior for the
    series ``cols`` (S,) bool: its variance 1, its covariances with x, v and a 0, its mean 0 (as a transition with
    phi = 0 and process noise 1 would give)."""
    pred[np.ix_(_B_ZERO, cols)] = 0.0
    pred[np.ix_(_B_ONE, cols)] = 1.0


def _update(X: np.ndarray, hx: np.ndarray, hb: np.ndarray, out: np.ndarray, W: np.ndarray, outer: np.ndarray,
            y: np.ndarray, r: np.ndarray, bias: np.ndarray) -> None:
    """One scalar-measurement Kalman update per series (shared by the three axes), H = e_x + bias e_b.

    Component-major (see :func:`smooth`): X (28, S) the [P | m] before, hx / hb (7, S) its [P[:, 0], m[0]] /
    [P[:, 3], m[3]], out (28, S) after (may be X); W (7, S) and outer (4, 7, S) scratch; y (3, S), r (S,) (inf: no
    measurement, the series is left alone: its gain is 0), bias (S,) the measurement's loading on the correlated
    error b (0: an observation of x).  P is left unsymmetrised (the next prediction reads (P + P^T) / 2).
    """
    np.multiply(hb, bias, out=W)  # [P H, H m - y]
    W += hx
    W[N_STATE:] -= y
    innov_var = (W[0] + W[3] * bias) + r  # inf where r is
    K = W[:N_STATE] / innov_var  # (4, S); 0 where r is inf
    np.multiply(K[:, None], W[None], out=outer)
    np.subtract(X.reshape(outer.shape), outer, out=out.reshape(outer.shape))


def _solve_spd(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """X with A X = B for symmetric positive-definite 4 x 4 A (N, 4, 4, S) and B (N, 4, k, S) (the matrices in axes
    1, 2), in B's place: an LDL^T factorisation written out over the batch (np.linalg.solve loops over the tiny
    matrices one by one)."""
    n = A.shape[1]
    b = B
    L = [[None] * n for _ in range(n)]
    d = [None] * n
    for j in range(n):
        dj = A[:, j, j].copy()
        for k in range(j):
            dj -= L[j][k] * L[j][k] * d[k]
        d[j] = dj
        for i in range(j + 1, n):
            v = A[:, i, j].copy()
            for k in range(j):
                v -= L[i][k] * L[j][k] * d[k]
            L[i][j] = v / dj
    for i in range(n):  # L z = b
        for k in range(i):
            b[:, i] -= L[i][k][:, None] * b[:, k]
    for i in range(n):  # D w = z
        b[:, i] /= d[i][:, None]
    for i in range(n - 1, -1, -1):  # L^T x = w
        for k in range(i + 1, n):
            b[:, i] -= L[k][i][:, None] * b[:, k]
    return b
