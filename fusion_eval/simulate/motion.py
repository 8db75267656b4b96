"""Smooth, vehicle-like motion with analytic IMU signals.

A profile is a list of :class:`Segment`: each sets targets for forward speed, yaw rate and road
slope, reached through a quintic (C2) transition at the segment's start and then held. Speed, yaw
rate and slope are therefore twice continuously differentiable, and so are the acceleration and the
angular rate the IMU sees. The vehicle does not slip: its velocity in the body frame is ``[v, 0, 0]``.

Attitude: ``R_wb = Rz(yaw) Ry(pitch)`` with pitch = -slope (KITTI's convention: positive pitch is
nose down for z up), roll 0. With these, exactly::

    w_b = Ry(pitch)^T [0, 0, yaw_rate] + [0, pitch_rate, 0]
    f_b = [dv/dt, 0, 0] + w_b x [v, 0, 0] + R_wb^T [0, 0, g]

The yaw angle and the position are integrated from these smooth functions with cumulative Simpson
quadrature on a grid finer than the IMU's, so they agree with the analytic IMU signals to far below
any sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.integrate import cumulative_simpson

from ..errors import ConfigError
from .. import yaml_lines

PROFILES = ("urban", "figure8", "highway")


@dataclass(frozen=True)
class Segment:
    duration_s: float
    speed_mps: float
    yaw_rate_rps: float = 0.0
    slope_rad: float = 0.0
    transition_s: float = 3.0


def _q(u):
    """Quintic smoothstep and its first derivative (u in [0, 1])."""
    u = np.clip(u, 0.0, 1.0)
    return u ** 3 * (10 - 15 * u + 6 * u * u), 30 * u ** 2 * (1 - u) ** 2


def _turn(angle_deg: float, speed: float, radius: float, tau: float, slope_rad: float = 0.0) -> list[Segment]:
    """A turn by ``angle_deg`` at constant speed and slope, and the straight run-out that ends it (the
    yaw-rate ramps in and out, each over ``tau``, make the turn exactly ``angle_deg``). A turn shorter than ``tau``
    ramps over its own length: a ramp that did not finish left the run-out to start from the full rate, a step in
    the angular rate (3 rad/s for a 25 m/s, 6 m radius corner) and a turn of the wrong angle (a stress test)."""
    w = np.sign(angle_deg) * speed / radius
    duration = abs(np.radians(angle_deg) / w)
    tau = min(tau, duration)
    return [Segment(duration, speed, w, slope_rad, tau), Segment(tau, speed, 0.0, slope_rad, tau)]


def urban() -> list[Segment]:
    """A city block loop: a stationary start, 90-degree turns at lower speed, a stop, slopes."""
    d = [Segment(10.0, 0.0, transition_s=0.0)]                 # stationary: lets a filter settle
    for k, slope in enumerate(np.radians([0.0, 3.0, 0.0, -3.0])):
        # the grade changes on the straights (6 s), never during a turn
        d += [Segment(18.0, 12.0, 0.0, slope, 6.0), Segment(4.0, 6.0, 0.0, slope, 4.0)]
        d += _turn(90.0, 6.0, 12.0, 3.0, slope)
        if k == 1:
            d += [Segment(8.0, 0.0, 0.0, slope, 5.0)]          # a stop on the slope
    return d


def figure8() -> list[Segment]:
    """Two 20 m circles at 8 m/s, left then right, the yaw rate swinging through zero between them
    (symmetric, so each repetition closes on itself)."""
    w = 8.0 / 20.0
    return [Segment(4.0, 0.0, transition_s=0.0), Segment(6.0, 8.0, 0.0, 0.0, 4.0), Segment(2.0, 8.0, 0.0, 0.0, 1.0),
            Segment(2 * np.pi / w, 8.0, w, 0.0, 2.0), Segment(2 * np.pi / w, 8.0, -w, 0.0, 2.0)]


def highway() -> list[Segment]:
    return [Segment(5.0, 0.0, transition_s=0.0), Segment(30.0, 27.0, 0.0, 0.0, 20.0),
            Segment(40.0, 27.0, 0.01, np.radians(1.0), 8.0), Segment(20.0, 30.0, 0.0, 0.0, 8.0),
            Segment(2.5, 30.0, 0.04, 0.0, 1.5), Segment(2.5, 30.0, -0.04, 0.0, 1.5),   # lane change
            Segment(40.0, 30.0, -0.012, np.radians(-1.0), 8.0), Segment(20.0, 25.0, 0.0, 0.0, 8.0)]


WAYPOINT_KEYS = frozenset({"waypoints", "speeds_mps", "turn_radius_m", "start_stationary_s"})


def from_waypoints_yaml(path: Path) -> tuple[list[Segment], float, int]:
    """Segments from ``waypoints: [[E, N], ...]`` (m), ``speeds_mps`` (one per leg, or one number),
    ``turn_radius_m`` (default 15) and ``start_stationary_s`` (default 5).

    Straight legs are joined by turns of the given radius taken at the leg's speed (yaw rate ramped in
    and out over 1 s, then a 1 s run-out); each leg's straight is shortened by the turns' tangent
    lengths and run-outs, and its speed change (3 s) is accounted for, so the path follows the polygon
    to within a few metres at the corners. A closed polygon (last waypoint = first) turns back into
    its first leg and repeats; an open one ends with a stop. Returns the segments and the initial
    heading (rad) and the number of segments before the part that repeats."""
    try:
        body = yaml_lines.load(Path(path).read_text(encoding="utf-8"))        # a waypoint key given twice is refused
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read the waypoint profile ({exc})") from None
    if not isinstance(body, dict) or "waypoints" not in body:
        raise ConfigError(f"{path}: a waypoint profile needs 'waypoints: [[east_m, north_m], ...]'")
    unknown = sorted(set(map(str, body)) - WAYPOINT_KEYS)
    if unknown:                  # a misspelt key would be ignored, its default used (a 'speedz:' ran at 10 m/s)
        raise ConfigError(f"{path}: unknown waypoint profile key {unknown[0]!r} (known: {', '.join(sorted(WAYPOINT_KEYS))})")
    try:
        W = np.asarray(body["waypoints"], float)
        sp = np.broadcast_to(np.asarray(body.get("speeds_mps", 10.0), float), (max(len(W) - 1, 1),))
        r = float(body.get("turn_radius_m", 15.0))
        t_still = float(body.get("start_stationary_s", 5.0))
    except (ValueError, TypeError):
        raise ConfigError(f"{path}: waypoints must be [east_m, north_m] pairs; speeds_mps one number per leg") from None
    if W.ndim != 2 or W.shape[1] != 2 or len(W) < 2 or not np.all(np.isfinite(W)):
        raise ConfigError(f"{path}: 'waypoints' must be a list of at least two [east_m, north_m] pairs of numbers")
    if not (np.all(np.isfinite(sp)) and np.isfinite(r) and np.isfinite(t_still) and t_still >= 0):
        raise ConfigError(f"{path}: speeds_mps, turn_radius_m and start_stationary_s must be numbers")
    legs = np.diff(W, axis=0)
    L = np.linalg.norm(legs, axis=1)
    if np.any(L <= 0) or np.any(sp <= 0) or r <= 0:
        raise ConfigError(f"{path}: consecutive waypoints must differ; speeds and the turn radius must be > 0")
    head = np.arctan2(legs[:, 1], legs[:, 0])
    closed = bool(np.allclose(W[0], W[-1]))
    n = len(legs)
    # turn[i]: from leg i into leg i+1 (closed loops also from the last leg into the first)
    turn = np.angle(np.exp(1j * np.diff(np.concatenate([head, head[:1]]) if closed else head)))
    tangent = r * np.tan(np.abs(turn) / 2)
    ramp, tau_v = 1.0, 3.0
    # each turn's run-out lasts its ramp, which a turn shorter than 1 s shortens to its own length (see _turn)
    runout = np.minimum(ramp, np.abs(turn) * r / sp[:turn.size])
    segs = [Segment(t_still, 0.0, transition_s=0.0)]
    if closed:   # accelerate once; the loop then starts at the last leg's speed, as every later lap does
        segs.append(Segment(tau_v, float(sp[-1]), 0.0, 0.0, tau_v))
    for i in range(n):
        prev_turn = i - 1 if i > 0 else (n - 1 if closed else None)
        before = 0.0 if prev_turn is None else tangent[prev_turn] + sp[prev_turn] * runout[prev_turn]  # + run-out
        after = tangent[i] if i < turn.size else 0.0
        straight = L[i] - before - after
        v_prev = sp[prev_turn] if prev_turn is not None else 0.0
        hold = (straight - tau_v * (v_prev + sp[i]) / 2) / sp[i] + tau_v
        if straight <= 0 or hold < tau_v:
            raise ConfigError(f"{path}: leg {i + 1} is too short for its turns (radius {r:g} m) and speed change")
        segs.append(Segment(hold, float(sp[i]), 0.0, 0.0, tau_v))
        if i < turn.size and abs(turn[i]) > 1e-9:
            segs += _turn(np.degrees(turn[i]), float(sp[i]), r, ramp)
    if not closed:
        # an open route ends with a stop and stays stopped (only the stop "repeats")
        segs.append(Segment(5.0, 0.0, 0.0, 0.0, 4.0))
        return segs, float(head[0]), len(segs) - 1
    return segs, float(head[0]), 2


def profile_segments(name: str) -> tuple[list[Segment], float, int]:
    """Segments, initial heading (rad) and the number of segments before the repeating part."""
    named = {"urban": (urban, 1), "figure8": (figure8, 3), "highway": (highway, 1)}
    if name in named:
        fn, n_prefix = named[name]
        return fn(), 0.0, n_prefix
    p = Path(name)
    if p.suffix in (".yaml", ".yml"):
        from ..resources import find

        return from_waypoints_yaml(find(p))          # configs/profiles/... from any directory
    raise ConfigError(f"unknown profile {name!r} (known: {', '.join(PROFILES)}, or a waypoint YAML file)")


@dataclass(frozen=True)
class Motion:
    """True motion sampled at ``t_s``: pose, velocity and the noise-free IMU signals."""

    t_s: np.ndarray
    p_w_m: np.ndarray
    v_w_mps: np.ndarray
    R_wb: np.ndarray
    yaw_rad: np.ndarray
    pitch_rad: np.ndarray
    speed_mps: np.ndarray
    f_b_mps2: np.ndarray
    w_b_rps: np.ndarray


def _channels(segs: list[Segment], t: np.ndarray):
    """Speed, yaw rate, slope and their time derivatives at ``t`` (segments laid end to end)."""
    starts = np.concatenate([[0.0], np.cumsum([s.duration_s for s in segs])])
    idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(segs) - 1)
    tgt = np.array([[s.speed_mps, s.yaw_rate_rps, s.slope_rad] for s in segs])
    prev = np.concatenate([tgt[:1], tgt[:-1]])
    tau = np.array([max(s.transition_s, 1e-9) for s in segs])
    u = (t - starts[idx]) / tau[idx]
    s, ds = _q(u)
    ds = np.where(u < 1.0, ds / tau[idx], 0.0)
    val = prev[idx] + (tgt[idx] - prev[idx]) * s[:, None]
    der = (tgt[idx] - prev[idx]) * ds[:, None]
    return val, der


def repeat_to(segs: list[Segment], duration_s: float, n_prefix: int = 1) -> list[Segment]:
    """The first ``n_prefix`` segments (the stationary start) once, then the rest repeated to cover ``duration_s``."""
    out = list(segs)
    body = segs[n_prefix:] if len(segs) > n_prefix else segs
    while sum(s.duration_s for s in out) < duration_s:
        out += body
    return out


def sample_motion(segs: list[Segment], yaw0_rad: float, t_s: np.ndarray, g_mps2: float, oversample: int = 4,
                  n_prefix: int = 1, t_origin_s: float | None = None) -> Motion:
    """Evaluate the motion at the stamps ``t_s`` (uniform), integrating yaw and position on a finer grid.

    ``t_origin_s``: the time at which the profile starts (default ``t_s[0]``); an earlier origin samples the
    same motion later in its course (the rates and specific force are exact there; yaw and position are
    integrated from ``t_s[0]``)."""
    n = t_s.size
    t_origin = t_s[0] if t_origin_s is None else t_origin_s
    dt = (t_s[-1] - t_s[0]) / (n - 1)
    tf = t_s[0] + np.arange((n - 1) * oversample + 1) * (dt / oversample)
    val, der = _channels(repeat_to(segs, t_s[-1] - t_origin, n_prefix), np.maximum(tf - t_origin, 0.0))
    v, yaw_rate, slope = val.T
    dv, _, dslope = der.T
    pitch, dpitch = -slope, -dslope
    yaw = yaw0_rad + cumulative_simpson(yaw_rate, x=tf, initial=0.0)
    cp, sp_, cy, sy = np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    v_w = np.column_stack([v * cp * cy, v * cp * sy, -v * sp_])     # R_wb [v, 0, 0]
    p = np.column_stack([cumulative_simpson(v_w[:, i], x=tf, initial=0.0) for i in range(3)])
    k = slice(None, None, oversample)
    cp, sp_, cy, sy = cp[k], sp_[k], cy[k], sy[k]
    v, dv, yaw_rate, dpitch = v[k], dv[k], yaw_rate[k], dpitch[k]
    R = np.zeros((n, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cp, -sy, cy * sp_
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = sy * cp, cy, sy * sp_
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = -sp_, 0.0, cp
    # w_b = Ry(pitch)^T [0, 0, yaw_rate] + [0, pitch_rate, 0]
    w_b = np.column_stack([-sp_ * yaw_rate, dpitch, cp * yaw_rate])
    # f_b = [dv, 0, 0] + w_b x [v, 0, 0] + R^T [0, 0, g]  (w x [v,0,0] = [0, w_z v, -w_y v])
    f_b = np.column_stack([dv, w_b[:, 2] * v, -w_b[:, 1] * v]) + g_mps2 * R[:, 2, :]
    return Motion(t_s=t_s, p_w_m=p[k], v_w_mps=v_w[k], R_wb=R, yaw_rad=yaw[k], pitch_rad=pitch[k], speed_mps=v,
                  f_b_mps2=f_b, w_b_rps=w_b)
