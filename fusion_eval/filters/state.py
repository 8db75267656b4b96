"""The nominal (whole) state shared by the filter formulations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class NominalState:
    """Position ``p_w_m`` and velocity ``v_w_mps`` in the world frame, attitude ``R_wb``, accelerometer and
    gyro biases in the body frame (SI), and the odometer scale error ``k_odo`` (odometer + gyro model)."""

    p_w_m: np.ndarray
    v_w_mps: np.ndarray
    R_wb: np.ndarray
    ba_b: np.ndarray
    bg_b: np.ndarray
    k_odo: float = 0.0

    def copy(self) -> "NominalState":
        return NominalState(self.p_w_m.copy(), self.v_w_mps.copy(), self.R_wb.copy(), self.ba_b.copy(),
                            self.bg_b.copy(), self.k_odo)
