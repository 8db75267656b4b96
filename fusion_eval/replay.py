"""Time-ordered replay of IMU samples and observations through the error-state filter.

Observations are sorted by time (lidar before GNSS at equal stamps); the filter is propagated to
each observation's own stamp (interpolating the IMU between samples, see ``kernels.predict_to``),
updated, and the state is recorded at every IMU sample.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .config import FilterParams
from .filters import kernels as kn
from .filters import observations as obs
from .filters.eskf import ErrorStateKF, dead_reckon
from .prepare import Prepared
from .so3 import matrix_to_quat_xyzw
from .types import PoseSeries

log = logging.getLogger(__name__)

LIDAR, GNSS = 0, 1


@dataclass(frozen=True)
class FilterOutput:
    """The filter's record at the IMU stamps from the start sample on."""

    fused: PoseSeries
    accel_bias_b: np.ndarray        # (N, 3) m/s^2
    gyro_bias_b: np.ndarray         # (N, 3) rad/s
    sigma: np.ndarray               # (N, 15) 1-sigma of the error state
    P_pos_att: np.ndarray           # (N, 6, 6) covariance of [dp, dtheta] (theta: right perturbation)
    nis: dict                       # kind -> {"t_s": (M,), "nis": (M,), "dof": int}
    imu_only: PoseSeries
    n_imu_samples: int


def process_params(fp: FilterParams, imu_t: np.ndarray) -> np.ndarray:
    prm = np.zeros(kn.N_PRM)
    prm[kn.PRM_G] = fp.gravity_mps2
    prm[kn.PRM_QA] = fp.accel_noise
    prm[kn.PRM_QG] = fp.gyro_noise
    random_walk = fp.bias_model == "random_walk"
    prm[kn.PRM_QBA] = fp.accel_bias_rw if random_walk else 0.0
    prm[kn.PRM_QBG] = fp.gyro_bias_rw if random_walk else 0.0
    prm[kn.PRM_GAP_DT] = fp.gap_factor * float(np.median(np.diff(imu_t))) if imu_t.size > 1 else np.inf
    prm[kn.PRM_GAP_SCALE2] = fp.gap_noise_scale ** 2
    return prm


def replay(prep: Prepared, fp: FilterParams, progress: Callable[[float], None] | None = None) -> FilterOutput:
    imu = prep.imu
    t_imu = np.ascontiguousarray(imu.t_s)
    f_imu = np.ascontiguousarray(imu.f_b_mps2)
    w_imu = np.ascontiguousarray(imu.w_b_rps)
    prm = process_params(fp, t_imu)
    k0 = prep.k_start
    t0, t_end = float(t_imu[k0]), float(t_imu[-1])
    P0 = np.diag(fp.init_std ** 2)
    kf = ErrorStateKF(prep.x0, P0, prm, t_imu, f_imu, w_imu, k0)

    events: list[tuple[float, int, int]] = []
    lidar = prep.lidar if fp.lidar_update != "none" else None
    if lidar is not None:
        R_lidar = lidar.R_wb()
        idx = np.flatnonzero((lidar.t_s >= t0 - 1e-9) & (lidar.t_s <= t_end))
        events += [(float(lidar.t_s[i]), LIDAR, int(i)) for i in idx]
    gnss = prep.gnss if fp.use_gnss else None
    if gnss is not None:
        idx = np.flatnonzero((gnss.t_s >= t0 - 1e-9) & (gnss.t_s <= t_end))
        events += [(float(gnss.t_s[i]), GNSS, int(i)) for i in idx]
    events.sort()

    nis = {"lidar": ([], []), "gnss": ([], [])}
    prev = None  # (p_w, R_wb) of the previous lidar frame, for relative updates
    n_ev = len(events)
    step = max(1, n_ev // 100)
    for j, (t, kind, i) in enumerate(events):
        kf.predict_to(max(t, kf.t))
        if kind == LIDAR:
            p_obs, R_obs = lidar.p_w_m[i], R_lidar[i]
            if fp.lidar_update == "absolute":
                H, r, Rm = obs.absolute_pose(kf.x, p_obs, R_obs, fp.abs_pos_std_m, fp.abs_att_std_rad)
                nis["lidar"][0].append(t)
                nis["lidar"][1].append(kf.update(H, r, Rm))
            else:
                if prev is not None:
                    dp_c = prev[1].T @ (p_obs - prev[0])
                    dR = prev[1].T @ R_obs
                    pos_std = float(np.hypot(fp.rel_pos_std_m, fp.rel_pos_std_frac * np.linalg.norm(dp_c)))
                    H, r, Rm = obs.relative_pose(kf.x, kf.clone_p, kf.clone_R, dp_c, dR, pos_std, fp.rel_att_std_rad)
                    nis["lidar"][0].append(t)
                    nis["lidar"][1].append(kf.update(H, r, Rm))
                kf.clone_pose()
                prev = (p_obs, R_obs)
        else:
            H, r, Rm = obs.gnss_position(kf.x, gnss.p_w_m[i], gnss.std_w_m[i], fp.gnss_lever_arm_b_m)
            nis["gnss"][0].append(t)
            nis["gnss"][1].append(kf.update(H, r, Rm))
        if progress is not None and j % step == 0:
            progress(j / n_ev)
    kf.predict_to(t_end)
    if progress is not None:
        progress(1.0)

    sl = slice(k0, None)
    fused = PoseSeries(t_s=t_imu[sl], p_w_m=kf.rec_p[sl], q_wb_xyzw=matrix_to_quat_xyzw(kf.rec_R[sl]),
                       v_w_mps=kf.rec_v[sl], source="fused")
    dr_p, dr_R = dead_reckon(prep.x0, prm, t_imu, f_imu, w_imu, k0)
    dr_p, dr_R = dr_p[sl], dr_R[sl]
    finite = np.all(np.isfinite(dr_p), axis=1) & np.all(np.abs(dr_p) < 1e9, axis=1)
    imu_only = PoseSeries(t_s=t_imu[sl][finite], p_w_m=dr_p[finite], q_wb_xyzw=matrix_to_quat_xyzw(dr_R[finite]),
                          source="imu_only")
    dof = {"lidar": 6, "gnss": 3}
    return FilterOutput(
        fused=fused, accel_bias_b=kf.rec_ba[sl].copy(), gyro_bias_b=kf.rec_bg[sl].copy(),
        sigma=np.sqrt(np.maximum(kf.rec_Pdiag[sl], 0.0)), P_pos_att=kf.rec_Ppt[sl],
        nis={k: {"t_s": np.array(v[0]), "nis": np.array(v[1]), "dof": dof[k]} for k, v in nis.items() if v[0]},
        imu_only=imu_only, n_imu_samples=int(t_imu.size - k0),
    )
