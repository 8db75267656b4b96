"""Absolute pose (position and attitude), as from lidar matching against a prior map:
``r = [p_obs - p, Log(R^T R_obs)]``.

Drifting odometry used this way passes its drift into the estimate and fights the GNSS; the relative
form (:mod:`.relative_pose`) is the right model for odometry.
"""

from __future__ import annotations

from functools import partial

import numpy as np
from numba import njit

from ...spec import S
from ..layout import Layout
from ..mech import log3
from .base import P_ID, TH_ID, XP, XR, Bound, Kernel, Observation, kernel_model, rows_inside

LIDAR_FORMS = ("relative", "absolute", "none")
# rows of a pose residual: position, then attitude
POSE_RESIDUAL = Layout("pose residual", [("p", 3), ("th", 3)])
RP, RTH = POSE_RESIDUAL.sl("p"), POSE_RESIDUAL.sl("th")


# data row of one absolute pose: position, attitude R_wb row-major, position std, attitude std
ROW = Layout("absolute pose data row", [("p", 3), ("R", 9), ("std_p", 1), ("std_th", 1)])
OP, OR, OSP, OSTH = (ROW.start(b) for b in ("p", "R", "std_p", "std_th"))
NRES = POSE_RESIDUAL.n


@njit(cache=True)
def absolute_pose_kernel(x, xc, row, H, r, Rm):
    """Absolute pose (position and attitude), as from lidar matching against a prior map (6 rows)."""
    H[:NRES, :] = 0.0
    Rm[:NRES, :NRES] = 0.0
    D = np.empty((3, 3))              # R_hat^T R_obs
    for i in range(3):
        for k in range(3):
            D[i, k] = x[XR + i] * row[OR + k] + x[XR + 3 + i] * row[OR + 3 + k] + x[XR + 6 + i] * row[OR + 6 + k]
    th = log3(D)
    for i in range(3):
        H[i, P_ID + i] = 1.0
        H[3 + i, TH_ID + i] = 1.0
        r[i] = row[OP + i] - x[XP + i]
        r[3 + i] = th[i]
        Rm[i, i] = row[OSP] * row[OSP]
        Rm[3 + i, 3 + i] = row[OSTH] * row[OSTH]
    return NRES


def absolute_pose(x, clone_p=None, clone_R=None, *, p_obs_w: np.ndarray, R_obs_wb: np.ndarray, pos_std_m: float,
                  att_std_rad: float):
    """Absolute pose (position and attitude), as from lidar matching against a prior map."""
    return kernel_model(absolute_pose_kernel, x, row=ROW.pack(p=p_obs_w, R=np.asarray(R_obs_wb, float).ravel(),
                                                              std_p=pos_std_m, std_th=att_std_rad))


def lidar_rows(run) -> np.ndarray:
    """The lidar frames inside the run (the stream's rows)."""
    t = run.imu.t_s
    return rows_inside(run.lidar.t_s, float(t[run.k_start]), float(t[-1]))


class AbsolutePose(Observation):
    name = "lidar"
    kernel = staticmethod(absolute_pose_kernel)
    label = "lidar absolute pose"
    dof = 6
    streams = ("lidar",)
    blocks = frozenset({"P", "TH"})
    enabled_by = "filter.lidar_update"
    keys = {
        "filter.lidar_update": S("relative", "lidar odometry as 'relative' pose increments (stochastic cloning), "
                                             "'absolute' poses, or 'none'", choices=LIDAR_FORMS),
        "lidar.absolute_pos_std_m": S(1.0, "absolute update: position std, m", positive=True, reads="filter"),
        "lidar.absolute_att_std_deg": S(1.0, "absolute update: attitude std, deg", positive=True, reads="filter"),
    }

    # the same gate as the relative form (the key is declared there): map matching has outliers of its own (a wrong
    # match, a changed scene), and the simulator's map-matching lidar makes them (lidar.outlier_prob)
    gate_key = "lidar.gate_prob"

    enable_with = {"filter.lidar_update": "absolute"}
    disable_with = {"filter.lidar_update": "none"}

    def bind(self, run, s) -> Bound:
        lid = run.lidar
        rows = lidar_rows(run)
        R = lid.R_wb()
        std_p, std_a = s.lidar.absolute_pos_std_m, s.lidar.absolute_att_std_rad

        data = ROW.columns(p=lid.p_w_m[rows], R=R[rows].reshape(-1, 9), std_p=np.full(rows.size, std_p),
                           std_th=np.full(rows.size, std_a))

        def model(j):
            return partial(kernel_model, absolute_pose_kernel, row=data[j])

        return Bound(self.name, self.dof, lid.t_s[rows], model, gate=self.gate(s),
                     kernel=Kernel(absolute_pose_kernel, np.ascontiguousarray(data)))


OBSERVATION = AbsolutePose()
