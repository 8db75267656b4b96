"""The direction a wheeled vehicle travels in, in the IMU frame, from the lidar odometry's own increments.

The non-holonomic constraint says the vehicle does not move sideways or up out of its own frame; the IMU is rarely
mounted exactly along that frame. On the KITTI drives the OXTS unit's x axis points about 8-13 mrad below the
direction of travel (measured on the ground truth's own body-frame velocity): a constraint ``v_z = 0`` in the IMU
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
MIN_STRETCHES = 20        # non-overlapping stretches needed (20 s of straight driving)
BLOCKS = 10
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


def estimate_travel_pitch(poses: PoseSeries) -> TravelEstimate | None:
    """The pitch of the direction of travel in the IMU frame from IMU poses (the lidar-derived ones, or an
    estimate's), or None when the drive holds too little straight driving (under :data:`MIN_STRETCHES` s)."""
    t, p, R = poses.t_s, poses.p_w_m, poses.R_wb()
    if t.size < 3:
        return None
    j = np.searchsorted(t, t + WINDOW_S)
    i = np.flatnonzero(j < t.size)
    j = j[i]
    if i.size == 0:
        return None
    d = np.einsum("nji,nj->ni", R[i], p[j] - p[i])                  # increment in the first frame's body axes
    turn = np.linalg.norm(log_so3(np.einsum("nji,njk->nik", R[i], R[j])), axis=1)
    ok = (d[:, 0] > MIN_FORWARD_M) & (turn < MAX_TURN_RAD)
    seconds = float(np.sum(np.diff(t)[np.clip(i[ok], 0, t.size - 2)]))
    if seconds < MIN_STRETCHES * WINDOW_S:
        return None
    pitch = np.arctan2(d[ok, 2], d[ok, 0])
    blocks = np.array_split(pitch, BLOCKS)
    meds = np.array([np.median(b) for b in blocks if b.size])
    return TravelEstimate(float(np.median(pitch) * 1e3), float(np.std(meds, ddof=1) / np.sqrt(meds.size) * 1e3),
                          int(ok.sum()), seconds)


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
    the smoothed pass lands within 0.4-0.8 mrad of the ground truth's own figure, the filtered one within 4.
    Returns the estimate (or None) and, without one, why."""
    import copy

    from ..config import Settings
    from ..errors import FusionEvalError
    from ..replay import replay

    c = copy.deepcopy(cfg)
    c["filter"].update(formulation="error_state", nhc_travel_pitch_mrad=None)
    c["smoother"]["method"] = "rts"
    body = {sect: dict(v) for sect, v in c.items()}
    for sect, vals in prep.resolved.items():
        body[sect].update(vals)
    try:
        out = replay(prep, Settings(body))
    except FusionEvalError as e:
        # the run's own filter meets the same trouble and says so; this pass only gives up its estimate
        log.info("direction of travel not estimated: the IMU + GNSS pass failed (%s)", e)
        return None, "the smoothed IMU + GNSS pass failed"
    est = estimate_travel_pitch(out.smoothed.fused)
    if est is None:
        return None, "under 20 s of straight driving in the smoothed IMU + GNSS pass"
    return TravelEstimate(est.pitch_mrad, est.std_mrad, est.stretches, est.seconds, SMOOTHED_METHOD), ""
