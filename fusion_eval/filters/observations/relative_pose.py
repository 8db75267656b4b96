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
from numba import njit

from ...spec import S
from .. import linalg
from ..layout import Layout
from ..mech import log3
from ...so3 import log_so3 as log3_many
from .base import (CLONE_P, CLONE_R, CP_ID, CTH_ID, P_ID, TH_ID, XP, XR, Bound, Kernel, Observation, kernel_model,
                   matched_variance)
from .pose import POSE_RESIDUAL, RP, RTH, lidar_rows

# data row of one lidar frame: 1 if it updates (0: the first frame, which only clones), the increment from the
# previous frame in its body frame, the rotation increment row-major, position std, rotation std
ROW = Layout("relative pose data row", [("update", 1), ("dp", 3), ("dR", 9), ("std_p", 1), ("std_th", 1), ("frame", 1)])
UPD, DP, DR, STD_P, STD_TH, FRAME = (ROW.start(b) for b in ("update", "dp", "dR", "std_p", "std_th", "frame"))
# the frame of the position increment (the data row's 'frame' column; lidar.relative_frame)
FRAMES = {"body": 0.0, "world": 1.0, "heading": 2.0}
NRES = POSE_RESIDUAL.n


@njit(cache=True)
def relative_pose_kernel(x, xc, row, H, r, Rm):
    """Odometry increment between the cloned pose (previous lidar frame) and the current pose (6 rows)."""
    if row[UPD] == 0.0:
        return 0
    H[:NRES, :] = 0.0
    Rm[:NRES, :NRES] = 0.0
    dpw = np.empty(3)
    for i in range(3):
        dpw[i] = x[XP + i] - xc[CLONE_P + i]
    dR = np.empty((3, 3))             # R_c^T R
    for i in range(3):
        for k in range(3):
            dR[i, k] = (xc[CLONE_R + i] * x[XR + k] + xc[CLONE_R + 3 + i] * x[XR + 3 + k]
                        + xc[CLONE_R + 6 + i] * x[XR + 6 + k])
    E = np.empty((3, 3))              # dR^T dR_obs
    for i in range(3):
        for k in range(3):
            E[i, k] = dR[0, i] * row[DR + k] + dR[1, i] * row[DR + 3 + k] + dR[2, i] * row[DR + 6 + k]
    th = log3(E)
    for i in range(3):
        for k in range(3):
            H[3 + i, CTH_ID + k] = -dR[k, i]                  # -dR^T
        H[3 + i, TH_ID + i] = 1.0
        r[3 + i] = th[i]
        Rm[i, i] = row[STD_P] * row[STD_P]
        Rm[3 + i, 3 + i] = row[STD_TH] * row[STD_TH]
    if row[FRAME] == 1.0:
        # the increment in the odometry's world frame: r_p = dp_w - (p - p_c), no attitude in it
        for i in range(3):
            H[i, P_ID + i] = 1.0
            H[i, CP_ID + i] = -1.0
            r[i] = row[DP + i] - dpw[i]
        return NRES
    if row[FRAME] == 2.0:
        # the increment in the clone's heading frame (its yaw only): r_p = dp_h - Rz(psi_c)^T (p - p_c); the yaw of a
        # right perturbation moves by (R21 dth_y + R22 dth_z) / (R00^2 + R10^2) (ZYX angles)
        r00, r10 = xc[CLONE_R], xc[CLONE_R + 3]
        c2 = r00 * r00 + r10 * r10
        cp, sp = r00 / np.sqrt(c2), r10 / np.sqrt(c2)
        h0, h1 = cp * dpw[0] + sp * dpw[1], -sp * dpw[0] + cp * dpw[1]
        H[0, P_ID], H[0, P_ID + 1], H[1, P_ID], H[1, P_ID + 1], H[2, P_ID + 2] = cp, sp, -sp, cp, 1.0
        H[0, CP_ID], H[0, CP_ID + 1], H[1, CP_ID], H[1, CP_ID + 1], H[2, CP_ID + 2] = -cp, -sp, sp, -cp, -1.0
        dy, dz = xc[CLONE_R + 7] / c2, xc[CLONE_R + 8] / c2          # d psi / d dth_c (y, z)
        H[0, CTH_ID + 1], H[0, CTH_ID + 2] = h1 * dy, h1 * dz
        H[1, CTH_ID + 1], H[1, CTH_ID + 2] = -h0 * dy, -h0 * dz
        r[0], r[1], r[2] = row[DP] - h0, row[DP + 1] - h1, row[DP + 2] - dpw[2]
        return NRES
    dp = np.empty(3)                  # R_c^T (p - p_c): only the body-frame form needs it
    for i in range(3):
        dp[i] = xc[CLONE_R + i] * dpw[0] + xc[CLONE_R + 3 + i] * dpw[1] + xc[CLONE_R + 6 + i] * dpw[2]
    for i in range(3):
        for k in range(3):
            H[i, P_ID + k] = xc[CLONE_R + 3 * k + i]          # R_c^T
            H[i, CP_ID + k] = -xc[CLONE_R + 3 * k + i]
        r[i] = row[DP + i] - dp[i]
    # [dp]x on the clone's attitude error
    H[0, CTH_ID + 1], H[0, CTH_ID + 2] = -dp[2], dp[1]
    H[1, CTH_ID], H[1, CTH_ID + 2] = dp[2], -dp[0]
    H[2, CTH_ID], H[2, CTH_ID + 1] = -dp[1], dp[0]
    return NRES


def relative_pose(x, clone_p_w: np.ndarray, clone_R_wb: np.ndarray, *, dp_obs_c: np.ndarray, dR_obs: np.ndarray,
                  pos_std_m: float, att_std_rad: float, frame: str = "body"):
    """Odometry increment between the cloned pose (previous lidar frame) and the current pose; ``frame``: the
    position increment ``dp_obs_c`` is in the clone's body frame, the world frame or the clone's heading frame."""
    row = ROW.pack(update=1.0, dp=dp_obs_c, dR=np.asarray(dR_obs, float).ravel(), std_p=pos_std_m, std_th=att_std_rad,
                   frame=FRAMES[frame])
    return kernel_model(relative_pose_kernel, x, clone_p_w, clone_R_wb, row)


class RelativePose(Observation):
    name = "lidar"
    kernel = staticmethod(relative_pose_kernel)
    label = "lidar relative pose (cloning)"
    dof = 6
    streams = ("lidar",)
    blocks = frozenset({"P", "TH", "CP", "CTH"})
    enabled_by = "filter.lidar_update"
    keys = {
        "lidar.relative_pos_std_m": S(0.02, "relative update: position increment std, constant part, m", nonneg=True, reads="filter"),
        "lidar.relative_pos_std_frac": S(0.01, "relative update: position increment std per metre travelled (0.01 = 1 %)",
                                         nonneg=True, reads="filter"),
        "lidar.relative_att_std_deg": S(0.05, "relative update: rotation increment std, constant part, deg", positive=True, reads="filter"),
        "lidar.relative_att_std_frac": S(0.0, "relative update: rotation increment std per radian turned (0.02 = 2 %: "
                                              "an odometry that under- or over-rotates turns)", nonneg=True, reads="filter"),
        "lidar.relative_frame": S("auto", "frame of the position increment: 'body' (the previous frame's, rotated by the "
                                          "filter's attitude), 'world' (the odometry's own map frame), 'heading' (the "
                                          "previous frame's yaw only: horizontal as 'body', vertical as 'world') or "
                                          "'auto' = body when GNSS is fused (or under the batch smoother), else heading",
                                  choices=("auto", *FRAMES)),
        "lidar.gate_prob": S(None, "reject a lidar update (a relative increment or an absolute pose) whose NIS is "
                                   "beyond this chi-square probability (6 dof), e.g. 0.9999; null = no gate", "float", positive=True, below=1.0, nullable=True, reads="filter"),
        "lidar.noise_adapt": S("auto", "'nis' = scale the position and rotation noise online so that each block's "
                                       "mean NIS matches its dof (no ground truth); 'nis_position' = the position block "
                                       "only; 'none' = as configured; 'auto' = nis when GNSS is fused, else none",
                               choices=("auto", "none", "nis", "nis_position"), reads="filter"),
        "lidar.adapt_rate": S(0.02, "adaptive noise: forgetting rate per update (0.02 = about 50 updates)", positive=True,
                              below=1.0, reads="filter"),
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
        frame = c.relative_frame if c.relative_frame != "auto" else frame_of("auto", s.filter.use_gnss, s.smoother.method)
        if frame == "heading":                              # Rz(psi_prev)^T (p_cur - p_prev)
            psi = np.arctan2(R[prev][:, 1, 0], R[prev][:, 0, 0])
            cp, sp, dw = np.cos(psi), np.sin(psi), p[cur] - p[prev]
            dp_frame = np.column_stack([cp * dw[:, 0] + sp * dw[:, 1], -sp * dw[:, 0] + cp * dw[:, 1], dw[:, 2]])
        else:
            dp_frame = (p[cur] - p[prev]) if frame == "world" else dp_c
        dR = np.einsum("nji,njk->nik", R[prev], R[cur])
        # the per-frame noise over every frame interval an increment spans (frames merged onto one IMU stamp: a lidar
        # faster than the IMU, the frames inside an IMU gap); the distance and angle terms take the increment whole
        span = getattr(run, "lidar_span", None)
        root = np.sqrt(span[rows][cur]) if span is not None else 1.0
        pos_std = np.hypot(c.relative_pos_std_m * root, c.relative_pos_std_frac * np.linalg.norm(dp_c, axis=1))
        att_std = np.hypot(c.relative_att_std_rad * root, c.relative_att_std_frac * np.linalg.norm(log3_many(dR), axis=1))
        mode = adapt_mode(s)
        scale = None if mode == "none" else AdaptiveScale(c.adapt_rate, mode == "nis")

        # row j: the increment into frame j (the first frame only starts the chain of clones)
        data = np.zeros((rows.size, ROW.n))
        if rows.size > 1:
            data[cur] = ROW.columns(update=np.ones(rows.size - 1), dp=dp_frame,
                                    dR=dR.reshape(-1, 9), std_p=pos_std, std_th=att_std,
                                    frame=np.full(rows.size - 1, FRAMES[frame]))

        def model(j):
            if j == 0:
                return None
            # the noise scales as they are now (the batch smoother reads the model after the update moved them)
            return partial(kernel_model, relative_pose_kernel, row=data[j],
                           rm_scale=None if scale is None else scale.rm_scale())

        blocks = () if scale is None else tuple((sl.start, sl.stop) for sl in scale.blocks)
        return Bound(self.name, self.dof, lid.t_s[rows], model, after=lambda kf, j: kf.clone_pose(),
                     gate=self.gate(s), on_result=None if scale is None else scale.update,
                     summary=None if scale is None else scale.summary,
                     kernel=Kernel(relative_pose_kernel, data, clone_after=True, adapt_blocks=blocks,
                                   adapt_rate=0.0 if scale is None else scale.rate), adapt=scale)


def frame_of(frame: str, use_gnss: bool, smoother: str) -> str:
    """'auto' resolved. With GNSS the fixes hold the filter's attitude, and the odometry's map, which tilts and
    turns as it drifts, would fight them in any frame of its own (world: kitti-00 4.08 m against 0.72); without an
    absolute position source the odometry's gravity-aligned map is the only vertical reference over distance, and
    the filter's pitch, held by an accelerometer with unmodelled lag, would tilt each increment ('heading' keeps
    the filter's yaw, which removes a map's rotation about the vertical). The batch smoother's between-factors
    are body-frame."""
    if frame != "auto":
        return frame
    return "body" if use_gnss or smoother == "batch" else "heading"


def adapt_mode(s) -> str:
    """'auto' resolved. Matching the innovations makes the 10 Hz increments consistent, but a white-noise model
    cannot also carry the odometry's slow rotation drift: with no absolute position source that drift goes
    straight into the heading, and the configured (looser) noise that leans on the gyro is the safer choice.
    With GNSS the drift is observed and short-term consistency is what counts."""
    return resolved_adapt_mode(s.lidar.noise_adapt, s.filter.use_gnss)


def resolved_adapt_mode(mode: str, use_gnss: bool) -> str:
    """:func:`adapt_mode` of the two values it depends on (a run's report and a tune's first trial show it)."""
    return mode if mode != "auto" else ("nis" if use_gnss else "none")


class AdaptiveScale:
    """Variance scales of the position and rotation blocks, matched online to the innovations."""

    def __init__(self, rate: float, rotation: bool = True):
        self.rate = rate
        self.blocks = (RP, RTH) if rotation else (RP,)
        self.var = np.ones(2)            # position, rotation
        self.history: list = []          # (t, var_p, var_th) rows, or (k, 3) blocks of them (the compiled replay)

    def rm_scale(self) -> tuple:
        """``((start, stop, variance factor), ...)`` of the adapted residual blocks, now (for :func:`kernel_model`)."""
        return tuple((sl.start, sl.stop, float(self.var[b])) for b, sl in enumerate(self.blocks))

    def update(self, t: float, r: np.ndarray, S: np.ndarray, nis: float, accepted: bool) -> None:
        if not accepted:
            return                       # a gated outlier says nothing about the noise of good matches
        L, y = np.zeros((3, 3)), np.zeros(3)
        for b, sl in enumerate(self.blocks):
            q = linalg.block_nis(S, sl.start, sl.stop, r, L, y) / (sl.stop - sl.start)
            self.var[b] = matched_variance(float(self.var[b]), q, self.rate)
        self.history.append((t, *self.var))

    def summary(self) -> dict:
        """The final std factors and their median over the second half of the drive (the settled value)."""
        h = np.vstack([np.reshape(e, (-1, 3)) for e in self.history]) if self.history else np.ones((1, 3))
        late = h[h.shape[0] // 2:]
        return {"pos_std_factor": float(np.sqrt(h[-1, 1])), "att_std_factor": float(np.sqrt(h[-1, 2])),
                "pos_std_factor_median": float(np.sqrt(np.median(late[:, 1]))),
                "att_std_factor_median": float(np.sqrt(np.median(late[:, 2])))}


OBSERVATION = RelativePose()
