"""Sensor models of the simulator. Each takes the true motion and a seeded generator and returns
what the sensor reports plus the true error terms (biases, scale, drift) for the ``truth/`` folder.

Noise densities are continuous-time (per sqrt(Hz)); a sample at interval dt gets white noise of
std ``density / sqrt(dt)`` and a bias random walk step of std ``density_rw * sqrt(dt)``, which is
the discrete model the filter assumes, so the true parameters make the filter consistent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..so3 import exp_so3
from .motion import Motion

D2R = np.pi / 180.0


@dataclass(frozen=True)
class ImuOut:
    f_b_mps2: np.ndarray
    w_b_rps: np.ndarray
    accel_bias: np.ndarray       # (N, 3) true bias, m/s^2
    gyro_bias: np.ndarray        # (N, 3) rad/s
    accel_scale_ppm: np.ndarray  # (3,)
    gyro_scale_ppm: np.ndarray


def imu(m: Motion, c: dict, rng: np.random.Generator) -> ImuOut:
    n = m.t_s.size
    dt = float(np.median(np.diff(m.t_s)))
    ba0 = rng.standard_normal(3) * c["accel_bias_init_std_mps2"]
    bg0 = rng.standard_normal(3) * c["gyro_bias_init_std_dps"] * D2R
    walk_a = rng.standard_normal((n, 3)) * c["accel_bias_rw_mps3_sqrthz"] * np.sqrt(dt)
    walk_g = rng.standard_normal((n, 3)) * c["gyro_bias_rw_dps2_sqrthz"] * D2R * np.sqrt(dt)
    walk_a[0] = walk_g[0] = 0.0
    tau = c["bias_corr_time_s"]
    if tau > 0:
        # first-order Gauss-Markov, exact discretisation: b_k+1 = a b_k + w_k, var(w) = q^2 tau / 2 (1 - a^2);
        # walk_* hold q sqrt(dt) draws, rescaled to that variance
        a = np.exp(-dt / tau)
        k = np.sqrt(tau / 2 * (1 - a * a) / dt)
        ba, bg = _ar1(ba0, walk_a * k, a), _ar1(bg0, walk_g * k, a)
    else:
        ba = ba0 + np.cumsum(walk_a, axis=0)
        bg = bg0 + np.cumsum(walk_g, axis=0)
    na = rng.standard_normal((n, 3)) * c["accel_noise_mps2_sqrthz"] / np.sqrt(dt)
    ng = rng.standard_normal((n, 3)) * c["gyro_noise_dps_sqrthz"] * D2R / np.sqrt(dt)
    sa = rng.standard_normal(3) * c["scale_factor_std_ppm"]
    sg = rng.standard_normal(3) * c["scale_factor_std_ppm"]
    f = m.f_b_mps2 * (1 + sa * 1e-6) + ba + na
    w = m.w_b_rps * (1 + sg * 1e-6) + bg + ng
    return ImuOut(f, w, ba, bg, sa, sg)


def _ar1(x0: np.ndarray, w: np.ndarray, a: float) -> np.ndarray:
    """x_0 = x0, x_k = a x_k-1 + w_k (rows), by a linear filter (no Python loop over the samples)."""
    from scipy.signal import lfilter

    w = w.copy()
    w[0] = x0
    return lfilter([1.0], [1.0, -a], w, axis=0)


def gnss_epochs(m: Motion, c: dict) -> tuple[np.ndarray, np.ndarray]:
    """The receiver's epochs: sample indices at ``gnss.rate_hz``, and which of them fall outside the outages."""
    step = max(1, int(round(1.0 / (c["rate_hz"] * float(np.median(np.diff(m.t_s)))))))
    idx = np.arange(0, m.t_s.size, step)
    rel = m.t_s[idx] - m.t_s[0]
    keep = np.ones(idx.size, bool)
    for a, b in c["outages_s"]:
        keep &= ~((rel >= a) & (rel < b))
    return idx, keep


def gnss(m: Motion, c: dict, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fix times, ENU positions with noise, jumps and outages applied, and the 1-sigma per axis."""
    idx, keep = gnss_epochs(m, c)
    t = m.t_s[idx]
    p = m.p_w_m[idx] + rng.standard_normal((idx.size, 3)) * np.asarray(c["noise_std_m"])
    rel = t - m.t_s[0]
    for a, b, de, dn, du in c["jumps"]:
        p[(rel >= a) & (rel < b)] += [de, dn, du]
    std = np.maximum(np.asarray(c["noise_std_m"], float), 0.01)   # a receiver never claims zero
    return t[keep], p[keep], np.tile(std, (int(keep.sum()), 1))


def odometer(m: Motion, c: dict, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    step = max(1, int(round(1.0 / (c["rate_hz"] * float(np.median(np.diff(m.t_s)))))))
    idx = np.arange(0, m.t_s.size, step)
    v = c["scale"] * m.speed_mps[idx] + rng.standard_normal(idx.size) * c["noise_std_mps"]
    return m.t_s[idx], v


def lidar_frames(m: Motion, c: dict) -> np.ndarray:
    step = max(1, int(round(1.0 / (c["rate_hz"] * float(np.median(np.diff(m.t_s)))))))
    return np.arange(0, m.t_s.size, step)


def lidar_odometry(m: Motion, c: dict, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMU poses ``T_b0_bk`` of integrated noisy increments: white noise per increment plus a scale error
    and a yaw drift proportional to the distance. Returns frame indices, positions, rotations."""
    idx = lidar_frames(m, c)
    R, p = m.R_wb[idx], m.p_w_m[idx]
    n = idx.size
    dp = np.einsum("nji,nj->ni", R[:-1], p[1:] - p[:-1])            # increments in the previous body frame
    dR = np.einsum("nji,njk->nik", R[:-1], R[1:])
    dist = np.linalg.norm(dp, axis=1)
    dp_m = dp * (1 + c["scale_drift"]) + rng.standard_normal((n - 1, 3)) * c["pos_noise_std_m"]
    yaw = c["yaw_drift_deg_per_100m"] * D2R * dist / 100.0
    noise = rng.standard_normal((n - 1, 3)) * c["att_noise_std_deg"] * D2R
    dR_m = np.einsum("nij,njk->nik", dR, exp_so3(noise + np.column_stack([np.zeros(n - 1), np.zeros(n - 1), yaw])))
    Ro = np.empty((n, 3, 3))
    po = np.empty((n, 3))
    Ro[0], po[0] = np.eye(3), 0.0
    for k in range(n - 1):
        po[k + 1] = po[k] + Ro[k] @ dp_m[k]
        Ro[k + 1] = Ro[k] @ dR_m[k]
    return idx, po, Ro


def lidar_map_matching(m: Motion, c: dict, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Absolute world IMU poses with white noise, and outliers with probability ``outlier_prob``."""
    idx = lidar_frames(m, c)
    n = idx.size
    p = m.p_w_m[idx] + rng.standard_normal((n, 3)) * c["pos_noise_std_m"]
    R = np.einsum("nij,njk->nik", m.R_wb[idx], exp_so3(rng.standard_normal((n, 3)) * c["att_noise_std_deg"] * D2R))
    out = rng.random(n) < c["outlier_prob"]
    p[out] += rng.standard_normal((int(out.sum()), 3)) * c["outlier_std_m"]
    return idx, p, R, out

