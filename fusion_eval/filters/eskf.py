"""Error-state Kalman filter for IMU + GNSS + lidar pose fusion (15 states plus an optional pose clone).

Nominal state: ``p_w`` (m), ``v_w`` (m/s), ``R_wb``, accelerometer bias ``ba_b`` (m/s^2), gyro bias
``bg_b`` (rad/s). Error state and its indices: see :mod:`fusion_eval.filters.kernels`.
After each update the error is injected into the nominal state and reset to zero; the reset
Jacobian ``G = I - [dtheta/2]x`` on the attitude blocks (Sola, eq. 287) is applied to P.
"""

from __future__ import annotations

import numpy as np

from ..errors import FilterDivergedError
from ..so3 import exp_so3, log_so3, skew
from . import kernels as kn
from . import propagate as pr
from .base import FilterBase
from .state import NominalState
from .kernels import BA_ID, BG_ID, CLONE_P_ID, CLONE_TH_ID, N_CORE, P_ID, TH_ID, V_ID


_PT = np.r_[P_ID:P_ID + 3, TH_ID:TH_ID + 3]
_PT_ROWS, _PT_COLS = np.ix_(_PT, _PT)


class ErrorStateKF(FilterBase):
    """The ESKF. Holds the nominal state, the error covariance ``P`` and at most one cloned pose.

    Prediction runs in compiled kernels over arrays of IMU samples (:meth:`predict_to`); updates
    take an observation model (:mod:`fusion_eval.filters.observations`) returning the textbook
    ``H, r, R``. The canonical error state of the observation models is this filter's own, so ``D = I``.
    """

    name = "error_state"
    n_core = N_CORE

    def __init__(self, x0: NominalState, P0: np.ndarray, prm: np.ndarray, imu_t: np.ndarray, imu_f: np.ndarray,
                 imu_w: np.ndarray, k0: int):
        self.x = x0.copy()
        self.P = np.zeros((N_CORE + kn.CLONE_SIZE, N_CORE + kn.CLONE_SIZE))
        self.P[:N_CORE, :N_CORE] = P0
        self.n = N_CORE
        self.prm = prm
        self.imu_t, self.imu_f, self.imu_w = imu_t, imu_f, imu_w
        N = imu_t.size
        self.rec_p = np.full((N, 3), np.nan)
        self.rec_v = np.full((N, 3), np.nan)
        self.rec_R = np.full((N, 3, 3), np.nan)
        self.rec_ba = np.full((N, 3), np.nan)
        self.rec_bg = np.full((N, 3), np.nan)
        self.rec_Pdiag = np.full((N, N_CORE), np.nan)
        self.rec_Ppt = np.full((N, 6, 6), np.nan)   # covariance of [dp, dtheta], for NEES
        self.last = np.concatenate([[imu_t[k0]], imu_f[k0], imu_w[k0]])
        self.k_next = k0 + 1
        self.clone_p: np.ndarray | None = None
        self.clone_R: np.ndarray | None = None
        self.record(k0)

    def predict_to(self, t_target: float) -> None:
        """Propagate nominal state and covariance to ``t_target`` (recording at each IMU sample passed)."""
        x = self.x
        self.k_next = pr.predict_to(x.p_w_m, x.v_w_mps, x.R_wb, x.ba_b, x.bg_b, self.P, self.n, self.last,
                                    self.imu_t, self.imu_f, self.imu_w, self.k_next, float(t_target), self.prm,
                                    pr.COV_ERROR_STATE, self.rec_p, self.rec_v, self.rec_R, self.rec_ba, self.rec_bg,
                                    self.rec_Pdiag, self.rec_Ppt, pr.NO_QREF.copy())

    def update(self, model, iterations: int = 1, tol: float = 1e-8) -> float:
        """Joseph-form update, injection and reset; the plain EKF update runs in compiled kernels."""
        if iterations > 1:
            return self.update_iterated(model, iterations, tol)
        H, r, Rm = model(self.x, self.clone_p, self.clone_R)
        n = self.n
        if not (np.isfinite(r).all() and np.isfinite(Rm).all()):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite residual")
        try:
            dx, nis = kn.joseph_update(self.P, n, np.ascontiguousarray(H[:, :n]), r, Rm)
        except np.linalg.LinAlgError as exc:
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: innovation covariance not invertible ({exc})") from None
        if not (np.all(np.isfinite(dx)) and np.isfinite(nis)):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite correction")
        x = self.x
        if self.clone_p is None:
            self.clone_p, self.clone_R = np.zeros(3), np.eye(3)
        kn.inject_reset(x.p_w_m, x.v_w_mps, x.R_wb, x.ba_b, x.bg_b, self.clone_p, self.clone_R, self.P, self.n, dx)
        self._check("non-finite state or negative variance after an update")
        self._record_if_on_sample()
        return float(nis)

    # ---- hooks of the generic (iterated) update --------------------------------------------------
    def D(self) -> np.ndarray:
        return np.eye(N_CORE + kn.CLONE_SIZE)[:, :self.n]

    def snapshot(self):
        return (self.x.copy(), None if self.clone_p is None else (self.clone_p.copy(), self.clone_R.copy()))

    def boxminus(self, snap) -> np.ndarray:
        x0, c0 = snap
        x = self.x
        d = np.concatenate([x.p_w_m - x0.p_w_m, x.v_w_mps - x0.v_w_mps, log_so3(x0.R_wb.T @ x.R_wb),
                            x.ba_b - x0.ba_b, x.bg_b - x0.bg_b])
        if self.n > N_CORE:
            d = np.concatenate([d, self.clone_p - c0[0], log_so3(c0[1].T @ self.clone_R)])
        return d

    def boxplus_from(self, snap, dx: np.ndarray) -> None:
        x0, c0 = snap
        x = self.x
        x.p_w_m[:] = x0.p_w_m + dx[P_ID:P_ID + 3]
        x.v_w_mps[:] = x0.v_w_mps + dx[V_ID:V_ID + 3]
        x.R_wb[:] = x0.R_wb @ exp_so3(dx[TH_ID:TH_ID + 3])
        x.ba_b[:] = x0.ba_b + dx[BA_ID:BA_ID + 3]
        x.bg_b[:] = x0.bg_b + dx[BG_ID:BG_ID + 3]
        if self.n > N_CORE:
            self.clone_p = c0[0] + dx[CLONE_P_ID:CLONE_P_ID + 3]
            self.clone_R = c0[1] @ exp_so3(dx[CLONE_TH_ID:CLONE_TH_ID + 3])

    def after_correction(self, dx: np.ndarray) -> None:
        # ESKF reset: G = I - [dtheta/2]x on each attitude block (Sola, eq. 287)
        G = np.eye(self.n)
        G[TH_ID:TH_ID + 3, TH_ID:TH_ID + 3] -= 0.5 * skew(dx[TH_ID:TH_ID + 3])
        if self.n > N_CORE:
            G[CLONE_TH_ID:CLONE_TH_ID + 3, CLONE_TH_ID:CLONE_TH_ID + 3] -= 0.5 * skew(dx[CLONE_TH_ID:CLONE_TH_ID + 3])
        self.P[:self.n, :self.n] = G @ self.P[:self.n, :self.n] @ G.T

    def clone_rows(self) -> np.ndarray:
        return _PT

    def record(self, k: int) -> None:
        x = self.x
        self.rec_p[k] = x.p_w_m
        self.rec_v[k] = x.v_w_mps
        self.rec_R[k] = x.R_wb
        self.rec_ba[k] = x.ba_b
        self.rec_bg[k] = x.bg_b
        self.rec_Pdiag[k] = self.P.diagonal()[:N_CORE]
        self.rec_Ppt[k] = self.P[_PT_ROWS, _PT_COLS]


def dead_reckon(x0: NominalState, prm: np.ndarray, imu_t, imu_f, imu_w, k0: int) -> tuple[np.ndarray, np.ndarray]:
    """Pure IMU integration from ``x0`` at sample ``k0`` through every later sample; returns positions and attitudes."""
    x = x0.copy()
    N = imu_t.size
    rec_p = np.full((N, 3), np.nan)
    rec_R = np.full((N, 3, 3), np.nan)
    rec_v, rec_ba, rec_bg = (np.empty((N, 3)) for _ in range(3))   # written, not returned
    last = np.concatenate([[imu_t[k0]], imu_f[k0], imu_w[k0]])
    rec_p[k0] = x.p_w_m
    rec_R[k0] = x.R_wb
    P = np.zeros((N_CORE, N_CORE))
    pr.predict_to(x.p_w_m, x.v_w_mps, x.R_wb, x.ba_b, x.bg_b, P, N_CORE, last, imu_t, imu_f, imu_w, k0 + 1,
                  float(imu_t[-1]), prm, pr.COV_NONE, rec_p, rec_v, rec_R, rec_ba, rec_bg, np.zeros((1, N_CORE)),
                  np.zeros((1, 6, 6)), pr.NO_QREF.copy())
    return rec_p, rec_R
