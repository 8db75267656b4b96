"""Compiled (numba) kernels for the per-IMU-sample work: mechanization and covariance propagation.

Conventions (see :mod:`fusion_eval.so3`): world frame w is local ENU with gravity ``g_w = [0, 0, -g]``;
``R`` is ``R_wb``; IMU samples are specific force ``f_b`` and angular rate ``w_b``; the attitude error
is a right perturbation ``R = R_hat Exp(dtheta)``.

Error state, named indices as in KF-GINS: ``[dp(P_ID), dv(V_ID), dtheta(TH_ID), dba(BA_ID), dbg(BG_ID)]``
(15 states), optionally followed by cloned poses ``[dp_c, dtheta_c]`` (6 each) that the prediction
leaves unchanged.

Continuous error dynamics (the classic IMU + lidar ESKF derivation)::

    dp'  = dv
    dv'  = -R [f - ba]x dtheta - R dba + R n_a
    dth' = -[w - bg]x dtheta   - dbg  + n_g
    dba' = n_ba,   dbg' = n_bg          (random walk; zero for the constant-bias model)

discretised as ``F = I + F_t T`` and ``Q_d = B Q B^T`` with B as in that derivation: ``R T`` and ``I T``
on the white noises, ``I sqrt(T)`` on the bias random walks, Q the discrete variances. With noise
densities ``sigma`` (per sqrt(Hz)) both give ``sigma^2 T`` per axis, and since ``R R^T = I`` the
discrete process noise is diagonal; :func:`propagate_cov` uses that and the sparsity of F to do
``F P F^T + Q`` in O(n) 3x3 products instead of a dense O(n^3) product.
"""

from __future__ import annotations

import numpy as np
from numba import njit

P_ID, V_ID, TH_ID, BA_ID, BG_ID = 0, 3, 6, 9, 12
N_CORE = 15
CLONE_P_ID, CLONE_TH_ID = 15, 18   # offsets of the first clone
CLONE_SIZE = 6

# Layout of the parameter vector passed to the kernels.
PRM_G, PRM_QA, PRM_QG, PRM_QBA, PRM_QBG, PRM_GAP_DT, PRM_GAP_SCALE2 = range(7)
N_PRM = 7


@njit(cache=True, fastmath=False)
def skew3(v):
    S = np.zeros((3, 3))
    S[0, 1] = -v[2]
    S[0, 2] = v[1]
    S[1, 0] = v[2]
    S[1, 2] = -v[0]
    S[2, 0] = -v[1]
    S[2, 1] = v[0]
    return S


@njit(cache=True)
def exp3(phi):
    """Rodrigues' formula, with the second-order series near zero."""
    th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    K = skew3(phi)
    if th2 < 1e-16:
        return np.eye(3) + K + 0.5 * (K @ K)
    th = np.sqrt(th2)
    return np.eye(3) + (np.sin(th) / th) * K + ((1.0 - np.cos(th)) / th2) * (K @ K)


@njit(cache=True)
def mech_step(p, v, R, ba, bg, f0, w0, f1, w1, dt, g):
    """One midpoint strapdown step from IMU sample 0 to sample 1 (in place on p, v, R).

    Attitude: ``R1 = R0 Exp(((w0 + w1)/2 - bg) dt + (w0 x w1) dt^2 / 12)`` (midpoint rate plus the
    coning correction of a linearly varying rate); acceleration: the mean of the world-frame
    accelerations at both ends, each with its own attitude; position with the second-order term.
    Exact for constant world acceleration; the attitude is exact for a constant body rate.
    """
    wa = w0 - bg
    wb = w1 - bg
    # rotation vector of a rate varying linearly over the step: the mean rate plus the coning term
    # (1/12) (wa dt) x (wb dt), which is zero for a fixed rotation axis and keeps slopes taken in
    # turns from tilting the attitude (second order in dt otherwise)
    phi = 0.5 * (wa + wb) * dt + (dt * dt / 12.0) * np.cross(wa, wb)
    R1 = R @ exp3(phi)
    a0 = R @ (f0 - ba)
    a1 = R1 @ (f1 - ba)
    am = 0.5 * (a0 + a1)
    am[2] -= g
    for i in range(3):
        p[i] += v[i] * dt + 0.5 * am[i] * dt * dt
        v[i] += am[i] * dt
    R[:, :] = R1


@njit(cache=True)
def propagate_cov(P, n, R, f_b, w_b, dt, prm, gap):
    """In place ``P <- F P F^T + Q`` for the error state, exploiting the sparsity of F.

    ``R``, ``f_b`` and ``w_b`` are the attitude and the bias-corrected IMU values the step was
    linearised at; ``n`` is the number of states (15 + 6 per clone).
    """
    A = -(R @ skew3(f_b)) * dt          # dv/dtheta
    B = -R * dt                         # dv/dba
    C = -skew3(w_b) * dt                # dtheta/dtheta (minus identity)
    M = P[:n, :n].copy()
    # rows: M = F P
    for j in range(n):
        for i in range(3):
            M[P_ID + i, j] = P[P_ID + i, j] + dt * P[V_ID + i, j]
            s = P[V_ID + i, j]
            t = P[TH_ID + i, j] - dt * P[BG_ID + i, j]
            for k in range(3):
                s += A[i, k] * P[TH_ID + k, j] + B[i, k] * P[BA_ID + k, j]
                t += C[i, k] * P[TH_ID + k, j]
            M[V_ID + i, j] = s
            M[TH_ID + i, j] = t
    # columns: P = M F^T
    for i in range(n):
        for j in range(3):
            P[i, P_ID + j] = M[i, P_ID + j] + dt * M[i, V_ID + j]
            s = M[i, V_ID + j]
            t = M[i, TH_ID + j] - dt * M[i, BG_ID + j]
            for k in range(3):
                s += M[i, TH_ID + k] * A[j, k] + M[i, BA_ID + k] * B[j, k]
                t += M[i, TH_ID + k] * C[j, k]
            P[i, V_ID + j] = s
            P[i, TH_ID + j] = t
        for j in range(9, n):
            P[i, j] = M[i, j]
    scale = prm[PRM_GAP_SCALE2] if gap else 1.0
    qa = prm[PRM_QA] * prm[PRM_QA] * dt * scale
    qg = prm[PRM_QG] * prm[PRM_QG] * dt * scale
    qba = prm[PRM_QBA] * prm[PRM_QBA] * dt
    qbg = prm[PRM_QBG] * prm[PRM_QBG] * dt
    for i in range(3):
        P[V_ID + i, V_ID + i] += qa
        P[TH_ID + i, TH_ID + i] += qg
        P[BA_ID + i, BA_ID + i] += qba
        P[BG_ID + i, BG_ID + i] += qbg
    # keep P symmetric against rounding
    for i in range(n):
        for j in range(i + 1, n):
            s = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = s
            P[j, i] = s


@njit(cache=True)
def joseph_update(P, n, H, r, Rm):
    """Kalman update of the error state; returns ``(dx, nis)`` and updates ``P`` in place.

    The Joseph form ``(I - K H) P (I - K H)^T + K R K^T`` keeps P symmetric positive
    semi-definite under rounding, and stays correct for the suboptimal gains that gating or
    clipping would give, where ``(I - K H) P`` does not.
    """
    Pn = np.ascontiguousarray(P[:n, :n])
    PHt = Pn @ np.ascontiguousarray(H.T)
    S = H @ PHt + Rm
    S = 0.5 * (S + S.T)
    Sinv = np.linalg.inv(S)
    K = PHt @ Sinv
    dx = K @ r
    nis = r @ (Sinv @ r)
    IKH = np.eye(n) - K @ H
    newP = IKH @ Pn @ np.ascontiguousarray(IKH.T) + K @ Rm @ np.ascontiguousarray(K.T)
    for i in range(n):
        for j in range(n):
            P[i, j] = 0.5 * (newP[i, j] + newP[j, i])
    return dx, nis


@njit(cache=True)
def log3(R):
    """Rotation vector of a rotation matrix (the inverse of :func:`exp3`), accurate near 0 and pi.

    The angle comes from ``atan2(sin, cos)`` (``arccos`` alone loses half the digits near 0 and pi);
    near pi the axis comes from the symmetric part, whose antisymmetric part vanishes there.
    """
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = 0.5 * np.sqrt(w @ w)
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    th = np.arctan2(s, c)
    if th < 1e-6:
        return 0.5 * w * (1.0 + th * th / 6.0)   # th / sin(th) ~ 1 + th^2/6
    if np.pi - th > 1e-3:
        return (0.5 * th / s) * w
    # (R + R^T)/2 - c I = (1 - c) a a^T
    k = 0
    for i in range(1, 3):
        if R[i, i] > R[k, k]:
            k = i
    a = np.empty(3)
    for i in range(3):
        a[i] = 0.5 * (R[i, k] + R[k, i])
    a[k] = R[k, k] - c
    a = a / np.sqrt(a @ a)
    if w @ a < 0.0:
        a = -a
    return th * a


@njit(cache=True)
def inject_reset(p, v, R, ba, bg, clone_p, clone_R, P, n, dx):
    """Inject the error ``dx`` into the nominal state (and clone), then reset: ``P <- G P G^T``
    with ``G = I - [dtheta/2]x`` on each attitude block (Sola, eq. 287)."""
    for i in range(3):
        p[i] += dx[P_ID + i]
        v[i] += dx[V_ID + i]
        ba[i] += dx[BA_ID + i]
        bg[i] += dx[BG_ID + i]
    R[:, :] = R @ exp3(dx[TH_ID:TH_ID + 3])
    G = np.eye(n)
    G[TH_ID:TH_ID + 3, TH_ID:TH_ID + 3] -= 0.5 * skew3(dx[TH_ID:TH_ID + 3])
    if n > N_CORE:
        for i in range(3):
            clone_p[i] += dx[CLONE_P_ID + i]
        clone_R[:, :] = clone_R @ exp3(dx[CLONE_TH_ID:CLONE_TH_ID + 3])
        G[CLONE_TH_ID:CLONE_TH_ID + 3, CLONE_TH_ID:CLONE_TH_ID + 3] -= 0.5 * skew3(dx[CLONE_TH_ID:CLONE_TH_ID + 3])
    Pn = np.ascontiguousarray(P[:n, :n])
    newP = G @ Pn @ G.T
    P[:n, :n] = newP
