"""Streams beyond the built-in ones (imu, groundtruth, gnss, lidar, odometer), declared by the observation
that reads them: its manifest name, the formats it can be read from (one reader each), the manifest keys
it accepts, and how a run prepares it (time offset, dropping filled packets, degradation).

The manifest validates and reads a declared stream exactly like a built-in one; the run's preparation
(:func:`fusion_eval.prepare.prepare`) calls :attr:`StreamSpec.prepare` on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .. import yaml_lines


@dataclass
class ReadContext:
    """What a reader needs besides its stream's manifest entry."""

    root: Path                                  # the manifest's folder
    manifest: Path
    origin: tuple[float, float, float] | None   # the geodetic origin of the local ENU world frame
    oxts: Callable[[dict], Any]                 # the (cached) KITTI OXTS packets of an entry's path
    imu_packets: Any = None                     # the IMU's OXTS packets (kitti_oxts IMU): a pose file's clock
    notes: dict = field(default_factory=dict)   # what a reader found out (a recovered frame clock), for the run

    def path(self, entry: dict) -> Path:
        return self.root / entry["path"]

    def at(self, entry: dict | None = None, key: str | None = None) -> str:
        """Where ``key`` of a manifest entry is, ``manifest:line``, for a reader's message."""
        return yaml_lines.at(self.manifest, entry, key)


@dataclass(frozen=True)
class StreamSpec:
    name: str
    what: str                                               # the quantity, frame and unit, for messages
    readers: dict = field(default_factory=dict)             # format -> reader(entry, ctx) -> series
    keys: frozenset = frozenset({"format", "path", "time_offset_s", "degrade"})
    degrade_formats: frozenset = frozenset()                # formats degraded unless the entry says degrade: false
    implicit_kitti_raw: bool = False                        # read from oxts/ of a plain KITTI raw drive folder
    # prepare(series, cfg, t_ref_s, degrade: bool) -> (series, info): a run's degradation of the stream
    prepare: Callable | None = None
