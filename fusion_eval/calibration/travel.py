"""The direction a wheeled vehicle travels in, in the IMU frame: from the lidar odometry's own increments, else
from a smoothed IMU + GNSS pass (:func:`pitch_from_smoothed_pass`).

The non-holonomic constraint says the vehicle does not move sideways or up out of its own frame; the IMU is rarely
mounted exactly along that frame. On the KITTI drives the OXTS unit's x axis points below the
direction of travel (measured on the ground truth's own body-frame velocity; 8-14 mrad): a constraint ``v_z = 0`` in the IMU
frame then forces a pitch error of that size, gravity leaks into the horizontal acceleration and the position
runs off by metres. The odometry sees the mount: over stretches of straight driving (little rotation, a few metres
travelled) its body-frame position increment points along the direction of travel. Its median pitch, over every
such stretch of the drive, is the mount's pitch; its uncertainty the spread of the medians of ten consecutive
blocks of the drive (neighbouring stretches overlap and are not independent).

The yaw is not estimated this way: the increments' lateral direction also carries the lidar-IMU mount's yaw error,
which on KITTI (5-6 mrad, measured against the ground truth's own lateral direction of 0.2-2.3 mrad) is larger
than the quantity sought; the lidar mount's pitch error is below 1 mrad (`fusion_eval.calibration.extrinsic`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..so3 import log_so3
from ..types import PoseSeries

log = logging.getLogger(__name__)

WINDOW_S = 1.0            # length of one stretch
MIN_FORWARD_M = 3.0       # travelled along it (slow creeping says little about direction)
MAX_TURN_RAD = 0.02       # rotation over it (in turns the IMU point slips sideways)
MIN_STRETCHES = 20        # seconds of straight driving needed (one 1 s stretch starting every lidar frame)
BLOCKS = 10
# an estimate less certain than this is not used: at 20 m/s an axis off by 5 mrad puts 0.1 m/s, the constraint's own
# default noise, into its vertical row (KITTI: 0.2-1.1 mrad from the lidar, 0.3-2.6 from the smoothed pass)
MAX_STD_MRAD = 5.0
LIDAR_METHOD = "median direction of the lidar's body-frame increments over 1 s of straight driving"
SMOOTHED_METHOD = ("median direction of a smoothed IMU + GNSS pass's body-frame increments over 1 s of straight "
                   "driving (lateral row only in that pass)")


@dataclass(frozen=True)
class TravelEstimate:
    pitch_mrad: float       # elevation of the direction of travel above the IMU's x-y plane
    std_mrad: float
    stretches: int          # overlapping stretches used
    seconds: float          # straight driving they cover
    method: str = LIDAR_METHOD

    def as_dict(self) -> dict:
        return {"pitch_mrad": self.pitch_mrad, "std_mrad": self.std_mrad, "stretches": self.stretches,
                "seconds": self.seconds, "method": self.method}


def estimate_travel_pitch(poses: PoseSeries, yaw_rad: float = 0.0) -> TravelEstimate | None:
    """The pitch of the direction of travel in the IMU frame from IMU poses (the lidar-derived ones, or an
    estimate's), or None when the drive holds too little straight driving (under :data:`MIN_STRETCHES` s).
    ``yaw_rad``: the direction of travel's yaw from the IMU's x axis (``filter.nhc_travel_yaw_mrad``; an IMU
    mounted across the car)."""
    t, p, R = poses.t_s, poses.p_w_m, poses.R_wb()
    if t.size < 3:
        return None
    j = np.searchsorted(t, t + WINDOW_S)
    i = np.flatnonzero(j < t.size)
    j = j[i]
    if i.size == 0:
        return None
    d = np.einsum("nji,nj->ni", R[i], p[j] - p[i])                  # increment in the first frame's body axes
    if yaw_rad:                                                        # ... and in the vehicle's (yawed) axes
        d = d @ vehicle_axes(0.0, yaw_rad).T
    turn = np.linalg.norm(log_so3(np.einsum("nji,njk->nik", R[i], R[j])), axis=1)
    # along the axis either way: reversing climbs the same axis, and a yaw given 180 deg off (its sign is not seen
    # in the IMU's data, fusion_eval.calibration.mount) flips the axis and the pitch together, the constraint's
    # vertical row staying the same
    d *= np.sign(d[:, :1])
    ok = (d[:, 0] > MIN_FORWARD_M) & (turn < MAX_TURN_RAD)
    seconds = float(np.sum(np.diff(t)[np.clip(i[ok], 0, t.size - 2)]))
    if seconds < MIN_STRETCHES * WINDOW_S:
        return None
    pitch = np.arctan2(d[ok, 2], d[ok, 0])
    blocks = np.array_split(pitch, BLOCKS)
    meds = np.array([np.median(b) for b in blocks if b.size])
    std = float(np.std(meds, ddof=1) / np.sqrt(meds.size) * 1e3) if meds.size > 1 else float("nan")
    return TravelEstimate(float(np.median(pitch) * 1e3), std, int(ok.sum()), seconds)


def uncertain(est: TravelEstimate) -> str:
    """Why ``est`` is too uncertain to use (its jackknife std above :data:`MAX_STD_MRAD`, or none), else ''."""
    if np.isfinite(est.std_mrad) and est.std_mrad <= MAX_STD_MRAD:
        return ""
    return f"an estimate of {est.pitch_mrad:.1f} +/- {est.std_mrad:.1f} mrad, over {MAX_STD_MRAD:g} mrad of uncertainty"


def vehicle_axes(pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """The vehicle's forward, lateral and vertical axes in the IMU frame (rows), for a direction of travel at
    ``pitch`` above and ``yaw`` to the left of the IMU's x axis: ``Rz(yaw) Ry(-pitch)`` transposed."""
    cp, sp, cy, sy = np.cos(pitch_rad), np.sin(pitch_rad), np.cos(yaw_rad), np.sin(yaw_rad)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]])       # Ry(-pitch)
    return (Rz @ Ry).T


def pitch_from_smoothed_pass(prep, cfg: dict) -> tuple[TravelEstimate | None, str]:
    """Without a lidar, the direction of travel from the run's own IMU + GNSS: one pass of the error-state filter
    with the constraint's lateral row only, smoothed (RTS: the future fixes pin the vertical velocity that a
    filter alone leaves loose), then the same median over its straight stretches. On the four KITTI raw drives
    the smoothed pass lands within 0.4-0.9 mrad of the ground truth's own figure, the filtered one within 4.

    The pass is a fixed estimator, like the time-offset one: it takes the built-in noise settings (the IMU's
    white noise from the stream, :data:`fusion_eval.batch.FILTER_ONLY_KEYS` at their defaults), not the run's, so
    that the preparation a sweep's batch or a tune's trials share does not depend on what they vary (with the
    noise of ``configs/lidar-imu.yaml`` the estimate moves by about 2 mrad). Returns the estimate (or None) and,
    without one, why."""
    import copy

    from ..batch import FILTER_ONLY_KEYS
    from ..config import default_config
    from ..errors import FusionEvalError
    from ..prepare import settings_for
    from ..replay import replay
    from . import imu_noise

    c, base = copy.deepcopy(cfg), default_config()
    for key in FILTER_ONLY_KEYS:
        sect, name = key.split(".")
        c[sect][name] = copy.deepcopy(base[sect][name])
    est = imu_noise.estimate(prep.imu)
    c["imu"].update(accel_noise_mps2_sqrthz=est["accel_mps2_sqrthz"], gyro_noise_dps_sqrthz=np.degrees(est["gyro_rps_sqrthz"]))
    c["filter"].update(formulation="error_state", nhc_travel_pitch_mrad=None, iterations=1)
    c["smoother"]["method"] = "rts"
    try:
        out = replay(prep, settings_for(c, replace_resolved(prep)))
    except FusionEvalError as e:
        # the run's own filter meets the same trouble and says so; this pass only gives up its estimate
        log.info("direction of travel not estimated: the IMU + GNSS pass failed (%s)", e)
        return None, "the smoothed IMU + GNSS pass failed"
    got = estimate_travel_pitch(out.smoothed.fused, cfg["filter"]["nhc_travel_yaw_mrad"] * 1e-3)
    if got is None:
        return None, f"under {MIN_STRETCHES * WINDOW_S:.0f} s of straight driving in the smoothed IMU + GNSS pass"
    why = uncertain(got)
    if why:
        return None, f"{why} from the smoothed IMU + GNSS pass"
    return TravelEstimate(got.pitch_mrad, got.std_mrad, got.stretches, got.seconds, SMOOTHED_METHOD), ""


def replace_resolved(prep):
    """``prep`` without the IMU densities it estimated for the run (the pass sets its own)."""
    from dataclasses import replace

    return replace(prep, resolved={sect: body for sect, body in prep.resolved.items() if sect != "imu"})
