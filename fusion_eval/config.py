"""Typed, validated run configuration: built-in defaults < YAML file < ``--set key=value``.

Values are given in human units (deg, deg/s/sqrt(Hz), m, ...) whose unit is in the key's name.
:func:`to_filter_params` converts them to SI exactly once; everything downstream is SI. The
resolved (merged) configuration is written next to every run's outputs.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from .errors import ConfigError

class Spec(NamedTuple):
    """One configuration key: default, meaning, and what values it accepts.

    ``kind``: ``choice`` (one of ``choices``), ``bool``, ``int``, ``float``, ``vec3`` (3 numbers, or one
    number for all three), ``windows`` (list of ``[start, end]``). ``auto`` admits the string 'auto',
    ``nullable`` admits null; ``positive``/``nonneg`` bound numbers.
    """

    default: Any
    doc: str
    kind: str = "float"
    choices: tuple = ()
    positive: bool = False
    nonneg: bool = False
    nullable: bool = False
    auto: bool = False


def S(default, doc, kind=None, **kw) -> Spec:
    if kind is None:
        kind = {bool: "bool", int: "int", float: "float", list: "vec3", str: "choice"}.get(type(default), "float")
    return Spec(default, doc, kind, **kw)


# Every key, its default and its meaning. README's configuration table is this table.
SCHEMA: dict[str, Spec] = {
    "filter.lidar_update": S("relative", "lidar odometry as 'relative' pose increments (stochastic cloning), 'absolute' poses, or 'none'",
                             choices=("relative", "absolute", "none")),
    "filter.use_gnss": S(True, "fuse GNSS position fixes"),
    "filter.bias_model": S("random_walk", "IMU bias model: 'random_walk' or 'constant' (bias states kept, no process noise)",
                           choices=("random_walk", "constant")),
    "filter.formulation": S("error_state", "'error_state' (ESKF: 15-state error, injection and reset) or 'nominal_state' "
                                           "(EKF on the full state [p, v, q, ba, bg] with quaternion normalisation)",
                            choices=("error_state", "nominal_state")),
    "filter.process_model": S("imu", "'imu' (strapdown mechanization) or 'odometer_gyro' (wheel speed and gyro drive the "
                                     "prediction; error state [dp, dtheta, dk, dbg])", choices=("imu", "odometer_gyro")),
    "filter.iterations": S(1, "iterated EKF: re-linearise each update up to this many times (1 = plain EKF)", positive=True),
    "filter.iteration_tol": S(1e-8, "iterated EKF: stop when the correction changes by less than this (norm)", positive=True),
    "filter.odometer_update": S(False, "fuse the odometer's forward speed as a body-frame velocity observation"),
    "filter.nhc": S(False, "non-holonomic constraint: lateral and vertical body velocity = 0 as a pseudo-observation "
                           "while not turning"),
    "filter.nhc_max_turn_rate_rps": S(0.13, "apply the constraint only while |angular rate| is below this, rad/s", positive=True),
    "filter.nhc_rate_hz": S(10.0, "rate of the constraint's pseudo-observations, Hz", positive=True),
    "filter.nhc_std_mps": S(0.1, "std of the constraint (lateral and vertical slip), m/s", positive=True),
    "filter.gravity_mps2": S("auto", "gravity magnitude; 'auto' = WGS84 normal gravity at the geodetic origin (9.80665 without one)",
                             "float", positive=True, auto=True),
    "filter.init_pose_from": S("groundtruth", "initial position/attitude from 'groundtruth' or the first valid 'lidar' pose",
                               choices=("groundtruth", "lidar")),
    "filter.init_velocity_from": S("groundtruth", "initial velocity from 'groundtruth' or from differencing the first two 'gnss' fixes",
                                   choices=("groundtruth", "gnss")),
    "imu.time_offset_s": S(None, "added to IMU stamps; null = the manifest's value (default 0)", "float", nullable=True),
    "imu.gyro_lag_s": S(None, "the gyro reports the rate of gyro_lag_s earlier and is advanced by this much; 'auto' = estimated "
                              "from the lidar rotation increments; null = the manifest's value", "float", nullable=True, auto=True),
    "imu.filled_packets": S("drop", "provider-filled IMU samples: 'drop' (default) or 'keep'", choices=("drop", "keep")),
    "imu.accel_noise_mps2_sqrthz": S(0.3, "accelerometer white noise density (velocity random walk), m/s^2/sqrt(Hz)", nonneg=True),
    "imu.gyro_noise_dps_sqrthz": S(0.1, "gyroscope white noise density (angle random walk), deg/s/sqrt(Hz)", nonneg=True),
    "imu.accel_bias_rw_mps3_sqrthz": S(1e-4, "accelerometer bias random walk, m/s^3/sqrt(Hz)", nonneg=True),
    "imu.gyro_bias_rw_dps2_sqrthz": S(1e-5, "gyroscope bias random walk, deg/s^2/sqrt(Hz)", nonneg=True),
    "imu.gap_factor": S(1.5, "an IMU interval longer than gap_factor x the median interval is a gap", positive=True),
    "imu.gap_noise_scale": S(10.0, "process noise std multiplier on intervals that are gaps", positive=True),
    "lidar.time_offset_s": S(None, "added to lidar stamps; null = the manifest's value (default 0)", "float", nullable=True),
    "lidar.interpolate_to_imu": S(True, "resample the lidar poses onto the IMU stamps (SLERP) before fusing"),
    "lidar.relative_pos_std_m": S(0.02, "relative update: position increment std, constant part, m", nonneg=True),
    "lidar.relative_pos_std_frac": S(0.01, "relative update: position increment std per metre travelled (0.01 = 1 %)", nonneg=True),
    "lidar.relative_att_std_deg": S(0.05, "relative update: rotation increment std, deg", positive=True),
    "lidar.absolute_pos_std_m": S(1.0, "absolute update: position std, m", positive=True),
    "lidar.absolute_att_std_deg": S(1.0, "absolute update: attitude std, deg", positive=True),
    "gnss.time_offset_s": S(None, "added to GNSS stamps; null = the manifest's value (default 0)", "float", nullable=True),
    "gnss.rate_hz": S(1.0, "decimate GNSS to this rate (null = keep every fix); only for streams the manifest marks 'degrade'",
                      "float", positive=True, nullable=True),
    "gnss.noise_std_m": S([1.0, 1.0, 2.0], "white noise added per axis E/N/U, m ([0, 0, 0] = none)", nonneg=True),
    "gnss.outages_s": S([], "outage windows [[start, end], ...] in seconds from the filter's start (the first IMU sample it uses)", "windows"),
    "gnss.seed": S(0, "seed of the GNSS noise", nonneg=True),
    "gnss.std_m": S("auto", "GNSS std given to the filter per axis, m; 'auto' = sqrt(reported accuracy^2 + added noise^2)",
                    "vec3", positive=True, auto=True),
    "gnss.lever_arm_b_m": S([0.0, 0.0, 0.0], "antenna position in the body frame, m"),
    "odometer.time_offset_s": S(None, "added to odometer stamps; null = the manifest's value (default 0)", "float", nullable=True),
    "odometer.speed_std_mps": S(0.1, "odometer forward-speed std of one reading (the velocity observation), m/s", positive=True),
    "odometer.added_noise_std_mps": S(0.05, "white noise added to an odometer stream the manifest marks 'degrade' "
                                            "(KITTI's OXTS vf is the GPS/INS solution), m/s", nonneg=True),
    "odometer.speed_noise_mps_sqrthz": S(0.05, "odometer + gyro model: speed noise density, m/s/sqrt(Hz)", positive=True),
    "odometer.slip_noise_mps_sqrthz": S(0.05, "odometer + gyro model: lateral/vertical slip noise density, m/s/sqrt(Hz)",
                                        positive=True),
    "odometer.scale_rw_per_sqrts": S(1e-5, "odometer + gyro model: random walk of the scale error, 1/sqrt(s)", nonneg=True),
    "init.odometer_scale_std": S(0.01, "initial std of the odometer scale error (odometer + gyro model)", nonneg=True),
    "init.pos_std_m": S(0.1, "initial position std, m", positive=True),
    "init.vel_std_mps": S(0.1, "initial velocity std, m/s", positive=True),
    "init.roll_pitch_std_deg": S(0.1, "initial roll and pitch std, deg", positive=True),
    "init.yaw_std_deg": S(0.01, "initial yaw std, deg (unobservable from relative lidar alone: keep it tight)", positive=True),
    "init.accel_bias_std_mps2": S(0.01, "initial accelerometer bias std, m/s^2", nonneg=True),
    "init.gyro_bias_std_dps": S(0.005, "initial gyroscope bias std, deg/s", nonneg=True),
    "evaluation.t_max_diff_s": S(0.01, "max stamp difference when evo associates estimate and reference poses, s", positive=True),
    "evaluation.association": S("nearest", "pose association: 'nearest' stamp within t_max_diff_s (evo's) or 'interpolate' "
                                           "the reference at the estimate's stamps (linear position, SLERP rotation)",
                                choices=("nearest", "interpolate")),
    "evaluation.alignment": S("none", "alignment before APE: 'none' (all estimates share the ground truth's frame), "
                                      "'origin', 'se3', 'sim3' (evo's) or '4dof' (yaw + translation)",
                              choices=("none", "origin", "se3", "sim3", "4dof")),
    "evaluation.segment_m": S(100.0, "per-segment breakdown: window length along the route, m", positive=True),
    "evaluation.segment_s": S(None, "per-segment breakdown by time instead: window length, s (null = by distance)",
                              "float", positive=True, nullable=True),
    "evaluation.rpe_delta_m": S(100.0, "RPE segment length for the per-distance RPE, m", positive=True),
    "output.plots": S(True, "write PNG plots"),
}


def defaults_of(schema: dict[str, Spec]) -> dict:
    out: dict = {}
    for key, spec in schema.items():
        sect, name = key.split(".")
        out.setdefault(sect, {})[name] = copy.deepcopy(spec.default)
    return out


def default_config() -> dict:
    """The built-in defaults as a nested dict (what ``configs/default.yaml`` spells out)."""
    return defaults_of(SCHEMA)


def check_value(key: str, spec: Spec, value: Any, where: str) -> Any:
    """Validate and normalise one value against its :class:`Spec`; raise :class:`ConfigError` naming the key."""
    if spec.nullable and value is None:
        return None
    if spec.auto and value == "auto":
        return value
    k = spec.kind
    if k == "choice":
        if value not in spec.choices:
            raise ConfigError(f"{where}: {key} must be one of {', '.join(spec.choices)}, got {value!r}")
        return value
    if k == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {key} must be true or false, got {value!r}")
        return value
    if k == "int":
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(f"{where}: {key} must be an integer, got {value!r}")
        if (spec.positive and value <= 0) or (spec.nonneg and value < 0):
            raise ConfigError(f"{where}: {key} must be {'> 0' if spec.positive else '>= 0'}, got {value!r}")
        return value
    if k == "vec3":
        return _vec3(key, value, where, positive=spec.positive, nonneg=spec.nonneg)
    if k == "windows":
        if not isinstance(value, list) or not all(isinstance(w, (list, tuple)) and len(w) == 2 for w in value):
            raise ConfigError(f"{where}: {key} must be a list of [start, end] pairs in seconds, got {value!r}")
        out = []
        for a, b in value:
            a, b = _number(key, a, where), _number(key, b, where)
            if b <= a:
                raise ConfigError(f"{where}: {key} window [{a}, {b}] must have end > start")
            out.append([a, b])
        return out
    if k == "jumps":
        if not isinstance(value, list) or not all(isinstance(w, (list, tuple)) and len(w) == 5 for w in value):
            raise ConfigError(f"{where}: {key} must be a list of [start_s, end_s, dE_m, dN_m, dU_m], got {value!r}")
        out = []
        for w in value:
            w = [_number(key, x, where) for x in w]
            if w[1] <= w[0]:
                raise ConfigError(f"{where}: {key} window [{w[0]}, {w[1]}] must have end > start")
            out.append(w)
        return out
    return _number(key, value, where, positive=spec.positive, nonneg=spec.nonneg)


def _number(key, value, where, positive=False, nonneg=False) -> float:
    if isinstance(value, str):
        # YAML 1.1 reads '1e-05' (no point, or no sign in the exponent) as a string
        try:
            value = float(value)
        except ValueError:
            pass
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


def merge(cfg: dict, overrides: dict, where: str, schema: dict[str, Spec] | None = None) -> dict:
    """Merge a nested ``{section: {key: value}}`` dict into ``cfg``, validating every key against ``schema``."""
    schema = SCHEMA if schema is None else schema
    out = copy.deepcopy(cfg)
    if not isinstance(overrides, dict):
        raise ConfigError(f"{where}: expected a mapping of sections ({', '.join(sorted(cfg))})")
    for sect, body in overrides.items():
        if sect not in out:
            raise ConfigError(f"{where}: unknown section {sect!r} (known: {', '.join(sorted(out))})")
        if not isinstance(body, dict):
            raise ConfigError(f"{where}: section {sect!r} must be a mapping of keys")
        for name, value in body.items():
            key = f"{sect}.{name}"
            if key not in schema:
                known = ", ".join(k.split(".")[1] for k in schema if k.startswith(sect + "."))
                raise ConfigError(f"{where}: unknown key {key!r} (known in {sect}: {known})")
            out[sect][name] = check_value(key, schema[key], value, where)
    return out


def load_config(path: Path | None, sets: tuple[str, ...] = (), schema: dict[str, Spec] | None = None,
                layers: tuple[tuple[dict, str], ...] = ()) -> dict:
    """Defaults, then ``layers`` (e.g. a dataset manifest's suggested settings), then the YAML file (if
    any), then ``key=value`` overrides; every value validated against ``schema``."""
    schema = SCHEMA if schema is None else schema
    cfg = defaults_of(schema)
    for body, where in layers:
        cfg = merge(cfg, body, where, schema)
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
        cfg = merge(cfg, body, str(path), schema)
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
        cfg = merge(cfg, {sect: {name: value}}, f"--set {key}", schema)
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
    formulation: str = "error_state"
    process_model: str = "imu"
    iterations: int = 1
    iteration_tol: float = 1e-8
    odometer_update: bool = False
    nhc: bool = False
    nhc_max_turn_rate_rps: float = 0.13
    nhc_rate_hz: float = 10.0
    nhc_std_mps: float = 0.1
    odo_speed_std_mps: float = 0.1
    odo_speed_noise: float = 0.05       # m/s/sqrt(Hz)
    odo_slip_noise: float = 0.05        # m/s/sqrt(Hz)
    odo_scale_rw: float = 1e-5          # 1/sqrt(s)
    odo_scale_init_std: float = 0.01


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
        formulation=c["filter"]["formulation"],
        process_model=c["filter"]["process_model"],
        iterations=int(c["filter"]["iterations"]),
        iteration_tol=c["filter"]["iteration_tol"],
        odometer_update=c["filter"]["odometer_update"],
        nhc=c["filter"]["nhc"],
        nhc_max_turn_rate_rps=c["filter"]["nhc_max_turn_rate_rps"],
        nhc_rate_hz=c["filter"]["nhc_rate_hz"],
        nhc_std_mps=c["filter"]["nhc_std_mps"],
        odo_speed_std_mps=c["odometer"]["speed_std_mps"],
        odo_speed_noise=c["odometer"]["speed_noise_mps_sqrthz"],
        odo_slip_noise=c["odometer"]["slip_noise_mps_sqrthz"],
        odo_scale_rw=c["odometer"]["scale_rw_per_sqrts"],
        odo_scale_init_std=init["odometer_scale_std"],
    )


def check_combination(cfg: dict) -> None:
    """Reject combinations of variant axes that do not make sense, naming the keys."""
    f = cfg["filter"]
    if f["process_model"] == "odometer_gyro":
        if f["formulation"] != "error_state":
            raise ConfigError("filter.process_model=odometer_gyro is an error-state filter: use filter.formulation=error_state")
        if f["odometer_update"] or f["nhc"]:
            raise ConfigError("filter.process_model=odometer_gyro already drives the prediction with the odometer and the "
                              "no-slip assumption: set filter.odometer_update=false and filter.nhc=false")
