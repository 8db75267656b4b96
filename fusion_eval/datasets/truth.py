"""What a simulated drive knows and real data never gives: the manifest's ``truth`` entry.

``fusion-eval simulate`` writes ``truth: {imu_biases: truth/imu_biases.csv, ...}`` into its manifest (paths
relative to the manifest's folder); :func:`fusion_eval.datasets.manifest.load_dataset` keeps that entry in
``Dataset.description["truth"]``. Only the IMU biases are read here, for the bias plot's overlay.

Clock: the bias file's ``t_s`` are the stamps the simulator gave the IMU samples (POSIX seconds, the same
floats as the IMU stream's stamps, to the file's microsecond); a run moves the IMU stream by its
``imu.time_offset_s``, so the truth is moved by the same offset to meet the filter's stamps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataFormatError
from .csv_stream import load_table

BIAS_COLUMNS = ("t_s", "ba_x_mps2", "ba_y_mps2", "ba_z_mps2", "bg_x_rps", "bg_y_rps", "bg_z_rps")


@dataclass(frozen=True)
class TruthBiases:
    """True IMU biases in the body (IMU) frame: ``t_s`` (N,) s, ``accel_b_mps2`` and ``gyro_b_rps`` (N, 3)."""

    t_s: np.ndarray
    accel_b_mps2: np.ndarray
    gyro_b_rps: np.ndarray
    source: str = "<truth>"


def read_imu_biases(path: str | Path) -> TruthBiases:
    """A ``truth/imu_biases.csv`` as the simulator writes it (header :data:`BIAS_COLUMNS`, one row per IMU sample)."""
    what = "true IMU biases (" + ",".join(BIAS_COLUMNS) + ")"
    rows, _, _ = load_table(Path(path), what, len(BIAS_COLUMNS), ncols_exact=len(BIAS_COLUMNS))   # names bad lines
    with open(path, encoding="utf-8", errors="replace") as fh:     # the columns' order, from the header line
        header = fh.readline().strip()
    if [c.strip() for c in header.split(",")] != list(BIAS_COLUMNS):
        raise DataFormatError(path, 1, f"expected the header {','.join(BIAS_COLUMNS)}, got {header[:80]!r}")
    return TruthBiases(t_s=rows[:, 0], accel_b_mps2=rows[:, 1:4], gyro_b_rps=rows[:, 4:7], source=str(path))


def truth_imu_biases(description: dict, imu_time_offset_s: float = 0.0) -> TruthBiases | None:
    """The true IMU biases of a dataset whose manifest names ``truth.imu_biases`` (a simulated drive), on the
    run's clock (the file's stamps plus the IMU time offset the run applied); None for any other dataset.

    ``description``: ``Dataset.description`` (its ``manifest`` path and ``truth`` entry).
    """
    truth = description.get("truth")
    rel = truth.get("imu_biases") if isinstance(truth, dict) else None
    if not rel or not description.get("manifest"):
        return None
    tb = read_imu_biases(Path(description["manifest"]).parent / rel)
    return TruthBiases(t_s=tb.t_s + float(imu_time_offset_s), accel_b_mps2=tb.accel_b_mps2, gyro_b_rps=tb.gyro_b_rps,
                       source=tb.source)
