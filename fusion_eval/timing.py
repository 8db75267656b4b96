"""The time alignment of the streams before the replay: the lidar clock offset and the IMU channel lags, each
given or estimated from the data ('auto', see :mod:`fusion_eval.calibration.time_offset`).

When the drive has no lidar to estimate from, 'auto' falls back on what is known of the device: for KITTI's
OXTS unit, the lags this estimator measured on the five KITTI IMU + lidar drives in ``../shared/data``
(KISS-ICP and SiMpLE odometry of seqs 00, 05, 06, 07; README "Time offsets"), none of it from ground truth.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from .calibration import measure_shifts, resolve
from .calibration.time_offset import MAX_SHIFT_S, turning_rps
from .datasets.plausible import LAG_NOTE, MAX_LAG_S, clock_hint
from .errors import ConfigError, DataRangeError, FusionEvalError, ShiftAtSearchEdgeError
from .types import Dataset, ImuSeries, shifted

log = logging.getLogger(__name__)

MIN_OVERLAP_S = 20.0    # below this, too few turns to find a shift of a few ms

# KITTI OXTS RT3003: the accelerometer and gyro shifts against the lidar (= the packet clock of the ground truth
# and GNSS) on the five drives (kitti-00 KISS-ICP; SiMpLE 00, 05, 06, 07), combined by inverse-variance weights:
# accel 65.8, 63.9, 66.3, 58.3, 62.0 ms (+/- 2.2, 2.4, 2.8, 4.7, 6.0) -> 64.6; gyro 58.8, 60.0, 59.9, 58.9,
# 59.3 ms (+/- 0.4, 0.4, 0.5, 1.2, 1.0) -> 59.5 (kitti-00 and SiMpLE 00 share one drive's IMU).
MAX_LEAD_S = 0.02        # an estimated lag below -20 ms (beyond 3 sigma) is no latency: flagged
# a jackknife std of an estimated lag or offset beyond this: the drive's blocks disagree (the real drives: 0.4-2.1 ms)
MAX_TIME_STD_S = 0.01
DEVICE_LAGS_S = {"kitti_oxts": {"accel_lag_s": 0.0646, "gyro_lag_s": 0.0595}}


def advance(imu: ImuSeries, accel_s: float, gyro_s: float) -> ImuSeries:
    """Each channel advanced by its lag: the value used at t is the one recorded at ``t + lag`` (ends held)."""
    def shifted(x, lag):
        if lag == 0.0:
            return x
        return np.column_stack([np.interp(imu.t_s + lag, imu.t_s, x[:, i]) for i in range(3)])

    return replace(imu, f_b_mps2=shifted(imu.f_b_mps2, accel_s), w_b_rps=shifted(imu.w_b_rps, gyro_s))


def _given(cfg: dict, section: str, key: str, manifest_value):
    """The configured value, else the manifest's."""
    v = cfg[section].get(key)
    return manifest_value if v is None else v


def align(ds: Dataset, cfg: dict, imu: ImuSeries, lidar_offset_given) -> tuple[ImuSeries, float, dict]:
    """The IMU with its channel lags applied, the lidar offset to add to its stamps, and what was applied
    (for the report). ``imu``: offset and filled-in packets already handled; ``lidar_offset_given``: the
    configured or manifest lidar offset (a number or 'auto')."""
    accel = _given(cfg, "imu", "accel_lag_s", ds.description.get("accel_lag_s", 0.0))
    gyro = _given(cfg, "imu", "gyro_lag_s", ds.description.get("gyro_lag_s", 0.0))
    off = lidar_offset_given if ds.lidar is not None else 0.0
    applied: dict = {"time_estimates": {}}
    if "auto" in (accel, gyro, off):
        if off == "auto" and accel == "auto":
            raise ConfigError("lidar.time_offset_s=auto and imu.accel_lag_s=auto together are ambiguous: the data fix "
                              "only their sum; give one of them (KITTI: the lidar is on the packet clock, lidar.time_offset_s=0)")
        overlap = 0.0 if ds.lidar is None or len(ds.lidar) < 2 else (
            min(imu.t_s[-1], ds.lidar.t_s[-1]) - max(imu.t_s[0], ds.lidar.t_s[0]))
        if overlap >= MIN_OVERLAP_S:
            # the readers give IMU poses on the lidar stamps (extrinsic applied); filled-in frames left out
            sh = measure_shifts(imu, ds.lidar.select(~ds.lidar.filled), accel="auto" in (accel, off), rate=gyro == "auto")
            est, off_given = resolve(sh, off, accel, gyro), off
            applied["time_estimates"] = {k: v.as_dict() for k, v in est.items()}
            off = est["lidar_offset"].value_s if off == "auto" else off
            accel = est["accel_lag"].value_s if accel == "auto" else accel
            gyro = est["gyro_lag"].value_s if gyro == "auto" else gyro
            ahead = set()                 # the channels said to report before their stamps (said once, here)
            for k in ("accel_lag", "gyro_lag"):
                # the data fix lidar offset + lag; a lag beyond a second means the given lidar offset is off (as a
                # lag set by hand beyond it is refused)
                if k in est and not abs(est[k].value_s) <= MAX_LAG_S:
                    raise DataRangeError(f"imu.{k}_s=auto comes out at {est[k].value_s:+.3f} s from the data, given the lidar's "
                                         f"time offset of {off:g} s (lidar.time_offset_s or the manifest's); {LAG_NOTE}: "
                                         "that offset is probably wrong")
                if k in est and est[k].value_s < -MAX_LEAD_S and est[k].value_s + 3 * (est[k].std_s or 0.0) < 0:
                    # a channel cannot report a rate before it happens: the estimate took up an error of the lidar
                    # offset given (0.3 s once became a gyro lag of -241 ms and a fused APE of 2.0 m with no word)
                    ahead.add(k)
                    applied.setdefault("time_warnings", []).append(
                        f"imu.{k}_s=auto comes out at {est[k].value_s * 1e3:+.0f} +/- {(est[k].std_s or 0.0) * 1e3:.0f} ms: the IMU "
                        f"would report its {'rates' if k == 'gyro_lag' else 'accelerations'} before they happen; the "
                        f"lidar's time offset of {off:g} s (lidar.time_offset_s or the manifest's) is the likely error "
                        "(try lidar.time_offset_s=auto with the lag given)")
            device = _off_the_device(ds, est, off_given)
            if device and "gyro_lag" not in ahead:                    # (a lag ahead of its stamp is said above)
                applied.setdefault("time_warnings", []).append(device)
            for k, v in est.items():
                log.info("%s estimated from the data: %.1f +/- %.1f ms", k.replace("_", " "), v.value_s * 1e3, v.std_s * 1e3)
                if v.std_s is not None and v.std_s > MAX_TIME_STD_S:
                    # one lidar frame missing or repeated where its stamps are the IMU's by index shifts every later
                    # frame: the lag came out at 121.6 +/- 18.2 ms (59.9 +/- 0.5 recorded) and 0.44 -> 0.67 m, no word
                    applied.setdefault("time_warnings", []).append(
                        f"{k.replace('_', ' ')} estimated from the data: {v.value_s * 1e3:+.1f} +/- {v.std_s * 1e3:.1f} ms, "
                        f"a spread over {MAX_TIME_STD_S * 1e3:.0f} ms: parts of the drive disagree on it, as when the "
                        "lidar's stamps shift partway (a frame missing or repeated where they are the IMU's by index, "
                        "times: align_to: imu); check the lidar's frames against its stamps")
        else:
            fmt = ds.description.get("streams", {}).get("imu", {}).get("format")
            known = DEVICE_LAGS_S.get(fmt)
            if known is None:
                # streams on two clocks overlap by nothing: that, not the missing figure, is what to fix (a bag's IMU
                # on its boot clock was told to give its lags in seconds, and then, given them, of the clocks; a review)
                hint = "" if ds.lidar is None or not len(ds.lidar) else clock_hint(
                    "IMU", float(imu.t_s[0]), "lidar", float(ds.lidar.t_s[0]))
                if hint:
                    raise DataRangeError(f"the IMU and the lidar overlap by {max(overlap, 0.0):.1f} s{hint}")
                raise ConfigError(f"imu.accel_lag_s / imu.gyro_lag_s / lidar.time_offset_s = auto need {MIN_OVERLAP_S:g} s of "
                                  f"lidar overlapping the IMU to estimate them from (here {max(overlap, 0.0):.1f} s, and no "
                                  f"known figure for IMU format {fmt!r}); give them in seconds")
            for name, val in (("accel_lag_s", accel), ("gyro_lag_s", gyro)):
                if val == "auto":
                    applied["time_estimates"][name[:-2]] = {"value_s": known[name], "std_s": None, "samples": 0,
                                                            "method": f"the {fmt} device figure (no {MIN_OVERLAP_S:g} s of lidar to estimate from)"}
            accel = known["accel_lag_s"] if accel == "auto" else accel
            gyro = known["gyro_lag_s"] if gyro == "auto" else gyro
            off = 0.0 if off == "auto" else off
    elif ds.lidar is not None and cfg["filter"].get("lidar_update", "none") != "none":
        warned = clock_check(imu, ds.lidar.select(~ds.lidar.filled), float(off), float(gyro))
        if warned:
            applied.setdefault("time_warnings", []).append(warned)
    accel, gyro, off = float(accel), float(gyro), float(off)
    applied.update(accel_lag_s=accel, gyro_lag_s=gyro)
    return advance(imu, accel, gyro), off, applied


# an IMU channel's estimated lag this far (and 3 sigma) from its device's known figure says the lidar offset given is off
DEVICE_MISS_S = 0.010


def _off_the_device(ds, est: dict, off) -> str:
    """Where a lag estimated against a lidar whose offset was given lands far from the IMU device's known lag: the data
    fix only lidar offset + lag, so a lidar stamped 59 ms off (KITTI odometry times given from packet 0, without the
    odometry's own shift) became a gyro lag of -0.1 ms and a fused 1.48 m against 0.75, with only NEES warnings (a
    review against the shared data's README). '' otherwise."""
    fmt = ds.description.get("streams", {}).get("imu", {}).get("format")
    known = DEVICE_LAGS_S.get(fmt)
    if known is None or off == "auto" or "gyro_lag" not in est:
        return ""
    e = est["gyro_lag"]
    miss = e.value_s - known["gyro_lag_s"]
    if not abs(miss) > DEVICE_MISS_S + 3 * (e.std_s or 0.0):
        return ""
    return (f"imu.gyro_lag_s=auto is estimated at {e.value_s * 1e3:+.1f} +/- {(e.std_s or 0.0) * 1e3:.1f} ms, "
            f"{miss * 1e3:+.0f} ms from the {fmt} device's {known['gyro_lag_s'] * 1e3:.1f} ms (the same to +/-0.6 ms on "
            f"five KITTI drives): the data fix the lidar's offset plus the lag, so the lidar's stamps are likely off "
            f"the IMU's clock with the offset given ({float(off):g} s; its times file, first stamp or frame offset?), and "
            f"lidar.time_offset_s={round(float(off) + miss, 3) + 0.0:.3f} with the device's lag would put them on it "
            "(lidar.time_offset_s=auto with imu.gyro_lag_s given estimates it)")


# Every offset given by hand: the gyro's rotation rate against the lidar's still says whether the two clocks meet.
# Over the first CHECK_SPAN_S of the drive (0.1 s on kitti-00's 470 s; an hour would cost a second), flagged beyond
# CHECK_MIN_S and 3 sigma: lidar stamps 250 ms late gave a fused APE of 1.06 m against 0.70 with no word, where
# lidar.time_offset_s=auto finds -232 +/- 16 ms and 0.69 m (a user's review). Only where the platform turns: a still or
# straight start correlates noise with noise (a review found 8 of 12 still drives 'off' by up to 250 ms); the turning is
# the spread of the gyro's rate about its median, over half a second, at its 90th percentile (kitti-00: 0.33 rad/s).
CHECK_SPAN_S, CHECK_MIN_S, CHECK_MIN_TURN_RPS = 300.0, 0.03, 0.05


def clock_check(imu: ImuSeries, lidar, off_s: float, gyro_lag_s: float) -> str:
    """Why the lidar's clock (with ``off_s``) and the gyro's (with ``gyro_lag_s``) do not meet, or '' (also where
    the data cannot tell: too short an overlap, too little turning)."""
    lidar = shifted(lidar, off_s)          # searched about the offset given (a GPS-time lidar 18 s off, say)
    t0 = max(float(imu.t_s[0]), float(lidar.t_s[0]) if len(lidar) else np.inf)
    # the search trims its shift range off each end and refuses less than MIN_OVERLAP_S after that
    if len(lidar) < 2 or min(float(imu.t_s[-1]), float(lidar.t_s[-1])) - t0 < MIN_OVERLAP_S + 2 * MAX_SHIFT_S + 1.0:
        return ""
    keep = lambda s: s.select(s.t_s <= t0 + CHECK_SPAN_S)          # noqa: E731
    imu_w, lid_w = keep(imu), keep(lidar)
    if turning_rps(imu_w.select(imu_w.t_s >= t0)) < CHECK_MIN_TURN_RPS:
        return ""
    given = f"lidar.time_offset_s = {off_s:g} s, imu.gyro_lag_s = {gyro_lag_s:g} s"
    try:
        sh = measure_shifts(imu_w, lid_w, accel=False, rate=True)
    except ShiftAtSearchEdgeError as exc:    # the best match at the end of the search: clocks or axes that do not meet
        why = str(exc).split("): ", 1)[-1]        # the streams do not share one clock to within that, or axes ...
        return (f"the lidar's rotation rate meets the gyro's nowhere within +/-{MAX_SHIFT_S * 1e3:.0f} ms of the offsets "
                f"given ({given}): {why}")
    except FusionEvalError:               # too little data left to correlate: not this check's to say
        return ""
    miss, sd = sh.rate - gyro_lag_s, sh.std(0, 1)
    if not (np.isfinite(miss) and abs(miss) > max(CHECK_MIN_S, 3 * sd)):
        return ""
    return (f"the lidar's rotation rate meets the gyro's {miss * 1e3:+.0f} +/- {sd * 1e3:.0f} ms away from the offsets "
            f"given ({given}; first {CHECK_SPAN_S:g} s): the lidar's stamps are off the IMU's clock, or the gyro lags; "
            "lidar.time_offset_s=auto (or imu.gyro_lag_s=auto) estimates it from the data")
