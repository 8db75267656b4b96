"""SO(3) helpers and the package's single quaternion convention.

Conventions, written once here:

* Rotation matrices ``R_wb`` map body-frame vectors into the world frame: ``v_w = R_wb @ v_b``.
* Quaternions inside the package are scipy's order ``(x, y, z, w)`` (``q_wb_xyzw``). evo and the
  TUM format's in-memory representation in evo use ``(w, x, y, z)``; :func:`xyzw_to_wxyz` and
  :func:`wxyz_to_xyzw` are the only places that convert.
* Attitude errors are right (body-frame, local) perturbations: ``R = R_hat @ Exp(dtheta)``.
* Euler angles of KITTI OXTS are ``R_wb = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (the devkit's convention).

The numba kernels in :mod:`fusion_eval.filters.mech` carry their own scalar versions of ``skew``/``Exp``;
the vectorised numpy versions here are what the rest of the package and the tests use.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``[v]x`` of a 3-vector, so that ``skew(a) @ b == cross(a, b)``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (rad); shape ``(3,)`` -> ``(3, 3)`` or ``(N, 3)`` -> ``(N, 3, 3)``."""
    return Rotation.from_rotvec(np.asarray(phi, dtype=float)).as_matrix()


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of a rotation matrix; inverse of :func:`exp_so3`."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()


def euler_rpy_to_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """``R_wb = Rz(yaw) Ry(pitch) Rx(roll)`` for arrays of angles (rad); returns ``(N, 3, 3)``."""
    angles = np.column_stack([np.atleast_1d(yaw), np.atleast_1d(pitch), np.atleast_1d(roll)])
    return Rotation.from_euler("ZYX", angles).as_matrix()


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(x, y, z, w)`` with ``w >= 0`` of rotation matrices ``(N, 3, 3)``."""
    q = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    q = np.atleast_2d(q)
    q[q[:, 3] < 0] *= -1.0  # one hemisphere, so equal rotations print equal
    return q


def quat_xyzw_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` of quaternions ``(x, y, z, w)`` (normalised first)."""
    return Rotation.from_quat(np.asarray(q_xyzw, dtype=float)).as_matrix()


def xyzw_to_wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    """Reorder scipy quaternions to evo's ``(w, x, y, z)``; the only conversion into evo's order."""
    q = np.asarray(q_xyzw, dtype=float)
    return q[..., [3, 0, 1, 2]]


def wxyz_to_xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    """Reorder evo's ``(w, x, y, z)`` quaternions to scipy's ``(x, y, z, w)``."""
    q = np.asarray(q_wxyz, dtype=float)
    return q[..., [1, 2, 3, 0]]


def make_T(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homogeneous 4x4 transform(s) from rotation(s) and translation(s)."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    if R.ndim == 2:
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = p
        return T
    T = np.tile(np.eye(4), (R.shape[0], 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of homogeneous transform(s) ``(4, 4)`` or ``(N, 4, 4)``, using R^T."""
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    p = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, p)
    out[..., 3, 3] = 1.0
    return out
