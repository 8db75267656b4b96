"""Synthetic lidar/radar measurement files with known truth (``fusion-eval simulate-track``).

The target moves with a smoothly varying speed and yaw rate (looping within some 25 m of its start,
like the public EKF dataset's target); lidar and radar measure it alternately, every ``interval_s``, with white noise of the
given variances. Deterministic for a seed."""

from __future__ import annotations

import numpy as np

from .measurements import format_line


CHUNK = 20_000        # measurements integrated and formatted at a time (~100 MB): bounded at 10 million too


def simulate_track_chunks(duration_s: float = 25.0, interval_s: float = 0.05, seed: int = 0, lidar_var=(0.0225, 0.0225),
                          radar_var=(0.09, 0.0009, 0.09), start=(0.6, 0.6), speed_mps: float = 5.0,
                          t0_us: int = 1477010443000000, heading0_rad: float = 0.0, turn_mean_rps: float = 0.4,
                          turn_amp_rps: float = 0.35, chunk: int = CHUNK):
    """The measurement file's text, :data:`CHUNK` lines at a time. The motion is integrated on a grid 50 times finer
    than the measurements (the trapezoid rule), chunk by chunk from the state where the previous one ended: the
    whole grid at once took 40 GB for 10 million measurements."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s / interval_s))
    sub = 50                                               # fine integration steps per measurement interval
    h = interval_s / sub
    yaw0, px0, py0 = heading0_rad, float(start[0]), float(start[1])
    lidar_sd, radar_sd = np.sqrt(lidar_var), np.sqrt(radar_var)
    for k0 in range(0, n, chunk):
        k1 = min(k0 + chunk, n)
        tf = np.arange(k0 * sub, k1 * sub + 1) * h             # through the next chunk's first point
        v = speed_mps * (1.0 + 0.2 * np.sin(2 * np.pi * tf / duration_s))
        # mostly turning one way: the target loops within some 25 m of its start, as in the public dataset
        w = turn_mean_rps + turn_amp_rps * np.sin(2 * np.pi * tf / 12.5)
        yaw = yaw0 + np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(tf))])
        vx, vy = v * np.cos(yaw), v * np.sin(yaw)
        px = px0 + np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * np.diff(tf))])
        py = py0 + np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * np.diff(tf))])
        lines = []
        for k in range(k0, k1):
            j = (k - k0) * sub
            gt = (px[j], py[j], vx[j], vy[j])
            t_us = t0_us + int(round(k * interval_s * 1e6))
            if k % 2 == 0:
                z = np.array([px[j], py[j]]) + rng.standard_normal(2) * lidar_sd
                lines.append(format_line("L", z, t_us, gt, yaw[j], w[j]))
            else:
                rho = np.hypot(px[j], py[j])
                phi = np.arctan2(py[j], px[j])
                rd = (px[j] * vx[j] + py[j] * vy[j]) / rho if rho > 0 else 0.0     # on the sensor: 0, not nan
                z = np.array([rho, phi, rd]) + rng.standard_normal(3) * radar_sd
                z[0] = abs(z[0])        # a radar reports no negative range (track refused a file near the sensor)
                z[1] = (z[1] + np.pi) % (2 * np.pi) - np.pi
                lines.append(format_line("R", z, t_us, gt, yaw[j], w[j]))
        yield "\n".join(lines) + "\n"
        end = (k1 - k0) * sub                                  # where the next chunk starts
        yaw0, px0, py0 = float(yaw[end]), float(px[end]), float(py[end])


def simulate_track(duration_s: float = 25.0, interval_s: float = 0.05, seed: int = 0, **kw) -> str:
    """The whole measurement file as one text (:func:`simulate_track_chunks`)."""
    return "".join(simulate_track_chunks(duration_s, interval_s, seed, **kw))
