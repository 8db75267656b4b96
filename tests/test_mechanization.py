"""Midpoint strapdown mechanization against analytic motion."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_eval.filters import kernels as kn
from fusion_eval.filters import propagate as pr
from fusion_eval.filters.eskf import NominalState, dead_reckon
from fusion_eval.so3 import exp_so3

G = 9.81


def _prm():
    prm = np.zeros(kn.N_PRM)
    prm[kn.PRM_G] = G
    prm[kn.PRM_GAP_DT] = np.inf
    prm[kn.PRM_GAP_SCALE2] = 1.0
    return prm


def _x0(p=(0, 0, 0), v=(0, 0, 0), R=np.eye(3)):
    return NominalState(np.array(p, float), np.array(v, float), np.array(R, float), np.zeros(3), np.zeros(3))


def test_stationary_with_gravity_stays_put():
    rng = np.random.default_rng(1)
    R0 = exp_so3(rng.normal(size=3) * 0.3)       # tilted, arbitrary heading
    t = np.arange(0, 100, 0.01)
    f = np.tile(R0.T @ [0, 0, G], (t.size, 1))   # specific force = -gravity in the body frame
    w = np.zeros((t.size, 3))
    p, R = dead_reckon(_x0(R=R0), _prm(), t, f, w, 0)
    assert np.abs(p).max() < 1e-9
    assert np.abs(R - R0).max() < 1e-12


def test_constant_acceleration_is_exact():
    R0 = exp_so3(np.array([0.1, -0.2, 0.7]))
    a_w = np.array([0.5, -0.2, 0.1])
    v0 = np.array([3.0, 1.0, 0.0])
    t = np.arange(0, 60, 0.01)
    f = np.tile(R0.T @ (a_w + [0, 0, G]), (t.size, 1))
    p, _ = dead_reckon(_x0(v=v0, R=R0), _prm(), t, f, np.zeros((t.size, 3)), 0)
    tt = (t - t[0])[:, None]
    p_true = v0 * tt + 0.5 * a_w * tt ** 2
    assert np.abs(p - p_true).max() < 1e-7


def test_constant_turn_rate_attitude_exact_and_circle_followed():
    # level car on a circle: speed V, yaw rate om; body specific force = centripetal + gravity
    V, om = 10.0, 0.2
    t = np.arange(0, 30, 0.01)
    f = np.tile([0.0, V * om, G], (t.size, 1))
    w = np.tile([0.0, 0.0, om], (t.size, 1))
    p, R = dead_reckon(_x0(v=(V, 0, 0)), _prm(), t, f, w, 0)
    yaw = om * (t - t[0])
    assert np.abs(R[:, 0, 0] - np.cos(yaw)).max() < 1e-12
    assert np.abs(R[:, 1, 0] - np.sin(yaw)).max() < 1e-12
    p_true = np.column_stack([V / om * np.sin(yaw), V / om * (1 - np.cos(yaw)), np.zeros_like(yaw)])
    # second-order scheme: 900 steps of 1 cm/s^2-scale truncation over 150 m of arc
    assert np.abs(p - p_true).max() < 0.05
    # and the error shrinks as dt^2 (halving dt quarters it)
    t2 = np.arange(0, 30, 0.005)
    p2, _ = dead_reckon(_x0(v=(V, 0, 0)), _prm(), t2, np.tile(f[0], (t2.size, 1)), np.tile(w[0], (t2.size, 1)), 0)
    yaw2 = om * t2
    p2_true = np.column_stack([V / om * np.sin(yaw2), V / om * (1 - np.cos(yaw2)), np.zeros_like(yaw2)])
    e1, e2 = np.abs(p[-1] - p_true[-1]).max(), np.abs(p2[-1] - p2_true[-1]).max()
    assert 3.0 < e1 / e2 < 5.0


def test_observation_between_samples_uses_interpolated_imu():
    # constant acceleration: stopping at an intermediate time and going on gives the same end state

    a_w = np.array([1.0, 0.0, 0.0])
    t = np.arange(0, 1.0 + 1e-9, 0.1)
    f = np.tile(a_w + [0, 0, G], (t.size, 1))
    w = np.zeros((t.size, 3))
    N = t.size
    rec = [np.full((N, 3), np.nan), np.full((N, 3), np.nan), np.full((N, 3, 3), np.nan), np.full((N, 3), np.nan),
           np.full((N, 3), np.nan), np.full((N, 15), np.nan), np.full((N, 6, 6), np.nan)]
    x = _x0()
    P = np.zeros((15, 15))
    last = np.concatenate([[t[0]], f[0], w[0]])
    k = pr.predict_to(x.p_w_m, x.v_w_mps, x.R_wb, x.ba_b, x.bg_b, P, 15, last, t, f, w, 1, 0.437, _prm(), pr.COV_ERROR_STATE, *rec, pr.NO_QREF.copy())
    assert abs(last[0] - 0.437) < 1e-15
    assert abs(x.p_w_m[0] - 0.5 * 0.437 ** 2) < 1e-12
    pr.predict_to(x.p_w_m, x.v_w_mps, x.R_wb, x.ba_b, x.bg_b, P, 15, last, t, f, w, k, 1.0, _prm(), pr.COV_ERROR_STATE, *rec, pr.NO_QREF.copy())
    assert abs(x.p_w_m[0] - 0.5) < 1e-12 and abs(x.v_w_mps[0] - 1.0) < 1e-12


def test_gap_noise_does_not_depend_on_where_an_observation_splits_the_gap():
    t = np.array([0.0, 0.1, 0.2, 1.9, 2.0])         # a 1.7 s gap between samples 2 and 3
    f = np.tile([0.0, 0.0, G], (t.size, 1))
    w = np.zeros((t.size, 3))
    prm = _prm()
    prm[kn.PRM_QA], prm[kn.PRM_GAP_DT], prm[kn.PRM_GAP_SCALE2] = 0.1, 0.15, 100.0
    N = t.size

    def run(stops):
        rec = [np.full((N, 3), np.nan), np.full((N, 3), np.nan), np.full((N, 3, 3), np.nan), np.full((N, 3), np.nan),
               np.full((N, 3), np.nan), np.full((N, 15), np.nan), np.full((N, 6, 6), np.nan)]
        x = _x0()
        P = np.zeros((15, 15))
        last = np.concatenate([[t[0]], f[0], w[0]])
        k = 1
        for s in stops:
            k = pr.predict_to(x.p_w_m, x.v_w_mps, x.R_wb, x.ba_b, x.bg_b, P, 15, last, t, f, w, k, s, prm, pr.COV_ERROR_STATE, *rec, pr.NO_QREF.copy())
        return P

    whole, split = run([2.0]), run([1.0, 2.0])
    # the velocity noise injected over the gap is the same (position terms depend on the step sizes)
    assert np.allclose(whole[3:6, 3:6], split[3:6, 3:6], rtol=1e-12)
    assert whole[3, 3] == pytest.approx(0.1 ** 2 * (0.3 + 100 * 1.7))   # the gap's interval got 10x the std
