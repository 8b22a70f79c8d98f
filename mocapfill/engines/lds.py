"""Linear dynamical system (LDS) primitives for DynaMMo: Kalman filter, RTS smoother, E-step statistics, M-step.

The model (BoLeRO paper, section 3.1, eqs. 1-4), with H hidden and m observed dimensions::

    z_1     = mu0 + w_0,        w_0 ~ N(0, Gamma)          (1)
    z_{n+1} = F z_n + w_n,      w_n ~ N(0, Lambda)         (2)
    x_n     = G z_n + v_n,      v_n ~ N(0, sigma2 * I_m)   (3), (4) with Sigma = sigma2 I

Everything here works on a *fully observed* sequence ``X`` of shape (T, m): DynaMMo treats its current imputation
of the missing entries as data, so the filter's covariances do not depend on the data at all.  That gives the three
speed-ups this module is built on:

* **Woodbury / information form.**  With isotropic observation noise the filter update (eqs. 16-18) needs only
  ``C = G^T G / sigma2`` (H x H) and ``b_t = G^T x_t / sigma2``: ``V_t = (P^-1 + C)^-1`` and
  ``mu_t = pred_t + V_t (b_t - C pred_t)``.  No m x m matrix is ever formed; ``|G P G^T + sigma2 I| =
  sigma2^m |I + R P R^T|`` (``R^T R = C``) gives the likelihood.  The covariances run in whitened coordinates
  ``z' = R z``, where ``C`` is the identity (:func:`filter_covariances`).
* **Steady state.**  The covariance recursions (eqs. 15, 18, 25, 27) are run until successive matrices agree to a
  relative ``rtol`` (:data:`STEADY_RTOL`); from then on the stored steady-state matrix is reused.  Covariance
  sequences are kept as :class:`PiecewiseCov` (explicit head, constant middle, explicit tail).
* **Few calls per transient frame.**  On short clips (a 145-frame trial: ~6 transient frames at each end, 200 EM
  iterations) the cost is the number of small NumPy / LAPACK calls per frame, not flops.  The forward transient
  (:func:`filter_covariances`) makes three, on triangles, with positional arguments; V, P, the smoother gains J and
  the log-determinants are formed batched after the loop; the smoother's tail (a Stein iteration with constant
  gain, :func:`_stein_sequence`) is tested for convergence once per chunk, not per step.
* **Vectorised means.**  In the steady state the filter mean obeys ``mu_t = A mu_{t-1} + u_t`` with constant
  ``A = (I - V C) F`` and the smoother mean ``mhat_t = J mhat_{t+1} + w_t``; both are solved by
  :func:`linear_recurrence` (a parallel prefix scan with matrix powers, or blocks of frames on long takes), not a
  Python loop over frames.

Sufficient statistics (eqs. 28-30) are formed as matrix products (``Ez^T Ez``) plus closed-form sums of the
piecewise-constant covariances, and :func:`m_step` implements eqs. 31-36 (with isotropic ``Gamma``/``Lambda`` by
default, as the authors' code runs).

:func:`missing_data_variance` is the one place where missing entries are treated as missing: it runs the covariance
recursions with the per-frame observed rows to give each missing sample a posterior variance (used for ``std``).

Shapes: ``T`` frames, ``m`` observed dimensions (3 x markers), ``H`` hidden dimensions.  Pure NumPy / SciPy.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import linalg as sla

#: Relative change below which a covariance recursion counts as having reached its steady state (the filter's is
#: measured in the observations' metric, see :func:`filter_covariances`), as in :func:`missing_data_variance`.  On a
#: 145-frame clip 1e-6 leaves ~6 transient frames where 1e-10 left ~15 (a quarter of DynaMMo's time); the
#: covariances are then within ~1e-6 of the exact ones, and after 200 EM iterations the fills of the authors' trials
#: move by at most ~0.04 mm (the EM path amplifies any rounding; 1e-8 moves them by 6e-4 mm), with unchanged
#: median RMSEs.  Tests of the algebra pass ``rtol=1e-13``.
STEADY_RTOL = 1e-6

#: :func:`filter_covariances` works in whitened coordinates (``R^T R = G^T G / sigma2``) when ``cond(C)`` is at most
#: MAX_WHITEN_COND and the steady ``V_ii >= MIN_WHITEN_RATIO (C^-1)_ii`` (``V = C^-1 - N^T N`` then loses at most
#: ~3 digits); else it runs the direct recursion.  Mocap data sit far inside both (observation noise << motion).
MAX_WHITEN_COND = 1e8
MIN_WHITEN_RATIO = 1e-3


class LDSParams(NamedTuple):
    """Parameters Theta = {mu0, Gamma, F, Lambda, G, Sigma = sigma2 I} of eqs. (1)-(4).

    Attributes
    ----------
    F : ndarray (H, H)        transition matrix, eq. (2)
    G : ndarray (m, H)        observation matrix, eq. (3)
    mu0 : ndarray (H,)        mean of z_1, eq. (1)
    Gamma : ndarray (H, H)    covariance of z_1
    Lambda : ndarray (H, H)   transition noise covariance
    sigma2 : float            isotropic observation noise variance (Sigma = sigma2 I_m)
    """

    F: np.ndarray
    G: np.ndarray
    mu0: np.ndarray
    Gamma: np.ndarray
    Lambda: np.ndarray
    sigma2: float


class PiecewiseCov(NamedTuple):
    """A sequence of T covariance matrices stored as explicit head, one constant middle, explicit tail.

    Index t maps to ``head[t]`` for ``t < len(head)``, to ``tail[t - (T - len(tail))]`` for
    ``t >= T - len(tail)``, and to ``mid`` in between.  Shapes: head (kh, H, H), mid (H, H), tail (kt, H, H).
    """

    head: np.ndarray
    mid: np.ndarray
    tail: np.ndarray
    T: int

    @property
    def n_mid(self) -> int:
        """How many indices hold ``mid``."""
        return self.T - len(self.head) - len(self.tail)

    def at(self, t: int) -> np.ndarray:
        """The (H, H) matrix at index ``t`` (0 <= t < T)."""
        if t < len(self.head):
            return self.head[t]
        if t >= self.T - len(self.tail):
            return self.tail[t - (self.T - len(self.tail))]
        return self.mid

    def total(self) -> np.ndarray:
        """Sum over all T indices, (H, H)."""
        out = self.head.sum(axis=0) + self.tail.sum(axis=0)
        if self.n_mid > 0:
            out = out + self.n_mid * self.mid
        return out

    def range_sum(self, a: int, b: int) -> np.ndarray:
        """Sum over the indices a..b-1 (0 <= a <= b <= T), (H, H)."""
        kh, ts = len(self.head), self.T - len(self.tail)
        out = self.head[a:min(b, kh)].sum(axis=0) + self.tail[max(a, ts) - ts:max(b, ts) - ts].sum(axis=0)
        n_mid = min(b, ts) - max(a, kh)
        return out + n_mid * self.mid if n_mid > 0 else out

    def dense(self) -> np.ndarray:
        """All T matrices as one (T, H, H) array (tests and small T only)."""
        return np.stack([self.at(t) for t in range(self.T)]) if self.T else np.zeros((0,) + self.mid.shape)


class FilterResult(NamedTuple):
    """Output of :func:`kalman_filter`.

    mu : (T, H)     filtered means E[z_t | x_1..x_t] (eq. 17)
    pred : (T, H)   predicted means E[z_t | x_1..x_{t-1}] (pred_0 = mu0)
    V : PiecewiseCov   filtered covariances V_t (eq. 18)
    P : PiecewiseCov   P_t = F V_t F^T + Lambda, the covariance of z_{t+1} given x_1..x_t (eq. 15)
    n_head : int    frames before the steady state (len(V.head)); V_t = V.mid for t >= n_head
    nll : float     negative log-likelihood -log p(x_1..x_T) of the (completed) data
    J : PiecewiseCov   the smoother gains of :class:`CovRecursions` (data-independent, formed with the filter)
    Q_inf : (H, H)     V - J P J^T in the steady state, likewise
    """

    mu: np.ndarray
    pred: np.ndarray
    V: PiecewiseCov
    P: PiecewiseCov
    n_head: int
    nll: float
    J: PiecewiseCov
    Q_inf: np.ndarray


class SmootherResult(NamedTuple):
    """Output of :func:`rts_smoother`.

    mean : (T, H)        E[z_t | all] (eqs. 26, 28)
    Vhat : PiecewiseCov  Cov[z_t | all] (eq. 27)
    J : PiecewiseCov     smoother gains J_t = V_t F^T P_t^-1 (eq. 25), index T-1 unused (holds J.mid or zeros)
    cross : (H, H)       sum_{t=1}^{T-1} Cov[z_t, z_{t-1} | all] = sum Vhat_t J_{t-1}^T
    """

    mean: np.ndarray
    Vhat: PiecewiseCov
    J: PiecewiseCov
    cross: np.ndarray


class Stats(NamedTuple):
    """Expected sufficient statistics of the E-step (eqs. 28-30), everything the M-step needs besides the data.

    Ez : (T, H)        E[z_t]
    Szz : (H, H)       sum_t E[z_t z_t^T]
    Ezz_first : (H, H) E[z_1 z_1^T];  Ezz_last : (H, H)  E[z_T z_T^T]
    Sz1z0 : (H, H)     sum_{t=2}^{T} E[z_t z_{t-1}^T]
    V1 : (H, H)        Cov[z_1 | all] (for Gamma, eq. 32)
    """

    Ez: np.ndarray
    Szz: np.ndarray
    Ezz_first: np.ndarray
    Ezz_last: np.ndarray
    Sz1z0: np.ndarray
    V1: np.ndarray


def _sym(a: np.ndarray) -> np.ndarray:
    return (a + a.T) * 0.5


def _close(a: np.ndarray, b: np.ndarray, rtol: float) -> bool:
    """Whether |a - b|_F <= rtol |b|_F (one BLAS dot each: this runs once per frame in the transient loops)."""
    d = (a - b).ravel()
    bb = b.ravel()
    return bool(np.dot(d, d) <= rtol * rtol * np.dot(bb, bb))


def posterior_cov(P: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, float]:
    """Filter update of the covariance (eqs. 16, 18) in information form.

    Parameters
    ----------
    P : (H, H) prior (predicted) covariance, SPD.
    C : (H, H) observation information ``G_o^T G_o / sigma2`` (rows of the observed coordinates).

    Returns
    -------
    V : (H, H)  ``(P^-1 + C)^-1``, computed as ``L (I + L^T C L)^-1 L^T`` with ``P = L L^T`` (never inverts P).
    logdet_w : float  ``log |I + L^T C L|`` = ``log |G P G^T + sigma2 I| - m log sigma2``.
    """
    L = _cholesky(P)
    W = L.T @ C @ L
    W.flat[:: W.shape[0] + 1] += 1.0
    Lw = _cholesky(W)
    Y, info = _dpotrs(Lw, L.T, lower=1)  # W^-1 L^T (potrs: OpenBLAS's threaded trtrs is pathologically slow here)
    V = L @ Y
    return (V + V.T) * 0.5, 2.0 * float(np.log(Lw.diagonal()).sum())


_dpotrf = sla.lapack.dpotrf
_dpotrs = sla.lapack.dpotrs
_dsyrk = sla.blas.dsyrk
_dtrsm = sla.blas.dtrsm
_dtrtri = sla.lapack.dtrtri


def _cholesky(A: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of the SPD matrix A (LAPACK directly: these are tiny and called per frame)."""
    L, info = _dpotrf(A, lower=1, clean=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"matrix not positive definite (potrf info {info})")
    return L


def _chol_solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Solve A X = B for SPD A via Cholesky (symmetrised first); falls back to least squares if A is singular."""
    A = _sym(A)
    L, info = _dpotrf(A, lower=1)
    if info == 0:
        X, info = _dpotrs(L, B, lower=1)
        if info == 0:
            return X
    return np.linalg.lstsq(A, B, rcond=None)[0]


def linear_recurrence(A: np.ndarray, U: np.ndarray, z0: np.ndarray) -> np.ndarray:
    """Solve ``z_t = A z_{t-1} + u_t`` for t = 0..n-1 with ``z_{-1} = z0``, vectorised over time.

    Short sequences (n < :data:`BLOCKED_MIN`): a parallel prefix scan.  After step k every row holds the sum of its
    last 2^k inputs propagated by powers of A (``S_t += A^(2^k) S_{t-2^k}``), so ceil(log2 n) matrix products of
    shape (n, H) x (H, H) replace n sequential steps.  It stops early once ``A^(2^k)`` has decayed below rounding
    relative to the data, so for a stable A (spectral radius < 1, as for the steady-state filter and smoother) the
    number of steps depends on A's decay time, not on n.  Long sequences: :func:`_blocked_recurrence`, whose cost
    does not grow with A's decay time (7 ms against 36 ms for 72,000 x 16 and a slow A).

    Parameters
    ----------
    A : (H, H), U : (n, H) inputs (row t is u_t), z0 : (H,).

    Returns
    -------
    Z : (n, H), row t is z_t.
    """
    n, H = U.shape
    if n >= BLOCKED_MIN:
        return _blocked_recurrence(A, U, z0)
    S = np.array(U, dtype=np.float64)
    if n == 0:
        return S
    S[0] += A @ z0
    P = A.T.copy()  # rows: S_t^T <- S_t^T + S_{t-k}^T (A^k)^T
    k = 1
    while k < n:
        S[k:] += S[:-k] @ P
        k *= 2
        if k >= n:
            break
        P = P @ P
        if np.vdot(P, P) * (H * H) <= 1e-36:  # |P|_F >= max |P_ij|: one dot instead of abs + max
            break  # every later term is below rounding
    return S


#: :func:`linear_recurrence` works in blocks from this many frames on (measured: the prefix scan is faster below
#: ~4,000 frames, the blocks 1.3x at 5,000 and 5x at 72,000, H = 16), with blocks of BLOCK_FRAMES frames.
BLOCKED_MIN = 4096
BLOCK_FRAMES = 64


def _blocked_recurrence(A: np.ndarray, U: np.ndarray, z0: np.ndarray, c: int = BLOCK_FRAMES) -> np.ndarray:
    """:func:`linear_recurrence` in blocks of ``c`` frames: three passes over the data whatever A's decay time.

    1. Every block runs the recurrence from a zero state, all blocks at once: c steps of one (blocks, H) x (H, H)
       product each (the data laid out (c, blocks, H) so that each step reads contiguous rows).
    2. The true state entering each block: the block ends obey ``e_b = A^c e_{b-1} + local_end_b``, the same
       recurrence on n / c rows (solved by the prefix scan).
    3. Frame j of block b adds ``A^(j+1) e_{b-1}``: one (blocks, H) x (H, c H) product with the stacked powers.
    Shapes as :func:`linear_recurrence`.
    """
    n, H = U.shape
    nb = -(-n // c)
    pad = nb * c - n
    Ub = np.asarray(U, dtype=np.float64) if not pad else np.concatenate([U, np.zeros((pad, H))])
    L = np.ascontiguousarray(Ub.reshape(nb, c, H).transpose(1, 0, 2))  # (c, blocks, H)
    AT = np.ascontiguousarray(A.T)
    for j in range(1, c):
        L[j] += L[j - 1] @ AT
    powers = np.empty((H, c, H))  # powers[:, j] = (A^(j+1))^T
    P = AT
    for j in range(c):
        powers[:, j] = P
        P = P @ AT
    ends = linear_recurrence(powers[:, -1].T, L[c - 1], z0)  # (blocks, H): the state at each block's last frame
    start = np.empty((nb, H))
    start[0] = z0
    start[1:] = ends[:-1]
    out = L.transpose(1, 0, 2).reshape(nb, c * H)  # a copy, frame order
    out += start @ powers.reshape(H, c * H)
    return out.reshape(nb * c, H)[:n]


class CovRecursions(NamedTuple):
    """Output of :func:`filter_covariances`: everything of the filter and smoother that does not depend on the data.

    V, P : PiecewiseCov   filtered V_t (eq. 18) and P_t = F V_t F^T + Lambda (eq. 15), no tail
    J : PiecewiseCov      smoother gains J_t = V_t F^T P_t^-1 (eq. 25); ``min(n_head, T - 1)`` explicit, no tail
    Q_inf : (H, H)        ``V - J P J^T`` in the steady state, so that there eq. 27 reads
                          ``Vhat_t = Q_inf + J Vhat_{t+1} J^T`` (zeros when the filter never gets steady)
    logdet_w : (T,)       ``log|G P_{t-1} G^T + sigma2 I| - m log sigma2`` per frame
    n_head : int          frames before the steady state
    """

    V: PiecewiseCov
    P: PiecewiseCov
    J: PiecewiseCov
    Q_inf: np.ndarray
    logdet_w: np.ndarray
    n_head: int


def _factor_information(G: np.ndarray, s: float) -> np.ndarray:
    """R with R^T R = G^T G / s (Cholesky; QR when G^T G is singular), shape (min(m, H), H) or (H, H)."""
    Rt, info = _dpotrf(G.T @ G / s, lower=1, clean=1)
    if info == 0:
        return Rt.T
    return np.linalg.qr(G / np.sqrt(s), mode="r")


def _sym_stack(a: np.ndarray) -> np.ndarray:
    """Symmetrise a stack (n, H, H) of matrices, once after a loop (cheaper than per frame)."""
    return (a + a.transpose(0, 2, 1)) * 0.5


def filter_covariances(params: LDSParams, T: int, rtol: float = STEADY_RTOL) -> CovRecursions:
    """Covariance part of the Kalman filter (eqs. 15-18, 20-22) and the smoother gains (eq. 25), for T frames.

    Run in whitened coordinates ``z' = R z`` with ``R^T R = C = G^T G / sigma2`` (the observations then carry unit
    information in every direction).  There ``P'_t = R P_t R^T``, ``Q_t = I + P'_{t-1}`` and the whole recursion is

        Q_0 = I + R Gamma R^T,    Q_t = L_t L_t^T,    Q_{t+1} = B - (L_t^-1 F'^T)^T (L_t^-1 F'^T)

    with ``F' = R F R^-1`` and the constant ``B = I + R Lambda R^T + F' F'^T``: three small LAPACK calls per transient
    frame (potrf, trsm, syrk), on lower triangles.  ``V_t = C^-1 - N_t^T N_t`` with ``N_t = L_t^-1 R^-T`` (from the
    same trsm), ``log|I + R P R^T| = log|Q_t|``, and P and J are formed batched after the loop.  The steady state is
    tested in the whitened metric (the change of ``P'`` relative to ``P'``): it weighs each direction by what the
    observations see of it, which is what the fill ``G z`` depends on, and it is reached in about half the frames
    the model's own metric needs.  Falls back to :func:`_direct_covariances` when C is singular or badly conditioned,
    or when the observations are so weak that ``C^-1 - N^T N`` would cancel.
    """
    F, G, _, Gamma, Lam, s = params
    H = F.shape[0]
    if T == 0:
        return _direct_covariances(params, T, rtol)
    R = _factor_information(G, s)
    rd = np.abs(R.diagonal()) if R.shape[0] == H else np.zeros(1)
    if rd.min() <= MAX_WHITEN_COND ** -0.5 * rd.max():  # (nearly) singular C: cond(C) ~ (rd.max / rd.min)^2
        return _direct_covariances(params, T, rtol)
    Ri = _dtrtri(R, 0)[0]  # R^-1 (upper): R^-T and C^-1 = R^-1 R^-T are needed explicitly below
    RiT = Ri.T
    rhs = np.asfortranarray(np.hstack([RiT @ (F.T @ R.T), RiT]))  # [F'^T | R^-T]
    FwT = rhs[:, :H]
    eye = np.eye(H)
    # B's upper triangle zero: syrk and potrf read the lower one, so every Q_t from t = 1 on (syrk's output) has a
    # zero upper triangle, and the steady test (from t = 1 on) sees no junk there.
    B = np.asfortranarray(np.tril(eye + R @ Lam @ R.T + FwT.T @ FwT))
    Q = np.asfortranarray(eye + R @ Gamma @ R.T)
    potrf, syrk, trsm, vdot = _dpotrf, _dsyrk, _dtrsm, np.vdot
    Ls, Ns = [], []
    r2 = rtol * rtol
    n_head = T
    for t in range(T):
        L, info = potrf(Q, 1, 1)
        if info != 0:
            raise np.linalg.LinAlgError(f"matrix not positive definite (potrf info {info})")
        Y = trsm(1.0, L, rhs, 0, 1)  # L^-1 [F'^T | R^-T]
        Ls.append(L)
        Ns.append(Y[:, H:])
        Qn = syrk(-1.0, Y[:, :H], 1.0, B, 1, 1)
        if t:  # steady when |P'_t - P'_{t-1}| <= rtol |P'_t| (P'_t = Q_{t+1} - I)
            d = Qn - Q
            Pw = Qn - eye
            if vdot(d, d) <= r2 * vdot(Pw, Pw):
                n_head = t
                break
        Q = Qn
    n = min(n_head + 1, T)  # frames with their own V: the transient and the first steady one
    Nst = np.array(Ns[:n])
    Cinv = Ri @ RiT
    Vall = _sym_stack(Cinv - Nst.transpose(0, 2, 1) @ Nst)
    # Weak observations (V << C^-1 in the steady state) would lose digits in the subtraction.  The first frames may
    # hold a much smaller V when Gamma has shrunk in EM (1e-5 C^-1 seen), but they stay accurate to ~1e-10 there.
    if (Vall[-1].diagonal() < MIN_WHITEN_RATIO * Cinv.diagonal()).any():
        return _direct_covariances(params, T, rtol)
    lw = 2.0 * np.log(np.diagonal(np.array(Ls[:n]), axis1=1, axis2=2)).sum(axis=1)
    FV = F @ Vall
    Pall = _sym_stack(FV @ np.ascontiguousarray(F.T)) + Lam
    nJ = n if n_head < T else T - 1
    Jall = np.linalg.solve(Pall[:nJ], FV[:nJ]).transpose(0, 2, 1)  # J_t^T = P_t^-1 F V_t
    return _assemble(F, Lam, Vall, Jall, lw, n_head, T, Pall=Pall, FV=FV[-1] if n_head < T else None)


def _assemble(F, Lam, Vall, Jall, lw, n_head, T, *, Pall=None, FV=None) -> CovRecursions:
    """:class:`CovRecursions` from the explicit filtered covariances ``Vall`` (n, H, H) (V_0..V_{n_head} when steady,
    else V_0..V_{T-1}), the gains ``Jall`` (J_0..J_{n_head}, else J_0..J_{T-2}) and log-determinants ``lw`` (n,)."""
    H = F.shape[0]
    if Pall is None:
        Pall = _sym_stack(F @ (Vall @ np.ascontiguousarray(F.T))) + Lam
    logdet = np.full(T, lw[-1])
    logdet[:len(lw)] = lw
    empty = np.zeros((0, H, H))
    if n_head < T:
        if FV is None:
            FV = F @ Vall[-1]
        V = PiecewiseCov(Vall[:-1], Vall[-1], empty, T)
        P = PiecewiseCov(Pall[:-1], Pall[-1], empty, T)
        J = PiecewiseCov(Jall[:-1], Jall[-1], empty, T)
        Q_inf = _sym(Vall[-1] - Jall[-1] @ FV)  # V - J P J^T = V - J F V  (J P = V F^T)
    else:
        V = PiecewiseCov(Vall, Vall[-1], empty, T)
        P = PiecewiseCov(Pall, Pall[-1], empty, T)
        zero = np.zeros((H, H))
        J = PiecewiseCov(Jall, Jall[-1] if len(Jall) else zero, empty, T)
        Q_inf = zero
    return CovRecursions(V, P, J, Q_inf, logdet, n_head)


def _direct_covariances(params: LDSParams, T: int, rtol: float = STEADY_RTOL) -> CovRecursions:
    """:func:`filter_covariances` in the model's own coordinates, for any ``C`` (also singular, ``m < H``); the steady
    state is tested on ``P`` itself.

    Each transient frame costs seven small BLAS / LAPACK calls and works on triangles only: with ``P_{t-1} = L L^T``
    and ``C = R^T R``, ``W = I + (R L)^T (R L)`` = ``Lw Lw^T``, ``Z = Lw^-1 L^T`` gives ``V_t = Z^T Z`` (so V is PSD
    by construction) and ``K = Z F^T`` gives ``P_t = K^T K + Lambda`` (syrk: lower triangle, all potrf reads).  The
    gain ``J_{t-1}^T = P_{t-1}^-1 F V_{t-1}`` reuses the Cholesky factor of the next frame.  Full, symmetric V and P
    stacks and the log-determinants are formed after the loop in a few batched operations.  The recursion stops at
    the first frame whose ``P_t`` is within relative ``rtol`` (Frobenius) of ``P_{t-1}``: from there V, P and J are
    constant.
    """
    F, G, _, Gamma, Lam, s = params
    H = F.shape[0]
    if T == 0:
        z = np.zeros((0, H, H))
        zero = PiecewiseCov(z, np.zeros((H, H)), z, 0)
        return CovRecursions(zero, zero, zero, np.zeros((H, H)), np.zeros(0), 0)
    R = _factor_information(G, s)
    eye = np.asfortranarray(np.eye(H))
    lam = np.asfortranarray(Lam)
    FT = F.T
    r2 = rtol * rtol
    potrf, potrs, syrk, trsm, dot, vdot = _dpotrf, _dpotrs, _dsyrk, _dtrsm, np.dot, np.vdot
    Vs, Ds, JTs = [], [], []  # V_t, diag(Lw_t), J_{t-1}^T
    P = _sym(Gamma)
    n_head = T
    # Positional arguments (lower = 1, clean = 1, trans = 1): keyword parsing costs more than these tiny calls.
    for t in range(T):
        L, info = potrf(P, 1, 1)
        if info != 0:
            raise np.linalg.LinAlgError(f"matrix not positive definite (potrf info {info})")
        if t:  # gain of the previous frame: P_{t-1}^-1 F V_{t-1} with F V = K^T Z
            JTs.append(potrs(L, dot(K.T, Z), 1)[0])
        Lw = potrf(syrk(1.0, dot(R, L), 1.0, eye, 1, 1), 1)[0]  # I + L^T C L >= I: always positive definite
        Z = trsm(1.0, Lw, L.T, 0, 1)  # Lw^-1 L^T
        K = dot(Z, FT)
        Pn = syrk(1.0, K, 1.0, lam, 1, 1)  # lower triangle valid
        if t:
            d = Pn - P
            if vdot(d, d) <= r2 * vdot(Pn, Pn):
                n_head = t
                break
        Vs.append(dot(Z.T, Z))
        Ds.append(Lw.diagonal())
        P = Pn
    if n_head < T:  # the steady frame's V, Lw, plus the gain at P_inf
        Vs.append(dot(Z.T, Z))
        Ds.append(Lw.diagonal())
        L = potrf(Pn, 1, 1)[0]
        FV = dot(K.T, Z)
        JTs.append(potrs(L, FV, 1)[0])
    lw = np.log(np.array(Ds)).sum(axis=1) * 2.0
    Vall = _sym_stack(np.array(Vs))
    Jall = np.array([g.T for g in JTs]).reshape(-1, H, H)
    return _assemble(F, Lam, Vall, Jall, lw, n_head, T)


def kalman_filter(params: LDSParams, X: np.ndarray, *, rtol: float = STEADY_RTOL,
                  x2: np.ndarray | None = None) -> FilterResult:
    """Kalman filter (eqs. 14-23) on a fully observed sequence ``X`` (T, m), with its log-likelihood.

    The negative log-likelihood is ``0.5 sum_t [m log 2 pi + log|S_t| + e_t^T S_t^-1 e_t]`` with innovation
    ``e_t = x_t - G pred_t`` and ``S_t = G P_{t-1} G^T + sigma2 I``; by Woodbury
    ``e^T S^-1 e = |e|^2 / sigma2 - g^T V_t g`` with ``g = G^T e / sigma2``.  ``x2`` (T,) may pass the precomputed
    ``|x_t|^2``.
    """
    F, G, mu0, _, _, s = params
    T, m = X.shape
    H = F.shape[0]
    cov = filter_covariances(params, T, rtol)
    V, P, logdet_w, k = cov.V, cov.P, cov.logdet_w, cov.n_head
    GtG = _sym(G.T @ G)
    C = GtG / s
    b = (X @ G) / s  # (T, H): G^T x_t / sigma2
    if x2 is None:
        x2 = np.einsum("ij,ij->i", X, X)
    mu = np.empty((T, H))
    if k:  # transient: mu_t = A_t mu_{t-1} + V_t b_t with A_t = (I - V_t C) F, the products batched
        u = list(np.matmul(V.head, b[:k, :, None])[:, :, 0])
        A = list(F - V.head @ (C @ F))
        prev = mu0 - V.head[0] @ (C @ mu0) + u[0]
        out = [prev]
        for t in range(1, k):
            prev = np.dot(A[t], prev) + u[t]
            out.append(prev)
        mu[:k] = out
    if k < T:  # steady state: mu_t = A mu_{t-1} + V b_t
        Vm = V.mid
        A = F - Vm @ C @ F
        U = b[k:] @ Vm  # V symmetric
        mu[k:] = linear_recurrence(A, U, mu[k - 1])  # k >= 1: the steady state is detected at t >= 1
    pred = np.empty((T, H))
    if T:
        pred[0] = mu0
        pred[1:] = mu[:-1] @ F.T
    # Likelihood.  |e_t|^2 = |x_t|^2 - 2 x_t^T G pred_t + pred_t^T G^T G pred_t from products already formed (no
    # second (T, m) pass); the cancellation costs about log10(|x|^2 / |e|^2) digits, far below what the
    # convergence test and the 1e-8 agreement with the dense reference need.
    g = b - pred @ C  # G^T e_t / sigma2
    e2 = x2 - np.einsum("ij,ij->i", 2.0 * s * b - pred @ GtG, pred)
    quad = e2 / s
    if k:
        quad[:k] -= np.einsum("ti,tij,tj->t", g[:k], V.head, g[:k])
    if k < T:
        quad[k:] -= np.einsum("ti,ti->t", g[k:] @ V.mid, g[k:])
    nll = 0.5 * float(T * m * np.log(2 * np.pi * s) + logdet_w.sum() + quad.sum())
    return FilterResult(mu, pred, V, P, k, nll, cov.J, cov.Q_inf)


def _stein_sequence(J: np.ndarray, Q: np.ndarray, S0: np.ndarray, n: int, rtol: float,
                    chunk: int = 32) -> tuple[np.ndarray, bool]:
    """``S_i = Q + J S_{i-1} J^T`` for i = 1..n from ``S_0``, stopping at the first i with S_i within relative
    ``rtol`` (Frobenius) of S_{i-1}.

    ``chunk`` steps at a time (two small products each), then one batched convergence test per chunk: the tests
    cost more than the steps when run per step.

    Returns ``(S, converged)``: S (i + 1, H, H) holds S_0..S_i (symmetrised), i = n when not converged.
    """
    r2 = rtol * rtol
    dot = np.dot
    JT = J.T
    out = [S0]
    cur = S0
    done = 0
    while done < n:
        N = min(n - done, chunk)
        for _ in range(N):
            cur = Q + dot(dot(J, cur), JT)
            out.append(cur)
        S = np.array(out[done:])
        Sf = S.reshape(N + 1, -1)
        d = Sf[1:] - Sf[:-1]
        hit = np.flatnonzero(np.einsum("ij,ij->i", d, d) <= r2 * np.einsum("ij,ij->i", Sf[1:], Sf[1:]))
        if hit.size:
            S = S[:hit[0] + 2] if not done else np.array(out[:done + hit[0] + 2])
            return _sym_stack(S), True
        done += N
        chunk *= 2
    return _sym_stack(np.array(out)), False


def rts_smoother(params: LDSParams, filt: FilterResult, *, rtol: float = STEADY_RTOL) -> SmootherResult:
    """Rauch-Tung-Striebel smoother (eqs. 24-27) and the summed lag-one cross-covariance (from eq. 29).

    ``J_t = V_t F^T P_t^-1`` is constant once the filter is steady (t >= n_head), so the mean recursion
    ``mhat_t = J_t mhat_{t+1} + (mu_t - J_t pred_{t+1})`` is vectorised there.  ``Vhat`` (eq. 27, written
    ``Vhat_t = Q_t + J_t Vhat_{t+1} J_t^T``) is a Stein iteration with constant J and Q there: from
    ``Vhat_{T-1} = V_{T-1}`` it is evaluated in chunks (:func:`_stein_sequence`) until it stops changing, then held;
    through the filter's transient head eq. 27 is iterated frame by frame (two products per frame, the gains come
    with the filter).  ``params`` is unused (kept for the call signature).
    """
    mu, pred, V, k, J = filt.mu, filt.pred, filt.V, filt.n_head, filt.J
    T, H = mu.shape
    J_inf = J.mid
    nJ = len(J.head)  # min(k, T - 1)

    # Means.
    mean = np.empty((T, H))
    if T:
        mean[T - 1] = mu[T - 1]
    if k < T - 1:  # steady segment t = k..T-2, run backward in time
        Wt = mu[k:T - 1] - pred[k + 1:T] @ J_inf.T
        rev = linear_recurrence(J_inf, Wt[::-1], mu[T - 1])
        mean[k:T - 1] = rev[::-1]
    if nJ:  # transient: mhat_t = J_t mhat_{t+1} + (mu_t - J_t pred_{t+1})
        w = list(mu[:nJ] - np.matmul(J.head, pred[1:nJ + 1, :, None])[:, :, 0])
        Jl = list(J.head)
        cur = mean[nJ]
        out = []
        for t in range(nJ - 1, -1, -1):
            cur = np.dot(Jl[t], cur) + w[t]
            out.append(cur)
        mean[:nJ] = out[::-1]

    # Covariances, backward from Vhat_{T-1} = V_{T-1}.
    empty = np.zeros((0, H, H))
    steady_tail = None
    if k < T:  # t = k..T-1: constant J, Q
        # The tail converges slower than the filter, whose test is in the observations' metric (measured: ~2 n_head
        # steps); a step costs a tenth of a convergence test, so the first chunk is generous.
        S, conv = _stein_sequence(J_inf, filt.Q_inf, V.mid, T - 1 - k, rtol, chunk=2 * k + 4)
        if conv:  # S_0..S_{i-1} explicit (times T-1..T-i), S_i held for times k..T-1-i
            steady_tail = (S[-1], S[:-1][::-1])
            cur = S[-1]
        else:
            cur = S[-1]  # time k
            later = S[::-1]  # times k..T-1
    else:
        cur = V.head[T - 1] if T else np.zeros((H, H))
        later = cur[None]
    heads = []
    dot = np.dot
    Jl, Vl, Pl = list(J.head), list(V.head), list(filt.P.head)
    for t in range(nJ - 1, -1, -1):  # eq. 27
        Jt = Jl[t]
        cur = Vl[t] + dot(dot(Jt, cur - Pl[t]), Jt.T)
        heads.append(cur)
    head = _sym_stack(np.array(heads[::-1]).reshape(-1, H, H))
    if steady_tail is not None:
        Vhat = PiecewiseCov(head, steady_tail[0], np.ascontiguousarray(steady_tail[1]), T)
    else:  # never steady: everything explicit, as a head
        allv = np.concatenate([head, later]) if T else empty
        Vhat = PiecewiseCov(allv, allv[-1] if T else np.zeros((H, H)), empty, T)

    # sum_{t=1}^{T-1} Vhat_t J_{t-1}^T: one product over the transient gains (stacked side by side), the rest with the
    # constant gain: (sum of Vhat over t = nJ+1..T-1) J_inf^T.
    cross = np.zeros((H, H))
    if nJ:
        A = np.concatenate([Vhat.head[1:nJ + 1], Vhat.at(nJ)[None]]) if len(Vhat.head) < nJ + 1 else \
            Vhat.head[1:nJ + 1]
        cross += A.transpose(1, 0, 2).reshape(H, -1) @ J.head.transpose(1, 0, 2).reshape(H, -1).T
    if nJ + 1 < T:
        cross += Vhat.range_sum(nJ + 1, T) @ J_inf.T
    return SmootherResult(mean, Vhat, J, cross)


def e_step(params: LDSParams, X: np.ndarray, *, rtol: float = STEADY_RTOL,
           x2: np.ndarray | None = None) -> tuple[Stats, SmootherResult, float]:
    """E-step: filter + smoother on the completed data ``X`` (T, m) and the sufficient statistics (eqs. 28-30).

    ``x2`` (T,) optionally gives ``|x_t|^2``.  Returns ``(stats, smoother, nll)`` with ``nll = -log p(X | params)``.
    """
    filt = kalman_filter(params, X, rtol=rtol, x2=x2)
    sm = rts_smoother(params, filt, rtol=rtol)
    Ez = sm.mean
    T = Ez.shape[0]
    Szz = Ez.T @ Ez + sm.Vhat.total()
    first = sm.Vhat.at(0) + np.outer(Ez[0], Ez[0])
    last = sm.Vhat.at(T - 1) + np.outer(Ez[-1], Ez[-1])
    Sz1z0 = Ez[1:].T @ Ez[:-1] + sm.cross
    return Stats(Ez, _sym(Szz), _sym(first), _sym(last), Sz1z0, sm.Vhat.at(0)), sm, filt.nll


def m_step(stats: Stats, XtEz: np.ndarray, sum_x2: float, m: int, old: LDSParams, *, isotropic: bool = True,
           var_floor: float = 1e-12) -> LDSParams:
    """M-step (eqs. 31-36) given the E-step statistics and the data's ``X^T Ez`` (m, H) and ``sum |x_t|^2``.

    ``Sigma = sigma2 I`` always (sigma2 = trace of eq. 36 / (T m)); with ``isotropic`` also ``Gamma`` and
    ``Lambda`` are replaced by ``trace / H * I`` (the maximiser under that constraint).  With T = 1 the transition
    parameters F and Lambda keep their old values (no transitions to learn from).  Variances are floored at
    ``var_floor`` (data scaled to unit RMS) so that a collapsing covariance cannot break the Cholesky factorisations.
    """
    Ez = stats.Ez
    T, H = Ez.shape
    eye = np.eye(H)
    mu0 = Ez[0].copy()  # (31)
    if T >= 2:
        S_prev = stats.Szz - stats.Ezz_last
        S_next = stats.Szz - stats.Ezz_first
        F = _chol_solve(S_prev, stats.Sz1z0.T).T  # (33)
    else:
        F = old.F
    G = _chol_solve(stats.Szz, XtEz.T).T  # (35)
    sigma2 = (sum_x2 - float(np.vdot(G, XtEz))) / (T * m)  # trace of (36) at the optimal G
    sigma2 = max(sigma2, var_floor)
    # (32) and (34) at the optimal F, Lambda = (S_next - F Sz1z0^T) / (T - 1); isotropic needs their traces only
    # (tr(F B^T) = sum F * B: this runs once per EM iteration, and small calls add up on short clips).
    if isotropic:
        lam = (np.trace(S_next) - np.vdot(F, stats.Sz1z0)) / (T - 1) if T >= 2 else np.trace(old.Lambda)
        Gamma = max(np.trace(stats.V1) / H, var_floor) * eye
        Lam = max(lam / H, var_floor) * eye
    else:
        Lam = _sym(S_next - F @ stats.Sz1z0.T) / (T - 1) if T >= 2 else old.Lambda
        Gamma = _sym(stats.V1) + var_floor * eye
        Lam = Lam + var_floor * eye
    return LDSParams(F, G, mu0, Gamma, Lam, float(sigma2))


def missing_data_variance(params: LDSParams, observed: np.ndarray, *, rtol: float = 1e-6,
                          chunk: int = 2048) -> np.ndarray:
    """Posterior variance of ``G z_t`` per missing sample, treating the missing entries as missing.

    Runs the covariance recursions of the filter and smoother with each frame's observed rows only
    (``C_t = sum_{observed markers k} G_k^T G_k / sigma2``), which depends on the missing pattern but not on the
    data.  Stretches where the pattern does not change and the recursion has reached its fixed point (relative
    ``rtol``; 1e-6 moves the standard deviations by ~1e-6 relative) are skipped, so the cost grows with the number
    of pattern changes, not the number of frames.

    Parameters
    ----------
    params : LDSParams with m = 3 * n_markers (x, y, z of each marker consecutive).
    observed : (T, n_markers) bool.

    Returns
    -------
    var : (T, n_markers): the mean over x/y/z of ``diag(G_k Cov[z_t | observed] G_k^T)`` where marker k is missing,
        0 where it is observed.
    """
    F, G, _, Gamma, Lam, s = params
    T, M = observed.shape
    H = F.shape[0]
    var = np.zeros((T, M))
    if T == 0 or observed.all():
        return var
    Gk = G.reshape(M, 3, H)
    blocks = np.einsum("kai,kaj->kij", Gk, Gk).reshape(M, H * H)  # G_k^T G_k per marker
    packed = np.packbits(observed, axis=1)  # one byte string per frame: unique rows fast
    keys = np.ascontiguousarray(packed).view(np.dtype((np.void, packed.shape[1]))).reshape(-1)
    _, first, pat = np.unique(keys, return_index=True, return_inverse=True)
    patterns = observed[first]
    pat = np.asarray(pat).reshape(-1).tolist()  # Python ints: this is indexed once per frame
    Cs = (patterns.astype(float) @ blocks).reshape(-1, H, H) / s

    # Forward: filtered V_t, P_t stored once per distinct value, indexed per frame.
    Vs, Ps, vid = [], [], [0] * T
    P_prev = _sym(Gamma)
    steady = False
    for t in range(T):
        if t > 0 and steady and pat[t] == pat[t - 1]:
            vid[t] = vid[t - 1]
            continue
        V, _ = posterior_cov(P_prev, Cs[pat[t]])  # B^T B: symmetric; potrf reads one triangle of Pn anyway
        Pn = F @ V @ F.T + Lam
        steady = t > 0 and pat[t] == pat[t - 1] and _close(V, Vs[-1], rtol) and _close(Pn, Ps[-1], rtol)
        Vs.append(V)
        Ps.append(Pn)
        vid[t] = len(Vs) - 1
        P_prev = Pn

    # Backward: smoothed Vhat_t, again stored per distinct value.
    gains: dict[int, np.ndarray] = {}
    Vh, hid = [Vs[vid[T - 1]]], [0] * T
    steady = False
    for t in range(T - 2, -1, -1):
        same = vid[t] == vid[t + 1]
        if same and steady:
            hid[t] = hid[t + 1]
            continue
        i = vid[t]
        if i not in gains:
            gains[i] = _chol_solve(Ps[i], F @ Vs[i]).T
        Jt = gains[i]
        new = Vs[i] + Jt @ (Vh[hid[t + 1]] - Ps[i]) @ Jt.T
        steady = bool(same) and _close(new, Vh[hid[t + 1]], rtol)
        Vh.append(new)
        hid[t] = len(Vh) - 1

    # Variances of the missing markers, once per distinct Vhat used by a frame with a missing marker.
    frames = np.flatnonzero(~observed.all(axis=1))
    used, inv = np.unique(np.asarray(hid)[frames], return_inverse=True)
    # diag(G V G^T)_r = sum_ij G_ri G_rj V_ij: one product with the (m, H^2) matrix of row outer products.
    K = (G[:, :, None] * G[:, None, :]).reshape(G.shape[0], H * H)
    diag = np.empty((len(used), M))
    for a in range(0, len(used), chunk):
        Vc = np.array([Vh[i] for i in used[a:a + chunk]]).reshape(-1, H * H)
        diag[a:a + chunk] = (Vc @ K.T).reshape(-1, M, 3).mean(axis=2)
    v = diag[np.asarray(inv).reshape(-1)]
    var[frames] = np.where(observed[frames], 0.0, v)
    return np.maximum(var, 0.0)
