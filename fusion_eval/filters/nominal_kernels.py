"""Compiled kernels of the nominal-state EKF (full state ``x = [p, v, q, ba, bg]``, 16 entries; with a
cloned pose ``[p_c, q_c]`` 23). Quaternions here are Hamilton, ``(w, x, y, z)``, body to world, as in
Sola's "Quaternion kinematics for the error-state Kalman filter"; the rest of the package sees only
rotation matrices and scipy's ``(x, y, z, w)``.

Per IMU step the state is propagated by the same midpoint mechanization as the ESKF (the shared
loop is :func:`fusion_eval.filters.propagate.predict_to`); the covariance by the Jacobian of that map
with respect to the full state (see ``docs/nominal_state.md``)::

    dp'/dq = T^2/2 d(R(q) a)/dq,   dv'/dq = T d(R(q) a)/dq,   d(R(q)a)/dq = 2 [w a + v x a | v.a I + v a^T - a v^T - w [a]x]
    dp'/dba = -T^2/2 R,  dv'/dba = -T R,  dq'/dq = [q{wT}]_R,  dq'/dbg = -T/2 [q]_L [0; I]
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import PRM_GAP_SCALE2, PRM_QA, PRM_QBA, PRM_QBG, PRM_QG, skew3

NP_ID, NV_ID, NQ_ID, NBA_ID, NBG_ID = 0, 3, 6, 10, 13
N_NOM = 16
NC_P_ID, NC_Q_ID = 16, 19
N_NOM_CLONE = 7


@njit(cache=True)
def rot_to_quat(R):
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    q = np.empty(4)
    if tr > 0.0:
        s = np.sqrt(tr + 1.0) * 2.0
        q[0] = 0.25 * s
        q[1] = (R[2, 1] - R[1, 2]) / s
        q[2] = (R[0, 2] - R[2, 0]) / s
        q[3] = (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2.0
        q[0] = (R[2, 1] - R[1, 2]) / s
        q[1] = 0.25 * s
        q[2] = (R[0, 1] + R[1, 0]) / s
        q[3] = (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2.0
        q[0] = (R[0, 2] - R[2, 0]) / s
        q[1] = (R[0, 1] + R[1, 0]) / s
        q[2] = 0.25 * s
        q[3] = (R[1, 2] + R[2, 1]) / s
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2.0
        q[0] = (R[1, 0] - R[0, 1]) / s
        q[1] = (R[0, 2] + R[2, 0]) / s
        q[2] = (R[1, 2] + R[2, 1]) / s
        q[3] = 0.25 * s
    if q[0] < 0.0:
        q = -q
    return q / np.sqrt(q @ q)


@njit(cache=True)
def quat_to_rot(q):
    w, x, y, z = q[0], q[1], q[2], q[3]
    R = np.empty((3, 3))
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)
    return R


@njit(cache=True)
def quat_L(q):
    """[q]_L with q (x) p = [q]_L p."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


@njit(cache=True)
def quat_R(q):
    """[q]_R with p (x) q = [q]_R p."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])


@njit(cache=True)
def xi(q):
    """Xi(q) = [q]_L[:, 1:]: the right perturbation q (x) [1, dtheta/2] adds Xi(q) dtheta / 2."""
    return quat_L(q)[:, 1:4].copy()


@njit(cache=True)
def dRa_dq(q, a):
    """d(R(q) a)/dq, 3x4 (Sola, eq. 174)."""
    w = q[0]
    v = q[1:4]
    out = np.empty((3, 4))
    out[:, 0] = w * a + np.cross(v, a)
    out[:, 1:4] = (v @ a) * np.eye(3) + np.outer(v, a) - np.outer(a, v) - w * skew3(a)
    return 2.0 * out


@njit(cache=True)
def nominal_F_Q(q, a_b, w_b, dt, prm, gap):
    """Jacobian F (16x16) of one mechanization step with respect to the full state, and its Q."""
    R = quat_to_rot(q)
    F = np.eye(N_NOM)
    J = dRa_dq(q, a_b)
    for i in range(3):
        F[NP_ID + i, NV_ID + i] = dt
        for j in range(4):
            F[NP_ID + i, NQ_ID + j] = 0.5 * dt * dt * J[i, j]
            F[NV_ID + i, NQ_ID + j] = dt * J[i, j]
        for j in range(3):
            F[NP_ID + i, NBA_ID + j] = -0.5 * dt * dt * R[i, j]
            F[NV_ID + i, NBA_ID + j] = -dt * R[i, j]
    phi = w_b * dt
    th = np.sqrt(phi @ phi)
    qw = np.empty(4)
    qw[0] = np.cos(0.5 * th)
    if th > 1e-12:
        qw[1:4] = np.sin(0.5 * th) / th * phi
    else:
        qw[1:4] = 0.5 * phi
    F[NQ_ID:NQ_ID + 4, NQ_ID:NQ_ID + 4] = quat_R(qw)
    X = xi(q)
    F[NQ_ID:NQ_ID + 4, NBG_ID:NBG_ID + 3] = -0.5 * dt * X
    scale = prm[PRM_GAP_SCALE2] if gap else 1.0
    Q = np.zeros((N_NOM, N_NOM))
    qa = prm[PRM_QA] ** 2 * dt * scale
    qg = prm[PRM_QG] ** 2 * dt * scale
    for i in range(3):
        Q[NV_ID + i, NV_ID + i] = qa
        Q[NBA_ID + i, NBA_ID + i] = prm[PRM_QBA] ** 2 * dt
        Q[NBG_ID + i, NBG_ID + i] = prm[PRM_QBG] ** 2 * dt
    Q[NQ_ID:NQ_ID + 4, NQ_ID:NQ_ID + 4] = 0.25 * qg * (X @ X.T)
    return F, Q


@njit(cache=True)
def canonical_cov(P, q):
    """The error-state (canonical) variances (15) and [dp, dtheta] covariance (6x6) of a nominal P."""
    D = np.zeros((15, N_NOM))
    for i in range(3):
        D[i, NP_ID + i] = 1.0
        D[3 + i, NV_ID + i] = 1.0
        D[9 + i, NBA_ID + i] = 1.0
        D[12 + i, NBG_ID + i] = 1.0
    D[6:9, NQ_ID:NQ_ID + 4] = 2.0 * xi(q).T
    C = D @ np.ascontiguousarray(P[:N_NOM, :N_NOM]) @ D.T
    diag = np.empty(15)
    for i in range(15):
        diag[i] = C[i, i]
    ppt = np.empty((6, 6))
    idx = np.array([0, 1, 2, 6, 7, 8])
    for i in range(6):
        for j in range(6):
            ppt[i, j] = C[idx[i], idx[j]]
    return diag, ppt


@njit(cache=True)
def aligned_quat(R, qref):
    """The quaternion of R in the hemisphere of ``qref``: P's quaternion block belongs to one sign, so
    the sign must stay continuous (rot_to_quat alone flips it when the heading passes 180 degrees)."""
    q = rot_to_quat(R)
    if q @ qref < 0.0:
        q = -q
    return q


@njit(cache=True)
def nominal_propagate_cov(P, n, q, f_b, w_b, dt, prm, gap):
    """In place ``P <- F P F^T + Q`` for the full state (clone blocks unchanged); ``q`` the quaternion
    at the start of the step in the sign of P, ``f_b``/``w_b`` the bias-corrected midpoint IMU values."""
    F, Q = nominal_F_Q(q, f_b, w_b, dt, prm, gap)
    Pn = np.ascontiguousarray(P[:n, :n])
    Fa = np.eye(n)
    Fa[:N_NOM, :N_NOM] = F
    newP = Fa @ Pn @ Fa.T
    newP[:N_NOM, :N_NOM] += Q
    for i in range(n):
        for j in range(n):
            P[i, j] = 0.5 * (newP[i, j] + newP[j, i])
