"""The batch factor-graph estimate (``smoother.method: batch``) with GTSAM: every measurement the filter used, at
once, optimised with Levenberg-Marquardt.

Keyframes are the filter's epochs (each lidar/GNSS stamp; the start and the end), each with a pose ``X``, a
velocity ``V`` and an IMU bias ``B``. Between consecutive keyframes a ``CombinedImuFactor`` preintegrates the very
inputs the filter stepped with (interpolated linearly over each interval, the partial interval to an event stamp
too, the same lag corrections; in sub-steps of at most 10 ms, :func:`substeps`), with the filter's IMU noise
densities and bias random walks. Each
update the filter applied becomes a factor with the noise the filter used at that moment (adaptive lidar noise
included): a relative lidar increment a ``BetweenFactor<Pose3>`` between the keyframe of its clone and its own, an
absolute lidar pose a ``PriorFactor<Pose3>``, a GNSS fix a ``GPSFactor`` (``GPSFactorArm`` with a lever arm).
Updates the filter's gate rejected are left out. Priors on the first keyframe come from the same initialisation.
The initial values are the filter's own posteriors; the marginal covariances give the NEES.

GTSAM's Pose3 tangent is ``[omega, t]`` with the translation perturbation in the body frame; the canonical error
is ``[dp_world, dtheta]`` with ``dtheta`` a right perturbation, so ``Sigma_canonical = J Sigma J^T`` with
``J = [[0, R], [I, 0]]``. IMU samples between keyframes (a 100 Hz IMU with 10 Hz lidar) get the previous keyframe's
IMU prediction and that keyframe's covariance; the metrics at the keyframes are exact.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError
from ..filters.formulations.imu_model import PRM_G, UF, UW
from ..filters.layout import CANONICAL, NOMINAL, POSE_PACKED_N, pack_pose_cov
from ..filters.observations import gnss_position as gp, pose as ap, relative_pose as rp
from ..filters.observations.base import kernel_model
from ..filters.state import NominalState
from .rts import Smoothed

EXTRA = "pip install 'fusion-eval[smoother]' (or: pip install gtsam)"

# GTSAM's preintegration takes each input as constant over its step and rotates the acceleration by the step's start
# attitude (first order), where the filter's mechanization is a midpoint scheme over the interval: at 10 Hz turning at
# 0.3 rad/s, a 2.7e-3 m/s velocity error per step (the filter's 1.3e-5), a 2.75 mrad tilt its noise does not hold.
# So each IMU interval is integrated in sub-steps of at most this length, the inputs interpolated linearly (a 100 Hz
# IMU: one step, as before; kitti-00's 10 Hz, 0.10-0.12 s: ten to twelve). Measured on a 10 Hz white-noise simulation: the smoothed attitude
# NEES 19.4 -> 3.05 (3 dof) and the rotation APE 0.0586 -> 0.0329 deg, the RTS pass's (found by a math review).
MAX_SUBSTEP_S = 0.01


def substeps(u0: np.ndarray, u1: np.ndarray, dt: float):
    """``(midpoint input, step, is_last)`` of the sub-steps of one interval of ``dt`` s whose input goes linearly
    from ``u0`` to ``u1`` (:data:`MAX_SUBSTEP_S`)."""
    n = max(1, int(np.ceil(dt / MAX_SUBSTEP_S - 1e-9)))
    h = dt / n
    for s in range(n):
        yield u0 + ((s + 0.5) / n) * (u1 - u0), h, s == n - 1


def _gap_params(gtsam, params, s, gap, in_gap_s: float, hidden2_s2: float, span_s: float, g: float):
    """The preintegration's noise over a keyframe interval that holds ``in_gap_s`` seconds of IMU gaps, as the
    filter's model adds it there: the white noise's variance scaled by ``gap[1]`` inside them, and for each gap that
    ends in the interval the motion it hid (``hidden2_s2``: the sum of their squared lengths), ``gap[2] T^2`` on the
    attitude and ``gap[3] T^2`` on the velocity; spread as one white density over the interval's ``span_s`` seconds (GTSAM
    takes one per factor), so that the interval's total is the filter's. The batch estimate had ignored every
    ``imu.gap_*`` key (a configuration audit: extreme values moved the filter from 1.52 to 20.4 m, it by 1e-5 m)."""
    ext = gtsam.PreintegrationCombinedParams.MakeSharedU(g)
    var_a, var_g = s.imu.accel_noise_mps2_sqrthz ** 2, s.imu.gyro_noise_rps_sqrthz ** 2
    grow = (gap[1] - 1.0) * in_gap_s / span_s
    I3 = np.eye(3)
    ext.setAccelerometerCovariance(I3 * (var_a * (1.0 + grow) + gap[3] * hidden2_s2 / span_s))
    ext.setGyroscopeCovariance(I3 * (var_g * (1.0 + grow) + gap[2] * hidden2_s2 / span_s))
    ext.setBiasAccCovariance(params.getBiasAccCovariance())
    ext.setBiasOmegaCovariance(params.getBiasOmegaCovariance())
    ext.setIntegrationCovariance(params.getIntegrationCovariance())
    return ext


def require_gtsam():
    try:
        import gtsam
    except ImportError:
        raise ConfigError(f"smoother.method=batch needs GTSAM, which is not installed: {EXTRA}") from None
    return gtsam


@dataclass
class BatchRecord:
    """What the replay hands the batch estimate: each applied update (its stamp, its model with the noise used
    then, the stamp of the clone it refers to) and the filter's posterior at each epoch (initial values)."""

    x0: np.ndarray                                    # the filter's initial nominal vector
    updates: list = field(default_factory=list)       # (t, model partial, clone stamp or None)
    posterior: dict = field(default_factory=dict)     # t -> nominal vector

    def epoch(self, kf) -> None:
        self.posterior[round(kf.t, 9)] = kf.xv.copy()

    def update(self, kf, model, clone_t, accepted: bool) -> None:
        if model is not None and accepted:
            self.updates.append((kf.t, model, clone_t))


class BatchSmoother:
    """``smoother.method: batch`` in the replay (:mod:`fusion_eval.smoothing`)."""

    name = "batch"

    @staticmethod
    def check(cfg: dict, formulation) -> None:
        """Refuse what the graph cannot express, naming the keys (before any data is read)."""
        f = cfg["filter"]
        if f["process_model"] != "imu":
            raise ConfigError(f"smoother.method=batch fuses IMU preintegration: filter.process_model={f['process_model']} "
                              "is not supported (use imu, or smoother.method=rts)")
        if f["bias_model"] == "gauss_markov":
            raise ConfigError("smoother.method=batch models the IMU biases as random walks (CombinedImuFactor): "
                              "filter.bias_model=gauss_markov is not supported (use random_walk or constant)")
        from ..filters.observations.relative_pose import frame_of

        frame = frame_of(cfg["lidar"]["relative_frame"], f["use_gnss"], "batch")
        if f["lidar_update"] == "relative" and frame != "body":
            raise ConfigError("smoother.method=batch expresses lidar increments as BetweenFactor<Pose3> in the body frame: "
                              f"lidar.relative_frame={frame} is not supported (use body, or smoother.method=rts)")
        from ..filters import observations

        for o in observations.enabled(cfg):
            if o.name not in _OBSERVATIONS:
                off = ", ".join(f"{k}={str(v).lower()}" for k, v in o.disable_with.items())
                raise ConfigError(f"smoother.method=batch has no factor for {o.label} ({o.enabled_by}): set {off}, "
                                  "or use smoother.method=rts")
        require_gtsam()

    def __init__(self, kf, s, n_events: int):
        self.s = s
        self.rec = BatchRecord(kf.xv.copy())
        self.rec.epoch(kf)

    def epoch(self, kf) -> None:
        self.rec.epoch(kf)

    def before_update(self, kf, bound, j: int) -> None:
        # the model with the noise it has now (adaptive noise moves after the update), and the clone it refers to
        self._model, self._clone_t = bound.model(j), kf.clone_t

    def after_update(self, kf, res) -> None:
        self.rec.update(kf, self._model, self._clone_t, res is not None and res[1])

    def finish(self, kf, k0: int) -> tuple[Smoothed, dict]:
        return batch_smooth(kf, self.rec, self.s, k0)


_FACTORS = (rp.relative_pose_kernel, ap.absolute_pose_kernel, gp.gnss_position_kernel)   # the models with a factor
_OBSERVATIONS = ("lidar", "gnss")                           # the registered observations they belong to


def _factor_of(model):
    """The compiled kernel of an observation model that has a factor, else a one-line refusal."""
    fn = getattr(model, "func", None)
    kern = model.args[0] if fn is kernel_model and model.args else None
    if kern not in _FACTORS:
        name = getattr(fn, "__name__", repr(model))
        raise ConfigError(f"smoother.method=batch has no factor for the observation model {name}: turn that observation off "
                          "(filter.use_gnss_velocity, filter.odometer_update, filter.nhc) or use smoother.method=rts")
    return kern


def _std_factors(model, *blocks: slice) -> list[float]:
    """The adaptive noise's std factor on each residual block (1 where it adapts none) as the model had it."""
    out = []
    for b in blocks:
        f = 1.0
        for lo, hi, v in model.keywords.get("rm_scale") or ():
            if lo == b.start and hi == b.stop:
                f = float(np.sqrt(v))
        out.append(f)
    return out


def batch_smooth(kf, rec: BatchRecord, s, k0: int, progress=None) -> tuple[Smoothed, dict]:
    gtsam = require_gtsam()
    from gtsam.symbol_shorthand import B, V, X

    t0_wall = time.perf_counter()
    a = kf.arrays
    t, u, prm_g = a.t, a.u, float(a.prm[PRM_G])
    keys_t = np.array(sorted(rec.posterior))
    index = {tt: i for i, tt in enumerate(keys_t)}
    n_kf = keys_t.size

    params = gtsam.PreintegrationCombinedParams.MakeSharedU(prm_g)
    I3 = np.eye(3)
    params.setAccelerometerCovariance(I3 * s.imu.accel_noise_mps2_sqrthz ** 2)
    params.setGyroscopeCovariance(I3 * s.imu.gyro_noise_rps_sqrthz ** 2)
    # a constant bias is a random walk of (almost) no noise: the factor needs a positive definite covariance
    qba, qbg = ((1e-12, 1e-12) if s.filter.bias_model == "constant"
                else (s.imu.accel_bias_rw_mps3_sqrthz, s.imu.gyro_bias_rw_rps2_sqrthz))
    params.setBiasAccCovariance(I3 * max(qba, 1e-12) ** 2)
    params.setBiasOmegaCovariance(I3 * max(qbg, 1e-12) ** 2)
    params.setIntegrationCovariance(I3 * 1e-10)

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()

    def nav(x):
        st = NominalState.from_vector(x)
        return gtsam.Pose3(gtsam.Rot3(st.R_wb.copy()), st.p_w_m.copy()), st.v_w_mps.copy(), \
            gtsam.imuBias.ConstantBias(st.ba_b.copy(), st.bg_b.copy())

    for i, tt in enumerate(keys_t):
        pose, vel, bias = nav(rec.posterior[tt])
        values.insert(X(i), pose)
        values.insert(V(i), vel)
        values.insert(B(i), bias)

    # priors from the filter's initialisation (canonical prior: position, velocity, attitude, biases)
    x0 = NominalState.from_vector(rec.x0.copy())
    ini = s.init
    pose0 = gtsam.Pose3(gtsam.Rot3(x0.R_wb.copy()), x0.p_w_m.copy())
    graph.add(gtsam.PriorFactorPose3(X(0), pose0, gtsam.noiseModel.Diagonal.Sigmas(
        np.r_[ini.roll_pitch_std_rad, ini.roll_pitch_std_rad, ini.yaw_std_rad, np.full(3, ini.pos_std_m)])))
    graph.add(gtsam.PriorFactorVector(V(0), x0.v_w_mps.copy(), gtsam.noiseModel.Isotropic.Sigma(3, ini.vel_std_mps)))
    graph.add(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(x0.ba_b.copy(), x0.bg_b.copy()),
                                            gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, max(ini.accel_bias_std_mps2, 1e-9)),
                                                                                   np.full(3, max(ini.gyro_bias_std_rps, 1e-9))])))
    # the start sits at sample k0; the replay stepped every sample, then to each event stamp (inputs interpolated)
    if abs(keys_t[0] - t[k0]) > 1e-9:
        raise ConfigError("smoother.method=batch: the first epoch is not the filter's start (internal)")
    pims: list = []
    k, t_prev, u_prev = k0 + 1, float(t[k0]), u[k0].copy()
    N = t.size
    # per keyframe interval: the integration steps (sample index or -1 for the partial step to the stamp, input, dt)
    steps_of: list[list[tuple[int, np.ndarray, float]]] = [[] for _ in range(n_kf)]
    gap = a.gap
    for i in range(1, n_kf):
        tb = float(keys_t[i])
        # linearised at the filter's own bias there (the factor corrects to first order around it)
        _, _, bias_lin = nav(rec.posterior[keys_t[i - 1]])
        steps = steps_of[i - 1]
        in_gap = hidden2 = 0.0      # seconds of this interval inside IMU gaps; the sum of the squared lengths of
        # the gaps that end here (the filter adds each one's hidden motion at its end)
        while k < N and t[k] <= tb + 1e-12:
            dt = t[k] - t_prev
            is_gap = k > 0 and t[k] - t[k - 1] > gap[0]
            if dt > 0:
                for um, h, last in substeps(u_prev, u[k], dt):
                    steps.append((k if last and t[k] < tb - 1e-9 else -1, um, h))
                in_gap += dt if is_gap else 0.0
                hidden2 += float(t[k] - t[k - 1]) ** 2 if is_gap else 0.0
            t_prev, u_prev = float(t[k]), u[k].copy()
            k += 1
        if tb > t_prev + 1e-12 and k < N:
            frac = (tb - t_prev) / (t[k] - t_prev)
            u1 = u_prev + frac * (u[k] - u_prev)
            for um, h, _ in substeps(u_prev, u1, tb - t_prev):
                steps.append((-1, um, h))
            in_gap += (tb - t_prev) if t[k] - t[k - 1] > gap[0] else 0.0
            t_prev, u_prev = tb, u1
        pim = gtsam.PreintegratedCombinedMeasurements(
            _gap_params(gtsam, params, s, gap, in_gap, hidden2, tb - float(keys_t[i - 1]), prm_g)
            if in_gap > 0.0 else params, bias_lin)
        for _, um, h in steps:
            pim.integrateMeasurement(um[UF:UF + 3], um[UW:UW + 3], h)
        pims.append(pim)
        if pim.deltaTij() > 0:
            graph.add(gtsam.CombinedImuFactor(X(i - 1), V(i - 1), X(i), V(i), B(i - 1), B(i), pim))
        else:               # two epochs at one instant cannot happen (one epoch per stamp)
            raise ConfigError("smoother.method=batch: two keyframes at one stamp (internal)")

    counts = {"imu": n_kf - 1, "lidar_relative": 0, "lidar_absolute": 0, "gnss": 0}
    for tt, model, clone_t in rec.updates:
        fn = _factor_of(model)
        row = np.asarray(model.keywords["row"], float)
        i = index[round(tt, 9)]
        if fn is rp.relative_pose_kernel:
            j = index[round(clone_t, 9)]
            kp, ka = _std_factors(model, rp.RP, rp.RTH)
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, row[rp.STD_TH] * ka), np.full(3, row[rp.STD_P] * kp)])
            pose = gtsam.Pose3(gtsam.Rot3(row[rp.ROW.sl("dR")].reshape(3, 3)), row[rp.ROW.sl("dp")])
            graph.add(gtsam.BetweenFactorPose3(X(j), X(i), pose, noise))
            counts["lidar_relative"] += 1
        elif fn is ap.absolute_pose_kernel:
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, row[ap.OSTH]), np.full(3, row[ap.OSP])])
            pose = gtsam.Pose3(gtsam.Rot3(row[ap.ROW.sl("R")].reshape(3, 3)), row[ap.ROW.sl("p")])
            graph.add(gtsam.PriorFactorPose3(X(i), pose, noise))
            counts["lidar_absolute"] += 1
        else:
            noise = gtsam.noiseModel.Diagonal.Sigmas(row[gp.ROW.sl("std")])
            lever, p_obs = row[gp.ROW.sl("lever")], row[gp.ROW.sl("p")]
            if np.any(lever != 0):
                graph.add(gtsam.GPSFactorArm(X(i), p_obs, lever, noise))
            else:
                graph.add(gtsam.GPSFactor(X(i), p_obs, noise))
            counts["gnss"] += 1

    t_build = time.perf_counter() - t0_wall
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(50)
    lm.setRelativeErrorTol(1e-7)
    # QR: with Cholesky, LM stalls on the stiff bias chain on some drives (simple-06: 50 iterations, error 3084,
    # APE 0.351 m; with QR 3 iterations, 3047, 0.322 m; kitti-00 the same either way)
    lm.setLinearSolverType("MULTIFRONTAL_QR")
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
    err0 = graph.error(values)
    result = opt.optimize()
    t_opt = time.perf_counter() - t0_wall - t_build
    # the marginals from a QR-factored Bayes tree (iSAM2 fed the solution once): gtsam.Marginals' Cholesky fails on
    # the stiff bias chain (random walks of 1e-7 rad/s^2/sqrt(Hz): "indeterminant system" at the first bias)
    ip = gtsam.ISAM2Params()
    ip.setFactorization("QR")
    marg = gtsam.ISAM2(ip)
    marg.update(graph, result)

    out = Smoothed(np.full((N, NOMINAL.n), np.nan), np.full((N, CANONICAL.n_core), np.nan),
                   np.full((N, POSE_PACKED_N), np.nan))
    P_, V_, TH_, BA_, BG_ = (CANONICAL.sl(b) for b in ("P", "V", "TH", "BA", "BG"))
    for i, tt in enumerate(keys_t):
        pose, vel, bias = result.atPose3(X(i)), result.atVector(V(i)), result.atConstantBias(B(i))
        R = pose.rotation().matrix()
        Sp = marg.marginalCovariance(X(i))
        J = np.zeros((6, 6))
        J[0:3, 3:6] = R                      # dp_world = R t_local
        J[3:6, 0:3] = I3                     # dtheta = omega (both right perturbations)
        Sc = J @ Sp @ J.T
        Sc_packed = pack_pose_cov(Sc)
        diag = np.empty(CANONICAL.n_core)
        diag[P_], diag[TH_] = np.diag(Sc)[:3], np.diag(Sc)[3:]
        diag[V_] = np.diag(marg.marginalCovariance(V(i)))
        Sb = np.diag(marg.marginalCovariance(B(i)))
        diag[BA_], diag[BG_] = Sb[:3], Sb[3:]
        nav_i = gtsam.NavState(pose, vel)
        kk = int(np.searchsorted(t, tt - 1e-9))
        samples = [(kk, nav_i)] if kk < N and abs(t[kk] - tt) <= 1e-9 else []
        # IMU samples before the next keyframe: the keyframe's IMU prediction, one preintegration for the interval
        pim = gtsam.PreintegratedCombinedMeasurements(params, bias)
        for kk, um, dt in steps_of[i]:
            pim.integrateMeasurement(um[UF:UF + 3], um[UW:UW + 3], dt)
            if kk >= 0:
                samples.append((kk, pim.predict(nav_i, bias)))
        for kk, st in samples:
            x = NominalState(st.position(), st.velocity(), st.attitude().matrix(), bias.accelerometer(), bias.gyroscope())
            out.rec_x[kk] = x.vec
            out.rec_Pdiag[kk] = diag      # between keyframes: the keyframe's covariance (the prediction's is not added)
            out.rec_Ppt[kk] = Sc_packed
        if progress is not None and i % 200 == 0:
            progress(i / n_kf)
    info = {"method": "batch", "keyframes": int(n_kf), "factors": int(graph.size()), **{f"{k}_factors": v for k, v in counts.items()},
            "iterations": int(opt.iterations()), "initial_error": float(err0), "final_error": float(graph.error(result)),
            "build_s": t_build, "optimize_s": t_opt, "backward_s": time.perf_counter() - t0_wall}
    return out, info
