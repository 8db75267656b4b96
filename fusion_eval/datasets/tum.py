"""TUM trajectory files: ``timestamp tx ty tz qx qy qz qw`` per line (8 values), ``#`` comments.

The TUM format stores quaternions in (x, y, z, w) order, which is also the package's internal
order; only evo's in-memory objects use (w, x, y, z) (see :mod:`fusion_eval.so3`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..types import PoseSeries
from ._text import parse_numeric_rows, read_text


def read_tum(path: Path) -> PoseSeries:
    """Read and validate a TUM trajectory file."""
    path = Path(path)
    rows, lines = parse_numeric_rows(path, read_text(path, "a TUM trajectory, 8 values per line"), 8,
                                     "TUM trajectory file (timestamp tx ty tz qx qy qz qw)")
    return PoseSeries(t_s=rows[:, 0], p_w_m=rows[:, 1:4], q_wb_xyzw=rows[:, 4:8], source=str(path), lines=lines)


def format_tum(poses: PoseSeries, header: str | None = None) -> str:
    """TUM text with 9 decimals (nanoseconds, nanometres): evo reading it back gives the same metrics to 1e-6."""
    out = []
    if header:
        out.extend(f"# {h}" for h in header.splitlines())
    mat = np.column_stack([poses.t_s, poses.p_w_m, poses.q_wb_xyzw])
    out.extend(" ".join(f"{x:.9f}" for x in row) for row in mat)
    return "\n".join(out) + "\n"
