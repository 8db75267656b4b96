"""Absolute pose (position and attitude), as from lidar matching against a prior map:
``r = [p_obs - p, Log(R^T R_obs)]``.

Drifting odometry used this way passes its drift into the estimate and fights the GNSS; the relative
form (:mod:`.relative_pose`) is the right model for odometry.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from ...spec import S
from ..layout import Layout
from ..mech import log3
from .base import N_MAX, P, TH, Bound, Observation, rows_inside

LIDAR_FORMS = ("relative", "absolute", "none")
# rows of a pose residual: position, then attitude
POSE_RESIDUAL = Layout("pose residual", [("p", 3), ("th", 3)])
RP, RTH = POSE_RESIDUAL.sl("p"), POSE_RESIDUAL.sl("th")


def absolute_pose(x, clone_p=None, clone_R=None, *, p_obs_w: np.ndarray, R_obs_wb: np.ndarray, pos_std_m: float,
                  att_std_rad: float):
    """Absolute pose (position and attitude), as from lidar matching against a prior map."""
    H = np.zeros((POSE_RESIDUAL.n, N_MAX))
    H[RP, P] = np.eye(3)
    H[RTH, TH] = np.eye(3)
    r = np.concatenate([p_obs_w - x.p_w_m, log3(x.R_wb.T @ R_obs_wb)])
    Rm = np.diag([pos_std_m ** 2] * 3 + [att_std_rad ** 2] * 3)
    return H, r, Rm


def lidar_rows(run) -> np.ndarray:
    """The lidar frames inside the run (the stream's rows)."""
    t = run.imu.t_s
    return rows_inside(run.lidar.t_s, float(t[run.k_start]), float(t[-1]))


class AbsolutePose(Observation):
    name = "lidar"
    label = "lidar absolute pose"
    dof = 6
    streams = ("lidar",)
    blocks = frozenset({"P", "TH"})
    enabled_by = "filter.lidar_update"
    keys = {
        "filter.lidar_update": S("relative", "lidar odometry as 'relative' pose increments (stochastic cloning), "
                                             "'absolute' poses, or 'none'", choices=LIDAR_FORMS),
        "lidar.absolute_pos_std_m": S(1.0, "absolute update: position std, m", positive=True),
        "lidar.absolute_att_std_deg": S(1.0, "absolute update: attitude std, deg", positive=True),
    }

    enable_with = {"filter.lidar_update": "absolute"}
    disable_with = {"filter.lidar_update": "none"}

    def bind(self, run, s) -> Bound:
        lid = run.lidar
        rows = lidar_rows(run)
        R = lid.R_wb()
        std_p, std_a = s.lidar.absolute_pos_std_m, s.lidar.absolute_att_std_rad

        def model(j):
            i = rows[j]
            return partial(absolute_pose, p_obs_w=lid.p_w_m[i], R_obs_wb=R[i], pos_std_m=std_p, att_std_rad=std_a)

        return Bound(self.name, self.dof, lid.t_s[rows], model)


OBSERVATION = AbsolutePose()
