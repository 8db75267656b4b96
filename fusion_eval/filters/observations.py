"""Observation models: each returns the textbook ``(H, r, R)`` for the error state.

``H`` has ``N_CORE + CLONE_SIZE`` columns (clone columns are zero unless the model uses the clone);
the filter slices it to its current size. Residuals ``r = z - h(x_hat)`` with the attitude part
``Log(R_hat^T R_obs)`` so that a right-perturbation ``R_obs = R_hat Exp(dtheta)`` gives ``r = dtheta``.
"""

from __future__ import annotations

import numpy as np

from ..so3 import skew
from .kernels import log3
from .state import NominalState
from .kernels import CLONE_P_ID, CLONE_SIZE, CLONE_TH_ID, N_CORE, P_ID, TH_ID, V_ID

N_MAX = N_CORE + CLONE_SIZE
# Every model is called as model(x, clone_p, clone_R) once its keyword arguments are bound
# (functools.partial), so an iterated update can re-evaluate it at each iterate.


def gnss_position(x: NominalState, clone_p=None, clone_R=None, *, p_obs_w: np.ndarray, std_w: np.ndarray,
                  lever_arm_b: np.ndarray):
    """GNSS antenna position ``p + R l``; with a lever arm the attitude enters as ``-R [l]x``."""
    H = np.zeros((3, N_MAX))
    H[:, P_ID:P_ID + 3] = np.eye(3)
    H[:, TH_ID:TH_ID + 3] = -x.R_wb @ skew(lever_arm_b)
    r = p_obs_w - (x.p_w_m + x.R_wb @ lever_arm_b)
    return H, r, np.diag(np.asarray(std_w, float) ** 2)


def absolute_pose(x: NominalState, clone_p=None, clone_R=None, *, p_obs_w: np.ndarray, R_obs_wb: np.ndarray,
                  pos_std_m: float, att_std_rad: float):
    """Absolute pose (position and attitude), as from lidar matching against a prior map."""
    H = np.zeros((6, N_MAX))
    H[0:3, P_ID:P_ID + 3] = np.eye(3)
    H[3:6, TH_ID:TH_ID + 3] = np.eye(3)
    r = np.concatenate([p_obs_w - x.p_w_m, log3(x.R_wb.T @ R_obs_wb)])
    Rm = np.diag([pos_std_m ** 2] * 3 + [att_std_rad ** 2] * 3)
    return H, r, Rm


def relative_pose(x: NominalState, clone_p_w: np.ndarray, clone_R_wb: np.ndarray, *, dp_obs_c: np.ndarray,
                  dR_obs: np.ndarray, pos_std_m: float, att_std_rad: float):
    """Odometry increment between the cloned pose (previous lidar frame) and the current pose.

    Predicted increment: ``dp = R_c^T (p - p_c)`` (in the clone's body frame), ``dR = R_c^T R``.
    Linearised in the right-perturbation errors of both poses::

        r_p  =  R_c^T dp_err - R_c^T dp_c_err + [dp]x dtheta_c
        r_th =  dtheta - dR^T dtheta_c
    """
    Rc_T = clone_R_wb.T
    dp_pred = Rc_T @ (x.p_w_m - clone_p_w)
    dR_pred = Rc_T @ x.R_wb
    H = np.zeros((6, N_MAX))
    H[0:3, P_ID:P_ID + 3] = Rc_T
    H[0:3, CLONE_P_ID:CLONE_P_ID + 3] = -Rc_T
    H[0:3, CLONE_TH_ID:CLONE_TH_ID + 3] = skew(dp_pred)
    H[3:6, TH_ID:TH_ID + 3] = np.eye(3)
    H[3:6, CLONE_TH_ID:CLONE_TH_ID + 3] = -dR_pred.T
    r = np.concatenate([dp_obs_c - dp_pred, log3(dR_pred.T @ dR_obs)])
    Rm = np.diag([pos_std_m ** 2] * 3 + [att_std_rad ** 2] * 3)
    return H, r, Rm


def body_velocity(x: NominalState, clone_p=None, clone_R=None, *, v_obs_b: np.ndarray, std_b: np.ndarray,
                  rows: tuple[int, ...] = (0, 1, 2)):
    """Body-frame velocity ``v_b = R^T v`` (rows: 0 forward, 1 lateral, 2 vertical).

    ``d v_b / d dv = R^T`` (R_bw) and ``d v_b / d dtheta = [v_b]x`` (``R = R_hat Exp(dtheta)``). An
    odometer observes the forward row; the non-holonomic constraint observes lateral and vertical = 0.
    """
    v_b = x.R_wb.T @ x.v_w_mps
    rows = list(rows)
    H = np.zeros((3, N_MAX))
    H[:, V_ID:V_ID + 3] = x.R_wb.T
    H[:, TH_ID:TH_ID + 3] = skew(v_b)
    r = np.asarray(v_obs_b, float) - v_b
    return H[rows], r[rows], np.diag(np.asarray(std_b, float)[rows] ** 2)
