"""Van Loan's exact discretisation of the ESKF's error dynamics, written on the dynamics' structure (compiled).

:func:`fusion_eval.filters.discretize.van_loan` sums the Taylor series of the 15-state exponential for any
``F_t``: a dozen sparse 15 x 15 products per IMU step, 10 us at 10 Hz, most of the replay's time. The ESKF's
``F_t`` (:mod:`.eskf`) is block upper triangular with one non-nilpotent block::

    dp' = dv,  dv' = A dth + B dba,  dth' = C dth - dbg,  dba' = -a dba,  dbg' = -g dbg
    A = -R [f]x,  B = -R,  C = -[w]x,  a, g = 1 / tau (0 for random walks)

so every block of ``F_t^k`` is ``A``, ``B`` or the identity times a power of ``C`` or a sum
``c_k = sum_{i+j=k-1} C^i (-g)^j``, and ``Phi(s) = expm(F_t s)`` is made of six 3 x 3 power series in ``s``
(``S0 = sum C^k s^k/k!`` = expm(C s), ``S1``, ``S2`` its first and second integrals; ``D1``, ``D2``, ``D3`` the same
for ``c_k``) and four scalar ones (the bias decays and their integrals). ``C`` is skew, so ``C^3 = -|w|^2 C``: each
of those matrices is ``x0 I + x1 C + x2 C^2``, a triple of scalars, and so is every product of two of them
(``C^T = -C``). The discrete noise ``Q_d = int_0^T Phi(s) Q_c Phi(s)^T ds`` (``Q_c`` isotropic per block, and
``B B^T = I``) is then integrals of products of triples, taken by Gauss-Legendre quadrature, times ``A`` on either side
once per step. The integrands are polynomials of degree 6 in ``s`` (``Phi``'s nilpotent part, up to ``s^3`` in the
position rows) times series in ``rho = max(|w|, a, g) T``, so an n-point rule (exact to degree 2n - 1) leaves a
remainder of order ``rho^(2n - 6)``: 6 points up to ``rho = 0.1``, 8 above, up to :data:`RHO_MAX` = 1/2. Against a
40-digit exponential of Van Loan's matrix (mpmath, over all kinds of steps up to ``rho = 1/2``, every 3 x 3 block
measured against its own size) that is within 3e-15 of each block (6 points throughout: 1.7e-12 at ``rho`` near 1/2;
5 points: 3e-9; 4 points: 4e-6).

That is the same ``(Phi, Q_d)`` as the general series (``tests/test_discretize.py``) at a quarter of its cost. A step
with ``rho`` above 1/2 (a spin above 5 rad/s at 10 Hz; an IMU gap of more than 0.5 s while turning at 1 rad/s, or of
more than ``tau / 2``) or a non-finite input returns False and the caller takes the general series, which scales and
doubles.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..layout import CANONICAL
from .imu_model import PRM_KBA, PRM_KBG, PRM_QA, PRM_QBA, PRM_QBG, PRM_QG

P_ID, V_ID, TH_ID, BA_ID, BG_ID = (CANONICAL.start(b) for b in ("P", "V", "TH", "BA", "BG"))
N_CORE = CANONICAL.n_core
RHO_MAX = 0.5                  # the largest |w| T, a T, g T taken here (module docstring); beyond: the series
RHO_6_POINTS = 0.1             # up to it 6 Gauss-Legendre points, above it 8 (module docstring)
_GL6_X, _GL6_W = np.polynomial.legendre.leggauss(6)
_GL8_X, _GL8_W = np.polynomial.legendre.leggauss(8)
_TERMS_MAX = 40                # rho <= 1/2: rounding level by k ~ 15


@njit(cache=True)
def _tmul(x0, x1, x2, z0, z1, z2, w2):
    """``(x0 I + x1 C + x2 C^2)(z0 I + z1 C + z2 C^2)`` as a triple, with ``C^3 = -w2 C`` and ``C^4 = -w2 C^2``."""
    return (x0 * z0, x0 * z1 + x1 * z0 - w2 * (x1 * z2 + x2 * z1), x0 * z2 + x1 * z1 + x2 * z0 - w2 * x2 * z2)


@njit(cache=True)
def _acc_ttp(G, g, x, z, wt, w2):
    """``G[g] += wt * x z^T`` for triples ``x``, ``z`` (``z^T``: ``C^T = -C``)."""
    p0, p1, p2 = _tmul(x[0], x[1], x[2], z[0], -z[1], z[2], w2)
    G[g, 0] += wt * p0
    G[g, 1] += wt * p1
    G[g, 2] += wt * p2


@njit(cache=True)
def _sums(s, K, tc, dc, a, g, e, out, sc):
    """At ``s``: the triples ``S0, S1, S2, D1, D2, D3`` into ``out`` (6, 3) and the scalars ``eps_a, beta1, beta2,
    eps_g`` into ``sc`` (4,), from the triples of ``C^k`` (``tc``) and ``c_k`` (``dc``), ``k <= K``."""
    e[0] = 1.0
    for k in range(1, K + 3):
        e[k] = e[k - 1] * s / k                    # s^k / k!
    for q in range(6):
        for c in range(3):
            out[q, c] = 0.0
    for c in range(3):
        for k in range(K + 1):
            out[0, c] += tc[k, c] * e[k]
            out[1, c] += tc[k, c] * e[k + 1]
            out[2, c] += tc[k, c] * e[k + 2]
            out[3, c] += dc[k, c] * e[k]
            out[4, c] += dc[k, c] * e[k + 1]
            out[5, c] += dc[k, c] * e[k + 2]
    ea = b1 = b2 = eg = 0.0
    pa = pg = 1.0
    for k in range(K + 1):
        ea += pa * e[k]
        b1 += pa * e[k + 1]
        b2 += pa * e[k + 2]
        eg += pg * e[k]
        pa *= -a
        pg *= -g
    sc[0], sc[1], sc[2], sc[3] = ea, b1, b2, eg


@njit(cache=True)
def _mat(t, C, C2, out):
    """``out <- t0 I + t1 C + t2 C^2`` (3 x 3)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = t[1] * C[i, j] + t[2] * C2[i, j]
        out[i, i] += t[0]


@njit(cache=True)
def _mm(X, Y, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = X[i, 0] * Y[0, j] + X[i, 1] * Y[1, j] + X[i, 2] * Y[2, j]


@njit(cache=True)
def _mmt(X, Y, out):
    """``out <- X Y^T``."""
    for i in range(3):
        for j in range(3):
            out[i, j] = X[i, 0] * Y[j, 0] + X[i, 1] * Y[j, 1] + X[i, 2] * Y[j, 2]


@njit(cache=True)
def _put(M, r, c, X, scale, sym):
    """``M[r:r+3, c:c+3] <- scale X`` (and its transpose at ``[c, r]`` when ``sym``)."""
    for i in range(3):
        for j in range(3):
            v = scale * X[i, j]
            M[r + i, c + j] = v
            if sym:
                M[c + j, r + i] = v


@njit(cache=True)
def _put_eye(M, r, c, v, sym):
    for i in range(3):
        M[r + i, c + i] = v
        if sym:
            M[c + i, r + i] = v


@njit(cache=True)
def van_loan_eskf(R, f, w, dt, prm, qscale, Phi, Qd):
    """``Phi = expm(F_t T)`` and ``Q_d`` (15 x 15, written into ``Phi`` and ``Qd``) of the ESKF linearised at the
    attitude ``R`` and the bias-corrected ``f``, ``w``: the same as ``discretize.van_loan(*continuous_model(...))``
    (module docstring). Returns False, writing nothing, where ``|w| T``, ``|a| T`` or ``|g| T`` exceeds
    :data:`RHO_MAX` or an input is not finite: the caller then takes the general series."""
    a, g = prm[PRM_KBA], prm[PRM_KBG]
    w2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    if not (np.isfinite(w2) and np.isfinite(a) and np.isfinite(g) and np.isfinite(dt) and dt >= 0.0):
        return False
    rho = max(np.sqrt(w2), abs(a), abs(g)) * dt
    if not rho <= RHO_MAX:
        return False
    gl_x, gl_w = (_GL6_X, _GL6_W) if rho <= RHO_6_POINTS else (_GL8_X, _GL8_W)
    # terms: rho^k / k! below rounding, one more for c_k's growth (|c_k| <= k max(|w|, g)^(k-1)), at least 3
    term, K = 1.0, 0
    while term > 1e-17 and K < _TERMS_MAX:
        K += 1
        term *= rho / K
    K = max(K + 1, 3)
    tc = np.zeros((K + 1, 3))
    dc = np.zeros((K + 1, 3))
    tc[0, 0] = 1.0
    dc[1, 0] = 1.0
    pg = -g
    for k in range(K):
        tc[k + 1, 0], tc[k + 1, 1], tc[k + 1, 2] = 0.0, tc[k, 0] - w2 * tc[k, 2], tc[k, 1]
        if k >= 1:
            dc[k + 1, 0], dc[k + 1, 1], dc[k + 1, 2] = pg, dc[k, 0] - w2 * dc[k, 2], dc[k, 1]
            pg *= -g
    e = np.empty(K + 3)
    t = np.empty((6, 3))
    sc = np.empty(4)
    # the quadrature of the triples' products: theta noise (S2 S2^T, S2 S1^T, S2 S0^T, S1 S1^T, S1 S0^T, S0 S0^T),
    # gyro-bias noise (the same of D3, D2, D1), then eps_g D3, eps_g D2, eps_g D1
    G = np.zeros((15, 3))
    sq = np.zeros(7)                # int beta2^2, beta2 beta1, beta1^2, beta2 eps_a, beta1 eps_a, eps_a^2, eps_g^2
    for nd in range(gl_x.shape[0]):
        s = 0.5 * dt * (1.0 + gl_x[nd])
        wt = 0.5 * dt * gl_w[nd]
        _sums(s, K, tc, dc, a, g, e, t, sc)
        for h in range(2):
            o = 3 * h                                   # S (0, 1, 2) or D (3, 4, 5): innermost-integral first
            x2, x1, x0 = t[o + 2], t[o + 1], t[o]
            _acc_ttp(G, 6 * h + 0, x2, x2, wt, w2)
            _acc_ttp(G, 6 * h + 1, x2, x1, wt, w2)
            _acc_ttp(G, 6 * h + 2, x2, x0, wt, w2)
            _acc_ttp(G, 6 * h + 3, x1, x1, wt, w2)
            _acc_ttp(G, 6 * h + 4, x1, x0, wt, w2)
            _acc_ttp(G, 6 * h + 5, x0, x0, wt, w2)
        ea, b1, b2, eg = sc[0], sc[1], sc[2], sc[3]
        for c in range(3):
            G[12, c] += wt * eg * t[5, c]
            G[13, c] += wt * eg * t[4, c]
            G[14, c] += wt * eg * t[3, c]
        sq[0] += wt * b2 * b2
        sq[1] += wt * b2 * b1
        sq[2] += wt * b1 * b1
        sq[3] += wt * b2 * ea
        sq[4] += wt * b1 * ea
        sq[5] += wt * ea * ea
        sq[6] += wt * eg * eg
    qv = prm[PRM_QA] * prm[PRM_QA] * qscale
    qth = prm[PRM_QG] * prm[PRM_QG] * qscale
    qba = prm[PRM_QBA] * prm[PRM_QBA]
    qbg = prm[PRM_QBG] * prm[PRM_QBG]
    # the 3 x 3 blocks: C, C^2, A = -R [f]x, B = -R
    C = np.empty((3, 3))
    C[0, 0], C[0, 1], C[0, 2] = 0.0, w[2], -w[1]
    C[1, 0], C[1, 1], C[1, 2] = -w[2], 0.0, w[0]
    C[2, 0], C[2, 1], C[2, 2] = w[1], -w[0], 0.0
    C2 = np.empty((3, 3))
    _mm(C, C, C2)
    A = np.empty((3, 3))
    for i in range(3):
        A[i, 0] = -(R[i, 1] * f[2] - R[i, 2] * f[1])
        A[i, 1] = -(R[i, 2] * f[0] - R[i, 0] * f[2])
        A[i, 2] = -(R[i, 0] * f[1] - R[i, 1] * f[0])
    M = np.empty((3, 3))
    X = np.empty((3, 3))
    Y = np.empty((3, 3))
    comb = np.empty(3)
    for i in range(N_CORE):
        for j in range(N_CORE):
            Phi[i, j] = 0.0
            Qd[i, j] = 0.0
    # Q_d: (row block, column block, pair index, A on the left, A^T on the right)
    for pr in range(6):
        for c in range(3):
            comb[c] = qth * G[pr, c] + qbg * G[6 + pr, c]
        _mat(comb, C, C2, M)
        if pr == 0 or pr == 1 or pr == 3:      # pp, pv, vv: A M A^T
            _mm(A, M, X)
            _mmt(X, A, Y)
        elif pr == 2 or pr == 4:               # p theta, v theta: A M
            _mm(A, M, Y)
        else:                                  # theta theta
            for i in range(3):
                for j in range(3):
                    Y[i, j] = M[i, j]
        r = P_ID if pr <= 2 else (V_ID if pr <= 4 else TH_ID)
        cb = (P_ID, V_ID, TH_ID, V_ID, TH_ID, TH_ID)[pr]
        _put(Qd, r, cb, Y, 1.0, r != cb)
        if r == cb:                            # exactly symmetric diagonal blocks
            for i in range(3):
                for j in range(i + 1, 3):
                    v = 0.5 * (Qd[r + i, r + j] + Qd[r + j, r + i])
                    Qd[r + i, r + j] = v
                    Qd[r + j, r + i] = v
    for i in range(3):
        Qd[P_ID + i, P_ID + i] += qv * dt * dt * dt / 3.0 + qba * sq[0]
        Qd[P_ID + i, V_ID + i] += qv * dt * dt / 2.0 + qba * sq[1]
        Qd[V_ID + i, P_ID + i] += qv * dt * dt / 2.0 + qba * sq[1]
        Qd[V_ID + i, V_ID + i] += qv * dt + qba * sq[2]
    for i in range(3):                          # the accelerometer-bias columns: q_ba int(beta eps_a) B, B = -R
        for j in range(3):
            v = -qba * sq[3] * R[i, j]
            Qd[P_ID + i, BA_ID + j] = v
            Qd[BA_ID + j, P_ID + i] = v
            v = -qba * sq[4] * R[i, j]
            Qd[V_ID + i, BA_ID + j] = v
            Qd[BA_ID + j, V_ID + i] = v
    for q in range(3):                          # the gyro-bias columns: -q_bg A (eps_g D3), -q_bg A (eps_g D2), -q_bg eps_g D1
        _mat(G[12 + q], C, C2, M)
        if q < 2:
            _mm(A, M, Y)
        else:
            for i in range(3):
                for j in range(3):
                    Y[i, j] = M[i, j]
        _put(Qd, (P_ID, V_ID, TH_ID)[q], BG_ID, Y, -qbg, True)
    _put_eye(Qd, BA_ID, BA_ID, qba * sq[5], False)
    _put_eye(Qd, BG_ID, BG_ID, qbg * sq[6], False)
    # Phi(T)
    _sums(dt, K, tc, dc, a, g, e, t, sc)
    ea, b1, b2, eg = sc[0], sc[1], sc[2], sc[3]
    for i in range(3):
        Phi[P_ID + i, P_ID + i] = 1.0
        Phi[P_ID + i, V_ID + i] = dt
        Phi[V_ID + i, V_ID + i] = 1.0
        Phi[BA_ID + i, BA_ID + i] = ea
        Phi[BG_ID + i, BG_ID + i] = eg
        for j in range(3):
            Phi[P_ID + i, BA_ID + j] = -b2 * R[i, j]
            Phi[V_ID + i, BA_ID + j] = -b1 * R[i, j]
    for q in range(6):              # S0, S1, S2, D1, D2, D3 -> their blocks
        _mat(t[q], C, C2, M)
        if q == 0:
            _put(Phi, TH_ID, TH_ID, M, 1.0, False)
        elif q == 3:
            _put(Phi, TH_ID, BG_ID, M, -1.0, False)
        else:
            _mm(A, M, Y)
            r = V_ID if (q == 1 or q == 4) else P_ID
            _put(Phi, r, TH_ID if q <= 2 else BG_ID, Y, 1.0 if q <= 2 else -1.0, False)
    return True
