"""Relative pose by stochastic cloning: the odometry increment between the previous lidar frame (a clone
of the pose taken there) and the current one.

Predicted increment ``dp = R_c^T (p - p_c)`` (in the clone's body frame), ``dR = R_c^T R``; linearised in
the right-perturbation errors of both poses::

    r_p  =  R_c^T dp_err - R_c^T dp_c_err + [dp]x dtheta_c
    r_th =  dtheta - dR^T dtheta_c

Std ``hypot(relative_pos_std_m, relative_pos_std_frac |dp|)`` and ``relative_att_std_deg``. As increments,
drifting odometry constrains the motion between frames and lets GNSS remove the drift.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from ...spec import S
from ...so3 import skew
from ..mech import log3
from .base import CP, CTH, N_MAX, P, TH, Bound, Observation
from .pose import POSE_RESIDUAL, RP, RTH, lidar_rows


def relative_pose(x, clone_p_w: np.ndarray, clone_R_wb: np.ndarray, *, dp_obs_c: np.ndarray, dR_obs: np.ndarray,
                  pos_std_m: float, att_std_rad: float):
    """Odometry increment between the cloned pose (previous lidar frame) and the current pose."""
    Rc_T = clone_R_wb.T
    dp_pred = Rc_T @ (x.p_w_m - clone_p_w)
    dR_pred = Rc_T @ x.R_wb
    H = np.zeros((POSE_RESIDUAL.n, N_MAX))
    H[RP, P] = Rc_T
    H[RP, CP] = -Rc_T
    H[RP, CTH] = skew(dp_pred)
    H[RTH, TH] = np.eye(3)
    H[RTH, CTH] = -dR_pred.T
    r = np.concatenate([dp_obs_c - dp_pred, log3(dR_pred.T @ dR_obs)])
    Rm = np.diag([pos_std_m ** 2] * 3 + [att_std_rad ** 2] * 3)
    return H, r, Rm


class RelativePose(Observation):
    name = "lidar"
    label = "lidar relative pose (cloning)"
    dof = 6
    streams = ("lidar",)
    blocks = frozenset({"P", "TH", "CP", "CTH"})
    enabled_by = "filter.lidar_update"
    keys = {
        "lidar.relative_pos_std_m": S(0.02, "relative update: position increment std, constant part, m", nonneg=True),
        "lidar.relative_pos_std_frac": S(0.01, "relative update: position increment std per metre travelled (0.01 = 1 %)",
                                         nonneg=True),
        "lidar.relative_att_std_deg": S(0.05, "relative update: rotation increment std, deg", positive=True),
    }

    enable_with = {"filter.lidar_update": "relative"}
    disable_with = {"filter.lidar_update": "none"}

    def bind(self, run, s) -> Bound:
        lid = run.lidar
        rows = lidar_rows(run)
        R, p = lid.R_wb()[rows], lid.p_w_m[rows]
        c = s.lidar
        # every increment at once: from frame j-1 to frame j, in frame j-1's body frame
        prev, cur = slice(None, -1), slice(1, None)          # consecutive frames (rows, not state indices)
        dp_c = np.einsum("nji,nj->ni", R[prev], p[cur] - p[prev])
        dR = np.einsum("nji,njk->nik", R[prev], R[cur])
        pos_std = np.hypot(c.relative_pos_std_m, c.relative_pos_std_frac * np.linalg.norm(dp_c, axis=1))
        std_a = c.relative_att_std_rad

        def model(j):
            if j == 0:
                return None                         # the first frame only starts the chain of clones
            return partial(relative_pose, dp_obs_c=dp_c[j - 1], dR_obs=dR[j - 1], pos_std_m=float(pos_std[j - 1]),
                           att_std_rad=std_a)

        return Bound(self.name, self.dof, lid.t_s[rows], model, after=lambda kf, j: kf.clone_pose())


OBSERVATION = RelativePose()
