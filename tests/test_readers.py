"""Readers on the real files: KITTI raw OXTS, KITTI poses and calibration, TUM, the manifest."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import KITTI00, shared_path
from fusion_eval.datasets import kitti_oxts, kitti_poses, tum
from fusion_eval.datasets.manifest import load_dataset
from fusion_eval.so3 import quat_xyzw_to_matrix


def test_oxts_reader_real_drive():
    pk = kitti_oxts.read_oxts(KITTI00)
    assert pk.values.shape == (4544, 30)
    # 134 packets filled in by KITTI, among them 0-13 and a run from 347 (shared/data/README.md)
    assert pk.filled.sum() == 134
    assert pk.filled[:14].all() and not pk.filled[14]
    assert pk.filled[347]
    dt = np.diff(pk.t_s)
    assert 0.07 < dt.min() and dt.max() < 0.13 and abs(np.median(dt) - 0.1) < 1e-3
    assert abs(pk.t_s[-1] - pk.t_s[0] - 470.8) < 0.1


def test_oxts_streams_units_and_frames():
    ds = load_dataset(KITTI00)
    valid = ~ds.imu.filled
    # specific force, z up: about +9.8 m/s^2 on average
    assert 9.6 < ds.imu.f_b_mps2[valid, 2].mean() < 10.0
    gt = ds.groundtruth
    first = int(np.flatnonzero(~gt.filled)[0])
    # the ENU origin is the first valid fix
    assert np.allclose(gt.p_w_m[first], 0.0, atol=1e-6)
    assert np.allclose(ds.gnss.p_w_m[first], 0.0, atol=1e-6)
    # the drive is 3.72 km long
    steps = np.linalg.norm(np.diff(gt.p_w_m[valid], axis=0), axis=1)
    assert 3600 < steps.sum() < 3850
    # velocity from R_wb [vf vl vu] agrees with differenced positions
    v_fd = np.diff(gt.p_w_m[1000:1100], axis=0) / np.diff(gt.t_s[1000:1100])[:, None]
    v_mid = 0.5 * (gt.v_w_mps[1000:1099] + gt.v_w_mps[1001:1100])
    assert np.sqrt(np.mean((v_fd - v_mid) ** 2)) < 0.3
    # attitude: the body x axis points along the horizontal velocity while driving
    R = quat_xyzw_to_matrix(gt.q_wb_xyzw[1000])
    v = gt.v_w_mps[1000]
    assert np.dot(R[:2, 0], v[:2]) / np.linalg.norm(v[:2]) > 0.99
    assert (ds.gnss.std_w_m > 0).all()


def test_kitti_poses_times_and_calibration():
    T, lines = kitti_poses.read_kitti_poses(KITTI00 / "lidar" / "00_poses_kitti.txt")
    assert T.shape == (4541, 4, 4) and lines[0] == 1
    assert np.allclose(T[0], np.eye(4), atol=1e-12)
    t, _ = kitti_poses.read_times(KITTI00 / "lidar" / "times.txt")
    assert t.size == 4541 and t[0] == 0.0 and abs(np.mean(np.diff(t)) - 0.1037) < 1e-3
    Tr = kitti_poses.calib_transform(KITTI00 / "lidar" / "calib.txt", "Tr")
    T_velo_imu = kitti_poses.calib_transform(KITTI00 / "calib_imu_to_velo.txt")
    assert np.allclose(T_velo_imu[:3, 3], [-8.086759e-01, 3.195559e-01, -7.997231e-01])
    T_cam_imu = Tr @ T_velo_imu
    # IMU x (forward) is camera z (forward); IMU z (up) is camera -y (down)
    assert T_cam_imu[2, 0] > 0.99 and T_cam_imu[1, 2] < -0.99


def test_lidar_times_aligned_on_oxts_clock():
    ds = load_dataset(KITTI00)
    # frame i is raw packet i: on the valid packets the aligned times sit on the OXTS stamps
    d = ds.lidar.t_s[14:4541] - ds.imu.t_s[14:4541]
    assert abs(np.median(d)) < 1e-3 and np.abs(d).max() < 0.03


def test_tum_round_trip(tmp_path):
    src = shared_path("evo-test-data", "freiburg1_xyz-groundtruth.txt")
    poses = tum.read_tum(src)
    assert len(poses) > 1000
    out = tmp_path / "x.tum"
    out.write_text(tum.format_tum(poses, "header"))
    back = tum.read_tum(out)
    assert np.allclose(back.t_s, poses.t_s, atol=1e-9)
    assert np.allclose(back.p_w_m, poses.p_w_m, atol=1e-9)
    assert np.allclose(back.q_wb_xyzw, poses.q_wb_xyzw, atol=1e-9)


def test_plain_kitti_raw_folder_needs_no_manifest():
    drive = shared_path("kitti-raw", "2011_09_30", "2011_09_30_drive_0020_sync")
    ds = load_dataset(drive)
    assert len(ds.imu) == 1104 and ds.lidar is None and ds.gnss is not None and ds.groundtruth is not None
    # no lidar odometry: the implicit manifest suggests the filter without it; a request for lidar still wins
    from fusion_eval import session
    from fusion_eval.errors import FusionEvalError

    assert session.resolve(session.request(), ds)["filter"]["lidar_update"] == "none"
    cfg = session.resolve(session.request(sets=("filter.lidar_update=relative",)), ds)
    assert cfg["filter"]["lidar_update"] == "relative"
    with pytest.raises(FusionEvalError, match="no lidar stream"):
        from fusion_eval.prepare import prepare

        prepare(ds, cfg)


@pytest.mark.parametrize("drive", ["2011_09_30_drive_0018_sync", "2011_09_30_drive_0027_sync"])
def test_other_real_drives_read(drive):
    ds = load_dataset(shared_path("kitti-raw", "2011_09_30", drive))
    assert len(ds.imu) > 1000
    assert np.isfinite(ds.groundtruth.p_w_m).all()


def test_series_share_what_cannot_change_and_copy_the_rest():
    """A series made from another's arrays (dataclasses.replace, select) shares them, since neither can write them;
    an array the caller can still write, or a read-only view of one, is copied, so a series never changes under it."""
    from dataclasses import replace

    import numpy as np

    from fusion_eval.types import PoseSeries

    t, q = np.arange(3.0), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    a = np.zeros((3, 3))
    s = PoseSeries(t_s=t, p_w_m=a, q_wb_xyzw=q)
    a[0, 0] = 5.0                                       # the caller's array: the series holds a copy
    assert s.p_w_m[0, 0] == 0.0 and not s.p_w_m.flags.writeable and not s.q_wb_xyzw.flags.writeable
    r = replace(s, source="again")
    assert r.p_w_m is s.p_w_m and r.t_s is s.t_s       # shared: read-only all the way down
    v = a.view()
    v.setflags(write=False)                             # read-only, but a view of a writable array
    assert PoseSeries(t_s=t, p_w_m=v, q_wb_xyzw=q).p_w_m is not v


def test_normal_gravity_falls_with_height_and_rises_towards_the_poles():
    """WGS84 normal gravity (Somigliana) with the free-air term -3.086e-6 /s^2 per metre (a mutation review found the
    sign of the height term held by no test): 9.780 at the equator, 9.832 at the poles, 9.8094 at KITTI."""
    from fusion_eval.geo import normal_gravity_mps2

    assert normal_gravity_mps2(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-9)
    assert normal_gravity_mps2(90.0, 0.0) == pytest.approx(9.8321849379, abs=1e-6)
    assert normal_gravity_mps2(49.0, 1000.0) - normal_gravity_mps2(49.0, 0.0) == pytest.approx(-3.086e-3, rel=1e-9)
    assert normal_gravity_mps2(49.0, 116.0) == pytest.approx(9.8094, abs=1e-4)
