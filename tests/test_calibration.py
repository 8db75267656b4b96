"""Gyro lag estimated from lidar rotation increments, without ground truth."""

from __future__ import annotations

import pytest

import numpy as np
from scipy.spatial.transform import Rotation

from fusion_eval.calibration import estimate_gyro_lag
from fusion_eval.types import ImuSeries, PoseSeries


@pytest.mark.slow
def test_recovers_a_known_lag_on_synthetic_data():
    rng = np.random.default_rng(0)
    t = np.arange(0, 120, 0.1)

    def w_true(tt):  # smooth body rates, mostly yaw
        return np.column_stack([0.02 * np.sin(0.7 * tt), 0.03 * np.sin(0.5 * tt + 1), 0.3 * np.sin(0.2 * tt) + 0.1 * np.sin(1.1 * tt)])

    # attitude by fine integration of the true rates
    tf = np.arange(0, 120 + 1e-9, 0.001)
    R = [Rotation.identity()]
    wf = w_true(tf)
    for i in range(tf.size - 1):
        R.append(R[-1] * Rotation.from_rotvec(0.5 * (wf[i] + wf[i + 1]) * 0.001))
    q = Rotation.concatenate(R[::100]).as_quat()
    lag = 0.06
    gyro = w_true(t - lag) + rng.normal(size=(t.size, 3)) * 1e-3     # the gyro reports the rate of 60 ms ago
    imu = ImuSeries(t_s=t, f_b_mps2=np.zeros((t.size, 3)), w_b_rps=gyro)
    lidar = PoseSeries(t_s=t, p_w_m=np.zeros((t.size, 3)), q_wb_xyzw=q[: t.size])
    est = estimate_gyro_lag(imu, lidar)
    assert abs(est - lag) < 0.005
    # lidar at a third of the IMU rate: the gyro is integrated between lidar frames
    sub = np.zeros(t.size, bool)
    sub[::3] = True
    assert abs(estimate_gyro_lag(imu, lidar.select(sub)) - lag) < 0.005
