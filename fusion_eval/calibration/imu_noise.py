"""White-noise densities of the IMU channels, from the data alone.

What the filter's process noise has to cover at the IMU's own rate is everything the mechanization cannot
predict from one sample to the next: the sensor's white noise and, for a point-sampled 10 Hz stream like
KITTI's OXTS, the motion between samples (vibration, road texture). Both show in the second difference
``x[k+1] - 2 x[k] + x[k-1]`` of each channel, whose variance is ``6 sigma^2`` for white noise of std
``sigma`` per sample while a smooth motion contributes ``O(T^4)``. The estimate is the median absolute
deviation of those differences over the drive (robust to the turns and the few glitches), as a density
``sigma sqrt(T)``, the RMS over the three axes (the filter's noise is isotropic). Only triples of equal
intervals are used (gaps of dropped packets would alias the motion into the estimate).
"""

from __future__ import annotations

import numpy as np

from ..errors import DataRangeError
from ..types import ImuSeries


def white_noise_density(t_s: np.ndarray, x: np.ndarray, source: str = "the IMU") -> float:
    """The white-noise density (units of x per sqrt(Hz)) of a 3-axis channel; see the module docstring."""
    dt = np.diff(t_s)
    T = float(np.median(dt))
    regular = (np.abs(dt[:-1] - T) < 0.1 * T) & (np.abs(dt[1:] - T) < 0.1 * T)
    if regular.sum() < 20:
        # (a driver stamping two samples per transfer 20 us apart has no two equal intervals in a row; the message
        # named neither the stream nor the settings that avoid the estimate)
        raise DataRangeError(f"{source}: too few regularly spaced samples ({int(regular.sum())} of {max(dt.size - 1, 0)} "
                             f"pairs of equal intervals; median interval {T * 1e3:.3g} ms) to estimate the IMU's noise "
                             "from: give imu.accel_noise_mps2_sqrthz and imu.gyro_noise_dps_sqrthz (a datasheet's "
                             "densities) instead of 'auto'")
    d2 = (x[2:] - 2 * x[1:-1] + x[:-2])[regular]
    mad = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    sigma = mad / np.sqrt(6.0)
    return float(np.sqrt(np.mean(sigma ** 2)) * np.sqrt(T))


def estimate(imu: ImuSeries) -> dict[str, float]:
    """``accel_mps2_sqrthz`` and ``gyro_rps_sqrthz`` of the (filled-packet-free) IMU stream."""
    return {"accel_mps2_sqrthz": white_noise_density(imu.t_s, imu.f_b_mps2, imu.source),
            "gyro_rps_sqrthz": white_noise_density(imu.t_s, imu.w_b_rps, imu.source)}
