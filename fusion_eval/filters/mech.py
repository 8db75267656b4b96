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
def rmul_exp3(R, phi):
    """``R <- R Exp(phi)`` in place, in scalars (a 3x3 ``@`` is a BLAS call, dearer than the product)."""
    th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    if th2 < 1e-16:
        a, b = 1.0, 0.5
    else:
        th = np.sqrt(th2)
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th2
    p0, p1, p2 = phi[0], phi[1], phi[2]
    # Exp(phi) = I + a K + b K^2, K = [phi]x, K^2 = phi phi^T - th2 I
    e00, e11, e22 = 1.0 + b * (p0 * p0 - th2), 1.0 + b * (p1 * p1 - th2), 1.0 + b * (p2 * p2 - th2)
    e01, e10 = -a * p2 + b * p0 * p1, a * p2 + b * p0 * p1
    e02, e20 = a * p1 + b * p0 * p2, -a * p1 + b * p0 * p2
    e12, e21 = -a * p0 + b * p1 * p2, a * p0 + b * p1 * p2
    for i in range(3):
        r0, r1, r2 = R[i, 0], R[i, 1], R[i, 2]
        R[i, 0] = r0 * e00 + r1 * e10 + r2 * e20
        R[i, 1] = r0 * e01 + r1 * e11 + r2 * e21
        R[i, 2] = r0 * e02 + r1 * e12 + r2 * e22


@njit(cache=True)
def mul_tn(A, B):
    """``A^T B`` of two 3x3 matrices, in scalars (a 3x3 ``@`` is a BLAS call, dearer than the product)."""
    C = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            C[i, j] = A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]
    return C


@njit(cache=True)
def log3(R):
    """Rotation vector of a rotation matrix (the inverse of :func:`exp3`), accurate near 0 and pi.

    The angle comes from ``atan2(sin, cos)`` (``arccos`` alone loses half the digits near 0 and pi);
    near pi the axis comes from the symmetric part, whose antisymmetric part vanishes there.
    """
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = 0.5 * np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
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
    # written out in scalars: this runs once per IMU sample, and numpy's 3x3 products (BLAS calls) and
    # small temporaries cost three times the arithmetic
    bg0, bg1, bg2 = x[XBG], x[XBG + 1], x[XBG + 2]
    wa0, wa1, wa2 = w0[0] - bg0, w0[1] - bg1, w0[2] - bg2
    wb0, wb1, wb2 = w1[0] - bg0, w1[1] - bg1, w1[2] - bg2
    # rotation vector of a rate varying linearly over the step: the mean rate plus the coning term
    # (1/12) (wa dt) x (wb dt), which is zero for a fixed rotation axis and keeps slopes taken in
    # turns from tilting the attitude (second order in dt otherwise)
    c = dt * dt / 12.0
    p0 = 0.5 * (wa0 + wb0) * dt + c * (wa1 * wb2 - wa2 * wb1)
    p1 = 0.5 * (wa1 + wb1) * dt + c * (wa2 * wb0 - wa0 * wb2)
    p2 = 0.5 * (wa2 + wb2) * dt + c * (wa0 * wb1 - wa1 * wb0)
    # Rodrigues: E = I + a K + b K^2, K = [phi]x, K^2 = phi phi^T - |phi|^2 I
    th2 = p0 * p0 + p1 * p1 + p2 * p2
    if th2 < 1e-16:
        a, b = 1.0, 0.5
    else:
        th = np.sqrt(th2)
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th2
    E00, E11, E22 = 1.0 - b * (p1 * p1 + p2 * p2), 1.0 - b * (p0 * p0 + p2 * p2), 1.0 - b * (p0 * p0 + p1 * p1)
    E01, E10 = b * p0 * p1 - a * p2, b * p0 * p1 + a * p2
    E02, E20 = b * p0 * p2 + a * p1, b * p0 * p2 - a * p1
    E12, E21 = b * p1 * p2 - a * p0, b * p1 * p2 + a * p0
    fa0, fa1, fa2 = f0[0] - x[XBA], f0[1] - x[XBA + 1], f0[2] - x[XBA + 2]
    fb0, fb1, fb2 = f1[0] - x[XBA], f1[1] - x[XBA + 1], f1[2] - x[XBA + 2]
    # row i of R1 and of the world acceleration read only row i of R0: each row is stepped in place
    for i in range(3):
        r0, r1, r2 = x[XR + 3 * i], x[XR + 3 * i + 1], x[XR + 3 * i + 2]
        n0 = r0 * E00 + r1 * E10 + r2 * E20
        n1 = r0 * E01 + r1 * E11 + r2 * E21
        n2 = r0 * E02 + r1 * E12 + r2 * E22
        x[XR + 3 * i], x[XR + 3 * i + 1], x[XR + 3 * i + 2] = n0, n1, n2
        am = 0.5 * ((r0 * fa0 + r1 * fa1 + r2 * fa2) + (n0 * fb0 + n1 * fb1 + n2 * fb2))
        if i == 2:
            am -= g
        x[XP + i] += x[XV + i] * dt + 0.5 * am * dt * dt
        x[XV + i] += am * dt
