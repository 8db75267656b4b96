"""The single quaternion convention and its one conversion to evo's order."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_euler_matrices_equal_scipys_and_the_devkits_product():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    r, p, y = rng.uniform(-np.pi, np.pi, (3, 5000))
    p[:4] = [np.pi / 2, -np.pi / 2, 0.0, 1e-9]                 # gimbal lock and tiny angles
    R = euler_rpy_to_matrix(r, p, y)
    assert np.abs(R - Rotation.from_euler("ZYX", np.column_stack([y, p, r])).as_matrix()).max() < 1e-15

    def rz(a):
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])

    def ry(a):
        return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])

    def rx(a):
        return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    for i in (0, 1, 7, 4999):
        assert np.abs(R[i] - rz(y[i]) @ ry(p[i]) @ rx(r[i])).max() < 1e-15
    assert euler_rpy_to_matrix(0.1, 0.2, 0.3).shape == (1, 3, 3)


def test_compiled_conversions_equal_scipys():
    """The compiled matrix/quaternion/Log/SLERP loops follow scipy's formulas: equal to 1e-15 on random rotations,
    the four branches of the matrix-to-quaternion choice, angles near 0 and pi; scipy still refuses what it refuses."""
    from scipy.spatial.transform import Rotation, Slerp

    from fusion_eval.so3 import log_so3, matrix_to_quat_xyzw, quat_xyzw_to_matrix, slerp_xyzw

    rng = np.random.default_rng(5)
    R = Rotation.random(2000, random_state=7).as_matrix()
    R[:4] = [np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]
    R[4] = Rotation.from_rotvec([1e-9, -2e-9, 3e-10]).as_matrix()
    R[5] = Rotation.from_rotvec([0, np.pi - 1e-9, 0]).as_matrix()
    R[6] = R[7] * 1.0001                                     # not orthogonal: scipy repairs it, so do we
    assert np.abs(log_so3(R) - Rotation.from_matrix(R).as_rotvec()).max() < 1e-15
    q_ref = Rotation.from_matrix(R).as_quat()
    q_ref[q_ref[:, 3] < 0] *= -1
    assert np.abs(matrix_to_quat_xyzw(R) - q_ref).max() < 1e-15
    q = Rotation.random(2000, random_state=8).as_quat() * rng.uniform(0.5, 2.0, (2000, 1))
    assert np.abs(quat_xyzw_to_matrix(q) - Rotation.from_quat(q).as_matrix()).max() < 1e-15
    t = np.cumsum(rng.uniform(0.001, 0.01, q.shape[0]))
    tq = np.r_[t[0], np.sort(rng.uniform(t[0], t[-1], 3000)), t[10], t[-1]]
    assert np.abs(slerp_xyzw(t, q, tq) - Slerp(t, Rotation.from_quat(q))(tq).as_quat()).max() < 1e-15
    assert log_so3(np.eye(3)).shape == (3,) and quat_xyzw_to_matrix(np.array([0, 0, 0, 1.0])).shape == (3, 3)
    # ties of the trace with a diagonal entry (quarter turns): scipy's argmax order, the same sign
    from fusion_eval.so3 import _quats

    Q = Rotation.from_rotvec(np.pi / 2 * np.eye(3)).as_matrix()
    assert np.array_equal(_quats(Q), Rotation.from_matrix(Q).as_quat())
    stack = np.stack([np.eye(3)] * 5)
    stack[3] = -np.eye(3)
    with pytest.raises(ValueError, match="determinant .* matrix 3"):
        log_so3(stack)
    with pytest.raises(ValueError, match="strictly increasing"):
        slerp_xyzw(np.array([0.0, 1.0, 1.0]), np.tile([0, 0, 0, 1.0], (3, 1)), np.array([0.5]))
    with pytest.raises(ValueError, match="within the range"):
        slerp_xyzw(np.array([0.0, 1.0, 2.0]), np.tile([0, 0, 0, 1.0], (3, 1)), np.array([-0.5]))
    with pytest.raises(ValueError, match="determinant"):
        log_so3(-np.eye(3))
    with pytest.raises(ValueError, match="zero norm"):
        quat_xyzw_to_matrix(np.zeros(4))


def test_relative_rotvecs_equal_the_log_of_the_matrix_product():
    """``Log(R_a^T R_b)`` from the quaternions alone equals scipy-exact ``log_so3`` of the matrices' product to 1e-9
    rad, for small and large relative rotations (near pi too), whatever each quaternion's sign and norm."""
    from scipy.spatial.transform import Rotation

    from fusion_eval.so3 import log_so3, relative_rotvecs

    rng = np.random.default_rng(7)
    qa = Rotation.random(3000, random_state=7).as_quat()
    d = np.concatenate([rng.normal(0, 1e-4, (1000, 3)), rng.normal(0, 0.5, (1000, 3)),
                        np.tile(np.pi * 0.999 * np.array([0.0, 0.6, 0.8]), (1000, 1))])
    qb = (Rotation.from_quat(qa) * Rotation.from_rotvec(d)).as_quat()
    qb[::2] *= -1.0
    qa[1::3] *= 1.7                        # not unit: normalised first, as the matrices would be
    want = log_so3(np.einsum("nji,njk->nik", quat_xyzw_to_matrix(qa), quat_xyzw_to_matrix(qb)))
    got = relative_rotvecs(qa, qb)
    assert np.max(np.abs(got - want)) < 1e-9
    assert np.max(np.abs(got - d)) < 1e-9


def test_roll_pitch_yaw_of_a_matrix_invert_the_devkits_convention():
    """The simulator writes OXTS attitude by :func:`matrix_to_euler_rpy`, the readers read it by
    :func:`euler_rpy_to_matrix`: one the other's inverse (away from pitch = +/-90 deg)."""
    from fusion_eval.so3 import euler_rpy_to_matrix, matrix_to_euler_rpy

    rng = np.random.default_rng(0)
    r, p, y = rng.uniform(-3.1, 3.1, 200), rng.uniform(-1.5, 1.5, 200), rng.uniform(-3.1, 3.1, 200)
    for got, want in zip(matrix_to_euler_rpy(euler_rpy_to_matrix(r, p, y)), (r, p, y)):
        np.testing.assert_allclose(np.angle(np.exp(1j * (got - want))), 0.0, atol=1e-12)
