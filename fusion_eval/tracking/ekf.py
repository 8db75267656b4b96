"""Constant-velocity Kalman filter for a 2-D target: linear lidar update, extended (EKF) radar update.

State ``x = [px, py, vx, vy]``. Process: white acceleration noise (sigma_ax^2, sigma_ay^2), so for a
step dt::

    F = [[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]]
    Q = [[dt^4/4 s_ax, 0, dt^3/2 s_ax, 0], [0, dt^4/4 s_ay, 0, dt^3/2 s_ay],
         [dt^3/2 s_ax, 0, dt^2 s_ax, 0], [0, dt^3/2 s_ay, 0, dt^2 s_ay]]

Lidar: ``z = [px, py]``, ``H = [I2 0]``. Radar: ``h(x) = [rho, phi, rho_dot]`` with
``rho = sqrt(px^2 + py^2)``, ``phi = atan2(py, px)``, ``rho_dot = (px vx + py vy) / rho``, its Jacobian
:func:`radar_jacobian`, the bearing residual wrapped to [-pi, pi], and no radar update while the target is
within ``min_range`` of the sensor (the Jacobian is singular at the origin), nor from a radar reading of range 0
(a dropout). After a gap of over ``max_gap_s`` between measurements the tracker restarts from the next one: a day's
gap grew the prior to 1e20 m^2, whose update then lost the covariance's definiteness and stopped the run as
"diverged" at a measurement that was fine, and over hours of gap the result drifted with its length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DataFormatError, FilterDivergedError
from ..filters.linalg import joseph_update


@dataclass(frozen=True)
class TrackParams:
    noise_ax: float = 9.0
    noise_ay: float = 9.0
    lidar_var: tuple = (0.0225, 0.0225)
    radar_var: tuple = (0.09, 0.0009, 0.09)
    init_pos_var: float = 1.0
    init_vel_var: float = 1000.0
    min_range: float = 1e-4
    sensors: str = "both"            # both | lidar | radar
    max_gap_s: float = 5.0           # restart after a gap this long: sigma_a T^2 / 2 = 37 m at the default noise


def wrap_angle(a: float) -> float:
    """Wrap to [-pi, pi]."""
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def h_radar(x: np.ndarray) -> np.ndarray:
    px, py, vx, vy = x
    rho = float(np.hypot(px, py))
    return np.array([rho, np.arctan2(py, px), (px * vx + py * vy) / rho])


def radar_jacobian(x: np.ndarray) -> np.ndarray:
    """d h_radar / d x (3x4)."""
    px, py, vx, vy = x
    c1 = px * px + py * py
    c2 = np.sqrt(c1)
    c3 = c1 * c2
    return np.array([
        [px / c2, py / c2, 0.0, 0.0],
        [-py / c1, px / c1, 0.0, 0.0],
        [py * (vx * py - vy * px) / c3, px * (vy * px - vx * py) / c3, px / c2, py / c2],
    ])


def F_Q(dt: float, p: TrackParams) -> tuple[np.ndarray, np.ndarray]:
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    d2, d3, d4 = dt * dt, dt ** 3, dt ** 4
    ax, ay = p.noise_ax, p.noise_ay
    Q = np.array([[d4 / 4 * ax, 0, d3 / 2 * ax, 0], [0, d4 / 4 * ay, 0, d3 / 2 * ay],
                  [d3 / 2 * ax, 0, d2 * ax, 0], [0, d3 / 2 * ay, 0, d2 * ay]])
    return F, Q


@dataclass
class TrackResult:
    t_us: np.ndarray          # (M,) stamps of the estimates (one per used measurement)
    x: np.ndarray             # (M, 4)
    gt: np.ndarray            # (M, 4)
    kind: np.ndarray          # (M,)
    z: np.ndarray             # (M, 3)
    nis: np.ndarray           # (M,) NaN where no update
    used: np.ndarray          # indices of the measurements used
    P: np.ndarray | None = None        # (M, 4, 4) posterior covariances
    F: np.ndarray | None = None        # (M, 4, 4) transition into each estimate from the previous one (F[0] unused)
    x_prior: np.ndarray | None = None  # (M, 4) predictions before each update
    P_prior: np.ndarray | None = None  # (M, 4, 4)
    x_smoothed: np.ndarray | None = None   # (M, 4) the RTS smoother's estimate (``smooth``)
    P_smoothed: np.ndarray | None = None
    skipped: int = 0          # radar readings not used: the estimate within min_range of the sensor
    dropouts: tuple = ()      # lines of radar readings of range 0, not used
    restarts: tuple = ()      # (line, gap_s) where the tracker restarted after a gap of over max_gap_s


def run_track(m, p: TrackParams) -> TrackResult:
    with np.errstate(over="ignore", invalid="ignore"):
        return _run_track(m, p)


def _run_track(m, p: TrackParams) -> TrackResult:
    use = {"both": ("L", "R"), "lidar": ("L",), "radar": ("R",)}[p.sensors]
    idx = [i for i in range(len(m.kind)) if m.kind[i] in use]
    R_l, R_r = np.diag(p.lidar_var), np.diag(p.radar_var)
    H_l = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    xs, nis = [], []
    Ps, Fs, xps, Pps = [], [], [], []
    x = P = None
    t_prev = None
    skipped = 0                  # radar readings not used: the estimate too close to the sensor to linearise
    dropouts, restarts, used = [], [], []        # used: the measurements each estimate is of
    for i in idx:
        k, z, t = m.kind[i], m.z[i], int(m.t_us[i])
        if k == "R" and not abs(z[0]) >= p.min_range:
            # a radar dropout (range 0): first, it put the target on the sensor with zero velocity and every later
            # radar update was then skipped as too close to linearise; later, it was fused (px error 0.11 -> 0.21 m
            # for three of them, radar NIS 5408, no word: a review)
            dropouts.append(int(m.lines[i]))
            continue
        if x is not None and (t - t_prev) / 1e6 > p.max_gap_s:
            restarts.append((int(m.lines[i]), (t - t_prev) / 1e6))
            x = None                 # the prediction over the gap is worthless: start again from this measurement
        if x is None:
            if k == "L":
                x = np.array([z[0], z[1], 0.0, 0.0])
            else:
                rho, phi, rd = z
                x = np.array([rho * np.cos(phi), rho * np.sin(phi), rd * np.cos(phi), rd * np.sin(phi)])
            P = np.diag([p.init_pos_var, p.init_pos_var, p.init_vel_var, p.init_vel_var])
            t_prev = t
            xs.append(x.copy())
            used.append(i)
            nis.append(np.nan)
            # a restart's transition from the estimate before it is 0: the smoother passes nothing back across it
            Ps.append(P.copy()), Fs.append(np.zeros((4, 4)) if len(xs) > 1 else np.eye(4))
            xps.append(x.copy()), Pps.append(P.copy())
            continue
        dt = (t - t_prev) / 1e6
        t_prev = t
        F = np.eye(4)
        if dt > 0:
            F, Q = F_Q(dt, p)
            x = F @ x
            P = F @ P @ F.T + Q
        Fs.append(F), xps.append(x.copy()), Pps.append(P.copy())
        try:
            if k == "L":
                dx, s, _ = joseph_update(P, 4, H_l, z[:2] - H_l @ x, R_l, np.inf)
            elif np.hypot(x[0], x[1]) < p.min_range:
                skipped += 1
                xs.append(x.copy())          # too close to the sensor to linearise the radar model
                used.append(i)
                nis.append(np.nan)
                Ps.append(P.copy())
                continue
            else:
                r = z - h_radar(x)
                r[1] = wrap_angle(r[1])
                dx, s, _ = joseph_update(P, 4, radar_jacobian(x), r, R_r, np.inf)
        except np.linalg.LinAlgError:
            dx = np.full(4, np.nan)
        x = x + dx
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            raise FilterDivergedError(f"{m.source}:{m.lines[i]}: the tracker diverged at this measurement "
                                      "(non-finite state; check its values)")
        xs.append(x.copy())
        used.append(i)
        nis.append(float(s))
        Ps.append(P.copy())
    if x is None:
        what = {"both": "lidar or radar", "lidar": "lidar", "radar": "radar"}[p.sensors]
        raise DataFormatError(m.source, None, f"no measurement to start the tracker from: no {what} reading in the "
                                              f"file (--sensors {p.sensors})" if not idx else
                              "no measurement to start the tracker from: every radar reading is within 0.1 mm of the "
                              "sensor (a range of 0: dropouts)")
    used = np.array(used)
    return TrackResult(skipped=skipped, dropouts=tuple(dropouts), restarts=tuple(restarts), t_us=m.t_us[used], x=np.array(xs), gt=m.gt[used], kind=m.kind[used], z=m.z[used],
                       nis=np.array(nis), used=used, P=np.array(Ps), F=np.array(Fs), x_prior=np.array(xps),
                       P_prior=np.array(Pps))


def smooth(res: TrackResult) -> TrackResult:
    """The Rauch-Tung-Striebel backward pass over the tracker's record (``track --smooth``): the same gain
    kernel as the ego-motion smoother (:func:`fusion_eval.smoothing.rts.rts_step`), on an additive state. The
    radar EKF's Jacobians stay those of the forward pass (an extended RTS smoother)."""
    from ..smoothing.rts import rts_step

    M = res.x.shape[0]
    xs, Ps = res.x.copy(), res.P.copy()
    for j in range(M - 2, -1, -1):
        d, Ps[j] = rts_step(res.P[j], res.F[j + 1], res.P_prior[j + 1], xs[j + 1] - res.x_prior[j + 1], Ps[j + 1])
        xs[j] = res.x[j] + d
    res.x_smoothed, res.P_smoothed = xs, Ps
    return res


def rmse(res: TrackResult, smoothed: bool = False) -> np.ndarray:
    x = res.x_smoothed if smoothed else res.x
    return np.sqrt(np.mean((x - res.gt) ** 2, axis=0))
