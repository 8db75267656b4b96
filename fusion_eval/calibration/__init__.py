"""Calibration from the data alone (no ground truth): stream time offsets, the IMU channel lags, the lidar-IMU
extrinsic rotation."""

from .time_offset import Shifts, TimeEstimate, measure_shifts, resolve

__all__ = ["Shifts", "TimeEstimate", "measure_shifts", "resolve"]
