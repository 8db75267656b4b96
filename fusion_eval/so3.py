"""SO(3) helpers and the package's single quaternion convention.

Conventions, written once here:

* Rotation matrices ``R_wb`` map body-frame vectors into the world frame: ``v_w = R_wb @ v_b``.
* Quaternions inside the package are scipy's order ``(x, y, z, w)`` (``q_wb_xyzw``). evo and the
  TUM format's in-memory representation in evo use ``(w, x, y, z)``; :func:`xyzw_to_wxyz` and
  :func:`wxyz_to_xyzw` are the only places that convert.
* Attitude errors are right (body-frame, local) perturbations: ``R = R_hat @ Exp(dtheta)``.
* Euler angles of KITTI OXTS are ``R_wb = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (the devkit's convention).

The numba kernels in :mod:`fusion_eval.filters.mech` carry their own scalar versions of ``skew``/``Exp``;
the vectorised versions here are what the rest of the package and the tests use. The conversions that run on
every pose of a long drive (matrix <-> quaternion, ``Log``, SLERP) are compiled loops that follow scipy's
formulas step for step (equal to scipy's to 1e-15, tested): scipy 1.17's array-API ``Rotation`` spends most of
its time in validation and temporaries, 0.2-0.5 s per call on 720,000 poses. Inputs scipy would repair or refuse
(a matrix that is not orthogonal to 1e-12, a non-positive determinant) are handed to scipy.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``[v]x`` of a 3-vector, so that ``skew(a) @ b == cross(a, b)``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation nearest a 3x3 matrix ``M`` (Frobenius; ``U diag(1, 1, det) V^T`` of its SVD). With
    ``M = sum y x^T`` it is the rotation minimising ``sum |y - R x|^2`` (Wahba's problem, Kabsch's fit)."""
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (rad); shape ``(3,)`` -> ``(3, 3)`` or ``(N, 3)`` -> ``(N, 3, 3)``."""
    return Rotation.from_rotvec(np.asarray(phi, dtype=float)).as_matrix()


@njit(cache=True)
def det3(M):
    """The determinant of a 3x3 matrix, by cofactors."""
    return (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]) - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
            + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))


@njit(cache=True)
def _quats_of_matrices(R, q, bad):
    """scipy's ``from_matrix`` on orthogonal matrices (the largest of trace and diagonal picks the formula),
    normalised; ``bad[n]`` where scipy would orthogonalise or refuse the matrix (left to scipy)."""
    for n in range(R.shape[0]):
        M = R[n]
        ok = True
        for i in range(3):
            for j in range(i, 3):              # M M^T is symmetric
                g = M[i, 0] * M[j, 0] + M[i, 1] * M[j, 1] + M[i, 2] * M[j, 2]
                e = 1.0 if i == j else 0.0
                if not abs(g - e) <= 1e-12 + 1e-5 * abs(e):
                    ok = False
        if not ok or not det3(M) > 0.0:
            bad[n] = True
            continue
        tr = M[0, 0] + M[1, 1] + M[2, 2]
        c, best = 0, M[0, 0]            # argmax over (M00, M11, M22, trace): the first of equal values, as scipy's
        for i in range(1, 3):
            if M[i, i] > best:
                c, best = i, M[i, i]
        if tr > best:
            c = 3
        if c == 3:
            q[n, 0] = M[2, 1] - M[1, 2]
            q[n, 1] = M[0, 2] - M[2, 0]
            q[n, 2] = M[1, 0] - M[0, 1]
            q[n, 3] = 1.0 + tr
        else:
            i = c
            j = (i + 1) % 3
            k = (j + 1) % 3
            q[n, i] = 1.0 - tr + 2.0 * M[i, i]
            q[n, j] = M[j, i] + M[i, j]
            q[n, k] = M[k, i] + M[i, k]
            q[n, 3] = M[k, j] - M[j, k]
        s = np.sqrt(q[n, 0] ** 2 + q[n, 1] ** 2 + q[n, 2] ** 2 + q[n, 3] ** 2)
        for i in range(4):
            q[n, i] /= s


@njit(cache=True)
def _rotvec_of_quat(x, y, z, w, out, n):
    """scipy's ``as_rotvec``: the canonical quaternion (w >= 0), angle by atan2, Taylor series below 1e-3 rad."""
    if w < 0 or (w == 0 and (x < 0 or (x == 0 and (y < 0 or (y == 0 and z < 0))))):
        x, y, z, w = -x, -y, -z, -w
    angle = 2.0 * np.arctan2(np.sqrt(x * x + y * y + z * z), w)
    if angle <= 1e-3:
        a2 = angle * angle
        scale = 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0
    else:
        scale = angle / np.sin(angle / 2.0)
    out[n, 0], out[n, 1], out[n, 2] = scale * x, scale * y, scale * z


@njit(cache=True)
def _rotvecs_of_quats(q, out):
    for n in range(q.shape[0]):
        _rotvec_of_quat(q[n, 0], q[n, 1], q[n, 2], q[n, 3], out, n)


@njit(cache=True)
def _relative_rotvec(a, b, out, n):
    """``out[n]``: the rotation vector of ``R(a)^T R(b)`` for quaternions ``a``, ``b`` (x, y, z, w): the normalised
    product ``conj(a) b`` (:func:`_qmul`, as SLERP forms it) and scipy's ``as_rotvec``."""
    x, y, z, w = _qmul(-a[0], -a[1], -a[2], a[3], b[0], b[1], b[2], b[3])
    _rotvec_of_quat(x, y, z, w, out, n)


@njit(cache=True)
def _relative_rotvecs(qa, qb, out):
    for n in range(qa.shape[0]):
        _relative_rotvec(qa[n], qb[n], out, n)


def relative_rotvecs(q_a_xyzw: np.ndarray, q_b_xyzw: np.ndarray) -> np.ndarray:
    """``Log(R_a^T R_b)`` (rad, ``(N, 3)``) of two stacks of quaternions (x, y, z, w), with no matrices: equal to
    :func:`log_so3` of the matrices' product to 1e-9 (tested); a long drive's stacks of matrices and products
    were ~150 MB and 0.3 s."""
    qa, qb = (np.ascontiguousarray(np.reshape(q, (-1, 4)), dtype=float) for q in (q_a_xyzw, q_b_xyzw))
    out = np.empty((qa.shape[0], 3))
    _relative_rotvecs(qa, qb, out)
    return out


@njit(cache=True)
def _matrices_of_quats(q, R):
    """scipy's ``from_quat(q).as_matrix()``: normalised, then the standard formula."""
    for n in range(q.shape[0]):
        s = np.sqrt(q[n, 0] ** 2 + q[n, 1] ** 2 + q[n, 2] ** 2 + q[n, 3] ** 2)
        x, y, z, w = q[n, 0] / s, q[n, 1] / s, q[n, 2] / s, q[n, 3] / s
        x2, y2, z2, w2 = x * x, y * y, z * z, w * w
        R[n, 0, 0] = x2 - y2 - z2 + w2
        R[n, 0, 1] = 2 * (x * y - z * w)
        R[n, 0, 2] = 2 * (x * z + y * w)
        R[n, 1, 0] = 2 * (x * y + z * w)
        R[n, 1, 1] = -x2 + y2 - z2 + w2
        R[n, 1, 2] = 2 * (y * z - x * w)
        R[n, 2, 0] = 2 * (x * z - y * w)
        R[n, 2, 1] = 2 * (y * z + x * w)
        R[n, 2, 2] = -x2 - y2 + z2 + w2


@njit(cache=True)
def _qmul(px, py, pz, pw, qx, qy, qz, qw):
    """Quaternion product ``p q`` (x, y, z, w), normalised (scipy's ``__mul__``), as four numbers: no array per
    product in the per-pose loops that call it."""
    x = pw * qx + qw * px + (py * qz - pz * qy)
    y = pw * qy + qw * py + (pz * qx - px * qz)
    z = pw * qz + qw * pz + (px * qy - py * qx)
    w = pw * qw - px * qx - py * qy - pz * qz
    s = np.sqrt(x ** 2 + y ** 2 + z ** 2 + w ** 2)
    return x / s, y / s, z / s, w / s


@njit(cache=True)
def _compose(p, q):
    """:func:`_qmul` of two quaternion arrays, as an array."""
    x, y, z, w = _qmul(p[0], p[1], p[2], p[3], q[0], q[1], q[2], q[3])
    return np.array([x, y, z, w])


@njit(cache=True)
def _slerp(t, q, tq, out):
    """scipy's ``Slerp(t, Rotation.from_quat(q))(tq).as_quat()`` for normalised ``q`` and ``tq`` inside
    ``[t[0], t[-1]]``: ``q_i Exp(alpha Log(q_i^-1 q_{i+1}))`` on the interval holding each query."""
    rv = np.empty((1, 3))
    for m in range(tq.size):
        i = np.searchsorted(t, tq[m]) - 1
        if tq[m] == t[0]:
            i = 0
        alpha = (tq[m] - t[i]) / (t[i + 1] - t[i])
        _relative_rotvec(q[i], q[i + 1], rv, 0)          # Log(q_i^-1 q_{i+1})
        v0, v1, v2 = rv[0, 0] * alpha, rv[0, 1] * alpha, rv[0, 2] * alpha
        angle = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        if angle <= 1e-3:
            a2 = angle * angle
            scale = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
        else:
            scale = np.sin(angle / 2.0) / angle
        e = np.array([v0 * scale, v1 * scale, v2 * scale, np.cos(angle / 2.0)])
        out[m] = _compose(q[i], e)


def slerp_xyzw(t_s: np.ndarray, q_xyzw: np.ndarray, tq_s: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) at ``tq_s`` (inside ``[t_s[0], t_s[-1]]``) by SLERP between the normalised
    ``q_xyzw`` at the strictly increasing ``t_s`` (scipy's ``Slerp``, compiled)."""
    t, tq = np.asarray(t_s, float), np.asarray(tq_s, float)
    if t.size < 2 or not np.all(np.diff(t) > 0):
        raise ValueError("SLERP needs at least 2 rotations at strictly increasing times")
    if tq.size and (tq.min() < t[0] or tq.max() > t[-1]):
        raise ValueError(f"Interpolation times must be within the range [{t[0]}, {t[-1]}], both inclusive.")
    q = np.asarray(q_xyzw, dtype=float)
    q = np.ascontiguousarray(q / np.linalg.norm(q, axis=1)[:, None])
    out = np.empty((np.size(tq_s), 4))
    _slerp(np.ascontiguousarray(t_s, float), q, np.ascontiguousarray(tq_s, float), out)
    return out


def _quats(R: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) of rotation matrices ``(..., 3, 3)`` exactly as scipy's ``from_matrix``."""
    R = np.asarray(R, dtype=float)
    flat = np.ascontiguousarray(R.reshape(-1, 3, 3))
    q = np.empty((flat.shape[0], 4))
    bad = np.zeros(flat.shape[0], bool)
    _quats_of_matrices(flat, q, bad)
    if bad.any():       # repaired, or refused with scipy's error (naming the matrix's index in the whole stack)
        q[bad] = np.atleast_2d(Rotation.from_matrix(flat).as_quat())[bad]
    return q.reshape(R.shape[:-2] + (4,))


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of a rotation matrix; inverse of :func:`exp_so3`."""
    R = np.asarray(R, dtype=float)
    q = _quats(R).reshape(-1, 4)
    out = np.empty((q.shape[0], 3))
    _rotvecs_of_quats(q, out)
    return out.reshape(R.shape[:-2] + (3,))


def matrix_to_euler_rpy(R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch, yaw (rad) of ``R_wb = Rz(yaw) Ry(pitch) Rx(roll)`` (the inverse of :func:`euler_rpy_to_matrix`
    away from pitch = +/-90 deg), each ``(N,)``: scipy's intrinsic z-y-x angles."""
    ypr = Rotation.from_matrix(np.asarray(R, dtype=float).reshape(-1, 3, 3)).as_euler("ZYX")
    return ypr[:, 2], ypr[:, 1], ypr[:, 0]


def euler_rpy_to_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """``R_wb = Rz(yaw) Ry(pitch) Rx(roll)`` for arrays of angles (rad); returns ``(N, 3, 3)``.

    The product written out, as the KITTI devkit forms it (scipy's ``from_euler`` goes through quaternions and
    agrees to 1e-15, tested; it took 0.9 s of a simulated hour's 3.8 s load)."""
    r, p, y = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    R = np.empty(np.broadcast(r, p, y).shape + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(x, y, z, w)`` with ``w >= 0`` of rotation matrices ``(N, 3, 3)``."""
    q = np.atleast_2d(_quats(R))
    q[q[:, 3] < 0] *= -1.0  # one hemisphere, so equal rotations print equal
    return q


def quat_xyzw_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(N, 3, 3)`` of quaternions ``(x, y, z, w)`` (normalised first)."""
    q = np.asarray(q_xyzw, dtype=float)
    flat = np.ascontiguousarray(q.reshape(-1, 4))
    if not np.all(np.isfinite(flat)) or np.any(np.einsum("ij,ij->i", flat, flat) == 0.0):
        return Rotation.from_quat(q).as_matrix()          # scipy's error for a zero or non-finite quaternion
    R = np.empty((flat.shape[0], 3, 3))
    _matrices_of_quats(flat, R)
    return R.reshape(q.shape[:-1] + (3, 3))


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


def fit_rotation_2d(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The rotation angle (rad) that best maps the centred 2-D points ``a`` onto ``b`` (least squares, 2-D Kabsch)
    and the RMS residual after it."""
    ac, bc = a - a.mean(axis=0), b - b.mean(axis=0)
    H = ac.T @ bc
    th = float(np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1]))
    c, s_ = np.cos(th), np.sin(th)
    r = bc - ac @ np.array([[c, s_], [-s_, c]])
    return th, float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))
