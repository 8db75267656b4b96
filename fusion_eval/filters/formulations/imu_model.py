"""The IMU process model's inputs and parameter record, shared by the IMU-driven formulations."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...errors import ConfigError
from ..discretize import METHODS
from ..mech import XBA, XBG
from ..layout import Layout

# IMU input rows: specific force and angular rate in the body frame
IMU_INPUT = Layout("IMU input", [("f", 3), ("w", 3)])
UF, UW = IMU_INPUT.start("f"), IMU_INPUT.start("w")

# The process parameter record (SI): gravity, white-noise densities, bias driving noises, the discretisation,
# and the bias decay rates 1/tau of a first-order Gauss-Markov bias (0 = random walk).
PARAMS = Layout("IMU process parameters", [("g", 1), ("qa", 1), ("qg", 1), ("qba", 1), ("qbg", 1), ("disc", 1),
                                           ("kba", 1), ("kbg", 1)])
PRM_G, PRM_QA, PRM_QG, PRM_QBA, PRM_QBG, PRM_DISC, PRM_KBA, PRM_KBG = (
    PARAMS.start(b) for b in ("g", "qa", "qg", "qba", "qbg", "disc", "kba", "kbg"))


def imu_params(g: float, accel_noise: float, gyro_noise: float, accel_bias_rw: float, gyro_bias_rw: float,
               discretization: str = "first_order", accel_bias_decay: float = 0.0, gyro_bias_decay: float = 0.0
               ) -> np.ndarray:
    """The parameter record: gravity (m/s^2), the noise densities (SI, per sqrt(Hz)), the discretisation of
    the error dynamics (:data:`fusion_eval.filters.discretize.METHODS`; the nominal-state EKF takes its process
    noise from it, its transition being its own step's Jacobian) and the bias decay rates (1/s, Gauss-Markov)."""
    if discretization not in METHODS:
        raise ConfigError(f"filter.discretization={discretization!r} is not resolved: 'auto' is chosen from the IMU "
                          "rate when a run is prepared (prepare.settings_for); give one of " + ", ".join(METHODS))
    return PARAMS.pack(g=g, qa=accel_noise, qg=gyro_noise, qba=accel_bias_rw, qbg=gyro_bias_rw,
                       disc=METHODS[discretization], kba=accel_bias_decay, kbg=gyro_bias_decay)


def imu_inputs(f_b: np.ndarray, w_b: np.ndarray) -> np.ndarray:
    """Input rows ``[f_b, w_b]`` (N, 6)."""
    return IMU_INPUT.columns(f=f_b, w=w_b)


@njit(cache=True)
def decay_biases(x, dt, prm):
    """The mean of a Gauss-Markov bias decays toward zero, ``E[b(t + dt) | b(t)] = exp(-dt / tau) b(t)``
    (in place on the nominal vector; nothing for a random walk or a constant bias)."""
    if prm[PRM_KBA] > 0.0 or prm[PRM_KBG] > 0.0:
        da, dg = np.exp(-prm[PRM_KBA] * dt), np.exp(-prm[PRM_KBG] * dt)
        for i in range(3):
            x[XBA + i] *= da
            x[XBG + i] *= dg


def run_params(s, gravity_mps2: float) -> np.ndarray:
    """The parameter record of a run's SI settings ``s``: noise densities, bias model, discretisation."""
    from ...errors import ConfigError
    from .base import bias_decays, bias_walks

    if "auto" in (s.imu.accel_noise_mps2_sqrthz, s.imu.gyro_noise_rps_sqrthz):
        raise ConfigError("imu noise 'auto' is estimated from the data by prepare(): build the settings with "
                          "fusion_eval.prepare.settings_for(cfg, prepared)")
    qba, qbg = bias_walks(s)
    return imu_params(gravity_mps2, s.imu.accel_noise_mps2_sqrthz, s.imu.gyro_noise_rps_sqrthz, qba, qbg,
                      s.filter.discretization, *bias_decays(s))
