"""The single quaternion convention and its one conversion to evo's order."""

from __future__ import annotations

import numpy as np

from fusion_eval.evaluation import to_evo
from fusion_eval.so3 import (euler_rpy_to_matrix, matrix_to_quat_xyzw, quat_xyzw_to_matrix, wxyz_to_xyzw,
                             xyzw_to_wxyz)
from fusion_eval.types import PoseSeries


def test_quaternion_order_round_trip_and_evo_trajectory():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    assert np.array_equal(wxyz_to_xyzw(xyzw_to_wxyz(q)), q)
    poses = PoseSeries(t_s=np.arange(20.0), p_w_m=rng.normal(size=(20, 3)), q_wb_xyzw=q)
    traj = to_evo(poses, "x")
    # evo's SE(3) matrices hold the same rotations as ours
    for i in (0, 7, 19):
        assert np.allclose(traj.poses_se3[i][:3, :3], quat_xyzw_to_matrix(q[i]), atol=1e-12)


def test_kitti_euler_convention():
    # yaw 90 deg: body x (forward) points north
    R = euler_rpy_to_matrix(0.0, 0.0, np.pi / 2)[0]
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # pitch positive: nose down for z up (KITTI devkit Ry)
    R = euler_rpy_to_matrix(0.0, 0.1, 0.0)[0]
    assert (R @ [1, 0, 0])[2] < 0
    q = matrix_to_quat_xyzw(euler_rpy_to_matrix(np.array([0.1]), np.array([-0.2]), np.array([3.0])))
    assert q.shape == (1, 4) and q[0, 3] >= 0
