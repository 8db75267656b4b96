"""Compiled kernels of the odometer + gyro process model (no accelerometer).

State: ``p_w``, ``R_wb``, odometer scale error ``k`` (the true forward speed is ``(1 - k) v_odo``), gyro
bias ``bg``. Error state ``[dp(0:3), dtheta(3:6), dk(6), dbg(7:10)]`` plus an optional cloned pose
``[dp_c, dtheta_c]`` (10:16). The vehicle moves along its body x axis (no lateral or vertical slip;
the slip is process noise). Per step (midpoint)::

    R' = R Exp((w - bg) T),   p' = p + (R + R')/2 e1 (1 - k) v T

and the error dynamics ``dp' = dp + T (-R [v_b]x dtheta - R e1 v dk)``, ``dtheta' = (I - [w]x T) dtheta - T dbg``.
See ``docs/odometer_gyro.md``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import PRM_GAP_DT, PRM_GAP_SCALE2, exp3, skew3

OP_ID, OTH_ID, OK_ID, OBG_ID = 0, 3, 6, 7
N_ODO = 10
OC_P_ID, OC_TH_ID = 10, 13

# parameter vector of this model
OPRM_QV, OPRM_QSLIP, OPRM_QG, OPRM_QK, OPRM_QBG = 0, 1, 2, 3, 4
N_OPRM = 5


@njit(cache=True)
def _ostep(p, R, k, bg, P, n, v0, w0, v1, w1, dt, prm, oprm, gap):
    w = 0.5 * (w0 + w1) - bg
    v = 0.5 * (v0 + v1)
    vb = (1.0 - k[0]) * v
    R1 = R @ exp3(w * dt)
    F = np.eye(n)
    e1 = np.array([vb, 0.0, 0.0])
    A = -(R @ skew3(e1)) * dt
    for i in range(3):
        for j in range(3):
            F[OP_ID + i, OTH_ID + j] = A[i, j]
        F[OP_ID + i, OK_ID] = -R[i, 0] * v * dt
    C = np.eye(3) - skew3(w) * dt
    for i in range(3):
        for j in range(3):
            F[OTH_ID + i, OTH_ID + j] = C[i, j]
        F[OTH_ID + i, OBG_ID + i] = -dt
    Pn = np.ascontiguousarray(P[:n, :n])
    newP = F @ Pn @ F.T
    scale = prm[PRM_GAP_SCALE2] if gap else 1.0
    # speed noise along the body x axis, slip across it, both mapped to the world by R
    Qb = np.diag(np.array([oprm[OPRM_QV] ** 2, oprm[OPRM_QSLIP] ** 2, oprm[OPRM_QSLIP] ** 2])) * dt * scale
    newP[OP_ID:OP_ID + 3, OP_ID:OP_ID + 3] += R @ Qb @ R.T
    for i in range(3):
        newP[OTH_ID + i, OTH_ID + i] += oprm[OPRM_QG] ** 2 * dt * scale
        newP[OBG_ID + i, OBG_ID + i] += oprm[OPRM_QBG] ** 2 * dt
    newP[OK_ID, OK_ID] += oprm[OPRM_QK] ** 2 * dt
    for i in range(n):
        for j in range(n):
            P[i, j] = 0.5 * (newP[i, j] + newP[j, i])
    for i in range(3):
        p[i] += 0.5 * (R[i, 0] + R1[i, 0]) * vb * dt
    R[:, :] = R1


@njit(cache=True)
def odo_predict_to(p, R, k, bg, P, n, last, t, v_odo, w_imu, k_next, t_target, prm, oprm,
                   rec_p, rec_v, rec_R, rec_bg, rec_k, rec_Pdiag, rec_Ppt):
    """Propagate through the samples up to ``t_target`` (``last`` = ``[t, v, wx, wy, wz]``).

    The same stepping as :func:`fusion_eval.filters.propagate.predict_to`, kept separate because this
    model's input (a speed and a rate) and state (no velocity, no accelerometer bias) differ."""
    N = t.shape[0]
    v0 = last[1]
    w0 = last[2:5].copy()
    t0 = last[0]
    j = k_next
    while j < N and t[j] <= t_target:
        dt = t[j] - t0
        gap = j > 0 and t[j] - t[j - 1] > prm[PRM_GAP_DT]
        if dt > 0.0:
            _ostep(p, R, k, bg, P, n, v0, w0, v_odo[j], w_imu[j], dt, prm, oprm, gap)
        t0 = t[j]
        v0 = v_odo[j]
        w0 = w_imu[j].copy()
        rec_p[j] = p
        rec_R[j] = R
        rec_v[j] = R[:, 0] * (1.0 - k[0]) * v0
        rec_bg[j] = bg
        rec_k[j] = k[0]
        for i in range(15):
            rec_Pdiag[j, i] = np.nan
        for i in range(3):
            rec_Pdiag[j, i] = P[OP_ID + i, OP_ID + i]
            rec_Pdiag[j, 6 + i] = P[OTH_ID + i, OTH_ID + i]
            rec_Pdiag[j, 12 + i] = P[OBG_ID + i, OBG_ID + i]
            for m in range(3):
                rec_Ppt[j, i, m] = P[OP_ID + i, OP_ID + m]
                rec_Ppt[j, i, 3 + m] = P[OP_ID + i, OTH_ID + m]
                rec_Ppt[j, 3 + i, m] = P[OTH_ID + i, OP_ID + m]
                rec_Ppt[j, 3 + i, 3 + m] = P[OTH_ID + i, OTH_ID + m]
        j += 1
    if t_target > t0 and j < N:
        a = (t_target - t0) / (t[j] - t0)
        v1 = v0 + a * (v_odo[j] - v0)
        w1 = w0 + a * (w_imu[j] - w0)
        gap = j > 0 and t[j] - t[j - 1] > prm[PRM_GAP_DT]
        _ostep(p, R, k, bg, P, n, v0, w0, v1, w1, t_target - t0, prm, oprm, gap)
        t0 = t_target
        v0 = v1
        w0 = w1
    last[0] = t0
    last[1] = v0
    last[2:5] = w0
    return j
