"""GNSS position fixes: ``z = p + R l`` (the antenna, at lever arm ``l`` in the body frame), world frame.

With a lever arm the attitude enters as ``dz/dtheta = -R [l]x``; the fix's 1-sigma per axis is the
stream's (after any degradation, see ``gnss.std_m``).
"""

from __future__ import annotations

from functools import partial

import numpy as np
from numba import njit

from ...spec import S
from ..layout import Layout
from .base import P_ID, TH_ID, XP, XR, Bound, Kernel, Observation, kernel_model, rows_inside

# data row of one fix: observed antenna position, std per axis, lever arm
ROW = Layout("gnss position data row", [("p", 3), ("std", 3), ("lever", 3)])
GP, GSTD, GLEV = (ROW.start(b) for b in ("p", "std", "lever"))
NRES = ROW["p"].size


@njit(cache=True)
def gnss_position_kernel(x, xc, row, H, r, Rm):
    """GNSS antenna position ``p + R l``; with a lever arm the attitude enters as ``-R [l]x`` (3 rows)."""
    l0, l1, l2 = row[GLEV], row[GLEV + 1], row[GLEV + 2]
    H[:NRES, :] = 0.0
    Rm[:NRES, :NRES] = 0.0
    for i in range(3):
        a0, a1, a2 = x[XR + 3 * i], x[XR + 3 * i + 1], x[XR + 3 * i + 2]
        H[i, P_ID + i] = 1.0
        # -(R [l]x)[i, :]
        H[i, TH_ID] = -(a1 * l2 - a2 * l1)
        H[i, TH_ID + 1] = -(a2 * l0 - a0 * l2)
        H[i, TH_ID + 2] = -(a0 * l1 - a1 * l0)
        r[i] = row[GP + i] - (x[XP + i] + a0 * l0 + a1 * l1 + a2 * l2)
        Rm[i, i] = row[GSTD + i] * row[GSTD + i]
    return NRES


def gnss_position(x, clone_p=None, clone_R=None, *, p_obs_w: np.ndarray, std_w: np.ndarray, lever_arm_b: np.ndarray):
    """GNSS antenna position ``p + R l``; with a lever arm the attitude enters as ``-R [l]x``."""
    return kernel_model(gnss_position_kernel, x, row=ROW.pack(p=p_obs_w, std=np.asarray(std_w, float) * np.ones(3),
                                                              lever=lever_arm_b))


class GnssPosition(Observation):
    name = "gnss"
    kernel = staticmethod(gnss_position_kernel)
    label = "GNSS position"
    read_elsewhere = frozenset({"gnss.lever_arm_b_m"})          # the GNSS's plausibility checks take the antenna's too
    dof = 3
    streams = ("gnss",)
    jumps = True
    blocks = frozenset({"P", "TH"})
    enabled_by = "filter.use_gnss"
    gate_key = "gnss.gate_prob"
    keys = {
        "filter.use_gnss": S(True, "fuse GNSS position fixes"),
        "gnss.std_m": S("auto", "GNSS std given to the filter per axis, m; 'auto' = sqrt(reported accuracy^2 + added noise^2)",
                        "vec3", positive=True, auto=True),
        "gnss.std_scale": S(1.0, "factor on the GNSS std given to the filter (after gnss.std_m): one number to tune "
                                 "that keeps the per-fix accuracy the receiver reports", positive=True, reads="filter"),
        "gnss.lever_arm_b_m": S([0.0, 0.0, 0.0], "antenna position in the body frame, m"),
        "gnss.gate_prob": S(None, "reject a fix whose NIS lies beyond this chi-square probability (e.g. 0.999); "
                                  "null = no gating", "float", positive=True, nullable=True, below_one=True),
    }

    def bind(self, run, s) -> Bound:
        g = run.gnss
        t = run.imu.t_s
        rows = rows_inside(g.t_s, float(t[run.k_start]), float(t[-1]))
        lever = np.asarray(s.gnss.lever_arm_b_m, float)

        data = ROW.columns(p=g.p_w_m[rows], std=g.std_w_m[rows] * float(s.gnss.std_scale),
                           lever=np.tile(lever, (rows.size, 1)))

        def model(j):
            return partial(kernel_model, gnss_position_kernel, row=data[j])

        return Bound(self.name, self.dof, g.t_s[rows], model, gate=self.gate(s),
                     kernel=Kernel(gnss_position_kernel, np.ascontiguousarray(data)))


OBSERVATION = GnssPosition()
