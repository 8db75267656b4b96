"""Trajectory alignment that evo lacks: 4-DoF (yaw and translation), the right one for inertial estimates,
whose roll and pitch are observable (gravity) but whose heading and position are not.

Closed form: with centred point sets ``a_i`` (estimate) and ``b_i`` (reference), the yaw that minimises
``sum |b_i - Rz(yaw) a_i|^2`` is ``atan2(sum(a_x b_y - a_y b_x), sum(a_x b_x + a_y b_y))`` and the translation
``t = mean(b) - Rz(yaw) mean(a)``. (evo provides none, origin, SE(3) and Sim(3); see evaluation.py.)
"""

from __future__ import annotations

import numpy as np

from ..so3 import matrix_to_quat_xyzw
from ..types import PoseSeries

ALIGNMENTS = ("none", "origin", "se3", "sim3", "4dof")


def yaw_translation_fit(p_est: np.ndarray, p_ref: np.ndarray) -> tuple[float, np.ndarray]:
    """Least-squares yaw (rad) and translation (3,) with ``p_ref ~ Rz(yaw) p_est + t``."""
    ma, mb = p_est.mean(axis=0), p_ref.mean(axis=0)
    a, b = p_est - ma, p_ref - mb
    yaw = float(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))
    Rz = rz(yaw)
    return yaw, mb - Rz @ ma


def rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def apply_4dof(poses: PoseSeries, yaw: float, t: np.ndarray) -> PoseSeries:
    """The poses moved by ``Rz(yaw)`` and ``t`` (positions and attitudes)."""
    Rz = rz(yaw)
    R = Rz[None] @ poses.R_wb()
    v = None if poses.v_w_mps is None else poses.v_w_mps @ Rz.T
    return PoseSeries(t_s=poses.t_s, p_w_m=poses.p_w_m @ Rz.T + t, q_wb_xyzw=matrix_to_quat_xyzw(R), v_w_mps=v,
                      has_orientation=poses.has_orientation, source=poses.source)
