"""The registry of stream formats: KITTI's family (``kitti_oxts``, ``kitti_poses``, ``tum``, ``csv_lla``,
``speed_txt``), EuRoC, generic CSV and ROS bags, each one module with a reader per stream it can carry; the
manifest validates an entry and calls its format's reader, whatever the format.

A format's reader takes the stream's manifest entry and a :class:`~fusion_eval.datasets.streams.ReadContext` and
returns the stream's typed series; ``keys`` are the manifest keys it accepts besides ``format``, ``path`` and the
common ones; ``first_fix`` (optional) gives a geodetic origin from a GNSS stream of that format. Adding a format is
one module and one line in the list of :func:`_formats`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable


@dataclass(frozen=True)
class StreamFormat:
    name: str
    readers: dict                                       # stream name -> reader(entry, ctx) -> series
    keys: frozenset | dict = frozenset()                # the keys it reads, or per stream: {stream: keys}
    first_fix: Callable | None = None                   # (entry, ctx) -> (lat, lon, alt) | None
    description: str = ""
    notes: dict = field(default_factory=dict)
    quaternion: str | None = None                       # 'xyzw' or 'wxyz': the order its files write a rotation in

    def keys_for(self, stream: str) -> frozenset:
        """The manifest keys this format reads for ``stream`` (a key it does not read there is refused, not
        ignored: a bag's IMU given ``std_m`` or a GNSS ``child_frame`` ran as if they were not there)."""
        return self.keys.get(stream, frozenset()) if isinstance(self.keys, dict) else self.keys


def _formats() -> dict[str, StreamFormat]:
    from . import csv_stream, euroc, kitti_formats, rosbag_streams

    fmts = [*(StreamFormat(name, readers, description="KITTI family", quaternion="xyzw" if name == "tum" else None,
                           first_fix=kitti_formats.FIRST_FIX.get(name))
              for name, readers in kitti_formats.READERS.items()),
        StreamFormat("euroc", euroc.READERS, euroc.KEYS, description="EuRoC / TUM-VI ASL CSV", quaternion="wxyz"),
        StreamFormat("csv", {"imu": csv_stream.read_imu, "gnss": csv_stream.read_gnss, "groundtruth": csv_stream.read_poses,
                             "lidar": csv_stream.read_poses, "odometer": csv_stream.read_speed},
                     csv_stream.KEYS, first_fix=csv_stream.first_fix, description="generic CSV with named columns",
                     quaternion="xyzw"),      # (named columns: qx qy qz qw, which a file written w-first mislabels)
        StreamFormat("rosbag", rosbag_streams.READERS, rosbag_streams.KEYS, first_fix=rosbag_streams.first_fix,
                     description="ROS 1 / ROS 2 bag topic"),
    ]
    return {f.name: f for f in fmts}


_CACHE: dict = {}


def formats() -> dict[str, StreamFormat]:
    if not _CACHE:
        _CACHE.update(_formats())
    return _CACHE


def for_stream(stream: str) -> dict[str, StreamFormat]:
    """The registered formats that can carry ``stream``."""
    return {n: f for n, f in formats().items() if stream in f.readers}
