"""The LDS primitives against dense, straightforward solutions (small sizes)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg as sla

from mocapfill.engines import lds


def random_params(H=3, m=6, *, seed=0, rho=0.95, sigma2=0.05, iso=False):
    """A stable LDS with well-conditioned covariances."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((H, H)))
    F = rho * Q @ np.diag(rng.uniform(0.6, 1.0, H)) @ Q.T + 0.05 * rng.standard_normal((H, H))
    F *= rho / max(1.0, np.max(np.abs(np.linalg.eigvals(F))))
    G = rng.standard_normal((m, H))
    mu0 = rng.standard_normal(H)
    if iso:
        Gamma, Lam = 0.5 * np.eye(H), 0.1 * np.eye(H)
    else:
        A = rng.standard_normal((H, H))
        Gamma = A @ A.T / H + 0.2 * np.eye(H)
        B = rng.standard_normal((H, H))
        Lam = 0.1 * (B @ B.T / H + 0.2 * np.eye(H))
    return lds.LDSParams(F, G, mu0, Gamma, Lam, sigma2)


def simulate(p, T, seed=1):
    rng = np.random.default_rng(seed)
    H, m = p.F.shape[0], p.G.shape[0]
    z = np.empty((T, H))
    z[0] = rng.multivariate_normal(p.mu0, p.Gamma)
    for t in range(1, T):
        z[t] = p.F @ z[t - 1] + rng.multivariate_normal(np.zeros(H), p.Lambda)
    x = z @ p.G.T + np.sqrt(p.sigma2) * rng.standard_normal((T, m))
    return z, x


def dense_posterior(p, X, observed=None):
    """Condition the joint Gaussian of (z_1..z_T, x_1..x_T) on the (observed entries of the) data."""
    T, m = X.shape
    H = p.F.shape[0]
    Ez = np.empty((T, H))
    Sig = np.empty((T, H, H))
    Ez[0], Sig[0] = p.mu0, p.Gamma
    for t in range(1, T):
        Ez[t] = p.F @ Ez[t - 1]
        Sig[t] = p.F @ Sig[t - 1] @ p.F.T + p.Lambda
    Czz = np.zeros((T * H, T * H))
    for t in range(T):
        Ft = np.eye(H)
        for s in range(t, T):  # Cov(z_s, z_t) = F^{s-t} Sig_t
            Czz[s * H:(s + 1) * H, t * H:(t + 1) * H] = Ft @ Sig[t]
            Czz[t * H:(t + 1) * H, s * H:(s + 1) * H] = (Ft @ Sig[t]).T
            Ft = p.F @ Ft
    Gb = np.kron(np.eye(T), p.G)
    Czx = Czz @ Gb.T
    Cxx = Gb @ Czz @ Gb.T + p.sigma2 * np.eye(T * m)
    x = X.reshape(-1)
    Ex = Gb @ Ez.reshape(-1)
    keep = np.ones(T * m, bool) if observed is None else np.repeat(observed, 3, axis=1).reshape(-1)
    cf = sla.cho_factor(Cxx[np.ix_(keep, keep)])
    mean = Ez.reshape(-1) + Czx[:, keep] @ sla.cho_solve(cf, x[keep] - Ex[keep])
    cov = Czz - Czx[:, keep] @ sla.cho_solve(cf, Czx[:, keep].T)
    n = keep.sum()
    resid = x[keep] - Ex[keep]
    nll = 0.5 * (n * np.log(2 * np.pi) + 2 * np.log(np.diag(cf[0])).sum() + resid @ sla.cho_solve(cf, resid))
    return mean.reshape(T, H), cov, nll


@pytest.mark.parametrize("T, iso", [(1, False), (2, False), (7, False), (60, False), (60, True)])
def test_smoother_matches_dense_joint_gaussian(T, iso):
    p = random_params(seed=T, iso=iso)
    _, X = simulate(p, T, seed=T + 1)
    stats, sm, nll = lds.e_step(p, X, rtol=1e-13)  # steady state within rounding: the algebra, not the truncation
    mean, cov, nll_dense = dense_posterior(p, X)
    H = p.F.shape[0]
    scale = np.max(np.abs(cov))
    np.testing.assert_allclose(sm.mean, mean, atol=1e-10 * max(1, np.abs(mean).max()))
    Vhat = sm.Vhat.dense()
    for t in range(T):
        np.testing.assert_allclose(Vhat[t], cov[t * H:(t + 1) * H, t * H:(t + 1) * H], atol=1e-10 * scale)
    cross = sum(cov[t * H:(t + 1) * H, (t - 1) * H:t * H] for t in range(1, T)) if T > 1 else np.zeros((H, H))
    np.testing.assert_allclose(sm.cross, cross, atol=1e-10 * scale * T)
    assert nll == pytest.approx(nll_dense, rel=1e-10)
    # The statistics of eqs. 28-30.
    Ezz = sum(cov[t * H:(t + 1) * H, t * H:(t + 1) * H] + np.outer(mean[t], mean[t]) for t in range(T))
    np.testing.assert_allclose(stats.Szz, Ezz, atol=1e-9 * np.abs(Ezz).max())


def test_steady_state_is_used_on_long_sequences():
    p = random_params(seed=3)
    _, X = simulate(p, 400)
    filt = lds.kalman_filter(p, X)
    assert 1 <= filt.n_head < 100
    sm = lds.rts_smoother(p, filt)
    assert sm.Vhat.n_mid > 200
    mean, cov, _ = dense_posterior(p, X[:120])  # a shorter window cannot match the end, but the head must
    sm_short = lds.rts_smoother(p, lds.kalman_filter(p, X[:120]))
    np.testing.assert_allclose(sm_short.mean, mean, atol=100 * lds.STEADY_RTOL * max(1, np.abs(mean).max()))


@pytest.mark.parametrize("rho, n, nonnormal", [(0.97, 500, 0.0), (0.999, 3000, 0.0), (0.9, 700, 3.0), (0.5, 1, 0.0),
                                             (0.999, 10001, 0.0), (0.95, 4096, 3.0), (1.0, 6000, 0.0)])
def test_linear_recurrence_matches_loop(rho, n, nonnormal):
    rng = np.random.default_rng(5)
    H = 6
    A = rng.standard_normal((H, H)) + nonnormal * np.triu(rng.standard_normal((H, H)), 1)
    A *= rho / np.max(np.abs(np.linalg.eigvals(A)))
    U = rng.standard_normal((n, H))
    z0 = rng.standard_normal(H)
    Z = lds.linear_recurrence(A, U, z0)
    ref = np.empty_like(U)
    prev = z0
    for t in range(n):
        prev = A @ prev + U[t]
        ref[t] = prev
    np.testing.assert_allclose(Z, ref, atol=1e-11 * np.abs(ref).max())


def test_m_step_maximises_expected_log_likelihood():
    """The closed-form M-step beats small perturbations of its own answer on the expected complete-data NLL."""
    p = random_params(seed=7, iso=True)
    _, X = simulate(p, 80)
    stats, sm, _ = lds.e_step(p, X)
    T, m = X.shape
    new = lds.m_step(stats, X.T @ stats.Ez, float((X ** 2).sum()), m, p, isotropic=True)

    def expected_nll(q):
        H = q.F.shape[0]
        Ez, Szz = stats.Ez, stats.Szz
        g, lam, s = q.Gamma[0, 0], q.Lambda[0, 0], q.sigma2
        e1 = stats.Ezz_first - np.outer(Ez[0], q.mu0) - np.outer(q.mu0, Ez[0]) + np.outer(q.mu0, q.mu0)
        Sp, Sn, S10 = Szz - stats.Ezz_last, Szz - stats.Ezz_first, stats.Sz1z0
        trans = Sn - q.F @ S10.T - S10 @ q.F.T + q.F @ Sp @ q.F.T
        XtEz = X.T @ Ez
        obs = (X ** 2).sum() - 2 * np.sum(q.G * XtEz) + np.trace(q.G @ Szz @ q.G.T)
        return (0.5 * (np.trace(e1) / g + H * np.log(g)) + 0.5 * (np.trace(trans) / lam + (T - 1) * H * np.log(lam))
                + 0.5 * (obs / s + T * m * np.log(s)))

    best = expected_nll(new)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = new._replace(F=new.F + 1e-3 * rng.standard_normal(new.F.shape),
                         G=new.G + 1e-3 * rng.standard_normal(new.G.shape),
                         mu0=new.mu0 + 1e-3 * rng.standard_normal(new.mu0.shape),
                         Lambda=new.Lambda * np.exp(0.01 * rng.standard_normal()),
                         Gamma=new.Gamma * np.exp(0.01 * rng.standard_normal()),
                         sigma2=new.sigma2 * np.exp(0.01 * rng.standard_normal()))
        assert expected_nll(q) > best


def test_missing_data_variance_matches_dense():
    p = random_params(H=3, m=9, seed=11, iso=True)
    T = 50
    _, X = simulate(p, T)
    observed = np.ones((T, 3), bool)
    observed[10:30, 1] = False
    observed[20:25, :] = False  # a blackout
    observed[45:, 2] = False  # a gap at the end
    var = lds.missing_data_variance(p, observed, rtol=1e-14)
    _, cov, _ = dense_posterior(p, X, observed)
    H = 3
    for t in range(T):
        C = cov[t * H:(t + 1) * H, t * H:(t + 1) * H]
        d = np.diag(p.G @ C @ p.G.T).reshape(3, 3).mean(axis=1)
        for k in range(3):
            expected = 0.0 if observed[t, k] else d[k]
            assert var[t, k] == pytest.approx(expected, rel=1e-8, abs=1e-12)


# --------------------------------------------------------------------------------------------------------------
# The fast recursions against a slow per-frame reference: the information-form filter and the RTS smoother written
# out frame by frame over all T frames (no steady state, no batching), as the module did before its batched paths.
# --------------------------------------------------------------------------------------------------------------

def slow_e_step(p, X):
    """Per-frame covariance filter + RTS smoother; returns (mu, V, P, mean, Vhat, J, cross, nll), dense over T."""
    F, G, mu0, Gamma, Lam, s = p
    T, m = X.shape
    H = F.shape[0]
    C = G.T @ G / s
    mu, V, P = np.empty((T, H)), np.empty((T, H, H)), np.empty((T, H, H))
    nll = 0.0
    P_prev, pred = Gamma, mu0
    for t in range(T):
        if t:
            pred = F @ mu[t - 1]
        L = np.linalg.cholesky(P_prev)
        W = np.eye(H) + L.T @ C @ L
        V[t] = L @ np.linalg.solve(W, L.T)
        V[t] = (V[t] + V[t].T) / 2
        mu[t] = pred + V[t] @ (G.T @ X[t] / s - C @ pred)
        P[t] = F @ V[t] @ F.T + Lam
        e = X[t] - G @ pred
        g = G.T @ e / s
        nll += 0.5 * (m * np.log(2 * np.pi * s) + np.linalg.slogdet(W)[1] + e @ e / s - g @ V[t] @ g)
        P_prev = P[t]
    mean, Vhat, J = mu.copy(), V.copy(), np.zeros((T, H, H))
    for t in range(T - 2, -1, -1):
        J[t] = np.linalg.solve(P[t], F @ V[t]).T
        mean[t] = mu[t] + J[t] @ (mean[t + 1] - F @ mu[t])
        Vhat[t] = V[t] + J[t] @ (Vhat[t + 1] - P[t]) @ J[t].T
        Vhat[t] = (Vhat[t] + Vhat[t].T) / 2
    cross = sum((Vhat[t] @ J[t - 1].T for t in range(1, T)), np.zeros((H, H)))
    return mu, V, P, mean, Vhat, J, cross, nll


@pytest.mark.parametrize("T", [1, 2, 5, 12, 40, 150, 700])
@pytest.mark.parametrize("iso", [False, True])
@pytest.mark.parametrize("rho, sigma2", [(0.6, 0.02), (0.95, 0.02), (0.995, 0.02), (0.995, 1.0), (0.995, 20.0)])
def test_fast_recursions_match_the_per_frame_reference(T, iso, rho, sigma2):
    """Short (T below the steady state), medium and long sequences; slow and fast dynamics, informative and weak
    observations (the filter steady after 5 frames, after 25, after 64 or never); full and isotropic."""
    H, m = 5, 12
    p = random_params(H=H, m=m, seed=T + 7 * iso, rho=rho, sigma2=sigma2, iso=iso)
    _, X = simulate(p, T, seed=3)
    mu, V, P, mean, Vhat, J, cross, nll = slow_e_step(p, X)
    rtol = 1e-13  # steady state within rounding: checks the algebra of the fast paths, not the truncation
    filt = lds.kalman_filter(p, X, rtol=rtol)
    sm = lds.rts_smoother(p, filt, rtol=rtol)
    stats, _, nll_e = lds.e_step(p, X, rtol=rtol)
    close = dict(rtol=0, atol=1e-11)
    sc = max(1.0, np.abs(mu).max())
    np.testing.assert_allclose(filt.mu / sc, mu / sc, **close)
    np.testing.assert_allclose(filt.V.dense(), V, atol=1e-12 * np.abs(V).max())
    np.testing.assert_allclose(filt.P.dense(), P, atol=1e-12 * np.abs(P).max())
    assert filt.nll == pytest.approx(nll, rel=1e-12) and nll_e == filt.nll
    np.testing.assert_allclose(sm.mean / sc, mean / sc, **close)
    np.testing.assert_allclose(sm.Vhat.dense(), Vhat, atol=1e-12 * np.abs(Vhat).max())
    if T > 1:
        np.testing.assert_allclose(sm.J.dense()[:T - 1], J[:T - 1], atol=1e-12 * np.abs(J).max())
    np.testing.assert_allclose(sm.cross, cross, atol=1e-12 * max(1, T) * np.abs(Vhat).max())
    np.testing.assert_allclose(stats.Szz, mean.T @ mean + Vhat.sum(axis=0), atol=1e-12 * T * np.abs(Vhat).max()
                               + 1e-13 * np.abs(mean.T @ mean).max())
    # The stored matrices are symmetric to the last bit where the module promises it.
    for pc in (filt.V, filt.P, sm.Vhat):
        d = pc.dense()
        np.testing.assert_array_equal(d, d.transpose(0, 2, 1))
    if T >= 700:  # long sequences use the steady state on both passes
        assert filt.n_head < T // 2 and sm.Vhat.n_mid > 0
    # The default tolerance truncates the transients earlier: still within a few STEADY_RTOL of the reference.
    stats_d, sm_d, nll_d = lds.e_step(p, X)
    tol = 100 * lds.STEADY_RTOL
    np.testing.assert_allclose(sm_d.mean / sc, mean / sc, rtol=0, atol=tol)
    np.testing.assert_allclose(sm_d.Vhat.dense(), Vhat, rtol=0, atol=tol * np.abs(Vhat).max())
    assert nll_d == pytest.approx(nll, rel=tol)


def test_fast_recursions_handle_a_rank_deficient_observation_matrix():
    """G with fewer rows than H (C = G^T G / sigma2 singular): the filter must not need C to be invertible."""
    p = random_params(H=6, m=3, seed=2, iso=True)
    _, X = simulate(p, 60, seed=4)
    mu, V, P, mean, Vhat, J, cross, nll = slow_e_step(p, X)
    _, sm, nll_e = lds.e_step(p, X, rtol=1e-13)
    np.testing.assert_allclose(sm.mean, mean, atol=1e-10 * max(1, np.abs(mean).max()))
    np.testing.assert_allclose(sm.Vhat.dense(), Vhat, atol=1e-11 * np.abs(Vhat).max())
    assert nll_e == pytest.approx(nll, rel=1e-11)


@pytest.mark.parametrize("n, chunk", [(0, 4), (3, 4), (40, 3), (40, 64), (200, 5)])
def test_stein_sequence_matches_the_loop(n, chunk):
    """Batched chunks (one, several, more than needed) give the plain iteration and stop where it first settles."""
    rng = np.random.default_rng(n + chunk)
    H = 4
    J = rng.standard_normal((H, H))
    J *= 0.8 / np.max(np.abs(np.linalg.eigvals(J)))
    B = rng.standard_normal((H, H))
    Q, S0 = B @ B.T, np.eye(H)
    S, conv = lds._stein_sequence(J, Q, S0, n, 1e-12, chunk=chunk)
    ref = [S0]
    for _ in range(n):
        ref.append(Q + J @ ref[-1] @ J.T)
        if np.linalg.norm(ref[-1] - ref[-2]) <= 1e-12 * np.linalg.norm(ref[-1]):
            break
    assert conv == (len(ref) - 1 < n or (n > 0 and np.linalg.norm(ref[-1] - ref[-2]) <= 1e-12 * np.linalg.norm(ref[-1])))
    assert len(S) == len(ref)
    np.testing.assert_allclose(S, np.array(ref), atol=1e-13 * np.abs(ref[-1]).max())


@pytest.mark.parametrize("sigma2, whitened", [(0.02, True), (1.0, True), (1e4, False)])
def test_whitened_covariances_match_the_direct_recursion(sigma2, whitened, monkeypatch):
    """The whitened recursion (three LAPACK calls per frame) against the direct one; observations too weak for it
    (``V << C^-1``) take the direct one."""
    p = random_params(H=5, m=12, seed=5, rho=0.99, sigma2=sigma2)
    T = 80
    ref = lds._direct_covariances(p, T, rtol=1e-13)
    direct = []
    monkeypatch.setattr(lds, "_direct_covariances", lambda *a, **k: direct.append(1) or ref)
    got = lds.filter_covariances(p, T, rtol=1e-13)
    assert bool(direct) != whitened
    for a, b in [(got.V, ref.V), (got.P, ref.P), (got.J, ref.J)]:
        np.testing.assert_allclose(a.dense()[:T - 1], b.dense()[:T - 1], rtol=0, atol=1e-11 * np.abs(b.dense()).max())
    np.testing.assert_allclose(got.logdet_w, ref.logdet_w, rtol=1e-12, atol=1e-12)
