"""Plausibility of a dataset's streams as a whole, checked once every stream is read (the readers check each value).

What no real drive holds is refused with the file, the line and the value: an IMU stream that stops for more than a
minute (a corrupted stamp, or two recordings run together), a stream whose time span is tens of times the IMU's (its
stamps in milliseconds or microseconds), a pose beyond 40,000 km of its frame's origin, or consecutive poses whose
implied speed exceeds 10 km/s (faster than a satellite). Each bound is far beyond any vehicle, so that no real data
is refused; what real data can hold (a lidar odometry failure jumping by metres) is left to the filter's gates.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataFormatError, DataRangeError, place
from ..so3 import fit_rotation_2d
from ..stats import moving_mean
from ..types import line_of

MAX_LAG_S = 1.0          # an IMU channel's latency: beyond a second it is a clock offset (or a typo), not a lag
LAG_NOTE = (f"a channel lag is a latency of milliseconds (KITTI's OXTS: 0.06 s), at most {MAX_LAG_S:g} s here; a clock "
            "offset between streams goes in time_offset_s")
MAX_IMU_GAP_S = 60.0
MAX_IMU_STEP_S = 0.2     # a median step above this is no IMU's (KITTI's OXTS, the slowest here: 0.1 s; a 4 kHz one in ms: 0.25)
FLAG_IMU_GAP_S = 1.0     # shorter stops are bridged by the filter (imu.gap_factor); longer ones are flagged
MAX_SPAN_RATIO = 50.0
# the Earth's circumference: more than any Earth-fixed frame holds (ENU, ECEF's 6,400 km, UTM's northings of up to
# 10,000 km in the southern hemisphere, Web Mercator's 20,000 km)
MAX_POSITION_M = 4e7
MAX_SPEED_MPS = 1e4
# A wheeled ground vehicle's speed with a wide margin (360 km/h): a faster step between consecutive poses of its ground
# truth, GNSS or lidar odometry is a glitch (a corrupted packet, an odometry failure). Flagged, not refused: a real
# receiver's fix can jump like that, and what the filter makes of it is for its gates to say.
MAX_GROUND_SPEED_MPS = 100.0
# Any platform this tool is for (cars, robots, drones, hand-held rigs) stays below this (an airliner's cruise): a step
# between consecutive GNSS fixes beyond it is a glitch whatever the manifest's platform (a multipath fix 1.1 km off,
# 5,460 m/s at 5 Hz, moved a simulated drive's fused APE from 0.46 to 6.0 m with no word where no platform was declared)
MAX_ANY_SPEED_MPS = 300.0


def check_imu(imu) -> None:
    t = np.asarray(imu.t_s)
    if t.size < 3:
        return
    d = np.diff(t)
    med = float(np.median(d))
    if med > MAX_IMU_STEP_S * 1.01:       # (5 Hz itself passes whatever the rounding of POSIX-scale stamps)
        if med < 1.0:
            # a genuinely slow IMU (1-5 Hz): a 4.2 Hz stream was told its stamps were milliseconds (a rate review)
            raise DataFormatError(imu.source, line_of(imu.lines, 0),
                                  f"the IMU's samples are {med:.6g} s apart (median step, {1.0 / med:.3g} Hz): below the "
                                  f"{1.0 / MAX_IMU_STEP_S:g} Hz a strapdown integration between observations needs "
                                  "(KITTI's OXTS, the slowest here, gives 10 Hz); use the IMU's full-rate stream")
        # no IMU a filter integrates samples this slowly: its stamps are in another unit (ms read as s: a 100 Hz IMU
        # 10 s apart; the others' spans then did not meet it and nothing named the unit, a user's review)
        raise DataFormatError(imu.source, line_of(imu.lines, 0),
                              f"the IMU's samples are {med:.6g} s apart (median step), where an IMU gives 10 to "
                              "thousands per second: its stamps are in another unit (milliseconds read as seconds?); "
                              "give seconds, or the unit (csv format: time_unit: ms)")
    bad = np.flatnonzero(d > max(MAX_IMU_GAP_S, 1000.0 * med))
    if bad.size:
        i = int(bad[0]) + 1
        raise DataFormatError(imu.source, line_of(imu.lines, i), f"the IMU stamps jump by {d[i - 1]:.3f} s (median step {med:.4g} s) "
                                                         f"to {t[i]:.6f}: a corrupted stamp, or recordings run together "
                                                         f"(a gap of over {MAX_IMU_GAP_S:g} s); split the drive there")


def check_span(name: str, series, imu) -> None:
    """A stream whose time span is :data:`MAX_SPAN_RATIO` times the IMU's has stamps in another unit."""
    t, ti = np.asarray(series.t_s), np.asarray(imu.t_s)
    if t.size < 2 or ti.size < 2:
        return
    span, span_imu = float(t[-1] - t[0]), float(ti[-1] - ti[0])
    if span_imu > 0 and span > MAX_SPAN_RATIO * span_imu:
        raise DataRangeError(f"{name} ({series.source}) spans {span:.6g} s against the IMU's {span_imu:.6g} s "
                             f"({span / span_imu:.0f}x): its stamps are in another unit (milliseconds? give seconds, or "
                             "the csv format's time_unit)")


def _odd_clock(imu, streams: dict) -> None:
    """Where every other stream spans :data:`MAX_SPAN_RATIO` times the IMU's span, the IMU's stamps are the ones in
    another unit (EuRoC IMU stamps in microseconds were blamed on the ground truth); with a single other stream the
    two cannot be told apart, and both are named."""
    ti = np.asarray(imu.t_s)
    if ti.size < 2 or not ti[-1] > ti[0]:
        return
    span_imu = float(ti[-1] - ti[0])
    spans = {n: float(np.asarray(s.t_s)[-1] - np.asarray(s.t_s)[0]) for n, s in streams.items()
             if s is not None and len(s.t_s) >= 2}
    long = {n: v for n, v in spans.items() if v > MAX_SPAN_RATIO * span_imu}
    if not long or len(long) < len(spans):
        return
    ratio = min(long.values()) / span_imu
    if len(long) >= 2:
        raise DataRangeError(f"the IMU ({imu.source}) spans {span_imu:.6g} s against {min(long.values()):.6g} s or more "
                             f"for {', '.join(long)} ({ratio:.0f}x): the IMU's stamps are in another unit (microseconds "
                             "read as nanoseconds?), or all of theirs are; give the unit the format expects")
    (name, span), = long.items()
    raise DataRangeError(f"{name} ({streams[name].source}) spans {span:.6g} s against the IMU's ({imu.source}) "
                         f"{span_imu:.6g} s ({ratio:.0f}x): the stamps of one of the two are in another unit "
                         "(milliseconds or microseconds? give the unit the format expects)")


def check_poses(name: str, poses) -> None:
    """Positions beyond :data:`MAX_POSITION_M` and consecutive poses faster than :data:`MAX_SPEED_MPS`."""
    check_track(name, poses.source, poses.lines, poses.t_s, poses.p_w_m)


def check_track(name: str, source, lines, t_s, p_m) -> None:
    """:func:`check_poses` on arrays: ``lines`` maps row ``i`` to its line in ``source`` (None: a source without lines,
    a bag's topic)."""
    p = np.asarray(p_m, float)
    if p.size == 0:
        return
    r = np.linalg.norm(p, axis=1)
    bad = np.flatnonzero(r > MAX_POSITION_M)
    if bad.size:
        i = int(bad[0])
        raise DataFormatError(source, line_of(lines, i), f"{name} position {p[i].tolist()} m is {r[i]:.4g} m from its "
                                                         f"frame's origin (more than {MAX_POSITION_M:g} m, the Earth's "
                                                         "circumference): a corrupted "
                                                         f"pose{_packet(source, line_of(lines, i))}")
    if p.shape[0] > 1:
        dt = np.diff(np.asarray(t_s, float))
        v = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.where(dt > 0, dt, np.inf)
        bad = np.flatnonzero(v > MAX_SPEED_MPS)
        if bad.size:
            i = int(bad[0]) + 1
            moving = v[np.isfinite(v) & (v > 0)]
            med = float(np.median(moving)) if moving.size else 0.0
            # every step that fast is a unit, not a corrupted row: stamps 1000x finer than read (a whole manifest's
            # time_unit ns for us was blamed on one pose; a conventions review)
            why = (f"; its median step is {med:.3g} m/s, no platform's speed: stamps in another unit than read (a "
                   "time_unit 1000x off: ns for us, us for ms?) or positions in mm" if med > MAX_ANY_SPEED_MPS
                   else f": a corrupted pose or stamp{_packet(source, line_of(lines, i))}")
            raise DataFormatError(source, line_of(lines, i), f"{name} pose moves {v[i - 1]:.3g} m/s from the previous one "
                                                             f"(more than {MAX_SPEED_MPS:.0e} m/s){why}")


def _packet(source, line) -> str:
    """For a KITTI OXTS stream, whose rows are named by the line of ``oxts/timestamps.txt``, the packet file that
    holds the row's values (a corrupted value is there, not in the stamp)."""
    src = Path(str(source))
    if line is None or src.name != "timestamps.txt" or not (src.parent / "data").is_dir():
        return ""
    return f" (its values: {src.parent / 'data' / f'{line - 1:010d}.txt'})"


def imu_gaps(imu) -> list[str]:
    """The IMU's stops longer than :data:`FLAG_IMU_GAP_S` (and 50 median steps), shorter than the refused
    :data:`MAX_IMU_GAP_S`, as one sentence for the report: the filter only dead-reckons across them, and a stop
    in the stamps alone (a corrupted clock) shifts every stream aligned to the IMU."""
    idx = np.arange(len(imu.t_s))
    d, limit, bad = _gaps(imu, idx)
    if not bad.size:
        return []
    i = int(bad[0]) + 1
    line = line_of(imu.lines, i)
    at = place(imu.source, line)
    return [f"imu: {bad.size} gap(s) longer than {limit:.3g} s, the longest {d[bad].max():.3g} s, "
            f"the first of {d[bad[0]]:.3g} s before {at}: the filter dead-reckons across a gap, and a gap in the stamps "
            "alone (a corrupted clock) shifts every stream aligned to the IMU"]


STEP_GAP_FACTOR = 3.0       # a truth interval this many median steps long (and 0.3 s) is checked against its motion
STEP_MIN_SPEED_MPS = 2.0    # ... where the truth moves at least this fast
STEP_MOTION_RATIO = 0.5     # ... and flagged where its positions moved less than this share of its speed times it


def clock_steps(truth) -> list[str]:
    """Stretches of a ground truth with velocities whose stamps jump further than its positions moved: an interval of
    1.1 s over which a car at 10 m/s moved 1 m is a clock step of +1 s, not a gap in the data (whose positions move on
    with the time). A 1 s step in KITTI's oxts/timestamps.txt was never located, the lags' estimate blamed the
    clocks or the axes, and with the lag given the run went on to 2.21 m for 0.76 (a corrupted-input review)."""
    v = getattr(truth, "v_w_mps", None)
    if truth is None or v is None or len(truth) < 10:
        return []
    idx = np.flatnonzero(_real(truth))
    if idx.size < 10:
        return []
    t, p, v = np.asarray(truth.t_s)[idx], np.asarray(truth.p_w_m)[idx], np.asarray(v)[idx]
    dt = np.diff(t)
    long = np.flatnonzero(dt > max(STEP_GAP_FACTOR * float(np.median(dt)), 0.3))
    if not long.size:
        return []
    speed = 0.5 * (np.linalg.norm(v[long], axis=1) + np.linalg.norm(v[long + 1], axis=1))
    moved = np.linalg.norm(p[long + 1] - p[long], axis=1)
    bad = long[(speed > STEP_MIN_SPEED_MPS) & (moved < STEP_MOTION_RATIO * speed * dt[long])]
    if not bad.size:
        return []
    k = int(bad[0])
    sp = 0.5 * (np.linalg.norm(v[k]) + np.linalg.norm(v[k + 1]))
    i = int(idx[k + 1])
    line = line_of(truth.lines, i)
    motion_s = float(np.linalg.norm(p[k + 1] - p[k])) / sp
    return [f"groundtruth: {bad.size} jump(s) of the stamps further than the positions moved, the first {dt[k]:.3g} s "
            f"before {place(truth.source, line)}{_packet(truth.source, line)} over which it moved "
            f"{np.linalg.norm(p[k + 1] - p[k]):.3g} m at {sp:.3g} m/s ({motion_s:.2g} s of its motion): a clock step of "
            f"about {dt[k] - motion_s:+.2g} s there, not a gap in the data; every stream stamped by that clock is shifted "
            "after it"]


def _gaps(imu, idx: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Over the samples ``idx`` of ``imu``: their steps, the flagged length (:data:`FLAG_IMU_GAP_S` and 50 median
    steps) and the steps longer than it (none for fewer than 3 samples)."""
    if idx.size < 3:
        return np.zeros(0), np.inf, np.zeros(0, np.int64)
    d = np.diff(np.asarray(imu.t_s)[idx])
    limit = max(FLAG_IMU_GAP_S, 50.0 * float(np.median(d)))
    return d, limit, np.flatnonzero(d > limit)


def dropped_gaps(imu, kept: np.ndarray, why: str) -> list[str]:
    """:func:`imu_gaps` of the samples ``kept`` (a mask over ``imu``), naming the dropped samples that open each
    gap: KITTI's filled-in packets are dropped before the filter, and a long run of them leaves a hole the raw stamps
    do not show (30 s of them once gave a 125 deg attitude error with no word)."""
    idx = np.flatnonzero(kept)
    d, limit, bad = _gaps(imu, idx)
    bad = bad[idx[bad + 1] - idx[bad] > 1]            # gaps the dropping opened: those in the stamps, imu_gaps says
    if not bad.size:
        return []
    a, b = int(idx[bad[0]]) + 1, int(idx[bad[0] + 1]) - 1          # the first gap's dropped samples
    la, lb = line_of(imu.lines, a), line_of(imu.lines, b)
    where = place(imu.source, f"{la}-{lb}") if la is not None and lb is not None else f"{imu.source} (samples {a}-{b})"
    return [f"imu: {bad.size} gap(s) longer than {limit:.3g} s after dropping {why}, the longest {d[bad].max():.3g} s, "
            f"the first of {d[bad[0]]:.3g} s ({b - a + 1} samples at {where}): the filter dead-reckons across a gap "
            "in one step, so the estimate there means little"]


# IMU units that read as plausible numbers. A wheeled vehicle turns at under 1 rad/s (a car's tightest turn at walking
# pace); a platform not declared is taken to be no acrobat (10 rad/s at its 99th percentile is 570 deg/s); a drone,
# a hand or legs may spin up to a 2000 deg/s gyro's range. Above: a rate in deg/s read as rad/s. Any platform's
# accelerometer reads gravity.
MAX_RATE_RPS = {"wheeled": 5.0, None: 10.0, "other": 10.0, "agile": 35.0}
MIN_SPECIFIC_FORCE_MPS2, MAX_SPECIFIC_FORCE_G = 4.0, 1.15
# the median above which no vehicle's specific force lies (gravity plus a car's or a drone's typical thrust: under 2 g);
# m/s^2 declared as g read 96 m/s^2 and dead-reckoned 278 km with only "no observation is enabled" (a review)
MAX_MEDIAN_SPECIFIC_FORCE_MPS2 = 20.0


def imu_units(imu, platform: str | None, wheeled: bool) -> list[str]:
    """The IMU's units where its values say they are wrong though each is a plausible number, one sentence each:
    angular rates in deg/s read as rad/s (a car 'turning' at 20 rad/s: the run diverged with a hint at the process
    noise), specific force without gravity (a driver's free acceleration: 38 m of error and no word) or in g."""
    out = []
    w = np.linalg.norm(np.asarray(imu.w_b_rps, float), axis=1)
    f = np.linalg.norm(np.asarray(imu.f_b_mps2, float), axis=1)
    if w.size < 100:
        return out
    w99, f50 = float(np.percentile(w, 99)), float(np.median(f))
    kind = "wheeled" if wheeled else platform if platform in (None, "other") else "agile"
    if w99 > MAX_RATE_RPS[kind]:
        who = f"platform '{platform}'" if platform else "a platform not declared (the manifest's platform)"
        out.append(f"imu: angular rate {w99:.3g} rad/s (99th percentile) for {who}: a gyro in deg/s read as rad/s? "
                   f"({imu.source}; a CSV stream's gyro_unit, a bag driver's units)")
    if f50 < MIN_SPECIFIC_FORCE_MPS2:
        # gravity's magnitude times a power of ten (1e-3: 9.9e-3 m/s^2 was called 'gravity removed?'; a review);
        # from 1e-3 on: a vehicle's free acceleration has a median of 0.1-1.3 m/s^2 (kitti-00's: 1.2), never 0.01
        k = round(-np.log10(max(f50, 1e-300) / 9.81))
        scaled = 3 <= k <= 6 and abs(f50 * 10.0 ** k / 9.81 - 1.0) < 0.15
        out.append(f"imu: specific force {f50:.3g} m/s^2 (median) where gravity alone gives 9.8: "
                   + ("in g? (a CSV stream's accel_unit)" if 0.85 < f50 < MAX_SPECIFIC_FORCE_G else
                      f"gravity's magnitude times 1e-{k}: a unit declared or converted wrong (values scaled by 1e-{k})?"
                      if scaled else
                      "gravity removed (a driver's 'free' or linear acceleration)? The filter needs the specific force, "
                      "gravity included")
                   + f" ({imu.source})")
    elif f50 > MAX_MEDIAN_SPECIFIC_FORCE_MPS2:
        g_read = 0.85 * 9.81 ** 2 < f50 < MAX_SPECIFIC_FORCE_G * 9.81 ** 2
        out.append(f"imu: specific force {f50:.3g} m/s^2 (median) where gravity alone gives 9.8: "
                   + ("values in m/s^2 read as g? (a CSV stream's accel_unit: g)" if g_read else
                      "another unit (mg, cm/s^2, raw counts)? The filter needs m/s^2")
                   + f" ({imu.source})")
    return out


def _real(s) -> np.ndarray:
    """The samples of a stream that are not filled-in packets (all of them for a stream without the flag)."""
    filled = getattr(s, "filled", None)
    return ~np.asarray(filled, bool) if filled is not None else np.ones(len(s), bool)


def speed_glitches(streams: dict, platform: str | None, max_speed_mps: float = MAX_GROUND_SPEED_MPS) -> list[str]:
    """Per stream (``streams``: name -> pose or GNSS series, or None), the steps between consecutive real (not
    filled-in) samples faster than ``max_speed_mps`` (for fixes with a std, beyond 6 sigma of their difference), as
    one sentence each for the report."""
    what = f"a {platform}" if platform else "any platform (none declared)"
    out = []
    for name, s in streams.items():
        if s is None or len(s) < 2:
            continue
        idx = np.flatnonzero(_real(s))
        p, t = np.asarray(s.p_w_m)[idx], np.asarray(s.t_s)[idx]
        dt = np.diff(t)
        step = np.linalg.norm(np.diff(p, axis=0), axis=1)
        std = getattr(s, "std_w_m", None)
        if std is not None:             # a fix's own noise is no glitch: 6 sigma of the two fixes' difference allowed
            sd = np.asarray(std, float)[idx]
            step = np.maximum(step - 6.0 * np.sqrt(np.sum(sd[1:] ** 2 + sd[:-1] ** 2, axis=1)), 0.0)
        v = step / np.where(dt > 0, dt, np.inf)
        bad = np.flatnonzero(v > max_speed_mps)
        if bad.size:
            i = int(idx[bad[0] + 1])
            line = line_of(s.lines, i)
            at = place(s.source, line)
            out.append(f"{name}: {bad.size} step(s) faster than {max_speed_mps:g} m/s for {what}, the first "
                       f"{v[bad[0]]:.3g} m/s at {at}{_packet(s.source, line)}: a glitch in the data, whose figures "
                       "are suspect")
    return out


# Seconds beyond this (year 5138) are no clock's: POSIX time in ms, us or ns read as seconds. The unit is told by
# the magnitude of a 21st-century POSIX stamp (1.0e9..4.1e9 s) in each unit.
MAX_STAMP_S = 1e11
_UNIT_OF_MAGNITUDE = ((1e17, "POSIX time in nanoseconds", "ns"),
                      (1e14, "POSIX time in microseconds (or a boot clock in nanoseconds)", "us or ns"),
                      (1e11, "POSIX time in milliseconds (or a boot clock in nanoseconds: a day's uptime is 8.6e13)",
                       "ms or ns"))


def check_stamp_magnitude(name: str, series) -> None:
    """Refuse stamps no clock gives in seconds, naming the unit their magnitude points at: every stream in ns read as
    seconds passed every span check (all alike) and the filter 'diverged at t=1767225636000000000.000 s' (a user's
    review)."""
    check_stamps_in_seconds(name, series.source, series.lines, series.t_s)


# where a stream's unit is given: the generic CSV format's key; every other format is in seconds (the hint named the
# csv key to a KITTI or EuRoC stream, which has none: an extension author's review)
STREAM_UNIT_HINT = "convert the file, or for the csv format give its time_unit: {unit}"


def check_stamps_in_seconds(name: str, source, lines, t_s, how: str = STREAM_UNIT_HINT) -> None:
    """:func:`check_stamp_magnitude` on arrays (``how``: where the unit is given, ``{unit}`` its short name)."""
    t = np.asarray(t_s)
    if t.size == 0 or not abs(float(t[0])) > MAX_STAMP_S:
        return
    big = abs(float(t[0]))
    word, unit = next((w, u) for lim, w, u in _UNIT_OF_MAGNITUDE if big >= lim)
    raise DataFormatError(source, line_of(lines, 0),
                          f"{name}: the first stamp is {float(t[0]):.6g} s, beyond any clock in seconds: {word} read "
                          f"as seconds? Give seconds ({how.format(unit=unit)})")


# a clock below this counts from a device's boot (12 days), one between the two bounds is POSIX time (1973-2100)
BOOT_CLOCK_MAX_S = 1e6
POSIX_RANGE_S = (1e8, 4.1e9)


# GPS time (from 1980-01-06, POSIX 315964800) runs ahead of UTC by the leap seconds since: (from, seconds), the
# dates of IERS's bulletins C
GPS_EPOCH_POSIX_S = 315964800.0
_LEAPS = ("1981-07-01", "1982-07-01", "1983-07-01", "1985-07-01", "1988-01-01", "1990-01-01", "1991-01-01", "1992-07-01",
          "1993-07-01", "1994-07-01", "1996-01-01", "1997-07-01", "1999-01-01", "2006-01-01", "2009-01-01", "2012-07-01",
          "2015-07-01", "2017-01-01")
# a start this close to the other clock's time of day (or of the GPS week) is that clock, not a boot clock
CLOCK_EPOCH_MATCH_S = 120.0


def gps_leap_s(t_posix: float) -> int:
    """GPS time minus UTC (s) at the POSIX time ``t_posix``."""
    from datetime import datetime, timezone

    return sum(t_posix >= datetime.fromisoformat(d).replace(tzinfo=timezone.utc).timestamp() for d in _LEAPS)


def _clock_epoch(t_near0: float, t_posix: float):
    """``(offset_s, what, epoch)`` where a clock near 0 is the seconds of the day (UTC) or of the GPS week of the
    POSIX one: a receiver's GPS-style file ran from 46534 s against KITTI's POSIX stamps and got 'add their starts'
    difference', 2 s off the day's midnight (an own-data review). The nearer of the two where both fit (on a Sunday
    the week's seconds are the day's plus the leap seconds; a review). None otherwise."""
    cands = []
    day0 = np.floor(t_posix / 86400.0) * 86400.0
    if t_near0 < 86400.0:
        cands.append((abs((t_posix - day0) - t_near0), day0, "seconds of the day (UTC)", "that day's midnight, UTC"))
    leap = gps_leap_s(t_posix)
    gps = t_posix - GPS_EPOCH_POSIX_S + leap
    week = np.floor(gps / 604800.0)
    if t_near0 < 604800.0:
        cands.append((abs((gps - week * 604800.0) - t_near0), GPS_EPOCH_POSIX_S + week * 604800.0 - leap,
                      f"seconds of the GPS week (GPS time, {leap} s ahead of UTC)",
                      f"the start of GPS week {week:.0f} in POSIX time"))
    cands = [c for c in cands if c[0] < CLOCK_EPOCH_MATCH_S]
    return min(cands)[1:] if cands else None


def clock_hint(a: str, a_t0: float, b: str, b_t0: float) -> str:
    """Why two streams' stamps do not meet, where their starts tell: one clock starts near 0 (a device's boot clock,
    or time relative to a recording's start) and the other is POSIX time (a bag's IMU on its driver's boot clock).
    '' otherwise."""
    def kind(t):
        return ("zero" if 0 <= t < BOOT_CLOCK_MAX_S else
                "posix" if POSIX_RANGE_S[0] <= t <= POSIX_RANGE_S[1] else "")
    ka, kb = kind(a_t0), kind(b_t0)
    if ka == kb == "posix":
        # both POSIX, whole hours apart: one clock in local time (a GNSS file converted with a time zone: 2 h on
        # kitti-00's GTSAM-style GPS file, with no hint; a conventions review)
        d = b_t0 - a_t0
        h = round(d / 3600.0)
        if 1 <= abs(h) <= 14 and abs(d - 3600.0 * h) < 120.0:
            return (f": their starts differ by {d:.0f} s, about {abs(h)} h: one of the clocks in local time, the other "
                    f"in UTC? add about {d:.0f} s to the {a} stream's time_offset_s, or stamp both in UTC")
        return ""
    if {ka, kb} != {"zero", "posix"}:
        return ""
    near0, posix = (a, b) if ka == "zero" else (b, a)
    d = (b_t0 - a_t0) if ka == "zero" else (a_t0 - b_t0)
    t_near0, t_posix = (a_t0, b_t0) if ka == "zero" else (b_t0, a_t0)
    epoch = _clock_epoch(t_near0, t_posix)
    if epoch:
        return (f": the {near0} stamps ({t_near0:.3f} s) are {epoch[1]}, the {posix} stamps POSIX time: add "
                f"{epoch[0]:.0f} s ({epoch[2]}) to the {near0} stream's time_offset_s")
    return (f": the {near0} stamps start near 0 ({min(a_t0, b_t0):.3f} s: a device's boot clock, or time from the "
            f"recording's start), the {posix} stamps are POSIX time: add about {d:.3f} s to the {near0} stream's "
            "time_offset_s (their starts' difference), or stamp both on one clock")


def check_dataset(imu, streams: dict) -> None:
    """Every check on a dataset: ``streams`` maps a stream's name to its series (None when absent)."""
    for name, s in {"imu": imu, **streams}.items():
        if s is not None:
            check_stamp_magnitude(name, s)
    check_imu(imu)
    _odd_clock(imu, streams)
    for name, s in streams.items():
        if s is None:
            continue
        check_span(name, s, imu)
        if hasattr(s, "q_wb_xyzw") or name == "gnss":
            check_poses(name, s)


MIN_TWIST_SPEED_MPS = 1.0      # slower, a pose's noise over one step is a large part of its differenced velocity
MAX_TWIST_MISMATCH = 0.3       # median |v - dp/dt| / |dp/dt| beyond this is a convention, not noise


SIDEWAYS_MIN_SPEED_MPS = 2.0      # the truth's motion at least this fast is checked for going sideways
SIDEWAYS_RATIO = 0.5              # ... sideways where the lateral speed is over this share of the speed
SIDEWAYS_FRACTION = 0.2           # ... said where that holds on this share of the moving time


def sideways(truth, platform: str, travel_yaw_rad: float = 0.0) -> str:
    """For a wheeled platform whose non-holonomic constraint is on: the ground truth's body moving sideways (across
    the direction of travel the constraint assumes, ``travel_yaw_rad`` off the IMU's x axis: its lateral speed over
    half its speed on a fifth of its moving time and more), which no car does, so that the constraint fights the
    data: a strafing drone declared a car went from 0.25 to 38.6 m with warnings on NIS and NEES only (a non-car
    review). The speed is the positions' rate of change (a truth's stored velocity may be in another frame: an
    Odometry twist in the parent frame). '' otherwise (KITTI's drives: under 1 % of the time)."""
    if truth is None or len(truth) < 10:
        return ""
    real = _real(truth)
    t, p = np.asarray(truth.t_s)[real], np.asarray(truth.p_w_m)[real]
    if t.size < 10 or np.any(np.diff(t) <= 0):
        return ""
    R = np.asarray(truth.R_wb())[real]
    c, sn = np.cos(travel_yaw_rad), np.sin(travel_yaw_rad)
    v_b = np.einsum("nji,nj->ni", R, np.gradient(p, t, axis=0))
    v_b = np.column_stack([c * v_b[:, 0] + sn * v_b[:, 1], -sn * v_b[:, 0] + c * v_b[:, 1], v_b[:, 2]])   # travel axes
    speed = np.linalg.norm(v_b, axis=1)
    moving = speed > SIDEWAYS_MIN_SPEED_MPS
    if moving.sum() < 10:
        return ""
    side = np.abs(v_b[moving, 1]) > SIDEWAYS_RATIO * speed[moving]
    if not side.mean() > SIDEWAYS_FRACTION:
        return ""
    rms = float(np.sqrt(np.mean(v_b[moving, 1] ** 2)))
    return (f"groundtruth: the body moves sideways (its lateral speed over half its speed on {side.mean():.0%} of the "
            f"time it moves, {rms:.2g} m/s RMS), which no {platform} does: the non-holonomic constraint, on for this "
            f"platform, fights the data; declare the platform it is (or none), or give the direction of travel "
            "(filter.nhc_travel_yaw_mrad) if the IMU's axes are not the vehicle's")


def velocity_mismatch(poses) -> str:
    """Why the velocities a pose stream carries (an Odometry twist, KITTI's vn/ve/vu) are not its positions'
    rate of change, or '' when they agree (or it has none, or never moves fast enough to tell). ROS's
    ``nav_msgs/Odometry`` twist is in ``child_frame_id``; written in the parent frame (a common mistake), it is read
    rotated by the heading, and the filter started with it runs off before any aiding corrects it."""
    v = getattr(poses, "v_w_mps", None)
    if v is None or len(poses) < 3:
        return ""
    real = _real(poses)
    t, p, v = np.asarray(poses.t_s)[real], np.asarray(poses.p_w_m)[real], np.asarray(v)[real]
    if t.size < 3 or np.any(np.diff(t) <= 0):
        return ""
    dp = np.gradient(p, t, axis=0)
    speed = np.linalg.norm(dp, axis=1)
    moving = speed > MIN_TWIST_SPEED_MPS
    if moving.sum() < 10:
        return ""
    rel = np.linalg.norm(v[moving] - dp[moving], axis=1) / speed[moving]
    med = float(np.median(rel))
    if not med > MAX_TWIST_MISMATCH:
        return ""
    return (f"{poses.source}: its velocities differ from its positions' rate of change by {med:.0%} of the speed (median "
            f"over {int(moving.sum())} samples above {MIN_TWIST_SPEED_MPS:g} m/s): a nav_msgs/Odometry twist in the "
            "parent frame rather than child_frame_id, or its axes or units mixed up; the filter's initial velocity is "
            "taken from the positions instead")


# a constant offset of the GNSS from the ground truth beyond this and three times the fixes' spread about it is an
# origin or a datum, not noise (a given origin 7 m off ran to 6.84 m with no word at the 10 m this was; a review);
# from MIN_GNSS_OFFSET_STATED_M where the receiver states a std that small (x MIN_OFFSET_STATED_SIGMAS): a receiver
# stating 0.5 m sat 2.5 m from the truth, fused 2.54 m against 0.79, with no word (an own-data review)
MIN_GNSS_OFFSET_M = 3.0
MIN_GNSS_OFFSET_STATED_M, MIN_OFFSET_STATED_SIGMAS = 1.0, 3.0
MIN_ANTENNA_DATUM_M = 5.0      # an offset under this may be an antenna's lever arm as well as an origin or a datum
# with the origin taken from the first fix, that fix's own error is carried by every fix: said beyond this and
# MIN_OFFSET_SIGMAS standard errors of the median (2.6 m where 0.54 was right, no word; a review)
MIN_FIRST_FIX_OFFSET_M, MIN_OFFSET_SIGMAS = 1.0, 5.0


def _fixes_on_truth(gnss, groundtruth, lever_b_m=None, stamps: bool = False):
    """The real GNSS fixes inside the ground truth's span and where the truth puts the antenna at their stamps
    ``(gnss, truth)``, each (n, 3): its positions, plus its attitude times the configured lever arm ``lever_b_m``
    (a 4 m arm given rightly was called another origin; a review); with ``stamps``, their stamps (n,) third. None with
    fewer than 10 of them (or a truth whose stamps do not increase)."""
    if gnss is None or groundtruth is None or len(gnss) < 10 or len(groundtruth) < 2:
        return None
    from ..interp import interpolate_poses

    t_gt = np.asarray(groundtruth.t_s)
    inside = (gnss.t_s >= t_gt[0]) & (gnss.t_s <= t_gt[-1]) & _real(gnss)
    if inside.sum() < 10 or np.any(np.diff(t_gt) <= 0):
        return None
    at = interpolate_poses(groundtruth, gnss.t_s[inside])
    r = at.p_w_m
    q = np.asarray(groundtruth.q_wb_xyzw, float)
    # (not by a placeholder orientation, the same on every pose of a position-only truth: it turned the arm wrongly
    # and gave false offsets; a review)
    if lever_b_m is not None and np.any(np.asarray(lever_b_m, float) != 0) and not np.all(q == q[0]):
        r = r + np.einsum("nij,j->ni", at.R_wb(), np.asarray(lever_b_m, float))
    g = np.asarray(gnss.p_w_m, float)[inside]
    return (g, r, np.asarray(gnss.t_s, float)[inside]) if stamps else (g, r)


def _offset_limits(gnss) -> tuple[float, float]:
    """The horizontal and vertical offsets (m) beyond which :func:`gnss_offset` speaks: :data:`MIN_GNSS_OFFSET_M`, or
    less where the receiver states a small std: :data:`MIN_OFFSET_STATED_SIGMAS` times it (medians over the real
    fixes), from :data:`MIN_GNSS_OFFSET_STATED_M` (a constant offset of many stated stds is not the receiver's noise)."""
    std = getattr(gnss, "std_w_m", None)
    real = _real(gnss)
    if std is None or np.asarray(std).shape != (len(gnss.t_s), 3) or not real.any():
        return MIN_GNSS_OFFSET_M, MIN_GNSS_OFFSET_M
    st = np.median(np.asarray(std, float)[real], axis=0)
    if not np.all(np.isfinite(st) & (st > 0)):
        return MIN_GNSS_OFFSET_M, MIN_GNSS_OFFSET_M
    h = float(np.hypot(st[0], st[1]) / np.sqrt(2.0))
    return tuple(float(np.clip(MIN_OFFSET_STATED_SIGMAS * v, MIN_GNSS_OFFSET_STATED_M, MIN_GNSS_OFFSET_M))
                 for v in (h, st[2]))


MAX_GEOID_M = 110.0        # the geoid's height above WGS84's ellipsoid lies within -107..+86 m everywhere


def gnss_offset(gnss, groundtruth, origin_from_first_fix: bool = False, lever_b_m=None) -> str:
    """Why the GNSS sits a constant distance from the ground truth (median over the fixes inside the truth's span,
    per ENU axis, beyond :data:`MIN_GNSS_OFFSET_M` (less for a receiver stating a small std: :func:`_offset_limits`)
    and three times the residuals' spread about it), or ''. The usual
    cause is a datum: an altitude above mean sea level (NavSatFix's is the ellipsoid's; the geoid lies 20-50 m
    from it in Europe) against a geodetic origin or ground truth on the ellipsoid; horizontally, another origin.
    ``origin_from_first_fix``: the local frame's origin is the GNSS's first fix (``geodetic_origin: first_fix``, the
    default) and the ground truth is in a frame of its own: an offset beyond :data:`MIN_FIRST_FIX_OFFSET_M` and
    :data:`MIN_OFFSET_SIGMAS` standard errors is that fix's error."""
    pair = _fixes_on_truth(gnss, groundtruth, lever_b_m)
    if pair is None:
        return ""
    d = pair[0] - pair[1]
    n_fixes = len(d)
    off = np.median(d, axis=0)
    spread = np.median(np.abs(d - off), axis=0) * 1.4826
    # horizontally by the offset's length (3.5 m at 45 deg passed each axis' 3 m; a review), vertically on its own
    h, sh = float(np.hypot(off[0], off[1])), float(np.hypot(spread[0], spread[1]) / np.sqrt(2.0))
    lim = _offset_limits(gnss)
    big_h = h > lim[0] and h > 3.0 * sh
    big = np.array([big_h, big_h, abs(off[2]) > lim[1] and abs(off[2]) > 3.0 * spread[2]])
    if not big.any():
        se = 1.2533 * spread / np.sqrt(n_fixes)          # the standard error of a median
        if origin_from_first_fix and float(np.linalg.norm(off)) > MIN_FIRST_FIX_OFFSET_M and \
                np.any(np.abs(off) > MIN_OFFSET_SIGMAS * se):
            return (f"{gnss.source}: the GNSS sits a constant east, north, up {off[0]:+.2f}, {off[1]:+.2f}, "
                    f"{off[2]:+.2f} m from the ground truth (median over {n_fixes} fixes; its standard error "
                    f"{se.max():.2f} m): the local frame's origin is the GNSS's first fix (geodetic_origin: first_fix, "
                    "the default), whose own error every fix then carries, while the ground truth has a frame of its "
                    "own; give geodetic_origin as the ground truth frame's origin (lat, lon, alt)")
        return ""
    # a few metres: an antenna whose lever arm is not given, as likely as a datum (kitti-00's GNSS raised 1.5 m, stated
    # 0.3 m, was called the geoid; a review)
    arm = ("" if float(np.linalg.norm(off)) > MIN_ANTENNA_DATUM_M else
           ", or an antenna offset from the IMU whose lever arm is not given (gnss.lever_arm_b_m; one fixed in the body "
           "reads as a constant offset on a straight drive)")
    what = ("an altitude above mean sea level against an ellipsoidal origin, or the other way round (the geoid lies "
            "-100 to +85 m from WGS84's ellipsoid; NavSatFix's altitude is the ellipsoid's)" if big[2] and not big[:2].any()
            and abs(off[2]) <= MAX_GEOID_M else
            # beyond the geoid's range no datum explains it (feet for metres read 264 m up, called the geoid; a review)
            f"altitudes in another unit (feet read as metres: x3.28?), in the GNSS or in the ground truth "
            f"({groundtruth.source}), or a geodetic_origin altitude off by that much (given as 0?); no datum "
            f"explains {abs(off[2]):.0f} m (the geoid lies -100 to +85 m from WGS84's ellipsoid)"
            if big[2] and not big[:2].any()
            else "another origin or datum than the ground truth's (the manifest's geodetic_origin)") + arm
    return (f"{gnss.source}: the GNSS sits a constant east, north, up {off[0]:+.1f}, {off[1]:+.1f}, {off[2]:+.1f} m from "
            f"the ground truth (median over {n_fixes} fixes; their spread about it {spread.max():.1f} m): "
            f"{what}; the filter, started on the ground truth, is pulled there and every figure carries the offset")


# The GNSS this many times its own stated noise (and this many metres) from the ground truth, median, where no offset,
# frame or clock explains it: one of the two is not what it says (measured: a simulated receiver's fixes, as csv and as
# a bag, 2.2 and 2.0 m from the truth against 2.45 m stated, 0.8-0.9x; KITTI's OXTS position, checked before it is
# degraded, is the truth itself)
MAX_GNSS_MISFIT, MIN_GNSS_MISFIT_M = 10.0, 10.0


def gnss_disagrees(gnss, groundtruth) -> str:
    """Why the GNSS and the ground truth cannot both be right, or '': their distance beyond :data:`MAX_GNSS_MISFIT` x
    the fixes' stated std and :data:`MIN_GNSS_MISFIT_M`, medians over the fixes. A bag's ground-truth topic set to the
    lidar's poses (camera frame) or to a wheel odometry whose pose stayed zero scored every estimate at 90-128 m and
    'fused over lidar 0.996' with no word (a corrupted-input review)."""
    pair = _fixes_on_truth(gnss, groundtruth)
    if pair is None:
        return ""
    g, r = pair
    # the median distance: two multipath fixes 1 km off among 441 gave an RMS of 61 m and this warning, which the
    # glitch warning already covers (a review)
    misfit = float(np.median(np.linalg.norm(g - r, axis=1)))
    std = getattr(gnss, "std_w_m", None)
    stated = float(np.median(np.linalg.norm(np.asarray(std, float), axis=1))) if std is not None else 0.0
    if not (misfit > MIN_GNSS_MISFIT_M and misfit > MAX_GNSS_MISFIT * stated):
        return ""
    path = [float(np.linalg.norm(np.diff(x, axis=0), axis=1).sum()) for x in (g, r)]
    return (f"{groundtruth.source}: the ground truth and the GNSS ({gnss.source}) are {misfit:.1f} m apart (median over "
            f"{len(g)} fixes; the fixes' stated std {stated:.2g} m), and travel {path[1]:.0f} and {path[0]:.0f} m over "
            "them: one of the two is not what it says (another stream, frame or origin; a pose that never moves), and "
            "every figure against it is of that")


# The GNSS as fused against the ground truth. Under SAME_SOURCE_M RMS apart, it is the truth's own source: a receiver
# against an independent reference, RTK included (1-2 cm horizontal, 2-3 cm vertical), does not come under it over a
# drive (KITTI's OXTS position with degrade: false scored the GNSS at 0.000 m and the fusion at 0.087 m with no word).
# Farther apart, an error vector that moves under SMOOTH_STEP_M from one fix to the next (RMS) and under SMOOTH_SHARE
# of its own size is a smooth offset with no receiver's noise: kitti2bag's fixes (the OXTS solution, ENU) against its
# /tf (the same solution in pykitti's Mercator frame) are 0.43 m RMS apart, moving by a fraction of a mm a fix (a user
# trial). A receiver's white noise moves it by sqrt(2) x its per-fix noise: RTK's 3/3/5 mm by 9 mm, 3 mm over a 1.5 cm
# wandering bias by 7 mm (a review found a first check, on the error's length, naming such receivers).
SAME_SOURCE_M, SMOOTH_STEP_M, SMOOTH_SHARE = 0.005, 0.005, 0.01


def gnss_from_truth(gnss, groundtruth) -> str:
    """Why the GNSS as fused is the ground truth's own solution, as it is or in another frame, or ''."""
    pair = _fixes_on_truth(gnss, groundtruth)
    if pair is None:
        return ""
    e = pair[0] - pair[1]
    size = float(np.sqrt(np.mean(np.sum(e * e, axis=1))))
    degrade = ("mark the stream for degradation (degrade: true under the manifest's gnss) with noise "
               "(gnss.noise_std_m, not zero)")
    if size < SAME_SOURCE_M:
        return (f"the GNSS's positions match the ground truth to {size * 1000:.3f} mm RMS over {len(e)} fixes: they are "
                "its own source (KITTI's OXTS GPS/INS solution is both), so every figure against the truth of an "
                f"estimate that fuses them is scored on the answer; {degrade}, or give a receiver's own fixes")
    step = float(np.sqrt(np.mean(np.sum(np.diff(e, axis=0) ** 2, axis=1))))
    if not (step < SMOOTH_STEP_M and step < SMOOTH_SHARE * size):
        return ""
    return (f"{gnss.source}: the GNSS's error against the ground truth is {size:.3f} m RMS but moves by only "
            f"{step * 1000:.2f} mm RMS from one fix to the next over {len(e)} fixes: a smooth offset with no receiver's "
            "noise. If the fixes are the truth's own solution in another map frame (kitti2bag's /tf is pykitti's "
            "Mercator frame, its fixes the same OXTS solution in ENU), every figure against that truth is scored on the "
            f"answer: {degrade.replace(', not zero', '')}; if a receiver smoothed them, their errors are not independent "
            "from fix to fix as the filter takes them, and its covariance understates the fused error")


# The GNSS and the ground truth horizontal tracks related by a rotation about up (a map or UTM grid frame against
# ENU: grid convergence reaches 3 deg at a zone's edge) or by swapped axes (NED or x/y swapped against ENU). Said
# when the best such relation leaves at most a third of the residual of the plain track (after the median offset),
# gains more than MIN_FRAME_GAIN_M, and the track spans MIN_FRAME_EXTENT_M (on a short one, noise fits any angle).
MIN_FRAME_EXTENT_M, MIN_FRAME_GAIN_M, MAX_FRAME_FIT, MIN_FRAME_ANGLE_DEG = 50.0, 2.0, 1.0 / 3.0, 0.5


def gnss_frame(gnss, groundtruth) -> str:
    """Why the GNSS track is the ground truth's turned about up or with its axes swapped, or ''. Both are usually
    a frame given wrongly: ground truth in a map or UTM grid frame against ENU fixes (a 5 deg yaw: GNSS APE 21 m
    against 2.3, no word), or local NED positions declared as ENU (229 m; only the NIS said anything)."""
    pair = _fixes_on_truth(gnss, groundtruth)
    if pair is None:
        return ""
    g, r = pair
    if float(np.max(np.ptp(r[:, :2], axis=0))) < MIN_FRAME_EXTENT_M:
        return ""
    plain = float(np.sqrt(np.mean(np.sum((g[:, :2] - g[:, :2].mean(0) - (r[:, :2] - r[:, :2].mean(0))) ** 2, axis=1))))
    th, rot = fit_rotation_2d(r[:, :2], g[:, :2])
    _, swap = fit_rotation_2d(r[:, :2], g[:, 1::-1])
    if swap <= MAX_FRAME_FIT * plain and plain - swap > MIN_FRAME_GAIN_M and swap < rot:
        up = "; its up axis points down too" if np.ptp(r[:, 2]) > 5.0 and np.corrcoef(g[:, 2], r[:, 2])[0, 1] < -0.5 else ""
        return (f"{gnss.source}: the GNSS track matches the ground truth's with its east and north swapped (RMS "
                f"{swap:.1f} m against {plain:.1f} m as given{up}): positions in NED, or x and y swapped, declared as "
                f"ENU, in the GNSS or in the ground truth ({groundtruth.source}: the two cannot tell which; a truth's "
                "frame mistake shows in every estimate's figures, the GNSS's in its own and the fused one's)")
    if rot <= MAX_FRAME_FIT * plain and plain - rot > MIN_FRAME_GAIN_M and abs(np.degrees(th)) > MIN_FRAME_ANGLE_DEG:
        return (f"{gnss.source}: the GNSS track matches the ground truth's turned {np.degrees(th):+.2f} deg about up "
                f"(RMS {rot:.1f} m against {plain:.1f} m as given): one of the two is in another frame than ENU (a map "
                "frame, or a UTM grid: grid north is up to 3 deg from true north); every figure of the GNSS, and of "
                "the filter it pulls, carries the rotation")
    return ""


# A stream matching the ground truth best this far from its stamps, with at most a third of the position error
# there and a metre less, is a clock offset: the search reaches +/- MAX_CLOCK_SHIFT_S (GPS against UNIX time is 18 s);
# a lag of the odometry or a receiver's latency is tens of milliseconds. A third, not a half: an odometry whose scale
# is off by a constant factor drifts along the track linearly, and the best constant shift halves that exactly.
MIN_CLOCK_SHIFT_S, MAX_CLOCK_SHIFT_S = 0.15, 30.0
MAX_CLOCK_FIT, MIN_CLOCK_GAIN_M = 1.0 / 3.0, 1.0


def _rms_at_shifts(t: np.ndarray, p: np.ndarray, t_gt: np.ndarray, p_gt: np.ndarray, shifts: np.ndarray,
                   e0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each shift, the RMS of ``|p(t) - p_gt(t + shift)|`` and, over the same points (those whose shifted time
    the ground truth covers), the RMS of the errors as stamped ``e0``: a shift is never credited with dropping the
    points it cannot reach (a receiver settling in the first seconds). NaN where under half the points are covered.
    Every shift in one interpolation per axis."""
    ts = t[None, :] + shifts[:, None]
    m = (ts >= t_gt[0]) & (ts <= t_gt[-1])
    e2 = sum((p[None, :, a] - np.interp(ts, t_gt, p_gt[:, a])) ** 2 for a in range(3))
    n = m.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.where(m, e2, 0.0).sum(axis=1) / n)
        rms0 = np.sqrt(np.where(m, e0[None, :] ** 2, 0.0).sum(axis=1) / n)
    few = 2 * n < t.size
    return np.where(few, np.nan, rms), np.where(few, np.nan, rms0)


def _best(shifts: np.ndarray, rms: np.ndarray) -> int:
    """The shift of least RMS, the one nearest zero among equals (a parked vehicle fits every shift alike)."""
    low = np.nanmin(rms)
    tied = np.flatnonzero(rms <= low + 1e-9 + 1e-6 * low)
    return int(tied[np.argmin(np.abs(shifts[tied]))])


MAX_SPEED_SHIFT_S = 5.0          # the speed profiles' search: +/- this, s
# a best correlation below this is no profile to time by (keyframes only, a hand-held camera; a simulated figure-8 at
# near-constant speed, its clock right, peaked at 0.91-0.92 0.4 s off, a simulate review; real offsets on the lidar
# drives and the simulator's urban drive peak at 0.998-0.999)
MIN_SPEED_CORR = 0.97
# the share of the speeds' misfit (1 - correlation) a shift must leave to be said: the five real lidar drives' own best
# shifts are 0-0.01 s and leave 0.99-1.0 of it; a lidar 0.2 s early on a smooth simulated drive leaves 0.66
MAX_SPEED_MISFIT_LEFT = 0.8


def clear_speed_shift(found, halves=()) -> bool:
    """Whether a :func:`speed_clock_shift` result is a clock offset to report: at least :data:`MIN_CLOCK_SHIFT_S`,
    profiles that correlate to :data:`MIN_SPEED_CORR`, and at most :data:`MAX_SPEED_MISFIT_LEFT` of the misfit left;
    and ``halves`` (the same search on each half of the stream: :func:`speed_shift_halves`) each finding it too where
    they can be timed (correlate to :data:`MIN_SPEED_CORR`): a half parked or cruising is no evidence either way."""
    if found is None:
        return False
    s, c_best, c_zero = found
    if not (abs(s) >= MIN_CLOCK_SHIFT_S and c_best >= MIN_SPEED_CORR and 1 - c_best <= MAX_SPEED_MISFIT_LEFT * (1 - c_zero)):
        return False
    # a half that cannot be timed (too short, or its profiles do not correlate: a parked or cruising stretch) is no
    # evidence either way; one that can must find the same shift (the real drives' halves agree to 0.01-0.02 s)
    return all(h is None or h[1] < MIN_SPEED_CORR or abs(h[0] - s) <= max(0.1, 0.3 * abs(s)) for h in halves)


def held_speed_shift(t_est_s, p_est_m, t_ref_s, p_ref_m) -> tuple[float, float, float] | None:
    """:func:`speed_clock_shift`'s result where it is a clock offset to report (:func:`clear_speed_shift`, the
    halves asked only then), else None."""
    found = speed_clock_shift(t_est_s, p_est_m, t_ref_s, p_ref_m)
    if not clear_speed_shift(found):
        return None
    return found if clear_speed_shift(found, speed_shift_halves(t_est_s, p_est_m, t_ref_s, p_ref_m)) else None


def speed_shift_halves(t_est_s, p_est_m, t_ref_s, p_ref_m) -> tuple:
    """:func:`speed_clock_shift` on each half of the estimate (None for a half too short to time)."""
    t, p = np.asarray(t_est_s, float), np.asarray(p_est_m, float)
    n = t.size // 2
    return tuple(speed_clock_shift(t[a:b], p[a:b], t_ref_s, p_ref_m) for a, b in ((0, n), (n, t.size)))


def _speed_on(grid: np.ndarray, t_s: np.ndarray, p_m: np.ndarray, smooth_s: float) -> np.ndarray:
    """Speed from position differences (strictly increasing stamps only), on a uniform ``grid``, smoothed."""
    keep = np.concatenate([[True], np.diff(t_s) > 0])
    t_s, p_m = t_s[keep], p_m[keep]
    v = np.linalg.norm(np.diff(p_m, axis=0), axis=1) / np.diff(t_s)
    s = np.interp(grid, 0.5 * (t_s[1:] + t_s[:-1]), v)
    k = max(1, int(round(smooth_s / (grid[1] - grid[0]))))
    return np.convolve(s, np.ones(k) / k, mode="same")


def speed_clock_shift(t_est_s, p_est_m, t_ref_s, p_ref_m, max_points: int = 20_000) -> tuple[float, float, float] | None:
    """The time shift ``s`` that best lines up an estimate's speed profile with a reference's (the estimate's stamp
    ``t`` is the reference's ``t - s``: positive, stamped late), with the correlation there and at 0; None where they
    overlap by under 20 s. Speed is the same in every frame and under any drift of position or heading, and its
    correlation under any scale: what a drifting odometry or a monocular SLAM estimate still shares with its
    reference (their positions, which a run's :func:`clock_shift` compares, do not: a lidar odometry 1 s late kept
    its 7 m of drift at every shift). Searched over +/- :data:`MAX_SPEED_SHIFT_S` by 0.05 s, then to 0.01 s; each
    profile is made once (at most ``max_points`` samples) and shifted by interpolation."""
    t_e, t_r = np.asarray(t_est_s, float), np.asarray(t_ref_s, float)
    if t_e.size < 20 or t_r.size < 20:
        return None
    a, b = max(t_e[0], t_r[0]) + MAX_SPEED_SHIFT_S + 0.5, min(t_e[-1], t_r[-1]) - MAX_SPEED_SHIFT_S - 0.5
    if not b - a >= 20.0:
        return None
    grid = np.linspace(a, b, int(min(max_points, (b - a) / 0.05)) + 1)
    step = grid[1] - grid[0]
    v_r = _speed_on(grid, t_r, np.asarray(p_ref_m, float), 0.5)
    own = np.arange(a - MAX_SPEED_SHIFT_S - 0.2, b + MAX_SPEED_SHIFT_S + 0.2, step)
    v_e = _speed_on(own, t_e, np.asarray(p_est_m, float), 0.5)
    if not (np.std(v_r) > 0 and np.std(v_e) > 0):
        return None

    def corr(shifts):
        return np.array([np.corrcoef(np.interp(grid + s, own, v_e), v_r)[0, 1] for s in shifts])

    coarse = np.round(np.arange(-MAX_SPEED_SHIFT_S, MAX_SPEED_SHIFT_S + 1e-9, 0.05), 2)
    c = corr(coarse)
    fine = coarse[int(np.argmax(c))] + np.round(np.arange(-0.05, 0.05 + 1e-9, 0.01), 2)
    cf = corr(fine)
    i = int(np.argmax(cf))
    return float(fine[i]), float(cf[i]), float(corr([0.0])[0])


def speed_clock_warning(name: str, series, groundtruth, offset_key: str = "", offset_s: float = 0.0) -> str:
    """Why a pose stream (the lidar odometry) runs at another time than the ground truth, by their speed profiles
    (:func:`speed_clock_shift`), or ''. What a position comparison misses under drift: a lidar 0.2 s early gave a
    fused 1.45 m for 0.69, with no word (a corrupted-input review). (The fused estimate cannot time the IMU so: it
    moves with the lidar and the GNSS that aid it, and took a lidar's offset for the IMU's.) Said where :func:`clear_speed_shift`; ``offset_key``, ``offset_s``: the offset the stream
    was given, for the value that fits."""
    if series is None or groundtruth is None or len(series) < 20 or len(groundtruth) < 20:
        return ""
    real = _real(series)
    found = held_speed_shift(np.asarray(series.t_s)[real], np.asarray(series.p_w_m)[real], groundtruth.t_s,
                             groundtruth.p_w_m)
    if found is None:
        return ""
    s, c_best, c_zero = found
    fix = f" ({offset_key} {offset_s - s:.3f} s fits, for the {offset_s:.3f} s given)" if offset_key else ""
    # s > 0: stamped late, its sample stamped t is the truth's at t - s (clock_shift's words for the same case)
    return (f"{name} ({series.source}) moves like the ground truth {abs(s):.2f} s {'earlier' if s > 0 else 'later'} than "
            f"stamped (correlation of their speeds {c_best:.4f} there, {c_zero:.4f} as stamped): a clock offset between "
            f"{name} and the ground truth{fix}, or in the ground truth's own stamps; every figure carries it")


def clock_shift(name: str, series, groundtruth, offset_key: str = "", offset_s: float = 0.0,
                max_points: int = 1000) -> str:
    """Why a stream's positions (GNSS fixes, the lidar odometry anchored on the ground truth) match the ground truth
    best at another time than their stamps say, or ''. A GNSS 1 s late gave 5.99 m for 0.84 (its NIS mean 28.5 for 3
    dof, no warning) and a ground truth 1 s late 9.86 m for 0.69; an 18 s offset (GPS against UNIX time) was blamed
    on units and frames. Searched over +/- MAX_CLOCK_SHIFT_S on at most ``max_points`` positions (coarse, then to
    10 ms); said when the best shift is over MIN_CLOCK_SHIFT_S and leaves at most MAX_CLOCK_FIT of the RMS position
    difference, MIN_CLOCK_GAIN_M less, over the same points. ``offset_key``, ``offset_s``: the time offset the stream
    was given, so that the message can say which value fits."""
    if series is None or groundtruth is None or len(series) < 10 or len(groundtruth) < 2:
        return ""
    t_gt, p_gt = np.asarray(groundtruth.t_s), np.asarray(groundtruth.p_w_m)
    real = _real(series)
    t, p = np.asarray(series.t_s)[real], np.asarray(series.p_w_m)[real]
    inside = (t >= t_gt[0]) & (t <= t_gt[-1])
    if inside.sum() < 10 or np.any(np.diff(t_gt) <= 0):
        return ""
    t, p = t[inside], p[inside]
    if t.size > max_points:
        k = np.linspace(0, t.size - 1, max_points).round().astype(int)
        t, p = t[k], p[k]
    e0 = np.linalg.norm(p - np.column_stack([np.interp(t, t_gt, p_gt[:, a]) for a in range(3)]), axis=1)
    coarse = np.arange(-MAX_CLOCK_SHIFT_S, MAX_CLOCK_SHIFT_S + 1e-9, 0.25)
    rms, _ = _rms_at_shifts(t, p, t_gt, p_gt, coarse, e0)
    if not np.isfinite(rms).any():
        return ""
    fine = coarse[_best(coarse, rms)] + np.arange(-0.25, 0.25 + 1e-9, 0.01)
    fine = fine[np.abs(fine) <= MAX_CLOCK_SHIFT_S + 1e-9]
    rms_fine, rms0_fine = _rms_at_shifts(t, p, t_gt, p_gt, fine, e0)
    if not np.isfinite(rms_fine).any():
        return ""
    i = _best(fine, rms_fine)
    best, at_best, at_zero = float(fine[i]), float(rms_fine[i]), float(rms0_fine[i])
    if abs(best) < MIN_CLOCK_SHIFT_S or not (at_best <= MAX_CLOCK_FIT * at_zero and at_zero - at_best >= MIN_CLOCK_GAIN_M):
        return ""
    fix = f" ({offset_key} {best:+.2f} s fits: {offset_s + best:.3f} s for the {offset_s:.3f} s given)" if offset_key else ""
    return (f"{name} ({series.source}) matches the ground truth best {abs(best):.2f} s {'later' if best > 0 else 'earlier'} "
            f"than stamped (RMS position difference {at_best:.2f} m there, {at_zero:.2f} m as stamped): a clock offset "
            f"between {name} and the ground truth{fix}, or in the ground truth's own stamps; every figure carries it")


# a GNSS latency: the least-squares shift of the fixes along the truth's velocity, said beyond this many seconds and
# this many standard errors (measured: KITTI's fixes, the truth itself, 0; the degraded ones 0.00 +/- 0.01 s)
MIN_LATENCY_S, MIN_LATENCY_SIGMAS, MIN_LATENCY_SPEED_MPS = 0.05, 6.0, 2.0


# an antenna this far ahead of or behind the truth's point along the track, beyond MIN_LATENCY_SIGMAS standard errors,
# is said where the speed's variation tells it from a latency
MIN_ANTENNA_M = 0.5
LATENCY_BLOCKS = 10          # not a state index: stretches of the drive of the latency's jackknife
# the two regressors (-v, the latency's, and u, an antenna's along the track) this close to parallel (the cosine of
# their angle, mean over RMS speed): a drive at one speed, where the data cannot tell them apart
MAX_SEPARABLE_COSINE = 0.995


def gnss_latency(gnss, groundtruth, offset_s: float = 0.0, lever_b_m=None) -> str:
    """Why the GNSS fixes lag (or lead) the ground truth by a fraction of a second, or sit ahead of or behind its point
    along the track, or '': below what :func:`clock_shift` can see against the fixes' noise (a receiver stamping its
    fixes 0.2 s late, at receive time, gave 1.50 m for 0.54 with no word; a conventions review). Each fix's error
    against the truth at its stamp (the configured antenna ``lever_b_m`` taken off) is ``-v d`` for a latency ``d``
    (``v`` the truth's velocity there), ``a u`` for an antenna ``a`` metres along the direction of travel ``u``, and a
    constant: by least squares over the moving fixes. Where the speed varies enough to separate them, each is said
    beyond its bound (:data:`MIN_LATENCY_S`, :data:`MIN_ANTENNA_M`) and :data:`MIN_LATENCY_SIGMAS` standard errors;
    at one speed the latency-only fit is said, naming the antenna as the other reading."""
    found = _fixes_on_truth(gnss, groundtruth, lever_b_m, stamps=True)      # the antenna the filter is told of, off
    if found is None:
        return ""
    g, r, t = found
    t_gt, p_gt = np.asarray(groundtruth.t_s), np.asarray(groundtruth.p_w_m)
    h = 0.05
    v = np.column_stack([(np.interp(t + h, t_gt, p_gt[:, a]) - np.interp(t - h, t_gt, p_gt[:, a])) / (2 * h)
                         for a in range(3)])
    speed = np.linalg.norm(v, axis=1)
    moving = speed > MIN_LATENCY_SPEED_MPS
    if moving.sum() < 30:
        return ""
    e, v, sp = (g - r)[moving], v[moving], speed[moving]
    if np.linalg.norm(v.std(axis=0)) < 0.1 * np.linalg.norm(v.mean(axis=0)):
        return ""            # one velocity throughout: -v d is a constant offset, gnss_offset's to say (a review)
    u = v / sp[:, None]
    n = e.shape[0]

    # contiguous stretches of time, each fix's three rows in its stretch
    rows = np.repeat(np.minimum((np.arange(n) * LATENCY_BLOCKS) // n, LATENCY_BLOCKS - 1), 3)

    def fit(columns):
        """Least squares of e on the columns and a constant: (coef, std) of each. The std is the larger of the white
        residuals' and a block jackknife's over stretches of the drive: a GNSS jump of 8 m for 40 s, an error
        correlated over its fixes, was read as an antenna 7.7 m ahead, and two jumps as a 0.18 s latency whose
        correction made the GNSS worse (a review)."""
        X = np.zeros((3 * n, len(columns) + 3))
        for j, c in enumerate(columns):
            X[:, j] = c.ravel()
        for a in range(3):
            X[a::3, len(columns) + a] = 1.0
        y = e.ravel()
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        res = y - X @ coef
        try:
            var = float(res @ res) / max(3 * n - X.shape[1], 1) * np.diag(np.linalg.inv(X.T @ X))
        except np.linalg.LinAlgError:
            return coef, np.full(coef.size, np.inf)
        loo = np.array([np.linalg.lstsq(X[rows != b], y[rows != b], rcond=None)[0] for b in range(LATENCY_BLOCKS)])
        jk = (LATENCY_BLOCKS - 1) / LATENCY_BLOCKS * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0)
        return coef, np.sqrt(np.maximum(np.maximum(var, jk), 0.0))

    def said(x, sx, bound):
        return abs(x) >= bound and abs(x) >= MIN_LATENCY_SIGMAS * sx

    separable = float(np.mean(sp) / np.sqrt(np.mean(sp ** 2))) < MAX_SEPARABLE_COSINE
    latency = antenna = False
    if separable:
        (d, a, *_), (sd, sa, *_) = fit([-v, u])
        latency, antenna = said(d, sd, MIN_LATENCY_S), said(a, sa, MIN_ANTENNA_M)
    if not (latency or antenna):
        # one speed, or too little of its variation to attribute the shift: the latency-only fit, both readings named
        (d, *_), (sd, *_) = fit([-v])
        if not said(d, sd, MIN_LATENCY_S):
            return ""
        separable = False
        latency = True
    fix = f"gnss.time_offset_s {-d:+.3f} s fits: {offset_s - d:.3f} s for the {offset_s:.3f} s given"
    where = lambda x: f"{abs(x):.2f} m {'ahead of' if x > 0 else 'behind'} the truth's point along the vehicle"  # noqa: E731
    if latency and not separable:
        along = -d * float(np.median(sp))
        return (f"{gnss.source}: the GNSS fixes match the ground truth {abs(d):.3f} +/- {sd:.3f} s "
                f"{'earlier' if d > 0 else 'later'} than stamped (their errors along the velocity, over {n} moving "
                f"fixes): a latency ({fix}), or an antenna {where(along)} not given in gnss.lever_arm_b_m; the drive's "
                "speed varies too little to tell the two apart")
    parts = []
    if latency:
        parts.append(f"they match it {abs(d):.3f} +/- {sd:.3f} s {'earlier' if d > 0 else 'later'} than stamped: a "
                     f"latency, such as fixes stamped when received rather than when measured ({fix})")
    if antenna:
        parts.append(f"they sit {where(a)} (+/- {sa:.2f} m), whatever the speed: an antenna offset not given in "
                     "gnss.lever_arm_b_m")
    return (f"{gnss.source}: the GNSS fixes' errors along the velocity, over {n} moving fixes, against the ground "
            f"truth: {'; '.join(parts)}; every fix is pulled along the track")


# a lidar odometry given in the ground truth's frame (``anchor: none``) starts within these of the truth's pose
MAX_UNANCHORED_DEG, MAX_UNANCHORED_M = 30.0, 20.0


def unanchored_lidar(lidar, groundtruth) -> str:
    """Why lidar poses declared to be in the ground truth's frame (the manifest's ``anchor: none``) are not, or '':
    their first pose inside the truth's span lies more than MAX_UNANCHORED_DEG or MAX_UNANCHORED_M from the truth's
    pose then. An odometry in its own frame so declared scored 231.6 m / 92 deg and "fusion is 99.8 % better than
    the lidar", with no word."""
    from ..interp import interpolate_pose_at

    t_gt = np.asarray(groundtruth.t_s)
    inside = np.flatnonzero((lidar.t_s >= t_gt[0]) & (lidar.t_s <= t_gt[-1]))
    if inside.size == 0 or len(groundtruth) < 2:
        return ""
    a = int(inside[0])
    p_gt, R_gt, _ = interpolate_pose_at(groundtruth, float(lidar.t_s[a]))
    R = lidar.R_wb()[a]
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R_gt.T @ R) - 1.0) / 2.0, -1.0, 1.0))))
    dist = float(np.linalg.norm(lidar.p_w_m[a] - p_gt))
    if angle <= MAX_UNANCHORED_DEG and dist <= MAX_UNANCHORED_M:
        return ""
    return (f"the lidar poses ({lidar.source}) are declared in the ground truth's frame (anchor: none), but their first "
            f"pose lies {angle:.0f} deg and {dist:.1f} m from the ground truth's at that time: the odometry's own frame? "
            "Every figure of 'lidar' compares frames; anchor: groundtruth expresses them in the truth's frame")


MAX_TILT_DEG = 30.0       # the specific force's angle from up at the start: a car's acceleration tilts it by under 20 deg


def gravity_against_attitude(imu, k0: int, R_wb0: np.ndarray, window_s: float = 1.0) -> str:
    """Why the IMU's specific force at the start disagrees with the initial attitude (from the ground truth or the
    lidar), or ''. Over the stillest second of the first ten it points up, give or take the vehicle's acceleration;
    pointing elsewhere
    in the attitude the filter starts with, the IMU and that attitude are in different frames (an IMU mounted upside
    down or rotated without its extrinsic, a ground truth in NED), and the filter diverges or drifts with a hint at
    its noise."""
    t = np.asarray(imu.t_s)
    k1 = int(np.searchsorted(t, t[k0] + window_s))
    if k1 - k0 < 2:
        return ""
    # the stillest second of the first ten: the one whose mean specific force is nearest gravity's size (an
    # acceleration adds to it in quadrature) with the least spread; a drone mid-manoeuvre or a car braking hard at
    # the start tilts the first second's mean by more than the bound
    k_end = int(np.searchsorted(t, t[k0] + 10.0))
    n = k1 - k0
    f_all = np.asarray(imu.f_b_mps2[k0:max(k_end, k1)], float)
    if f_all.shape[0] > n:
        mean = moving_mean(f_all, n)
        spread = moving_mean(np.sum(f_all ** 2, axis=1), n) - np.sum(mean ** 2, axis=1)
        g = float(np.nanmedian(np.linalg.norm(f_all, axis=1)))
        score = (np.linalg.norm(mean, axis=1) - g) ** 2 + spread
        f = mean[int(np.nanargmin(score))] if np.isfinite(score).any() else mean[0]
    else:
        f = f_all.mean(axis=0)
    up = np.asarray(R_wb0) @ f
    n = float(np.linalg.norm(up))
    if not n > 1.0:                                    # gravity-free data: imu_units says so
        return ""
    tilt = float(np.degrees(np.arccos(np.clip(up[2] / n, -1.0, 1.0))))
    if tilt <= MAX_TILT_DEG:
        return ""
    return (f"{imu.source}: at the start the IMU's specific force points {tilt:.0f} deg from up in the initial "
            "attitude (the ground truth's or the lidar's, z up): the IMU and that attitude are in different frames (an "
            "IMU mounted rotated or upside down without its extrinsic, a ground truth in NED rather than ENU)")


PLACEHOLDER_PATH_M = 10.0    # a truth that travels this far with one orientation on every pose holds placeholders


def truth_orientation_placeholder(gt) -> str | None:
    """Why the ground truth's orientations are placeholders (one and the same quaternion on every pose while it travels
    over :data:`PLACEHOLDER_PATH_M`: an RTK or GNSS truth written with identity quaternions), or None. Its rotation APE,
    RPE and attitude NEES are then about the placeholder: 113.7 deg and an RPE 1 frame of 0.134 m against 0.019 m with
    the real truth, with no word (a corrupted-input review)."""
    q = np.asarray(gt.q_wb_xyzw, float)
    if len(q) < 2 or not np.all(q == q[0]):
        return None
    p = np.asarray(gt.p_w_m, float)
    path = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
    if not path > PLACEHOLDER_PATH_M:
        return None
    # a straight drive keeps one orientation for real: only a path that leaves its line (its second principal spread
    # over a metre and 1 % of its length) says the orientations are placeholders (a simulated straight, flat 30 s drive
    # was told its truth was a placeholder: a corrupted-input review)
    spread = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    if not (spread.size > 1 and spread[1] / np.sqrt(len(p)) > max(1.0, 0.01 * path)):
        return None
    return (f"{gt.source}: the ground truth has one and the same orientation on every pose over {path:.0f} m of travel "
            "(placeholders: a position-only truth): its rotation APE, relative (RPE) and attitude NEES figures measure "
            "the placeholder, not the estimates; only the translation APE means anything")


# The gyro's turning against the ground truth's: the 90th percentiles of their angular rate magnitudes (robust to a
# clock offset and to straight stretches), each over RATE_BASELINE_S (a motion-capture truth at 100 Hz with 0.01 deg
# of jitter differenced sample to sample 'turned' at 0.06 rad/s standing still: a review), compared where the truth
# turns at all. A gyro in rad/s declared deg/s reads 57x too slow, which no bound on the rates catches (a car turning
# at 0.009 rad/s is plausible): fused APE 112.9 m, 90.9 deg, exit 0 (a user's review). A factor beyond 3 either way is
# a unit, not a scale-factor error.
MIN_TRUTH_TURN_RPS, MAX_GYRO_SCALE, RATE_BASELINE_S = 0.05, 3.0, 0.2


def _stride(t: np.ndarray, baseline_s: float) -> int:
    """Samples per ``baseline_s`` at the median step of ``t`` (at least one)."""
    return max(1, int(np.ceil(baseline_s / max(float(np.median(np.diff(t))), 1e-9))))


def _rows_at(tq: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Each column of ``x`` (sampled at ``t``) linearly interpolated at ``tq`` (any shape), stacked last."""
    return np.stack([np.interp(tq, t, x[:, a]) for a in range(x.shape[1])], axis=-1)


def _gyro_turned(ti: np.ndarray, w: np.ndarray, ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
    """The gyro's rotation vector over each interval ``[ta, tb]`` (n, 3): its rates integrated (trapezoid), the
    cumulative integral interpolated at the ends (for turns of a few degrees, the rotation itself)."""
    cum = np.vstack([np.zeros((1, w.shape[1])), np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(ti)[:, None], axis=0)])
    return _rows_at(tb, ti, cum) - _rows_at(ta, ti, cum)


def gyro_scale(imu, gt) -> str:
    """Why the gyro turns a constant factor faster or slower than the ground truth (a unit), or ''. Both are taken
    over the same intervals of :data:`RATE_BASELINE_S`, those the IMU covers without a gap (a 5 s gap over the
    drive's one turn left the gyro 'turning' 0.13x the truth)."""
    if gt is None or len(gt) < 20 or len(imu.t_s) < 100 or truth_orientation_placeholder(gt):
        return ""
    t = np.asarray(gt.t_s, float)
    ti = np.asarray(imu.t_s, float)
    if np.any(np.diff(t) <= 0) or np.any(np.diff(ti) <= 0):
        return ""
    k = _stride(t, RATE_BASELINE_S)
    if t.size <= k + 10:
        return ""
    ta, tb = t[:-k], t[k:]
    # the intervals inside the IMU's span with no IMU gap in them (a gap: over 3 median steps)
    dti = np.diff(ti)
    gaps = np.flatnonzero(dti > 3.0 * float(np.median(dti)))
    ok = (ta >= ti[0]) & (tb <= ti[-1])
    for g in gaps:
        ok &= (tb <= ti[g]) | (ta >= ti[g + 1])
    if ok.sum() < 50:
        return ""
    R = gt.R_wb()
    cos = (np.einsum("nji,nji->n", R[:-k][ok], R[k:][ok]) - 1.0) / 2.0    # trace(R_a^T R_b) = 1 + 2 cos(angle)
    dt = (tb - ta)[ok]
    truth_rate = np.arccos(np.clip(cos, -1.0, 1.0)) / dt
    truth = float(np.percentile(truth_rate, 90))
    if not truth > MIN_TRUTH_TURN_RPS:
        return ""
    turned = _gyro_turned(ti, np.asarray(imu.w_b_rps, float), ta[ok], tb[ok])
    gyro = float(np.percentile(np.linalg.norm(turned, axis=1) / dt, 90))
    ratio = gyro / truth
    if 1.0 / MAX_GYRO_SCALE <= ratio <= MAX_GYRO_SCALE:
        return ""
    hint = ("rad/s declared as deg/s? (a CSV stream's gyro_unit)" if 1 / 80 < ratio < 1 / 40 else
            "deg/s read as rad/s? (a CSV stream's gyro_unit)" if 40 < ratio < 80 else "another unit?")
    return (f"{imu.source}: the gyro turns {ratio:.3g}x as fast as the ground truth ({gyro:.3g} against {truth:.3g} "
            f"rad/s, 90th percentiles of the rate over {RATE_BASELINE_S:g} s): {hint} Every figure of the filter rests "
            "on the gyro")


# The odometer's speed against the ground truth's, as the gyro's rate above: a factor beyond 1.5 either way is a unit
# (km/h read as m/s: 3.6x; mph: 2.24x), not a wheel's scale error (a few percent). Such an odometer made the filter
# diverge with a hint at the process noise (a user's review).
MIN_TRUTH_SPEED_MPS, MAX_ODOMETER_SCALE = 1.0, 1.5
_SPEED_UNITS = ((3.6, "km/h read as m/s"), (2.237, "mph read as m/s"), (1 / 3.6, "m/s read as km/h"))


def odometer_scale(odo, gt) -> str:
    """Why the odometer's speed is a constant factor off the ground truth's (a unit), or ''."""
    if odo is None or gt is None or len(gt) < 20 or len(odo.t_s) < 20:
        return ""
    t, p = np.asarray(gt.t_s, float), np.asarray(gt.p_w_m, float)
    dt = np.diff(t)
    ok = dt > 0
    truth = float(np.percentile(np.linalg.norm(np.diff(p, axis=0)[ok], axis=1) / dt[ok], 90))
    inside = (odo.t_s >= t[0]) & (odo.t_s <= t[-1])
    if not truth > MIN_TRUTH_SPEED_MPS or inside.sum() < 20:
        return ""
    v = np.asarray(odo.v_mps, float)[inside]
    # the opposite sign to the truth's velocity along its body's x axis nearly all the time it moves: a sign (a
    # flipped odometer made the filter diverge blaming km/h and g; a conventions review). Along the body's axis, not
    # the speed: a drive whose IMU x points backwards reads a negative speed rightly (a review). A truth whose
    # orientation never changes (placeholders) says nothing of its axes.
    q = np.asarray(gt.q_wb_xyzw, float)
    if not np.all(q == q[0]):
        ts = odo.t_s[inside]
        k = np.clip(np.searchsorted(t, ts), 1, t.size - 1)
        vel = (p[k] - p[k - 1]) / np.where(t[k] - t[k - 1] > 0, t[k] - t[k - 1], np.inf)[:, None]
        vx = np.einsum("nji,nj->ni", gt.R_wb()[k], vel)[:, 0]           # the truth's velocity along its body's x
        moving = np.abs(vx) > MIN_TRUTH_SPEED_MPS
        opposite = np.sign(v[moving]) == -np.sign(vx[moving])
        if moving.sum() >= 20 and np.mean(opposite) > 0.8:
            return (f"{odo.source}: the odometer's sign is opposite to the ground truth's velocity along its body's x "
                    f"axis ({np.mean(opposite):.0%} of {int(moving.sum())} moving samples; median {np.median(v[moving]):.3g} "
                    "m/s): its sign reversed (a wheel's axis or a driver's convention); where the odometer is fused, the "
                    "filter takes it as the speed along the IMU's x axis")
    ratio = float(np.percentile(np.abs(v), 90)) / truth
    if 1.0 / MAX_ODOMETER_SCALE <= ratio <= MAX_ODOMETER_SCALE:
        return ""
    unit = next((u for f, u in _SPEED_UNITS if abs(ratio / f - 1.0) < 0.1), "another unit?")
    return (f"{odo.source}: the odometer's speed is {ratio:.3g}x the ground truth's (90th percentiles: "
            f"{ratio * truth:.3g} against {truth:.3g} m/s): {unit}; the filter needs m/s")


# A car's body moves along one axis: its pose stream's displacement over ~0.5 s, turned into the body frame by the
# stream's own orientation, points the same way at every speed worth reading (the direction's mean resultant length:
# 0.995-0.998 on the KITTI poses, lidar and truth, in the camera's frame or the IMU's). Orientations read in the wrong
# quaternion order, or the poses inverted (the world's in the body), turn that direction with the heading: 0.05-0.25
# on the KITTI drives, 0.55 for kitti-00's truth in the IMU's frame read in the other order. A reading that
# concentrates it where the stream as read does not names itself (a wrong reading's best: 0.91); a platform that moves
# every way (a drone, a hand-held camera) concentrates under no reading, and is not said; a car that reverses a fifth
# of the time is, as read, dispersed, but no other reading concentrates it either.
READING_STEP_S, READING_MIN_SPEED_MPS, READING_MIN_STEPS = 0.5, 2.0, 20
READING_DISPERSED, READING_CONCENTRATED = 0.8, 0.95


def _forward_concentration(t: np.ndarray, p: np.ndarray, R: np.ndarray) -> float | None:
    """The mean resultant length of the body-frame direction of motion over ~:data:`READING_STEP_S` (None where
    fewer than :data:`READING_MIN_STEPS` steps are faster than :data:`READING_MIN_SPEED_MPS`)."""
    dt = np.diff(t)
    if t.size < 3 or not np.all(dt > 0):
        return None
    s = max(1, int(round(READING_STEP_S / float(np.median(dt)))))
    if t.size <= s:
        return None
    dp = p[s:] - p[:-s]
    d = np.linalg.norm(dp, axis=1)
    moving = np.isfinite(d) & (d > READING_MIN_SPEED_MPS * (t[s:] - t[:-s]))
    if moving.sum() < READING_MIN_STEPS:
        return None
    v_b = np.einsum("nji,nj->ni", R[:-s][moving], dp[moving])
    u = v_b / np.maximum(np.linalg.norm(v_b, axis=1, keepdims=True), 1e-300)
    return float(np.linalg.norm(u.mean(axis=0)))


def pose_reading(name: str, poses, quaternion: str | None) -> str:
    """Why a pose stream's orientations look misread, or '': its body-frame direction of motion spread over every
    heading as read, and concentrated with the quaternions in the other order (``quaternion``: the order its format
    writes, 'xyzw' or 'wxyz'; None for matrices and named fields) or with the poses inverted. A lidar TUM written
    w x y z ran to a fused 5.47 m against 0.65 with a 'mount disagrees by 40-52 mrad' warning, a ground truth's
    to 47 m blaming the IMU (an implausible-data review)."""
    from ..so3 import quat_xyzw_to_matrix

    if poses is None or len(poses) < READING_MIN_STEPS:
        return ""
    real = _real(poses)
    t, p, q = (np.asarray(x, float)[real] for x in (poses.t_s, poses.p_w_m, poses.q_wb_xyzw))
    R = quat_xyzw_to_matrix(q)
    as_read = _forward_concentration(t, p, R)
    if as_read is None or as_read >= READING_DISPERSED:
        return ""
    readings = {}
    if quaternion in ("xyzw", "wxyz"):
        # a file written w x y z read as x y z w holds (w, x, y, z) in our (x, y, z, w); the other way round likewise
        other, fix = ("w x y z", [1, 2, 3, 0]) if quaternion == "xyzw" else ("x y z w", [3, 0, 1, 2])
        readings[f"quaternions written {other} where the format reads {' '.join(quaternion)}"] = \
            (p, quat_xyzw_to_matrix(q[:, fix]))
    Ri = np.transpose(R, (0, 2, 1))
    readings["poses inverted: each the world's in the sensor frame (T_sensor_world, a view matrix or a transform "
             "looked up the other way round), where the stream wants the sensor's in the world"] = \
        (-np.einsum("nij,nj->ni", Ri, p), Ri)
    score = {k: _forward_concentration(t, pp, RR) for k, (pp, RR) in readings.items()}
    best = max((k for k in score if score[k] is not None), key=lambda k: score[k], default=None)
    if best is None or score[best] < READING_CONCENTRATED:
        return ""
    return (f"{name} ({poses.source}): its body-frame direction of motion turns with the heading as read (mean "
            f"resultant length {as_read:.2f}; a vehicle's stays along one axis, 0.99 and more) and keeps to one axis "
            f"({score[best]:.3f}) with its {best}; every figure that uses its orientations is wrong until they are read so")


# A pose stream's displacement over windows of this long against a reference's over the same times (where the reference
# moves at least the minimum): a lidar odometry's scale is the truth's to a few percent (kitti-00 and the four SiMpLE
# drives: 1.00 to 0.5 % against the truth and against the receiver's fixes), so beyond this factor its positions are
# in another unit (cm read as m: 100x) or have no scale (a monocular visual odometry's).
SCALE_WINDOW_S, SCALE_MIN_MOVE_M, SCALE_MIN_WINDOWS, MAX_POSE_SCALE = 10.0, 20.0, 5, 1.5
_LENGTH_UNITS = ((10.0, "decimetres read as metres?"), (100.0, "centimetres read as metres?"),
                 (1000.0, "millimetres read as metres?"), (0.001, "kilometres read as metres?"),
                 (0.3048, "feet read as metres?"), (1 / 0.3048, "metres read as feet?"))


def pose_scale(name: str, poses, refs: dict) -> str:
    """Why a pose stream's displacements are a constant factor off a reference's (``refs``: a description -> a series
    with positions, the first usable taken), or '': the median ratio over :data:`SCALE_WINDOW_S` windows beyond
    :data:`MAX_POSE_SCALE` either way. A lidar's positions 10x and 100x ran to 2.57 and 1.01 m (0.65 unscaled), said
    only as 'steps faster than 100 m/s: a glitch', the adaptive noise hiding the rest (an implausible-data review)."""
    if poses is None or len(poses) < 10:
        return ""
    real = _real(poses)
    t, p = np.asarray(poses.t_s, float)[real], np.asarray(poses.p_w_m, float)[real]
    for what, ref in refs.items():
        if ref is None or len(ref) < 10:
            continue
        keep = _real(ref)
        tr, pr = np.asarray(ref.t_s, float)[keep], np.asarray(ref.p_w_m, float)[keep]
        if tr.size < 10 or np.any(np.diff(tr) <= 0):
            continue
        a = np.arange(max(t[0], tr[0]), min(t[-1], tr[-1]) - SCALE_WINDOW_S, SCALE_WINDOW_S)
        if a.size < SCALE_MIN_WINDOWS:
            continue
        b = a + SCALE_WINDOW_S
        d_own = np.linalg.norm(_rows_at(b, t, p) - _rows_at(a, t, p), axis=1)
        d_ref = np.linalg.norm(_rows_at(b, tr, pr) - _rows_at(a, tr, pr), axis=1)
        moving = d_ref > SCALE_MIN_MOVE_M
        if moving.sum() < SCALE_MIN_WINDOWS:
            continue
        ratio = float(np.median(d_own[moving] / d_ref[moving]))
        if 1.0 / MAX_POSE_SCALE <= ratio <= MAX_POSE_SCALE:
            return ""
        unit = next((u for f, u in _LENGTH_UNITS if abs(ratio / f - 1.0) < 0.1),
                    "no scale of its own (a monocular visual odometry's) or another unit?")
        return (f"{name} ({poses.source}): its positions move {ratio:.3g}x as far as the {what}'s over the same "
                f"{SCALE_WINDOW_S:g} s windows (median of {int(moving.sum())}): {unit} The filter takes them as metres")
    return ""


# A gyro that turns the other way about up than the platform's poses: one axis's sign flipped (a left-handed IMU
# frame), or a frame whose gyro and accelerometer disagree. Up is the accelerometer's mean direction (a ground
# vehicle's mean specific force is gravity's reaction); the poses' turns over the same 0.5 s intervals, in their body
# frame (the IMU's), along it. Said where the two turn opposite ways on more than this share of the intervals where
# the poses turn faster than MIN_TRUTH_TURN_RPS (the KITTI drives: none; a gyro z of the wrong sign: all).
OPPOSITE_TURN_SHARE, TURN_BASELINE_S, MIN_TURN_INTERVALS = 0.8, 0.5, 30


def gyro_turns_backwards(imu, poses) -> str:
    """Why the gyro's rate about up has the opposite sign to the poses' (``poses``: the ground truth, whose world is
    z-up), or ''. A gyro z of the wrong sign ran to 18.5 m against 0.62, its first warning blaming the lidar's clock
    by 49 ms (an implausible-data review). Only where the accelerometer's up agrees with the poses' (their world z in
    their body frame): an IMU mounted otherwise than the poses' body (FRD against FLU) turns the other way too, and
    is said by its own check (:func:`gravity_against_attitude`)."""
    from ..so3 import log_so3

    if poses is None or len(poses) < 20 or len(imu.t_s) < 100 or truth_orientation_placeholder(poses):
        return ""
    keep = _real(poses)
    t, R = np.asarray(poses.t_s, float)[keep], np.asarray(poses.R_wb())[keep]
    ti, f = np.asarray(imu.t_s, float), np.asarray(imu.f_b_mps2, float)
    if t.size < 20 or np.any(np.diff(t) <= 0) or np.any(np.diff(ti) <= 0):
        return ""
    up = np.median(f, axis=0)
    if not np.linalg.norm(up) > 5.0:                    # no gravity to tell up by (units: said by their own checks)
        return ""
    up = up / np.linalg.norm(up)
    if float(np.median(R[:, 2, :] @ up)) < np.cos(np.radians(45.0)):    # R_wb^T e_z: the poses' up in their body
        return ""
    k = _stride(t, TURN_BASELINE_S)
    if t.size <= k + MIN_TURN_INTERVALS:
        return ""
    ta, tb = t[:-k], t[k:]
    inside = (ta >= ti[0]) & (tb <= ti[-1])
    dt = tb - ta
    turn = log_so3(np.einsum("nji,njk->nik", R[:-k], R[k:])) @ up / dt           # the poses' body-frame rate about up
    gyro = _gyro_turned(ti, np.asarray(imu.w_b_rps, float), ta, tb) @ up / dt
    turning = inside & (np.abs(turn) > MIN_TRUTH_TURN_RPS) & (np.abs(gyro) > MIN_TRUTH_TURN_RPS)
    if turning.sum() < MIN_TURN_INTERVALS:
        return ""
    opposite = float(np.mean(np.sign(turn[turning]) != np.sign(gyro[turning])))
    if opposite <= OPPOSITE_TURN_SHARE:
        return ""
    return (f"{imu.source}: the gyro turns the other way about up than the ground truth ({poses.source}) on "
            f"{opposite:.0%} of the "
            f"{int(turning.sum())} intervals where both turn (up: the accelerometer's mean direction, body axes "
            f"{up[0]:+.2f}, {up[1]:+.2f}, {up[2]:+.2f}): the gyro's axis along up of the wrong sign (a left-handed "
            "frame), or a gyro and an accelerometer in different frames; the filter integrates the turns backwards")


# The IMU's span this much shorter than other streams' that start with it: its stamps compressed (made from sample
# counts at a rate assumed wrong) or the recording cut short. KITTI's, EuRoC's and the simulated drives' streams span
# the IMU's to a few percent.
SHORT_IMU_RATIO, SAME_START_S = 1.5, 5.0


def imu_span_short(imu, streams: dict) -> str:
    """Why the IMU spans much less time than the other streams that start with it, or '': stamps compressed 3x ran
    to 19.7 m, said only as "scored over 155 s only" and a lidar "meeting the gyro nowhere" (an implausible-data
    review). ``streams``: name -> series (None when absent)."""
    ti = np.asarray(imu.t_s, float)
    if ti.size < 100 or not ti[-1] > ti[0]:
        return ""
    span_imu = float(ti[-1] - ti[0])
    longer = {}
    for name, st in streams.items():
        if st is None or len(st) < 10:
            continue
        t = np.asarray(st.t_s, float)
        span = float(t[-1] - t[0])
        if abs(t[0] - ti[0]) <= max(SAME_START_S, 0.05 * span) and span > SHORT_IMU_RATIO * span_imu:
            longer[name] = span
    if not longer:
        return ""
    ratio = min(longer.values()) / span_imu
    return (f"the IMU ({imu.source}) spans {span_imu:.4g} s where {', '.join(longer)} span "
            f"{', '.join(f'{v:.4g}' for v in longer.values())} s from about the same start ({ratio:.3g}x): its stamps "
            "compressed (made from sample counts at a rate assumed wrong: check the stream's rate or time unit), or "
            "the recording stopped early; the fused estimate covers the IMU's span only")
