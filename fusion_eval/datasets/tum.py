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


def stamp_decimals(t_s: np.ndarray) -> int:
    """Decimals of a stamp column: 9 (nanoseconds), or as many as a float64 stamp of this size holds exactly
    (6 for Unix stamps of ~1.3e9 s, whose spacing is 0.24 us)."""
    big = float(np.max(np.abs(t_s), initial=1.0))
    return int(max(0, min(9, np.floor(np.log10(2.0 ** 53 / max(big, 1.0))))))


def tum_chunks(poses: PoseSeries, header: str | None = None):
    """TUM text as ``bytes`` chunks: positions and quaternions with 9 decimals (nanometres), stamps with
    :func:`stamp_decimals`; evo reading it back gives the same metrics to 1e-6. Formatted by the compiled table
    writer a chunk at a time (a simulated hour at 200 Hz is 5.8 million numbers: streamed into its file, it is
    never held whole)."""
    from ..fastfmt import table_chunks

    if header:
        yield "".join(f"# {h}\n" for h in header.splitlines()).encode("utf-8")
    mat = np.column_stack([poses.t_s, poses.p_w_m, poses.q_wb_xyzw])
    if mat.size and np.all(np.isfinite(mat)) and np.abs(mat[:, 1:]).max() < 9e6:
        yield from table_chunks(mat, [stamp_decimals(poses.t_s)] + [9] * 7)
    else:       # non-finite or huge values (a diverged dead reckoning): Python's formatting handles them
        yield "".join(" ".join(f"{x:.9f}" for x in row) + "\n" for row in mat).encode()


def format_tum(poses: PoseSeries, header: str | None = None) -> str:
    """The TUM text of :func:`tum_chunks` as one string."""
    return b"".join(tum_chunks(poses, header)).decode("utf-8")
