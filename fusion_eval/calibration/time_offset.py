"""Time offsets of the lidar clock and of the gyro, estimated from the data by cross-correlation.

Two signals that the lidar odometry and the IMU both see, compared on a common fine grid for a range of
candidate shifts:

- **accelerometer vs lidar** (the lidar clock against the IMU clock): the lidar's world-frame acceleration
  (its positions differentiated twice) against the accelerometer rotated by the lidar's attitude. Gravity
  is a constant in that frame, solved out in closed form, so neither the anchoring of the odometry nor the
  gravity magnitude matters. The shift that minimises the residual is ``lidar.time_offset_s``: the true
  time of a lidar stamp ``t`` is ``t + offset``.
- **gyro vs lidar** (the gyro against the lidar clock): the body-frame rate of the lidar's rotation
  increments against the gyro. The residual is minimised over a free scale (the correlation coefficient
  is maximised), so an odometry that under-rotates every turn, as KISS-ICP does, does not pull the lag the
  way a residual of the raw increments does. The gyro lag is this shift minus the lidar offset: the gyro
  reports at ``t`` the rate of ``t - lag``.

Why correlation and not filter states: the offsets are constants of a drive, observable only in the
turns and the accelerations, and a batch estimate over the whole drive uses every one of them with no
tuning of a random-walk noise; it is also cheap (a fraction of a second) and reproducible. The
uncertainty is a block jackknife: the drive is split into ``blocks`` stretches of equal duration, the
estimate is repeated leaving each out, and the spread of those estimates gives the standard error, which
is honest about the correlation of neighbouring samples (a formal curvature-based variance is not).

Every signal goes through the same zero-phase path (linear interpolation onto a 5 ms grid, a Gaussian
low-pass): a symmetric filter delays neither side, so it cannot bias the shift. Grid points near a gap
in either stream (dropped filled-in OXTS packets, missing scans) are left out.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numba import njit
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation, Slerp

from ..errors import DataRangeError, ShiftAtSearchEdgeError
from ..stats import moving_mean
from ..types import ImuSeries, PoseSeries

GRID_S = 0.005          # comparison grid; the minimum is refined below it by a parabola
MAX_SHIFT_S = 0.25      # search range of each shift, +/- (KITTI's known lag is 60 ms)
ACCEL_SMOOTH_S = 0.25   # Gaussian sigma of the acceleration comparison: second differences of cm-level
                        # lidar positions at 10 Hz are metres/s^2 of noise unsmoothed
RATE_SMOOTH_S = 0.08    # Gaussian sigma of the rate comparison
BLOCKS = 10


@dataclass(frozen=True)
class TimeEstimate:
    """One estimated shift: value and jackknife standard error in seconds, and what it was found from."""

    value_s: float
    std_s: float
    method: str
    samples: int

    def as_dict(self) -> dict:
        return {"value_s": float(self.value_s), "std_s": float(self.std_s), "method": self.method, "samples": int(self.samples)}


def _valid_on_grid(t_src: np.ndarray, grid: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Grid points bracketed by two source samples at most ``max_gap_s`` apart."""
    j = np.searchsorted(t_src, grid)
    ok = (j > 0) & (j < t_src.size)
    jj = np.clip(j, 1, t_src.size - 1)
    return ok & (t_src[jj] - t_src[jj - 1] <= max_gap_s)


def turning_rps(imu: ImuSeries, about_median: bool = True) -> float:
    """How much the platform turns: the 90th percentile of the gyro's rate magnitude, averaged over half a second,
    about its median (``about_median``: what a time shift can be read from; a steady turn says nothing of it) or as
    it is (what shows a mount: a steady circle shows the lever arm in its centripetal acceleration). The half second
    in samples from the mean interval: the median of stamps that come in bursts is a fraction of it, and a 50 s
    window hid every turn (a review)."""
    t, w = np.asarray(imu.t_s, float), np.asarray(imu.w_b_rps, float)
    if w.shape[0] < 3 or not t[-1] > t[0]:
        return 0.0
    k = max(1, int(round(0.5 * (t.size - 1) / (t[-1] - t[0]))))
    mean = moving_mean(w - np.median(w, axis=0) if about_median else w, min(k, w.shape[0]))
    return float(np.percentile(np.linalg.norm(mean, axis=1), 90))


def _interp(t_src: np.ndarray, x: np.ndarray, grid: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(grid, t_src, x[:, i]) for i in range(x.shape[1])])


def _smooth(x: np.ndarray, valid: np.ndarray, sigma_s: float, step_s: float = GRID_S) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian low-pass on the grid (of ``step_s``); a point stays valid only if its whole kernel (+/- 3 sigma) is."""
    s = sigma_s / step_s
    m = gaussian_filter1d(valid.astype(float), s, axis=0, truncate=3.0)
    y = gaussian_filter1d(np.where(valid[:, None], x, 0.0), s, axis=0, truncate=3.0)
    return y, m > 1.0 - 1e-6


def _max_gap(t: np.ndarray) -> float:
    return 2.5 * float(np.median(np.diff(t)))


def _lidar_rates(lidar: PoseSeries) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame mean rates of the rotation increments (rad/s), at the increments' mid-times."""
    R = Rotation.from_quat(lidar.q_wb_xyzw)
    dt = np.diff(lidar.t_s)
    w = (R[:-1].inv() * R[1:]).as_rotvec() / dt[:, None]
    return 0.5 * (lidar.t_s[:-1] + lidar.t_s[1:]), w


def _shifts(max_shift_s: float) -> np.ndarray:
    k = int(round(max_shift_s / GRID_S))
    return np.arange(-k, k + 1)


def _refine(cost: np.ndarray, shifts: np.ndarray) -> float:
    """Shift (s) at the minimum of ``cost``, refined by a parabola through the best grid point and its neighbours."""
    i = int(np.argmin(cost))
    x = float(shifts[i]) * GRID_S
    if 0 < i < cost.size - 1:
        c0, c1, c2 = cost[i - 1:i + 2]
        d = c0 - 2 * c1 + c2
        if d > 0:
            x += float(0.5 * GRID_S * (c0 - c2) / d)
    return x


def _jackknife(per_block_cost, shifts: np.ndarray, blocks: int) -> tuple[float, float, np.ndarray]:
    """Estimate from all blocks, its jackknife standard error and the leave-one-out estimates. ``per_block_cost(keep)`` returns the cost
    curve over the blocks flagged in ``keep``."""
    full = _refine(per_block_cost(np.ones(blocks, bool)), shifts)
    loo = []
    for b in range(blocks):
        keep = np.ones(blocks, bool)
        keep[b] = False
        loo.append(_refine(per_block_cost(keep), shifts))
    loo = np.asarray(loo)
    return full, float(np.sqrt((blocks - 1) / blocks * np.sum((loo - loo.mean()) ** 2))), loo


def _common_grid(imu: ImuSeries, lidar: PoseSeries, max_shift_s: float, step_s: float = GRID_S) -> np.ndarray:
    t0 = max(imu.t_s[0], lidar.t_s[0]) + max_shift_s
    t1 = min(imu.t_s[-1], lidar.t_s[-1]) - max_shift_s
    if t1 - t0 < 20.0:
        raise DataRangeError(f"IMU ({imu.source}) and lidar ({lidar.source}) overlap for {max(t1 - t0, 0):.1f} s; "
                             "estimating their time offset needs at least 20 s")
    return t0 + np.arange(int((t1 - t0) / step_s)) * step_s


def _block_of(n: int, blocks: int) -> np.ndarray:
    return np.minimum((np.arange(n) * blocks) // n, blocks - 1)


def _extended(grid: np.ndarray, pad: int) -> np.ndarray:
    """The grid extended by ``pad`` points on each side (the shifted IMU signal is read from it)."""
    return grid[0] + (np.arange(grid.size + 2 * pad) - pad) * GRID_S


def _block_sums(x: np.ndarray, ok: np.ndarray, blk: np.ndarray, blocks: int) -> np.ndarray:
    """Sum of ``x`` (N, k) over the valid points of each block (blocks are contiguous runs of the grid)."""
    starts = np.searchsorted(blk, np.arange(blocks))
    return np.add.reduceat(np.where(ok[:, None], x, 0.0), starts, axis=0)


def lidar_accel_signal(lidar: PoseSeries, grid: np.ndarray, step_s: float = GRID_S):
    """The lidar's body-frame acceleration ``A = smooth(R^T a)`` and gravity matrix ``B = smooth(R^T)`` on the
    grid of ``step_s`` (``A - B g`` is the specific force the IMU sees), with their validity."""
    gl = _valid_on_grid(lidar.t_s, grid, _max_gap(lidar.t_s))
    p = _interp(lidar.t_s, lidar.p_w_m, grid)
    a_w = np.gradient(np.gradient(p, step_s, axis=0), step_s, axis=0)
    Rt = Slerp(lidar.t_s, Rotation.from_quat(lidar.q_wb_xyzw))(np.clip(grid, lidar.t_s[0], lidar.t_s[-1])).inv()
    A, ok = _smooth(Rt.apply(a_w), gl, ACCEL_SMOOTH_S, step_s)
    B, _ = _smooth(Rt.as_matrix().reshape(-1, 9), gl, ACCEL_SMOOTH_S, step_s)
    return A, B.reshape(-1, 3, 3), ok


def lidar_rate_signal(lidar: PoseSeries, grid: np.ndarray, step_s: float = GRID_S):
    """The lidar's body-frame rotation rate, low-passed, on the grid, with its validity."""
    tm, w = _lidar_rates(lidar)
    return _smooth(_interp(tm, w, grid), _valid_on_grid(tm, grid, _max_gap(lidar.t_s)), RATE_SMOOTH_S, step_s)


def imu_signal(t_s: np.ndarray, x: np.ndarray, grid: np.ndarray, sigma_s: float, step_s: float = GRID_S):
    """An IMU channel on the grid through the same zero-phase path as the lidar's, with its validity."""
    return _smooth(_interp(t_s, x, grid), _valid_on_grid(t_s, grid, _max_gap(t_s)), sigma_s, step_s)


def _scan(shifts: np.ndarray, n: int, ok_fixed: np.ndarray, ok_moving: np.ndarray, blocks: int, fill) -> np.ndarray:
    """Per shift and block, the sums of the columns ``fill(sl)`` writes for the moving (IMU) signal's slice
    ``sl`` of the extended grid, over the points valid on both sides."""
    pad = int(np.abs(shifts).max())
    blk = _block_of(n, blocks)
    out = []
    for k in shifts:
        sl = slice(pad + k, pad + k + n)
        out.append(_block_sums(fill(sl), ok_fixed & ok_moving[sl], blk, blocks))
    return np.asarray(out)


def accel_cost_terms(imu: ImuSeries, lidar: PoseSeries, shifts: np.ndarray, grid: np.ndarray, blocks: int):
    """Per shift and block, the sums that give the body-frame residual d = A - F(t + shift) - B g with the
    gravity g solved out: A = smooth(R^T a_lidar), B = smooth(R^T), F = smooth(f). Smoothing each side once
    (before shifting) keeps the comparison exact: the low-pass is linear and the same on both sides."""
    A, B, ok_l = lidar_accel_signal(lidar, grid)
    F, ok_i = imu_signal(imu.t_s, imu.f_b_mps2, _extended(grid, int(np.abs(shifts).max())), ACCEL_SMOOTH_S)
    # columns: |A - F|^2, B^T (A - F) (3), B^T B (9), count; the last two the same at every shift
    x = np.empty((grid.size, 14))
    x[:, 4:13] = np.einsum("nki,nkj->nij", B, B).reshape(-1, 9)
    x[:, 13] = 1.0
    BtA = np.einsum("nji,nj->ni", B, A)

    def fill(sl):
        r = A - F[sl]
        x[:, 0] = np.einsum("ij,ij->i", r, r)
        x[:, 1:4] = BtA - np.einsum("nji,nj->ni", B, F[sl])
        return x

    return _scan(shifts, grid.size, ok_l, ok_i, blocks, fill)


def rate_cost_terms(imu: ImuSeries, lidar: PoseSeries, shifts: np.ndarray, grid: np.ndarray, blocks: int):
    """Per shift and block: sums of w_l, w_g, |w_l|^2, w_l . w_g, |w_g|^2 and the count (gyro at t + shift)."""
    pad = int(np.abs(shifts).max())
    wl, ok_l = lidar_rate_signal(lidar, grid)
    wg, ok_i = imu_signal(imu.t_s, imu.w_b_rps, _extended(grid, pad), RATE_SMOOTH_S)
    return _rate_sums(wl, ok_l, wg, ok_i, shifts.astype(np.int64), pad, _block_of(grid.size, blocks), blocks)


@njit(cache=True)
def _rate_sums(wl, ok_l, wg, ok_g, shifts, pad, blk, blocks):
    """:func:`rate_cost_terms`' sums in one pass per shift (in NumPy, ten masked columns per shift and a ``reduceat``
    over them: kitti-00's preparation took 0.56 s, now 0.23 s, of which these sums 0.02 s)."""
    out = np.zeros((shifts.size, blocks, 10))
    for s in range(shifts.size):
        o = pad + shifts[s]
        for i in range(wl.shape[0]):
            if not (ok_l[i] and ok_g[o + i]):
                continue
            r = out[s, blk[i]]
            l0, l1, l2 = wl[i, 0], wl[i, 1], wl[i, 2]
            g0, g1, g2 = wg[o + i, 0], wg[o + i, 1], wg[o + i, 2]
            r[0] += l0
            r[1] += l1
            r[2] += l2
            r[3] += g0
            r[4] += g1
            r[5] += g2
            r[6] += l0 * l0 + l1 * l1 + l2 * l2
            r[7] += l0 * g0 + l1 * g1 + l2 * g2
            r[8] += g0 * g0 + g1 * g1 + g2 * g2
            r[9] += 1.0
    return out


def _accel_cost(terms: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Mean squared residual with the best constant gravity, per shift."""
    t = terms[:, keep].sum(axis=1)
    n = np.maximum(t[:, 13], 1.0)
    btr, btb = t[:, 1:4], t[:, 4:13].reshape(-1, 3, 3)
    g = np.linalg.solve(btb + 1e-12 * np.eye(3), btr[..., None])[..., 0]
    return (t[:, 0] - np.sum(btr * g, axis=1)) / n


def _rate_cost(terms: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Minus the correlation coefficient of the (mean-removed) rates, per shift: blind to a scale error."""
    t = terms[:, keep].sum(axis=1)
    n = np.maximum(t[:, 9], 1.0)
    sl, sg = t[:, 0:3], t[:, 3:6]
    cll = t[:, 6] - np.sum(sl * sl, axis=1) / n
    clg = t[:, 7] - np.sum(sl * sg, axis=1) / n
    cgg = t[:, 8] - np.sum(sg * sg, axis=1) / n
    return -clg / np.sqrt(np.maximum(cll * cgg, 1e-300))


@dataclass(frozen=True)
class Shifts:
    """The two raw shifts (s) at which the IMU signals best match the lidar's, with the leave-one-block-out
    estimates that give their joint uncertainty: the lidar signal at stamp t matches the accelerometer at
    ``t + accel`` and the gyro at ``t + rate``."""

    accel: float
    rate: float
    accel_loo: np.ndarray
    rate_loo: np.ndarray
    samples: int

    def std(self, a: float, r: float) -> float:
        """Jackknife standard error of the combination ``a * accel + r * rate``."""
        x = (a * self.accel_loo if a else 0.0) + (r * self.rate_loo if r else 0.0)   # an unmeasured shift is NaN
        n = x.size
        return float(np.sqrt((n - 1) / n * np.sum((x - x.mean()) ** 2)))


COARSE = 4              # the coarse search steps every 4 grid points (20 ms), the fine one +/-2 coarse steps


def _search(terms_fn, cost_fn, imu, lidar, grid, blocks: int, max_shift_s: float):
    """Coarse-to-fine minimum of a shift cost: the estimate and its leave-one-block-out estimates."""
    full = _shifts(max_shift_s)
    coarse = full[::COARSE]
    c = cost_fn(terms_fn(imu, lidar, coarse, grid, blocks), np.ones(blocks, bool))
    k0 = int(coarse[int(np.argmin(c))])
    fine = np.arange(max(k0 - 2 * COARSE, full[0]), min(k0 + 2 * COARSE, full[-1]) + 1)
    t = terms_fn(imu, lidar, fine, grid, blocks)
    if t[..., -1].sum() == 0:
        raise DataRangeError(f"no stretch of {imu.source} and {lidar.source} without gaps to estimate time offsets from")
    est, _, loo = _jackknife(lambda keep: cost_fn(t, keep), fine, blocks)
    return est, loo, int(t[fine.size // 2, :, -1].sum())


def measure_shifts(imu: ImuSeries, lidar: PoseSeries, max_shift_s: float = MAX_SHIFT_S, blocks: int = BLOCKS,
                   accel: bool = True, rate: bool = True) -> Shifts:
    """The accelerometer and gyro shifts against the lidar (each only if asked for; NaN otherwise); see the module
    docstring. ``lidar`` holds IMU poses (extrinsic applied) on the lidar's own stamps, in any world frame."""
    # on a clock relative to the first IMU sample: a 5 ms grid in POSIX seconds (1.8e9) loses 1e-7 s per
    # point to rounding, which accumulates into milliseconds over a drive
    t_ref = float(imu.t_s[0])
    imu, lidar = replace(imu, t_s=imu.t_s - t_ref), replace(lidar, t_s=lidar.t_s - t_ref)
    grid = _common_grid(imu, lidar, max_shift_s)
    nan = (float("nan"), np.full(blocks, np.nan), 0)
    acc, acc_loo, n_a = _search(accel_cost_terms, _accel_cost, imu, lidar, grid, blocks, max_shift_s) if accel else nan
    rt, rate_loo, n_r = _search(rate_cost_terms, _rate_cost, imu, lidar, grid, blocks, max_shift_s) if rate else nan
    for name, v in (("accelerometer", acc), ("gyro", rt)):
        if np.isfinite(v) and abs(v) >= max_shift_s - 2 * GRID_S:
            raise ShiftAtSearchEdgeError(f"the {name} of {imu.source} matches the lidar of {lidar.source} best at the end of the "
                                 f"searched range (+/-{max_shift_s * 1000:.0f} ms): the streams do not share one clock "
                                 "to within that, or do not share axes (the IMU's frame not the one the lidar's "
                                 "extrinsic assumes: an IMU mounted rotated, FRD for FLU, a transform transposed); "
                                 "set the offsets by hand to see which")
    return Shifts(acc, rt, acc_loo, rate_loo, max(n_a, n_r))


def resolve(sh: Shifts, lidar_offset_s, accel_lag_s, gyro_lag_s) -> dict[str, TimeEstimate]:
    """The lidar offset and the two IMU channel lags, each given (a number) or 'auto'.

    The data fix only differences: accel shift = lidar offset + accel lag, rate shift = lidar offset +
    gyro lag. So at most one of the lidar offset and the accelerometer lag can be 'auto' (which clock is
    the reference is the user's knowledge, not the data's)."""
    if lidar_offset_s == "auto" and accel_lag_s == "auto":
        raise ValueError("lidar offset and accelerometer lag cannot both be estimated")
    out: dict[str, TimeEstimate] = {}
    if lidar_offset_s == "auto":
        off, off_coef = sh.accel - float(accel_lag_s), (1.0, 0.0)
        out["lidar_offset"] = TimeEstimate(off, sh.std(1, 0), "accelerometer vs lidar acceleration", sh.samples)
    else:
        off, off_coef = float(lidar_offset_s), (0.0, 0.0)
    if accel_lag_s == "auto":
        out["accel_lag"] = TimeEstimate(sh.accel - off, sh.std(1, 0), "accelerometer vs lidar acceleration", sh.samples)
    if gyro_lag_s == "auto":
        out["gyro_lag"] = TimeEstimate(sh.rate - off, sh.std(-off_coef[0], 1), "gyro vs lidar rotation rate (correlation)",
                                       sh.samples)
    return out
