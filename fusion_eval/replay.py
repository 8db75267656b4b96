"""Time-ordered replay of IMU samples and the registered observations through the configured filter.

Each enabled observation, bound to the run's data, gives its event stamps; the events are merged in time
(at equal stamps in registry order: lidar first); the filter is propagated to each event's own stamp
(interpolating the IMU between samples, see :mod:`fusion_eval.filters.propagate`), updated, and the state
is recorded at every IMU sample.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .config import Settings
from . import smoothing
from .filters import compiled_replay, make_filter, observations
from .filters.formulations.eskf import dead_reckon_poses
from .filters.formulations.imu_model import imu_inputs, imu_params
from .filters.layout import PACKED, unpack_pose_cov
from .filters.state import unpack
from .prepare import Prepared
from .so3 import matrix_to_quat_xyzw
from .types import PoseSeries

log = logging.getLogger(__name__)


@dataclass
class FilterOutput:
    """The filter's record at the IMU stamps from the start sample on."""

    fused: PoseSeries
    accel_bias_b: np.ndarray        # (N, 3) m/s^2
    gyro_bias_b: np.ndarray         # (N, 3) rad/s
    sigma: np.ndarray               # (N, 15) 1-sigma of the canonical error state (NaN where the filter has no such state)
    P_pos_att_packed: np.ndarray    # (N, 21) covariance of [dp, dtheta] (theta: right perturbation), packed as
                                    # recorded (filters.layout.PACKED); P_pos_att: the (N, 6, 6) matrices
    nis: dict                       # observation name -> {"t_s": (M,), "nis": (M,), "dof": int, "rejected": int}
    imu_only: PoseSeries
    n_imu_samples: int
    odometer_scale: np.ndarray | None = None   # (N,) odometer scale error k (formulations with a K block)
    smoothed: "FilterOutput | None" = None     # the smoother's estimate (smoother.method), same fields
    smoother_info: dict | None = None          # what the smoother kept and how long it took

    @property
    def P_pos_att(self) -> np.ndarray:
        """``(N, 6, 6)`` covariance of [dp, dtheta], unpacked on each access (a new array: 207 MB on a long drive)."""
        return unpack_pose_cov(self.P_pos_att_packed)


def dead_reckoning(prep: Prepared, s: Settings) -> PoseSeries:
    """Pure IMU integration (accelerometer and gyro) from the filter's initial state: the unfiltered IMU."""
    t = np.ascontiguousarray(prep.imu.t_s)
    k0 = prep.k_start
    p, R = dead_reckon_poses(prep.x0, imu_params(prep.gravity_mps2, 0.0, 0.0, 0.0, 0.0), t,
                             imu_inputs(prep.imu.f_b_mps2, prep.imu.w_b_rps), k0)
    t = t[k0:]
    finite = np.all(np.isfinite(p), axis=1) & np.all(np.abs(p) < 1e9, axis=1)
    return PoseSeries(t_s=t[finite], p_w_m=p[finite], q_wb_xyzw=matrix_to_quat_xyzw(R[finite]), source="imu_only")


def replay(prep: Prepared, s: Settings, progress: Callable[[float], None] | None = None,
           imu_only: PoseSeries | None = None, monitor=None) -> FilterOutput:
    """Replay every enabled observation through the configured filter; ``imu_only`` (dead reckoning) is
    computed here unless given (the pipeline computes it first, to evaluate it while the filter runs).
    ``monitor``: watches the innovations during a compiled replay and may stop it by raising
    (:func:`fusion_eval.filters.compiled_replay.run`); the Python loop does not call it."""
    t_imu = np.ascontiguousarray(prep.imu.t_s)
    k0 = prep.k_start
    t_end = float(t_imu[-1])
    kf = make_filter(prep, s)
    bound = [o.bind(prep, s) for o in observations.enabled(s.cfg)]
    if not bound:
        log.warning("no observation is enabled: the fused estimate is the %s prediction alone (dead reckoning)",
                    s.filter.process_model)
    # events as (time, registry position, event index), sorted: at equal stamps the registry order decides
    times = np.concatenate([b.t_s for b in bound]) if bound else np.zeros(0)
    which = np.concatenate([np.full(b.t_s.size, i) for i, b in enumerate(bound)]) if bound else np.zeros(0, int)
    index = np.concatenate([np.arange(b.t_s.size) for b in bound]) if bound else np.zeros(0, int)
    order = np.lexsort((index, which, times))
    smoother = smoothing.start(kf, s, times.size)

    it, tol = s.filter.iterations, s.filter.iteration_tol
    if compiled_replay.usable(kf, bound, smoother, it, s.filter.replay):
        nis = _replay_compiled(kf, bound, times, which, index, order, progress, monitor)
    else:
        nis = _replay_python(kf, bound, times, which, index, order, smoother, it, tol, progress)
    kf.predict_to(t_end)
    if smoother is not None:
        smoother.epoch(kf)
    if progress is not None:
        progress(1.0)
    dof = {b.name: b.dof for b in bound}

    summaries = {b.name: b.summary() for b in bound if b.summary is not None}
    if imu_only is None:
        imu_only = dead_reckoning(prep, s)
    a = kf.arrays
    out = _output(kf, t_imu, k0, a.rec_x, a.rec_Pdiag, a.rec_Ppt, "fused", imu_only,
                  nis={k: {"t_s": np.asarray(v[0], float), "nis": np.asarray(v[1], float), "dof": dof[k],
                           "rejected": int(np.size(v[2]) - np.count_nonzero(v[2])), "logdet_S": np.asarray(v[3], float),
                           **({"adapt": summaries[k]} if summaries.get(k) else {})} for k, v in nis.items() if len(v[0])})
    check_divergence(out)
    if smoother is not None:
        sm, out.smoother_info = smoother.finish(kf, k0)
        out.smoothed = _output(kf, t_imu, k0, sm.rec_x, sm.rec_Pdiag, sm.rec_Ppt, "smoothed", imu_only, nis={})
    return out


# An observation whose innovations run this many times their predicted covariance (median NIS over the last quarter
# of its updates, per degree of freedom) means a filter that no longer follows the data: a 100-sigma error
# sustained. A mistuned but working filter stays within tens.
NIS_DIVERGED_PER_DOF = 1e4
MIN_UPDATES_FOR_NIS = 20  # not a state index


def check_divergence(out: FilterOutput) -> None:
    """Raise :class:`FilterDivergedError` (exit 3) when the covariance went non-finite or negative, or when an
    observation's NIS exploded: the state may still be finite while the filter has lost the data (process noise
    and initial uncertainty far too small make it reject nothing and follow nothing)."""
    from .errors import FilterDivergedError

    P = out.P_pos_att_packed
    diag = P[:, np.diagonal(PACKED)] if P.size else np.zeros((0, 6))
    # a row's sum is non-finite when one of its entries is (inf - inf is NaN): one number a row, not 21 booleans
    bad = np.flatnonzero(~np.isfinite(P.sum(axis=1)) | np.any(diag < 0, axis=1)) if P.size else []
    if len(bad):
        raise FilterDivergedError(f"filter diverged at t={out.fused.t_s[bad[0]]:.3f} s: the position/attitude covariance is "
                                  "non-finite or has a negative variance")
    tails = {}
    for name, d in out.nis.items():
        nis = np.asarray(d["nis"], float)
        if nis.size >= MIN_UPDATES_FOR_NIS:
            tail = nis[-max(MIN_UPDATES_FOR_NIS, nis.size // 4):]
            tails[name] = (tail, float(np.median(tail)), d)
    for name, (tail, med, d) in tails.items():
        if not np.isfinite(med) or med > NIS_DIVERGED_PER_DOF * d["dof"]:
            others = ", ".join(f"{k} {m / e['dof']:.3g}x" for k, (_, m, e) in tails.items() if k != name)
            raise FilterDivergedError(
                f"filter diverged: the {name} innovations are {med / d['dof']:.3g} times their predicted variance over the "
                f"last {tail.size} updates (median NIS {med:.3g} for {d['dof']} dof, from t={d['t_s'][-tail.size]:.3f} s"
                + (f"; the other streams: {others}" if others else "") + "); the filter trusts its prediction far "
                "more than the data: a stream in another frame or unit than the IMU's (an IMU mounted rotated without its "
                "extrinsic, NED for ENU, km/h, g), or process noise or initial uncertainty too small")


def _replay_python(kf, bound, times, which, index, order, smoother, it, tol, progress) -> dict:
    """The event loop stepped from Python (any formulation, observation, smoother, iterated update)."""
    nis: dict[str, tuple[list, list, list, list]] = {b.name: ([], [], [], []) for b in bound}
    n_ev = order.size
    step = max(1, n_ev // 100)
    for j, e in enumerate(order):
        t, b = float(times[e]), bound[which[e]]
        kf.predict_to(max(t, kf.t))
        if smoother is not None:
            smoother.before_update(kf, b, int(index[e]))
        kf.last_S = None
        res = b.apply(kf, int(index[e]), it, tol)
        if smoother is not None:
            smoother.after_update(kf, res)
            smoother.epoch(kf)
        if res is not None:
            rec = nis[b.name]
            rec[0].append(t)
            rec[1].append(res[0])
            rec[2].append(res[1])
            # log det S where the update left its innovation covariance (the plain compiled update; NaN otherwise)
            S = kf.last_S
            rec[3].append(float(np.linalg.slogdet(S)[1]) if S is not None else np.nan)
        if progress is not None and j % step == 0:
            progress(j / n_ev)
    return nis


def _replay_compiled(kf, bound, times, which, index, order, progress, monitor=None) -> dict:
    """The event loop in compiled chunks (:mod:`fusion_eval.filters.compiled_replay`); the same record."""
    nis_ev, ok_ev, ld_ev = compiled_replay.run(kf, bound, times, which, index, order, progress, monitor)
    ts, pos = times[order], which[order]
    out = {}
    for c, b in enumerate(bound):
        sel = (pos == c) & np.isfinite(nis_ev)        # NaN: the event updated nothing (a first lidar frame)
        out[b.name] = (ts[sel], nis_ev[sel], ok_ev[sel], ld_ev[sel])
    return out


def _output(kf, t_imu, k0, rec_x, rec_Pdiag, rec_Ppt, source, imu_only, nis) -> FilterOutput:
    """A filter output (``fused`` or ``smoothed``) from the record at the IMU samples ``k0 ..``."""
    sl = slice(k0, None)
    # the square roots taken in the record itself, which nothing reads after this (a new array was another 82 MB on
    # a long drive, at the run's peak)
    sigma = rec_Pdiag[sl]
    np.maximum(sigma, 0.0, out=sigma)
    np.sqrt(sigma, out=sigma)
    rec = unpack(rec_x[sl])
    poses = PoseSeries(t_s=t_imu[sl], p_w_m=rec["p"], q_wb_xyzw=matrix_to_quat_xyzw(rec["R"]), v_w_mps=rec["v"],
                       source=source)
    return FilterOutput(
        fused=poses, accel_bias_b=rec["ba"].copy(), gyro_bias_b=rec["bg"].copy(),
        sigma=sigma, P_pos_att_packed=rec_Ppt[sl], nis=nis,
        imu_only=imu_only, n_imu_samples=int(t_imu.size - k0), odometer_scale=kf.odometer_scale(rec_x[sl]),
    )


__all__ = ["FilterOutput", "replay", "dead_reckoning"]
