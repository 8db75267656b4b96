"""The filter's initial state from the data alone, for a drive without ground truth (``filter.init_pose_from: data``).

What a navigation system does at switch-on, offline:

- **Roll and pitch** by levelling: the mean specific force over the first :data:`LEVEL_WINDOW_S` is gravity's
  reaction in the body frame. A vehicle accelerating at ``a`` tilts it by ``atan(a / g)``: the acceleration the lidar
  or the odometer shows is taken out, and the stated std covers what is left (:data:`RESIDUAL_ACCEL_MPS2`, or
  :data:`UNKNOWN_ACCEL_MPS2` where nothing shows it).
- **Heading**, which no low-cost IMU can find by itself (the Earth's rate is below its gyro's noise):
  with lidar odometry and GNSS, the horizontal rotation that lays the lidar's track (levelled at the start) on the
  fixes over the first :data:`MIN_TRAVEL_M` of driving (a 2-D Procrustes fit; any platform); with GNSS alone on a
  wheeled vehicle, the fixes' direction of travel less the gyro's turn since the start (a car drives where it points,
  less its mount's travel yaw); without GNSS, zero: the world frame is then the start's levelled frame.
- **Position** from the same fit (or the fixes' line over the first seconds), zero without GNSS; **velocity** from
  the lidar's positions differenced (centimetres), else the fixes' slope, else the odometer along the body's forward
  axis, else zero.

Each comes with the std it earned, which the filter's initial covariance takes where it exceeds the configured one
(the configured ones are a start from a reference trajectory's pose: 0.01 deg of yaw).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import DataRangeError
from ..interp import anchored_at, interpolate_poses
from ..so3 import euler_rpy_to_matrix, exp_so3, fit_rotation_2d, make_T
from ..stats import moving_mean
from ..types import GnssSeries, ImuSeries, PoseSeries, SpeedSeries

LEVEL_WINDOW_S = 1.0          # the specific force averaged for roll and pitch
MIN_TRAVEL_M = 20.0           # horizontal driving the heading fit needs (1 m of GNSS noise over 20 m: ~3 deg a fix)
WINDOWS_S = (30.0, 60.0, 120.0, 300.0)   # the first of these over which the platform has driven MIN_TRAVEL_M
OUTLIER_SIGMAS, MIN_OUTLIER_M, MIN_OUTLIER_RAD = 4.0, 3.0, np.radians(30.0)   # fixes / fix pairs left out of the fits
MAX_FIRST_FIX_DELAY_S = 2.0    # without lidar, the start is the fixes': the first this close after it (a 1 Hz receiver)
CORRELATED_ERRORS = 2.0       # the heading fit's std over its white-noise value (below)
MIN_TRACK_SPEED_MPS = 3.0     # fix pairs slower than this give no direction of travel (GNSS noise over the step)
VELOCITY_FIT_S = 3.0          # the fixes' line over the first seconds gives the start's position and velocity
# What the levelling's specific force is off by, as acceleration (a tilt of atan(a / g)): the accelerometer's bias and lag
# against the acceleration taken out (on kitti-00 and SiMpLE 05/07 the IMU's acceleration, the truth's attitude taken
# out, differed from the lidar's by 0.10-0.28 m/s^2: 0.6-1.6 deg of levelling error, measured 0.3-2.0 deg), and
# further the acceleration of a platform whose own is not known (a car pulling away gently).
RESIDUAL_ACCEL_MPS2, UNKNOWN_ACCEL_MPS2 = 0.25, 0.5
# at rest only the accelerometer's bias is left (its lag acts on a changing acceleration only): a navigation IMU's is
# mg-level, an automotive MEMS one's up to 10 mg
AT_REST_ACCEL_MPS2 = 0.1
MIN_REST_S, REST_MARGIN_S = 2.0, 0.5     # a standstill long enough for the gyro's bias, less its end (moving off)
MIN_LIDAR_VEL_STD_MPS = 0.05  # the lidar's positions differenced over +/-0.3 s: their acceleration over it
REST_SPEED_MPS = 0.1          # the lidar's or odometer's speed over a second under this: standing still
MIN_SLOPE_SPAN_M = 20.0       # the track's spread (std) along its main direction that lets its height tell a slope
MIN_TILT_STD_DEG = 0.2        # levelling's floor: the accelerometer's own misalignment and noise


@dataclass(frozen=True)
class InitialState:
    p_w_m: np.ndarray
    v_w_mps: np.ndarray
    R_wb: np.ndarray
    std: dict          # pos_std_m, vel_std_mps, roll_pitch_std_deg, yaw_std_deg: what each method earned
    method: dict       # how each part was found, in words (the report)
    frame: str = "world"   # 'start': no GNSS, the world is the start's levelled frame (the plots' axes say so)
    bg_b_rps: np.ndarray = field(default_factory=lambda: np.zeros(3))   # the gyro's bias, where the platform stood still


def _window(t0: float, t: np.ndarray, dist_m: np.ndarray) -> float:
    """The first of :data:`WINDOWS_S` over which ``dist_m`` (horizontal distance from the start, at ``t``) reaches
    :data:`MIN_TRAVEL_M`; 0 where none does."""
    for w in WINDOWS_S:
        if np.any((t <= t0 + w) & (dist_m >= MIN_TRAVEL_M)):
            return w
    return 0.0


def _level_end(imu: ImuSeries, k0: int) -> int:
    """The IMU index just after the levelling window that starts at ``k0`` (one sample at least)."""
    return max(k0 + 1, int(np.searchsorted(imu.t_s, float(imu.t_s[k0]) + LEVEL_WINDOW_S, "right")))


def level(imu: ImuSeries, k0: int, accel_b_mps2: np.ndarray | None = None) -> tuple[float, float]:
    """Roll and pitch (rad) of the body at ``imu.t_s[k0]`` from the mean specific force over :data:`LEVEL_WINDOW_S`
    less the body's own acceleration where it is known (``f_b = R_wb^T (a_w + [0, 0, g])``, ``R_wb = Rz Ry Rx``)."""
    k1 = _level_end(imu, k0)
    f = np.mean(imu.f_b_mps2[k0:k1], axis=0) - (0.0 if accel_b_mps2 is None else accel_b_mps2)
    return float(np.arctan2(f[1], f[2])), float(np.arctan2(-f[0], np.hypot(f[1], f[2])))


def body_acceleration(imu: ImuSeries, k0: int, lidar: PoseSeries | None,
                      odometer: SpeedSeries | None) -> tuple[np.ndarray | None, str]:
    """The body's mean acceleration over the levelling window in its own frame, and where it came from: the lidar's
    positions (a parabola over the window and half a second either side, rotated into the body at the start: the same
    in any frame the odometry is given in; each axis taken as zero where the parabola's curvature is within 3 of its
    standard errors: a lidar's noise at rest tilted a simulated start by 1.6 deg), else the odometer's speed change
    along the forward axis and the centripetal term ``v * yaw rate`` across it; ``(None, "")`` where neither covers
    the start. A car pulling away at 0.6 m/s^2 tilts the levelling by 3.5 deg (kitti-00's start)."""
    t0 = float(imu.t_s[k0])
    lo, hi = t0 - 0.5, t0 + LEVEL_WINDOW_S + 0.5
    if lidar is not None:
        k = np.flatnonzero((lidar.t_s >= lo) & (lidar.t_s <= hi))
        if k.size >= 6 and lidar.t_s[k[0]] <= t0 + 0.1:
            c, cov = np.polyfit(lidar.t_s[k] - t0, lidar.p_w_m[k], 2, cov=True)
            at0 = interpolate_poses(lidar, np.array([t0 + 0.5 * LEVEL_WINDOW_S]))
            if len(at0):
                a = 2.0 * c[0]
                se = 2.0 * np.sqrt(np.abs(cov[0, 0]))
                return at0.R_wb()[0].T @ np.where(np.abs(a) > 3.0 * se, a, 0.0), "the lidar's positions"
    if odometer is not None:
        k = np.flatnonzero((odometer.t_s >= lo) & (odometer.t_s <= hi))
        if k.size >= 3 and odometer.t_s[k[0]] <= t0 + 0.1:
            slope = np.polyfit(odometer.t_s[k] - t0, odometer.v_mps[k], 1)[0]
            k1 = _level_end(imu, k0)
            v = float(np.mean(np.interp(imu.t_s[k0:k1], odometer.t_s, odometer.v_mps)))
            return np.array([slope, v * float(np.mean(imu.w_b_rps[k0:k1, 2])), 0.0]), "the odometer's speed"
    return None, ""


def _speed_positions(t: np.ndarray, p: np.ndarray, half_s: float) -> np.ndarray:
    """Speed at each stamp from the positions ``half_s`` either side (interpolated; clamped at the ends)."""
    lo, hi = (np.column_stack([np.interp(t + d, t, p[:, i]) for i in range(3)]) for d in (-half_s, half_s))
    return np.linalg.norm(hi - lo, axis=1) / (2 * half_s)


def rest_span(imu: ImuSeries, k0: int, lidar: PoseSeries | None, odometer: SpeedSeries | None) -> tuple[float, str]:
    """How long (s) the platform stands still from ``imu.t_s[k0]``, and what shows it: the odometer's mean speed over
    a second under :data:`REST_SPEED_MPS`, else the lidar's speed over a second; ``(0, "")`` where neither covers the
    start. Averaged over a second, so that an odometer's noise at rest is not motion (a simulated one's 0.1 m/s); an
    odometry that wanders at rest (the simulator's lidar random walk: 0.05-0.15 m/s over a second) reads as moving,
    the safe side (no standstill taken). Neither the IMU alone (rest and a straight drive at constant speed read alike) nor GNSS
    fixes (metres of noise: a car pulling away slowly on KITTI's raw 0027 stayed within three stds of its first fix
    for seconds, and the gyro's 'bias' over them, its turn, put the heading 137 deg off) tell it."""
    t0 = float(imu.t_s[k0])
    sources = []
    if odometer is not None and len(odometer) > 2:      # first: a wheel at rest reads zero (an odometry drifts)
        n = min(len(odometer), max(1, int(round(1.0 / max(float(np.median(np.diff(odometer.t_s))), 1e-3)))))
        # each stamp takes the mean of the second that starts there
        sources.append((odometer.t_s[:len(odometer) - n + 1], np.abs(moving_mean(odometer.v_mps, n)) > REST_SPEED_MPS,
                        "the odometer"))
    if lidar is not None and len(lidar) > 2:
        sources.append((lidar.t_s, _speed_positions(lidar.t_s, lidar.p_w_m, 0.5) > REST_SPEED_MPS, "the lidar's track"))
    for t, moved, what in sources:
        if t[0] > t0 + 0.1:
            continue
        after = (t >= t0 - 1e-9) & moved
        first = float(t[np.argmax(after)]) if after.any() else float(t[-1])
        return max(0.0, first - t0), what
    return 0.0, ""


def _gyro_heading(imu: ImuSeries, k0: int, R0: np.ndarray, t_end: float,
                  bg_rps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The body's forward axis' heading (rad, from East) in the start's frame, from the gyro alone (less its bias
    ``bg_rps``), at the IMU stamps ``t_s[k0]..t_end``: the turn since the start that the fixes' direction of travel is
    corrected by."""
    k1 = min(len(imu), int(np.searchsorted(imu.t_s, t_end, "right")) + 1)
    t = imu.t_s[k0:k1]
    steps = exp_so3((imu.w_b_rps[k0:k1 - 1] - bg_rps) * np.diff(t)[:, None]).reshape(-1, 3, 3)
    x = np.empty((t.size, 2))          # the forward axis' East and North components
    R = R0.copy()
    x[0] = R[0, 0], R[1, 0]
    for i in range(1, t.size):       # (a 3x3 product per sample: at most WINDOWS_S[-1] of them, once per run)
        R = R @ steps[i - 1]
        x[i] = R[0, 0], R[1, 0]
    return t, np.unwrap(np.arctan2(x[:, 1], x[:, 0]))


def _line(t: np.ndarray, p: np.ndarray, t0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares line through positions ``p`` at ``t``: its value and slope at ``t0`` and the residuals."""
    A = np.column_stack([np.ones_like(t), t - t0])
    coef, *_ = np.linalg.lstsq(A, p, rcond=None)
    return coef[0], coef[1], p - A @ coef


def _start_height(p_L: np.ndarray, z_w: np.ndarray) -> tuple[float, float]:
    """The start's height in the world: the fixes' heights ``z_w`` less the lidar's track's (``p_L``, in the levelled
    start frame), extrapolated to the start along the track's main direction where it spreads over
    :data:`MIN_SLOPE_SPAN_M`. The levelling's tilt and the odometry's own vertical drift make the height difference
    grow with the distance driven (1 deg over the first 300 m is 5 m), so its mean over the fit's window is not the
    start's (on kitti-00 and SiMpLE 05/06/07: 0.03-3.6 m off as the mean, 0.35-0.63 m extrapolated). Not turned into
    a tilt of the start's attitude: the odometry's vertical drift is as large as the levelling's error (tried: the
    tilt fitted that way was 0.3-1.4 deg off where the levelling was 0.3-2.0 deg off). Returns the height and its
    std from the fit's residuals."""
    dz = z_w - p_L[:, 2]
    xy = p_L[:, :2] - p_L[:, :2].mean(axis=0)
    evals, evecs = np.linalg.eigh(np.cov(xy.T)) if len(dz) >= 5 else (np.zeros(2), np.eye(2))
    A = (np.column_stack([np.ones(len(dz)), p_L[:, :2] @ evecs[:, 1]])
         if np.sqrt(max(evals[1], 0.0)) >= MIN_SLOPE_SPAN_M else np.ones((len(dz), 1)))
    coef, *_ = np.linalg.lstsq(A, dz, rcond=None)
    res = dz - A @ coef
    var = float(res @ res) / max(len(dz) - A.shape[1], 1)
    return float(coef[0]), float(np.sqrt(var * np.linalg.inv(A.T @ A)[0, 0]))


def _lay_on(xl: np.ndarray, xg: np.ndarray):
    """The rotation about the vertical (rad) that lays positions ``xl`` on ``xg`` (2-D Procrustes, centroids
    removed), the centroids, and the residuals."""
    cl, cg = xl.mean(axis=0), xg.mean(axis=0)
    yaw, _ = fit_rotation_2d(xl[:, :2], xg[:, :2])
    res = (xg - cg) - (xl - cl) @ euler_rpy_to_matrix(0.0, 0.0, yaw)[0].T
    return yaw, cl, cg, res


def _outliers(r: np.ndarray, floor: float = MIN_OUTLIER_M) -> np.ndarray:
    """Residuals beyond :data:`OUTLIER_SIGMAS` robust stds (1.4826 x their median absolute value) and ``floor``."""
    return r > max(floor, OUTLIER_SIGMAS * 1.4826 * float(np.median(np.abs(r))))


def _count(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else many or one + 's'}"


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def from_data(imu: ImuSeries, k0: int, gnss: GnssSeries | None, lidar: PoseSeries | None,
              odometer: SpeedSeries | None, wheeled: bool, travel_yaw_rad: float, gravity_mps2: float,
              lever_arm_b_m=(0.0, 0.0, 0.0)) -> InitialState:
    """The initial state at ``imu.t_s[k0]`` (module docstring). ``lidar``: IMU poses in the odometry's own frame
    (not anchored); ``wheeled``: the platform drives where it points (the GNSS-only heading needs it);
    ``lever_arm_b_m``: the GNSS antenna in the body frame (the fixes are the antenna's, the state the IMU's)."""
    arm = np.asarray(lever_arm_b_m, float)
    if gnss is not None and len(gnss) == 1:
        raise DataRangeError(f"{gnss.source}: a single GNSS fix inside the run: a drive without ground truth starts "
                             "from the fixes (two or more) or without any (filter.use_gnss: false and no gnss stream)")
    t0 = float(imu.t_s[k0])
    # a standstill at the start: no acceleration to take out of the levelling, and the gyro's mean there is its bias
    # (a static alignment), taken out of the turn the GNSS-track heading integrates over up to minutes, and the
    # filter's first bias estimate
    rest_s, rest_by = rest_span(imu, k0, lidar, odometer)
    at_rest = rest_s >= LEVEL_WINDOW_S + REST_MARGIN_S
    acc_b, acc_from = (np.zeros(3), rest_by) if at_rest else body_acceleration(imu, k0, lidar, odometer)
    roll, pitch = level(imu, k0, acc_b)
    R_lev = euler_rpy_to_matrix(roll, pitch, 0.0)[0]
    method = {"roll_pitch": f"levelled on the mean specific force over the first {LEVEL_WINDOW_S:g} s"
                            + (f", at rest as shown by {acc_from}" if at_rest else
                               f", less the acceleration shown by {acc_from}" if acc_b is not None else
                               " (no lidar or odometer at the start: the platform's acceleration is not taken out)")}
    bg = np.zeros(3)
    if rest_s >= MIN_REST_S:
        k1 = int(np.searchsorted(imu.t_s, t0 + rest_s - REST_MARGIN_S, "right"))
        bg = np.mean(imu.w_b_rps[k0:k1], axis=0)
        method["gyro_bias"] = (f"the gyro's mean over the first {rest_s - REST_MARGIN_S:.1f} s at rest (as shown by "
                               f"{rest_by}): {np.round(np.degrees(bg), 4).tolist()} deg/s")
    lid_L = None
    if lidar is not None and lidar.t_s[0] <= t0 + 1e-9 and lidar.t_s[-1] > t0:
        # the lidar's track in the levelled start frame (yaw 0): the body at t0 sits at the origin with R_lev
        lid_L = anchored_at(lidar, make_T(R_lev, np.zeros(3)), t0)
    g = None if gnss is None or len(gnss) < 2 else gnss
    yaw, yaw_std, p0, pos_std = 0.0, 0.0, np.zeros(3), 0.0
    v0, vel_std = None, 0.0
    if g is not None and lid_L is not None:
        inside = (g.t_s >= t0 - 1e-9) & (g.t_s <= lid_L.t_s[-1])
        at = interpolate_poses(lid_L, g.t_s[inside])
        keep = np.isin(g.t_s[inside], at.t_s)
        tg, pg = g.t_s[inside][keep], g.p_w_m[inside][keep]
        w = _window(t0, at.t_s, np.hypot(at.p_w_m[:, 0], at.p_w_m[:, 1]))
        if not w:
            raise DataRangeError(_no_heading(lidar.source, "the lidar odometry", t0))
        sel = at.t_s <= t0 + w
        xl, xg = at.p_w_m[sel], pg[sel]
        yaw, cl, cg, res = _lay_on(xl, xg)
        if np.any(arm):
            # the fixes are the antenna's: moved onto the IMU with the attitude the first fit gives, and fitted again
            R_L = at.R_wb()[sel]
            xg = xg - np.einsum("ij,njk,k->ni", euler_rpy_to_matrix(0.0, 0.0, yaw)[0], R_L, arm)
            yaw, cl, cg, res = _lay_on(xl, xg)
        n_all = len(xl)
        out = _outliers(np.hypot(res[:, 0], res[:, 1]))
        if out.any():            # a multipath fix or a receiver's jump: left out, the fit made again
            xl, xg = xl[~out], xg[~out]
            yaw, cl, cg, res = _lay_on(xl, xg)
        a = xl[:, :2] - cl[:2]
        Rz = euler_rpy_to_matrix(0.0, 0.0, yaw)[0]
        rms = float(np.sqrt(np.mean(np.sum(res[:, :2] ** 2, axis=1)) / 2))
        # the white-noise std of the fit, doubled: consecutive fixes' errors are correlated (a receiver's wander, the
        # odometry's drift); on kitti-00 and SiMpLE 05/06/07 the heading was 0.2-0.57 deg off against 0.12-0.24 deg
        yaw_std = CORRELATED_ERRORS * rms / float(np.sqrt(np.sum(a ** 2)))
        p0 = cg - Rz @ cl                      # the lidar's origin (the body at t0) in the world
        pos_std = float(np.sqrt(rms ** 2 / len(xl) + (yaw_std * np.max(np.linalg.norm(a, axis=1))) ** 2))
        method["heading"] = (f"the lidar's track laid on {len(xl)} GNSS fixes over the first {w:g} s "
                             f"(2-D fit, residual {rms:.2f} m RMS per axis"
                             + (f"; {_count(n_all - len(xl), 'fix', 'fixes')} off the fit left out" if n_all > len(xl)
                                else "") + ")")
        method["position"] = "the same fit"
        p0[2], z_std = _start_height(xl, xg[:, 2])
        pos_std = max(pos_std, z_std)
    elif g is not None:
        if g.t_s[0] > t0 + MAX_FIRST_FIX_DELAY_S:
            # (an outage over the first seconds: the fixes' line was extrapolated back over it, 161 m off a simulated
            # drive's start against 2 m stated)
            raise DataRangeError(f"{g.source}: the first GNSS fix used lies {g.t_s[0] - t0:.1f} s after the filter's "
                                 f"start (t = {t0:.3f} s; a gnss.outages_s window over the start?): a drive without "
                                 "ground truth and without lidar starts from the fixes at its start; move the outage "
                                 "off the first seconds, or add a lidar or groundtruth stream")
        if not wheeled:
            raise DataRangeError(f"{g.source}: a drive without ground truth and without lidar odometry starts its "
                                 "heading from the GNSS's direction of travel, which a platform not declared wheeled "
                                 "(the manifest's platform: car or wheeled) need not point along; add a lidar stream, "
                                 "declare the platform, or give a groundtruth stream")
        inside = g.t_s >= t0 - 1e-9
        tg, pg = g.t_s[inside], g.p_w_m[inside]
        w = _window(t0, tg, np.hypot(*(pg[:, :2] - pg[0, :2]).T))
        if not w or tg.size < 3:
            raise DataRangeError(_no_heading(g.source, "the GNSS fixes", t0))
        sel = tg <= t0 + w
        tg, pg = tg[sel], pg[sel]
        dt = np.diff(tg)
        d = np.diff(pg[:, :2], axis=0)
        fast = (dt > 0) & (np.hypot(d[:, 0], d[:, 1]) >= MIN_TRACK_SPEED_MPS * np.maximum(dt, 1e-9))
        if fast.sum() < 3:
            raise DataRangeError(f"{g.source}: a drive without ground truth and without lidar starts its heading from "
                                 f"the GNSS's direction of travel, but under 3 fix pairs within {w:g} s of the start "
                                 f"(t = {t0:.3f} s) are {MIN_TRACK_SPEED_MPS:g} m/s or faster apart (slower, the "
                                 "direction is the fixes' noise); add a lidar stream or a groundtruth stream")
        th, h = _gyro_heading(imu, k0, R_lev, float(tg[-1]), bg)
        mid = 0.5 * (tg[1:] + tg[:-1])[fast]
        psi = _wrap(np.arctan2(d[fast, 1], d[fast, 0]) - np.interp(mid, th, h) - travel_yaw_rad)
        yaw = float(np.arctan2(np.mean(np.sin(psi)), np.mean(np.cos(psi))))
        out = _outliers(np.abs(_wrap(psi - yaw)), MIN_OUTLIER_RAD)
        if out.any() and (~out).sum() >= 3:     # a fix off by metres turns the two steps beside it
            psi = psi[~out]
            yaw = float(np.arctan2(np.mean(np.sin(psi)), np.mean(np.cos(psi))))
        spread = float(np.sqrt(np.mean(_wrap(psi - yaw) ** 2)))
        yaw_std = spread / np.sqrt(psi.size)
        method["heading"] = (f"the GNSS's direction of travel over {psi.size} fix pairs in the first {w:g} s, "
                             f"less the gyro's turn (spread {np.degrees(spread):.1f} deg"
                             + (f"; {_count(int(out.sum()), 'pair')} off it left out" if out.any() else "") + ")")
    if g is not None and lid_L is None and at_rest and np.sum(g.t_s <= t0 + rest_s) >= 3:
        # standing still: the fixes' mean over the standstill (their errors correlated: the std of the mean doubled)
        still = g.t_s <= t0 + rest_s
        p0 = np.mean(g.p_w_m[still], axis=0)
        pos_std = CORRELATED_ERRORS * float(np.max(np.median(np.asarray(g.std_w_m, float)[still], axis=0))) / np.sqrt(
            still.sum())
        method["position"] = f"the mean of the {int(still.sum())} GNSS fixes while at rest"
    elif g is not None and lid_L is None:
        first = g.t_s <= g.t_s[0] + VELOCITY_FIT_S
        if first.sum() < 2:
            first = np.arange(len(g)) < 2
        p0, v0, res = _line(g.t_s[first], g.p_w_m[first], t0)
        n = int(first.sum())
        spread_m = float(np.sqrt(np.sum(res ** 2) / max(n - 2, 1) / 3)) if n > 2 else 0.0
        # a few fixes' scatter says little of their noise: the stream's own std per axis bounds it from below (3.0 m
        # off against 1.5 m stated from 4 fixes' scatter: a user trial)
        spread_m = max(spread_m, float(np.max(np.median(np.asarray(g.std_w_m, float)[first], axis=0))))
        span = float(np.ptp(g.t_s[first])) or 1.0
        pos_std = spread_m
        vel_std = float(np.sqrt(12.0 / n) * spread_m / span) if n > 2 else float(np.sqrt(2) * spread_m / span)
        method["position"] = method["velocity"] = f"the line through the first {n} GNSS fixes"
    Rz = euler_rpy_to_matrix(0.0, 0.0, yaw)[0]
    if g is not None and lid_L is None and np.any(arm):
        p0 = p0 - Rz @ R_lev @ arm         # the fixes' start is the antenna's
    if at_rest:
        v0, vel_std = np.zeros(3), REST_SPEED_MPS
        method["velocity"] = f"zero: at rest as shown by {rest_by}"
    elif lid_L is not None:
        k = np.flatnonzero(np.abs(lid_L.t_s - t0) <= 0.3)
        if k.size >= 2:
            _, v_L, res = _line(lid_L.t_s[k], lid_L.p_w_m[k], t0)
            v0 = Rz @ v_L
            # the slope's standard error from the positions' scatter about it (a simulated lidar's noise: 0.15 m/s)
            dt = lid_L.t_s[k] - lid_L.t_s[k].mean()
            scatter = float(np.sqrt(np.sum(res ** 2) / max(3 * (k.size - 2), 1)))
            vel_std = max(MIN_LIDAR_VEL_STD_MPS, 2.0 * scatter / float(np.sqrt(dt @ dt)))
            method["velocity"] = f"the lidar's positions differenced over {np.ptp(lid_L.t_s[k]):.2f} s"
    if v0 is None and odometer is not None and odometer.t_s[0] <= t0 <= odometer.t_s[-1]:
        v0 = Rz @ R_lev @ np.array([float(np.interp(t0, odometer.t_s, odometer.v_mps)), 0.0, 0.0])
        vel_std = 0.1
        method["velocity"] = "the odometer's speed along the body's forward axis"
    if v0 is None:
        v0, vel_std = np.zeros(3), 1.0
        method["velocity"] = "zero (no GNSS, lidar or odometer to tell it: the std says 1 m/s)"
    if g is None:
        method["heading"] = "zero: no GNSS, so the world frame is the start's levelled frame"
        method["position"] = "zero: the world frame's origin is the start"
    # levelling's error: the platform's acceleration over the window where it was not taken out
    acc = UNKNOWN_ACCEL_MPS2 if acc_b is None else AT_REST_ACCEL_MPS2 if at_rest else RESIDUAL_ACCEL_MPS2
    tilt_std = float(np.degrees(np.arctan2(acc, gravity_mps2))) + MIN_TILT_STD_DEG
    return InitialState(p_w_m=np.asarray(p0, float), v_w_mps=np.asarray(v0, float), R_wb=Rz @ R_lev,
                        std={"pos_std_m": float(pos_std), "vel_std_mps": float(vel_std),
                             "roll_pitch_std_deg": tilt_std, "yaw_std_deg": float(np.degrees(yaw_std))},
                        method=method, bg_b_rps=bg, frame="world" if g is not None else "start")


def _no_heading(source: str, what: str, t0: float) -> str:
    return (f"{source}: a drive without ground truth starts its heading from {what}, but the platform drives under "
            f"{MIN_TRAVEL_M:g} m within {WINDOWS_S[-1]:g} s of the start (t = {t0:.3f} s) or before the stream ends; "
            "the heading comes from the motion: give a groundtruth stream (any reference trajectory), or a drive "
            "that moves")
