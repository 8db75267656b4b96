"""Odometer + gyro process model: the wheel speed and the gyro drive the prediction, no accelerometer.

Error state ``[dp, dtheta, dk, dbg]`` (10; ``k`` the odometer scale error) plus a cloned pose
``[dp_c, dtheta_c]`` (6). It fuses the same position and pose observations as the IMU filters (their
canonical Jacobian columns for velocity and accelerometer bias have no counterpart here, so velocity
observations are not offered with this model). Kernels and derivation: ``filters/odo_kernels.py``
and ``docs/odometer_gyro.md``.
"""

from __future__ import annotations

import numpy as np

from ..so3 import exp_so3, log_so3, skew
from . import odo_kernels as ok
from .base import FilterBase
from .kernels import N_CORE
from .state import NominalState


class OdometerGyroKF(FilterBase):
    name = "odometer_gyro"
    n_core = ok.N_ODO
    uses_accelerometer = False

    def __init__(self, x0: NominalState, P0_err: np.ndarray, k_std: float, prm: np.ndarray, oprm: np.ndarray,
                 t: np.ndarray, v_odo: np.ndarray, w_imu: np.ndarray, k0: int):
        self.x = x0.copy()
        n_max = ok.N_ODO + 6
        self.P = np.zeros((n_max, n_max))
        sel = np.r_[0:3, 6:9]                       # canonical dp, dtheta
        self.P[0:6, 0:6] = P0_err[np.ix_(sel, sel)]
        self.P[ok.OK_ID, ok.OK_ID] = k_std ** 2
        self.P[ok.OBG_ID:ok.OBG_ID + 3, ok.OBG_ID:ok.OBG_ID + 3] = P0_err[12:15, 12:15]
        self.n = ok.N_ODO
        self.prm, self.oprm = prm, oprm
        self.imu_t, self.v_odo, self.imu_w = t, v_odo, w_imu
        N = t.size
        self.rec_p, self.rec_v, self.rec_bg = (np.full((N, 3), np.nan) for _ in range(3))
        self.rec_ba = np.zeros((N, 3))
        self.rec_k = np.full(N, np.nan)
        self.rec_R = np.full((N, 3, 3), np.nan)
        self.rec_Pdiag = np.full((N, N_CORE), np.nan)
        self.rec_Ppt = np.full((N, 6, 6), np.nan)
        self.last = np.concatenate([[t[k0], v_odo[k0]], w_imu[k0]])
        self.k_next = k0 + 1
        self.kbox = np.array([x0.k_odo])
        self.clone_p: np.ndarray | None = None
        self.clone_R: np.ndarray | None = None
        self.record(k0)

    def predict_to(self, t_target: float) -> None:
        x = self.x
        self.k_next = ok.odo_predict_to(x.p_w_m, x.R_wb, self.kbox, x.bg_b, self.P, self.n, self.last, self.imu_t,
                                        self.v_odo, self.imu_w, self.k_next, float(t_target), self.prm, self.oprm,
                                        self.rec_p, self.rec_v, self.rec_R, self.rec_bg, self.rec_k, self.rec_Pdiag,
                                        self.rec_Ppt)
        x.k_odo = float(self.kbox[0])
        x.v_w_mps[:] = x.R_wb[:, 0] * (1 - x.k_odo) * self.last[1]

    def D(self) -> np.ndarray:
        D = np.zeros((21, self.n))
        D[0:3, 0:3] = np.eye(3)
        D[6:9, 3:6] = np.eye(3)
        D[12:15, 7:10] = np.eye(3)
        if self.n > ok.N_ODO:
            D[15:21, 10:16] = np.eye(6)
        return D

    def snapshot(self):
        return (self.x.copy(), None if self.clone_p is None else (self.clone_p.copy(), self.clone_R.copy()))

    def boxminus(self, snap) -> np.ndarray:
        x0, c0 = snap
        x = self.x
        d = np.concatenate([x.p_w_m - x0.p_w_m, log_so3(x0.R_wb.T @ x.R_wb), [x.k_odo - x0.k_odo], x.bg_b - x0.bg_b])
        if self.n > ok.N_ODO:
            d = np.concatenate([d, self.clone_p - c0[0], log_so3(c0[1].T @ self.clone_R)])
        return d

    def boxplus_from(self, snap, dx: np.ndarray) -> None:
        x0, c0 = snap
        x = self.x
        x.p_w_m[:] = x0.p_w_m + dx[0:3]
        x.R_wb[:] = x0.R_wb @ exp_so3(dx[3:6])
        x.k_odo = x0.k_odo + float(dx[6])
        self.kbox[0] = x.k_odo
        x.bg_b[:] = x0.bg_b + dx[7:10]
        if self.n > ok.N_ODO:
            self.clone_p = c0[0] + dx[10:13]
            self.clone_R = c0[1] @ exp_so3(dx[13:16])

    def after_correction(self, dx: np.ndarray) -> None:
        G = np.eye(self.n)
        G[3:6, 3:6] -= 0.5 * skew(dx[3:6])
        if self.n > ok.N_ODO:
            G[13:16, 13:16] -= 0.5 * skew(dx[13:16])
        self.P[:self.n, :self.n] = G @ self.P[:self.n, :self.n] @ G.T

    def clone_rows(self) -> np.ndarray:
        return np.r_[0:6]

    def record(self, k: int) -> None:
        x = self.x
        self.rec_p[k], self.rec_R[k], self.rec_bg[k], self.rec_k[k] = x.p_w_m, x.R_wb, x.bg_b, x.k_odo
        self.rec_v[k] = x.R_wb[:, 0] * (1 - x.k_odo) * self.v_odo[k]
        d = np.full(N_CORE, np.nan)
        d[0:3], d[6:9], d[12:15] = np.diag(self.P)[0:3], np.diag(self.P)[3:6], np.diag(self.P)[7:10]
        self.rec_Pdiag[k] = d
        self.rec_Ppt[k] = self.P[0:6, 0:6]

