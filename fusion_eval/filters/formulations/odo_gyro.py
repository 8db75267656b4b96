"""Odometer + gyro process model: the wheel speed and the gyro drive the prediction, no accelerometer.

State: ``p_w``, ``R_wb``, odometer scale error ``k`` (the true forward speed is ``(1 - k) v_odo``), gyro
bias ``bg``. Error state ``[dp, dtheta, dk, dbg]`` (:data:`LAYOUT`) plus an optional cloned pose
``[dp_c, dtheta_c]``. The vehicle moves along the direction of travel ``c`` in the IMU frame, the IMU's x axis
turned by ``filter.nhc_travel_yaw_mrad`` to the left (the yaw the constraint and the odometer observation share: a
robot's ``imu_link`` yawed 90 deg from ``base_link`` drives along its y axis), with no slip across it (the slip is
process noise). Per step (midpoint)::

    R' = R Exp((w - bg) T),   p' = p + (R + R')/2 c (1 - k) v T

and the error dynamics ``dp' = dp + T (-R [v_b]x dtheta - R c v dk)``, ``dtheta' = (I - [w]x T) dtheta - T dbg``,
``v_b = c (1 - k) v``.
It fuses the same position and pose observations as the IMU filters; it has no velocity or accelerometer
bias state (its velocity is the odometer's, ``R c (1 - k) v``, kept in the nominal vector for reports),
so velocity observations are refused with it. Derivation: ``docs/odometer_gyro.md``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..layout import Layout
from ..linalg import symmetrize_into
from ..mech import XBG, XK, XP, XV, attitude, exp3, skew3
from ..propagate import LAST_U, compiled_loop, record_cov_by_index
from ...spec import S
from .base import ErrorStateBase, bias_walks

LAYOUT = Layout("odometer + gyro", [("P", 3), ("TH", 3), ("K", 1), ("BG", 3)], clone=[("CP", 3), ("CTH", 3)],
                clone_of={"CP": "P", "CTH": "TH"})
OP_ID, OTH_ID, OK_ID, OBG_ID = (LAYOUT.start(b) for b in ("P", "TH", "K", "BG"))
PAIRS = (("P", "P"), ("TH", "TH"), ("BG", "BG"), ("CP", "CP"), ("CTH", "CTH"))

ODO_INPUT = Layout("odometer + gyro input", [("v", 1), ("w", 3)])
UV, UW = ODO_INPUT.start("v"), ODO_INPUT.start("w")

PARAMS = Layout("odometer + gyro process parameters", [("qv", 1), ("qslip", 1), ("qg", 1), ("qk", 1), ("qbg", 1),
                                                      ("c", 2)])
PRM_QV, PRM_QSLIP, PRM_QG, PRM_QK, PRM_QBG, PRM_C = (PARAMS.start(b) for b in ("qv", "qslip", "qg", "qk", "qbg", "c"))


def odo_params(speed_noise: float, slip_noise: float, gyro_noise: float, scale_rw: float, gyro_bias_rw: float,
               travel_yaw_rad: float = 0.0) -> np.ndarray:
    """The step's parameters; ``travel_yaw_rad``: the direction of travel to the left of the IMU's x axis (its
    cosine and sine are kept: ``c = (cos, sin, 0)``, exactly ``e1`` at zero)."""
    return PARAMS.pack(qv=speed_noise, qslip=slip_noise, qg=gyro_noise, qk=scale_rw, qbg=gyro_bias_rw,
                       c=[np.cos(travel_yaw_rad), np.sin(travel_yaw_rad)])


def odo_inputs(v_odo: np.ndarray, w_b: np.ndarray) -> np.ndarray:
    return ODO_INPUT.columns(v=v_odo, w=w_b)


@njit(cache=True)
def step(x, P, n, u0, u1, dt, qscale, prm, aux, cov):
    R = attitude(x)
    k = x[XK]
    w = 0.5 * (u0[UW:UW + 3] + u1[UW:UW + 3]) - x[XBG:XBG + 3]
    v = 0.5 * (u0[UV] + u1[UV])
    vb = (1.0 - k) * v
    cx, cy = prm[PRM_C], prm[PRM_C + 1]              # the direction of travel in the IMU frame (x-y plane)
    R1 = R @ exp3(w * dt)
    if cov:
        F = np.eye(n)
        A = -(R @ skew3(np.array([cx * vb, cy * vb, 0.0]))) * dt
        for i in range(3):
            for j in range(3):
                F[OP_ID + i, OTH_ID + j] = A[i, j]
            F[OP_ID + i, OK_ID] = -(R[i, 0] * cx + R[i, 1] * cy) * v * dt
        C = np.eye(3) - skew3(w) * dt
        for i in range(3):
            for j in range(3):
                F[OTH_ID + i, OTH_ID + j] = C[i, j]
            F[OTH_ID + i, OBG_ID + i] = -dt
        Pn = np.ascontiguousarray(P[:n, :n])
        newP = F @ Pn @ F.T
        # speed noise along the direction of travel, slip across it, both mapped to the world by R (diag(qv^2,
        # qslip^2, qslip^2) exactly when c = e1)
        c = np.array([cx, cy, 0.0])
        cc = np.outer(c, c)
        Qb = (prm[PRM_QV] ** 2 * cc + prm[PRM_QSLIP] ** 2 * (np.eye(3) - cc)) * dt * qscale
        newP[OP_ID:OP_ID + 3, OP_ID:OP_ID + 3] += R @ Qb @ R.T
        for i in range(3):
            newP[OTH_ID + i, OTH_ID + i] += prm[PRM_QG] ** 2 * dt * qscale
            newP[OBG_ID + i, OBG_ID + i] += prm[PRM_QBG] ** 2 * dt
        newP[OK_ID, OK_ID] += prm[PRM_QK] ** 2 * dt
        symmetrize_into(P, n, newP)
    for i in range(3):
        x[XP + i] += 0.5 * ((R[i, 0] + R1[i, 0]) * cx + (R[i, 1] + R1[i, 1]) * cy) * vb * dt
    R[:, :] = R1
    for i in range(3):
        x[XV + i] = (R1[i, 0] * cx + R1[i, 1] * cy) * (1.0 - k) * u1[UV]


predict_to = compiled_loop(__name__, step, record_cov_by_index)


class OdometerGyroKF(ErrorStateBase):
    name = "error_state"
    process_model = "odometer_gyro"
    discretizations = ("first_order",)        # its step is F = I + F_t T; 'auto' took van_loan in the report only
    label = "odometer + gyro (wheel speed and gyro drive the prediction; error state [dp, dtheta, dk, dbg])"
    layout = LAYOUT
    pairs = PAIRS
    targets = {"P": "p", "TH": "R", "K": "k", "BG": "bg", "CP": "clone.p", "CTH": "clone.R"}
    _step = staticmethod(step)
    _predict = staticmethod(predict_to)
    _record_cov = staticmethod(record_cov_by_index)

    def odometer_scale(self, rec_x: np.ndarray) -> np.ndarray:
        return rec_x[:, XK].copy()

    def after_correction_state(self) -> None:
        # the velocity is derived, not a state: the odometer's speed along the corrected heading and scale
        x = self.x
        c = self.arrays.prm[PRM_C:PRM_C + 2]
        x.v_w_mps[:] = (x.R_wb[:, 0] * c[0] + x.R_wb[:, 1] * c[1]) * (1 - x.k_odo) * self.arrays.last[LAST_U + UV]

    keys = {
        "odometer.speed_noise_mps_sqrthz": S(0.05, "odometer + gyro model: speed noise density, m/s/sqrt(Hz)", positive=True, reads="filter"),
        "odometer.slip_noise_mps_sqrthz": S(0.05, "odometer + gyro model: lateral/vertical slip noise density, m/s/sqrt(Hz)",
                                            positive=True, reads="filter"),
        "odometer.scale_rw_per_sqrts": S(1e-5, "odometer + gyro model: random walk of the scale error, 1/sqrt(s)", nonneg=True, reads="filter"),
        "init.odometer_scale_std": S(0.01, "initial std of the odometer scale error (odometer + gyro model)", nonneg=True, reads="filter"),
    }
    streams = ("odometer",)

    @classmethod
    def run_inputs(cls, run) -> np.ndarray:
        # the speed that drives the prediction, on the gyro's stamps
        t = run.imu.t_s
        return odo_inputs(np.interp(t, run.odometer.t_s, run.odometer.v_mps), run.imu.w_b_rps)

    @classmethod
    def run_params(cls, s, gravity_mps2: float) -> np.ndarray:
        o = s.odometer
        return odo_params(o.speed_noise_mps_sqrthz, o.slip_noise_mps_sqrthz, s.imu.gyro_noise_rps_sqrthz,
                          o.scale_rw_per_sqrts, bias_walks(s)[1], s.filter.nhc_travel_yaw_mrad * 1e-3)

    @classmethod
    def run_extra_var(cls, s) -> dict[str, float]:
        return {"K": s.init.odometer_scale_std ** 2}
