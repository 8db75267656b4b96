"""The rotation between the lidar odometry's body frame and the IMU, estimated from the data (hand-eye).

With a mount rotated by R_E against the calibration file, the IMU poses the readers derive from the lidar
move as ``E T E^-1``: their body-frame rotation rate is ``R_E w`` and their body-frame specific force
``R_E f``, where ``w`` and ``f`` are what the gyro and the accelerometer measure. So R_E is the rotation
that best maps the IMU's signals onto the lidar's (Wahba's problem, solved by SVD), both signals on the
time-aligned, low-passed grid of :mod:`fusion_eval.calibration.time_offset`:

- the rates fix roll and pitch of R_E (a car turns about its vertical axis, so its rate vector points up
  and a yaw of R_E leaves it unchanged);
- the specific force fixes the yaw: forward and lateral acceleration have distinct directions in the body
  frame. Gravity, a constant in the odometry's world frame, is solved out as in the time-offset estimate.

The two sets are weighted by the inverse of their residual variance; the uncertainty is a block
jackknife. The lever arm is not estimated: at a car's yaw rates its signal (the centripetal acceleration
of a 10 cm arm, w^2 r ~ 1 cm/s^2) is far below the noise of a 10 Hz odometry's second differences.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import DataRangeError
from ..so3 import inv_T, make_T, matrix_to_quat_xyzw
from ..types import ImuSeries, PoseSeries
from . import time_offset as to


@dataclass(frozen=True)
class RotationEstimate:
    R_E: np.ndarray              # lidar-derived body frame from the IMU frame (the correction is its inverse)
    rpy_mrad: np.ndarray         # R_E as roll, pitch, yaw (extrinsic xyz), mrad
    std_mrad: np.ndarray         # jackknife standard error of each
    samples: int

    def as_dict(self) -> dict:
        return {"rpy_mrad": self.rpy_mrad.tolist(), "std_mrad": self.std_mrad.tolist(), "samples": self.samples,
                "method": "hand-eye: gyro vs lidar rotation rate and accelerometer vs lidar acceleration (Wahba, SVD)"}


def _wahba(H: np.ndarray) -> np.ndarray:
    """The rotation R minimising sum |y - R x|^2, for H = sum x y^T."""
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def _signals(imu: ImuSeries, lidar: PoseSeries):
    """Body-frame signals on a common grid: lidar rates and IMU rates; lidar acceleration A, its gravity
    matrix B (A - B g = R_E f) and the accelerometer F; validity masks."""
    t_ref = float(imu.t_s[0])
    imu, lidar = replace(imu, t_s=imu.t_s - t_ref), replace(lidar, t_s=lidar.t_s - t_ref)
    grid = to._common_grid(imu, lidar, 0.0)
    wl, ok_r = to.lidar_rate_signal(lidar, grid)
    wg, ok_g = to.imu_signal(imu.t_s, imu.w_b_rps, grid, to.RATE_SMOOTH_S)
    A, B, ok_a = to.lidar_accel_signal(lidar, grid)
    F, ok_f = to.imu_signal(imu.t_s, imu.f_b_mps2, grid, to.ACCEL_SMOOTH_S)
    return wl, wg, ok_r & ok_g, A, B, F, ok_a & ok_f


def _solve(wl, wg, A, B, F, iters: int = 4) -> np.ndarray:
    wl0, wg0 = wl - wl.mean(axis=0), wg - wg.mean(axis=0)
    R = np.eye(3)
    for _ in range(iters):
        # gravity for the current R: min sum |A - B g - R F|^2
        g = np.linalg.solve(np.einsum("nki,nkj->ij", B, B), np.einsum("nji,nj->i", B, A - F @ R.T))
        y = A - np.einsum("nij,j->ni", B, g)
        ra = np.mean(np.sum((y - F @ R.T) ** 2, axis=1))
        rr = np.mean(np.sum((wl0 - wg0 @ R.T) ** 2, axis=1))
        H = wg0.T @ wl0 / max(rr, 1e-12) + F.T @ y / max(ra, 1e-12)
        R = _wahba(H)
    return R


def estimate_rotation(imu: ImuSeries, lidar: PoseSeries, blocks: int = to.BLOCKS) -> RotationEstimate:
    """R_E with its jackknife uncertainty; ``imu`` and ``lidar`` already time-aligned (lags and offset applied),
    ``lidar`` holding the IMU poses the calibration file gives, on the lidar stamps."""
    wl, wg, ok_r, A, B, F, ok_a = _signals(imu, lidar)
    if ok_r.sum() < 1000 or ok_a.sum() < 1000:
        raise DataRangeError(f"too little overlap of {imu.source} and {lidar.source} without gaps to estimate the lidar rotation")
    blk = to._block_of(ok_r.size, blocks)

    def solve(keep):
        mr, ma = ok_r & keep[blk], ok_a & keep[blk]
        return _solve(wl[mr], wg[mr], A[ma], B[ma], F[ma])

    R = solve(np.ones(blocks, bool))
    rpy = Rotation.from_matrix(R).as_euler("xyz") * 1e3
    loo = []
    for b in range(blocks):
        keep = np.ones(blocks, bool)
        keep[b] = False
        loo.append(Rotation.from_matrix(solve(keep)).as_euler("xyz") * 1e3)
    loo = np.asarray(loo)
    std = np.sqrt((blocks - 1) / blocks * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0))
    return RotationEstimate(R, rpy, std, int(ok_a.sum()))


def apply_rotation(lidar: PoseSeries, R_E: np.ndarray) -> PoseSeries:
    """The lidar poses corrected for the mount rotation: relative to the first pose, ``X -> E^-1 X E``."""
    T = make_T(lidar.R_wb(), lidar.p_w_m)
    E = make_T(R_E, np.zeros(3))
    Ei = make_T(R_E.T, np.zeros(3))
    X = inv_T(T[0])[None] @ T
    Tc = T[0][None] @ Ei[None] @ X @ E[None]
    return replace(lidar, p_w_m=Tc[:, :3, 3], q_wb_xyzw=matrix_to_quat_xyzw(Tc[:, :3, :3]))


__all__ = ["RotationEstimate", "estimate_rotation", "apply_rotation"]
