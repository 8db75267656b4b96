"""A trajectory file of any localization system: TUM (8 values per line) or KITTI poses (12 values per line),
told apart by their column count. KITTI files take their stamps from a times file; without one, poses are
matched by index (frame i gets the stamp i seconds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataFormatError
from ..so3 import matrix_to_quat_xyzw
from ..types import PoseSeries
from . import kitti_poses, tum
from ._text import read_text

BY_INDEX = "frame index (no times file)"


def read_trajectory(path: Path, times: Path | None = None) -> tuple[PoseSeries, str]:
    """A TUM or KITTI trajectory; returns it and how its stamps were obtained."""
    path = Path(path)
    first = next((ln for ln in read_text(path, "a TUM or KITTI trajectory").splitlines()
                  if ln.strip() and not ln.lstrip().startswith("#")), "")
    n = len(first.split())
    if n == 8:
        return tum.read_tum(path), "TUM stamps"
    if n != 12:
        raise DataFormatError(path, None, f"expected a TUM (8 values per line) or KITTI (12 values) trajectory, got {n} values")
    T, lines = kitti_poses.read_kitti_poses(path)
    if times is not None:
        t, _ = kitti_poses.read_times(times)
        if t.size != T.shape[0]:
            raise DataFormatError(times, None, f"expected {T.shape[0]} times (one per pose of {path.name}), got {t.size}")
        how = f"times from {Path(times).name}"
    else:
        t, how = np.arange(T.shape[0], dtype=float), BY_INDEX
    return PoseSeries(t_s=t, p_w_m=T[:, :3, 3], q_wb_xyzw=matrix_to_quat_xyzw(T[:, :3, :3]), source=str(path),
                      lines=lines), how
