"""Trajectory alignment that evo lacks: 4-DoF (a rotation about the gravity axis, and a translation), the right
one for inertial estimates, whose roll and pitch are observable (gravity) but whose heading and position are not.

The gravity ("up") axis is the reference frame's: ``z`` in ENU or a motion-capture world, ``y`` (pointing down) in
KITTI's cam0 poses. It is given (``x``, ``y``, ``z``) or detected (``auto``): the coordinate axis nearest to the
direction in which the reference's positions vary least (the normal of the plane a ground vehicle drives in).
Only the axis matters, not its sign: a rotation by ``a`` about ``-u`` is the rotation by ``-a`` about ``u``.

Closed form: with the centred points expressed in a frame whose third axis is ``u`` (``a_i`` estimate, ``b_i``
reference), the angle that minimises ``sum |b_i - R_u(yaw) a_i|^2`` is ``atan2(sum(a_x b_y - a_y b_x),
sum(a_x b_x + a_y b_y))`` and the translation ``t = mean(b) - R mean(a)``.
"""

from __future__ import annotations

import numpy as np

from ..errors import DataRangeError

UP_AXES = ("auto", "x", "y", "z")
_AXES = {"x": 0, "y": 1, "z": 2}


def detect_up_axis(p_ref_m: np.ndarray) -> tuple[str, dict]:
    """The coordinate axis nearest to the reference's least-varying direction, and how clear that is.

    Returns the axis name and ``{"normal": unit vector, "angle_deg": angle between it and the axis,
    "flatness": smallest / middle principal spread}`` (a planar drive: ~0; a 3-D flight: near 1, where the
    detection means little and ``--up-axis`` should be given).
    """
    p = np.asarray(p_ref_m, float)
    if p.shape[0] < 3:
        raise DataRangeError("4-DoF alignment needs at least 3 reference poses to find the gravity axis")
    w, V = np.linalg.eigh(np.cov((p - p.mean(axis=0)).T))
    normal = V[:, 0]
    k = int(np.argmax(np.abs(normal)))
    angle = float(np.degrees(np.arccos(min(1.0, abs(normal[k])))))
    flat = float(np.sqrt(max(w[0], 0.0) / w[1])) if w[1] > 0 else 1.0
    return "xyz"[k], {"normal": normal.tolist(), "angle_deg": angle, "flatness": flat}


def _frame_with_up(axis: str) -> np.ndarray:
    """A rotation ``Q`` (rows: the new axes) whose third row is the unit ``axis``: ``Q p`` puts ``axis`` on z."""
    k = _AXES[axis]
    return np.eye(3)[[(k + 1) % 3, (k + 2) % 3, k]]


def fit_4dof(p_est_m: np.ndarray, p_ref_m: np.ndarray, up_axis: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares rotation about ``up_axis`` and translation with ``p_ref ~ R p_est + t``.

    Returns ``R`` (3, 3), ``t`` (3,) in metres and the angle in radians (right-handed about the axis).
    """
    Q = _frame_with_up(up_axis)
    ma, mb = p_est_m.mean(axis=0), p_ref_m.mean(axis=0)
    a, b = (p_est_m - ma) @ Q.T, (p_ref_m - mb) @ Q.T
    yaw = float(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))
    c, s = np.cos(yaw), np.sin(yaw)
    R = Q.T @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ Q
    return R, mb - R @ ma, yaw

