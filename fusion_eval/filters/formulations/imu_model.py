"""The IMU process model's inputs and parameter record, shared by the IMU-driven formulations."""

from __future__ import annotations

import numpy as np

from ..layout import Layout

# IMU input rows: specific force and angular rate in the body frame
IMU_INPUT = Layout("IMU input", [("f", 3), ("w", 3)])
UF, UW = IMU_INPUT.start("f"), IMU_INPUT.start("w")

# The process parameter record (SI): gravity, white-noise densities, bias random walks.
PARAMS = Layout("IMU process parameters", [("g", 1), ("qa", 1), ("qg", 1), ("qba", 1), ("qbg", 1)])
PRM_G, PRM_QA, PRM_QG, PRM_QBA, PRM_QBG = (PARAMS.start(b) for b in ("g", "qa", "qg", "qba", "qbg"))


def imu_params(g: float, accel_noise: float, gyro_noise: float, accel_bias_rw: float, gyro_bias_rw: float) -> np.ndarray:
    """The parameter record: gravity (m/s^2) and the noise densities (SI, per sqrt(Hz))."""
    prm = np.zeros(PARAMS.n)
    prm[PRM_G], prm[PRM_QA], prm[PRM_QG], prm[PRM_QBA], prm[PRM_QBG] = g, accel_noise, gyro_noise, accel_bias_rw, gyro_bias_rw
    return prm


def imu_inputs(f_b: np.ndarray, w_b: np.ndarray) -> np.ndarray:
    """Input rows ``[f_b, w_b]`` (N, 6)."""
    u = np.empty((f_b.shape[0], IMU_INPUT.n))
    u[:, IMU_INPUT.sl("f")], u[:, IMU_INPUT.sl("w")] = f_b, w_b
    return u
