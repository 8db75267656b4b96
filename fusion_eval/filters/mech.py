"""Pure, compiled (numba) SO(3) kernels and the strapdown mechanization: no filter, no covariance.

Conventions (see :mod:`fusion_eval.so3`): world frame w is local ENU with gravity ``g_w = [0, 0, -g]``;
``R`` is ``R_wb``; IMU samples are specific force ``f_b`` and angular rate ``w_b``; attitude errors are
right perturbations ``R = R_hat Exp(dtheta)``. The state is the flat nominal vector of
:data:`~fusion_eval.filters.layout.NOMINAL`, updated in place.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .layout import NOMINAL

XP, XV, XR, XBA, XBG, XK = (NOMINAL.start(b) for b in ("p", "v", "R", "ba", "bg", "k"))


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
def attitude(x):
    """``R_wb`` of a nominal state vector, as a (3, 3) view."""
    return x[XR:XR + 9].reshape((3, 3))


@njit(cache=True)
def mech_step(x, f0, w0, f1, w1, dt, g):
    """One midpoint strapdown step from IMU sample 0 to sample 1, in place on the nominal vector ``x``.

    Attitude: ``R1 = R0 Exp(((w0 + w1)/2 - bg) dt + (w0 x w1) dt^2 / 12)`` (midpoint rate plus the
    coning correction of a linearly varying rate); acceleration: the mean of the world-frame
    accelerations at both ends, each with its own attitude; position with the second-order term.
    Exact for constant world acceleration; the attitude is exact for a constant body rate.
    """
    R = attitude(x)
    ba = x[XBA:XBA + 3]
    bg = x[XBG:XBG + 3]
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
        x[XP + i] += x[XV + i] * dt + 0.5 * am[i] * dt * dt
        x[XV + i] += am[i] * dt
    R[:, :] = R1
