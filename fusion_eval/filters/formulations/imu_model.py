"""The IMU process model's inputs and parameter record, shared by the IMU-driven formulations."""

from __future__ import annotations

import numpy as np

from ..discretize import METHODS
from ..layout import Layout

# IMU input rows: specific force and angular rate in the body frame
IMU_INPUT = Layout("IMU input", [("f", 3), ("w", 3)])
UF, UW = IMU_INPUT.start("f"), IMU_INPUT.start("w")

# The process parameter record (SI): gravity, white-noise densities, bias random walks.
PARAMS = Layout("IMU process parameters", [("g", 1), ("qa", 1), ("qg", 1), ("qba", 1), ("qbg", 1), ("disc", 1)])
PRM_G, PRM_QA, PRM_QG, PRM_QBA, PRM_QBG, PRM_DISC = (PARAMS.start(b) for b in ("g", "qa", "qg", "qba", "qbg", "disc"))


def imu_params(g: float, accel_noise: float, gyro_noise: float, accel_bias_rw: float, gyro_bias_rw: float,
               discretization: str = "first_order") -> np.ndarray:
    """The parameter record: gravity (m/s^2), the noise densities (SI, per sqrt(Hz)) and the discretisation of
    the error dynamics (:data:`fusion_eval.filters.discretize.METHODS`; formulations that linearise their own
    discrete step, like the nominal-state EKF, ignore it)."""
    return PARAMS.pack(g=g, qa=accel_noise, qg=gyro_noise, qba=accel_bias_rw, qbg=gyro_bias_rw,
                       disc=METHODS[discretization])


def imu_inputs(f_b: np.ndarray, w_b: np.ndarray) -> np.ndarray:
    """Input rows ``[f_b, w_b]`` (N, 6)."""
    return IMU_INPUT.columns(f=f_b, w=w_b)
