"""From a loaded dataset and a configuration to the streams the filter replays.

Applies, in this order and nowhere else: stream time offsets, dropping filled-in packets, the IMU
channel lags and the lidar clock offset (given or estimated, :mod:`fusion_eval.timing`), GNSS
degradation, anchoring the lidar odometry in the world frame, and resampling it on the IMU stamps.
Checks that the streams overlap in time and picks the initial state.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from . import timing
from .datasets import interpolated, plausible
from .calibration import imu_noise
from .config import Settings
from .calibration.extrinsic import apply_extrinsic, estimate_extrinsic, mount_disagrees
from .calibration.mount import HINT as MOUNT_HINT, across_travel
from .calibration.travel import MIN_STRETCHES, estimate_travel_pitch, pitch_from_smoothed_pass, uncertain
from .degrade import degrade_gnss, keep_receiver, not_degraded_note
from .errors import ConfigError, DataRangeError, ShiftAtSearchEdgeError
from .filters import check_combination, formulation_of, observations
from .filters.state import NominalState
from .geo import normal_gravity_mps2
from .interp import anchored_at, interpolate_pose_at, snap_to_stamps
from .so3 import inv_T, make_T, matrix_to_quat_xyzw
from .types import Dataset, GnssSeries, ImuSeries, PoseSeries, SpeedSeries, shifted

log = logging.getLogger(__name__)
GRAVITY_RANGE_MPS2 = (9.0, 10.5)


@dataclass(frozen=True)
class Prepared:
    """Everything the replay needs, on one clock and in the world frame."""

    imu: ImuSeries
    groundtruth: PoseSeries
    gnss: GnssSeries | None           # degraded, inside the run
    lidar: PoseSeries | None          # IMU poses in the world frame
    k_start: int                      # IMU index where the filter starts
    x0: NominalState
    gravity_mps2: float
    gnss_info: dict | None
    applied: dict = field(default_factory=dict)   # effective offsets, lag, anchor (for the report)
    odometer: SpeedSeries | None = None          # forward speed, inside the run
    streams: dict = field(default_factory=dict)  # the enabled observations' other streams, prepared, inside the run
    resolved: dict = field(default_factory=dict)  # configuration values estimated from the data ('auto'), by section
    # per lidar pose, the frame intervals its increment from the previous pose spans (frames merged onto one IMU stamp:
    # :func:`fusion_eval.interp.snap_to_stamps`); None: one each
    lidar_span: np.ndarray | None = None


def settings_for(cfg: dict, prep: Prepared) -> Settings:
    """The SI settings of the run: the configuration with what :func:`prepare` estimated in place of 'auto'."""
    c = {sect: dict(body) for sect, body in cfg.items()}
    for sect, body in prep.resolved.items():
        c[sect].update(body)
    imu = c["imu"]
    for key, scale in NOISE_SCALES:
        f = float(imu.get(scale, 1.0))
        if f != 1.0 and isinstance(imu.get(key), (int, float)):     # the filter's value; the report keeps the estimate
            imu[key] = imu[key] * f
    return Settings(c)


# each IMU white-noise density and the factor the filter applies to it (to a value given or estimated alike)
NOISE_SCALES = (("accel_noise_mps2_sqrthz", "accel_noise_scale"), ("gyro_noise_dps_sqrthz", "gyro_noise_scale"))


def _offset(cfg: dict, ds: Dataset, stream: str, auto: bool = False):
    """The stream's time offset: the configuration's (``<stream>.time_offset_s``), else the manifest's (default 0);
    'auto' passes through where ``auto`` (the lidar's, estimated by :mod:`fusion_eval.timing`)."""
    v = cfg.get(stream, {}).get("time_offset_s")
    v = ds.description.get("time_offset_s", {}).get(stream, 0.0) if v is None else v
    return v if (auto and v == "auto") else float(v)


def _odometer_scaled(odo: SpeedSeries, scale, gnss, imu, applied: dict) -> SpeedSeries:
    """The odometer with its scale factor divided out: given, or with 'auto' estimated from the fused GNSS
    (:mod:`fusion_eval.calibration.odometer_scale`; recorded in ``applied["odometer_scale"]``), else as it is."""
    if scale == "auto":
        from .calibration import odometer_scale

        est = odometer_scale.estimate(odo, gnss, imu) if gnss is not None and len(gnss) > 1 else None
        if est is None:
            applied["odometer_scale"] = {"scale": 1.0, "method": "not estimated (no GNSS fused, or under "
                                         f"{odometer_scale.MIN_WINDOWS} windows of "
                                         f"{odometer_scale.MIN_DISPLACEMENT_M:g} m driven): taken as 1"}
            return odo
        # applied where the data tell it from 1: KITTI's odometer (the GPS/INS speed, scale 1) gave 1.0017 +/- 0.0022,
        # and dividing that out cost 2.6 % of fused APE; a simulated 1.005 gave 1.0068 +/- 0.0007
        applied["odometer_scale"] = est
        if abs(est["scale"] - 1.0) <= odometer_scale.MIN_SIGMAS * est["std"]:
            applied["odometer_scale"] = {**est, "applied": False, "scale_estimated": est["scale"], "scale": 1.0}
            return odo
        scale = est["scale"]
    else:
        applied["odometer_scale"] = {"scale": float(scale), "method": "given (odometer.scale)"}
    return replace(odo, v_mps=odo.v_mps / float(scale)) if scale != 1.0 else odo


def anchor_lidar(lidar_odom: PoseSeries, gt: PoseSeries) -> tuple[PoseSeries, float]:
    """Express odometry poses in the world frame by anchoring the first frame inside the ground truth's span."""
    inside = np.flatnonzero((lidar_odom.t_s >= gt.t_s[0]) & (lidar_odom.t_s <= gt.t_s[-1]))
    if inside.size == 0:
        raise DataRangeError(f"lidar poses ({lidar_odom.source}) and ground truth do not overlap in time: "
                             f"lidar {lidar_odom.t_s[0]:.3f}..{lidar_odom.t_s[-1]:.3f} s, "
                             f"ground truth {gt.t_s[0]:.3f}..{gt.t_s[-1]:.3f} s"
                             + plausible.clock_hint("lidar", float(lidar_odom.t_s[0]), "ground-truth", float(gt.t_s[0])))
    a = int(inside[0])
    p_a, R_a, _ = interpolate_pose_at(gt, float(lidar_odom.t_s[a]))
    T_o = make_T(lidar_odom.R_wb(), lidar_odom.p_w_m)
    T_w_o = make_T(R_a, p_a) @ inv_T(T_o[a])
    T_w = T_w_o[None] @ T_o[a:]
    sel = np.zeros(len(lidar_odom), bool)
    sel[a:] = True
    base = lidar_odom.select(sel)
    return replace(base, p_w_m=T_w[:, :3, 3], q_wb_xyzw=matrix_to_quat_xyzw(T_w[:, :3, :3])), float(lidar_odom.t_s[a])


def start_from(cfg: dict, ds: Dataset) -> tuple[str, str]:
    """``filter.init_pose_from`` and ``init_velocity_from`` as this drive takes them: 'auto' is 'groundtruth' where
    the drive has one, else 'data' (:mod:`fusion_eval.calibration.initial_state`)."""
    own = "groundtruth" if ds.groundtruth is not None else "data"
    return tuple(own if cfg["filter"][k] == "auto" else cfg["filter"][k] for k in ("init_pose_from", "init_velocity_from"))


def _velocity_from_positions(poses, t0: float, half_window_s: float = 0.1) -> np.ndarray:
    """The velocity at ``t0`` of a pose series without one: the least-squares slope of its positions over
    ``t0 +/- half_window_s`` (a motion capture's millimetre noise over 0.1 s is centimetres per second), or of the two
    samples nearest ``t0`` where the window holds fewer than two."""
    t, p = np.asarray(poses.t_s), np.asarray(poses.p_w_m)
    k = np.flatnonzero(np.abs(t - t0) <= half_window_s)
    if k.size < 2:
        k = np.sort(np.argsort(np.abs(t - t0))[:2])
    dt = t[k] - t[k].mean()
    if not np.any(dt):
        raise ConfigError(f"filter.init_velocity_from=groundtruth: {poses.source} has no velocity and no two poses near "
                          "the start to difference; use gnss")
    return (dt @ (p[k] - p[k].mean(axis=0))) / (dt @ dt)


def _flag_data(ds: Dataset, applied: dict, more: list[str] = (), travel_yaw_rad: float = 0.0) -> None:
    """What the data hold that no plausibility bound refuses but that makes the figures suspect, said on stderr and
    in the report: the IMU stopping for seconds (in its stamps, or once its filled-in packets are dropped), a wheeled
    vehicle's streams jumping faster than it can drive, and what the preparation found (``more``: the GNSS a constant
    distance off the ground truth, a datum, among them)."""
    from .filters.observations.nhc import WHEELED

    platform = ds.description.get("platform")
    scale = plausible.pose_scale("lidar", ds.lidar, {"ground truth": ds.groundtruth, "GNSS": ds.gnss})
    short = plausible.imu_span_short(ds.imu, {"groundtruth": ds.groundtruth, "gnss": ds.gnss, "lidar": ds.lidar})
    warnings = (list(ds.description.get("misread_poses") or ()) + [w for w in (scale, short) if w]
                + plausible.imu_gaps(ds.imu)
                + plausible.clock_steps(ds.groundtruth) + list(more)
                + plausible.imu_units(ds.imu, platform, platform in WHEELED))
    if platform in WHEELED:
        warnings += plausible.speed_glitches({"groundtruth": ds.groundtruth, "gnss": ds.gnss, "lidar": ds.lidar},
                                                      platform)
        if str(applied.get("nhc", "")).startswith("on"):       # the constraint that sideways motion fights
            warnings += list(filter(None, [plausible.sideways(ds.groundtruth, platform, travel_yaw_rad)]))
    else:                 # any platform: a fix or a pose kilometres off is a glitch (a lidar odometry reset to its
        # origin mid-drive read 'fused over lidar 0.005' with no word where no platform was declared: a review)
        warnings += plausible.speed_glitches({"groundtruth": ds.groundtruth, "gnss": ds.gnss, "lidar": ds.lidar},
                                             platform, plausible.MAX_ANY_SPEED_MPS)
    for w in warnings:
        log.warning("%s", w)
    if warnings:
        applied["data_warnings"] = warnings


def _say_models(cfg: dict, ds: Dataset, applied: dict, across: str = "") -> None:
    """For the report: the non-holonomic constraint (on or off, and why) and the lidar increments' frame, where the
    configuration left them to the data ('auto'). ``across``: why the IMU's mount left the constraint out."""
    from .filters.observations.nhc import WHEELED
    from .filters.observations.relative_pose import frame_of

    f, platform = cfg["filter"], ds.description.get("platform")
    if across:
        applied["nhc"] = "off: the IMU is not mounted along the direction of travel (see the data warnings)"
    elif f["nhc"]:
        pitch = f.get("nhc_travel_pitch_mrad")
        rows = "lateral row only" if pitch is None else "lateral and vertical rows"
        why = f"the dataset's platform is a {platform}" if platform in WHEELED else "filter.nhc=true"
        applied["nhc"] = f"on ({why}), {rows}" if pitch != "auto" else f"on ({why})"
    elif platform in WHEELED:
        applied["nhc"] = ("off on this {platform} (filter.nhc=false, or a process model or smoother without it; "
                          "see README, 'The non-holonomic constraint')").format(platform=platform)
    else:       # said too: a drone's report spoke of the constraint as of a car's (a non-car review)
        applied["nhc"] = (f"off (the dataset's platform is {'a ' + platform if platform else 'not declared'}: the "
                          "constraint is a wheeled vehicle's)")
    if f["lidar_update"] == "relative" and cfg["lidar"]["relative_frame"] == "auto":
        frame = frame_of("auto", f["use_gnss"], cfg["smoother"]["method"])
        why = "GNSS fused" if f["use_gnss"] else ("the batch smoother" if frame == "body" else "no GNSS fused")
        applied["lidar_frame"] = {"frame": frame, "why": why}


def ground_truth(ds: Dataset) -> PoseSeries:
    """The dataset's ground truth as a run scores against it (``groundtruth.tum``): on the clock of its source (the
    manifest's offset applied), without filled-in packets (they are not truth)."""
    gt = shifted(ds.groundtruth, float(ds.description.get("time_offset_s", {}).get("groundtruth", 0.0)))
    return gt.select(~gt.filled)


def needed_streams(cfg: dict) -> dict[str, tuple[str, str]]:
    """The streams the configured filter needs, each with the key that asks for it and the setting that
    would do without it."""
    need: dict[str, tuple[str, str]] = {}
    for o in observations.enabled(cfg):
        off = ", ".join(f"{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in o.disable_with.items())
        for st in o.streams:
            need.setdefault(st, (o.enabled_by, off))
    for st in formulation_of(cfg).streams:
        need.setdefault(st, ("filter.process_model", "filter.process_model=imu"))
    return need


def offsets_note(applied: dict) -> str:
    """The time offsets a run applied, for a message about streams that do not meet."""
    offs = [f"{k}.time_offset_s = {v:g} s" for k, v in applied.get("time_offset_s", {}).items()
            if isinstance(v, (int, float)) and v]
    return f"(applied: {', '.join(offs)}; a wrong time offset?)" if offs else "(no time offset applied)"


def check_streams(ds: Dataset, cfg: dict) -> dict:
    """That ``ds`` has what ``cfg`` reads (ground truth, each enabled observation's stream), before any work (a
    comparison checks every variant's first); returns the streams needed."""
    check_combination(cfg)
    need = needed_streams(cfg)
    if ds.groundtruth is None:
        for key in ("init_pose_from", "init_velocity_from"):
            if cfg["filter"][key] == "groundtruth":
                raise ConfigError(f"filter.{key}=groundtruth, but dataset {ds.name!r} has no groundtruth stream: set "
                                  f"filter.{key}=auto (the start from the data: README 'A drive without ground truth')")
    for st, (key, off) in need.items():
        if ds.stream(st) is None:
            raise ConfigError(f"dataset {ds.name!r} has no {st} stream, which {key} needs; set {off}")
    return need


def prepare(ds: Dataset, cfg: dict) -> Prepared:
    need = check_streams(ds, cfg)
    use_lidar = "lidar" in need
    use_gnss = "gnss" in need

    for key in ("gyro_lag_s", "accel_lag_s"):
        lag = cfg["imu"].get(key)
        if isinstance(lag, (int, float)) and abs(lag) > plausible.MAX_LAG_S:
            raise ConfigError(f"imu.{key} = {lag:g} s: {plausible.LAG_NOTE}")
    applied: dict = {"time_offset_s": {}}
    # --- IMU: offset, drop filled packets, gyro lag
    imu = ds.imu
    off = _offset(cfg, ds, "imu")
    applied["time_offset_s"]["imu"] = off
    imu = shifted(imu, off)
    more_warnings: list[str] = []
    # a provider's interpolated samples that the format could not mark (a KITTI drive made into a bag)
    found, said = interpolated.interpolated_imu(imu)
    if said:
        keep = cfg["imu"]["filled_packets"] == "keep"
        more_warnings.append(said + ("" if not found.any() else " (imu.filled_packets: keep: used as measurements)" if keep
                                     else " (imu.filled_packets: drop)"))
    if found.any():
        imu = replace(imu, filled=imu.filled | found)
    n_filled = int(imu.filled.sum())
    if cfg["imu"]["filled_packets"] == "drop" and n_filled:
        more_warnings += plausible.dropped_gaps(imu, ~imu.filled, "the filled-in packets (imu.filled_packets: drop)")
        imu = imu.select(~imu.filled)
    applied["imu_filled_samples"] = n_filled
    applied["imu_filled_found"] = int(found.sum())
    applied["imu_filled_packets"] = cfg["imu"]["filled_packets"]
    if len(imu) < 2:
        raise DataRangeError(f"{ds.imu.source}: fewer than 2 usable IMU samples")
    # --- time alignment: the IMU channel lags and the lidar clock offset, given or estimated from the data
    imu_recorded = imu         # as recorded: the lag correction interpolates, which would smooth the noise estimate
    try:
        imu, lidar_off, timing_applied = timing.align(ds, cfg, imu, _offset(cfg, ds, "lidar", auto=True))
    except ShiftAtSearchEdgeError as exc:
        # a clock step in the truth's (and IMU's) stamps is the cause, where there is one: it was never located, the
        # message blamed the clocks or the axes (a corrupted-input review)
        steps = plausible.clock_steps(ds.groundtruth)
        if steps:
            raise ShiftAtSearchEdgeError(f"{exc}; the likely cause: {steps[0].removeprefix('groundtruth: ')}") from None
        misread = ds.description.get("misread_poses")        # orientations misread match no gyro at any shift
        if misread:
            raise ShiftAtSearchEdgeError(f"{exc}; the likely cause: the {misread[0]}") from None
        backwards = plausible.gyro_turns_backwards(ds.imu, ds.groundtruth)
        if backwards:                                           # nor does a gyro of a flipped axis
            raise ShiftAtSearchEdgeError(f"{exc}; the likely cause: {backwards}") from None
        raise
    more_warnings += timing_applied.pop("time_warnings", [])
    applied.update(timing_applied)

    gt = ground_truth(ds) if ds.groundtruth is not None else None
    pose_from, vel_from = start_from(cfg, ds)
    placeholder = plausible.truth_orientation_placeholder(gt) if gt is not None else ""
    if placeholder:
        applied["truth_orientation_placeholder"] = True     # no attitude figure against it means anything
    if gt is not None:
        more_warnings += filter(None, [placeholder, plausible.gyro_scale(imu, gt),
                                       plausible.gyro_turns_backwards(imu, gt)])
    if gt is not None and (len(gt) < 2 or gt.t_s[-1] <= imu.t_s[0] or gt.t_s[0] >= imu.t_s[-1]):
        raise DataRangeError(f"IMU ({ds.imu.source}, {imu.t_s[0]:.3f}..{imu.t_s[-1]:.3f} s after imu.time_offset_s = "
                             f"{applied['time_offset_s']['imu']:g} s) and ground truth ({gt.source}, "
                             f"{gt.t_s[0] if len(gt) else float('nan'):.3f}..{gt.t_s[-1] if len(gt) else float('nan'):.3f} s) "
                             "do not overlap in time"
                             + (plausible.clock_hint("IMU", float(imu.t_s[0]), "ground-truth", float(gt.t_s[0])) if len(gt) else ""))

    # --- lidar: offset, anchor in the world frame, resample on the IMU stamps
    lidar = travel = lidar_span = None
    anchor = ds.description.get("lidar_anchor", "groundtruth")
    if ds.lidar is not None:
        applied["time_offset_s"]["lidar"] = lidar_off
        lid = shifted(ds.lidar, lidar_off)
        rot_auto, arm_auto = (cfg["lidar"][k] == "auto" for k in ("extrinsic_rotation", "extrinsic_translation"))
        if rot_auto or arm_auto:
            # the mount against the calibration file, from the time-aligned signals (hand-eye)
            est = estimate_extrinsic(imu, lid.select(~lid.filled))
            lid = apply_extrinsic(lid, est.R_E if rot_auto else np.eye(3), est.t_E_m if arm_auto else None)
            applied["lidar_extrinsic"] = {**est.as_dict(), "applied": [k for k, on in (("rotation", rot_auto),
                                                                                      ("lever_arm", arm_auto)) if on]}
            log.info("lidar mount correction estimated: roll, pitch, yaw %s mrad; lever arm x, y %s cm",
                     np.round(est.rpy_mrad, 2), np.round(est.t_E_m[:2] * 100, 1))
        else:
            # a calibration taken as it is, checked against the data: a flipped or inverted one gave no other sign
            more_warnings += filter(None, [mount_disagrees(imu, lid.select(~lid.filled),
                                                           f"the extrinsic its manifest entry gives for {ds.lidar.source}")])
        other_frame = ""
        if anchor == "groundtruth":
            if gt is None:
                raise ConfigError(f"{ds.lidar.source}: the manifest anchors the lidar odometry on the ground truth "
                                  "(anchor: groundtruth), but the dataset has no groundtruth stream; use anchor: start")
            lid, t_anchor = anchor_lidar(lid, gt)
            applied["lidar_anchor_t_s"] = t_anchor
        elif anchor == "none" and gt is not None:
            other_frame = plausible.unanchored_lidar(lid, gt)
        # (positions in another frame fit the truth at no time shift: the frame is the warning then)
        if gt is not None:
            more_warnings += filter(None, [other_frame or plausible.clock_shift("the lidar", lid, gt, "lidar.time_offset_s", lidar_off)
                                           or plausible.speed_clock_warning("the lidar", lid, gt, "lidar.time_offset_s", lidar_off)])
        for k in ("lidar_clock", "lidar_times_aligned"):
            if ds.description.get(k):
                applied[k] = ds.description[k]
        if cfg["filter"].get("nhc") and cfg["filter"].get("nhc_travel_pitch_mrad") == "auto":
            travel = estimate_travel_pitch(lid.select(~lid.filled), cfg["filter"]["nhc_travel_yaw_mrad"] * 1e-3)
        if cfg["lidar"]["interpolate_to_imu"]:
            n_frames = len(lid)
            lid, lidar_span = snap_to_stamps(lid, imu.t_s)
            if int(np.sum(lidar_span > 1)):
                applied["lidar_frames_merged"] = {"frames": n_frames, "poses": len(lid),
                                                  "increments_over_several_frames": int(np.sum(lidar_span > 1))}
        lidar = lid
        if use_lidar and (len(lidar) < 2 or lidar.t_s[-1] <= imu.t_s[0] or lidar.t_s[0] >= imu.t_s[-1]):
            raise DataRangeError(f"lidar ({ds.lidar.source}) and IMU ({ds.imu.source}) do not overlap in time {offsets_note(applied)}"
                                 + (plausible.clock_hint("lidar", float(lidar.t_s[0]), "IMU", float(imu.t_s[0]))
                                    if len(lidar) else ""))

    # --- start: first IMU sample covered by the ground truth (and the lidar, when it is fused; and the GNSS, when the
    #     start is found from the data)
    t_min, t_max = (gt.t_s[0], gt.t_s[-1]) if gt is not None else (imu.t_s[0], imu.t_s[-1])
    if use_lidar or pose_from == "lidar":
        if lidar is None:
            raise ConfigError("filter.init_pose_from=lidar needs a lidar stream")
        if pose_from == "lidar" and anchor == "start":
            raise ConfigError("filter.init_pose_from=lidar takes the anchored lidar pose, but the manifest anchors the "
                              "lidar on the filter's start (anchor: start): set filter.init_pose_from=auto or data")
        t_min = max(t_min, lidar.t_s[0])
    fixes_t_s = None if ds.gnss is None else ds.gnss.t_s[~ds.gnss.filled] + _offset(cfg, ds, "gnss")
    applied["start_covered_by"] = "ground truth" if gt is not None else "the IMU"
    if pose_from == "data" and fixes_t_s is not None and fixes_t_s.size:
        t_min = max(t_min, float(fixes_t_s[0]))
        if gt is None:
            applied["start_covered_by"] = "the GNSS"
    ks = np.flatnonzero((imu.t_s >= t_min - 1e-9) & (imu.t_s <= t_max))
    if ks.size < 2:
        raise DataRangeError(f"fewer than 2 IMU samples ({ds.imu.source}) lie where "
                             f"{'ground truth (' + gt.source + ')' if gt is not None else 'the GNSS'} and lidar are "
                             f"available {offsets_note(applied)}")
    k0 = int(ks[0])
    t0 = float(imu.t_s[k0])

    # --- GNSS: offset, drop filled, degrade
    gnss = gnss_info = None
    if ds.gnss is not None:
        off = _offset(cfg, ds, "gnss")
        applied["time_offset_s"]["gnss"] = off
        g = shifted(ds.gnss, off)
        g = g.select(~g.filled)
        arm = cfg["gnss"].get("lever_arm_b_m")
        if gt is not None:
            shift = plausible.clock_shift("GNSS", g, gt, "gnss.time_offset_s", off)     # as configured
            # a clock offset moves the fixes along the route, which a median offset reads as a constant displacement:
            # that advice (a geodetic origin, a lever arm) went first, and wrong, for GNSS 18 s ahead (a bag review)
            said = list(filter(None, [None if shift else plausible.gnss_offset(g, gt, bool(ds.description.get("origin_from_first_fix")), arm),
                                      plausible.gnss_frame(g, gt), shift or plausible.gnss_latency(g, gt, off, arm)]))
            more_warnings += said or list(filter(None, [plausible.gnss_disagrees(g, gt)]))
        if len(g) and (g.t_s[-1] < t0 or g.t_s[0] > imu.t_s[-1]):
            raise DataRangeError(f"GNSS ({ds.gnss.source}, {g.t_s[0]:.3f}..{g.t_s[-1]:.3f} s after its time_offset_s of "
                                 f"{off:g} s) and IMU ({ds.imu.source}, {t0:.3f}..{imu.t_s[-1]:.3f} s) do not overlap in time"
                                 + plausible.clock_hint("GNSS", float(g.t_s[0]), "IMU", t0))
        g = g.select((g.t_s >= t0) & (g.t_s <= imu.t_s[-1]))
        if len(g):      # the stream's extent before the outages and rate set: what the scores' common span takes
            applied["gnss_coverage_s"] = [float(g.t_s[0]), float(g.t_s[-1])]
        c = cfg["gnss"]
        span_s = float(imu.t_s[-1] - t0)
        for a, b in c["outages_s"]:
            if b <= 0.0 or a >= span_s:      # (a window in ms did nothing, and only '0 fixes removed' hinted at it)
                log.warning("gnss.outages_s window [%g, %g] s lies outside the run's 0..%.1f s (seconds from the filter's "
                            "start): it removes no fix", a, b, span_s)
        if ds.description.get("gnss_degrade", True):
            gnss, gnss_info = degrade_gnss(g, t0, c["rate_hz"], c["noise_std_m"], c["outages_s"], c["seed"], c["std_m"])
            # the report's reason for it: KITTI's OXTS solution, or a stream the manifest marks (a KITTI bag's fixes)
            gnss_info["format"] = ((ds.description.get("streams") or {}).get("gnss") or {}).get("format")
        else:
            # a receiver's fixes get no noise and keep their rate, but outages are the user's experiment: they apply
            # (once silently ignored here); the degradation's own keys do nothing, and are said
            gnss, gnss_info = keep_receiver(g, t0, c["outages_s"], c["std_m"], "m", "std_w_m")
            more_warnings += filter(None, [not_degraded_note(
                "gnss", c, ("rate_hz", "noise_std_m"), "a GNSS", "the manifest's gnss degrade: true; KITTI's OXTS "
                "solution is", ds.gnss.source, "is a receiver's output, used at its own rate and noise (gnss.outages_s "
                "and gnss.std_m do apply)")])
        # the fixes as fused: the truth's own solution, as it is or in another frame (a kitti2bag trial)
        more_warnings += filter(None, [plausible.gnss_from_truth(gnss, gt) if gt is not None else None])
        if use_gnss and len(gnss) == 0:
            raise DataRangeError(f"no GNSS fix of {ds.gnss.source} is left inside the IMU span after degradation")

    # --- odometer: offset, optional degradation (KITTI's vf is the GPS/INS solution)
    odo = None
    needs_odo = "odometer" in need
    if ds.odometer is not None:
        off = _offset(cfg, ds, "odometer")
        applied["time_offset_s"]["odometer"] = off
        odo = shifted(ds.odometer, off)
        more_warnings += filter(None, [plausible.odometer_scale(odo, gt) if gt is not None else None])
        if ds.description.get("odometer_degrade", False) and cfg["odometer"]["added_noise_std_mps"] > 0:
            # its own stream of gnss.seed (seed + 1 would be the next Monte-Carlo trial's GNSS noise)
            rng = np.random.default_rng([cfg["gnss"]["seed"], 2])
            odo = replace(odo, v_mps=odo.v_mps + rng.standard_normal(len(odo)) * cfg["odometer"]["added_noise_std_mps"])
            applied["odometer_added_noise_std_mps"] = cfg["odometer"]["added_noise_std_mps"]
        elif needs_odo and not ds.description.get("odometer_degrade", False):      # (did nothing with no word: an audit)
            more_warnings += filter(None, [not_degraded_note("odometer", cfg["odometer"], ("added_noise_std_mps",),
                                                             "an odometer", "KITTI's OXTS speed is", ds.odometer.source,
                                                             "is used as it is")])
        if needs_odo:                    # (a stream the filter does not fuse is left as it is, and unreported)
            odo = _odometer_scaled(odo, cfg["odometer"]["scale"], gnss if use_gnss else None, imu, applied)
        if needs_odo and (odo.t_s[-1] <= imu.t_s[k0] or odo.t_s[0] >= imu.t_s[-1]):
            raise DataRangeError(f"odometer ({ds.odometer.source}) and IMU ({ds.imu.source}) do not overlap in time "
                                 f"{offsets_note(applied)}"
                                 + plausible.clock_hint("odometer", float(odo.t_s[0]), "IMU", float(imu.t_s[k0])))

    # --- IMU white noise: given, or from the stream's own second differences (no ground truth), estimated
    #     once the streams are known to overlap
    resolved: dict = {}
    noise_keys = (("accel_noise_mps2_sqrthz", "accel_mps2_sqrthz", 1.0),
                  ("gyro_noise_dps_sqrthz", "gyro_rps_sqrthz", 180 / np.pi))
    if any(cfg["imu"][k] == "auto" for k, _, _ in noise_keys):
        est = imu_noise.estimate(imu_recorded)
        resolved["imu"] = {k: est[e] * f for k, e, f in noise_keys if cfg["imu"][k] == "auto"}
    if resolved:
        applied["imu_noise"] = dict(resolved["imu"])
    if cfg["filter"].get("discretization") == "auto":          # formulations that discretise a continuous model
        from .filters.discretize import resolve_auto

        only = formulation_of(cfg).discretizations
        # a process model with one discretisation takes it (the odometer + gyro model was reported as van_loan)
        resolved.setdefault("filter", {})["discretization"] = only[0] if len(only) == 1 else resolve_auto("auto", imu.t_s)
        applied["discretization"] = resolved["filter"]["discretization"]
        applied["discretization_from"] = "the IMU rate" if len(only) > 1 else "the process model's only one"
    g = cfg["filter"]["gravity_mps2"]
    if g == "auto":
        g = normal_gravity_mps2(ds.geodetic_origin[0], ds.geodetic_origin[2]) if ds.geodetic_origin else 9.80665
    elif not GRAVITY_RANGE_MPS2[0] <= g <= GRAVITY_RANGE_MPS2[1]:
        # the Earth's gravity is 9.76-9.84 m/s^2 at sea level and less only kilometres up; 98 (a typo for 9.8) once
        # ran to a fused APE of 395 m with exit 0
        raise ConfigError(f"filter.gravity_mps2={g:g} is no gravity on Earth's surface (accepted: {GRAVITY_RANGE_MPS2[0]:g} "
                          f"to {GRAVITY_RANGE_MPS2[1]:g} m/s^2; 'auto' takes WGS84's at the geodetic origin)")
    applied["gravity_mps2"] = float(g)
    # --- initial state
    est = None
    if "data" in (pose_from, vel_from):
        from .calibration.initial_state import from_data
        from .filters.observations.nhc import WHEELED

        yaw_mount = cfg["filter"].get("nhc_travel_yaw_mrad")
        est = from_data(imu, k0, gnss, lidar, odo, ds.description.get("platform") in WHEELED,
                        float(yaw_mount) * 1e-3 if isinstance(yaw_mount, (int, float)) else 0.0, float(g),
                        cfg["gnss"].get("lever_arm_b_m") or (0.0, 0.0, 0.0))
        applied["init_state"] = {"pose_from": pose_from, "velocity_from": vel_from, "method": est.method,
                                 "std": est.std, "frame": est.frame}
        # the configured initial stds suit a start on a reference trajectory's pose: the data's own are larger (of
        # the parts taken from the data: a velocity alone on a drive with truth keeps its pose's)
        used = est.std if pose_from == "data" else {"vel_std_mps": est.std["vel_std_mps"]} if vel_from == "data" else {}
        resolved["init"] = {k: v for k, v in used.items() if v > float(cfg["init"][k])}
    if pose_from == "data":
        p0, R0 = est.p_w_m, est.R_wb
    elif pose_from == "lidar":
        p0, R0, _ = interpolate_pose_at(lidar, t0)
    else:
        p0, R0, _ = interpolate_pose_at(gt, t0)
    if vel_from == "data":
        v0 = est.v_w_mps
    elif vel_from == "gnss":
        if gnss is None or len(gnss) < 2:
            raise ConfigError("filter.init_velocity_from=gnss needs at least two GNSS fixes")
        v0 = (gnss.p_w_m[1] - gnss.p_w_m[0]) / (gnss.t_s[1] - gnss.t_s[0])
    else:
        _, _, v0 = interpolate_pose_at(gt, t0)
        mismatch = plausible.velocity_mismatch(gt) if v0 is not None else ""
        if mismatch:            # its velocities are not its positions' rate of change: a twist in the wrong frame
            more_warnings.append(mismatch)
            v0 = _velocity_from_positions(gt, t0)
            applied["init_velocity"] = "the ground truth's positions differenced (its velocities disagree with them)"
        if v0 is None:          # a ground truth of poses only (TUM, EuRoC's motion capture): its positions differenced
            v0 = _velocity_from_positions(gt, t0)
            applied["init_velocity"] = "the ground truth's positions differenced (it has no velocity)"
    x0 = NominalState(p_w_m=np.array(p0), v_w_mps=np.array(v0), R_wb=np.array(R0), ba_b=np.zeros(3),
                      bg_b=est.bg_b_rps if pose_from == "data" else np.zeros(3))
    if lidar is not None and anchor == "start":
        if lidar.t_s[0] > t0 + 1e-9 or lidar.t_s[-1] < t0:
            # not fused (a fused lidar covers the start), and nothing to lay it on where it does not: left out
            more_warnings.append(f"the lidar poses ({ds.lidar.source}, {lidar.t_s[0]:.3f}..{lidar.t_s[-1]:.3f} s) do not "
                                 f"cover the filter's start (t = {t0:.3f} s), on whose pose a drive without ground truth "
                                 "anchors them: the unfiltered lidar estimate is left out")
            lidar = None
        else:
            # the odometry's frame laid on the filter's initial pose at its start
            lidar = anchored_at(lidar, make_T(np.asarray(R0), np.asarray(p0)), t0)
            applied["lidar_anchor_start_t_s"] = t0
    if lidar is not None:
        applied["lidar_anchor"] = anchor
    more_warnings += filter(None, [plausible.gravity_against_attitude(imu, k0, R0)])

    # --- the enabled observations' own streams: offset, filled packets, the run's span, degradation
    extra: dict = {}
    for o in observations.enabled(cfg):
        for spec in o.extra_streams:
            raw = ds.extra[spec.name]
            off = _offset(cfg, ds, spec.name)
            applied["time_offset_s"][spec.name] = off
            st = shifted(raw, off)
            st = st.select(~st.filled)
            st = st.select((st.t_s >= t0) & (st.t_s <= imu.t_s[-1]))
            if spec.prepare is not None:
                st, applied[spec.name] = spec.prepare(st, cfg, t0, ds.description.get("degrade", {}).get(spec.name, False))
                more_warnings += applied[spec.name].pop("warnings", [])     # a stream's own, for the report
            if len(st) == 0:
                raise DataRangeError(f"no {spec.what} of {raw.source} is left inside the IMU span "
                                     f"({imu.t_s[0]:.3f}..{imu.t_s[-1]:.3f} s) after the time offset and degradation")
            extra[spec.name] = st

    if ds.geodetic_origin is not None:
        # the local frame's origin, in the report and metrics.json: a first fix without altitude moved it to the next
        # fix (0.83 m; fused 0.76 -> 1.06 m) with no record of where it was (a bag review)
        lat, lon, alt = (float(v) for v in ds.geodetic_origin)
        applied["geodetic_origin"] = {"lat_deg": lat, "lon_deg": lon, "alt_m": alt,
                                      "from": ds.description.get("geodetic_origin_from", "the manifest")}
    applied["t_start_s"] = t0
    f = cfg["filter"]
    odo_model = f.get("process_model") == "odometer_gyro"       # it drives along the direction of travel too
    along = f["nhc"] or f.get("odometer_update") or odo_model
    across = across_travel(imu.select(imu.t_s >= t0), f["nhc_travel_yaw_mrad"]) if along else ""
    if across:
        if f["nhc"]:      # it would hold the forward velocity at zero: left out
            resolved.setdefault("filter", {})["nhc"] = False
            across += "; the non-holonomic constraint is left out"
        if f.get("odometer_update"):      # fused as configured (a process model may rest on it), but said
            across += "; the odometer's speed is fused along that direction as configured"
        if odo_model:
            across += "; the odometer + gyro process model drives along that direction as configured"
        more_warnings.append(f"{across}: {MOUNT_HINT}")
    _say_models(cfg, ds, applied, across)
    yaw = cfg["filter"].get("nhc_travel_yaw_mrad")
    _flag_data(ds, applied, more_warnings, float(yaw) * 1e-3 if isinstance(yaw, (int, float)) else 0.0)
    prep = Prepared(imu=imu, groundtruth=gt, gnss=gnss, lidar=lidar, k_start=k0, x0=x0, gravity_mps2=float(g),
                    gnss_info=gnss_info, applied=applied, odometer=odo, streams=extra, resolved=resolved,
                    lidar_span=lidar_span)
    if cfg["filter"].get("nhc") and not across and cfg["filter"].get("nhc_travel_pitch_mrad") == "auto":
        # the IMU's pitch against the direction of travel: from the lidar, else from a smoothed IMU + GNSS pass;
        # without an estimate the constraint's vertical row is left out
        why = "no lidar stream" if ds.lidar is None else f"under {MIN_STRETCHES} s of straight driving in the lidar"
        if travel is not None and uncertain(travel):
            travel, why = None, f"{uncertain(travel)} from the lidar"
        if travel is None:
            travel, why_not = pitch_from_smoothed_pass(prep, cfg) if use_gnss else (None, "no GNSS fused")
            why = f"{why}; {why_not}"
        resolved.setdefault("filter", {})["nhc_travel_pitch_mrad"] = None if travel is None else travel.pitch_mrad
        applied["nhc_travel"] = travel.as_dict() if travel is not None else {"pitch_mrad": None, "method": why}
    return prep


def auto_settled(cfg: dict, resolved: dict, applied: dict) -> dict:
    """``{section.key: value}`` for each configuration key left to the data ('auto') that the preparation settled
    to one value for the whole run: the report's configuration block shows it beside the 'auto'. Of one run's
    ``cfg``: runs that share a preparation (a sweep's batch) differ in the noise scales applied here."""
    got = {f"{sect}.{k}": v for sect, body in resolved.items() for k, v in body.items() if cfg[sect].get(k) == "auto"}
    for key, scale in NOISE_SCALES:
        if f"imu.{key}" in got:                      # what the filter runs with (settings_for): the estimate x scale
            got[f"imu.{key}"] *= float(cfg["imu"].get(scale, 1.0))
    if cfg["filter"]["gravity_mps2"] == "auto":
        got["filter.gravity_mps2"] = applied["gravity_mps2"]
    if "lidar_frame" in applied:
        got["lidar.relative_frame"] = applied["lidar_frame"]["frame"]
    if cfg["lidar"].get("noise_adapt") == "auto" and cfg["filter"].get("lidar_update") == "relative":
        from .filters.observations.relative_pose import resolved_adapt_mode

        got["lidar.noise_adapt"] = resolved_adapt_mode("auto", bool(cfg["filter"]["use_gnss"]))
    return got
