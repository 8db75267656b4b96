"""Midpoint strapdown mechanization against analytic motion."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_eval.filters.formulations import eskf
from fusion_eval.filters.formulations.eskf import dead_reckon, positions_attitudes
from fusion_eval.filters.formulations.imu_model import imu_inputs, imu_params
from fusion_eval.filters.propagate import new_arrays
from fusion_eval.filters.state import NominalState
from fusion_eval.so3 import exp_so3

G = 9.81


def _prm(qa=0.0):
    return imu_params(G, qa, 0.0, 0.0, 0.0)


def _dr(x0, t, f, w):
    """Dead reckoning: positions and attitudes at every sample."""
    return positions_attitudes(dead_reckon(x0, _prm(), t, imu_inputs(f, w), 0))


def _x0(p=(0, 0, 0), v=(0, 0, 0), R=np.eye(3)):
    return NominalState(np.array(p, float), np.array(v, float), np.array(R, float), np.zeros(3), np.zeros(3))


def test_stationary_with_gravity_stays_put():
    rng = np.random.default_rng(1)
    R0 = exp_so3(rng.normal(size=3) * 0.3)       # tilted, arbitrary heading
    t = np.arange(0, 100, 0.01)
    f = np.tile(R0.T @ [0, 0, G], (t.size, 1))   # specific force = -gravity in the body frame
    w = np.zeros((t.size, 3))
    p, R = _dr(_x0(R=R0), t, f, w)
    assert np.abs(p).max() < 1e-9
    assert np.abs(R - R0).max() < 1e-12


def test_constant_acceleration_is_exact():
    R0 = exp_so3(np.array([0.1, -0.2, 0.7]))
    a_w = np.array([0.5, -0.2, 0.1])
    v0 = np.array([3.0, 1.0, 0.0])
    t = np.arange(0, 60, 0.01)
    f = np.tile(R0.T @ (a_w + [0, 0, G]), (t.size, 1))
    p, _ = _dr(_x0(v=v0, R=R0), t, f, np.zeros((t.size, 3)))
    tt = (t - t[0])[:, None]
    p_true = v0 * tt + 0.5 * a_w * tt ** 2
    assert np.abs(p - p_true).max() < 1e-7


def test_constant_turn_rate_attitude_exact_and_circle_followed():
    # level car on a circle: speed V, yaw rate om; body specific force = centripetal + gravity
    V, om = 10.0, 0.2
    t = np.arange(0, 30, 0.01)
    f = np.tile([0.0, V * om, G], (t.size, 1))
    w = np.tile([0.0, 0.0, om], (t.size, 1))
    p, R = _dr(_x0(v=(V, 0, 0)), t, f, w)
    yaw = om * (t - t[0])
    assert np.abs(R[:, 0, 0] - np.cos(yaw)).max() < 1e-12
    assert np.abs(R[:, 1, 0] - np.sin(yaw)).max() < 1e-12
    p_true = np.column_stack([V / om * np.sin(yaw), V / om * (1 - np.cos(yaw)), np.zeros_like(yaw)])
    # second-order scheme: 900 steps of 1 cm/s^2-scale truncation over 150 m of arc
    assert np.abs(p - p_true).max() < 0.05
    # and the error shrinks as dt^2 (halving dt quarters it)
    t2 = np.arange(0, 30, 0.005)
    p2, _ = _dr(_x0(v=(V, 0, 0)), t2, np.tile(f[0], (t2.size, 1)), np.tile(w[0], (t2.size, 1)))
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
    x = _x0()
    a = new_arrays(x.vec, np.zeros((15, 15)), t, imu_inputs(f, w), 0, _prm(), np.array([np.inf, 1.0]), np.zeros(1),
                   np.arange(15))
    k = eskf.predict_to(a, 15, 1, 0.437, True)
    assert abs(a.last[0] - 0.437) < 1e-15
    assert abs(x.p_w_m[0] - 0.5 * 0.437 ** 2) < 1e-12
    eskf.predict_to(a, 15, k, 1.0, True)
    assert abs(x.p_w_m[0] - 0.5) < 1e-12 and abs(x.v_w_mps[0] - 1.0) < 1e-12


def test_gap_noise_does_not_depend_on_where_an_observation_splits_the_gap():
    t = np.array([0.0, 0.1, 0.2, 1.9, 2.0])         # a 1.7 s gap between samples 2 and 3
    f = np.tile([0.0, 0.0, G], (t.size, 1))
    w = np.zeros((t.size, 3))
    prm = _prm(qa=0.1)

    def run(stops):
        x = _x0()
        a = new_arrays(x.vec, np.zeros((15, 15)), t, imu_inputs(f, w), 0, prm, np.array([0.15, 100.0]), np.zeros(1),
                       np.arange(15))
        k = 1
        for s in stops:
            k = eskf.predict_to(a, 15, k, s, True)
        return a.P

    whole, split = run([2.0]), run([1.0, 2.0])
    # the velocity noise injected over the gap is the same (position terms depend on the step sizes)
    assert np.allclose(whole[3:6, 3:6], split[3:6, 3:6], rtol=1e-12)
    assert whole[3, 3] == pytest.approx(0.1 ** 2 * (0.3 + 100 * 1.7))   # the gap's interval got 10x the std


@pytest.mark.parametrize("chunk", [1, 97, 65_536])
def test_dead_reckoning_in_chunks_equals_the_whole_drive_loop(chunk):
    """The run's dead reckoning integrates a chunk at a time into one reused record (a long drive's nominal states
    need not be held): the same numbers, bit for bit, as the loop over the whole drive, from any start sample."""
    from fusion_eval.filters.formulations.eskf import dead_reckon_poses

    rng = np.random.default_rng(5)
    n, k0 = 1500, 37
    t = 10.0 + np.cumsum(rng.uniform(0.004, 0.006, n))
    t[700:] += 0.5                                             # a gap
    f = np.column_stack([rng.normal(0, 0.3, n), rng.normal(0, 0.3, n), 9.81 + rng.normal(0, 0.1, n)])
    w = rng.normal(0, 0.05, (n, 3))
    x0 = _x0(p=(1.0, 2.0, 0.5), v=(5.0, 0.5, 0.0), R=exp_so3(np.array([0.01, -0.02, 0.7])))
    p_ref, R_ref = positions_attitudes(dead_reckon(x0, _prm(), t, imu_inputs(f, w), k0))
    p, R = dead_reckon_poses(x0, _prm(), t, imu_inputs(f, w), k0, chunk=chunk)
    assert np.array_equal(p, p_ref[k0:]) and np.array_equal(R, R_ref[k0:])


def test_a_gaps_white_noise_is_scaled_by_the_square_of_its_std_scale():
    """imu.gap_noise_scale is a std factor: the gap's variances take its square (its first power survived a mutation
    review; every KITTI drive has gaps)."""
    from types import SimpleNamespace

    from fusion_eval.filters.formulations.base import gap_of

    imu = SimpleNamespace(gap_factor=5.0, gap_noise_scale=10.0, gap_turn_rate_rps=0.3, gap_accel_mps2=2.0)
    dt, var_scale, turn_var, acc_var = gap_of(SimpleNamespace(imu=imu), np.arange(0.0, 1.0, 0.1))
    assert dt == pytest.approx(0.5) and var_scale == 100.0
    assert turn_var == pytest.approx(0.09) and acc_var == 4.0
