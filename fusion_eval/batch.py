"""Runs that may share one data preparation: a sweep's batches and a tune's trials on one worker."""

from __future__ import annotations

import hashlib
import json

# Keys that only the filter reads: not the data preparation, not the evaluation (checked: prepare, timing,
# degrade, calibration, datasets and evaluation read none of them, but for whether an IMU density is 'auto').
# Runs of one dataset whose configurations differ only in these are one batch: the data is loaded and
# prepared once, the unfiltered estimates evaluated once, and each run replays and evaluates its own filter.
FILTER_ONLY_KEYS = (
    "imu.accel_noise_mps2_sqrthz", "imu.gyro_noise_dps_sqrthz", "imu.accel_noise_scale", "imu.gyro_noise_scale",
    "imu.accel_bias_rw_mps3_sqrthz",
    "imu.gyro_bias_rw_dps2_sqrthz", "imu.gap_noise_scale", "imu.accel_bias_corr_time_s", "imu.gyro_bias_corr_time_s",
    "lidar.relative_pos_std_m", "lidar.relative_pos_std_frac", "lidar.relative_att_std_deg",
    "lidar.relative_att_std_frac", "lidar.gate_prob", "lidar.noise_adapt", "lidar.adapt_rate",
    "lidar.absolute_pos_std_m", "lidar.absolute_att_std_deg", "filter.nhc_std_mps", "gnss.std_scale",
    "odometer.speed_noise_mps_sqrthz", "odometer.slip_noise_mps_sqrthz", "odometer.scale_rw_per_sqrts",
    "init.pos_std_m", "init.vel_std_mps", "init.roll_pitch_std_deg", "init.yaw_std_deg", "init.accel_bias_std_mps2",
    "init.gyro_bias_std_dps", "init.odometer_scale_std",
)


def batch_key(dataset: str, cfg: dict) -> str:
    """Equal for two runs that may share one preparation: same dataset, same configuration but for the
    values of :data:`FILTER_ONLY_KEYS` (an 'auto' value stays distinct: preparation estimates it)."""
    masked = {sect: dict(body) for sect, body in cfg.items()}
    for k in FILTER_ONLY_KEYS:
        sect, key = k.split(".", 1)
        if key in masked.get(sect, {}):
            masked[sect][key] = "auto" if masked[sect][key] == "auto" else "<filter>"
    return hashlib.sha256(json.dumps({"dataset": dataset, "config": masked}, sort_keys=True,
                                     default=str).encode()).hexdigest()[:12]
