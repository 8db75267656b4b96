"""Relative pose by stochastic cloning: the odometry increment between the previous lidar frame (a clone
of the pose taken there) and the current one.

Predicted increment ``dp = R_c^T (p - p_c)`` (in the clone's body frame), ``dR = R_c^T R``; linearised in
the right-perturbation errors of both poses::

    r_p  =  R_c^T dp_err - R_c^T dp_c_err + [dp]x dtheta_c
    r_th =  dtheta - dR^T dtheta_c

Noise per increment (odometry error grows with the motion it measures): position std
``hypot(relative_pos_std_m, relative_pos_std_frac |dp|)``, rotation std
``hypot(relative_att_std_deg, relative_att_std_frac |dtheta|)``. As increments, drifting odometry
constrains the motion between frames and lets GNSS remove the drift.

Two safeguards that need no ground truth:

- **gating** (``lidar.gate_prob``): an increment whose NIS lies beyond that chi-square probability for 6
  dof is rejected (a failed scan match) and counted in the report; the IMU bridges it;
- **adaptive noise** (``lidar.noise_adapt: nis``; ``auto``, the default, is ``nis`` when GNSS is fused): the position and rotation variances are each scaled
  online so that the mean normalised innovation of their block (``r_b^T S_bb^-1 r_b / 3``) is 1:
  covariance matching with exponential forgetting over about ``1 / lidar.adapt_rate`` updates, from past
  innovations only (what an online filter could do). The scales are reported.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from ...spec import S
from ...so3 import skew
from ..mech import log3
from ...so3 import log_so3 as log3_many
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
        "lidar.relative_att_std_deg": S(0.05, "relative update: rotation increment std, constant part, deg", positive=True),
        "lidar.relative_att_std_frac": S(0.0, "relative update: rotation increment std per radian turned (0.02 = 2 %: "
                                              "an odometry that under- or over-rotates turns)", nonneg=True),
        "lidar.gate_prob": S(None, "reject a relative increment whose NIS is beyond this chi-square probability "
                                   "(6 dof), e.g. 0.9999; null = no gate", "float", positive=True, below=1.0, nullable=True),
        "lidar.noise_adapt": S("auto", "'nis' = scale the position and rotation noise online so that each block's "
                                       "mean NIS matches its dof (no ground truth); 'nis_position' = the position block "
                                       "only; 'none' = as configured; 'auto' = nis when GNSS is fused, else none",
                               choices=("auto", "none", "nis", "nis_position")),
        "lidar.adapt_rate": S(0.02, "adaptive noise: forgetting rate per update (0.02 = about 50 updates)", positive=True,
                              below=1.0),
    }
    gate_key = "lidar.gate_prob"

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
        att_std = np.hypot(c.relative_att_std_rad, c.relative_att_std_frac * np.linalg.norm(log3_many(dR), axis=1))
        mode = adapt_mode(s)
        scale = None if mode == "none" else AdaptiveScale(c.adapt_rate, mode == "nis")

        def model(j):
            if j == 0:
                return None                         # the first frame only starts the chain of clones
            kp, ka = (1.0, 1.0) if scale is None else scale.std_factors()
            return partial(relative_pose, dp_obs_c=dp_c[j - 1], dR_obs=dR[j - 1], pos_std_m=float(pos_std[j - 1]) * kp,
                           att_std_rad=float(att_std[j - 1]) * ka)

        return Bound(self.name, self.dof, lid.t_s[rows], model, after=lambda kf, j: kf.clone_pose(),
                     gate=self.gate(s), on_result=None if scale is None else scale.update,
                     summary=None if scale is None else scale.summary)


def adapt_mode(s) -> str:
    """'auto' resolved. Matching the innovations makes the 10 Hz increments consistent, but a white-noise model
    cannot also carry the odometry's slow rotation drift: with no absolute position source that drift goes
    straight into the heading, and the configured (looser) noise that leans on the gyro is the safer choice.
    With GNSS the drift is observed and short-term consistency is what counts."""
    mode = s.lidar.noise_adapt
    if mode != "auto":
        return mode
    return "nis" if s.filter.use_gnss else "none"


class AdaptiveScale:
    """Variance scales of the position and rotation blocks, matched online to the innovations."""

    def __init__(self, rate: float, rotation: bool = True):
        self.rate = rate
        self.blocks = (RP, RTH) if rotation else (RP,)
        self.var = np.ones(2)            # position, rotation
        self.history: list[tuple[float, float, float]] = []

    def std_factors(self) -> tuple[float, float]:
        return float(np.sqrt(self.var[0])), float(np.sqrt(self.var[1]))

    def update(self, t: float, r: np.ndarray, S: np.ndarray, nis: float, accepted: bool) -> None:
        if not accepted:
            return                       # a gated outlier says nothing about the noise of good matches
        for b, sl in enumerate(self.blocks):
            rb = r[sl]
            q = float(rb @ np.linalg.solve(S[sl, sl], rb)) / 3.0
            # multiplicative step toward E[q] = 1, bounded so one wild increment cannot swing it
            self.var[b] = float(np.clip(self.var[b] * (1.0 + self.rate * (min(q, 10.0) - 1.0)), 1e-3, 1e3))
        self.history.append((t, *self.var))

    def summary(self) -> dict:
        """The final std factors and their median over the second half of the drive (the settled value)."""
        h = np.asarray(self.history) if self.history else np.ones((1, 3))
        late = h[h.shape[0] // 2:]
        return {"pos_std_factor": float(np.sqrt(h[-1, 1])), "att_std_factor": float(np.sqrt(h[-1, 2])),
                "pos_std_factor_median": float(np.sqrt(np.median(late[:, 1]))),
                "att_std_factor_median": float(np.sqrt(np.median(late[:, 2])))}


OBSERVATION = RelativePose()
