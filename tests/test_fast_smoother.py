"""motion_smoother.smooth (component-major forward pass, gains for all frames at once) against a plain reference:
the per-frame Kalman filter and RTS smoother written out below, one frame and one measurement at a time."""

from __future__ import annotations

import numpy as np
import pytest

from mocapfill.engines.motion_smoother import N_STATE, MotionModel, smooth, transition


def reference_smooth(obs, spatial, spatial_sd, bias_sd, model, *, init=None, obs_var=None, reset=None):
    """The smoother as a straightforward loop: predict, update with the observation, update with the spatial
    prediction (H = e_x + s e_b), symmetrise; then RTS backwards with G = Pf F_t^T Pp^-1.  ``reset`` (T, S) bool:
    the transition into frame t has phi = 0 and the bias's process noise 1 there (b drawn anew)."""
    T, S, _ = obs.shape
    F0, Q = transition(model)

    def step(t, s):  # the transition into frame t of series s
        F = F0.copy()
        if reset is not None and reset[t, s]:
            F[3, 3] = 0.0
        return F
    has_obs = np.isfinite(obs).all(axis=2)
    has_sp = np.isfinite(spatial).all(axis=2) & np.isfinite(spatial_sd) & np.isfinite(bias_sd)
    if init is None:
        init = np.zeros((S, 3))
        for s in range(S):
            for t in range(T):
                if has_obs[t, s] or has_sp[t, s]:
                    init[s] = obs[t, s] if has_obs[t, s] else spatial[t, s]
                    break
    vals = np.concatenate([obs[has_obs], spatial[has_sp]])
    spread = float(np.max(np.std(vals, axis=0))) if len(vals) > 1 else 1.0
    big = 1e6 * max(spread, 1.0) ** 2
    rho_a = model.rho if model.rho_acc is None else model.rho_acc
    q0 = np.asarray(model.q, float) * (1.0 if model.gain is None else float(np.median(model.gain)))
    var_a = q0 / max(1.0 - rho_a ** 2, 1e-9)
    mf = np.empty((T, S, N_STATE, 3))
    Pf = np.empty((T, S, N_STATE, N_STATE))
    mp = np.empty((T, S, N_STATE, 3))
    Pp = np.empty((T, S, N_STATE, N_STATE))
    for s in range(S):
        m = np.zeros((N_STATE, 3))
        m[0] = init[s]
        P = np.diag([big, var_a[s] / max(1.0 - model.rho, 1e-9) ** 2, var_a[s], 1.0])
        for t in range(T):
            if t:
                Qt = Q[s].copy()
                if model.gain is not None:
                    Qt[:3, :3] *= model.gain[t - 1]
                F = step(t, s)
                if reset is not None and reset[t, s]:
                    Qt[3, 3] = 1.0
                m = F @ m
                P = F @ P @ F.T + Qt
                mp[t, s], Pp[t, s] = m, P
            meas = []
            if has_obs[t, s]:
                r = model.r_obs if obs_var is None else obs_var[t, s]
                if np.isfinite(r):
                    meas.append((obs[t, s], r, 0.0))
            if has_sp[t, s]:
                meas.append((spatial[t, s], spatial_sd[t, s] ** 2, bias_sd[t, s]))
            for y, r, b in meas:
                H = np.array([1.0, 0.0, 0.0, b])
                PH = P @ H
                K = PH / (H @ PH + r)
                m = m + np.outer(K, y - H @ m)
                P = P - np.outer(K, PH)
                P = (P + P.T) / 2
            mf[t, s], Pf[t, s] = m, P
    mean = np.empty((T, S, 3))
    var = np.empty((T, S))
    for s in range(S):
        ms, Ps = mf[-1, s], Pf[-1, s]
        mean[-1, s], var[-1, s] = ms[0], Ps[0, 0]
        for t in range(T - 2, -1, -1):
            Ppred = (Pp[t + 1, s] + Pp[t + 1, s].T) / 2
            G = np.linalg.solve(Ppred, step(t + 1, s) @ Pf[t, s]).T
            ms = mf[t, s] + G @ (ms - mp[t + 1, s])
            Ps = Pf[t, s] + G @ (Ps - Ppred) @ G.T
            mean[t, s], var[t, s] = ms[0], Ps[0, 0]
    return mean, np.sqrt(np.clip(var, 0.0, None))


def random_case(seed, T=80, S=5, *, late_start=False, gain=True, rho_acc=None, fragments=False, no_data=False):
    """Smooth 3-D trajectories with gaps; spatial predictions in the gaps and at their edges (where both exist)."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None]
    phase = rng.uniform(0, 6, (1, S, 3))
    truth = 100 * np.sin(t / rng.uniform(8, 20, (1, S, 3)) + phase) + rng.normal(0, 50, (1, S, 3))
    missing = np.zeros((T, S), bool)
    for s in range(S):
        for _ in range(rng.integers(1, 4)):
            a = rng.integers(0, T - 5)
            missing[a:a + rng.integers(2, 25), s] = True
    if late_start:  # series 0 has nothing (neither observation nor spatial prediction) before frame 20
        missing[:30, 0] = True
    obs = np.where(missing[..., None], np.nan, truth + rng.normal(0, 0.3, truth.shape))
    near = missing | np.roll(missing, 1, axis=0) | np.roll(missing, -1, axis=0)
    spatial = np.where(near[..., None], truth + rng.normal(0, 3, truth.shape), np.nan)
    sd = np.where(near, rng.uniform(1, 6, (T, S)), np.nan)
    if late_start:
        spatial[:20, 0] = np.nan
        sd[:20, 0] = np.nan
    if no_data:  # the last series has no measurement at all
        obs[:, -1] = np.nan
        spatial[:, -1] = np.nan
        sd[:, -1] = np.nan
    white, bias = sd * np.sqrt(0.3), sd * np.sqrt(0.7)
    model = MotionModel(q=rng.uniform(0.05, 2.0, S), rho=np.exp(-1 / 40), phi=np.exp(-1 / 25), r_obs=0.09,
                        gain=rng.uniform(0.3, 2.5, T) if gain else None, rho_acc=rho_acc)
    obs_var = None
    if fragments:  # short observed runs inside gaps are trusted less; NaN where not observed
        obs_var = np.where(np.isfinite(obs).all(axis=2), np.where(rng.random((T, S)) < 0.3, 400.0, 0.09), np.nan)
    return obs, spatial, white, bias, model, obs_var


def assert_same(case, *, init=None, mean_tol=1e-9, sd_tol=1e-9, reset=None):
    obs, spatial, white, bias, model, obs_var = case
    mean, sd = smooth(obs, spatial, white, bias, model, init=init, obs_var=obs_var, reset=reset)
    ref_mean, ref_sd = reference_smooth(obs, spatial, white, bias, model, init=init, obs_var=obs_var, reset=reset)
    T, S, _ = obs.shape
    assert mean.shape == (T, S, 3) and sd.shape == (T, S)
    assert np.array_equal(np.isnan(mean), np.isnan(ref_mean)) and np.array_equal(np.isnan(sd), np.isnan(ref_sd))
    # positions ~100: absolute 1e-9 is ~1e-11 relative; each sd relative
    assert np.nanmax(np.abs(mean - ref_mean)) <= mean_tol
    assert np.nanmax(np.abs(sd - ref_sd) / np.maximum(ref_sd, 1e-3)) <= sd_tol


@pytest.mark.parametrize("seed", range(4))
def test_gaps_with_gain_and_edges(seed):
    assert_same(random_case(seed))


def test_gain_none():
    assert_same(random_case(10, gain=False))


def test_acceleration_memory_set():
    assert_same(random_case(11, rho_acc=np.exp(-1 / 2.5)))


def test_obs_var_given_fragments():
    assert_same(random_case(12, fragments=True))


def test_obs_var_nan_where_observed_drops_the_sample():
    obs, spatial, white, bias, model, _ = random_case(13)
    obs_var = np.full(obs.shape[:2], 0.09)
    obs_var[10:14, 1] = np.nan  # as if unobserved there: the spatial prediction (if any) is the only measurement
    assert_same((obs, spatial, white, bias, model, obs_var))


def test_no_measurement_at_the_start():
    # before the first measurement the prior is diffuse (variance ~1e6 x spread^2): the smoothed variance there is a
    # difference of huge numbers, so both implementations carry round-off of ~1e-16 of them (relative 1e-7 here)
    assert_same(random_case(14, late_start=True), sd_tol=1e-6)


def test_series_without_any_measurement():
    assert_same(random_case(15, no_data=True), sd_tol=1e-6)


def test_spatial_only_stretch():
    obs, spatial, white, bias, model, obs_var = random_case(16, T=120, S=3)
    obs[30:90, 2] = np.nan  # a long gap bridged by spatial predictions only
    spatial[29:91, 2] = obs[28, 2] + np.linspace(0, 30, 62)[:, None]
    white[29:91, 2], bias[29:91, 2] = 2.0, 3.0
    assert_same((obs, spatial, white, bias, model, obs_var))


def test_init_given():
    case = random_case(17)
    assert_same(case, init=np.nan_to_num(case[0][0]) + 5.0)


@pytest.mark.parametrize("T", [1, 2, 3])
def test_very_short(T):
    obs, spatial, white, bias, model, obs_var = random_case(18, T=40)
    model = model._replace(gain=model.gain[:T])
    assert_same((obs[:T], spatial[:T], white[:T], bias[:T], model, None), sd_tol=1e-6)


def test_long_observed_stretch_after_a_spatial_measurement():
    # the correlations of b with x, v, a shrink at every observed frame: after a few hundred frames they would be
    # subnormal numbers, which the fast version sets to 0 (far below round-off): same result
    T = 1500
    obs, spatial, white, bias, model, obs_var = random_case(19, T=T, S=2)
    rng = np.random.default_rng(0)
    obs[:] = 50 * np.sin(np.arange(T) / 30)[:, None, None] + rng.normal(0, 0.3, (T, 2, 3))
    obs[5:8] = np.nan
    spatial[:] = np.nan
    spatial[4:9] = obs[3] + 1.0
    white[:], bias[:] = np.nan, np.nan
    white[4:9], bias[4:9] = 2.0, 3.0
    assert_same((obs, spatial, white, bias, model, None))


@pytest.mark.parametrize("seed", range(3))
def test_bias_drawn_anew(seed):
    """Where the spatial model changes (``reset``), b is drawn anew: the same numbers as the loop with phi = 0 and the
    bias's process noise 1 on that step, forward and backward; and not those of the smoother without it."""
    case = random_case(seed, fragments=seed == 1)
    reset = np.random.default_rng(seed + 100).random(case[0].shape[:2]) < 0.08
    reset[0] = False
    assert_same(case, reset=reset)
    plain, _ = smooth(*case[:5], obs_var=case[5])
    redrawn, _ = smooth(*case[:5], obs_var=case[5], reset=reset)
    assert np.nanmax(np.abs(plain - redrawn)) > 0.1
