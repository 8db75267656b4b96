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
def joseph_update(P, n, H, r, Rm, gate):
    """Kalman update of an error state; returns ``(dx, nis, accepted)`` and updates ``P`` in place.

    An innovation whose NIS exceeds ``gate`` (a chi-square quantile; ``inf`` = no gating) is rejected:
    ``P`` is left unchanged and ``dx`` is zero.
    """
    K, Sinv = gain(P, n, H, Rm)
    nis = r @ (Sinv @ r)
    if nis > gate:      # (a NaN passes and surfaces as a non-finite correction: divergence, not rejection)
        return np.zeros(n), nis, False
    dx = K @ r
    joseph(P, n, K, H, Rm)
    return dx, nis, True
