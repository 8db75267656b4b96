"""The smoother's linear algebra, compiled: one backward step costs a few microseconds instead of the ~100 of
small NumPy calls, which matters at one step per IMU interval.

Loops are written by hand where they exploit a structure (triangles, symmetric halves, a clone's identity rows) or
where a LAPACK call would cost more than its arithmetic; dense products of whole 15-21 state blocks go to BLAS
(``@``), which at these sizes is 3-4x faster than a scalar triple loop (0.37 against 1.4 us for 15x15, measured)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def chol_scaled(P, rcond):
    """``d`` and ``L`` with ``P = diag(d) L L^T diag(d)``: the Cholesky factor of the correlation matrix, so that a
    1e-10 rad^2/s^2 bias variance beside a 1e2 m^2 position variance is not cut off; ``ok`` is False when a pivot
    falls below ``rcond`` (a degenerate covariance: a quaternion's norm, a clone taken this instant). By hand:
    numba's raises on failure, and a tiny pivot must fall back as well."""
    n = P.shape[0]
    d = np.empty(n)
    for i in range(n):
        d[i] = np.sqrt(P[i, i]) if P[i, i] > 0.0 else 1.0
    L = np.zeros((n, n))
    for j in range(n):
        s = P[j, j] / (d[j] * d[j])
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if s <= 1e3 * rcond:
            return d, L, False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s2 = P[i, j] / (d[i] * d[j])
            for k in range(j):
                s2 -= L[i, k] * L[j, k]
            L[i, j] = s2 / L[j, j]
    return d, L, True


@njit(cache=True)
def _pinv_eig(P, d, rcond):
    """The pseudo-inverse of a degenerate covariance through its correlation matrix's eigen-decomposition, the
    directions below ``rcond`` dropped."""
    n = P.shape[0]
    C = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            C[i, j] = P[i, j] / (d[i] * d[j])
    w, V = np.linalg.eigh(C)
    G = np.zeros((n, n))
    top = max(w[n - 1], 1e-300)
    for k in range(n):
        if w[k] > rcond * top:
            v = V[:, k]
            G += np.outer(v, v) / w[k]
    for i in range(n):
        for j in range(n):
            G[i, j] /= d[i] * d[j]
    return G


@njit(cache=True)
def pinv_sym(P, rcond):
    """The (pseudo-)inverse of a covariance (:func:`chol_scaled`; degenerate: :func:`_pinv_eig`)."""
    n = P.shape[0]
    d, L, ok = chol_scaled(P, rcond)
    if not ok:
        return _pinv_eig(P, d, rcond)
    # C^-1 = L^-T L^-1, the product over its triangle: no LAPACK call, which costs more than the arithmetic here
    Li = _tri_inverse(L)
    G = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for k in range(j, n):              # Li[k, i] Li[k, j], nonzero for k >= max(i, j) = j
                acc += Li[k, i] * Li[k, j]
            G[i, j] = acc / (d[i] * d[j])
            G[j, i] = G[i, j]
    return G


@njit(cache=True)
def solve_sym(P, M, rcond):
    """``P^+ M`` for a covariance ``P`` and a block of columns ``M``: two triangular solves over
    :func:`chol_scaled`'s factor (a third of the work of forming the inverse and multiplying); a degenerate ``P``
    through :func:`_pinv_eig`."""
    d, L, ok = chol_scaled(P, rcond)
    if not ok:
        return _pinv_eig(P, d, rcond) @ np.ascontiguousarray(M)
    return _solve_factored(d, L, M)


@njit(cache=True)
def _tri_inverse(L):
    """The inverse of a lower-triangular ``L``, by forward substitution (itself lower triangular)."""
    n = L.shape[0]
    Li = np.zeros((n, n))
    for j in range(n):
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            acc = 0.0
            for k in range(j, i):
                acc += L[i, k] * Li[k, j]
            Li[i, j] = -acc / L[i, i]
    return Li


@njit(cache=True)
def _solve_factored(d, L, M):
    """``P^-1 M = D^-1 L^-T L^-1 D^-1 M`` from :func:`chol_scaled`'s ``d, L``, by forward and back substitution over
    ``M``'s columns in place: for the smoother's 6-15 columns faster than forming ``L``'s inverse and two BLAS
    products (15 x 6: 3.0 -> 2.7 us, 15 x 15: 6.5 -> 4.0 us, measured)."""
    n, r = M.shape
    X = np.empty((n, r))
    for i in range(n):
        inv = 1.0 / d[i]
        for c in range(r):
            X[i, c] = M[i, c] * inv
    for i in range(n):                               # L y = z
        for k in range(i):
            lik = L[i, k]
            for c in range(r):
                X[i, c] -= lik * X[k, c]
        li = 1.0 / L[i, i]
        for c in range(r):
            X[i, c] *= li
    for i in range(n - 1, -1, -1):                   # L^T w = y
        for k in range(i + 1, n):
            lki = L[k, i]
            for c in range(r):
                X[i, c] -= lki * X[k, c]
        li = 1.0 / L[i, i]
        for c in range(r):
            X[i, c] *= li
    for i in range(n):
        inv = 1.0 / d[i]
        for c in range(r):
            X[i, c] *= inv
    return X


@njit(cache=True)
def backward(P_j, phi, P_prior, e, Ps_next, rcond):
    """One RTS step over an interval whose transition is ``phi`` on the leading states and the identity on the
    rest (a clone): the correction ``C e`` of the posterior at j and the smoothed covariance at j."""
    m = phi.shape[0]
    FP = P_j.copy()                                  # Phi P_j = (P_j Phi^T)^T
    FP[:m, :] = phi @ np.ascontiguousarray(P_j[:m, :])
    C = solve_sym(P_prior, FP, rcond).T              # P_j Phi^T (P^-)^-1, both symmetric
    Ps = P_j + C @ (Ps_next - P_prior) @ C.T
    return C @ e, 0.5 * (Ps + Ps.T)


@njit(cache=True)
def condition(P, m, rcond):
    """Split a covariance over ``[x (m), c]`` into ``x``'s covariance given ``c`` (``A - B D^-1 B^T``), the cross
    block ``B`` and ``D^-1``."""
    Dinv = pinv_sym(np.ascontiguousarray(P[m:, m:]), rcond)
    Ac, B = condition_given(P, m, Dinv)
    return Ac, B, Dinv


@njit(cache=True)
def condition_given(P, m, Dinv):
    """:func:`condition` with the clone's ``D^-1`` already known (the clone is constant between epochs): ``x``'s
    covariance given ``c`` and the cross block."""
    n = P.shape[0]
    B = np.ascontiguousarray(P[:m, m:])
    BD = B @ Dinv
    Ac = np.empty((m, m))
    for i in range(m):
        for j in range(i, m):
            acc = 0.0
            for k in range(n - m):
                acc += BD[i, k] * B[j, k]
            Ac[i, j] = 0.5 * ((P[i, j] - acc) + (P[j, i] - acc))
            Ac[j, i] = Ac[i, j]
    return Ac, B


@njit(cache=True)
def assemble(Ac, B, D, Dinv):
    """The joint covariance over ``[x, c]`` from ``x``'s conditional covariance, the cross block and ``D``."""
    m = Ac.shape[0]
    nb = D.shape[0]
    n = m + nb
    BD = B @ Dinv
    P = np.empty((n, n))
    for i in range(m):
        for j in range(m):
            acc = 0.0
            for k in range(nb):
                acc += BD[i, k] * B[j, k]
            P[i, j] = Ac[i, j] + acc
        for j in range(nb):
            P[i, m + j] = B[i, j]
            P[m + j, i] = B[i, j]
    for i in range(nb):
        for j in range(nb):
            P[m + i, m + j] = D[i, j]
    return P


@njit(cache=True)
def backward_clone(Ac_j, B_j, Dinv, phi, S_j, e, Ps_next, P_j, P_next, rcond):
    """One RTS step for a state ``[x, c]`` whose clone ``c`` is constant, in the conditional form that keeps the
    near-perfect correlation of ``x`` and ``c`` just after a clone out of every inverse::

        C_xx = A_c Phi^T S^-1,   C_xc = (I - C_xx Phi) B D^-1,   C_cc = I

    (``A_c``: x's covariance given c at j, ``S = Phi A_c Phi^T + Q`` the same at j+1; ``docs/rts_smoother.md``)."""
    m = Ac_j.shape[0]
    n = P_j.shape[0]
    Cx = np.empty((m, n))
    Cx[:, :m] = solve_sym(S_j, phi @ Ac_j, rcond).T           # C_xx = (S^-1 Phi A_c)^T: S, A_c symmetric
    BD = B_j @ Dinv
    Cx[:, m:] = BD - np.ascontiguousarray(Cx[:, :m]) @ (phi @ BD)
    return _clone_gain_applied(Cx, e, Ps_next - P_next, P_j)


@njit(cache=True)
def interval_clone(CxxT, B_i, Dinv, BD_b, e, dP, P_i):
    """:func:`backward_clone` from a point ``i`` of an interval straight to its end ``b`` (no observation between):
    the gains of the steps between multiply out to ``C_xx = A_c,i Phi(b,i)^T S_b^-1``, given here transposed
    (``CxxT = S_b^-1 Phi(b,i) A_c,i``: :func:`gain_t`), and ``C_xc = (B_i - C_xx B_b) D^-1`` (``B_b = Phi(b,i) B_i``);
    ``e`` and ``dP`` are the end's correction and ``P^s_b - P^-_b`` (``docs/rts_smoother.md``, section 3)."""
    m = CxxT.shape[0]
    Cx = np.empty((m, P_i.shape[0]))
    Cx[:, :m] = CxxT.T
    Cx[:, m:] = B_i @ Dinv - np.ascontiguousarray(Cx[:, :m]) @ BD_b
    return _clone_gain_applied(Cx, e, dP, P_i)


@njit(cache=True)
def gain_t(S, phi, A, rcond):
    """``S^-1 Phi A`` for a covariance ``S``: the transposed gain of a single-step interval (``S``: the end's prior,
    ``A``: the start's covariance), by one factorisation and substitution instead of ``S``'s inverse and two
    products."""
    return solve_sym(S, phi @ A, rcond)


@njit(cache=True)
def interval_plain(CT, P_i, e, dP):
    """:func:`backward` from a point ``i`` of an interval straight to its end ``b``: ``C = P_i Phi(b,i)^T
    (P^-_b)^-1``, given transposed (``CT = (P^-_b)^-1 Phi(b,i) P_i``)."""
    C = np.ascontiguousarray(CT.T)
    Ps = P_i + C @ dP @ C.T
    return C @ e, 0.5 * (Ps + Ps.T)


@njit(cache=True)
def _clone_gain_applied(Cx, e, dP, P_j):
    """The correction ``C e`` and ``P_j + C dP C^T`` for ``C = [[C_x], [0 I]]``: a clone's rows of the gain are
    ``[0 I]``, so the product is formed from the leading rows only: ``W = C_x dP`` (whose clone columns are the
    cross block) and ``W C_x^T``, two thirds of the full product."""
    m, n = Cx.shape
    W = Cx @ dP
    lead = W @ np.ascontiguousarray(Cx.T)
    Ps = np.empty((n, n))
    for i in range(n):                               # P_j + C dP C^T, both symmetrized (upper triangle, mirrored)
        for j in range(i, n):
            if j < m:
                x = lead[i, j]
            elif i < m:
                x = W[i, j]
            else:
                x = 0.5 * (dP[i, j] + dP[j, i])
            v = 0.5 * (P_j[i, j] + P_j[j, i]) + x
            Ps[i, j] = v
            Ps[j, i] = v
    d = np.empty(n)
    d[:m] = Cx @ e
    d[m:] = e[m:]
    return d, Ps


@njit(cache=True)
def uncondition(P_pre, m, e, Ps_lead, rcond):
    """Undo a clone: the smoothed correction and covariance of the state before it (its leading ``m`` states
    and the old clone) from the smoothed leading states (``e``: their correction, ``Ps_lead``: covariance).
    With ``C = [I; Y^T]``, ``Y = A^-1 B`` (``A``, ``B``: the leading block and its cross block with the old
    clone), the leading block becomes ``Ps_lead`` itself and only the clone's rows are computed."""
    n = P_pre.shape[0]
    nb = n - m
    A = np.ascontiguousarray(P_pre[:m, :m])
    d, L, ok = chol_scaled(A, rcond)
    if not ok:                                       # a degenerate leading block: A A^+ is not I, the general form
        C = np.ascontiguousarray(P_pre[:, :m]) @ _pinv_eig(A, d, rcond)
        P = P_pre + C @ (Ps_lead - A) @ C.T
        return C @ e, 0.5 * (P + P.T)
    Y = _solve_factored(d, L, P_pre[:m, m:])
    dA = Ps_lead - A
    T = dA @ Y                                       # (Ps_lead - A) Y: m x nb
    P = np.empty((n, n))
    for i in range(m):
        for j in range(m):
            P[i, j] = 0.5 * (Ps_lead[i, j] + Ps_lead[j, i])
        for j in range(nb):
            P[i, m + j] = P_pre[i, m + j] + T[i, j]
            P[m + j, i] = P[i, m + j]
    for i in range(nb):
        for j in range(i, nb):
            acc = 0.0
            for k in range(m):
                acc += Y[k, i] * T[k, j]
            v = P_pre[m + i, m + j] + acc
            P[m + i, m + j] = v
            P[m + j, m + i] = v
    out = np.empty(n)
    for i in range(m):
        out[i] = e[i]
    for j in range(nb):
        acc = 0.0
        for k in range(m):
            acc += Y[k, j] * e[k]
        out[m + j] = acc
    return out, P


@njit(cache=True)
def unpack_upper(row, n_max, n):
    """The leading ``n x n`` block of a symmetric matrix stored as the upper triangle of ``n_max x n_max``."""
    P = np.empty((n, n))
    k = 0
    for i in range(n_max):
        for j in range(i, n_max):
            if i < n and j < n:
                P[i, j] = row[k]
                P[j, i] = row[k]
            k += 1
    return P


@njit(cache=True)
def augmented(P, nc):
    """``P`` with a constant copy of its leading ``nc`` states appended (cross block the identity): after one
    step of a formulation, that cross block is the step's transition matrix."""
    n = P.shape[0]
    Pa = np.zeros((n + nc, n + nc))
    Pa[:n, :n] = P
    for i in range(nc):
        Pa[i, n + i] = 1.0
        Pa[n + i, i] = 1.0
    return Pa
