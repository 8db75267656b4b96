"""Manifest streams read from ROS 1 / ROS 2 bags (``format: rosbag``), through :mod:`fusion_eval.datasets.rosbag`::

    imu:         {format: rosbag, path: drive.bag, topic: /imu/data}                 # sensor_msgs/Imu
    gnss:        {format: rosbag, path: drive.bag, topic: /gps/fix}                  # sensor_msgs/NavSatFix
    groundtruth: {format: rosbag, path: drive.bag, topic: /gt/odom}                  # nav_msgs/Odometry, PoseStamped, ...
    lidar:       {format: rosbag, path: drive.bag, topic: /tf, child_frame: velodyne, frame: velodyne,
                  T_imu_velodyne: {tf_static: [imu_link, velodyne]}}                 # a TF child frame, its extrinsic
    odometer:    {format: rosbag, path: drive.bag, topic: /wheel/odom}               # Odometry: forward body speed

``stamps: header`` (default) takes each message's header stamp, ``record`` the bag's record time. A NavSatFix
without a covariance needs the entry's ``std_m``. The path is a ``.bag`` file, a ROS 2 bag folder, a ``.db3`` or an
``.mcap`` file.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import ConfigError, MissingTopicError
from ..types import SpeedSeries
from .streams import ReadContext

log = logging.getLogger(__name__)

_POSE_TOPIC = frozenset({"topic", "stamps", "child_frame", "parent_frame"})    # a /tf topic names its frames
KEYS = {"imu": frozenset({"topic", "stamps", "frame_id"}), "gnss": frozenset({"topic", "stamps", "std_m", "frame_id"}),
        "groundtruth": _POSE_TOPIC, "lidar": _POSE_TOPIC, "odometer": _POSE_TOPIC}


def _topic(entry: dict, ctx: ReadContext) -> str:
    t = entry.get("topic")
    if not isinstance(t, str) or not t:
        raise ConfigError(f"{ctx.at(entry)}: a rosbag stream needs 'topic' (the topic to read)")
    stamps = entry.get("stamps", "header")
    if stamps not in ("header", "record"):
        raise ConfigError(f"{ctx.at(entry, 'stamps')}: 'stamps' must be 'header' or 'record', got {stamps!r}")
    return t


def read_imu(entry: dict, ctx: ReadContext):
    from . import rosbag

    return rosbag.read_imu(ctx.path(entry), _topic(entry, ctx), stamps=entry.get("stamps", "header"),
                           frame_id=_frame_id(entry, ctx))


def _frame_id(entry: dict, ctx: ReadContext) -> str | None:
    """The entry's ``frame_id`` (which sensor's messages to read where two publish on one topic), or None."""
    v = entry.get("frame_id")
    if v is not None and (not isinstance(v, str) or not v):
        raise ConfigError(f"{ctx.at(entry, 'frame_id')}: 'frame_id' must be a frame name (a message's header.frame_id)")
    return v


def read_gnss(entry: dict, ctx: ReadContext):
    from . import rosbag
    from .csv_stream import std_m

    topic = _topic(entry, ctx)
    if ctx.origin is None:
        raise ConfigError(f"{ctx.at(entry)}: NavSatFix fixes need a geodetic_origin ('first_fix' or [lat, lon, alt])")
    default = std_m(entry, ctx) if "std_m" in entry else None
    return rosbag.read_navsatfix(ctx.path(entry), topic, ctx.origin, stamps=entry.get("stamps", "header"),
                                 default_std_m=default, frame_id=_frame_id(entry, ctx))


def first_fix(entry: dict, ctx: ReadContext):
    from . import rosbag

    return tuple(float(v) for v in rosbag.first_fix(ctx.path(entry), _topic(entry, ctx), _frame_id(entry, ctx)))


def read_poses(entry: dict, ctx: ReadContext):
    from . import rosbag

    frames: dict = {}
    poses = rosbag.read_poses(ctx.path(entry), _topic(entry, ctx), stamps=entry.get("stamps", "header"),
                              child_frame=entry.get("child_frame"), parent_frame=entry.get("parent_frame"), frames=frames)
    _check_frame(entry, ctx, frames)
    return poses


def _check_frame(entry: dict, ctx: ReadContext, frames: dict) -> None:
    """Warn where the poses are of another frame than the one whose extrinsic the manifest takes from /tf_static:
    odometry of ``velo_link`` (its messages' child_frame_id) given ``T_imu_base: {tf_static: [imu_link, base_link]}``
    made the fused APE 1.11 m for 0.76 with no word (a bag review). Only where both frames are named in the bag (a
    frame's name in a manifest may differ from its frame_id)."""
    frame = entry.get("frame")
    spec = entry.get(f"T_imu_{frame}") if isinstance(frame, str) else None
    pair = spec.get("tf_static") if isinstance(spec, dict) else None
    children = {c for (_, c) in frames if c}            # ('' where a driver leaves child_frame_id unset)
    if not (isinstance(pair, list) and len(pair) == 2 and children):
        return
    from .rosbag import _strip

    want = _strip(str(pair[1]))
    if want in children:
        return
    have = ", ".join(f"'{c}'" for c in sorted(children))
    log.warning("%s: the poses of topic %s are of frame %s (their child_frame_id), but the extrinsic taken is %s's "
                "(T_imu_%s: tf_static %s -> %s): name the frame the poses are of (tf_static: [%s, %s]), or check the "
                "topic", ctx.at(entry, "topic"), entry.get("topic"), have, want, frame, pair[0], pair[1], pair[0],
                sorted(children)[0])


def read_speed(entry: dict, ctx: ReadContext) -> SpeedSeries:
    """The forward speed of an Odometry topic: its twist (child frame) along the body x axis."""
    poses = read_poses(entry, ctx)
    if poses.v_w_mps is None:
        raise ConfigError(f"{ctx.at(entry, 'topic')}: odometer topic {entry['topic']!r} has no twist (expected nav_msgs/Odometry)")
    v_b = np.einsum("nji,nj->ni", poses.R_wb(), poses.v_w_mps)
    return SpeedSeries(t_s=poses.t_s, v_mps=v_b[:, 0], source=poses.source)


def _at_the_topic_line(read):
    """``read`` with a topic the bag lacks named at the manifest's line (the topic's), where it is fixed."""
    def named(entry: dict, ctx: ReadContext):
        try:
            return read(entry, ctx)
        except MissingTopicError as exc:
            raise ConfigError(f"{ctx.at(entry, 'topic')}: {exc.expected} in {exc.path}") from None
    named.__name__, named.__doc__ = read.__name__, read.__doc__
    return named


READERS = {k: _at_the_topic_line(f) for k, f in {"imu": read_imu, "gnss": read_gnss, "groundtruth": read_poses,
                                                 "lidar": read_poses, "odometer": read_speed}.items()}
first_fix = _at_the_topic_line(first_fix)
