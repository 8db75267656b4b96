"""Write a simulated drive in the KITTI raw layout, with a manifest and a ``truth/`` folder.

Layout of OUT_DIR::

    oxts/timestamps.txt, oxts/data/NNNNNNNNNN.txt   true pose + measured IMU, one packet per IMU sample
                                                     (or oxts/packets.csv with output.layout=csv)
    gnss/gnss.csv                                    GNSS fixes (t_s, lat, lon, alt, std E/N/U)
    odometer/speed.txt                               wheel speed (t_s v_mps)
    lidar/poses.txt + times.txt + calib.txt          lidar odometry (KITTI poses, cam0), or
    lidar/map_matching.tum                           map-matching poses (world IMU poses)
    calib_imu_to_velo.txt                            KITTI's IMU -> velodyne calibration
    dataset.yaml                                     the manifest, with the sensors' specs as suggested settings
    truth/imu_biases.csv, truth/poses.tum, truth/sensors.yaml   what real data never gives
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d
import yaml

from .. import __version__
from ..outputs import SIMULATED_MANIFEST_HEADER
from ..config import load_config
from ..datasets.gnss_csv import format_gnss_csv
from ..datasets.kitti_oxts import CSV_HEADER
from ..errors import ConfigError
from ..fastfmt import format_table, table_text
from ..geo import enu_rotation, normal_gravity_mps2
from ..outputs import StagedDir
from ..pool import executor
from ..so3 import exp_so3, inv_T, make_T, matrix_to_euler_rpy, matrix_to_quat_xyzw, quat_xyzw_to_matrix
from ..types import IMU_MAX_RATE_RPS, IMU_MAX_SPECIFIC_FORCE_MPS2
from . import layouts, sensors
from .motion import PROFILES, profile_segments, sample_motion
from .settings import GRADES, sim_schema

log = logging.getLogger(__name__)

# KITTI's calibration (odometry sequences 00-02 and raw 2011_10_03), so the simulated lidar exercises
# the same extrinsic chain as the real data: T_cam0_imu = Tr * T_velo_imu.
TR_VELO_TO_CAM0 = [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02,
                   -7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02,
                   9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01]
R_IMU_TO_VELO = [9.999976e-01, 7.553071e-04, -2.035826e-03, -7.854027e-04, 9.998898e-01, -1.482298e-02,
                 2.024406e-03, 1.482454e-02, 9.998881e-01]
T_IMU_TO_VELO = [-8.086759e-01, 3.195559e-01, -7.997231e-01]


class _NoAliases(yaml.SafeDumper):
    """Write repeated values in full (no &id001 anchors) so the truth file reads plainly."""

    def ignore_aliases(self, data):
        return True


def sim_config(grade: str, sets: tuple[str, ...]) -> dict:
    if grade not in GRADES:
        raise ConfigError(f"unknown grade {grade!r} (known: {', '.join(GRADES)})")
    return load_config(None, sets, schema_=sim_schema(), layers=((GRADES[grade], f"grade {grade}"),))


# decimals of the 30 OXTS fields: lat lon (1e-12 deg = 0.1 um), alt, angles, velocities, IMU, accuracies, status
PACKET_DECIMALS = [12, 12, 6] + [12] * 3 + [9] * 5 + [12] * 12 + [4, 4] + [0] * 5

_SHARED: dict = {}


def _write_packet_range(args) -> None:
    """Write packets [lo, hi) as one file each, from the formatted buffer (inherited by fork)."""
    folder, lo, hi = args
    buf, offs = _SHARED["buf"], _SHARED["offs"]
    mv = memoryview(buf)
    for i in range(lo, hi):
        fd = os.open(os.path.join(folder, f"{i:010d}.txt"), os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.write(fd, mv[offs[i]:offs[i + 1]])
        finally:
            os.close(fd)


def kitti_stamps(t_s: np.ndarray) -> str:
    """KITTI ``YYYY-MM-DD HH:MM:SS.nnnnnnnnn`` lines for POSIX seconds (vectorised; to the nanosecond, so that the
    reader gets back the very same floats)."""
    from ..datasets._text import s_to_ns

    ns = s_to_ns(t_s).astype("datetime64[ns]")
    return "\n".join(np.datetime_as_string(ns, unit="ns")).replace("T", " ") + "\n"


MIN_DURATION_S, MAX_DURATION_S = 2.0, 86400.0


def simulate(out_dir: Path, profile: str, duration_s: float, seed: int, grade: str, sets: tuple[str, ...] = (),
             overwrite: bool = False, jobs: int | None = None) -> dict:
    """Simulate a drive and write it (atomically) to ``out_dir``; returns a summary for the CLI."""
    c = sim_config(grade, sets)
    rate = c["imu"]["rate_hz"]
    if not 10.0 <= rate <= 400.0:
        raise ConfigError(f"imu.rate_hz must be between 10 and 400 Hz, got {rate:g}")
    # at least two lidar frames and a GNSS fix to write; at most a day (a day at 400 Hz is 2.6 GB of IMU text: more is
    # a typo, which once asked numpy for 745 GiB)
    if not (MIN_DURATION_S <= duration_s <= MAX_DURATION_S):
        raise ConfigError(f"--duration must be between {MIN_DURATION_S:g} and {MAX_DURATION_S:g} s, got {duration_s:g}")
    if seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {seed}")
    if not 0.0 <= c["lidar"]["outlier_prob"] <= 1.0:
        raise ConfigError(f"lidar.outlier_prob must be between 0 and 1, got {c['lidar']['outlier_prob']:g}")
    if not -90.0 <= c["origin"]["lat_deg"] <= 90.0 or not -180.0 <= c["origin"]["lon_deg"] <= 360.0:
        raise ConfigError("origin.lat_deg must be in [-90, 90] and origin.lon_deg in [-180, 360]")
    if c["start"]["posix_s"] > 4e9:
        raise ConfigError(f"start.posix_s must be between 0 and 4e9, got {c['start']['posix_s']:g}")
    bad = []
    for sensor in (k for k, sec in c.items() if k != "imu" and isinstance(sec, dict) and "rate_hz" in sec):
        # every sensor samples the true motion at IMU stamps: its rate must divide the IMU rate (every sensor's, a
        # registered observation's too: an extension author's barometer at 7 Hz was written at 7.14 Hz without a word)
        r = c[sensor]["rate_hz"]
        step = round(rate / r)
        if r > rate:
            bad.append(f"{sensor}.rate_hz={r:g} is above imu.rate_hz={rate:g} (a sensor is sampled at IMU stamps)")
        elif abs(rate / step - r) > 1e-9 * r:          # (r <= rate: step >= 1)
            bad.append(f"{sensor}.rate_hz={r:g} must divide imu.rate_hz={rate:g} (e.g. {rate / step:g} Hz)")
    if bad:             # every one at once (they came one per attempt: a rate review)
        raise ConfigError("; ".join(bad))
    segs, yaw0, n_prefix = profile_segments(profile)
    staged = StagedDir(out_dir, overwrite=overwrite)
    staged.check()

    rng = np.random.default_rng(seed)
    o = c["origin"]
    origin = (o["lat_deg"], o["lon_deg"], o["alt_m"])
    g = normal_gravity_mps2(o["lat_deg"], o["alt_m"])   # the filter's 'auto' gravity at this origin
    n = int(round(duration_s * rate)) + 1
    t = c["start"]["posix_s"] + np.arange(n) / rate
    m = sample_motion(segs, yaw0, t, g, n_prefix=n_prefix)
    im = sensors.imu(_lagged(m, c["imu"], segs, yaw0, t, g, n_prefix), c["imu"], rng)
    for what, a, lim, unit in (("angular rate", im.w_b_rps, IMU_MAX_RATE_RPS, "rad/s"),
                               ("specific force", im.f_b_mps2, IMU_MAX_SPECIFIC_FORCE_MPS2, "m/s^2")):
        peak = float(np.max(np.abs(a)))
        if not peak <= lim:        # what no reader takes (run would refuse the dataset written): an absurd setting
            raise ConfigError(f"the simulated IMU's {what} reaches {peak:.3g} {unit}, beyond the {lim:g} {unit} a reader "
                              f"accepts: an imu.* noise, bias or scale-factor setting is implausible")
    gt_t, gps_p, gps_std = sensors.gnss(m, c["gnss"], rng)
    if gt_t.size < 2:             # a GNSS file without fixes is one `run` refuses: refused here, where it is made
        raise ConfigError(f"the simulated GNSS has {gt_t.size} fixes over the {duration_s:g} s drive: gnss.outages_s "
                          f"{c['gnss']['outages_s']} (s from the start) or gnss.rate_hz leave too few")
    odo_t, odo_v = sensors.odometer(m, c["odometer"], rng)
    lc = c["lidar"]
    if lc["mode"] == "odometry":
        l_idx, l_p, l_R = sensors.lidar_odometry(m, lc, rng)
        l_out = None
    else:
        l_idx, l_p, l_R, l_out = sensors.lidar_map_matching(m, lc, rng)

    lat, lon, alt = pymap3d.enu2geodetic(m.p_w_m[:, 0], m.p_w_m[:, 1], m.p_w_m[:, 2], *origin)
    # as an OXTS reports them: attitude and velocity in the local level frame at each packet (the motion's frame is
    # the origin's ENU, which the readers turn them back into; written as the origin's, they were 0.06 deg off in yaw
    # 6.7 km from it; a stress test)
    to_local = enu_rotation(lat, lon, origin[0], origin[1]).transpose(0, 2, 1)
    roll, pitch, yaw = matrix_to_euler_rpy(np.einsum("nij,njk->nik", to_local, m.R_wb))
    v_local = np.einsum("nij,nj->ni", to_local, m.v_w_mps)
    packets = np.column_stack([
        lat, lon, alt, roll, pitch, yaw,
        v_local[:, 1], v_local[:, 0], m.speed_mps, np.zeros(n), np.zeros(n),
        im.f_b_mps2, im.f_b_mps2, im.w_b_rps, im.w_b_rps,
        np.full(n, 0.02), np.full(n, 0.02),
        np.full(n, 4), np.full(n, 10), np.full(n, 5), np.full(n, 5), np.full(n, 6)])

    name = f"sim-{Path(profile).stem}-{grade}-s{seed}"
    layout = c["output"]["layout"]
    kitti_family = layout in ("kitti", "csv")
    with staged as out:
        if kitti_family:
            (out.staging / "oxts").mkdir()
        if layout == "csv":
            out.write_text("oxts/packets.csv", CSV_HEADER + "\n" + _stamped(t, packets, PACKET_DECIMALS, sep=","))
        elif layout == "kitti":
            out.write_text("oxts/timestamps.txt", kitti_stamps(t))
            folder = out.staging / "oxts" / "data"
            folder.mkdir(parents=True)
            _SHARED["buf"], _SHARED["offs"] = format_table(packets, PACKET_DECIMALS)
            jobs = max(1, min(jobs or os.cpu_count() or 1, 8))
            bounds = np.linspace(0, n, jobs + 1).astype(int)
            work = [(str(folder), int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
            try:
                if jobs > 1 and n > 20000:   # file creation is the cost: spread it over the cores
                    # the project's pool (forked after _SHARED is set, so the workers hold the table): it kills its
                    # workers when the block ends by a signal; multiprocessing.Pool's terminate() waited forever for
                    # the queue's lock that a worker killed by a SIGTERM to the process group held (an interruption
                    # review: 2 hangs in 8, only SIGKILL ended them)
                    with executor(jobs) as pool:
                        list(pool.map(_write_packet_range, work))
                else:
                    for w in work:
                        _write_packet_range(w)
            finally:
                _SHARED.clear()
        glat, glon, galt = pymap3d.enu2geodetic(gps_p[:, 0], gps_p[:, 1], gps_p[:, 2], *origin)
        if kitti_family:
            out.write_text("gnss/gnss.csv", format_gnss_csv(gt_t, np.column_stack([glat, glon, galt]), gps_std))
            out.write_text("odometer/speed.txt", "# t_s v_mps (forward wheel speed)\n" +
                           _stamped(odo_t, odo_v[:, None], [6]))
            out.write_text("calib_imu_to_velo.txt", "calib_time: simulated\nR: " + " ".join(f"{x:.6e}" for x in R_IMU_TO_VELO)
                           + "\nT: " + " ".join(f"{x:.6e}" for x in T_IMU_TO_VELO) + "\n")
        T_velo_imu = np.eye(4)
        T_velo_imu[:3, :3] = np.reshape(R_IMU_TO_VELO, (3, 3))
        T_velo_imu[:3, 3] = T_IMU_TO_VELO
        Tr = np.eye(4)
        Tr[:3, :] = np.reshape(TR_VELO_TO_CAM0, (3, 4))
        T_c_b = Tr @ T_velo_imu
        t_l = t[l_idx]
        t_l_stamp = t_l - lc["time_offset_s"]          # the lidar clock's stamps
        E = make_T(exp_so3(np.asarray(lc["extrinsic_error_rpy_mrad"], float) * 1e-3), np.asarray(lc["extrinsic_error_m"], float))
        if lc["mode"] == "odometry":
            # the true mount differs from the calibration file by E: the tool reads E T E^-1 as IMU motion
            # (the mount is rigid: the calibration's 6-digit rotation, orthonormal only to ~1e-6, is projected onto
            # SO(3), so that the poses written are rigid motions, whose rotation a quaternion holds as well as a matrix)
            A = _rigid(T_c_b @ E)
            T_c = A[None] @ make_T(l_R, l_p) @ inv_T(A)[None]
            lidar_text = "\n".join(" ".join(f"{x:.12e}" for x in T[:3, :].ravel()) for T in T_c) + "\n"
            # the stamps of the lidar clock, absolute (a relative times file plus t0 would round once more)
            lidar_stream = {"format": "kitti_poses", "path": "lidar/poses.txt", "frame": "cam0",
                            "T_cam0_velo": {"file": "lidar/calib.txt", "key": "Tr"},
                            "T_velo_imu": {"file": "calib_imu_to_velo.txt"},
                            "times": {"file": "lidar/times.txt"}, "anchor": "groundtruth"}
            if kitti_family:
                out.write_text("lidar/poses.txt", lidar_text)
                out.write_text("lidar/times.txt", "\n".join(f"{x:.9f}" for x in t_l_stamp) + "\n")
                out.write_text("lidar/calib.txt", "Tr: " + " ".join(f"{x:.12e}" for x in TR_VELO_TO_CAM0) + "\n")
            lidar_T = layouts.parse_rows(lidar_text).reshape(-1, 3, 4)
            lidar_T = np.concatenate([lidar_T, np.tile([[[0.0, 0.0, 0.0, 1.0]]], (lidar_T.shape[0], 1, 1))], axis=1)
        else:
            T_m = make_T(l_R, l_p) @ inv_T(E)[None]        # the IMU pose the mis-calibrated chain reports
            q = matrix_to_quat_xyzw(T_m[:, :3, :3])
            tum_text = _stamped(t_l_stamp, np.column_stack([T_m[:, :3, 3], q]), [9] * 7)
            if kitti_family:
                out.write_text("lidar/map_matching.tum", "# t x y z qx qy qz qw (world IMU poses, map matching)\n" + tum_text)
            lidar_stream = {"format": "tum", "path": "lidar/map_matching.tum", "frame": "imu", "anchor": "none"}
            rows = layouts.parse_rows(tum_text)
            lidar_T = make_T(quat_xyzw_to_matrix(rows[:, 4:8]).reshape(-1, 3, 3), rows[:, 1:4])
        if not kitti_family:
            streams = layouts.write(layout, out, layouts.SimStreams(
                t_s=t, packets=layouts.as_written(packets, PACKET_DECIMALS), origin=origin, gnss_t_s=gt_t,
                gnss_lla=layouts.as_written(np.column_stack([glat, glon, galt]), [10, 10, 4]),
                gnss_std_m=layouts.as_written(gps_std, [4, 4, 4]), odo_t_s=odo_t, odo_v_mps=layouts.as_written(odo_v[:, None], [6])[:, 0],
                lidar_t_s=t_l_stamp, lidar_T=lidar_T, lidar_mode=lc["mode"], T_cam0_imu=_calib_chain(),
                bias_f_mps2=im.accel_bias, bias_w_rps=im.gyro_bias))
        else:
            streams = {"imu": {"format": "kitti_oxts", "path": "oxts"},
                       "groundtruth": {"format": "kitti_oxts", "path": "oxts"},
                       "gnss": {"format": "csv_lla", "path": "gnss/gnss.csv", "degrade": False},
                       "odometer": {"format": "speed_txt", "path": "odometer/speed.txt"},
                       "lidar": lidar_stream}

        out.write_text("truth/imu_biases.csv", "t_s,ba_x_mps2,ba_y_mps2,ba_z_mps2,bg_x_rps,bg_y_rps,bg_z_rps\n" +
                       table_text(np.column_stack([t, im.accel_bias, im.gyro_bias]), [6] + [12] * 6, sep=","))
        qt = matrix_to_quat_xyzw(m.R_wb)
        out.write_text("truth/poses.tum", "# true IMU poses in the local ENU frame: t x y z qx qy qz qw\n" +
                       table_text(np.column_stack([t, m.p_w_m, qt]), [6] + [9] * 7))
        truth = {
            "generator": f"fusion-eval {__version__}", "profile": profile, "grade": grade, "seed": seed,
            "duration_s": duration_s, "gravity_mps2": g, "sensors": c,
            "imu_initial_bias": {"accel_mps2": im.accel_bias[0].tolist(), "gyro_dps": np.degrees(im.gyro_bias[0]).tolist()},
            "imu_scale_factor_ppm": {"accel": im.accel_scale_ppm.tolist(), "gyro": im.gyro_scale_ppm.tolist()},
            "odometer_scale": c["odometer"]["scale"],
            "gnss_outages_s": c["gnss"]["outages_s"], "gnss_jumps": c["gnss"]["jumps"],
            "lidar_outliers": None if l_out is None else int(l_out.sum()),
            "distance_m": float(np.sum(np.linalg.norm(np.diff(m.p_w_m, axis=0), axis=1))),
        }
        out.write_text("truth/sensors.yaml", yaml.dump(truth, Dumper=_NoAliases, sort_keys=False))
        extra_streams, extra_config = _observation_sensors(m, c, seed, out)
        manifest = {
            "name": name,
            "description": f"simulated by fusion-eval {__version__}: profile {profile}, grade {grade}, seed {seed}, "
                           f"{duration_s:g} s at {rate:g} Hz",
            "geodetic_origin": list(origin),
            "streams": {**streams, **extra_streams},
            "config": _merged(suggested_config(c), extra_config),
            "truth": {"imu_biases": "truth/imu_biases.csv", "poses": "truth/poses.tum", "sensors": "truth/sensors.yaml"},
        }
        out.write_text("dataset.yaml", SIMULATED_MANIFEST_HEADER + "\n" +
                       yaml.safe_dump(manifest, sort_keys=False))
    return {"name": name, "samples": n, "distance_m": truth["distance_m"], "lidar_frames": int(l_idx.size),
            "gnss_fixes": int(gt_t.size)}


def _rigid(T: np.ndarray) -> np.ndarray:
    """The nearest rigid transform (the rotation block projected onto SO(3) by SVD)."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    out = np.array(T, float)
    out[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return out


def _stamped(t_s: np.ndarray, values: np.ndarray, decimals, sep: str = " ") -> str:
    """Rows of ``stamp values...``: the stamps with 9 decimals (they read back as the same floats; the compiled
    formatter's integers cannot hold 1e9 s in nanoseconds), the values by the compiled formatter."""
    body = table_text(values, decimals, sep).splitlines()
    return "".join(f"{ts}{sep}{row}\n" for ts, row in zip(layouts.s_text(t_s), body))


def _calib_chain() -> np.ndarray:
    """``T_cam0_imu`` as the manifest computes it from the calibration files the KITTI layout writes."""
    Tr, T_vi = np.eye(4), np.eye(4)
    Tr[:3, :] = np.reshape([float(f"{x:.12e}") for x in TR_VELO_TO_CAM0], (3, 4))
    T_vi[:3, :3] = np.reshape([float(f"{x:.6e}") for x in R_IMU_TO_VELO], (3, 3))
    T_vi[:3, 3] = [float(f"{x:.6e}") for x in T_IMU_TO_VELO]
    return Tr @ T_vi


def _lagged(m, ci: dict, segs, yaw0: float, t: np.ndarray, g: float, n_prefix: int):
    """The motion the IMU channels see: each reports its quantity of ``<channel>_lag_s`` earlier (sampled
    exactly there, not interpolated)."""
    from dataclasses import replace

    f, w = m.f_b_mps2, m.w_b_rps
    if ci["accel_lag_s"]:
        f = sample_motion(segs, yaw0, t - ci["accel_lag_s"], g, n_prefix=n_prefix, t_origin_s=t[0]).f_b_mps2
    if ci["gyro_lag_s"]:
        w = sample_motion(segs, yaw0, t - ci["gyro_lag_s"], g, n_prefix=n_prefix, t_origin_s=t[0]).w_b_rps
    return replace(m, f_b_mps2=f, w_b_rps=w)


@dataclass(frozen=True)
class SimContext:
    """What a registered observation's simulated sensor gets: the true motion, the simulator settings, its own
    seeded generator (independent of every other sensor's draws), the staging folder and the ENU origin."""

    motion: object
    settings: dict
    rng: np.random.Generator
    out: StagedDir
    origin: tuple[float, float, float]


def _observation_sensors(m, c: dict, seed: int, out: StagedDir) -> tuple[dict, dict]:
    """Run the simulated sensor of every registered observation that has one (found by name): their manifest
    streams and suggested settings."""
    from ..filters.observations import REGISTRY

    streams: dict = {}
    config: dict = {}
    origin = (c["origin"]["lat_deg"], c["origin"]["lon_deg"], c["origin"]["alt_m"])
    for o in REGISTRY:
        if o.simulate is None:
            continue
        # a generator of its own, keyed on the observation's name: adding a sensor changes no other draw
        rng = np.random.default_rng([seed, int.from_bytes(o.name.encode()[:8].ljust(8, b"\0"), "little")])
        s, cf = o.simulate(SimContext(m, c, rng, out, origin))
        streams.update(s)
        config = _merged(config, cf)
    return streams, config


def _merged(a: dict, b: dict) -> dict:
    out = {k: dict(v) for k, v in a.items()}
    for sect, body in b.items():
        out.setdefault(sect, {}).update(body)
    return out


def suggested_config(c: dict) -> dict:
    """The filter settings a user would take from these sensors' datasheets (the simulator's true specs)."""
    i, lc = c["imu"], c["lidar"]
    odo = lc["mode"] == "odometry"
    gm = i["bias_corr_time_s"] > 0    # a datasheet's bias instability with its correlation time
    return {
        "filter": {"lidar_update": "relative" if odo else "absolute"} | ({"bias_model": "gauss_markov"} if gm else {}),
        "imu": {k: max(i[k], 1e-9) for k in ("accel_noise_mps2_sqrthz", "gyro_noise_dps_sqrthz",
                                             "accel_bias_rw_mps3_sqrthz", "gyro_bias_rw_dps2_sqrthz")} | {"gyro_lag_s": 0.0}
               | ({"accel_bias_corr_time_s": i["bias_corr_time_s"], "gyro_bias_corr_time_s": i["bias_corr_time_s"]} if gm else {}),
        "lidar": ({"relative_pos_std_m": max(lc["pos_noise_std_m"], 1e-3), "relative_pos_std_frac": lc["scale_drift"],
                   "relative_att_std_deg": max(lc["att_noise_std_deg"], 1e-3)} if odo else
                  {"absolute_pos_std_m": max(lc["pos_noise_std_m"], 1e-3), "absolute_att_std_deg": max(lc["att_noise_std_deg"], 1e-3)}),
        "gnss": {"std_m": "auto"},
        "init": {"accel_bias_std_mps2": max(i["accel_bias_init_std_mps2"], 1e-4),
                 "gyro_bias_std_dps": max(i["gyro_bias_init_std_dps"], 1e-4),
                 "pos_std_m": 0.01, "vel_std_mps": 0.01, "roll_pitch_std_deg": 0.01, "yaw_std_deg": 0.01},
    }


__all__ = ["simulate", "PROFILES", "GRADES"]
