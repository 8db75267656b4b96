"""EuRoC MAV / TUM-VI ASL folders (``format: euroc``).

Layout (``mav0/`` below the sequence folder)::

    imu0/data.csv                          #timestamp [ns], w_RS_S_x/y/z [rad/s], a_RS_S_x/y/z [m/s^2]
    state_groundtruth_estimate0/data.csv   #timestamp [ns], p_RS_R_x/y/z [m], q_RS_w/x/y/z, v_RS_R_x/y/z [m/s], biases
    mocap0/data.csv (TUM-VI)               #timestamp [ns], p_RS_R_x/y/z [m], q_RS_w/x/y/z
    leica0/data.csv (EuRoC machine hall)   #timestamp [ns], p_RS_R_x/y/z [m]   (a position only: read as a 'gnss' stream)

Frames: ``S`` is the IMU (body) frame, ``R`` the ground-truth world frame (z up), so the ground-truth poses are IMU
poses (``frame: imu``). Quaternions are w-first in the files. Stamps are integer nanoseconds, converted exactly
(:func:`_text.ns_to_s`). A plain sequence folder works without a manifest (:func:`implicit_streams`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataFormatError
from ..types import GnssSeries, ImuSeries, PoseSeries
from ._text import ns_to_s
from .csv_stream import load_table, std_m
from .streams import ReadContext

KEYS = frozenset({"std_m"})
IMU_FILE = "imu0/data.csv"
GT_FILES = ("state_groundtruth_estimate0/data.csv", "mocap0/data.csv")


def find_root(path: Path) -> Path | None:
    """The ``mav0`` folder of a EuRoC / TUM-VI sequence (the sequence folder or ``mav0`` itself), or None."""
    for d in (Path(path) / "mav0", Path(path)):
        if (d / IMU_FILE).exists():
            return d
    return None


def implicit_streams(folder: Path) -> dict | None:
    """The manifest streams of a plain EuRoC / TUM-VI folder: the IMU, and the ground truth where there is one."""
    root = find_root(folder)
    if root is None:
        return None
    rel = root.relative_to(folder) if root != Path(folder) else Path(".")
    streams = {"imu": {"format": "euroc", "path": str(rel / IMU_FILE)}}
    gt = next((g for g in GT_FILES if (root / g).exists()), None)
    if gt is not None:
        streams["groundtruth"] = {"format": "euroc", "path": str(rel / gt)}
    return streams


def _rows(path: Path, what: str, ncols: int, exact: bool = False):
    rows, ns, lines = load_table(path, what, ncols, ",", stamp_col=0, ncols_exact=ncols if exact else None)
    return rows, ns_to_s(ns), lines


def read_imu(entry: dict, ctx: ReadContext) -> ImuSeries:
    path = ctx.path(entry)
    rows, t, lines = _rows(path, "EuRoC IMU CSV (#timestamp [ns],w_x,w_y,w_z [rad/s],a_x,a_y,a_z [m/s^2])", 7, exact=True)
    if rows.shape[1] != 7:
        raise DataFormatError(path, int(lines[0]), f"EuRoC IMU CSV: expected 7 values per row, got {rows.shape[1]}")
    return ImuSeries(t_s=t, f_b_mps2=rows[:, 4:7], w_b_rps=rows[:, 1:4], source=str(path), lines=lines)


def read_poses(entry: dict, ctx: ReadContext) -> PoseSeries:
    path = ctx.path(entry)
    rows, t, lines = _rows(path, "EuRoC pose CSV (#timestamp [ns],p_x,p_y,p_z [m],q_w,q_x,q_y,q_z[,v_x,v_y,v_z,...])", 8)
    v = rows[:, 8:11] if rows.shape[1] >= 11 else None
    return PoseSeries(t_s=t, p_w_m=rows[:, 1:4], q_wb_xyzw=rows[:, [5, 6, 7, 4]], v_w_mps=v, source=str(path), lines=lines)


def read_positions(entry: dict, ctx: ReadContext) -> GnssSeries:
    """A position stream (``leica0``: #timestamp [ns], p_x, p_y, p_z) as local fixes with the entry's ``std_m``."""
    path = ctx.path(entry)
    rows, t, lines = _rows(path, "EuRoC position CSV (#timestamp [ns],p_x,p_y,p_z [m])", 4, exact=True)
    return GnssSeries(t_s=t, p_w_m=rows[:, 1:4], std_w_m=np.tile(std_m(entry, ctx), (t.size, 1)), source=str(path), lines=lines)


READERS = {"imu": read_imu, "groundtruth": read_poses, "lidar": read_poses, "gnss": read_positions}
