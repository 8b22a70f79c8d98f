"""The DynaMMo engine: against a straightforward reference implementation, EM's monotonicity, recovery, edge cases."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from mocapfill.errors import ConvergenceWarning
from mocapfill.engines import lds
from mocapfill.methods.dynammo import (bridge_residuals, choose_hidden, fill_dynammo, body_frame_transform, DEFAULT_INIT_NOISE, initial_params,
                                       interpolate_columns, run_dynammo)


# --------------------------------------------------------------------------------------------------------------
# A straightforward reference: full m x m solves per frame, Python loops, the paper's equations written out.
# --------------------------------------------------------------------------------------------------------------

def dense_e_step(p: lds.LDSParams, X: np.ndarray):
    """Kalman filter (eqs. 15-22) and RTS smoother (eqs. 25-27) with explicit m x m innovation covariances."""
    T, m = X.shape
    H = p.F.shape[0]
    R = p.sigma2 * np.eye(m)
    mu = np.zeros((T, H))
    V = np.zeros((T, H, H))
    Pp = np.zeros((T, H, H))  # P_t = F V_t F^T + Lambda
    nll = 0.0
    for t in range(T):
        pred = p.mu0 if t == 0 else p.F @ mu[t - 1]
        Pprior = p.Gamma if t == 0 else Pp[t - 1]
        S = p.G @ Pprior @ p.G.T + R
        e = X[t] - p.G @ pred
        K = np.linalg.solve(S, p.G @ Pprior).T  # P G^T S^-1
        mu[t] = pred + K @ e
        V[t] = (np.eye(H) - K @ p.G) @ Pprior
        V[t] = (V[t] + V[t].T) / 2
        Pp[t] = p.F @ V[t] @ p.F.T + p.Lambda
        sign, logdet = np.linalg.slogdet(S)
        nll += 0.5 * (m * np.log(2 * np.pi) + logdet + e @ np.linalg.solve(S, e))
    mh = mu.copy()
    Vh = V.copy()
    J = np.zeros((T, H, H))
    for t in range(T - 2, -1, -1):
        J[t] = V[t] @ p.F.T @ np.linalg.inv(Pp[t])
        mh[t] = mu[t] + J[t] @ (mh[t + 1] - p.F @ mu[t])
        Vh[t] = V[t] + J[t] @ (Vh[t + 1] - Pp[t]) @ J[t].T
    Ezz = [Vh[t] + np.outer(mh[t], mh[t]) for t in range(T)]
    Ez1z0 = [Vh[t] @ J[t - 1].T + np.outer(mh[t], mh[t - 1]) for t in range(1, T)]  # E[z_t z_{t-1}^T]
    return mh, Ezz, Ez1z0, Vh, nll


def dense_m_step(p: lds.LDSParams, X, mh, Ezz, Ez1z0, Vh):
    """Eqs. 31-36 summed frame by frame, then isotropic Gamma / Lambda (trace / H)."""
    T, m = X.shape
    H = mh.shape[1]
    mu0 = mh[0]
    Gamma = np.trace(Vh[0]) / H * np.eye(H)
    if T >= 2:
        A = sum(Ez1z0)
        B = sum(Ezz[:-1])
        F = A @ np.linalg.inv(B)
        Lam = sum(Ezz[t] - F @ Ez1z0[t - 1].T - Ez1z0[t - 1] @ F.T + F @ Ezz[t - 1] @ F.T
                  for t in range(1, T)) / (T - 1)
        Lam = np.trace(Lam) / H * np.eye(H)
    else:
        F, Lam = p.F, p.Lambda
    G = sum(np.outer(X[t], mh[t]) for t in range(T)) @ np.linalg.inv(sum(Ezz))
    Sig = sum(np.outer(X[t], X[t]) - G @ np.outer(mh[t], X[t]) - np.outer(X[t], mh[t]) @ G.T + G @ Ezz[t] @ G.T
              for t in range(T)) / T
    return lds.LDSParams(F, G, mu0, Gamma, Lam, float(np.trace(Sig) / m))


def reference_dynammo(positions, *, hidden, n_iter, seed=0, body_frame=True):
    """DynaMMo as the paper states it, on the same preprocessing; returns (filled positions, objective trace)."""
    T, M, _ = positions.shape
    m = 3 * M
    miss = np.isnan(positions).any(axis=2)
    miss_cols = np.repeat(miss, 3, axis=1)
    Y = interpolate_columns(positions.reshape(T, m), miss_cols)
    if body_frame:
        R, c, _ = body_frame_transform(Y.reshape(T, M, 3), ~miss, "auto")
        Y = np.einsum("tmi,tij->tmj", Y.reshape(T, M, 3) - c[:, None], R).reshape(T, m)
        Y = interpolate_columns(Y, miss_cols)
    obs = np.where(miss_cols, np.nan, Y).reshape(T, M, 3)
    centre = np.tile(np.nanmean(obs, axis=(0, 1)), M)  # one mean per axis
    scale = np.sqrt(np.nanmean((np.where(miss_cols, np.nan, Y) - centre) ** 2))
    X = (Y - centre) / scale
    p = initial_params(X, hidden, np.random.default_rng(seed), noise=DEFAULT_INIT_NOISE)
    objective = []
    for it in range(1, n_iter + 1):
        mh, Ezz, Ez1z0, Vh, nll = dense_e_step(p, X)
        objective.append(nll / (T * m) + np.log(scale))
        fitted = mh @ p.G.T
        X[miss_cols] = fitted[miss_cols]
        if it == n_iter:
            break
        p = dense_m_step(p, X, mh, Ezz, Ez1z0, Vh)
    out = (X * scale + centre).reshape(T, M, 3)
    if body_frame:
        out = np.einsum("tmj,tij->tmi", out, R) + c[:, None]
    return out, objective


# --------------------------------------------------------------------------------------------------------------

def lds_markers(T=200, M=5, H=3, *, seed=0, sigma2=1e-3, rho=0.98):
    """Marker-shaped data (T, M, 3) from a known stable LDS, with its parameters."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((H, H)))
    ang = rng.uniform(0.02, 0.15, H)
    F = rho * Q @ np.diag(np.cos(ang)) @ Q.T + 0.05 * (Q @ np.triu(rng.standard_normal((H, H)), 1) @ Q.T)
    F *= rho / max(rho, np.max(np.abs(np.linalg.eigvals(F))))
    G = rng.standard_normal((3 * M, H))
    p = lds.LDSParams(F, G, rng.standard_normal(H), 0.5 * np.eye(H), 0.01 * np.eye(H), sigma2)
    z = np.empty((T, H))
    z[0] = p.mu0 + np.sqrt(0.5) * rng.standard_normal(H)
    for t in range(1, T):
        z[t] = F @ z[t - 1] + 0.1 * rng.standard_normal(H)
    x = z @ G.T + np.sqrt(sigma2) * rng.standard_normal((T, 3 * M))
    return x.reshape(T, M, 3), p


def with_gaps(P):
    X = P.copy()
    T = len(X)
    X[: T // 10, 0] = np.nan  # gap at the start
    X[T // 3: T // 3 + T // 5, 1] = np.nan
    X[T // 2: T // 2 + 4] = np.nan  # a whole-body blackout
    X[-T // 8:, 2] = np.nan  # gap at the end
    return X


def run_quiet(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return run_dynammo(*args, **kwargs)


@pytest.mark.parametrize("body_frame", [False, True])
def test_fast_engine_matches_reference_implementation(body_frame, monkeypatch):
    monkeypatch.setattr(lds, "STEADY_RTOL", 1e-13)  # steady state within rounding: the algebra, not the truncation
    P, _ = lds_markers(T=90, M=4, H=3, seed=1)
    X = with_gaps(P)
    n_iter = 12
    ref, ref_obj = reference_dynammo(X, hidden=3, n_iter=n_iter, body_frame=body_frame)
    res = run_quiet(X, hidden=3, max_iter=n_iter, tol=0.0, seed=0, body_frame=body_frame, bridge=False)
    assert res.n_iter == n_iter and not res.converged
    miss = np.isnan(X).any(axis=2)
    span = np.abs(P).max()
    np.testing.assert_allclose(res.positions[miss], ref[miss], rtol=0, atol=1e-8 * span)
    np.testing.assert_allclose(res.objective, ref_obj, rtol=1e-8)


def test_objective_is_monotone_without_projection():
    P, _ = lds_markers(T=300, M=6, H=4, seed=2)
    res = run_quiet(with_gaps(P), hidden=4, max_iter=60, tol=0.0, seed=0)
    obj = np.array(res.objective)
    assert np.all(np.diff(obj) <= 1e-10 * np.abs(obj[:-1]))
    assert obj[-1] < obj[0]


def test_recovers_lds_data_far_better_than_linear_interpolation():
    P, _ = lds_markers(T=600, M=8, H=4, seed=3, sigma2=1e-4)
    X = P.copy()
    X[200:280, 3] = np.nan
    X[400:440, 6] = np.nan
    X[100:110] = np.nan  # blackout
    res = run_quiet(X, hidden=4, seed=0, body_frame=False, max_iter=1000)  # converges after ~540 iterations
    miss = np.isnan(X).any(axis=2)
    lin = interpolate_columns(X.reshape(600, -1), np.isnan(X.reshape(600, -1))).reshape(X.shape)
    err = np.sqrt(np.mean((res.positions[miss] - P[miss]) ** 2))
    err_lin = np.sqrt(np.mean((lin[miss] - P[miss]) ** 2))
    assert err < 0.3 * err_lin
    assert res.converged


def test_hidden_is_capped_at_the_observed_coordinates():
    """--hidden 1000 on a few markers ran EM with 1000 states for minutes; now capped at 3 x the observed markers."""
    P, _ = lds_markers(T=80, M=5, H=3, seed=4)
    X = with_gaps(P)
    X[:, 4] = np.nan  # missing throughout: not observed, 4 markers = 12 coordinates left
    with pytest.warns(UserWarning, match=r"hidden=1000 is more than the 12 coordinates of the 4 observed markers: "
                                         r"capped at 12"):
        res = run_quiet(X, hidden=1000, max_iter=5, seed=0)
    assert res.info["hidden"] == 12 and res.info["hidden_capped"] == 1000
    capped = run_quiet(X, hidden=12, max_iter=5, seed=0)
    np.testing.assert_array_equal(res.positions, capped.positions)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # the default (16) is capped quietly: the user did not ask
        quiet = run_quiet(X, max_iter=2, seed=0)
    assert quiet.info["hidden"] == 12 and quiet.info["hidden_capped"] == 16


def test_determinism_under_seed_and_edge_cases():
    P, _ = lds_markers(T=80, M=5, H=3, seed=4)
    X = with_gaps(P)
    X[:, 4] = np.nan  # a marker missing throughout
    a = run_quiet(X, hidden=10, max_iter=15, seed=7)  # rank 3 < H <= 12 coordinates: the seed draws G's extra columns
    b = run_quiet(X, hidden=10, max_iter=15, seed=7)
    np.testing.assert_array_equal(a.positions, b.positions)
    assert a.objective == b.objective
    miss = np.isnan(X).any(axis=2)
    assert np.isnan(a.positions[:, 4]).all()
    assert not np.isnan(a.positions[:, :4]).any()  # edges and the blackout filled
    assert a.filled[:, :4].sum() == miss[:, :4].sum() and not a.filled[:, 4].any()
    np.testing.assert_array_equal(a.positions[~miss], X[~miss])
    assert a.info["markers_all_missing"] == [4]
    assert np.isnan(a.std[:, 4]).all()
    assert (a.std[~miss] == 0).all() and (a.std[miss[:, :4].nonzero()[0], miss[:, :4].nonzero()[1]] > 0).all()


def test_one_frame_and_nothing_to_fill():
    X = np.arange(12, dtype=float).reshape(1, 4, 3)
    X[0, 1] = np.nan
    res = fill_dynammo(X)
    assert res.positions.shape == (1, 4, 3) and np.isnan(res.positions[0, 1]).all()
    np.testing.assert_array_equal(res.positions[0, [0, 2, 3]], X[0, [0, 2, 3]])
    full = np.random.default_rng(0).standard_normal((30, 3, 3))
    res = fill_dynammo(full)
    np.testing.assert_array_equal(res.positions, full)
    # one frame but two frames' worth of markers observed elsewhere: T = 2 with a gap
    two = np.random.default_rng(1).standard_normal((2, 4, 3))
    two[1, 2] = np.nan
    res = run_quiet(two, max_iter=5)
    assert np.isfinite(res.positions).all()


def test_std_grows_inside_a_long_gap():
    P, _ = lds_markers(T=400, M=6, H=3, seed=5)
    X = P.copy()
    X[100:250, 2] = np.nan
    res = run_quiet(X, hidden=3, max_iter=30)
    s = res.std[100:250, 2]
    assert np.isfinite(s).all() and (s > 0).all()
    assert s[75] > s[0] and s[75] > s[-1]
    assert res.info["sigma2"] > 0 and res.info["hidden"] == 3


def test_project_hook_and_progress():
    P, _ = lds_markers(T=100, M=4, H=3, seed=6)
    X = with_gaps(P)
    miss = np.isnan(X).any(axis=2)
    frames = np.flatnonzero(miss.any(axis=1))
    calls, ticks = [], []

    def project(step):
        calls.append((step.iteration, step.final))
        n = frames.size
        assert step.estimate.shape == (n, 4, 3) and (step.frames == frames).all()
        assert (step.missing == miss[frames]).all()
        assert step.sigma2 > 0 and np.isfinite(step.estimate).all()
        np.testing.assert_array_equal(step.estimate[~step.missing], X[frames][~step.missing])  # the data there
        out = step.estimate.copy()
        out[step.missing] = 123.0
        return out

    res = run_quiet(X, hidden=3, max_iter=6, tol=0.0, project=project, project_start=3,
                    progress=lambda i, n, obj: ticks.append((i, n, obj)))
    assert calls == [(3, False), (4, False), (5, False), (6, False), (6, True)]  # + the final, bridged call
    assert [t[0] for t in ticks] == [1, 2, 3, 4, 5, 6] and all(t[1] == 6 for t in ticks)
    np.testing.assert_allclose(res.positions[miss], 123.0, rtol=1e-9)


@pytest.mark.parametrize("bridge", [False, True])
def test_identity_hook_is_plain_dynammo(bridge):
    """The hook sees G E[z] in data units and its answer goes back through the inverse transform exactly."""
    P, _ = lds_markers(T=120, M=5, H=3, seed=9)
    X = with_gaps(P)
    plain = run_quiet(X, hidden=3, max_iter=8, tol=0.0, bridge=bridge)
    hooked = run_quiet(X, hidden=3, max_iter=8, tol=0.0, bridge=bridge, project=lambda step: step.estimate)
    np.testing.assert_allclose(hooked.positions, plain.positions, rtol=0, atol=1e-9 * np.abs(P).max())
    np.testing.assert_allclose(hooked.objective, plain.objective, rtol=1e-9)


def test_convergence_warning_at_the_cap():
    P, _ = lds_markers(T=60, M=4, H=3, seed=8)
    with pytest.warns(ConvergenceWarning):
        run_dynammo(with_gaps(P), hidden=3, max_iter=2, tol=0.0)


@pytest.mark.accuracy
def test_beats_spline_on_real_capture(sample_data):
    import mocapfill

    P = mocapfill.read(sample_data / "85_02.c3d").positions
    T = len(P)
    rng = np.random.default_rng(2024)
    ratios = []
    for _ in range(3):
        k = int(rng.integers(P.shape[1]))
        L = int(rng.integers(60, 241))  # 0.5-2 s at 120 Hz
        s = int(rng.integers(1, T - L - 1))
        X = P.copy()
        X[s:s + L, k] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            res = fill_dynammo(X)
        ok = np.arange(T)[~np.isnan(X[:, k, 0])]
        spline = CubicSpline(ok, X[ok, k])(np.arange(s, s + L))
        rmse = lambda E: np.sqrt(np.mean(np.sum((E - P[s:s + L, k]) ** 2, axis=-1)))
        ratios.append(rmse(res.positions[s:s + L, k]) / rmse(spline))
    assert np.median(ratios) < 1.0, ratios


def test_bridge_residuals_blends_the_neighbouring_residuals():
    T, H = 10, 2
    G = np.arange(6 * H, dtype=float).reshape(6, H) / 10
    Ez = np.zeros((T, H))
    X = np.zeros((T, 6))
    X[:, 0:3] = 1.0  # marker 0: residual 1 everywhere it is observed
    X[:, 3:6] = -2.0
    missing = np.zeros((T, 2), bool)
    missing[3:6, 0] = True  # inside: both neighbours have residual 1
    missing[7:, 1] = True  # at the end: held
    X[missing[:, 0], 0:3] = 0.0
    X[missing[:, 1], 3:6] = 0.0
    X[4, 0:3] = 0.0
    bridge_residuals(X, Ez, G, missing)
    np.testing.assert_allclose(X[3:6, 0:3], 1.0)
    np.testing.assert_allclose(X[7:, 3:6], -2.0)
    # unequal residuals: a straight line between them
    X2 = np.zeros((5, 3))
    X2[0], X2[4] = 0.0, 4.0
    miss = np.array([[False], [True], [True], [True], [False]])
    X2[1:4] = 0.0
    bridge_residuals(X2, np.zeros((5, 1)), np.zeros((3, 1)), miss)
    np.testing.assert_allclose(X2[1:4, 0], [1.0, 2.0, 3.0])


def test_fill_dynammo_joins_the_observed_trajectory():
    P, _ = lds_markers(T=300, M=6, H=3, seed=9)
    X = P.copy()
    X[100:160, 2] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        res = fill_dynammo(X, hidden=3)
    step_in = np.abs(res.positions[100, 2] - res.positions[99, 2]).max()
    typical = np.abs(np.diff(P[:, 2], axis=0)).max()
    assert step_in <= 2 * typical


def test_energy_chooses_the_hidden_dimension():
    rng = np.random.default_rng(0)
    X = rng.standard_normal((200, 3)) @ rng.standard_normal((3, 12)) + 1e-3 * rng.standard_normal((200, 12))
    assert choose_hidden(X, 0.999) == 3
    P, _ = lds_markers(T=100, M=4, H=3, seed=10)
    res = run_quiet(with_gaps(P), energy=0.99, max_iter=5)
    assert 1 <= res.info["hidden"] <= 12
