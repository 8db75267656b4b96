"""The simulated drive written in the layouts users hold besides KITTI raw (``output.layout``):

- ``euroc``: an ASL folder (``mav0/imu0/data.csv``, ``mav0/state_groundtruth_estimate0/data.csv`` with the true
  biases, the lidar poses as ``mav0/lidar0/data.csv``), GNSS and wheel speed as generic CSV streams;
- ``csv_log``: one generic CSV per stream (``imu.csv``, ``gnss.csv``, ``groundtruth.csv``, ``lidar.csv``,
  ``odometer.csv``), columns named in the manifest;
- ``rosbag1`` / ``rosbag2``: one bag (``drive.bag`` / the ``drive/`` folder) with ``/imu/data`` (sensor_msgs/Imu),
  ``/gps/fix`` (NavSatFix with its covariance), ``/ground_truth/odom`` (nav_msgs/Odometry with the velocity),
  ``/lidar/pose`` (PoseStamped in the cam0 frame, or the IMU poses of map matching), ``/wheel/odom`` (Odometry,
  forward speed) and the IMU -> cam0 extrinsic on ``/tf_static`` (the manifest gives it as numbers too: see
  :func:`_write_bag`).

Every layout carries the same values as the KITTI layout: the numbers written are those the KITTI files hold
(the same decimals, parsed back), and every stamp is carried to the nanosecond, which every reader turns into the
same float (:func:`fusion_eval.datasets._text.ns_to_s`). So the same drive gives the same fused metrics through
every layout (tested to 1e-9); what differs is only how a rotation is stored (a matrix in KITTI pose files, a
quaternion elsewhere), a difference of a few units in the last place.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

from ..datasets.kitti_oxts import OxtsPackets, imu_from_oxts, poses_from_oxts
from ..datasets._text import exact_floats
from ..fastfmt import table_text
from ..so3 import inv_T, matrix_to_quat_xyzw
from ..types import PoseSeries

LAYOUTS = ("euroc", "csv_log", "rosbag1", "rosbag2")


@dataclass
class SimStreams:
    """What the simulator measured, as the KITTI layout writes it (see :func:`as_written`)."""

    t_s: np.ndarray                 # IMU stamps (s)
    packets: np.ndarray             # (N, 30) OXTS packets as written
    origin: tuple                   # geodetic origin (lat, lon, alt)
    gnss_t_s: np.ndarray
    gnss_lla: np.ndarray            # (M, 3) as written (deg, deg, m)
    gnss_std_m: np.ndarray          # (M, 3) east/north/up 1-sigma as written
    odo_t_s: np.ndarray
    odo_v_mps: np.ndarray
    lidar_t_s: np.ndarray           # lidar clock stamps
    lidar_T: np.ndarray             # (K, 4, 4) as written: cam0 poses T_c0_ci (odometry) or world IMU poses (map matching)
    lidar_mode: str                 # odometry | map_matching
    T_cam0_imu: np.ndarray          # the calibration chain as the KITTI files give it
    bias_f_mps2: np.ndarray         # true biases at the IMU stamps (for EuRoC's ground truth)
    bias_w_rps: np.ndarray


def parse_rows(text: str) -> np.ndarray:
    """Whitespace-separated rows of numbers, parsed exactly as the readers parse them (correctly rounded)."""
    import pandas as pd

    return pd.read_csv(io.StringIO(text), sep=r"\s+", header=None, **exact_floats()).to_numpy(float)


def as_written(a: np.ndarray, decimals) -> np.ndarray:
    """The values a text file written with ``decimals`` gives back (formatted, then parsed exactly)."""
    return parse_rows(table_text(np.atleast_2d(np.asarray(a, float)), decimals))


def s_text(t_s: np.ndarray) -> np.ndarray:
    """Stamps as 9-decimal text: parsed back they give the same floats (floats near 1e9 s are 0.24 us apart, so
    rounding to the nanosecond cannot move a stamp to another float)."""
    return np.array([f"{t:.9f}" for t in np.asarray(t_s, float)])


def _rows(columns: list[np.ndarray], sep: str = ",") -> str:
    """Text rows of columns already formatted (strings)."""
    return "\n".join(sep.join(r) for r in zip(*columns)) + "\n"


def _g17(a: np.ndarray) -> np.ndarray:
    return np.char.mod("%.17g", np.asarray(a, float))


def _packets(s: SimStreams) -> OxtsPackets:
    return OxtsPackets(t_s=s.t_s, values=s.packets, filled=np.zeros(s.t_s.size, bool), stamps_path=None, packet_paths=())


def _ground_truth(s: SimStreams) -> PoseSeries:
    return poses_from_oxts(_packets(s), s.origin)


def _imu(s: SimStreams):
    return imu_from_oxts(_packets(s))


def _lidar_quat(s: SimStreams) -> tuple[np.ndarray, np.ndarray]:
    return s.lidar_T[:, :3, 3], matrix_to_quat_xyzw(s.lidar_T[:, :3, :3])


def _lidar_entry(s: SimStreams, base: dict) -> dict:
    """The lidar stream's frame, extrinsic and anchoring, for a pose stream of any format."""
    if s.lidar_mode == "odometry":
        return {**base, "frame": "cam0", "T_cam0_imu": [float(x) for x in s.T_cam0_imu[:3, :].ravel()],
                "anchor": "groundtruth"}
    return {**base, "frame": "imu", "anchor": "none"}


def _gnss_csv(out, name: str, s: SimStreams) -> dict:
    out.write_text(name, "t_s,lat_deg,lon_deg,alt_m,std_e_m,std_n_m,std_u_m\n" + _rows(
        [s_text(s.gnss_t_s), *_g17(s.gnss_lla).T, *_g17(s.gnss_std_m).T]))
    return {"format": "csv", "path": name, "columns": ["t", "lat", "lon", "alt", "std_e", "std_n", "std_u"], "degrade": False}


def _odometer_csv(out, name: str, s: SimStreams) -> dict:
    out.write_text(name, "t_s,v_mps\n" + _rows([s_text(s.odo_t_s), _g17(s.odo_v_mps)]))
    return {"format": "csv", "path": name, "columns": ["t", "v"]}


def _write_euroc(out, s: SimStreams) -> dict:
    from ..datasets._text import s_to_ns

    imu = _imu(s)
    ns = s_to_ns(s.t_s).astype(str)
    out.write_text("mav0/imu0/data.csv", "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                   "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
                   + _rows([ns, *_g17(imu.w_b_rps).T, *_g17(imu.f_b_mps2).T]))
    gt = _ground_truth(s)
    q = gt.q_wb_xyzw
    out.write_text("mav0/state_groundtruth_estimate0/data.csv",
                   "#timestamp,p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z [],"
                   "v_RS_R_x [m s^-1],v_RS_R_y [m s^-1],v_RS_R_z [m s^-1],b_w_RS_S_x [rad s^-1],b_w_RS_S_y [rad s^-1],"
                   "b_w_RS_S_z [rad s^-1],b_a_RS_S_x [m s^-2],b_a_RS_S_y [m s^-2],b_a_RS_S_z [m s^-2]\n"
                   + _rows([ns, *_g17(gt.p_w_m).T, *_g17(q[:, [3, 0, 1, 2]]).T, *_g17(gt.v_w_mps).T,
                            *_g17(s.bias_w_rps).T, *_g17(s.bias_f_mps2).T]))
    p, ql = _lidar_quat(s)
    out.write_text("mav0/lidar0/data.csv", "#timestamp [ns],p_x [m],p_y [m],p_z [m],q_w [],q_x [],q_y [],q_z []\n"
                   + _rows([s_to_ns(s.lidar_t_s).astype(str), *_g17(p).T, *_g17(ql[:, [3, 0, 1, 2]]).T]))
    return {"imu": {"format": "euroc", "path": "mav0/imu0/data.csv"},
            "groundtruth": {"format": "euroc", "path": "mav0/state_groundtruth_estimate0/data.csv"},
            "gnss": _gnss_csv(out, "gnss/data.csv", s),
            "odometer": _odometer_csv(out, "odometer/data.csv", s),
            "lidar": _lidar_entry(s, {"format": "euroc", "path": "mav0/lidar0/data.csv"})}


def _write_csv_log(out, s: SimStreams) -> dict:
    imu = _imu(s)
    t = s_text(s.t_s)
    out.write_text("imu.csv", "t_s,ax,ay,az,wx_dps,wy_dps,wz_dps\n"
                   + _rows([t, *_g17(imu.f_b_mps2).T, *_g17(np.degrees(imu.w_b_rps)).T]))
    gt = _ground_truth(s)
    out.write_text("groundtruth.csv", "t_s,x,y,z,qx,qy,qz,qw,vx,vy,vz\n"
                   + _rows([t, *_g17(gt.p_w_m).T, *_g17(gt.q_wb_xyzw).T, *_g17(gt.v_w_mps).T]))
    p, ql = _lidar_quat(s)
    out.write_text("lidar.csv", "t_s,x,y,z,qx,qy,qz,qw\n" + _rows([s_text(s.lidar_t_s), *_g17(p).T, *_g17(ql).T]))
    pose_cols = ["t", "x", "y", "z", "qx", "qy", "qz", "qw"]
    return {"imu": {"format": "csv", "path": "imu.csv", "columns": ["t", "ax", "ay", "az", "wx", "wy", "wz"],
                    "gyro_unit": "deg/s"},
            "groundtruth": {"format": "csv", "path": "groundtruth.csv", "columns": pose_cols + ["vx", "vy", "vz"]},
            "gnss": _gnss_csv(out, "gnss.csv", s),
            "odometer": _odometer_csv(out, "odometer.csv", s),
            "lidar": _lidar_entry(s, {"format": "csv", "path": "lidar.csv", "columns": pose_cols})}


def _write_bag(out, s: SimStreams, version: str) -> dict:
    from ..datasets import rosbag

    imu = _imu(s)
    gt = _ground_truth(s)
    fixes = rosbag.FixSeries(t_s=s.gnss_t_s, lat_deg=s.gnss_lla[:, 0], lon_deg=s.gnss_lla[:, 1], alt_m=s.gnss_lla[:, 2],
                             std_enu_m=s.gnss_std_m)
    p, ql = _lidar_quat(s)
    lidar = PoseSeries(t_s=s.lidar_t_s, p_w_m=p, q_wb_xyzw=ql)
    n = s.odo_t_s.size
    wheel = PoseSeries(t_s=s.odo_t_s, p_w_m=np.zeros((n, 3)), q_wb_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
                       v_w_mps=np.column_stack([s.odo_v_mps, np.zeros(n), np.zeros(n)]))
    odometry = s.lidar_mode == "odometry"
    streams = [rosbag.BagStream("/imu/data", "imu", imu, "imu_link"),
               rosbag.BagStream("/gps/fix", "navsatfix", fixes, "gps"),
               rosbag.BagStream("/ground_truth/odom", "odometry", gt, "map", child_frame_id="imu_link"),
               rosbag.BagStream("/lidar/pose", "pose", lidar, "cam0_init" if odometry else "map"),
               rosbag.BagStream("/wheel/odom", "odometry", wheel, "odom", child_frame_id="base_link")]
    name = "drive.bag" if version == "rosbag1" else "drive"
    tf_static = [("imu_link", "cam0", inv_T(s.T_cam0_imu))]
    rosbag.write_bag(out.staging / name, version, streams, tf_static=tf_static)
    lidar_entry = {"format": "rosbag", "path": name, "topic": "/lidar/pose"}
    # the extrinsic as the KITTI calibration files give it (its 6-digit rotation is orthonormal only to ~1e-6, which
    # /tf_static's quaternion cannot carry: 'T_imu_cam0: {tf_static: [imu_link, cam0]}' reads the rigid version)
    lidar_entry = _lidar_entry(s, lidar_entry)
    return {"imu": {"format": "rosbag", "path": name, "topic": "/imu/data"},
            "groundtruth": {"format": "rosbag", "path": name, "topic": "/ground_truth/odom"},
            "gnss": {"format": "rosbag", "path": name, "topic": "/gps/fix", "degrade": False},
            "odometer": {"format": "rosbag", "path": name, "topic": "/wheel/odom"},
            "lidar": lidar_entry}


def write(layout: str, out, s: SimStreams) -> dict:
    """Write the streams in ``layout``; returns the manifest's stream entries."""
    if layout == "euroc":
        return _write_euroc(out, s)
    if layout == "csv_log":
        return _write_csv_log(out, s)
    return _write_bag(out, s, layout)
