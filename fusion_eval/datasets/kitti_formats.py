"""The KITTI family's stream formats, registered like every other (:mod:`.formats`): ``kitti_oxts`` (the OXTS
packets of a raw drive: IMU, GNSS, ground truth, wheel speed), ``kitti_poses`` (an odometry pose file with its
times), ``tum`` (poses, or positions as GNSS fixes), ``csv_lla`` (geodetic fixes with their sigmas) and ``speed_txt``
(wheel speed). Each reader takes the stream's manifest entry and the :class:`~.streams.ReadContext`; the manifest
applies a pose stream's frame (``T_imu_<frame>``, KITTI's cam0 chain) to whatever the reader returns.
"""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError, DataFormatError, DataRangeError
from ..so3 import matrix_to_quat_xyzw
from ..types import GnssSeries, PoseSeries
from . import clock, gnss_csv, kitti_oxts, kitti_poses, speed, tum
from .csv_stream import std_m
from .streams import ReadContext

def _origin(ctx: ReadContext, what: str):
    if ctx.origin is None:
        raise ConfigError(f"{ctx.at()}: {what} needs a geodetic origin (geodetic_origin: first_fix or [lat, lon, alt])")
    return ctx.origin


def _num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


TIMES_KEYS = {"file", "align_to", "index_offset", "smooth_s", "t0_s"}


def pose_times(entry: dict, ctx: ReadContext, n_poses: int) -> np.ndarray:
    """The stamps of a KITTI pose file: a times file (absolute, or put on the IMU packets' clock with ``align_to``
    or ``t0_s``), or the stamps of the IMU packets themselves (``align_to: imu``, optionally smoothed: the recovered
    clock is left in ``ctx.notes['clock']``)."""
    raw, times = ctx.imu_packets, entry.get("times")
    pose_path = ctx.path(entry)
    if not isinstance(times, dict):
        raise ConfigError(f"{ctx.at(entry)}: KITTI poses need 'times': {{file: times.txt}} and/or {{align_to: imu, index_offset: 0}}")
    # a misspelt key (smooth for smooth_s) was ignored: the run went on without what the user asked for
    unknown = sorted(set(map(str, times)) - TIMES_KEYS)
    if unknown:
        raise ConfigError(f"{ctx.at(times, unknown[0])}: unknown key {unknown[0]!r} in times "
                          f"(known: {', '.join(sorted(TIMES_KEYS))})")
    # keys that the chosen way of stamping does not read were ignored as silently as misspelt ones
    ignored = (("smooth_s", "file", "times.smooth_s smooths the IMU packets' own stamps (align_to: imu without a file); "
                                    "a times file's stamps are used as they are: remove one of the two"),
               ("t0_s", "align_to", "times.t0_s shifts a times file; with align_to: imu the stamps are on the IMU "
                                    "packets' clock already: remove one of the two"),
               ("index_offset", None, "times.index_offset pairs frames with IMU packets and applies with align_to: imu "
                                      "only: remove it, or add align_to: imu"))
    for key, other, why in ignored:
        if key in times and (other in times if other else "align_to" not in times):
            raise ConfigError(f"{ctx.at(times, key)}: {why}")
    if "align_to" in times and times["align_to"] != "imu":
        raise ConfigError(f"{ctx.at(times, 'align_to')}: times.align_to takes 'imu' (the IMU packets' clock), "
                          f"got {times['align_to']!r}")
    if times.get("align_to") == "imu" and raw is None:
        # (a bag's or a CSV's IMU has no packets to pair frames with; the message said 'give times.file instead' to a
        # user who had: a kitti2bag trial)
        how = ("remove align_to and put the file on the IMU's clock with t0_s (the stamp of its frame 0: KITTI's raw "
               "packet 0's, plus the odometry's own offset)" if "file" in times else
               "give times.file with t0_s (the stamp of its frame 0 on the IMU's clock)")
        raise ConfigError(f"{ctx.at(times, 'align_to')}: times.align_to: imu pairs frames with kitti_oxts packets, and "
                          f"the IMU here is not read as packets: {how}")
    offset = times.get("index_offset", 0)
    if isinstance(offset, bool) or not isinstance(offset, int):
        raise ConfigError(f"{ctx.at(times, 'index_offset')}: times.index_offset must be an integer, got {offset!r}")
    if "t0_s" in times and not _num(times["t0_s"]):
        raise ConfigError(f"{ctx.at(times, 't0_s')}: times.t0_s must be a number of seconds, got {times['t0_s']!r}")
    if "file" in times and not isinstance(times["file"], str):
        raise ConfigError(f"{ctx.at(times, 'file')}: times.file must be a file name, got {times['file']!r}")
    if "file" in times:
        tpath = ctx.root / times["file"]
        t, _ = kitti_poses.read_times(tpath)
        if t.size != n_poses:
            raise DataFormatError(tpath, None, f"expected {n_poses} times (one per pose in {pose_path.name}), got {t.size}")
        if times.get("align_to") == "imu":
            # The times file counts from its own zero; put it on the raw clock with the median offset
            # of the frames whose raw packet is a real (not filled-in) one.
            j = np.arange(n_poses) + offset
            ok = (j >= 0) & (j < raw.t_s.size)
            ok[ok] &= ~raw.filled[j[ok]]
            if not ok.any():
                raise DataRangeError(f"{ctx.at(times, 'index_offset')}: no lidar frame maps onto a valid IMU packet (index_offset {offset})")
            d = raw.t_s[j[ok]] - t[ok]
            shift = float(np.median(d))
            t = t + shift
            # said in the report: the shift carries the odometry's own offset from the packets (KITTI's 59 ms), which
            # left no trace beside "time offsets added: none" (a review against the shared data's README)
            ctx.notes["times_aligned"] = {"file": str(times["file"]), "shift_s": shift, "frames": int(ok.sum()),
                                          "spread_ms": float(np.median(np.abs(d - shift)) * 1e3), "index_offset": offset}
        elif "t0_s" in times:
            t = t + float(times["t0_s"])
        return t
    if times.get("align_to") == "imu":
        j = np.arange(n_poses) + offset
        if j[0] < 0 or j[-1] >= raw.t_s.size:
            raise DataRangeError(f"{ctx.at(times, 'index_offset')}: lidar frames 0..{n_poses - 1} with index_offset {offset} map outside the "
                                 f"{raw.t_s.size} IMU packets; give a times file or another index_offset")
        smooth = times.get("smooth_s")
        if smooth is None:
            return raw.t_s[j].copy()
        if not _num(smooth) or smooth <= 0:
            raise ConfigError(f"{ctx.at(times, 'smooth_s')}: times.smooth_s must be a positive number of seconds, got {smooth!r}")
        t, ctx.notes["clock"] = clock.smooth_frame_times(raw.t_s[j], ~raw.filled[j], float(smooth))
        return t
    raise ConfigError(f"{ctx.at(entry, 'times')}: 'times' needs 'file' or 'align_to: imu'")


def read_kitti_poses(entry: dict, ctx: ReadContext) -> PoseSeries:
    """A KITTI pose file ``T_c0_ci`` with its times, as poses of its sensor frame."""
    path = ctx.path(entry)
    T, lines = kitti_poses.read_kitti_poses(path)
    t = pose_times(entry, ctx, T.shape[0])
    return PoseSeries(t_s=t, p_w_m=T[:, :3, 3], q_wb_xyzw=matrix_to_quat_xyzw(T[:, :3, :3]), source=str(path), lines=lines)


def read_tum_gnss(entry: dict, ctx: ReadContext) -> GnssSeries:
    """TUM positions already in the world frame as fixes with the entry's ``std_m`` (default 1 m)."""
    poses = tum.read_tum(ctx.path(entry))
    std = std_m(entry, ctx, default=1.0)
    return GnssSeries(t_s=poses.t_s, p_w_m=poses.p_w_m, std_w_m=np.tile(std, (len(poses), 1)), source=poses.source,
                      lines=poses.lines)


READERS = {
    "kitti_oxts": {
        "imu": lambda e, ctx: kitti_oxts.imu_from_oxts(ctx.oxts(e)),
        "gnss": lambda e, ctx: kitti_oxts.gnss_from_oxts(ctx.oxts(e), _origin(ctx, "GNSS from OXTS")),
        "groundtruth": lambda e, ctx: kitti_oxts.poses_from_oxts(ctx.oxts(e), _origin(ctx, "ground truth from OXTS")),
        "odometer": lambda e, ctx: kitti_oxts.speed_from_oxts(ctx.oxts(e)),
    },
    "kitti_poses": {"groundtruth": read_kitti_poses, "lidar": read_kitti_poses},
    "tum": {"gnss": read_tum_gnss, "groundtruth": lambda e, ctx: tum.read_tum(ctx.path(e)),
            "lidar": lambda e, ctx: tum.read_tum(ctx.path(e))},
    "csv_lla": {"gnss": lambda e, ctx: gnss_csv.read_gnss_csv(ctx.path(e), _origin(ctx, "GNSS in geodetic coordinates"))},
    "speed_txt": {"odometer": lambda e, ctx: speed.read_speed(ctx.path(e))},
}
# a geodetic GNSS stream's first fix (the local frame's origin where the manifest gives none)
FIRST_FIX = {"csv_lla": lambda e, ctx: gnss_csv.first_fix(ctx.path(e))}
