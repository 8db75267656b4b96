"""The one loop over IMU samples that every IMU-driven filter uses (compiled).

It steps the strapdown mechanization from the sample the state sits at through every IMU sample up to
a target time, then to the target itself with the IMU interpolated there (so an observation is
applied at its own time), and records the state at each sample passed. ``mode`` selects what
happens to the covariance: nothing (dead reckoning), the error state's ``F P F^T + Q``
(:func:`fusion_eval.filters.kernels.propagate_cov`) or the full state's
(:func:`fusion_eval.filters.nominal_kernels.nominal_propagate_cov`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import N_CORE, P_ID, PRM_G, PRM_GAP_DT, TH_ID, mech_step, propagate_cov
from .nominal_kernels import aligned_quat, canonical_cov, nominal_propagate_cov

COV_NONE, COV_ERROR_STATE, COV_NOMINAL = 0, 1, 2


@njit(cache=True)
def _step(p, v, R, ba, bg, P, n, f0, w0, f1, w1, dt, prm, mode, gap, qref):
    if mode != COV_NONE:
        # linearise at the start-of-interval attitude and the midpoint, bias-corrected IMU values
        fm = 0.5 * (f0 + f1) - ba
        wm = 0.5 * (w0 + w1) - bg
        if mode == COV_ERROR_STATE:
            propagate_cov(P, n, R, fm, wm, dt, prm, gap)
        else:
            nominal_propagate_cov(P, n, aligned_quat(R, qref), fm, wm, dt, prm, gap)
    mech_step(p, v, R, ba, bg, f0, w0, f1, w1, dt, prm[PRM_G])
    if mode == COV_NOMINAL:
        qref[:] = aligned_quat(R, qref)


@njit(cache=True)
def _record(k, p, v, R, ba, bg, P, mode, qref, rec_p, rec_v, rec_R, rec_ba, rec_bg, rec_Pdiag, rec_Ppt):
    rec_p[k] = p
    rec_v[k] = v
    rec_R[k] = R
    rec_ba[k] = ba
    rec_bg[k] = bg
    if mode == COV_ERROR_STATE:
        for i in range(N_CORE):
            rec_Pdiag[k, i] = P[i, i]
        for i in range(3):
            for j in range(3):
                rec_Ppt[k, i, j] = P[P_ID + i, P_ID + j]
                rec_Ppt[k, i, 3 + j] = P[P_ID + i, TH_ID + j]
                rec_Ppt[k, 3 + i, j] = P[TH_ID + i, P_ID + j]
                rec_Ppt[k, 3 + i, 3 + j] = P[TH_ID + i, TH_ID + j]
    elif mode == COV_NOMINAL:
        d, ppt = canonical_cov(P, qref)
        rec_Pdiag[k] = d
        rec_Ppt[k] = ppt


@njit(cache=True)
def predict_to(p, v, R, ba, bg, P, n, last, imu_t, imu_f, imu_w, k_next, t_target, prm, mode,
               rec_p, rec_v, rec_R, rec_ba, rec_bg, rec_Pdiag, rec_Ppt, qref):
    """Propagate through every IMU sample up to ``t_target`` and then to ``t_target`` itself.

    ``last`` (7,) holds the IMU sample the state currently sits at: ``[t, fx, fy, fz, wx, wy, wz]``.
    Samples ``k_next, k_next+1, ...`` with stamps ``<= t_target`` are integrated one by one and the
    state at each is recorded at index k (``rec_Pdiag`` the error-state variances, ``rec_Ppt`` the
    6x6 covariance of ``[dp, dtheta]``, for NEES). If ``t_target`` falls between two samples, the
    IMU is linearly interpolated there and ``last`` becomes that interpolated sample. ``qref`` is the
    sign reference of the nominal filter's quaternion (unused otherwise). Returns the new ``k_next``.
    """
    N = imu_t.shape[0]
    f0 = last[1:4].copy()
    w0 = last[4:7].copy()
    t0 = last[0]
    k = k_next
    while k < N and imu_t[k] <= t_target:
        dt = imu_t[k] - t0
        # a gap is a long interval between two IMU samples, however an observation splits it
        gap = k > 0 and imu_t[k] - imu_t[k - 1] > prm[PRM_GAP_DT]
        if dt > 0.0:
            _step(p, v, R, ba, bg, P, n, f0, w0, imu_f[k], imu_w[k], dt, prm, mode, gap, qref)
        t0 = imu_t[k]
        f0 = imu_f[k].copy()
        w0 = imu_w[k].copy()
        _record(k, p, v, R, ba, bg, P, mode, qref, rec_p, rec_v, rec_R, rec_ba, rec_bg, rec_Pdiag, rec_Ppt)
        k += 1
    if t_target > t0 and k < N:
        a = (t_target - t0) / (imu_t[k] - t0)
        f1 = f0 + a * (imu_f[k] - f0)
        w1 = w0 + a * (imu_w[k] - w0)
        gap = k > 0 and imu_t[k] - imu_t[k - 1] > prm[PRM_GAP_DT]
        _step(p, v, R, ba, bg, P, n, f0, w0, f1, w1, t_target - t0, prm, mode, gap, qref)
        t0 = t_target
        f0 = f1
        w0 = w1
    last[0] = t0
    last[1:4] = f0
    last[4:7] = w0
    return k


NO_QREF = np.array([1.0, 0.0, 0.0, 0.0])
