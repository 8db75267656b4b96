"""The right-invariant EKF and the Gauss-Markov bias model: the error maps, the limits, consistency on simulated data."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import fusion_eval as fe
from fusion_eval.filters.formulations import invariant as inv


def _group_exp(xi_p, xi_v, xi_R, R, v, p):
    """X = Exp(xi) X_hat on SE_2(3)."""
    E, J = Rotation.from_rotvec(xi_R).as_matrix(), inv.left_jacobian(np.asarray(xi_R, float))
    return E @ R, E @ v + J @ xi_v, E @ p + J @ xi_p


def test_core_map_is_the_derivative_of_the_canonical_error():
    R = Rotation.random(random_state=1).as_matrix()
    v, p = np.array([12.0, -3.0, 0.4]), np.array([850.0, -420.0, 12.0])
    D = inv.core_map(R, v, p)
    h = 1e-6
    for k in range(9):
        xi = np.zeros(9)
        xi[k] = h
        R1, v1, p1 = _group_exp(xi[0:3], xi[3:6], xi[6:9], R, v, p)
        canon = np.concatenate([p1 - p, v1 - v, Rotation.from_matrix(R.T @ R1).as_rotvec()])
        np.testing.assert_allclose(canon / h, D[:9, k], atol=1e-4 * max(1.0, np.abs(D[:9, k]).max()))
    assert np.allclose(D[9:, 9:], np.eye(6))


@pytest.mark.slow
def test_gauss_markov_with_an_infinite_correlation_time_is_the_random_walk(kitti_slice):
    ds = fe.load_dataset(kitti_slice)
    for f in ("error_state", "invariant"):
        rw = fe.run(ds, overrides={"filter.formulation": f}).metrics
        gm = fe.run(ds, overrides={"filter.formulation": f, "filter.bias_model": "gauss_markov",
                                   "imu.accel_bias_corr_time_s": 1e15, "imu.gyro_bias_corr_time_s": 1e15}).metrics
        a, b = (m["estimates"]["fused"]["ape"]["translation_m"]["rmse"] for m in (rw, gm))
        assert a == pytest.approx(b, rel=1e-9, abs=1e-9), f
        short = fe.run(ds, overrides={"filter.formulation": f, "filter.bias_model": "gauss_markov",
                                      "imu.accel_bias_corr_time_s": 1.0, "imu.gyro_bias_corr_time_s": 1.0}).metrics
        assert short["estimates"]["fused"]["ape"]["translation_m"]["rmse"] != pytest.approx(a, rel=1e-6)


@pytest.mark.slow
def test_invariant_matches_the_eskf_on_kitti_with_gnss(kitti_slice):
    ds = fe.load_dataset(kitti_slice)
    a = fe.run(ds).metrics["estimates"]["fused"]["ape"]["translation_m"]["rmse"]
    b = fe.run(ds, overrides={"filter.formulation": "invariant"}).metrics["estimates"]["fused"]["ape"]["translation_m"]["rmse"]
    assert b == pytest.approx(a, rel=0.05)


@pytest.mark.slow
def test_every_imu_formulation_is_consistent_on_a_simulation_with_true_white_noise(white_sim):
    """Sensors whose errors are the white noises the filters assume (no lidar scale or yaw drift): position and
    attitude NEES inside the 95 % interval on at least 90 % of the epochs, for every formulation (the runs are shared
    with the smoother's tests: a smoother does not change the filter)."""
    for f in ("error_state", "nominal_state", "invariant"):
        m = white_sim(f, "none" if f == "nominal_state" else "rts").metrics
        for q in ("position", "attitude"):
            assert m["nees"][q]["fraction_in_95"] >= 0.9, (f, q, m["nees"][q])


def test_the_compiled_group_operations_against_the_group_exponential():
    """``inject_state`` and ``boxminus_vec`` (the filter's injection and the compiled RTS pass's [+] / [-], which the
    Python smoother now calls too) against ``Exp(xi) X`` written out here, the clone's SE(3) included: the smoother's
    compiled-against-Python test compares them with themselves (a diff review)."""
    from fusion_eval.filters.layout import CLONE, NOMINAL

    rng = np.random.default_rng(4)
    R0, Rc0 = (Rotation.random(random_state=s).as_matrix() for s in (2, 3))
    x0 = np.zeros(NOMINAL.n)
    x0[NOMINAL.sl("p")], x0[NOMINAL.sl("v")] = [850.0, -420.0, 12.0], [12.0, -3.0, 0.4]
    x0[NOMINAL.sl("R")], x0[NOMINAL.sl("ba")], x0[NOMINAL.sl("bg")] = R0.ravel(), [0.1, 0, -0.2], [1e-3, 0, 2e-3]
    c0 = np.zeros(CLONE.n)
    c0[CLONE.sl("p")], c0[CLONE.sl("R")] = [840.0, -415.0, 11.5], Rc0.ravel()
    n = inv.LAYOUT.n
    dx = rng.normal(scale=0.05, size=n)
    x, c = x0.copy(), c0.copy()
    inv.inject_state(x, c, dx, n)
    R1, v1, p1 = _group_exp(dx[inv.IP:inv.IP + 3], dx[inv.IV:inv.IV + 3], dx[inv.ITH:inv.ITH + 3], R0,
                            x0[NOMINAL.sl("v")], x0[NOMINAL.sl("p")])
    np.testing.assert_allclose(x[NOMINAL.sl("R")].reshape(3, 3), R1, atol=1e-12)
    np.testing.assert_allclose(x[NOMINAL.sl("v")], v1, atol=1e-9)
    np.testing.assert_allclose(x[NOMINAL.sl("p")], p1, atol=1e-9)
    np.testing.assert_allclose(x[NOMINAL.sl("bg")] - x0[NOMINAL.sl("bg")], dx[inv.IBG:inv.IBG + 3], atol=1e-15)
    E = Rotation.from_rotvec(dx[inv.ICTH:inv.ICTH + 3]).as_matrix()
    np.testing.assert_allclose(c[CLONE.sl("R")].reshape(3, 3), E @ Rc0, atol=1e-12)
    np.testing.assert_allclose(c[CLONE.sl("p")], E @ c0[CLONE.sl("p")]
                               + inv.left_jacobian(dx[inv.ICTH:inv.ICTH + 3]) @ dx[inv.ICP:inv.ICP + 3], atol=1e-9)
    np.testing.assert_allclose(inv.boxminus_vec(x, c, x0, c0, n), dx, atol=1e-9)       # [-] undoes [+]
