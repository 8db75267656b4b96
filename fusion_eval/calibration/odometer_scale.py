"""A wheel odometer's scale factor, from the GNSS (no ground truth).

A wheel odometer reads the true speed times a scale ``k`` (the tyre's rolling radius against the nominal one:
0.5-2 % off, changing with pressure, load and wear). The filters fuse its speed with a white-noise std and have no
state for ``k``, so a constant 0.5 % reads as a bias the velocity follows: a simulated drive with the simulator's
own 1.005 ran to a fused 0.722 m against 0.469 without the odometer (a stress test).

Over a window of ``WINDOW_S`` between two fixes, the odometer's speed along the heading the gyro integrates
(its rate about the window's mean specific force, i.e. about the vertical) dead-reckons a horizontal displacement
whose shape is the true path's (a gyro drifts by hundredths of a degree in 30 s) and whose length is ``k`` times it;
the GNSS gives the true displacement between the two fixes (in 3-D: the odometer counts a slope's length). ``k`` is the ratio of the two lengths summed over the
drive, its uncertainty a jackknife over the windows. The GNSS noise enters once per window, not per fix: 1 m on a
300 m window is 0.3 %, and under 0.1 % over a dozen of them. Windows with a gap in either stream, or that move under
:data:`MIN_DISPLACEMENT_M`, are left out. The gyro's bias about the vertical is fitted first (:func:`_rate_bias`):
a loop turning mostly one way shortened every window alike under it.
"""

from __future__ import annotations

import numpy as np

from ..types import GnssSeries, ImuSeries, SpeedSeries

WINDOW_S = 30.0                # each window: this long between its two fixes
MIN_DISPLACEMENT_M = 100.0     # of the GNSS between them (a stop or a loop says little of a scale)
MIN_WINDOWS = 5
MIN_SIGMAS = 3.0               # the estimate is divided out only where it lies this many stds from 1
MAX_RATE_BIAS_RPS = 0.01       # the gyro bias about the vertical searched for (0.57 deg/s: beyond any car IMU's)


def _window(t0: float, t1: float, to, vo, ti, f, w):
    """The dead reckoning of ``[t0, t1]``: its stamps, the gyro's rate about the vertical and the odometer's speed
    there (:func:`_dead_reckoned` lays the path out), or None where either stream has a gap."""
    ii, io = (np.arange(np.searchsorted(x, t0, "left"), np.searchsorted(x, t1, "right")) for x in (ti, to))  # in [t0, t1]
    if ii.size < 3 or io.size < 2:
        return None
    for t, idx in ((ti, ii), (to, io)):
        dt = np.diff(t[idx])
        if dt.max() > 3.0 * np.median(dt) or t[idx[0]] - t0 > 3.0 * np.median(dt) or t1 - t[idx[-1]] > 3.0 * np.median(dt):
            return None
    # the vertical in the body: the specific force's median over the window (its mean leans into the turns, by a
    # centripetal 3 m/s^2 at 6 m/s on a 12 m radius, and under-turned the heading)
    up = np.median(f[ii], axis=0)
    up = up / np.linalg.norm(up)
    # from t0 to t1 exactly (the IMU's samples inside, and the two ends interpolated: at 10 Hz the samples alone
    # left out up to 0.2 s of each window, 0.6 % of its distance)
    k = np.clip(np.searchsorted(ti, [t0, t1]), 1, ti.size - 1)
    idx = np.arange(k[0] - 1, k[1] + 1)
    rate_all = w[idx] @ up                                   # about the vertical
    t = np.concatenate([[t0], ti[ii], [t1]])
    rate = np.interp(t, ti[idx], rate_all)
    return t, rate, np.interp(t, to, vo)


def _dead_reckoned(t, rate, v, bias: float) -> np.ndarray:
    """The horizontal path (complex, from 0) the speed ``v`` lays along the heading of ``rate - bias``."""
    r = rate - bias
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * np.diff(t))])
    step = 0.5 * (v[1:] * np.exp(1j * heading[1:]) + v[:-1] * np.exp(1j * heading[:-1])) * np.diff(t)
    return np.concatenate([[0.0], np.cumsum(step)])


def _shape_misfit(windows, bias: float) -> float:
    """How far the dead-reckoned paths under a heading-rate ``bias`` are from the GNSS fixes inside their windows,
    each path turned and scaled onto its fixes (a complex factor: the unknown heading and the scale)."""
    total = 0.0
    for t, rate, v, tf, gf in windows:
        path = _dead_reckoned(t, rate, v, bias)
        z = np.interp(tf, t, path.real) + 1j * np.interp(tf, t, path.imag)
        c = np.vdot(z, gf) / max(np.vdot(z, z).real, 1e-300)
        total += float(np.sum(np.abs(gf - c * z) ** 2))
    return total


def _rate_bias(windows) -> float:
    """The gyro's bias about the vertical that lays the dead-reckoned paths best onto the fixes (golden section over
    +/- :data:`MAX_RATE_BIAS_RPS`): a bias of 0.02 deg/s turns a 30 s window's path by 0.6 deg, and where a drive turns
    mostly one way (a loop) that shortens every curved window's chord alike: the simulator's urban loop read 1.0041
    for a true 1.005 with the truth's positions, 1.0054 with the truth's rates (a simulate review)."""
    a, b = -MAX_RATE_BIAS_RPS, MAX_RATE_BIAS_RPS
    g = (np.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = b - g * (b - a), a + g * (b - a)
    f1, f2 = _shape_misfit(windows, x1), _shape_misfit(windows, x2)
    while b - a > 1e-7:
        if f1 < f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - g * (b - a)
            f1 = _shape_misfit(windows, x1)
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + g * (b - a)
            f2 = _shape_misfit(windows, x2)
    return 0.5 * (a + b)


def estimate(odo: SpeedSeries, gnss: GnssSeries, imu: ImuSeries) -> dict | None:
    """``{"scale", "std", "windows", "distance_m", "method"}`` of the odometer's scale (its reading over the true
    speed), or None where fewer than :data:`MIN_WINDOWS` windows moved far enough."""
    tg, pg = np.asarray(gnss.t_s, float), np.asarray(gnss.p_w_m, float)
    to, vo = np.asarray(odo.t_s, float), np.asarray(odo.v_mps, float)
    ti, f, w = (np.asarray(x, float) for x in (imu.t_s, imu.f_b_mps2, imu.w_b_rps))
    gnss_d, windows = [], []
    a = 0
    while a < tg.size - 1:
        b = int(np.searchsorted(tg, tg[a] + WINDOW_S))
        if b >= tg.size:
            break
        # in 3-D: on a slope the odometer counts the distance along it, which the horizontal dead reckoning takes
        # as level (the horizontal chord left 0.1 % per 3 deg of slope in the estimate)
        chord = float(np.linalg.norm(pg[b] - pg[a]))
        if tg[b] - tg[a] < 1.5 * WINDOW_S and chord > MIN_DISPLACEMENT_M:
            got = _window(tg[a], tg[b], to, vo, ti, f, w)
            if got is not None:
                gnss_d.append(chord)
                g = pg[a:b + 1, 0] + 1j * pg[a:b + 1, 1]
                windows.append((*got, tg[a:b + 1], g - g[0]))
        a = b
    if len(gnss_d) < MIN_WINDOWS:
        return None
    bias = _rate_bias(windows)
    c = np.asarray(gnss_d)
    p = np.array([abs(_dead_reckoned(t, rate, v, bias)[-1]) for t, rate, v, _, _ in windows])
    k = float(p.sum() / c.sum())
    jack = np.array([(p.sum() - p[i]) / (c.sum() - c[i]) for i in range(c.size)])
    std = float(np.sqrt((c.size - 1) / c.size * np.sum((jack - jack.mean()) ** 2)))
    return {"scale": k, "std": std, "windows": int(c.size), "distance_m": float(c.sum()),
            "gyro_bias_vertical_dps": float(np.degrees(bias)),
            "method": f"the odometer's speed dead-reckoned along the gyro's heading (its bias about the vertical, "
                      f"{np.degrees(bias):.4f} deg/s, fitted to the shape of the fixes) against the GNSS's displacement, "
                      f"{c.size} windows of {WINDOW_S:g} s ({c.sum() / 1000:.1f} km)"}
