"""The lidar odometry's mount against the IMU, estimated from the data (hand-eye): the rotation and the
horizontal lever arm.

With a mount offset by ``E = (R_E, t_E)`` against the calibration file, the IMU poses the readers derive from the
lidar move as ``E T E^-1``: their body-frame rotation rate is ``R_E w``, and their body-frame specific force
``R_E f - K t_E`` with ``K = [w']x^2 + [dw'/dt]x`` (``w' = R_E w``): the centripetal and tangential acceleration of
the offset point. So R_E is the rotation that best maps the IMU's signals onto the lidar's and ``t_E`` a linear
least-squares term beside it (one Gauss-Newton fit over both), all signals on the time-aligned, low-passed grid of
:mod:`fusion_eval.calibration.time_offset`:

- the rates fix roll and pitch of R_E (a car turns about its vertical axis, so its rate vector points up
  and a yaw of R_E leaves it unchanged);
- the specific force fixes the yaw (forward and lateral acceleration have distinct directions in the body frame)
  and the lever arm's horizontal components (through ``K``, in turns). Gravity, a constant in the odometry's world
  frame, is solved out as in the time-offset estimate, and so is a constant horizontal accelerometer bias: left in,
  its ~0.05 m/s^2 correlates with the always-negative ``-w^2`` of turning and put a 13-17 cm lever arm into a
  simulated drive that had none. The vertical component of the lever arm is not observable from a ground
  vehicle's yaw (``K``'s third column is zero for a rate about z) and stays the calibration's.

The two sets are weighted by the inverse of their residual variance; the uncertainty is a block jackknife.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import DataRangeError
from ..so3 import inv_T, make_T, matrix_to_quat_xyzw
from ..types import ImuSeries, PoseSeries
from . import time_offset as to


@dataclass(frozen=True)
class ExtrinsicEstimate:
    R_E: np.ndarray              # lidar-derived body frame from the IMU frame (the correction is its inverse)
    rpy_mrad: np.ndarray         # R_E as roll, pitch, yaw (extrinsic xyz), mrad
    std_mrad: np.ndarray         # jackknife standard error of each
    samples: int
    t_E_m: np.ndarray = field(default_factory=lambda: np.zeros(3))     # the calibration's lever-arm error, IMU axes
    t_std_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))

    def as_dict(self) -> dict:
        return {"rpy_mrad": self.rpy_mrad.tolist(), "std_mrad": self.std_mrad.tolist(), "samples": self.samples,
                "lever_arm_error_m": self.t_E_m.tolist(), "lever_arm_std_m": self.t_std_m.tolist(),
                "method": "hand-eye: gyro vs lidar rotation rate and accelerometer vs lidar acceleration (Gauss-Newton; "
                          "lever arm and horizontal accelerometer bias by least squares beside it)"}


def _signals(imu: ImuSeries, lidar: PoseSeries, step_s: float):
    """Body-frame signals on a common grid of ``step_s``: lidar rates and IMU rates; lidar acceleration A, its
    gravity matrix B (A - B g = R_E f) and the accelerometer F; the raw gyro and its derivative for the lever arm's
    regressor; validity masks."""
    t_ref = float(imu.t_s[0])
    imu, lidar = replace(imu, t_s=imu.t_s - t_ref), replace(lidar, t_s=lidar.t_s - t_ref)
    grid = to._common_grid(imu, lidar, 0.0, step_s)
    wl, ok_r = to.lidar_rate_signal(lidar, grid, step_s)
    wg, ok_g = to.imu_signal(imu.t_s, imu.w_b_rps, grid, to.RATE_SMOOTH_S, step_s)
    A, B, ok_a = to.lidar_accel_signal(lidar, grid, step_s)
    F, ok_f = to.imu_signal(imu.t_s, imu.f_b_mps2, grid, to.ACCEL_SMOOTH_S, step_s)
    w = to._interp(imu.t_s, imu.w_b_rps, grid)
    return wl, wg, ok_r & ok_g, A, B, F, ok_a & ok_f, (w, np.gradient(w, step_s, axis=0), ok_f, step_s)


def _lever_regressor(raw) -> np.ndarray:
    """``smooth([w]x^2 + [dw/dt]x)`` on the grid (N, 3, 3), through the accelerometer's low-pass. The regressor of a
    mount rotation ``R`` (``w' = R w``) is ``R K R^T``: ``[R w]x = R [w]x R^T``, and the low-pass, linear and the
    same at every point, commutes with a constant ``R``; so the grid is smoothed once, not once per iteration of
    every jackknife fit (66 smoothings of 9 channels took 6.9 of 9.2 s on a simulated 300 s drive)."""
    w, wd, ok, step_s = raw
    S = _skew(w)
    Ks, _ = to._smooth((S @ S + _skew(wd)).reshape(-1, 9), ok, to.ACCEL_SMOOTH_S, step_s)
    return Ks.reshape(-1, 3, 3)


def _skew(v: np.ndarray) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return S - np.swapaxes(S, -1, -2)


# weak priors on what the data may not show (m, m/s^2): far beyond any calibration error or accelerometer bias, so
# that they only hold an unobserved direction (a drive without turns) at zero
LEVER_PRIOR_M, BIAS_PRIOR_MPS2 = 0.5, 0.5


def _solve(wl, wg, A, B, F, K_of, R0=None, iters: int = 10):
    """R_E and the lever-arm term ``d = -t_E`` (horizontal; the vertical stays 0) for the grid points given,
    starting from ``R0`` (the whole drive's fit, for the jackknife's: one or two steps then).

    Gauss-Newton on all of them at once: R_E = exp([phi]x) R, so ``R_E F ~ R F - [R F]x phi`` (and the rates
    likewise) beside the linear gravity g (world), d (x, y) and accelerometer bias c (x, y), each set weighted by its
    residual variance. Alternating (g, d, c given R; R by Wahba given them) crept: gravity, tilted with the body,
    re-absorbed each step's roll and pitch, and a 35 mrad pitch came out at 18 after six rounds."""
    wl0, wg0 = wl - wl.mean(axis=0), wg - wg.mean(axis=0)
    n = A.shape[0]
    R = np.eye(3) if R0 is None else R0
    ones = np.broadcast_to(np.eye(3)[:, :2], (n, 3, 2))
    Ja = np.empty((n, 3, 10))
    Ja[:, :, :3], Ja[:, :, 5:7] = B, ones
    # the accelerometer's residual variance at the start: given R the model is linear in (g, d, c)
    J7 = np.concatenate([B, K_of(R)[:, :, :2], ones], axis=2).reshape(-1, 7)
    y0 = (A - F @ R.T).reshape(-1)
    ra = np.mean(np.sum((y0 - J7 @ np.linalg.lstsq(J7.T @ J7, y0 @ J7, rcond=1e-12)[0]).reshape(-1, 3) ** 2, axis=1))
    rr = np.mean(np.sum((wl0 - wg0 @ R.T) ** 2, axis=1))
    sol = np.zeros(10)
    for _ in range(iters):
        RF, Rw = F @ R.T, wg0 @ R.T
        # the rows of every point stacked (3N, 10): the normal equations as matrix products (einsum's loops took 1.3 s;
        # y @ J, not J.T @ y: 10x faster over a transposed view)
        Ja[:, :, 3:5], Ja[:, :, 7:] = K_of(R)[:, :, :2], -_skew(RF)
        J = Ja.reshape(-1, 10)
        ya, yr = (A - RF).reshape(-1), wl0 - Rw
        wa, wr = 1.0 / max(ra, 1e-12), 1.0 / max(rr, 1e-12)
        N = wa * (J.T @ J)
        b = wa * (ya @ J)
        # the rates' rows -[Rw]x phi: their normal block sum [v]x^T [v]x = sum |v|^2 I - v v^T and right side sum v x y
        N[7:, 7:] += wr * (np.sum(Rw * Rw) * np.eye(3) - Rw.T @ Rw)
        b[7:] += wr * np.sum(np.cross(Rw, yr), axis=0)
        N[3:5, 3:5] += np.eye(2) / LEVER_PRIOR_M ** 2
        N[5:7, 5:7] += np.eye(2) / BIAS_PRIOR_MPS2 ** 2
        sol = np.linalg.solve(N, b)
        R = Rotation.from_rotvec(sol[7:]).as_matrix() @ R
        ra = np.mean(np.sum((ya - J @ sol).reshape(-1, 3) ** 2, axis=1))
        rr = np.mean(np.sum((yr + np.cross(Rw, sol[7:])) ** 2, axis=1))
        if np.linalg.norm(sol[7:]) < 1e-6:            # a microradian: far below what the data resolve
            break
    return R, np.array([sol[3], sol[4], 0.0])


def estimate_extrinsic(imu: ImuSeries, lidar: PoseSeries, blocks: int = to.BLOCKS, step_s: float = to.GRID_S) -> ExtrinsicEstimate:
    """R_E and t_E with their jackknife uncertainty; ``imu`` and ``lidar`` already time-aligned (lags and offset
    applied), ``lidar`` holding the IMU poses the calibration file gives, on the lidar stamps. ``blocks=0``: no
    uncertainty (one fit, stds NaN); ``step_s``: the grid (its signals are low-passed far below 200 Hz: a coarser
    one loses little but time)."""
    wl, wg, ok_r, A, B, F, ok_a, raw = _signals(imu, lidar, step_s)
    if (ok_r & ok_a).sum() * step_s < 5.0:
        raise DataRangeError(f"too little overlap of {imu.source} and {lidar.source} without gaps to estimate the lidar mount")
    blk = to._block_of(ok_r.size, max(blocks, 1))
    K = _lever_regressor(raw)           # smoothed over the whole grid (its low-pass needs it), once

    def solve(keep, R0=None):
        m = ok_r & ok_a & keep[blk]
        Km = K[m]
        n = Km.shape[0]

        Kflat = Km.reshape(n, 9)

        def K_of(R):                    # R Km R^T at every point: one (n, 9) x (9, 9) product, vec(R K R^T) = (R x R) vec(K)
            return (Kflat @ np.kron(R, R).T).reshape(n, 3, 3)
        R, d = _solve(wl[m], wg[m], A[m], B[m], F[m], K_of, R0)
        return np.r_[Rotation.from_matrix(R).as_euler("xyz") * 1e3, -d], R

    full, R = solve(np.ones(max(blocks, 1), bool))
    if blocks < 2:
        return ExtrinsicEstimate(R, full[:3], np.full(3, np.nan), int((ok_r & ok_a).sum()), full[3:], np.full(3, np.nan))
    loo = np.asarray([solve(np.arange(blocks) != b, R)[0] for b in range(blocks)])
    std = np.sqrt((blocks - 1) / blocks * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0))
    std[5] = np.nan                     # the vertical lever arm: not estimated
    return ExtrinsicEstimate(R, full[:3], std[:3], int((ok_r & ok_a).sum()), full[3:], std[3:])


def apply_extrinsic(lidar: PoseSeries, R_E: np.ndarray, t_E_m=None) -> PoseSeries:
    """The lidar poses corrected for the mount's offset ``E = (R_E, t_E)``: relative to the first pose,
    ``X -> E^-1 X E``."""
    T = make_T(lidar.R_wb(), lidar.p_w_m)
    E = make_T(R_E, np.zeros(3) if t_E_m is None else np.asarray(t_E_m, float))
    X = inv_T(T[0])[None] @ T
    Tc = T[0][None] @ inv_T(E)[None] @ X @ E[None]
    return replace(lidar, p_w_m=Tc[:, :3, 3], q_wb_xyzw=matrix_to_quat_xyzw(Tc[:, :3, :3]))


# what a mount check warns about: far outside what the five real KITTI lidar drives give against their calibration
# (README "Time offsets": lever arm 13-28 cm horizontal, roll and pitch under 1 mrad, yaw -1 to -10 +/- 5 mrad), so a
# sign or frame mistake in a calibration file shows (kitti-00 with its lever arm's sign flipped: 1.8 m) and a
# drive's own calibration does not
CHECK_LEVER_M, CHECK_TILT_MRAD, CHECK_YAW_MRAD = 0.5, 10.0, 30.0
CHECK_STEP_S = 0.02         # the check's grid (the 5 ms one's fit took 4x as long for the same figures)
CHECK_BLOCKS = 4            # its jackknife: a figure is named only beyond CHECK_SIGMAS of its spread, a t quantile
CHECK_SIGMAS = 5.8          # for the 3 degrees of freedom of 4 blocks (99 %): 3 let a parked minute's 4-sigma roll by
MIN_TURN_RPS = 0.05         # time_offset.turning_rps of the rate itself (the time offsets' check takes the same bound)


def _beyond_bounds(est: ExtrinsicEstimate) -> bool:
    r, p, y = est.rpy_mrad
    return (float(np.hypot(*est.t_E_m[:2])) > CHECK_LEVER_M  # not a state index: the horizontal components
            or max(abs(r), abs(p)) > CHECK_TILT_MRAD or abs(y) > CHECK_YAW_MRAD)


def mount_disagrees(imu: ImuSeries, lidar: PoseSeries, source: str) -> str:
    """A warning when the hand-eye fit puts the lidar's mount far from the calibration ``source`` gives, beyond the
    bounds above and beyond CHECK_SIGMAS of its jackknife's standard errors (a parked minute, which shows no mount,
    fitted tilts of 15-44 mrad: a review), on a 20 ms grid (0.1-0.2 s on kitti-00): so that a flipped lever arm (kitti-00:
    fused 0.76 -> 1.66 m with no other sign) or a tilted mount is named. Nothing when the data cannot tell."""
    # only where the platform turns: roll and pitch show in the rates' direction, the lever arm in the turns'
    # centripetal acceleration; a parked or straight drive fits noise
    if to.turning_rps(imu, about_median=False) <= MIN_TURN_RPS:
        return ""
    try:
        # one fit first: on a drive within the bounds (every real one) the jackknife's four more are not needed
        est = estimate_extrinsic(imu, lidar, blocks=0, step_s=CHECK_STEP_S)
        if not _beyond_bounds(est):
            return ""
        est = estimate_extrinsic(imu, lidar, blocks=CHECK_BLOCKS, step_s=CHECK_STEP_S)
    except (DataRangeError, np.linalg.LinAlgError):
        return ""
    roll, pitch, yaw = est.rpy_mrad
    sd = est.std_mrad
    arm = float(np.hypot(*est.t_E_m[:2]))  # not a state index: the horizontal components
    arm_sd = float(np.hypot(*est.t_std_m[:2]))  # not a state index: the horizontal components
    off = []
    if arm > max(CHECK_LEVER_M, CHECK_SIGMAS * arm_sd):
        off.append(f"the lever arm {est.t_E_m[0]:+.2f}, {est.t_E_m[1]:+.2f} m (x, y; +/- {arm_sd:.2f} m)")
    tilted = any(abs(a) > max(CHECK_TILT_MRAD, CHECK_SIGMAS * e) for a, e in ((roll, sd[0]), (pitch, sd[1])))
    if tilted or abs(yaw) > max(CHECK_YAW_MRAD, CHECK_SIGMAS * sd[2]):
        off.append(f"the rotation {roll:+.0f}, {pitch:+.0f}, {yaw:+.0f} mrad (roll, pitch, yaw; +/- {sd[0]:.0f}, "
                   f"{sd[1]:.0f}, {sd[2]:.0f})")
    if not off:
        return ""
    return (f"the lidar's mount ({source}) disagrees with the data: a hand-eye fit of the gyro and accelerometer "
            f"to the lidar's motion puts {' and '.join(off)} away from it (the five real KITTI lidar drives: under "
            "0.3 m, 1 mrad of roll and pitch, 11 mrad of yaw); "
            "check the calibration's direction (sensor to IMU, not IMU to sensor), its sign and its frames, or set "
            "lidar.extrinsic_rotation=auto / lidar.extrinsic_translation=auto to estimate them")


__all__ = ["ExtrinsicEstimate", "estimate_extrinsic", "apply_extrinsic", "mount_disagrees"]
