"""Time-ordered replay of IMU samples and observations through the error-state filter.

Observations are sorted by time (lidar before GNSS at equal stamps); the filter is propagated to
each observation's own stamp (interpolating the IMU between samples, see ``propagate.predict_to``),
updated, and the state is recorded at every IMU sample.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import partial
from typing import Callable

import numpy as np

from .config import FilterParams
from .filters import kernels as kn
from .filters import observations as obs
from .filters.eskf import dead_reckon
from .filters.registry import make_filter
from .prepare import Prepared
from .so3 import matrix_to_quat_xyzw
from .types import PoseSeries

log = logging.getLogger(__name__)

LIDAR, GNSS, ODOM, NHC = 0, 1, 2, 3   # at equal stamps: lidar first


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
    odometer_scale: np.ndarray | None = None   # (N,) odometer scale error k (odometer + gyro model)


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


def dead_reckoning(prep: Prepared, fp: FilterParams) -> PoseSeries:
    """Pure IMU integration (accelerometer and gyro) from the filter's initial state: the unfiltered IMU."""
    t = np.ascontiguousarray(prep.imu.t_s)
    k0 = prep.k_start
    p, R = dead_reckon(prep.x0, process_params(fp, t), t, np.ascontiguousarray(prep.imu.f_b_mps2),
                       np.ascontiguousarray(prep.imu.w_b_rps), k0)
    p, R, t = p[k0:], R[k0:], t[k0:]
    finite = np.all(np.isfinite(p), axis=1) & np.all(np.abs(p) < 1e9, axis=1)
    return PoseSeries(t_s=t[finite], p_w_m=p[finite], q_wb_xyzw=matrix_to_quat_xyzw(R[finite]), source="imu_only")


def replay(prep: Prepared, fp: FilterParams, progress: Callable[[float], None] | None = None,
           imu_only: PoseSeries | None = None) -> FilterOutput:
    """Replay every observation through the configured filter; ``imu_only`` (dead reckoning) is computed
    here unless given (the pipeline computes it first, to evaluate it while the filter runs)."""
    imu = prep.imu
    t_imu = np.ascontiguousarray(imu.t_s)
    f_imu = np.ascontiguousarray(imu.f_b_mps2)
    w_imu = np.ascontiguousarray(imu.w_b_rps)
    prm = process_params(fp, t_imu)
    k0 = prep.k_start
    t0, t_end = float(t_imu[k0]), float(t_imu[-1])
    odo = prep.odometer
    v_odo = None
    if fp.process_model == "odometer_gyro":   # the speed that drives the prediction, on the gyro's stamps
        v_odo = np.ascontiguousarray(np.interp(t_imu, odo.t_s, odo.v_mps))
    kf = make_filter(fp, prep.x0, prm, t_imu, f_imu, w_imu, k0, v_odo)

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
    if fp.odometer_update:
        idx = np.flatnonzero((odo.t_s >= t0 - 1e-9) & (odo.t_s <= t_end))
        events += [(float(odo.t_s[i]), ODOM, int(i)) for i in idx]
    if fp.nhc:
        # at IMU stamps, about nhc_rate_hz, only while not turning
        step = max(1, int(round(1.0 / (fp.nhc_rate_hz * float(np.median(np.diff(t_imu)))))))
        cand = np.arange(k0 + step, t_imu.size, step)
        still = np.linalg.norm(w_imu[cand], axis=1) < fp.nhc_max_turn_rate_rps
        events += [(float(t_imu[k]), NHC, int(k)) for k in cand[still]]
    events.sort()

    nis = {"lidar": ([], []), "gnss": ([], []), "odometer": ([], []), "nhc": ([], [])}
    prev = None  # (p_w, R_wb) of the previous lidar frame, for relative updates
    n_ev = len(events)
    step = max(1, n_ev // 100)
    it, tol = fp.iterations, fp.iteration_tol

    def upd(kind: str, t: float, model) -> None:
        nis[kind][0].append(t)
        nis[kind][1].append(kf.update(model, it, tol))

    for j, (t, kind, i) in enumerate(events):
        kf.predict_to(max(t, kf.t))
        if kind == LIDAR:
            p_obs, R_obs = lidar.p_w_m[i], R_lidar[i]
            if fp.lidar_update == "absolute":
                upd("lidar", t, partial(obs.absolute_pose, p_obs_w=p_obs, R_obs_wb=R_obs, pos_std_m=fp.abs_pos_std_m,
                                        att_std_rad=fp.abs_att_std_rad))
            else:
                if prev is not None:
                    dp_c = prev[1].T @ (p_obs - prev[0])
                    dR = prev[1].T @ R_obs
                    pos_std = float(np.hypot(fp.rel_pos_std_m, fp.rel_pos_std_frac * np.linalg.norm(dp_c)))
                    upd("lidar", t, partial(obs.relative_pose, dp_obs_c=dp_c, dR_obs=dR, pos_std_m=pos_std,
                                            att_std_rad=fp.rel_att_std_rad))
                kf.clone_pose()
                prev = (p_obs, R_obs)
        elif kind == GNSS:
            upd("gnss", t, partial(obs.gnss_position, p_obs_w=gnss.p_w_m[i], std_w=gnss.std_w_m[i],
                                   lever_arm_b=fp.gnss_lever_arm_b_m))
        elif kind == ODOM:
            upd("odometer", t, partial(obs.body_velocity, v_obs_b=np.array([odo.v_mps[i], 0.0, 0.0]),
                                       std_b=np.full(3, fp.odo_speed_std_mps), rows=(0,)))
        else:
            upd("nhc", t, partial(obs.body_velocity, v_obs_b=np.zeros(3), std_b=np.full(3, fp.nhc_std_mps), rows=(1, 2)))
        if progress is not None and j % step == 0:
            progress(j / n_ev)
    kf.predict_to(t_end)
    if progress is not None:
        progress(1.0)

    sl = slice(k0, None)
    fused = PoseSeries(t_s=t_imu[sl], p_w_m=kf.rec_p[sl], q_wb_xyzw=matrix_to_quat_xyzw(kf.rec_R[sl]),
                       v_w_mps=kf.rec_v[sl], source="fused")
    if imu_only is None:
        imu_only = dead_reckoning(prep, fp)
    dof = {"lidar": 6, "gnss": 3, "odometer": 1, "nhc": 2}
    return FilterOutput(
        fused=fused, accel_bias_b=kf.rec_ba[sl].copy(), gyro_bias_b=kf.rec_bg[sl].copy(),
        sigma=np.sqrt(np.maximum(kf.rec_Pdiag[sl], 0.0)), P_pos_att=kf.rec_Ppt[sl],
        nis={k: {"t_s": np.array(v[0]), "nis": np.array(v[1]), "dof": dof[k]} for k, v in nis.items() if v[0]},
        imu_only=imu_only, n_imu_samples=int(t_imu.size - k0),
        odometer_scale=kf.rec_k[sl].copy() if hasattr(kf, "rec_k") else None,
    )
