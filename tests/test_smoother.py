"""The RTS smoother: exact on a linear-Gaussian model (against the batch least-squares solution), the recomputed
forward intervals equal to the filter's own, consistent and better than the filter on a simulation, and in every
output of a run."""

from __future__ import annotations

import re
import json

import numpy as np
import pytest
from numba import njit

import fusion_eval as fe
from fusion_eval.errors import ConfigError
from fusion_eval.filters.formulations.base import ErrorStateBase
from fusion_eval.filters.layout import CANONICAL, CLONE, Layout
from fusion_eval.filters.mech import XP, XV
from fusion_eval.filters.propagate import compiled_loop, record_cov_by_index
from fusion_eval.filters.state import NominalState
from fusion_eval.smoothing.record import EpochRecord
from fusion_eval.smoothing.rts import smooth

# ---- a linear-Gaussian formulation: constant-velocity motion driven by a known acceleration input ----------
LIN = Layout("linear test", [("P", 3), ("V", 3)], clone=[("CP", 3)], clone_of={"CP": "P"})


@njit(cache=False)
def _lin_step(x, P, n, u0, u1, dt, qscale, prm, aux, cov):
    a = 0.5 * (u0[:3] + u1[:3])
    if cov:
        F = np.eye(n)
        for i in range(3):
            F[i, 3 + i] = dt
        q = prm[0] * prm[0] * qscale
        newP = F @ np.ascontiguousarray(P[:n, :n]) @ F.T
        for i in range(3):
            newP[i, i] += q * dt ** 3 / 3.0
            newP[i, 3 + i] += q * dt ** 2 / 2.0
            newP[3 + i, i] += q * dt ** 2 / 2.0
            newP[3 + i, 3 + i] += q * dt
        P[:n, :n] = 0.5 * (newP + newP.T)
    for i in range(3):
        x[XP + i] += x[XV + i] * dt + 0.5 * a[i] * dt * dt
        x[XV + i] += a[i] * dt


class LinearCV(ErrorStateBase):
    name = "linear_test"
    layout = LIN
    pairs = (("P", "P"), ("V", "V"), ("CP", "CP"))
    targets = {"P": "p", "V": "v", "CP": "clone.p"}
    _step = staticmethod(_lin_step)
    _predict = staticmethod(compiled_loop(__name__, _lin_step, record_cov_by_index))
    _record_cov = staticmethod(record_cov_by_index)


CP = CLONE.start("p")


@njit(cache=False)
def _lin_minus(x, xc, x0, xc0, n):
    d = np.zeros(n)
    for i in range(3):
        d[i] = x[XP + i] - x0[XP + i]
        d[3 + i] = x[XV + i] - x0[XV + i]
        if n > 6:
            d[6 + i] = xc[CP + i] - xc0[CP + i]
    return d


@njit(cache=False)
def _lin_plus_into(x, xc, x0, xc0, dx, n):
    x[:] = x0
    xc[:] = xc0
    for i in range(3):
        x[XP + i] += dx[i]
        x[XV + i] += dx[3 + i]
        if n > 6:
            xc[CP + i] += dx[6 + i]


class LinearCVCompiled(LinearCV):
    """The same model with its ``[-]``/``[+]`` compiled: smoothed by the compiled backward pass."""
    _rts_boxminus = staticmethod(_lin_minus)
    _rts_boxplus = staticmethod(_lin_plus_into)


def _interp_inputs(t, u, times):
    """The input rows the replay loop steps with at ``times`` (linear interpolation, as the loop does)."""
    return np.stack([np.array([np.interp(tt, t, u[:, j]) for j in range(u.shape[1])]) for tt in times])


def _batch(x0, P0, q, nodes, u_nodes, gnss, rel):
    """The batch least-squares (MAP) solution over the states at ``nodes``: mean and covariance of each."""
    m = len(nodes)
    N = 6 * m
    Lam, eta = np.zeros((N, N)), np.zeros(N)

    def add(J, r0, W):      # a residual r = J X - r0 with weight W
        nonlocal Lam, eta
        Lam += J.T @ W @ J
        eta += J.T @ W @ r0

    J = np.zeros((6, N))
    J[:, :6] = np.eye(6)
    add(J, x0, np.linalg.inv(P0))
    for i in range(m - 1):
        dt = nodes[i + 1] - nodes[i]
        a = 0.5 * (u_nodes[i] + u_nodes[i + 1])
        F = np.eye(6)
        F[:3, 3:] = dt * np.eye(3)
        b = np.concatenate([0.5 * a * dt * dt, a * dt])
        Q = q * q * np.block([[dt ** 3 / 3 * np.eye(3), dt ** 2 / 2 * np.eye(3)], [dt ** 2 / 2 * np.eye(3), dt * np.eye(3)]])
        J = np.zeros((6, N))
        J[:, 6 * (i + 1):6 * (i + 2)] = np.eye(6)
        J[:, 6 * i:6 * (i + 1)] = -F
        add(J, b, np.linalg.inv(Q))
    for i, z, R in gnss:
        J = np.zeros((3, N))
        J[:, 6 * i:6 * i + 3] = np.eye(3)
        add(J, z, np.linalg.inv(R))
    for i0, i1, z, R in rel:
        J = np.zeros((3, N))
        J[:, 6 * i1:6 * i1 + 3] = np.eye(3)
        J[:, 6 * i0:6 * i0 + 3] = -np.eye(3)
        add(J, z, np.linalg.inv(R))
    cov = np.linalg.inv(Lam)
    return (cov @ eta).reshape(m, 6), cov


@pytest.mark.slow
@pytest.mark.parametrize("cls", [LinearCV, LinearCVCompiled], ids=["python", "compiled"])
def test_rts_equals_the_batch_least_squares_solution_on_a_linear_gaussian_model(cls):
    """Position fixes and relative-position increments through a stochastic clone, some at sample stamps and some
    between them (partial intervals), one at the very first stamp: every smoothed mean and variance at the samples
    equals the batch solution to 1e-9, stepped sample by sample (Python) and smoothed a whole interval at once
    (compiled)."""
    from fusion_eval.smoothing.compiled import compiled_pass

    assert (compiled_pass(cls) is not None) == (cls is LinearCVCompiled)
    rng = np.random.default_rng(3)
    t = np.round(np.arange(0.0, 6.0, 0.1), 10)      # the literal event stamps below fall exactly on samples
    u = rng.normal(0.0, 0.5, (t.size, 3))
    q = 0.3
    x0 = NominalState(np.array([1.0, -2.0, 0.5]), np.array([3.0, 0.5, 0.0]), np.eye(3), np.zeros(3), np.zeros(3))
    P0c = np.diag(np.r_[np.full(3, 0.2 ** 2), np.full(3, 0.1 ** 2), np.full(9, 1e-4)])
    kf = cls(x0, P0c, np.array([q]), t, u, 0)
    lidar_t = np.r_[0.0, 0.3, 0.65, 1.0, 1.4, 2.05, 2.5, 3.0, 3.55, 4.0, 4.7, 5.2]
    gnss_t = np.array([0.5, 1.4, 2.5, 3.33, 4.5, 5.9])
    events = sorted([(tt, 0) for tt in lidar_t] + [(tt, 1) for tt in gnss_t])
    rec = kf.recorder = EpochRecord(kf, len(events))
    rec.epoch(kf)
    R_rel, R_gnss = np.diag([0.05, 0.04, 0.06]) ** 2, np.diag([0.5, 0.5, 1.0]) ** 2
    z_of = {}
    for tt, kind in events:
        kf.predict_to(tt)
        if kind == 1:
            z = rng.normal(0, 1, 3)
            z_of[(tt, 1)] = z

            def model(x, cp, cR, z=z):
                H = np.zeros((3, CANONICAL.n))
                H[:, CANONICAL.sl("P")] = np.eye(3)
                return H, z - x.p_w_m, R_gnss
            kf.update(model)
        else:
            if kf.cloned:
                z = rng.normal(0, 0.5, 3)
                z_of[(tt, 0)] = z

                def model(x, cp, cR, z=z):
                    H = np.zeros((3, CANONICAL.n))
                    H[:, CANONICAL.sl("P")] = np.eye(3)
                    H[:, CANONICAL.sl("CP")] = -np.eye(3)
                    return H, z - (x.p_w_m - cp), R_rel
                kf.update(model)
            kf.clone_pose()
        rec.epoch(kf)
    kf.predict_to(t[-1])
    rec.epoch(kf)
    sm = smooth(kf, rec, 0)

    nodes = np.unique(np.r_[t, lidar_t, gnss_t])
    idx = {round(v, 9): i for i, v in enumerate(nodes)}
    gnss = [(idx[round(tt, 9)], z_of[(tt, 1)], R_gnss) for tt in gnss_t]
    rel = [(idx[round(a, 9)], idx[round(b, 9)], z_of[(b, 0)], R_rel) for a, b in zip(lidar_t[:-1], lidar_t[1:])]
    P0 = P0c[:6, :6]
    mean, cov = _batch(x0.vec[:6].copy(), P0, q, nodes, _interp_inputs(t, u, nodes), gnss, rel)
    at = np.array([idx[round(v, 9)] for v in t])
    np.testing.assert_allclose(sm.rec_x[:, :6], mean[at], rtol=0, atol=1e-9)
    var = np.array([np.diag(cov[6 * i:6 * i + 6, 6 * i:6 * i + 6]) for i in at])
    np.testing.assert_allclose(sm.rec_Pdiag[:, :6], var, rtol=1e-9, atol=1e-15)
    # and the filter itself is not the smoother: the last state agrees, the first does not
    np.testing.assert_allclose(kf.rec_x[-1, :6], sm.rec_x[-1, :6], atol=1e-12)
    assert np.abs(kf.rec_x[0, :6] - sm.rec_x[0, :6]).max() > 1e-3


def _capture(monkeypatch):
    import fusion_eval.smoothing.rts as rts

    seen = {}
    orig = rts.smooth

    def spy(kf, rec, k0, python=False):
        seen.update(kf=kf, rec=rec, python=python)
        return orig(kf, rec, k0, python)
    monkeypatch.setattr(rts, "smooth", spy)
    return seen


@pytest.mark.parametrize("sets", [{}, {"filter.lidar_update": "none"}, {"filter.formulation": "invariant"},
                                  {"filter.formulation": "invariant", "filter.lidar_update": "none"}],
                         ids=["lidar-clones+gnss", "gnss", "invariant", "invariant-gnss"])
def test_the_compiled_backward_pass_equals_the_one_stepped_from_python(kitti_slice, monkeypatch, sets):
    """The ESKF's backward pass runs in one compiled call (fusion_eval/smoothing/compiled.py) that smooths each point
    of an IMU interval from the interval's end at once (the gains of the steps between multiply out); stepped from
    Python (each interval recomputed, each clone undone, each sample smoothed from the next one) it is the same
    estimate to rounding: 1e-13 m measured, 1e-9 required; variances to 1e-6 relative (the gain amplifies rounding
    in near-singular directions). The invariant filter's too, on its group (it was stepped from Python, ~100 us per IMU
    sample: a rate review)."""
    from fusion_eval.smoothing.compiled import compiled_pass
    from fusion_eval.smoothing.rts import smooth

    seen = _capture(monkeypatch)
    fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts", **sets})
    kf, rec = seen["kf"], seen["rec"]
    assert compiled_pass(type(kf)) is not None and (rec.clones.size > 100) == ("filter.lidar_update" not in sets)
    a, b = smooth(kf, rec, 0, python=True), smooth(kf, rec, 0)
    assert np.isfinite(b.rec_x[-1]).all() and np.array_equal(np.isnan(a.rec_x), np.isnan(b.rec_x))
    assert np.nanmax(np.abs(b.rec_x - kf.rec_x)) > 1e-3          # smoothed, not the filter's record
    np.testing.assert_allclose(b.rec_x, a.rec_x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.rec_Pdiag, a.rec_Pdiag, rtol=1e-6, atol=1e-15)
    np.testing.assert_allclose(b.rec_Ppt, a.rec_Ppt, rtol=1e-6, atol=1e-12)


def test_a_python_replay_steps_the_backward_pass_from_python_too(kitti_slice, monkeypatch):
    """filter.replay: python ("always from Python") reached the forward loop only: the RTS pass stayed compiled (a
    configuration audit). The report's smoother section says which ran."""
    seen = _capture(monkeypatch)
    res = fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts", "filter.replay": "python",
                                                          "filter.lidar_update": "none"})
    assert seen["python"] is True and res.metrics["smoother"]["backward_pass"] == "python"
    res = fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts", "filter.lidar_update": "none"})
    assert seen["python"] is False and res.metrics["smoother"]["backward_pass"] == "compiled"


@pytest.mark.parametrize("formulation", ["error_state", "invariant"])
def test_the_smoothers_step_after_a_gap_adds_the_formulations_own_gap_motion(kitti_slice, monkeypatch, formulation):
    """The backward pass recomputes the step that ends an IMU gap with the motion the gap hid, as the filter added it:
    in the formulation's own coordinates (the invariant filter's, added by index, moved its smoothed estimate 2.3 mm;
    a review)."""
    from fusion_eval.smoothing.rts import RTS

    seen = _capture(monkeypatch)
    fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts", "filter.formulation": formulation})
    kf, rec = seen["kf"], seen["rec"]
    bw = RTS(kf, rec)
    nc = kf.layout.n_core
    x0, u = kf.arrays.rec_x[100].copy(), kf.arrays.u
    A = np.eye(nc) * 1e-4
    outs = []
    for gap_s in (0.0, 2.0):
        x = x0.copy()
        outs.append(bw._step(x, kf.aux.copy(), A.copy(), u[100], u[101], 0.1, 1.0, gap_s)[0])
    # the increment, seen in the canonical error (D dP D^T): the attitude's and velocity's variances, nothing else
    diag = np.empty(15)
    kf._record_cov(np.ascontiguousarray(outs[1] - outs[0]), nc, x, kf.aux, kf.cidx, diag, np.empty(21))
    gap = kf.arrays.gap
    expected = np.r_[np.zeros(3), np.full(3, gap[3] * 4.0), np.full(3, gap[2] * 4.0), np.zeros(6)]
    np.testing.assert_allclose(diag, expected, rtol=1e-9, atol=1e-12)
    assert expected.max() > 1e-3


@pytest.mark.parametrize("python", [False, True], ids=["compiled", "python"])
def test_the_priors_kept_forward_give_the_estimate_of_every_interval_recomputed(kitti_slice, monkeypatch, python):
    """The forward pass keeps each epoch's prior covariance, so the backward pass steps into an epoch with the
    transition alone; with those priors withheld it recomputes the covariance of every interval: the same smoothed
    estimate (to 1e-9 m, variances to 1e-6 relative: the gain amplifies rounding in near-singular directions)."""
    from fusion_eval.smoothing.rts import smooth

    seen = _capture(monkeypatch)
    fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts"})
    kf, rec = seen["kf"], seen["rec"]
    n = rec.epochs.size
    assert rec.prior_ok[1:n].all() and rec.bytes_per_epoch() > 4000       # every epoch after the first has its prior
    a = smooth(kf, rec, 0, python=python)
    rec.prior_ok[:] = False
    b = smooth(kf, rec, 0, python=python)
    np.testing.assert_allclose(a.rec_x[:, :3], b.rec_x[:, :3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.rec_Pdiag, b.rec_Pdiag, rtol=1e-6, atol=1e-15)


@pytest.mark.slow
def test_the_compiled_event_loop_keeps_the_smoothers_forward_record(kitti_slice, monkeypatch):
    """With an RTS smoother the ESKF's replay stays in the compiled event loop, which keeps the epochs and the
    states before each clone itself; the record and the filtered estimate equal those of the loop stepped from Python
    (measured bit for bit), the smoothed one to rounding (the backward pass is stepped from Python there too)."""
    from fusion_eval.filters import compiled_replay

    used = []
    orig = compiled_replay.usable
    monkeypatch.setattr(compiled_replay, "usable", lambda *a: used.append(orig(*a)) or used[-1])
    seen = _capture(monkeypatch)
    ds = fe.load_dataset(kitti_slice)
    runs, recs = {}, {}
    for mode in ("python", "auto"):
        runs[mode] = fe.run(ds, overrides={"smoother.method": "rts", "filter.replay": mode})
        recs[mode] = seen["rec"]
    assert used == [False, True]
    a, b = recs["python"], recs["auto"]
    assert (a.epochs.size, a.clones.size) == (b.epochs.size, b.clones.size) and b.clones.size > 100
    for f in ("t", "k_next", "n", "x", "c", "aux", "u", "P"):
        np.testing.assert_array_equal(getattr(b.epochs, f)[:b.epochs.size], getattr(a.epochs, f)[:a.epochs.size], f)
        np.testing.assert_array_equal(getattr(b.clones, f)[:b.clones.size], getattr(a.clones, f)[:a.clones.size], f)
    np.testing.assert_array_equal(b.clone_epoch[:b.clones.size], a.clone_epoch[:a.clones.size])
    np.testing.assert_array_equal(b.prior_ok, a.prior_ok)              # each epoch's prior, kept by both loops
    np.testing.assert_array_equal(b.prior_P[b.prior_ok], a.prior_P[a.prior_ok])
    np.testing.assert_array_equal(b.prior_phi[b.prior_ok], a.prior_phi[a.prior_ok])   # and the transition into it
    assert np.isfinite(b.prior_phi[b.prior_ok]).all() and np.abs(b.prior_phi[b.prior_ok] - np.eye(15).ravel()).max() > 0.1
    assert b.prior_ok[1:b.epochs.size].all()
    np.testing.assert_array_equal(runs["auto"].series["fused"].p_w_m, runs["python"].series["fused"].p_w_m)
    # (filter.replay=python steps the backward pass from Python too: the same estimate to rounding)
    np.testing.assert_allclose(runs["auto"].series["smoothed"].p_w_m, runs["python"].series["smoothed"].p_w_m,
                               rtol=0, atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("formulation", ["error_state", "invariant"])
def test_the_recomputed_intervals_are_the_filters_own(kitti_slice, monkeypatch, formulation):
    """Between GNSS epochs the backward pass recomputes each IMU interval with the formulation's compiled step (and
    its transition from an augmented covariance): the states and variances equal what the filter recorded."""
    from fusion_eval.smoothing.rts import RTS

    seen = _capture(monkeypatch)
    ds = fe.load_dataset(kitti_slice)
    fe.run(ds, overrides={"smoother.method": "rts", "filter.lidar_update": "none", "filter.formulation": formulation})
    kf, rec = seen["kf"], seen["rec"]
    bw = RTS(kf, rec)
    checked = 0
    for b in range(1, rec.epochs.size):
        points, phis = bw.segment(b - 1, float(rec.epochs.t[b]))
        assert len(phis) == len(points) - 1
        for x, aux, A, B, P, k, _ in points[1:-1]:          # samples strictly inside: the filter recorded its prior there
            np.testing.assert_allclose(x, kf.rec_x[k], rtol=0, atol=1e-9)
            diag = np.empty(15)
            kf._record_cov(np.ascontiguousarray(P), P.shape[0], x, aux, kf.cidx, diag, np.empty(21))
            # the replay's output took the record's square roots in place (its sigmas)
            np.testing.assert_allclose(np.sqrt(np.maximum(diag, 0.0)), kf.arrays.rec_Pdiag[k], rtol=1e-9, atol=1e-18)
            checked += 1
    assert checked > 50


@pytest.mark.slow
def test_a_run_writes_and_reports_the_smoothed_estimate(kitti_slice, tmp_path):
    from click.testing import CliRunner

    from fusion_eval.cli import main

    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--out", str(out), "--set", "smoother.method=rts"])
    assert r.exit_code == 0, r.output
    m = json.loads((out / "metrics.json").read_text())
    s, f = (m["estimates"][k]["ape"]["translation_m"]["rmse"] for k in ("smoothed", "fused"))
    assert s < f
    assert m["ratios"]["smoothed_over_fused"] == pytest.approx(s / f)
    assert m["smoother"]["method"] == "rts" and m["smoother"]["bytes_per_epoch"] > 0
    assert set(m["nees_smoothed"]) == {"position", "attitude"}
    assert (out / "smoothed.tum").read_text().count("\n") > 100
    report = (out / "report.md").read_text()
    assert re.search(r"\| smoothed +\|", report) and "NEES smoothed position" in report
    # check gates on it like on any estimate
    mj = str(out / "metrics.json")
    r = CliRunner().invoke(main, ["check", mj, "-b", mj, "--metric", "smoothed.*", "--require", "smoothed.ape.rmse < fused.ape.rmse",
                                  "--require", "nees_smoothed.position.fraction_in_95 > 0.5"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["check", mj, "-b", mj, "--require", "smoothed.ape.rmse > fused.ape.rmse"])
    assert r.exit_code != 0


def test_the_nominal_state_filter_is_refused_with_a_reason(kitti_slice):
    with pytest.raises(ConfigError, match="smoother.method=rts is not available with filter.formulation=nominal_state"):
        fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts", "filter.formulation": "nominal_state"})


@pytest.mark.slow
@pytest.mark.parametrize("formulation", ["error_state", "invariant"])
def test_the_smoother_is_consistent_and_better_than_the_filter_on_a_simulation(white_sim, formulation):
    """The smoothed NEES is inside its 95 % interval on >= 90 % of the epochs, and the smoothed error below the
    filtered one, for each formulation the smoother runs over (measured: 99.7 % / 98 %, 0.27 against 0.58 m)."""
    m = white_sim(formulation).metrics
    for q in ("position", "attitude"):
        assert m["nees_smoothed"][q]["fraction_in_95"] >= 0.9, (formulation, q, m["nees_smoothed"][q])
    e = m["estimates"]
    for rel in ("translation_m", "rotation_deg"):
        assert e["smoothed"]["ape"][rel]["rmse"] < 0.8 * e["fused"]["ape"][rel]["rmse"], (formulation, rel)


@pytest.mark.slow
def test_the_batch_estimate_runs_and_says_what_it_built(kitti_slice, tmp_path):
    pytest.importorskip("gtsam", reason="the 'smoother' extra (gtsam) is not installed")
    res = fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "batch"})
    m = res.metrics
    info = m["smoother"]
    assert info["method"] == "batch" and info["keyframes"] > 10
    nis = m["nis"]
    assert info["lidar_relative_factors"] == nis["lidar"]["epochs"] - nis["lidar"]["rejected"]
    assert info["gnss_factors"] == nis["gnss"]["epochs"] - nis["gnss"]["rejected"] > 0
    assert info["final_error"] < 1e-3 * info["initial_error"] or info["final_error"] < 10 * info["factors"]
    s, f = (m["estimates"][k]["ape"]["translation_m"]["rmse"] for k in ("smoothed", "fused"))
    assert s < f
    assert np.isfinite(res.filter.smoothed.P_pos_att).all()
    from click.testing import CliRunner

    from fusion_eval.cli import main

    r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--out", str(tmp_path / "b"), "--no-plots",
                                  "--set", "smoother.method=batch"])
    assert r.exit_code == 0, r.output
    assert "Smoother: **batch** (GTSAM)" in (tmp_path / "b" / "report.md").read_text()
    assert (tmp_path / "b" / "smoothed.tum").exists()


@pytest.mark.slow
def test_the_batch_estimate_takes_the_imu_gaps_as_the_filter_does(tmp_path):
    """The batch estimate preintegrated an IMU gap with the ordinary noise and without the motion it hid: extreme
    imu.gap_* values moved the filter from 1.52 to 20.4 m and it by 1e-5 m (a configuration audit). Across kitti-00's
    1.7 s gap at 34 s it now takes the filter's noise there: a wider gap noise loosens it as it loosens the filter."""
    pytest.importorskip("gtsam", reason="the 'smoother' extra (gtsam) is not installed")
    from conftest import make_slice

    ds = fe.load_dataset(make_slice(tmp_path / "gap", 160, first=280))
    base = {"smoother.method": "batch", "filter.lidar_update": "none", "filter.nhc": False}
    runs = [fe.run(ds, overrides={**base, **extra}).filter.smoothed
            for extra in ({}, {"imu.gap_noise_scale": 1.0},
                          {"imu.gap_noise_scale": 100.0, "imu.gap_turn_rate_dps": 200.0, "imu.gap_accel_mps2": 20.0})]
    moved = [float(np.max(np.abs(r.fused.p_w_m - runs[0].fused.p_w_m))) for r in runs[1:]]
    assert moved[0] > 1e-3 and moved[1] > 1e-2, moved
    # its position's variance across the gap (packets 347-361: 6.7-8.1 s in) grows with the gap noise, as the filter's
    t = runs[0].fused.t_s - runs[0].fused.t_s[0]
    near = (t > 6.0) & (t < 10.0)
    assert np.nanmax(runs[2].P_pos_att[near, 0, 0]) > 1.3 * np.nanmax(runs[0].P_pos_att[near, 0, 0])


def test_the_batch_estimate_names_the_missing_extra(kitti_slice, monkeypatch):
    import builtins

    real = builtins.__import__

    def no_gtsam(name, *a, **kw):
        if name == "gtsam" or name.startswith("gtsam."):
            raise ImportError("No module named 'gtsam'")
        return real(name, *a, **kw)
    monkeypatch.setattr(builtins, "__import__", no_gtsam)
    with pytest.raises(ConfigError, match=r"needs GTSAM, which is not installed: pip install 'fusion-eval\[smoother\]'"):
        fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "batch"})


def test_the_batch_estimate_refuses_what_it_cannot_express(kitti_slice):
    with pytest.raises(ConfigError, match="filter.bias_model=gauss_markov is not supported"):
        fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "batch", "filter.bias_model": "gauss_markov"})
    with pytest.raises(ConfigError, match="lidar.relative_frame=world is not supported"):
        fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "batch", "lidar.relative_frame": "world"})


@pytest.mark.slow
def test_the_batch_estimate_agrees_with_rts_on_a_simulation(white_sim):
    """The same measurements and noise, two solvers: the GTSAM optimum and the RTS pass over the filter agree within
    their reported uncertainties (and their covariances agree), on white-noise sensors."""
    pytest.importorskip("gtsam", reason="the 'smoother' extra (gtsam) is not installed")
    a, b = (white_sim(method=m).filter.smoothed for m in ("rts", "batch"))
    d = a.fused.p_w_m - b.fused.p_w_m
    sig = np.sqrt(a.sigma[:, 0:3] ** 2 + b.sigma[:, 0:3] ** 2)
    assert np.all(np.abs(d) <= 3 * sig)
    assert np.sqrt(np.mean(d ** 2)) < 0.2 * np.median(a.sigma[:, 0:3])
    np.testing.assert_allclose(np.median(b.sigma[:, 0:3], axis=0), np.median(a.sigma[:, 0:3], axis=0), rtol=0.05)


def test_a_formulation_that_derives_part_of_its_state_from_the_input_is_smoothed_with_it(kitti_slice):
    """The odometer + gyro model derives its velocity from the odometer input: the smoothed velocity must be the one
    of each sample's own input, not of whatever input the filter object last sat at."""
    res = fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts", "filter.process_model": "odometer_gyro",
                                                          "filter.lidar_update": "none"})
    f, s = res.filter.fused, res.filter.smoothed.fused
    speed_f, speed_s = np.linalg.norm(f.v_w_mps, axis=1), np.linalg.norm(s.v_w_mps, axis=1)
    assert np.median(np.abs(speed_s - speed_f)) < 0.05 * np.median(speed_f)


def test_the_batch_estimate_refuses_an_observation_it_has_no_factor_for_before_filtering(kitti_slice):
    with pytest.raises(ConfigError, match=r"smoother.method=batch has no factor for .*\(filter.nhc\): set filter.nhc=false"):
        fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "batch", "filter.nhc": True})


def test_a_transition_the_step_did_not_write_surfaces_as_nan_not_as_an_estimate(kitti_slice, monkeypatch):
    """The room the smoother reserves for the step's transition is NaN until the step writes it and is refilled
    after each epoch takes it: were a formulation to claim it keeps transitions without writing them, the smoothed
    estimate would be NaN (and the run refused as diverged), never a plausible one from a zero transition."""
    from fusion_eval.filters.formulations.eskf import ErrorStateKF
    from fusion_eval.smoothing.rts import smooth

    seen = _capture(monkeypatch)
    fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts"})
    kf, rec = seen["kf"], seen["rec"]
    assert kf.keeps_transition() and np.isnan(kf.aux[1:]).all()       # the room, refilled after the last epoch
    assert np.isfinite(smooth(kf, rec, 0).rec_x[-1]).all()
    rec.prior_phi[rec.prior_ok] = np.nan                              # as if the step had written nothing
    assert np.isnan(smooth(kf, rec, 0).rec_x[:-1, :3]).any()
    kf.reserve_transition()                                           # once per filter: a second call adds nothing
    assert kf.aux.size == 1 + 15 * 15 and isinstance(kf, ErrorStateKF)


def test_an_imu_interval_is_preintegrated_in_substeps_of_interpolated_inputs():
    from fusion_eval.smoothing.batch import MAX_SUBSTEP_S, substeps

    u0, u1 = np.array([0.0, 1.0]), np.array([1.0, 3.0])
    steps = list(substeps(u0, u1, 0.1))
    assert len(steps) == round(0.1 / MAX_SUBSTEP_S) and [s[2] for s in steps] == [False] * 9 + [True]
    assert sum(h for _, h, _ in steps) == pytest.approx(0.1)
    # each sub-step's midpoint input: their mean is the interval's, their first the first tenth's midpoint
    np.testing.assert_allclose(np.mean([u for u, _, _ in steps], axis=0), 0.5 * (u0 + u1))
    np.testing.assert_allclose(steps[0][0], u0 + 0.05 * (u1 - u0))
    assert len(list(substeps(u0, u1, 0.005))) == 1                # a 100 Hz+ IMU: one step, as before


@pytest.mark.slow
def test_the_batch_estimate_is_consistent_with_a_10_hz_imu(tmp_path):
    """GTSAM's preintegration is first order within a step: fed KITTI's 10 Hz intervals whole, the smoothed attitude
    NEES was 19.4 for 3 dof on white-noise sensors (a math review); in 10 ms sub-steps it is as consistent as RTS's."""
    pytest.importorskip("gtsam", reason="the 'smoother' extra (gtsam) is not installed")
    import fusion_eval as fe
    from fusion_eval.simulate.dataset import simulate

    out = tmp_path / "w10"
    simulate(out, "urban", 90.0, 1, "automotive", ("lidar.scale_drift=0", "lidar.yaw_drift_deg_per_100m=0",
                                                   "imu.rate_hz=10"), jobs=1)
    ds = fe.load_dataset(out)
    res = {m: fe.run(ds, overrides={"smoother.method": m, "output.plots": False}) for m in ("rts", "batch")}
    nees = {m: r.metrics["nees_smoothed"]["attitude"]["mean"] for m, r in res.items()}
    rot = {m: r.metrics["estimates"]["smoothed"]["ape"]["rotation_deg"]["rmse"] for m, r in res.items()}
    assert nees["batch"] < 6.0, nees
    assert rot["batch"] < 1.3 * rot["rts"], rot
