"""GNSS position fixes: ``z = p + R l`` (the antenna, at lever arm ``l`` in the body frame), world frame.

With a lever arm the attitude enters as ``dz/dtheta = -R [l]x``; the fix's 1-sigma per axis is the
stream's (after any degradation, see ``gnss.std_m``).
"""

from __future__ import annotations

from functools import partial

import numpy as np

from ...spec import S
from ...so3 import skew
from .base import N_MAX, P, TH, Bound, Observation, rows_inside


def gnss_position(x, clone_p=None, clone_R=None, *, p_obs_w: np.ndarray, std_w: np.ndarray, lever_arm_b: np.ndarray):
    """GNSS antenna position ``p + R l``; with a lever arm the attitude enters as ``-R [l]x``."""
    H = np.zeros((3, N_MAX))
    H[:, P] = np.eye(3)
    H[:, TH] = -x.R_wb @ skew(lever_arm_b)
    r = p_obs_w - (x.p_w_m + x.R_wb @ lever_arm_b)
    return H, r, np.diag(np.asarray(std_w, float) ** 2)


class GnssPosition(Observation):
    name = "gnss"
    label = "GNSS position"
    dof = 3
    streams = ("gnss",)
    blocks = frozenset({"P", "TH"})
    enabled_by = "filter.use_gnss"
    gate_key = "gnss.gate_prob"
    keys = {
        "filter.use_gnss": S(True, "fuse GNSS position fixes"),
        "gnss.std_m": S("auto", "GNSS std given to the filter per axis, m; 'auto' = sqrt(reported accuracy^2 + added noise^2)",
                        "vec3", positive=True, auto=True),
        "gnss.lever_arm_b_m": S([0.0, 0.0, 0.0], "antenna position in the body frame, m"),
        "gnss.gate_prob": S(None, "reject a fix whose NIS lies beyond this chi-square probability (e.g. 0.999); "
                                  "null = no gating", "float", positive=True, nullable=True, below_one=True),
    }

    def bind(self, run, s) -> Bound:
        g = run.gnss
        t = run.imu.t_s
        rows = rows_inside(g.t_s, float(t[run.k_start]), float(t[-1]))
        lever = np.asarray(s.gnss.lever_arm_b_m, float)

        def model(j):
            i = rows[j]
            return partial(gnss_position, p_obs_w=g.p_w_m[i], std_w=g.std_w_m[i], lever_arm_b=lever)

        return Bound(self.name, self.dof, g.t_s[rows], model, gate=self.gate(s))


OBSERVATION = GnssPosition()
