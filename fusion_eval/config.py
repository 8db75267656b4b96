"""Typed, validated configuration: the schema, its layers, and the one conversion to SI.

Values are given in human units (deg, deg/s/sqrt(Hz), m, ...) whose unit is in the key's name. The
schema is one :class:`Spec` per key: the core keys below, plus the keys each registered formulation and
observation declares in its own module (:func:`schema` assembles them). A configuration is built from
layers (built-in defaults, a dataset manifest's suggestions, files, ``--set`` items, Python overrides),
each validated key by key as it is read (:func:`parse_file`, :func:`parse_sets`, :func:`parse_overrides`)
and merged in order (:func:`merge_layers`); :mod:`fusion_eval.session` decides the order for a run.
:class:`Settings` is the resolved configuration in SI units, converted once by a rule on the key names
(``_deg`` -> ``_rad``, ``_dps`` -> ``_rps``, ...); everything downstream reads it.
"""

from __future__ import annotations

import copy
import functools
import math
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from . import yaml_lines
from .errors import ConfigError, shown as shown_value
from .spec import S, Spec  # noqa: F401  (re-exported: config.S, config.Spec)


# Sections written in config.resolved.yaml for information; a config file may hold them (ignored).
INFORMATIONAL_SECTIONS = ("dataset", "applied", "config_source", "versions")
SECTION_ORDER = ("filter", "smoother", "imu", "lidar", "gnss", "odometer", "init", "evaluation", "output")

# The core keys: what no single formulation or observation owns. Keys of the formulations and observations
# are declared in their modules (fusion_eval/filters/formulations/, fusion_eval/filters/observations/).
CORE: dict[str, Spec] = {
    "filter.bias_model": S("random_walk", "IMU bias model: 'random_walk', 'constant' (bias states kept, no process noise) "
                                          "or 'gauss_markov' (first order, correlation time imu.*_bias_corr_time_s)",
                           choices=("<bias models>",)),
    "filter.formulation": S("error_state", "'error_state' (ESKF: 15-state error, injection and reset), 'nominal_state' "
                                           "(EKF on the full state [p, v, q, ba, bg] with quaternion normalisation) or "
                                           "'invariant' (right-invariant EKF on SE_2(3), biases additive)",
                            choices=("<formulations>",)),
    "filter.process_model": S("imu", "'imu' (strapdown mechanization) or 'odometer_gyro' (wheel speed and gyro drive the "
                                     "prediction; error state [dp, dtheta, dk, dbg])", choices=("<process models>",)),
    "filter.iterations": S(1, "iterated EKF: re-linearise each update up to this many times (1 = plain EKF)", positive=True),
    "filter.replay": S("auto", "'auto' = the event loop in one compiled call when the formulation and every enabled "
                               "observation have compiled kernels (the RTS smoother too; not the batch smoother or the iterated update), else from Python; "
                               "'python' = always from Python (same estimate, slower; for debugging)",
                       choices=("auto", "python")),
    "filter.iteration_tol": S(1e-8, "iterated EKF: stop when the correction changes by less than this (norm)", positive=True),
    "filter.gravity_mps2": S("auto", "gravity magnitude; 'auto' = WGS84 normal gravity at the geodetic origin (9.80665 without one)",
                             "float", positive=True, auto=True),
    "filter.init_pose_from": S("auto", "initial position/attitude: 'groundtruth', the first valid 'lidar' pose (anchored on "
                                       "the ground truth), or 'data' (levelling, and the heading from the lidar's track "
                                       "on the GNSS or the GNSS's direction of travel: no ground truth); 'auto' = "
                                       "'groundtruth' where the drive has one, else 'data'",
                               choices=("auto", "groundtruth", "lidar", "data")),
    "filter.init_velocity_from": S("auto", "initial velocity from 'groundtruth' (its velocity, or its positions "
                                           "differenced over +/-0.1 s where it has none: TUM, EuRoC motion capture), "
                                           "from differencing the first two 'gnss' fixes, or from the 'data' (the lidar's "
                                           "positions, else the GNSS's, else the odometer); 'auto' = 'groundtruth' "
                                           "where the drive has one, else 'data'",
                                   choices=("auto", "groundtruth", "gnss", "data")),
    "smoother.method": S("none", "offline smoothing beside the filter, written as the 'smoothed' estimate: 'none', 'rts' "
                                 "(Rauch-Tung-Striebel backward pass over the filter's own models) or 'batch' (GTSAM factor "
                                 "graph of every measurement the filter used; the 'smoother' extra); see \"Offline smoothing\"",
                         choices=("none", "rts", "batch")),
    "imu.time_offset_s": S(None, "added to IMU stamps; null = the manifest's value (default 0)", "float", nullable=True),
    "imu.gyro_lag_s": S(None, "the gyro reports the rate of gyro_lag_s earlier and is advanced by this much; 'auto' = estimated "
                              "from the data (gyro vs lidar rotation rate; the device figure without lidar); null = the "
                              "manifest's value (default 0)", "float", nullable=True, auto=True),
    "imu.accel_lag_s": S(None, "the accelerometer reports the specific force of accel_lag_s earlier and is advanced by this "
                               "much; 'auto' = estimated from the data (accelerometer vs lidar acceleration; the device figure "
                               "without lidar); null = the manifest's value (default 0)", "float", nullable=True, auto=True),
    "imu.filled_packets": S("drop", "provider-filled IMU samples (KITTI's marked packets; in a bag or CSV, runs of samples on "
                               "exact straight lines, README 'Handling the KITTI quirks'): 'drop' (default) or 'keep'",
                               choices=("drop", "keep")),
    "imu.accel_noise_mps2_sqrthz": S("auto", "accelerometer white noise density (velocity random walk), m/s^2/sqrt(Hz); "
                                          "'auto' = from the stream's second differences", "float", nonneg=True, auto=True, reads="filter"),
    "imu.gyro_noise_dps_sqrthz": S("auto", "gyroscope white noise density (angle random walk), deg/s/sqrt(Hz); 'auto' = from "
                                        "the stream's second differences", "float", nonneg=True, auto=True, reads="filter"),
    "imu.accel_noise_scale": S(1.0, "factor on the accelerometer white noise (given or estimated): a tuned value that "
                                    "carries over to drives whose noise is estimated from their own data", positive=True, reads="filter"),
    "imu.gyro_noise_scale": S(1.0, "factor on the gyroscope white noise (given or estimated)", positive=True, reads="filter"),
    "imu.accel_bias_rw_mps3_sqrthz": S(1e-4, "accelerometer bias random walk, m/s^3/sqrt(Hz)", nonneg=True, reads="filter"),
    "imu.gyro_bias_rw_dps2_sqrthz": S(1e-5, "gyroscope bias random walk, deg/s^2/sqrt(Hz)", nonneg=True, reads="filter"),
    "imu.gap_factor": S(1.5, "an IMU interval longer than gap_factor x the median interval is a gap (above 1: at 1 or "
                             "below every interval is one)", above=1.0),
    "imu.gap_noise_scale": S(10.0, "process noise std multiplier on intervals that are gaps", positive=True, reads="filter"),
    "imu.gap_turn_rate_dps": S(10.0, "std of the unknown turn rate over an IMU gap, per axis, deg/s: at the first sample "
                                     "after a gap of T s the attitude's variance grows by (rate x T)^2 (the KITTI drives' "
                                     "own RMS turn rate, from their gyro: 8-12 deg/s)", nonneg=True, reads="filter"),
    "imu.gap_accel_mps2": S(0.5, "std of the unknown acceleration over an IMU gap, per axis, m/s^2: the velocity's "
                                 "variance grows by (accel x T)^2 (a car's typical longitudinal acceleration)",
                            nonneg=True, reads="filter"),
    "lidar.time_offset_s": S(None, "added to lidar stamps; 'auto' = estimated from the data (accelerometer vs lidar "
                                   "acceleration; not together with imu.accel_lag_s=auto); null = the manifest's value "
                                   "(default 0)", "float", nullable=True, auto=True),
    "lidar.extrinsic_rotation": S("calibration", "lidar-IMU rotation: the 'calibration' files' as they are, or 'auto' = corrected "
                                                 "by a hand-eye estimate from the data (gyro and accelerometer vs lidar)",
                                  choices=("calibration", "auto")),
    "lidar.extrinsic_translation": S("calibration", "lidar-IMU lever arm: the 'calibration' files' as it is, or 'auto' = its "
                                                    "horizontal components corrected by the same hand-eye estimate",
                                     choices=("calibration", "auto")),
    "lidar.interpolate_to_imu": S(True, "resample the lidar poses onto the IMU stamps (SLERP) before fusing"),
    "gnss.time_offset_s": S(None, "added to GNSS stamps; null = the manifest's value (default 0)", "float", nullable=True),
    "gnss.rate_hz": S(1.0, "decimate GNSS to this rate (null = keep every fix); only for streams the manifest marks "
                           "'degrade' (on another stream it and gnss.noise_std_m are a data warning: a sweep over them "
                           "gave identical rows and a 'best' with no word)",
                      "float", positive=True, nullable=True, reads="data"),
    "gnss.noise_std_m": S([1.0, 1.0, 2.0], "white noise added per axis E/N/U, m ([0, 0, 0] = none)", nonneg=True, reads="data"),
    "gnss.outages_s": S([], "outage windows [[start, end], ...] in seconds from the filter's start (the first IMU sample it "
                            "uses); applied to a receiver's stream too (which gets no noise and keeps its rate)", "windows", reads="data"),
    "gnss.seed": S(0, "seed of the GNSS noise", nonneg=True, reads="data"),
    "odometer.time_offset_s": S(None, "added to odometer stamps; null = the manifest's value (default 0)", "float", nullable=True),
    "odometer.added_noise_std_mps": S(0.05, "white noise added to an odometer stream the manifest marks 'degrade' "
                                            "(KITTI's OXTS vf is the GPS/INS solution), m/s", nonneg=True, reads="data"),
    "odometer.scale": S("auto", "the odometer's scale factor (its reading over the true speed), divided out of its "
                                "readings: a number, or 'auto' = estimated from the fused GNSS (the odometer's speed "
                                "dead-reckoned along the gyro's heading against the GNSS's displacement over 30 s "
                                "windows) and applied where it lies over 3 std from 1; 1 without GNSS",
                                "float", positive=True, auto=True, reads="data"),
    "init.pos_std_m": S(0.1, "initial position std, m", positive=True, reads="filter"),
    "init.vel_std_mps": S(0.1, "initial velocity std, m/s", positive=True, reads="filter"),
    "init.roll_pitch_std_deg": S(0.1, "initial roll and pitch std, deg", positive=True, reads="filter"),
    "init.yaw_std_deg": S(0.01, "initial yaw std, deg (unobservable from relative lidar alone: keep it tight)", positive=True, reads="filter"),
    "init.accel_bias_std_mps2": S(0.01, "initial accelerometer bias std, m/s^2", nonneg=True, reads="filter"),
    "init.gyro_bias_std_dps": S(0.005, "initial gyroscope bias std, deg/s", nonneg=True, reads="filter"),
    "evaluation.t_max_diff_s": S(0.01, "max stamp difference when evo associates estimate and reference poses, s", positive=True),
    "evaluation.association": S("nearest", "pose association (evo's --sync_method): 'nearest' stamp within t_max_diff_s, "
                                           "or 'interpolate': the stamps matched the same way, then the denser "
                                           "trajectory interpolated (linear position, SLERP rotation) at the matched "
                                           "stamps of the other; with t_max_diff_s above half the ground truth's "
                                           "interval, every pose of a sparser estimate is scored at its own stamp",
                                choices=("nearest", "interpolate")),
    "evaluation.alignment": S("none", "alignment before APE: 'none' (all estimates share the ground truth's frame), "
                                      "'origin', 'se3', 'sim3' (evo's) or '4dof' (yaw + translation)",
                              choices=("none", "origin", "se3", "sim3", "4dof")),
    "evaluation.engine": S("arrays", "how evo's APE/RPE are computed: 'arrays' (evo's association, alignment, pair selection "
                                     "and results, the per-pose loops on whole arrays; equal to evo to 1e-9) or 'evo' "
                                     "(evo's own per-pose loops, ~10x slower)", choices=("arrays", "evo")),
    "evaluation.span": S("common", "score every estimate over the same span, the intersection of their coverage with the "
                         "ground truth ('common'), or each over its own poses ('own')", choices=("common", "own")),
    "evaluation.segment_m": S(100.0, "per-segment breakdown: window length along the route, m", positive=True),
    "evaluation.segment_s": S(None, "per-segment breakdown by time instead: window length, s (null = by distance)",
                              "float", positive=True, nullable=True),
    "evaluation.rpe_delta_m": S(100.0, "RPE segment length for the per-distance RPE, m", positive=True),
    "output.plots": S(True, "write PNG plots"),
    "output.zip_trajectories": S(False, "also store the associated reference and estimate trajectories in each estimate's "
                                        "APE translation result zip, as evo does with its save_traj_in_zip setting (off by "
                                        "default, as in evo: the TUM files hold the same poses)"),
}


@functools.lru_cache(maxsize=1)
def schema() -> dict[str, Spec]:
    """Every key of a run's configuration: the core keys and those of the registered formulations and
    observations, with the registries' choices filled in, in section order."""
    from .filters import formulations as fm
    from .filters import observations as ob

    keys: dict[str, Spec] = {}
    for src, where in ((CORE, "config.CORE"), (fm.keys(), "a formulation"), (ob.keys(), "an observation")):
        for k, spec in src.items():
            if k in keys:
                raise RuntimeError(f"configuration key {k!r} declared twice ({where})")
            keys[k] = spec
    choices = {"filter.bias_model": tuple(fm.BIAS_MODELS), "filter.formulation": fm.formulations(),
               "filter.process_model": fm.process_models()}
    for k, c in choices.items():
        keys[k] = keys[k]._replace(choices=c)
    order = {s: i for i, s in enumerate(SECTION_ORDER)}
    return dict(sorted(keys.items(), key=lambda kv: order.get(kv[0].split(".")[0], len(order))))


def keys_read_by(role: str) -> tuple[str, ...]:
    """The keys declared ``reads=role`` (:class:`~fusion_eval.spec.Spec`): ``filter`` (a sweep batches runs that
    differ only in these), ``data`` (``tune`` refuses to tune these)."""
    return tuple(k for k, spec in schema().items() if spec.reads == role)


def defaults_of(schema_: dict[str, Spec]) -> dict:
    out: dict = {}
    for key, spec in schema_.items():
        sect, name = key.split(".")
        out.setdefault(sect, {})[name] = copy.deepcopy(spec.default)
    return out


def default_config() -> dict:
    """The built-in defaults as a nested dict (what ``configs/default.yaml`` spells out)."""
    return defaults_of(schema())


def check_value(key: str, spec: Spec, value: Any, where: str) -> Any:
    """Validate and normalise one value against its :class:`Spec`; raise :class:`ConfigError` naming the key."""
    if spec.nullable and value is None:
        return None
    if spec.auto and value == "auto":
        return value
    try:
        return _checked(key, spec, value, where)
    except ConfigError as e:
        # name the words the key also takes (its default may be one of them)
        also = [w for w, ok in (("'auto'", spec.auto), ("null", spec.nullable)) if ok]
        if not also or spec.kind == "choice":
            raise
        msg = str(e)
        for lead, words in ((" must be true or false", ["true", "false"]), (" must be a number", ["a number"])):
            if lead in msg:
                w = words + also
                raise ConfigError(msg.replace(lead, f" must be {', '.join(w[:-1])} or {w[-1]}", 1)) from None
        raise


def _checked(key: str, spec: Spec, value: Any, where: str) -> Any:
    k = spec.kind
    if k == "choice":
        if value not in spec.choices:
            raise ConfigError(f"{where}: {key} must be one of {', '.join(spec.choices)}, got {shown_value(value)}")
        return value
    if k == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {key} must be true or false, got {shown_value(value)}")
        return value
    if k == "int":
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(f"{where}: {key} must be an integer, got {shown_value(value)}")
        if (spec.positive and value <= 0) or (spec.nonneg and value < 0):
            raise ConfigError(f"{where}: {key} must be {'> 0' if spec.positive else '>= 0'}, got {shown_value(value)}")
        return value
    if k == "vec3":
        return _vec3(key, value, where, positive=spec.positive, nonneg=spec.nonneg)
    if k == "windows":
        if not isinstance(value, list) or not all(isinstance(w, (list, tuple)) and len(w) == 2 for w in value):
            raise ConfigError(f"{where}: {key} must be a list of [start, end] pairs in seconds, got {shown_value(value)}")
        out = []
        for a, b in value:
            a, b = _number(key, a, where), _number(key, b, where)
            if b <= a:
                raise ConfigError(f"{where}: {key} window [{a}, {b}] must have end > start")
            out.append([a, b])
        return out
    if k == "jumps":
        if not isinstance(value, list) or not all(isinstance(w, (list, tuple)) and len(w) == 5 for w in value):
            raise ConfigError(f"{where}: {key} must be a list of [start_s, end_s, dE_m, dN_m, dU_m], got {shown_value(value)}")
        out = []
        for w in value:
            w = [_number(key, x, where) for x in w]
            if w[1] <= w[0]:
                raise ConfigError(f"{where}: {key} window [{w[0]}, {w[1]}] must have end > start")
            out.append(w)
        return out
    v = _number(key, value, where, positive=spec.positive, nonneg=spec.nonneg)
    if spec.below is not None and not v < spec.below:
        raise ConfigError(f"{where}: {key} must be < {spec.below:g}, got {shown_value(value)}")
    if spec.above is not None and not v > spec.above:
        raise ConfigError(f"{where}: {key} must be > {spec.above:g}, got {shown_value(value)}")
    return v


# No setting of a navigation filter or simulator is a number beyond this (stamps are ~1e9 s; a correlation time of 1e15 s
# stands for infinity; noise densities, lengths
# and rates far below); 1e200 is a typo, and squared it overflows.
MAX_MAGNITUDE = 1e15


def _number(key, value, where, positive=False, nonneg=False) -> float:
    if isinstance(value, str):
        # YAML 1.1 reads '1e-05' (no point, or no sign in the exponent) as a string
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (isinstance(value, float) and not math.isfinite(value)):
        # (an integer is finite, and is not handed to numpy: one beyond int64, 99999999999999999999999, was a traceback)
        raise ConfigError(f"{where}: {key} must be a number, got {shown_value(value)}")
    if abs(value) > MAX_MAGNITUDE:
        raise ConfigError(f"{where}: {key} = {shown_value(value)} is beyond any plausible value of it (|value| <= {MAX_MAGNITUDE:.0e})")
    if positive and value <= 0:
        raise ConfigError(f"{where}: {key} must be > 0, got {shown_value(value)}")
    if nonneg and value < 0:
        raise ConfigError(f"{where}: {key} must be >= 0, got {shown_value(value)}")
    return float(value)


def _vec3(key, value, where, positive=False, nonneg=False) -> list[float]:
    if isinstance(value, str):           # '2e0' or '1e300': floats in YAML 1.2, strings to PyYAML's YAML 1.1
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * 3
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ConfigError(f"{where}: {key} must be a list of 3 numbers, got {shown_value(value)}")
    return [_number(key, v, where, positive=positive, nonneg=nonneg) for v in value]


# ---- layers ------------------------------------------------------------------------------------
class Layer(NamedTuple):
    """One validated source of settings: ``{section: {key: value}}`` and where it came from."""

    body: dict
    where: str
    dataset: dict | None = None     # a config.resolved.yaml's record of the dataset it was run on (informational)


def validate(body: Any, where: str, schema_: dict[str, Spec] | None = None, informational: tuple = ()) -> Layer:
    """Check a nested ``{section: {key: value}}`` mapping against the schema, key by key; sections named
    in ``informational`` are dropped."""
    schema_ = schema() if schema_ is None else schema_
    sections = sorted({k.split(".")[0] for k in schema_})
    if not isinstance(body, dict):
        raise ConfigError(f"{where}: expected a mapping of sections ({', '.join(sections)})")
    out: dict = {}
    for sect, keys in body.items():
        if sect in informational:
            continue
        if sect not in sections:
            raise ConfigError(f"{yaml_lines.at(where, body, sect)}: unknown section {sect!r} (known: {', '.join(sections)})")
        if not isinstance(keys, dict):
            raise ConfigError(f"{yaml_lines.at(where, body, sect)}: section {sect!r} must be a mapping of keys")
        for name, value in keys.items():
            key = f"{sect}.{name}"
            at = yaml_lines.at(where, keys, name)          # file:line when the body came from a file
            if key not in schema_:
                known = ", ".join(k.split(".")[1] for k in schema_ if k.startswith(sect + "."))
                raise ConfigError(f"{at}: unknown key {key!r} (known in {sect}: {known})")
            if name in getattr(keys, "empty", ()):     # 'rate_hz:' with nothing after it: null, by YAML's rule
                raise ConfigError(f"{at}: {key} has no value (write null for null)")
            out.setdefault(sect, {})[name] = check_value(key, schema_[key], value, at)
    return Layer(out, where)


def _shipped_hint(path: Path) -> str:
    """'; did you mean configs/lidar-imu.yaml?' where a file of that name is under configs/ (the working directory's,
    else the shipped tree's): `-c lidar-imu.yaml` said only 'not found' (a student's review)."""
    from .resources import shipped_root

    for root in (r for r in (Path.cwd(), shipped_root()) if r is not None):
        hits = sorted((root / "configs").rglob(path.name)) if (root / "configs").is_dir() else []
        if hits:
            q = hits[0]
            shown = q.relative_to(root) if root == Path.cwd() else q
            return f"; did you mean {shown}{' (shipped with fusion-eval)' if root != Path.cwd() else ''}?"
    return ""


def read_yaml(path: Path, what: str = "config file") -> Any:
    """A YAML file's content; a missing file or bad YAML is a one-line error naming the file (and line)."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path}: is a folder; expected a YAML {what}")
    if not path.is_file():
        raise ConfigError(f"{path}: {what} not found{_shipped_hint(path)}")
    try:
        return yaml_lines.load(path.read_text(encoding="utf-8"))     # mappings that know their lines
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text (UTF-8) YAML {what}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{path}{line}: not valid YAML ({getattr(exc, 'problem', exc)})") from None


def parse_file(path: Path, schema_: dict[str, Spec] | None = None) -> Layer:
    """A configuration file as a layer. A ``config.resolved.yaml`` is accepted: its informational sections
    (dataset, applied, config_source, versions) are ignored."""
    body = read_yaml(path) or {}
    if isinstance(body, dict) and "streams" in body:
        raise ConfigError(f"{path}: this is a dataset manifest (it has 'streams'), not a configuration: give it as the "
                          "DATASET argument")
    layer = validate(body, str(path), schema_, informational=INFORMATIONAL_SECTIONS)
    ran_on = body.get("dataset") if isinstance(body, dict) else None
    return layer._replace(dataset=ran_on) if isinstance(ran_on, dict) else layer


def parse_sets(sets: tuple[str, ...], schema_: dict[str, Spec] | None = None) -> Layer:
    """``--set section.key=value`` items (the value is YAML) as one layer, later items winning."""
    schema_ = schema() if schema_ is None else schema_
    body: dict = {}
    for item in sets:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or "." not in key:
            raise ConfigError(f"--set {item!r}: expected section.key=value, e.g. imu.gyro_noise_dps_sqrthz=0.05")
        shown = item if len(item) <= 200 else item[:200] + f"... ({len(item):,} characters)"
        if not raw.strip():      # YAML reads nothing as null: an empty shell variable kept every GNSS fix, with no word
            raise ConfigError(f"--set {shown!r}: no value (write {key}=null for null)")
        try:
            value = yaml_lines.load(raw)       # as a file's values: YAML 1.2 floats, no 1.1 octal or base-60
        except yaml.YAMLError as exc:
            why = getattr(exc, "problem", None) or ""
            raise ConfigError(f"--set {shown!r}: " + (why if "YAML 1.1" in why else "value is not valid YAML")) from None
        except ValueError:       # an integer of thousands of digits (Python's int limit): no setting's value
            raise ConfigError(f"--set {shown!r}: the value is not a plausible number") from None
        sect, _, name = key.partition(".")
        one = validate({sect: {name: value}}, f"--set {key}", schema_)
        body.setdefault(sect, {}).update(one.body[sect])
    return Layer(body, "--set")


def parse_overrides(overrides: dict | None, where: str = "overrides", schema_: dict[str, Spec] | None = None) -> Layer:
    """Python overrides as a layer: ``{"gnss.rate_hz": 2.0}`` (dotted keys, plain values) or nested
    ``{"gnss": {"rate_hz": 2.0}}``."""
    nested: dict = {}
    for k, v in (overrides or {}).items():
        if isinstance(v, dict) and "." not in k:
            nested.setdefault(k, {}).update(v)
            continue
        sect, dot, name = str(k).partition(".")
        if not dot:
            raise ConfigError(f"{where}: {k!r} is not a 'section.key' name")
        nested.setdefault(sect, {})[name] = v
    return validate(nested, where, schema_)


def merge_layers(layers: tuple[Layer, ...] | list[Layer], schema_: dict[str, Spec] | None = None) -> dict:
    """The built-in defaults with each (validated) layer applied in order."""
    cfg = defaults_of(schema() if schema_ is None else schema_)
    for layer in layers:
        for sect, body in layer.body.items():
            cfg[sect].update(copy.deepcopy(body))
    return cfg


def load_config(path: Path | None, sets: tuple[str, ...] = (), schema_: dict[str, Spec] | None = None,
                layers: tuple[tuple[dict, str], ...] = ()) -> dict:
    """Defaults, then ``layers`` (``(body, where)`` pairs), then the YAML file (if any), then ``key=value``
    overrides; every value validated against ``schema_`` (default: the run schema)."""
    sch = schema() if schema_ is None else schema_
    ls = [validate(body, where, sch) for body, where in layers]
    if path is not None:
        ls.append(parse_file(path, sch))
    ls.append(parse_sets(tuple(sets), sch))
    return merge_layers(ls, sch)


def get(cfg: dict, key: str) -> Any:
    sect, name = key.split(".")
    return cfg[sect][name]


# ---- SI ------------------------------------------------------------------------------------------
D2R = np.pi / 180.0
_SI_UNITS = {"deg": ("rad", D2R), "dps": ("rps", D2R), "dps2": ("rps2", D2R)}


def si_name(name: str) -> tuple[str, float]:
    """The SI name of a key and the factor its value is multiplied by (``gyro_noise_dps_sqrthz`` ->
    ``gyro_noise_rps_sqrthz``, pi/180); names already in SI map to themselves with factor 1."""
    parts = name.split("_")
    factor = 1.0
    for i, p in enumerate(parts):
        if p in _SI_UNITS:
            parts[i], factor = _SI_UNITS[p]
    return "_".join(parts), factor


def _scaled(value, factor: float):
    if factor == 1.0 or value is None or isinstance(value, (str, bool)):
        return value
    if isinstance(value, list):
        return [v * factor for v in value]
    return value * factor


class _Section:
    __slots__ = ("_name", "_values")

    def __init__(self, name: str, values: dict):
        self._name, self._values = name, values

    def __getattr__(self, key: str):
        if key.startswith("_"):            # copy/pickle look for dunder hooks before __init__ ran
            raise AttributeError(key)
        try:
            return self._values[key]
        except KeyError:
            raise AttributeError(f"settings {self._name}.{key}: no such (SI) key; "
                                 f"known: {', '.join(self._values)}") from None

    def __repr__(self) -> str:
        return f"{self._name}({self._values})"


class Settings:
    """A resolved configuration in SI units (rad, m, s), converted once: ``s.imu.gyro_noise_rps_sqrthz``.

    Keys whose name carries a non-SI unit token (deg, dps, dps2) are renamed and scaled; the others keep
    their name and value. ``cfg`` holds the human-unit configuration it was built from.
    """

    def __init__(self, cfg: dict):
        self.cfg = copy.deepcopy(cfg)
        self._sections = {}
        for sect, body in self.cfg.items():
            vals = {}
            for k, v in body.items():
                name, f = si_name(k)
                vals[name] = _scaled(v, f)
            self._sections[sect] = _Section(sect, vals)

    def __getattr__(self, sect: str) -> _Section:
        if sect.startswith("_"):
            raise AttributeError(sect)
        try:
            return self._sections[sect]
        except KeyError:
            raise AttributeError(f"settings: no section {sect!r}") from None

    def __reduce__(self):
        return Settings, (self.cfg,)
