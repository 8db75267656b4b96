"""Every registered observation and formulation against finite differences, picked up from the registries.

Observations: on simulated data, each model's Jacobian (over the canonical error state) against a central
difference of its residual, at the true state of its own events; columns outside the blocks it declares
must be zero. Formulations: the covariance propagation of each step against the finite-difference
Jacobian of the same step's state map, and the canonical map ``D`` against finite differences.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fusion_eval.cli import main
from fusion_eval.config import Settings, load_config
from fusion_eval.filters import formulations, observations
from fusion_eval.filters.layout import CANONICAL, canonical_blocks
from fusion_eval.filters.state import ClonePose, NominalState
from fusion_eval.interp import interpolate_pose_at
from fusion_eval.prepare import prepare, settings_for
from fusion_eval import session
from fusion_eval.session import dataset
from fusion_eval.so3 import exp_so3, log_so3

OBS = list(observations.REGISTRY)
FORMS = list(formulations.REGISTRY)


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    # lidar map matching: absolute poses with sensor noise only, so that every model's residual at the true
    # state is the noise (the attitude rows are exact at a zero residual)
    d = tmp_path_factory.mktemp("reg") / "urban"
    r = CliRunner().invoke(main, ["-q", "simulate", str(d), "--profile", "urban", "--duration", "60", "--set", "imu.rate_hz=50",
                                  "--set", "output.layout=csv", "--set", "lidar.mode=map_matching"])
    assert r.exit_code == 0, r.output
    return d


def _perturbed(x: NominalState, clone: ClonePose, d: np.ndarray) -> tuple[NominalState, ClonePose]:
    """x [+] d for a canonical error d (21): additive on vectors, right perturbation on attitudes."""
    C = CANONICAL
    xp, cp = x.copy(), clone.copy()
    xp.p_w_m[:] += d[C.sl("P")]
    xp.v_w_mps[:] += d[C.sl("V")]
    xp.R_wb[:] = xp.R_wb @ exp_so3(d[C.sl("TH")])
    xp.ba_b[:] += d[C.sl("BA")]
    xp.bg_b[:] += d[C.sl("BG")]
    cp.p_w_m[:] += d[C.sl("CP")]
    cp.R_wb[:] = cp.R_wb @ exp_so3(d[C.sl("CTH")])
    return xp, cp


def _truth(gt, t: float, rng) -> NominalState:
    p, R, v = interpolate_pose_at(gt, t)
    return NominalState(p, v, R, rng.normal(size=3) * 0.02, rng.normal(size=3) * 1e-3)


@pytest.mark.parametrize("obs", OBS, ids=[f"{o.name}:{type(o).__name__}" for o in OBS])
def test_observation_jacobian_matches_finite_differences(sim, obs):
    sets = tuple(f"{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in obs.enable_with.items())
    if obs.enabled_by != "filter.lidar_update":
        sets += ("filter.lidar_update=none",)
    # a lever arm makes the attitude and gyro-bias columns of the GNSS models non-trivial
    sets += ("gnss.lever_arm_b_m=[0.5, -0.3, 1.2]",)
    ds = dataset(sim)
    cfg = session.resolve(session.request(sets=sets), ds)
    prep = prepare(ds, cfg)
    b = obs.bind(prep, settings_for(cfg, prep))
    assert b.t_s.size > 5, "the observation never fires on the simulated drive"
    rng = np.random.default_rng(7)
    checked = 0
    for j in np.linspace(1, b.t_s.size - 1, 4).astype(int):
        model = b.model(int(j))
        if model is None:
            continue
        x = _truth(prep.groundtruth, float(b.t_s[j]), rng)
        t_prev = float(b.t_s[j - 1])
        pc, Rc, _ = interpolate_pose_at(prep.groundtruth, t_prev)
        clone = ClonePose()
        clone.set(pc, Rc)
        H, r0, Rm = model(x, clone.p_w_m, clone.R_wb)
        assert H.shape == (r0.size, CANONICAL.n) and Rm.shape == (r0.size, r0.size) and r0.size == b.dof
        eps = 1e-6
        Hnum = np.zeros_like(H)
        for i in range(CANONICAL.n):
            d = np.zeros(CANONICAL.n)
            d[i] = eps
            xp, cp = _perturbed(x, clone, d)
            xm, cm = _perturbed(x, clone, -d)
            # r = z - h(x): dr = -H dx
            Hnum[:, i] = -(model(xp, cp.p_w_m, cp.R_wb)[1] - model(xm, cm.p_w_m, cm.R_wb)[1]) / (2 * eps)
        # the attitude rows are exact at a zero residual; here the residual is the sensor's noise
        assert np.abs(H - Hnum).max() < 2e-3 * max(1.0, np.abs(H).max()), (obs.name, np.abs(H - Hnum).max())
        outside = [c for c in CANONICAL.blocks if c not in obs.blocks]
        for c in outside:
            assert not np.any(H[:, CANONICAL.sl(c)]), f"{obs.name}: Jacobian uses block {c} it does not declare"
        checked += 1
    assert checked >= 2


NOISELESS = ("imu.accel_noise_mps2_sqrthz=0", "imu.gyro_noise_dps_sqrthz=0", "imu.accel_bias_rw_mps3_sqrthz=0",
             "imu.gyro_bias_rw_dps2_sqrthz=0", "odometer.speed_noise_mps_sqrthz=1e-12", "odometer.slip_noise_mps_sqrthz=1e-12",
             "odometer.scale_rw_per_sqrts=0", "filter.discretization=van_loan")


def _filter(cls, rng, dt: float = 0.01):
    """A filter of the class at a random state, with a random prior and no process noise."""
    x = NominalState(rng.normal(size=3) * 10, rng.normal(size=3) * 5, exp_so3(rng.normal(size=3)), rng.normal(size=3) * 0.05,
                     rng.normal(size=3) * 0.01, k_odo=0.01)
    t = np.arange(3) * dt
    m = 4 if cls.process_model == "odometer_gyro" else 6
    u = np.tile(np.r_[[9.0], np.zeros(m - 1)], (3, 1)) + rng.normal(size=(3, m)) * 0.5
    A = rng.normal(size=(CANONICAL.n_core, CANONICAL.n_core))
    P0 = A @ A.T / CANONICAL.n_core + np.eye(CANONICAL.n_core) * 0.01
    extra = {b: 1e-4 for b in cls.layout.core if all(b != o for _, o in cls.pairs)}
    prm = cls.run_params(Settings(load_config(None, NOISELESS)), 9.81)
    return cls(x, P0, prm, t, u, 0, (np.inf, 1.0), extra)


@pytest.mark.parametrize("cls", FORMS, ids=[f"{c.name}+{c.process_model}" for c in FORMS])
def test_formulation_propagation_jacobian_matches_finite_differences(cls):
    """The covariance propagation of each formulation's compiled step, ``F Sigma F^T`` for random ``Sigma``,
    against ``J Sigma J^T`` with ``J`` the finite-difference Jacobian of the same step's state map in the
    formulation's own coordinates: the increments over one step agree to the step's O(dt) discretisation
    (F = I + F_t T for the error-state filters; the nominal filter's exact midpoint Jacobian differs from
    the coning-corrected mechanization at second order)."""
    rng = np.random.default_rng(3)
    dt = 1e-3
    kf = _filter(cls, rng, dt)
    n = kf.layout.n_core
    a = kf.arrays
    u0, u1 = a.u[0].copy(), a.u[1].copy()

    def stepped(vec: np.ndarray) -> np.ndarray:
        v = vec.copy()
        cls._step(v, np.zeros((kf.layout.n, kf.layout.n)), n, u0, u1, dt, 1.0, a.prm, kf.aux.copy(), False)
        return v

    snap0 = kf.snapshot()
    x_next = stepped(kf.xv)
    eps = 1e-6
    J = np.zeros((n, n))
    for i in range(n):
        cols = []
        for sgn in (1.0, -1.0):
            d = np.zeros(n)
            d[i] = sgn * eps
            kf.boxplus_from(snap0, d)
            kf.xv[:] = stepped(kf.xv)
            moved = kf.snapshot()
            kf.xv[:] = x_next
            cols.append(-kf.boxminus(moved))          # (stepped perturbed) [-] (stepped), own coordinates
        J[:, i] = (cols[0] - cols[1]) / (2 * eps)
    kf.boxplus_from(snap0, np.zeros(n))
    T = np.eye(n)
    if "Q" in kf.layout:
        # the quaternion block is a unit 4-vector: compare on its tangent space (the filter normalises)
        q, sl = kf.quats()["Q"], kf.layout.sl("Q")
        T[sl, sl] -= np.outer(q, q)
    for trial in range(3):
        A = rng.normal(size=(n, n))
        Sigma = T @ (A @ A.T) @ T.T
        P = np.zeros((kf.layout.n, kf.layout.n))
        P[:n, :n] = Sigma
        cls._step(kf.xv.copy(), P, n, u0, u1, dt, 1.0, a.prm, kf.aux.copy(), True)
        got, want = P[:n, :n] - Sigma, J @ Sigma @ J.T - Sigma
        assert np.abs(got - want).max() < 2e-2 * np.abs(want).max(), (cls.name, trial, np.abs(got - want).max() / np.abs(want).max())


def test_the_nominal_filter_s_transition_holds_the_gyro_bias_path_into_velocity_and_position():
    """Per block, at 10 Hz: the gyro bias turns the end attitude the step's mean acceleration reads, dv'/dbg =
    T^2/2 R [a]x and dp'/dbg = T^3/4 R [a]x. Both blocks were zero (a finite-difference audit); the whole-matrix test
    above, at 1 ms and 2 % of the largest entry, cannot see a block that small."""
    from fusion_eval.filters import mech
    from fusion_eval.filters.formulations import nominal
    from fusion_eval.filters.formulations.nominal import NBG_ID, NP_ID, NV_ID, nominal_F_Q

    cls = next(c for c in FORMS if c.name == "nominal_state")
    rng = np.random.default_rng(5)
    dt = 0.1
    kf = _filter(cls, rng, dt)
    a = kf.arrays
    u0 = a.u[0].copy()
    u1 = u0.copy()                        # one IMU value over the step: its midpoint is the sample
    x0 = kf.xv.copy()

    def stepped(bg_shift):
        v = x0.copy()
        v[mech.XBG:mech.XBG + 3] += bg_shift
        f, w = u1[nominal.UF:nominal.UF + 3], u1[nominal.UW:nominal.UW + 3]
        mech.mech_step(v, f, w, f, w, dt, a.prm[nominal.PRM_G])
        return v

    eps = 1e-6
    J = np.column_stack([(stepped(e * eps) - stepped(-e * eps)) / (2 * eps) for e in np.eye(3)])
    fm = u0[nominal.UF:nominal.UF + 3] - x0[mech.XBA:mech.XBA + 3]
    wm = u0[nominal.UW:nominal.UW + 3] - x0[mech.XBG:mech.XBG + 3]
    q = nominal.aligned_quat(mech.attitude(x0), kf.aux[nominal.AQ0:nominal.AQ0 + 4])
    F, _ = nominal_F_Q(q, fm, wm, dt, a.prm, 1.0)
    for rows, x_rows in ((slice(NV_ID, NV_ID + 3), slice(mech.XV, mech.XV + 3)),
                         (slice(NP_ID, NP_ID + 3), slice(mech.XP, mech.XP + 3))):
        want, got = J[x_rows], F[rows, NBG_ID:NBG_ID + 3]
        # to first order in the step's rotation (|w| T ~ 0.08 rad here: 4 %); a missing block is 100 % off
        assert np.abs(got - want).max() < 0.1 * np.abs(want).max(), (rows, got, want)


@pytest.mark.parametrize("cls", FORMS, ids=[f"{c.name}+{c.process_model}" for c in FORMS])
def test_canonical_map_matches_finite_differences(cls):
    """D = d(canonical error)/d(own state), built from the layout's pairs, against perturbing the own state
    and measuring the canonical error of the result (clone included)."""
    rng = np.random.default_rng(5)
    kf = _filter(cls, rng)
    kf.clone_pose()
    kf.clone.R_wb[:] = kf.clone.R_wb @ exp_so3(rng.normal(size=3) * 0.1)
    n = kf.n
    snap0 = kf.snapshot()
    x0, c0 = kf.x.copy(), kf.clone.copy()
    D = kf.D()
    C = CANONICAL
    eps = 1e-6
    Dnum = np.zeros_like(D)
    for i in range(n):
        d = np.zeros(n)
        d[i] = eps
        kf.boxplus_from(snap0, d)
        e = np.zeros(C.n)
        e[C.sl("P")] = kf.x.p_w_m - x0.p_w_m
        e[C.sl("V")] = kf.x.v_w_mps - x0.v_w_mps
        e[C.sl("TH")] = log_so3(x0.R_wb.T @ kf.x.R_wb)
        e[C.sl("BA")] = kf.x.ba_b - x0.ba_b
        e[C.sl("BG")] = kf.x.bg_b - x0.bg_b
        e[C.sl("CP")] = kf.clone.p_w_m - c0.p_w_m
        e[C.sl("CTH")] = log_so3(c0.R_wb.T @ kf.clone.R_wb)
        Dnum[:, i] = e / eps
        kf.boxplus_from(snap0, np.zeros(n))
    have = canonical_blocks(cls.layout, cls.pairs)
    rows = np.concatenate([np.arange(C[b].start, C[b].stop) for b in C.blocks if b in have])
    assert np.abs(D[rows] - Dnum[rows]).max() < 1e-5, cls.name
    # canonical blocks the formulation has no counterpart for map to nothing
    for b in C.blocks:
        if b not in have:
            assert not np.any(D[C.sl(b)]), (cls.name, b)
