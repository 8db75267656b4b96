"""Frame chain: OXTS ground-truth poses carried into cam0 through T_cam0_imu = Tr * T_velo_imu reproduce
the official KITTI odometry ground truth of sequence 00."""

from __future__ import annotations

import numpy as np

from conftest import KITTI00
from fusion_eval.datasets import kitti_oxts, kitti_poses
from fusion_eval.so3 import inv_T, make_T, quat_xyzw_to_matrix


def test_oxts_in_cam0_matches_kitti_odometry_groundtruth():
    pk = kitti_oxts.read_oxts(KITTI00)
    gt = kitti_oxts.poses_from_oxts(pk, kitti_oxts.first_valid_fix(pk))
    T_w_b = make_T(quat_xyzw_to_matrix(gt.q_wb_xyzw), gt.p_w_m)[:4541]
    T_cam0_imu = kitti_poses.calib_transform(KITTI00 / "lidar" / "calib.txt", "Tr") @ \
        kitti_poses.calib_transform(KITTI00 / "calib_imu_to_velo.txt")
    T_b_c = inv_T(T_cam0_imu)
    # cam0 poses relative to frame 0: T_c0_ci = (T_w_b0 T_b_c)^-1 T_w_bi T_b_c
    T_c0_ci = inv_T(T_w_b[0] @ T_b_c)[None] @ T_w_b @ T_b_c[None]
    G, _ = kitti_poses.read_kitti_poses(KITTI00 / "lidar" / "00_gt_kitti.txt")
    valid = ~pk.filled[:4541]
    err = np.linalg.norm(T_c0_ci[valid, :3, 3] - G[valid, :3, 3], axis=1)
    # shared/data/README.md: 0.86 m mean, 1.6 m max (the two ground truths are not identical)
    assert err.max() < 2.0
    assert 0.5 < err.mean() < 1.2
    # with the wrong extrinsic (identity) the chain does not reproduce it
    T_bad = inv_T(T_w_b[0])[None] @ T_w_b
    assert np.linalg.norm(T_bad[valid, :3, 3] - G[valid, :3, 3], axis=1).max() > 100


def test_world_frame_cam0_poses_without_anchor_are_imu_poses(tmp_path):
    """A pose file of cam0 poses already in the world frame (anchor: none) gives the IMU poses back."""
    from fusion_eval.datasets.manifest import load_dataset

    pk = kitti_oxts.read_oxts(KITTI00)
    gt = kitti_oxts.poses_from_oxts(pk, kitti_oxts.first_valid_fix(pk))
    T_w_b = make_T(quat_xyzw_to_matrix(gt.q_wb_xyzw), gt.p_w_m)[:200]
    T_cam0_imu = kitti_poses.calib_transform(KITTI00 / "lidar" / "calib.txt", "Tr") @ \
        kitti_poses.calib_transform(KITTI00 / "calib_imu_to_velo.txt")
    T_w_c = T_w_b @ inv_T(T_cam0_imu)[None]
    (tmp_path / "cam.txt").write_text("\n".join(" ".join(f"{x:.15e}" for x in T[:3, :].ravel()) for T in T_w_c) + "\n")
    (tmp_path / "times.txt").write_text("\n".join(f"{t:.9f}" for t in gt.t_s[:200]) + "\n")
    (tmp_path / "dataset.yaml").write_text(f"""
streams:
  imu: {{format: kitti_oxts, path: {KITTI00 / 'oxts'}}}
  lidar:
    format: kitti_poses
    path: cam.txt
    frame: cam0
    T_cam0_velo: {{file: {KITTI00 / 'lidar' / 'calib.txt'}, key: Tr}}
    T_velo_imu: {{file: {KITTI00 / 'calib_imu_to_velo.txt'}}}
    times: {{file: times.txt}}
    anchor: none
""")
    lid = load_dataset(tmp_path).lidar
    assert np.abs(lid.p_w_m - gt.p_w_m[:200]).max() < 1e-6
