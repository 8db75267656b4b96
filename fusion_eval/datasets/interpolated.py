"""IMU samples a data provider interpolated, found in the values themselves.

KITTI fills the gaps of its OXTS logs with packets whose values are straight lines between the real packets around
them (sample by sample, in every channel) and marks them in status fields that only its own text format carries. A
bag made from the drive (kitti2bag and the like), or a CSV export, keeps the values and loses the marks: the filter
then integrates 1.5 s ramps as measurements (kitti-00 with its filled packets kept: fused APE 1.55 m against 0.753).

A line between two real samples moves every channel (each endpoint carries its own noise: all of KITTI's 149 ramp
steps on the four raw drives do), and a real sample lies on the straight line of its two neighbours in all six
channels to 1e-9 only by accident, two in a row practically never: that is what is looked for here. What is left
alone:
- a sample where any channel does not change: a noise-free simulation's ramps (a clothoid's yaw rate and lateral
  force, the other channels constant), a coarsely quantised IMU with channels at rest or saturated;
- a stream where such samples are not rare (over :data:`MAX_SHARE` of it: too many to be the repair of a few gaps,
  as in a stream upsampled by linear interpolation), which is said instead of dropped: dropping most of a stream
  would turn it into gaps;
- values stored with too few digits: a ramp rounded to d decimals leaves its line by up to 1e-d, so text with fewer
  than about 12 decimals hides some or all of it (kitti 2011_10_03_0027 rounded to 8, 10, 12 decimals: 3, 41, 134 of
  its 134 packets found), and float32 values hide all of it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..stats import true_runs

REL_TOL = 1e-9          # a sample on its neighbours' line: |v[i-1] - 2 v[i] + v[i+1]| <= REL_TOL (their magnitudes)
MIN_RUN = 2             # consecutive such samples: one alone happens in coarsely quantised data at rest
MAX_SHARE = 0.2         # above this share of the stream, interpolation is the stream's nature, not a repair


@njit(cache=True)
def _inner_points(v):
    """``out[i]``: sample ``i + 1`` lies on the line of its neighbours in every channel, and every channel changes (one
    pass: numpy's per-channel temporaries took 0.16 s on an hour at 200 Hz)."""
    n, m = v.shape
    out = np.zeros(n - 2, np.bool_)
    tiny = np.finfo(np.float64).tiny
    for i in range(n - 2):
        ramp = True
        for ch in range(m):
            a, b, c = v[i, ch], v[i + 1, ch], v[i + 2, ch]
            if not (abs(a - 2.0 * b + c) <= REL_TOL * (abs(a) + 2.0 * abs(b) + abs(c)) + tiny
                    and abs(c - b) > REL_TOL * (abs(b) + abs(c)) + tiny):
                ramp = False
                break
        out[i] = ramp
    return out


def linear_runs(values: np.ndarray) -> np.ndarray:
    """Samples of ``values`` ``(N, C)`` that are the inner points of straight lines, in sample index, in every
    channel at once, every channel changing, in runs of at least :data:`MIN_RUN`; a run reaching the first or last
    sample takes it too (KITTI extrapolates its first packets: no real sample starts that line; where one does, it
    goes with the run). A boolean mask ``(N,)``."""
    v = np.asarray(values, float)
    n = v.shape[0]
    out = np.zeros(n, bool)
    if n < MIN_RUN + 2:
        return out
    inner = _inner_points(np.ascontiguousarray(v))
    if not inner.any():
        return out
    for s, e in zip(*true_runs(inner)):
        if e - s >= MIN_RUN:
            out[s + 1:e + 1] = True          # inner index i is sample i + 1
    if out[1]:
        out[0] = True
    if out[-2]:
        out[-1] = True
    return out


def interpolated_imu(imu) -> tuple[np.ndarray, str | None]:
    """The IMU samples to take as filled-in (a mask; none where the provider marked its own), and a sentence for
    the report where any were found, or where they are too many to be a repair and are kept."""
    found = linear_runs(np.hstack([imu.f_b_mps2, imu.w_b_rps])) & ~imu.filled
    k = int(found.sum())
    if not k:
        return found, None
    runs = true_runs(found)[0].size
    what = (f"imu: {k} samples in {runs} run(s) lie exactly on the straight line between their neighbours in all six "
            "channels")
    if k > MAX_SHARE * len(imu):
        return np.zeros_like(found), (f"{what} ({100.0 * k / len(imu):.0f} % of the stream: too many to be the "
                                      "repair of a few gaps, as in an IMU upsampled by linear interpolation): kept as "
                                      "measurements")
    return found, (f"{what}: a provider's interpolation (as KITTI's filled-in packets, which a bag or a CSV cannot "
                   "mark), taken as filled-in packets")
