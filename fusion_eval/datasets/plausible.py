"""Plausibility of a dataset's streams as a whole, checked once every stream is read (the readers check each value).

What no real drive holds is refused with the file, the line and the value: an IMU stream that stops for more than a
minute (a corrupted stamp, or two recordings run together), a stream whose time span is tens of times the IMU's (its
stamps in milliseconds or microseconds), a pose beyond 10,000 km of its frame's origin, or consecutive poses whose
implied speed exceeds 10 km/s (faster than a satellite). Each bound is far beyond any vehicle, so that no real data
is refused; what real data can hold (a lidar odometry failure jumping by metres) is left to the filter's gates.
"""

from __future__ import annotations

import numpy as np

from ..errors import DataFormatError, DataRangeError
from ..types import line_of

MAX_LAG_S = 1.0          # an IMU channel's latency: beyond a second it is a clock offset (or a typo), not a lag
LAG_NOTE = (f"a channel lag is a latency of milliseconds (KITTI's OXTS: 0.06 s), at most {MAX_LAG_S:g} s here; a clock "
            "offset between streams goes in time_offset_s")
MAX_IMU_GAP_S = 60.0
MAX_SPAN_RATIO = 50.0
MAX_POSITION_M = 1e7
MAX_SPEED_MPS = 1e4


def check_imu(imu) -> None:
    t = np.asarray(imu.t_s)
    if t.size < 3:
        return
    d = np.diff(t)
    med = float(np.median(d))
    bad = np.flatnonzero(d > max(MAX_IMU_GAP_S, 1000.0 * med))
    if bad.size:
        i = int(bad[0]) + 1
        raise DataFormatError(imu.source, line_of(imu.lines, i), f"the IMU stamps jump by {d[i - 1]:.3f} s (median step {med:.4g} s) "
                                                         f"to {t[i]:.6f}: a corrupted stamp, or recordings run together "
                                                         f"(a gap of over {MAX_IMU_GAP_S:g} s); split the drive there")


def check_span(name: str, series, imu) -> None:
    """A stream whose time span is :data:`MAX_SPAN_RATIO` times the IMU's has stamps in another unit."""
    t, ti = np.asarray(series.t_s), np.asarray(imu.t_s)
    if t.size < 2 or ti.size < 2:
        return
    span, span_imu = float(t[-1] - t[0]), float(ti[-1] - ti[0])
    if span_imu > 0 and span > MAX_SPAN_RATIO * span_imu:
        raise DataRangeError(f"{name} ({series.source}) spans {span:.6g} s against the IMU's {span_imu:.6g} s "
                             f"({span / span_imu:.0f}x): its stamps are in another unit (milliseconds? give seconds, or "
                             "the csv format's time_unit)")


def check_poses(name: str, poses) -> None:
    """Positions beyond :data:`MAX_POSITION_M` and consecutive poses faster than :data:`MAX_SPEED_MPS`."""
    p = np.asarray(poses.p_w_m)
    if p.size == 0:
        return
    r = np.linalg.norm(p, axis=1)
    bad = np.flatnonzero(r > MAX_POSITION_M)
    if bad.size:
        i = int(bad[0])
        raise DataFormatError(poses.source, line_of(poses.lines, i), f"{name} position {p[i].tolist()} m is {r[i]:.3g} m from its "
                                                             f"frame's origin (more than {MAX_POSITION_M:.0e} m): a corrupted pose")
    if p.shape[0] > 1:
        dt = np.diff(np.asarray(poses.t_s))
        v = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.where(dt > 0, dt, np.inf)
        bad = np.flatnonzero(v > MAX_SPEED_MPS)
        if bad.size:
            i = int(bad[0]) + 1
            raise DataFormatError(poses.source, line_of(poses.lines, i), f"{name} pose moves {v[i - 1]:.3g} m/s from the previous one "
                                                                 f"(more than {MAX_SPEED_MPS:.0e} m/s): a corrupted pose or stamp")


def check_dataset(imu, streams: dict) -> None:
    """Every check on a dataset: ``streams`` maps a stream's name to its series (None when absent)."""
    check_imu(imu)
    for name, s in streams.items():
        if s is None:
            continue
        check_span(name, s, imu)
        if hasattr(s, "q_wb_xyzw") or name == "gnss":
            check_poses(name, s)
