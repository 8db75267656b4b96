"""Estimates that need no ground truth: the gyro's time lag against the lidar odometry.

The OXTS angular rates of KITTI lag the attitude (and the lidar's rotation increments) by about
60 ms. The lag is found by comparing, for a grid of candidate lags, the rotation the gyro integrates
between consecutive IMU samples with the rotation increment of the lidar odometry resampled on the
same stamps, and taking the lag that minimises the mean squared residual (refined by a parabola
through the best grid point and its neighbours).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import DataRangeError
from .types import ImuSeries, PoseSeries


def gyro_lag_cost(imu: ImuSeries, lidar_on_imu: PoseSeries, lags_s: np.ndarray) -> np.ndarray:
    """Mean squared rotation residual (rad^2) between gyro and lidar increments for each candidate lag.

    ``lidar_on_imu`` holds poses on IMU stamps; the gyro is integrated (midpoint steps) over the IMU
    samples between each pair of consecutive lidar poses.
    """
    k = np.flatnonzero(np.isin(imu.t_s, lidar_on_imu.t_s))
    if k.size < 20:
        raise DataRangeError("too few lidar poses on the IMU stamps to estimate the gyro lag")
    j = np.searchsorted(lidar_on_imu.t_s, imu.t_s[k])
    Rl = Rotation.from_quat(lidar_on_imu.q_wb_xyzw[j])
    dR_lidar = Rl[:-1].inv() * Rl[1:]
    start, length = k[:-1], np.diff(k)
    dt = np.diff(imu.t_s)[:, None]
    cost = np.empty(lags_s.size)
    for n, lag in enumerate(lags_s):
        w = np.column_stack([np.interp(imu.t_s + lag, imu.t_s, imu.w_b_rps[:, i]) for i in range(3)])
        steps = (0.5 * (w[:-1] + w[1:]) * dt)
        acc = Rotation.identity(start.size)
        for m in range(int(length.max())):
            live = m < length
            inc = np.zeros((start.size, 3))
            inc[live] = steps[start[live] + m]
            acc = acc * Rotation.from_rotvec(inc)
        cost[n] = np.mean(np.sum((acc.inv() * dR_lidar).as_rotvec() ** 2, axis=1))
    return cost


def estimate_gyro_lag(imu: ImuSeries, lidar_on_imu: PoseSeries, max_lag_s: float = 0.2, step_s: float = 0.005) -> float:
    """The gyro lag (s) that best aligns gyro and lidar rotation increments; see the module docstring."""
    lags = np.arange(-max_lag_s, max_lag_s + step_s / 2, step_s)
    cost = gyro_lag_cost(imu, lidar_on_imu, lags)
    i = int(np.argmin(cost))
    if 0 < i < lags.size - 1:
        c0, c1, c2 = cost[i - 1:i + 2]
        denom = c0 - 2 * c1 + c2
        if denom > 0:
            return float(lags[i] + 0.5 * step_s * (c0 - c2) / denom)
    return float(lags[i])
