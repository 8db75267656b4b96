"""Wheel-odometer speed: ``t_s v_mps`` per line (forward speed, m/s), ``#`` comments allowed."""

from __future__ import annotations

from pathlib import Path

from ..types import SpeedSeries
from ._text import parse_numeric_rows, read_text


def read_speed(path: Path) -> SpeedSeries:
    path = Path(path)
    rows, lines = parse_numeric_rows(path, read_text(path, "odometer speed 't_s v_mps' per line"), 2,
                                     "odometer file (t_s v_mps)")
    return SpeedSeries(t_s=rows[:, 0], v_mps=rows[:, 1], source=str(path), lines=lines)
