"""The covariance arithmetic every formulation shares (compiled): symmetrisation and the Joseph update.

Each exists once; the formulations' propagation steps and the (iterated) updates call these.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def symmetrize_into(P, n, M):
    """``P[:n, :n] <- (M + M^T) / 2``: keeps P symmetric against rounding (``M`` may be ``P`` itself)."""
    for i in range(n):
        P[i, i] = M[i, i]
        for j in range(i + 1, n):
            s = 0.5 * (M[i, j] + M[j, i])
            P[i, j] = s
            P[j, i] = s


@njit(cache=True)
def joseph(P, n, K, H, Rm):
    """``P <- (I - K H) P (I - K H)^T + K R K^T`` on the first ``n`` states, symmetrised.

    The Joseph form keeps P symmetric positive semi-definite under rounding, and stays correct for the
    suboptimal gains that gating, clipping or an iterated update's last iterate give, where
    ``(I - K H) P`` does not.
    """
    Pn = np.ascontiguousarray(P[:n, :n])
    IKH = np.eye(n) - K @ H
    newP = IKH @ Pn @ np.ascontiguousarray(IKH.T) + K @ Rm @ np.ascontiguousarray(K.T)
    symmetrize_into(P, n, newP)


@njit(cache=True)
def gain(P, n, H, Rm):
    """Kalman gain ``K = P H^T S^-1`` and ``S^-1`` with ``S = H P H^T + R`` (symmetrised)."""
    Pn = np.ascontiguousarray(P[:n, :n])
    PHt = Pn @ np.ascontiguousarray(H.T)
    S = H @ PHt + Rm
    S = 0.5 * (S + S.T)
    Sinv = np.linalg.inv(S)
    return PHt @ Sinv, Sinv


@njit(cache=True)
def joseph_update_dense(P, n, H, r, Rm, gate):
    """The Joseph update written as the textbook's dense products (the tests' oracle for
    :func:`joseph_update`, which computes the same quantity in O(n^2 m))."""
    K, Sinv = gain(P, n, H, Rm)
    nis = r @ (Sinv @ r)
    if nis > gate:
        return np.zeros(n), nis, False
    dx = K @ r
    joseph(P, n, K, H, Rm)
    return dx, nis, True


def workspace(n_max: int, m_max: int):
    """Scratch arrays of :func:`joseph_update_into` for up to ``n_max`` states and ``m_max`` residual rows."""
    return (np.zeros((3, m_max, n_max)), np.zeros((3, m_max, m_max)), np.zeros(n_max),
            np.zeros((m_max, n_max + 1), np.int64))


@njit(cache=True)
def joseph_update_into(P, n, H, m, r, Rm, gate, wn, wm, dx, cols):
    """Kalman update of an error state, in place and without allocation; returns ``(nis, accepted)``.

    The same quantity as :func:`joseph_update_dense` (``P <- (I - K H) P (I - K H)^T + K R K^T``,
    symmetrised, ``K = P H^T S^-1``), for a residual of ``m`` rows (``m << n``), in the Joseph form's own order
    but on its structure: with ``U = P H^T`` (n x m), ``A = (I - K H) P = P - K U^T`` (in place), then
    ``P+ = A (I - K H)^T + K R K^T = A - (W - K R) K^T`` with ``W = A H^T`` taken from ``A`` as the dense
    product takes it. That is O(n^2 m) instead of the O(n^3) of the dense products, and keeps their rounding:
    an expanded form (``P - K U^T - U K^T + K S K^T``) equal in exact arithmetic lost up to 6e-3 relative and
    turned variances negative on badly scaled covariances (stds from 1e-4 to 1e4, R from 1e-8 to 1), where this order
    and the dense one stay at 1e-15. ``S`` is factored by a Cholesky decomposition (it is symmetric positive
    definite, or the filter has failed). ``U``, ``K`` and ``W`` are held transposed (m x n) so that the inner
    loops run along rows; only each row's non-zero entries of ``H`` enter ``U``, ``S`` and ``W`` (a pose residual's
    rows touch 4 or 9 of 21 states).
    ``wn``: (>= 3, m_max, n_max) scratch for U^T, K^T, (W - K R)^T; ``wm``: (>= 2, m_max, m_max) for S (left holding
    the innovation covariance ``H P H^T + R``) and its Cholesky factor; ``dx``: the correction (n_max,);
    ``cols``: (m_max, n_max + 1) int scratch (each row's non-zero columns). An innovation whose NIS exceeds
    ``gate`` is rejected (``P`` unchanged,
    ``dx`` zero).
    """
    UT, KT, VT = wn[0], wn[1], wn[2]
    S, L = wm[0], wm[1]
    # each row's non-zero columns, ascending: cols[a, 0] of them in cols[a, 1:] (a pose residual's rotation
    # rows touch 4 of 21 states, its position rows 9), so that H's products skip its zeros
    for a in range(m):
        c = 0
        for j in range(n):
            if H[a, j] != 0.0:
                c += 1
                cols[a, c] = j
        cols[a, 0] = c
    for a in range(m):                      # U^T = H P
        for i in range(n):
            UT[a, i] = 0.0
        for c in range(cols[a, 0]):
            j = cols[a, 1 + c]
            h = H[a, j]
            for i in range(n):
                UT[a, i] += h * P[j, i]
    for a in range(m):                      # S = H U + R, symmetrised
        for b in range(a, m):
            s1 = 0.0
            s2 = 0.0
            for c in range(cols[a, 0]):
                j = cols[a, 1 + c]
                s1 += H[a, j] * UT[b, j]
            for c in range(cols[b, 0]):
                j = cols[b, 1 + c]
                s2 += H[b, j] * UT[a, j]
            v = 0.5 * (s1 + s2 + Rm[a, b] + Rm[b, a])
            S[a, b] = v
            S[b, a] = v
    cholesky_into(S, 0, m, L)
    nis = whitened_norm2(L, m, r, 0, dx)    # dx[:m] as scratch
    if nis > gate:      # (a NaN passes and surfaces as a non-finite correction: divergence, not rejection)
        for i in range(n):
            dx[i] = 0.0
        return nis, False
    for a in range(m):                      # K^T = S^-1 U^T: L Y = U^T, then L^T K^T = Y
        inv = 1.0 / L[a, a]
        for i in range(n):
            KT[a, i] = UT[a, i]
        for k in range(a):
            l = L[a, k]
            for i in range(n):
                KT[a, i] -= l * KT[k, i]
        for i in range(n):
            KT[a, i] *= inv
    for a in range(m - 1, -1, -1):
        inv = 1.0 / L[a, a]
        for k in range(a + 1, m):
            l = L[k, a]
            for i in range(n):
                KT[a, i] -= l * KT[k, i]
        for i in range(n):
            KT[a, i] *= inv
    for i in range(n):
        dx[i] = 0.0
    for a in range(m):
        ra = r[a]
        for i in range(n):
            dx[i] += KT[a, i] * ra
    # the Joseph form in its own order, on the structure: A = (I - K H) P = P - K U^T in place, then
    # P+ = A (I - K H)^T + K R K^T = A - (W - K R) K^T with W = A H^T (from A, as the dense product takes it)
    for i in range(n):
        for a in range(m):
            k = KT[a, i]
            for j in range(n):
                P[i, j] -= k * UT[a, j]
    for i in range(n):                      # W^T = H A^T, on each row's non-zero columns; then W^T - (K R)^T
        for a in range(m):
            s = 0.0
            for c in range(cols[a, 0]):
                j = cols[a, 1 + c]
                s += P[i, j] * H[a, j]
            for b in range(m):
                s -= KT[b, i] * Rm[b, a]
            VT[a, i] = s
    for i in range(n):                      # P+ is symmetric: its upper triangle, mirrored
        for b in range(m):
            v = VT[b, i]
            for j in range(i, n):
                P[i, j] -= v * KT[b, j]
        for j in range(i + 1, n):
            P[j, i] = P[i, j]
    return nis, True


@njit(cache=True)
def cholesky_into(S, lo, m, L):
    """``L L^T = S[lo:lo + m, lo:lo + m]`` into the first ``m`` rows of ``L``, in scalars (the innovation
    covariance is symmetric positive definite, or the filter has failed: a non-positive pivot raises)."""
    for a in range(m):
        for b in range(a + 1):
            s = S[lo + a, lo + b]
            for k in range(b):
                s -= L[a, k] * L[b, k]
            if a == b:
                if not s > 0.0:
                    raise np.linalg.LinAlgError("innovation covariance not positive definite")
                L[a, a] = np.sqrt(s)
            else:
                L[a, b] = s / L[b, b]


@njit(cache=True)
def whitened_norm2(L, m, r, lo, y):
    """``|L^-1 r[lo:lo + m]|^2`` by forward substitution (``y``: scratch of ``m``, left holding ``L^-1 r``)."""
    q = 0.0
    for a in range(m):
        s = r[lo + a]
        for k in range(a):
            s -= L[a, k] * y[k]
        y[a] = s / L[a, a]
        q += y[a] * y[a]
    return q


@njit(cache=True)
def block_nis(S, lo, hi, r, L, y):
    """``r_b^T S_bb^-1 r_b`` of the diagonal block ``lo:hi`` of ``S`` and ``r`` (``L`` and ``y``: scratch at
    least (hi - lo) square and long)."""
    cholesky_into(S, lo, hi - lo, L)
    return whitened_norm2(L, hi - lo, r, lo, y)


@njit(cache=True)
def joseph_update_s(P, n, H, r, Rm, gate):
    """:func:`joseph_update` that also returns the innovation covariance ``S = H P H^T + R`` it used."""
    m = H.shape[0]
    wn = np.zeros((3, m, n))
    wm = np.zeros((2, m, m))
    dx = np.zeros(n)
    cols = np.zeros((m, n + 1), np.int64)
    nis, ok = joseph_update_into(P, n, H, m, np.ascontiguousarray(r), Rm, gate, wn, wm, dx, cols)
    return dx, nis, ok, wm[0].copy()


@njit(cache=True)
def joseph_update(P, n, H, r, Rm, gate):
    """Kalman update of an error state; returns ``(dx, nis, accepted)`` and updates ``P`` in place
    (:func:`joseph_update_into` with scratch of its own; ``H``: (m, n)).

    An innovation whose NIS exceeds ``gate`` (a chi-square quantile; ``inf`` = no gating) is rejected:
    ``P`` is left unchanged and ``dx`` is zero.
    """
    dx, nis, ok, _ = joseph_update_s(P, n, H, r, Rm, gate)
    return dx, nis, ok


@njit(cache=True)
def clone_covariance(P, n_core, rows):
    """Stochastic cloning of ``P``: the core's ``rows`` (the pose) copied into the block after the core, with
    their cross-covariances (``P_aug = J P J^T``, ``J`` selecting the rows); returns the clone's size."""
    mc = rows.shape[0]
    for p in range(mc):
        for q in range(n_core):
            v = P[rows[p], q]
            P[n_core + p, q] = v
            P[q, n_core + p] = v
        for q in range(mc):
            P[n_core + p, n_core + q] = P[rows[p], rows[q]]
    return mc


@njit(cache=True)
def reset_attitude_block(P, n, b, dth):
    """``P <- G P G^T`` for ``G`` the identity but ``I - [dth/2]x`` on the 3x3 block at ``b`` (the error-state
    reset of one attitude, Sola eq. 287), as 3-row and 3-column operations: O(n) instead of O(n^3). A symmetric
    ``P`` stays symmetric to the last bit (the clone copies rows, and the Python path columns, of it)."""
    h0, h1, h2 = 0.5 * dth[0], 0.5 * dth[1], 0.5 * dth[2]
    # G = [[1, h2, -h1], [-h2, 1, h0], [h1, -h0, 1]]
    for j in range(n):
        a0, a1, a2 = P[b, j], P[b + 1, j], P[b + 2, j]
        P[b, j] = a0 + h2 * a1 - h1 * a2
        P[b + 1, j] = -h2 * a0 + a1 + h0 * a2
        P[b + 2, j] = h1 * a0 - h0 * a1 + a2
    for i in range(n):
        a0, a1, a2 = P[i, b], P[i, b + 1], P[i, b + 2]
        P[i, b] = a0 + h2 * a1 - h1 * a2
        P[i, b + 1] = -h2 * a0 + a1 + h0 * a2
        P[i, b + 2] = h1 * a0 - h0 * a1 + a2
    for i in range(b, b + 3):       # the 3x3 block itself was formed rows first: mirrored to stay exactly symmetric
        for j in range(b, b + 3):
            if j > i:
                v = 0.5 * (P[i, j] + P[j, i])
                P[i, j] = v
                P[j, i] = v
