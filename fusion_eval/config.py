"""Typed, validated run configuration: built-in defaults < YAML file < ``--set key=value``.

Values are given in human units (deg, deg/s/sqrt(Hz), m, ...) whose unit is in the key's name.
:func:`to_filter_params` converts them to SI exactly once; everything downstream is SI. The
resolved (merged) configuration is written next to every run's outputs.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import ConfigError

CHOICES = {
    "filter.lidar_update": ("relative", "absolute", "none"),
    "filter.bias_model": ("random_walk", "constant"),
    "filter.init_pose_from": ("groundtruth", "lidar"),
    "filter.init_velocity_from": ("groundtruth", "gnss"),
    "imu.filled_packets": ("drop", "keep"),
}

# Every key, its default and its meaning. README's configuration table is this table.
SCHEMA: dict[str, tuple[Any, str]] = {
    "filter.lidar_update": ("relative", "lidar odometry as 'relative' pose increments (stochastic cloning), 'absolute' poses, or 'none'"),
    "filter.use_gnss": (True, "fuse GNSS position fixes"),
    "filter.bias_model": ("random_walk", "IMU bias model: 'random_walk' or 'constant' (bias states kept, no process noise)"),
    "filter.gravity_mps2": ("auto", "gravity magnitude; 'auto' = WGS84 normal gravity at the geodetic origin (9.80665 without one)"),
    "filter.init_pose_from": ("groundtruth", "initial position/attitude from 'groundtruth' or the first valid 'lidar' pose"),
    "filter.init_velocity_from": ("groundtruth", "initial velocity from 'groundtruth' or from differencing the first two 'gnss' fixes"),
    "imu.time_offset_s": (None, "added to IMU stamps; null = the manifest's value (default 0)"),
    "imu.gyro_lag_s": (None, "the gyro reports the rate of gyro_lag_s earlier and is advanced by this much; 'auto' = estimated from the lidar rotation increments; null = the manifest's value"),
    "imu.filled_packets": ("drop", "provider-filled IMU samples: 'drop' (default) or 'keep'"),
    "imu.accel_noise_mps2_sqrthz": (0.3, "accelerometer white noise density (velocity random walk), m/s^2/sqrt(Hz)"),
    "imu.gyro_noise_dps_sqrthz": (0.1, "gyroscope white noise density (angle random walk), deg/s/sqrt(Hz)"),
    "imu.accel_bias_rw_mps3_sqrthz": (1e-4, "accelerometer bias random walk, m/s^3/sqrt(Hz)"),
    "imu.gyro_bias_rw_dps2_sqrthz": (1e-5, "gyroscope bias random walk, deg/s^2/sqrt(Hz)"),
    "imu.gap_factor": (1.5, "an IMU interval longer than gap_factor x the median interval is a gap"),
    "imu.gap_noise_scale": (10.0, "process noise std multiplier on intervals that are gaps"),
    "lidar.time_offset_s": (None, "added to lidar stamps; null = the manifest's value (default 0)"),
    "lidar.interpolate_to_imu": (True, "resample the lidar poses onto the IMU stamps (SLERP) before fusing"),
    "lidar.relative_pos_std_m": (0.02, "relative update: position increment std, constant part, m"),
    "lidar.relative_pos_std_frac": (0.01, "relative update: position increment std per metre travelled (0.01 = 1 %)"),
    "lidar.relative_att_std_deg": (0.05, "relative update: rotation increment std, deg"),
    "lidar.absolute_pos_std_m": (1.0, "absolute update: position std, m"),
    "lidar.absolute_att_std_deg": (1.0, "absolute update: attitude std, deg"),
    "gnss.time_offset_s": (None, "added to GNSS stamps; null = the manifest's value (default 0)"),
    "gnss.rate_hz": (1.0, "decimate GNSS to this rate (null = keep every fix)"),
    "gnss.noise_std_m": ([1.0, 1.0, 2.0], "white noise added per axis E/N/U, m ([0, 0, 0] = none)"),
    "gnss.outages_s": ([], "outage windows [[start, end], ...] in seconds from the first IMU sample"),
    "gnss.seed": (0, "seed of the GNSS noise"),
    "gnss.std_m": ("auto", "GNSS std given to the filter per axis, m; 'auto' = sqrt(reported accuracy^2 + added noise^2)"),
    "gnss.lever_arm_b_m": ([0.0, 0.0, 0.0], "antenna position in the body frame, m"),
    "init.pos_std_m": (0.1, "initial position std, m"),
    "init.vel_std_mps": (0.1, "initial velocity std, m/s"),
    "init.roll_pitch_std_deg": (0.1, "initial roll and pitch std, deg"),
    "init.yaw_std_deg": (0.01, "initial yaw std, deg (unobservable from relative lidar alone: keep it tight)"),
    "init.accel_bias_std_mps2": (0.01, "initial accelerometer bias std, m/s^2"),
    "init.gyro_bias_std_dps": (0.005, "initial gyroscope bias std, deg/s"),
    "evaluation.t_max_diff_s": (0.01, "max stamp difference when evo associates estimate and reference poses, s"),
    "evaluation.rpe_delta_m": (100.0, "RPE segment length for the per-distance RPE, m"),
    "output.plots": (True, "write PNG plots"),
}


def default_config() -> dict:
    """The built-in defaults as a nested dict (what ``configs/default.yaml`` spells out)."""
    out: dict = {}
    for key, (value, _) in SCHEMA.items():
        sect, name = key.split(".")
        out.setdefault(sect, {})[name] = copy.deepcopy(value)
    return out


def _check_value(key: str, value: Any, where: str) -> Any:
    default = SCHEMA[key][0]
    if key in CHOICES:
        if value not in CHOICES[key]:
            raise ConfigError(f"{where}: {key} must be one of {', '.join(CHOICES[key])}, got {value!r}")
        return value
    if key == "filter.gravity_mps2":
        if value == "auto":
            return value
        return _number(key, value, where, positive=True)
    if key == "imu.gyro_lag_s":
        if value is None or value == "auto":
            return value
        return _number(key, value, where)
    if key == "gnss.std_m":
        if value == "auto":
            return value
        return _vec3(key, value, where, positive=True)
    if key == "gnss.outages_s":
        if not isinstance(value, list) or not all(isinstance(w, (list, tuple)) and len(w) == 2 for w in value):
            raise ConfigError(f"{where}: {key} must be a list of [start, end] pairs in seconds, got {value!r}")
        out = []
        for a, b in value:
            a, b = _number(key, a, where), _number(key, b, where)
            if b <= a:
                raise ConfigError(f"{where}: {key} window [{a}, {b}] must have end > start")
            out.append([a, b])
        return out
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {key} must be true or false, got {value!r}")
        return value
    if isinstance(default, list):
        return _vec3(key, value, where, positive=False, nonneg=True)
    if isinstance(default, int) and not isinstance(default, bool):
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(f"{where}: {key} must be an integer, got {value!r}")
        return value
    if default is None or isinstance(default, float):
        if value is None and (default is None or key == "gnss.rate_hz"):
            return None
        return _number(key, value, where, positive=key.endswith(("rate_hz", "_factor", "_scale", "t_max_diff_s", "rpe_delta_m")),
                       nonneg=not key.endswith("offset_s") and not key.endswith("lag_s"))
    return value


def _number(key, value, where, positive=False, nonneg=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ConfigError(f"{where}: {key} must be a number, got {value!r}")
    if positive and value <= 0:
        raise ConfigError(f"{where}: {key} must be > 0, got {value!r}")
    if nonneg and value < 0:
        raise ConfigError(f"{where}: {key} must be >= 0, got {value!r}")
    return float(value)


def _vec3(key, value, where, positive=False, nonneg=False) -> list[float]:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * 3
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ConfigError(f"{where}: {key} must be a list of 3 numbers, got {value!r}")
    return [_number(key, v, where, positive=positive, nonneg=nonneg) for v in value]


def merge(cfg: dict, overrides: dict, where: str) -> dict:
    """Merge a nested ``{section: {key: value}}`` dict into ``cfg``, validating every key."""
    out = copy.deepcopy(cfg)
    if not isinstance(overrides, dict):
        raise ConfigError(f"{where}: expected a mapping of sections (filter, imu, lidar, gnss, init, evaluation, output)")
    for sect, body in overrides.items():
        if sect == "dataset":
            out["dataset"] = body
            continue
        if sect not in out:
            raise ConfigError(f"{where}: unknown section {sect!r} (known: {', '.join(sorted(k for k in out if k != 'dataset'))}, dataset)")
        if not isinstance(body, dict):
            raise ConfigError(f"{where}: section {sect!r} must be a mapping of keys")
        for name, value in body.items():
            key = f"{sect}.{name}"
            if key not in SCHEMA:
                known = ", ".join(k.split(".")[1] for k in SCHEMA if k.startswith(sect + "."))
                raise ConfigError(f"{where}: unknown key {key!r} (known in {sect}: {known})")
            out[sect][name] = _check_value(key, value, where)
    return out


def load_config(path: Path | None, sets: tuple[str, ...] = ()) -> dict:
    """Defaults, then the YAML file (if any), then ``key=value`` overrides; validated."""
    cfg = default_config()
    if path is not None:
        path = Path(path)
        if not path.exists():
            raise ConfigError(f"{path}: config file not found")
        try:
            body = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = f":{mark.line + 1}" if mark is not None else ""
            raise ConfigError(f"{path}{line}: not valid YAML ({getattr(exc, 'problem', exc)})") from None
        cfg = merge(cfg, body, str(path))
    for item in sets:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or "." not in key:
            raise ConfigError(f"--set {item!r}: expected section.key=value, e.g. imu.gyro_noise_dps_sqrthz=0.05")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f"--set {item!r}: value is not valid YAML") from None
        sect, _, name = key.partition(".")
        cfg = merge(cfg, {sect: {name: value}}, f"--set {key}")
    return cfg


def get(cfg: dict, key: str) -> Any:
    sect, name = key.split(".")
    return cfg[sect][name]


@dataclass(frozen=True)
class FilterParams:
    """Filter settings in SI units (rad, m, s), converted once from the human-unit config."""

    lidar_update: str
    use_gnss: bool
    bias_model: str
    gravity_mps2: float
    accel_noise: float      # m/s^2/sqrt(Hz)
    gyro_noise: float       # rad/s/sqrt(Hz)
    accel_bias_rw: float    # m/s^3/sqrt(Hz)
    gyro_bias_rw: float     # rad/s^2/sqrt(Hz)
    gap_factor: float
    gap_noise_scale: float
    rel_pos_std_m: float
    rel_pos_std_frac: float
    rel_att_std_rad: float
    abs_pos_std_m: float
    abs_att_std_rad: float
    gnss_lever_arm_b_m: np.ndarray
    init_std: np.ndarray    # (15,) 1-sigma of [dp, dv, dtheta, dba, dbg]


def to_filter_params(cfg: dict, gravity_mps2: float) -> FilterParams:
    """Convert the human-unit config to SI :class:`FilterParams` (the one place units change)."""
    d2r = np.pi / 180.0
    c = cfg
    init = c["init"]
    init_std = np.concatenate([
        np.full(3, init["pos_std_m"]),
        np.full(3, init["vel_std_mps"]),
        [init["roll_pitch_std_deg"] * d2r, init["roll_pitch_std_deg"] * d2r, init["yaw_std_deg"] * d2r],
        np.full(3, init["accel_bias_std_mps2"]),
        np.full(3, init["gyro_bias_std_dps"] * d2r),
    ])
    return FilterParams(
        lidar_update=c["filter"]["lidar_update"],
        use_gnss=c["filter"]["use_gnss"],
        bias_model=c["filter"]["bias_model"],
        gravity_mps2=gravity_mps2,
        accel_noise=c["imu"]["accel_noise_mps2_sqrthz"],
        gyro_noise=c["imu"]["gyro_noise_dps_sqrthz"] * d2r,
        accel_bias_rw=c["imu"]["accel_bias_rw_mps3_sqrthz"],
        gyro_bias_rw=c["imu"]["gyro_bias_rw_dps2_sqrthz"] * d2r,
        gap_factor=c["imu"]["gap_factor"],
        gap_noise_scale=c["imu"]["gap_noise_scale"],
        rel_pos_std_m=c["lidar"]["relative_pos_std_m"],
        rel_pos_std_frac=c["lidar"]["relative_pos_std_frac"],
        rel_att_std_rad=c["lidar"]["relative_att_std_deg"] * d2r,
        abs_pos_std_m=c["lidar"]["absolute_pos_std_m"],
        abs_att_std_rad=c["lidar"]["absolute_att_std_deg"] * d2r,
        gnss_lever_arm_b_m=np.array(c["gnss"]["lever_arm_b_m"], float),
        init_std=init_std,
    )
