"""The smoother's linear algebra, compiled: one backward step costs a few microseconds instead of the ~100 of
small NumPy calls, which matters at one step per IMU interval."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def pinv_sym(P, rcond):
    """The (pseudo-)inverse of a covariance, taken on its correlation matrix so that a 1e-10 rad^2/s^2 bias
    variance beside a 1e2 m^2 position variance is not cut off. A well-conditioned one goes through Cholesky;
    a degenerate one (a quaternion's norm, a clone taken this instant) through the eigen-decomposition, with
    the directions below ``rcond`` dropped."""
    n = P.shape[0]
    d = np.empty(n)
    for i in range(n):
        d[i] = np.sqrt(P[i, i]) if P[i, i] > 0.0 else 1.0
    C = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            C[i, j] = P[i, j] / (d[i] * d[j])
    # Cholesky by hand: numba's raises on failure, and a tiny pivot must fall back as well
    L = np.zeros((n, n))
    ok = True
    for j in range(n):
        s = C[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if s <= 1e3 * rcond:
            ok = False
            break
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s2 = C[i, j]
            for k in range(j):
                s2 -= L[i, k] * L[j, k]
            L[i, j] = s2 / L[j, j]
    if ok:
        # C^-1 = L^-T L^-1 with L^-1 by forward substitution (lower triangular) and the product over its triangle:
        # no LAPACK call, which costs more than the arithmetic at these sizes
        Li = np.zeros((n, n))
        for j in range(n):
            Li[j, j] = 1.0 / L[j, j]
            for i in range(j + 1, n):
                acc = 0.0
                for k in range(j, i):
                    acc += L[i, k] * Li[k, j]
                Li[i, j] = -acc / L[i, i]
        G = np.empty((n, n))
        for i in range(n):
            for j in range(i, n):
                acc = 0.0
                for k in range(j, n):              # Li[k, i] Li[k, j], nonzero for k >= max(i, j) = j
                    acc += Li[k, i] * Li[k, j]
                G[i, j] = acc
                G[j, i] = acc
    else:
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
def backward(P_j, phi, P_prior, e, Ps_next, rcond):
    """One RTS step over an interval whose transition is ``phi`` on the leading states and the identity on the
    rest (a clone): the correction ``C e`` of the posterior at j and the smoothed covariance at j."""
    n = P_j.shape[0]
    m = phi.shape[0]
    PF = P_j.copy()                                  # P_j Phi^T
    PF[:, :m] = np.ascontiguousarray(P_j[:, :m]) @ np.ascontiguousarray(phi.T)
    C = PF @ pinv_sym(P_prior, rcond)
    Ps = P_j + C @ (Ps_next - P_prior) @ C.T
    return C @ e, 0.5 * (Ps + Ps.T)


@njit(cache=True)
def condition(P, m, rcond):
    """Split a covariance over ``[x (m), c]`` into ``x``'s covariance given ``c`` (``A - B D^-1 B^T``), the cross
    block ``B`` and ``D^-1``."""
    A = np.ascontiguousarray(P[:m, :m])
    B = np.ascontiguousarray(P[:m, m:])
    Dinv = pinv_sym(np.ascontiguousarray(P[m:, m:]), rcond)
    Ac = A - B @ Dinv @ B.T
    return 0.5 * (Ac + Ac.T), B, Dinv


@njit(cache=True)
def assemble(Ac, B, D, Dinv):
    """The joint covariance over ``[x, c]`` from ``x``'s conditional covariance, the cross block and ``D``."""
    m = Ac.shape[0]
    n = m + D.shape[0]
    P = np.empty((n, n))
    P[:m, :m] = Ac + B @ Dinv @ B.T
    P[:m, m:] = B
    P[m:, :m] = B.T
    P[m:, m:] = D
    return P


@njit(cache=True)
def backward_clone(Ac_j, B_j, Dinv, phi, S_j, e, Ps_next, P_j, P_next, rcond):
    """One RTS step for a state ``[x, c]`` whose clone ``c`` is constant, in the conditional form that keeps the
    near-perfect correlation of ``x`` and ``c`` just after a clone out of every inverse::

        C_xx = A_c Phi^T S^-1,   C_xc = (I - C_xx Phi) B D^-1,   C_cc = I

    (``A_c``: x's covariance given c at j, ``S = Phi A_c Phi^T + Q`` the same at j+1; ``docs/rts_smoother.md``)."""
    m = Ac_j.shape[0]
    n = P_j.shape[0]
    Cxx = Ac_j @ np.ascontiguousarray(phi.T) @ pinv_sym(S_j, rcond)
    Cxc = (np.eye(m) - Cxx @ phi) @ B_j @ Dinv
    C = np.eye(n)
    C[:m, :m] = Cxx
    C[:m, m:] = Cxc
    Ps = P_j + C @ (Ps_next - P_next) @ C.T
    return C @ e, 0.5 * (Ps + Ps.T)


@njit(cache=True)
def uncondition(P_pre, m, e, Ps_lead, rcond):
    """Undo a clone: the smoothed correction and covariance of the state before it (its leading ``m`` states
    and the old clone) from the smoothed leading states (``e``: their correction, ``Ps_lead``: covariance)."""
    A = np.ascontiguousarray(P_pre[:m, :m])
    C = np.ascontiguousarray(P_pre[:, :m]) @ pinv_sym(A, rcond)
    P = P_pre + C @ (Ps_lead - A) @ C.T
    return C @ e, 0.5 * (P + P.T)


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
