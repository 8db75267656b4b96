"""Whether a wheeled vehicle's IMU is mounted along the vehicle: the axis of its longitudinal acceleration, from the
IMU alone.

The non-holonomic constraint holds the velocity across and above the direction of travel at zero, with the vehicle's
axes taken in the IMU frame (:mod:`fusion_eval.filters.observations.nhc`, ``filter.nhc_travel_yaw_mrad``). An IMU
mounted across the car (a robot's ``imu_link`` yawed 90 deg from ``base_link``) then gets its forward velocity
held at zero, and the filter twists its heading to obey: figures that look like a filter's, about nothing. The
mount shows in the data without ground truth or another sensor: while a car drives straight, its acceleration
and braking are along its own x axis, so the horizontal specific force (averaged over a second, its mean over the
drive removed: gravity through the mount's tilt) varies most along that axis. On the four KITTI raw drives the
axis found is within 3 deg of the OXTS x axis, its variance 6-19x the across one; on the simulator's drives within
9 deg. That is far too coarse to set the constraint's axes (a degree puts 2 % of the speed into its lateral row),
but a mount 30 deg or more from the configured direction of travel is no calibration error.

A car at steady speed through gentle bends (30 m/s at 0.03 rad/s: 1 m/s^2 across it, under the straight-driving
rate bound) varies its specific force most *across* itself, so that axis alone once called a well-mounted IMU
"90 deg off". A second, independent axis must agree: the centripetal acceleration ``v w_z`` is across the car and
follows the yaw rate, so the regression of the horizontal specific force on ``w_z`` points to the car's left (its
sign seen too); on the raw drives it is within 21 deg of the OXTS y axis, within 3 deg on the simulator's. The
mount is called off only when both put the direction of travel 30 deg or more from the configured one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..stats import moving_mean
from ..types import ImuSeries

WINDOW_S = 1.0               # averaging of the specific force and the rates: vibration and road noise out
MAX_RATE_RPS = 0.05          # straight driving: in turns the centripetal acceleration is across the car
MIN_STRAIGHT_S = 20.0        # straight driving needed for an answer
MIN_ANISOTROPY = 3.0         # variance along the axis over that across it: a clear axis, not noise
GROSS_DEG = 30.0             # an axis this far from the configured direction of travel is a mount, not an error


@dataclass(frozen=True)
class LongitudinalAxis:
    yaw_deg: float           # the axis' angle to the left of the IMU's x axis, in (-90, 90] (its sign is not seen)
    anisotropy: float        # variance along it over the variance across it
    straight_s: float        # straight driving used


def _window(imu: ImuSeries) -> tuple[int | None, float]:
    """Samples in :data:`WINDOW_S` and the median step, or (None, step) for a stream too short to average."""
    t = np.asarray(imu.t_s)
    if t.size < 3:
        return None, float("nan")
    dt = float(np.median(np.diff(t)))
    n = max(1, int(round(WINDOW_S / dt))) if dt > 0 else 1
    return (n if t.size > n + 2 else None), dt


def longitudinal_axis(imu: ImuSeries) -> LongitudinalAxis | None:
    """The horizontal IMU axis along which the specific force varies most while not turning, or None (too little
    straight driving, or no clear axis)."""
    n, dt = _window(imu)
    if n is None:
        return None
    f_mean, rate = moving_mean(imu.f_b_mps2, n), moving_mean(np.linalg.norm(imu.w_b_rps, axis=1), n)
    ok = np.isfinite(rate) & np.all(np.isfinite(f_mean), axis=1) & (rate < MAX_RATE_RPS)
    straight_s = float(ok.sum() * dt)
    if straight_s < MIN_STRAIGHT_S:
        return None
    h = f_mean[ok, :2] - f_mean[ok, :2].mean(axis=0)
    ev, vec = np.linalg.eigh(h.T @ h / h.shape[0])
    if not ev[0] > 0 or ev[1] / ev[0] < MIN_ANISOTROPY:
        return None
    yaw = np.degrees(np.arctan2(vec[1, 1], vec[0, 1]))
    return LongitudinalAxis(float((yaw + 90.0) % 180.0 - 90.0), float(ev[1] / ev[0]), straight_s)


MIN_RATE_STD_RPS = 0.005      # turning enough for the centripetal acceleration to show
MIN_CORRELATION = 0.5
MIN_SPEED_MPS = 1.0          # the regression's slope is the speed of the turns


def lateral_axis_yaw_deg(imu: ImuSeries) -> float | None:
    """The direction of travel's yaw from the IMU's x axis (deg, signed), from the horizontal specific force's
    regression on the yaw rate (averaged over a second): the centripetal acceleration points to the car's left in a
    left turn. None when the drive turns too little or the regression is not clear."""
    n, _ = _window(imu)
    if n is None:
        return None
    h, wz = moving_mean(imu.f_b_mps2[:, :2], n), moving_mean(imu.w_b_rps[:, 2], n)
    ok = np.isfinite(wz) & np.all(np.isfinite(h), axis=1)
    h, wz = h[ok] - h[ok].mean(axis=0), wz[ok] - wz[ok].mean()
    if wz.size < 3 or not wz.std() > MIN_RATE_STD_RPS:
        return None
    c = h.T @ wz / (wz @ wz)                      # m/s: the speed of the turns, along the car's left
    speed = float(np.linalg.norm(c))
    if not speed > MIN_SPEED_MPS or not np.corrcoef(h @ (c / speed), wz)[0, 1] > MIN_CORRELATION:
        return None
    return float(np.degrees(np.arctan2(-c[0], c[1])))        # the left axis turned 90 deg clockwise


def across_travel(imu: ImuSeries, travel_yaw_mrad: float) -> str:
    """Why the IMU is not mounted along the configured direction of travel (its longitudinal axis 30 deg or more
    from it), or '' when it is, or when the data cannot tell."""
    ax = longitudinal_axis(imu)
    if ax is None:
        return ""
    configured = np.degrees(travel_yaw_mrad * 1e-3)
    off = (ax.yaw_deg - configured + 90.0) % 180.0 - 90.0
    if abs(off) < GROSS_DEG:
        return ""
    turns = lateral_axis_yaw_deg(imu)
    if turns is None or abs((turns - configured + 180.0) % 360.0 - 180.0) < GROSS_DEG:
        return ""                 # the turns do not confirm it (a steady drive through bends varies most across)
    return (f"{imu.source}: while driving straight the IMU's specific force varies most along an axis {ax.yaw_deg:+.0f} deg "
            f"from its x axis ({ax.anisotropy:.0f}x the variance across it, over {ax.straight_s:.0f} s), and its "
            f"centripetal acceleration in turns puts the direction of travel at {turns:+.0f} deg: the IMU looks mounted "
            f"{abs(off):.0f} deg from the direction of travel configured (filter.nhc_travel_yaw_mrad={travel_yaw_mrad:g})")


HINT = ("give the mount's yaw as filter.nhc_travel_yaw_mrad (from the mount's drawing or its tf_static: these axes are "
        "only good to some 20 deg)")
