"""Error-state Kalman filter for IMU-driven fusion (15 states plus an optional pose clone).

Nominal state: ``p_w`` (m), ``v_w`` (m/s), ``R_wb``, accelerometer bias ``ba_b`` (m/s^2), gyro bias
``bg_b`` (rad/s). Error state ``[dp, dv, dtheta, dba, dbg]``, KF-GINS-style named blocks (:data:`LAYOUT`,
the canonical layout itself), optionally followed by a cloned pose ``[dp_c, dtheta_c]`` that the
prediction leaves unchanged. After each update the error is injected into the nominal state and reset
to zero; the reset Jacobian ``G = I - [dtheta/2]x`` on the attitude blocks (Sola, eq. 287) is applied to P.

Continuous error dynamics (the classic IMU + lidar ESKF derivation)::

    dp'  = dv
    dv'  = -R [f - ba]x dtheta - R dba + R n_a
    dth' = -[w - bg]x dtheta   - dbg  + n_g
    dba' = -dba / tau_a + n_ba,   dbg' = -dbg / tau_g + n_bg
                                        (Gauss-Markov; 1/tau = 0 for the random walk, n = 0 for the constant bias)

discretised by ``filter.discretization`` (:mod:`fusion_eval.filters.discretize`; Van Loan's on this structure in
:mod:`.eskf_van_loan`). The first-order form is
``F = I + F_t T`` and ``Q_d = B Q B^T`` with B as in that derivation: ``R T`` and ``I T`` on the white
noises, ``I sqrt(T)`` on the bias random walks, Q the discrete variances. With noise densities ``sigma``
(per sqrt(Hz)) both give ``sigma^2 T`` per axis, and since ``R R^T = I`` the discrete process noise is
diagonal; :func:`propagate_cov` uses that and the sparsity of F to do ``F P F^T + Q`` in O(n) 3x3 products
instead of a dense O(n^3) product. The second-order and Van Loan forms take ``F_t`` and ``Q_c`` from
:func:`continuous_model`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import discretize, linalg
from ..layout import CANONICAL, CLONE
from ..mech import XBA, XBG, XP, XV, attitude, log3, mech_step, mul_tn, rmul_exp3, skew3
from ..propagate import compiled_loop, new_arrays, record_cov_by_index
from ..state import NominalState, unpack
from ...spec import S
from . import imu_model
from .base import ErrorStateBase
from .eskf_van_loan import van_loan_eskf
from .imu_model import PRM_G, PRM_DISC, PRM_KBA, PRM_KBG, PRM_QA, PRM_QBA, PRM_QBG, PRM_QG, UF, UW, decay_biases

LAYOUT = CANONICAL
P_ID, V_ID, TH_ID, BA_ID, BG_ID = (LAYOUT.start(b) for b in ("P", "V", "TH", "BA", "BG"))
CP_ID, CTH_ID = LAYOUT.start("CP"), LAYOUT.start("CTH")
N_CORE = LAYOUT.n_core
AUX_OWN = 1             # not a state index: the size of its own scratch (unused); an RTS record's transition room follows it
CLONE_P, CLONE_R = CLONE.start("p"), CLONE.start("R")


@njit(cache=True)
def propagate_cov(P, n, R, f_b, w_b, dt, prm, qscale):
    """In place ``P <- F P F^T + Q`` for the error state, exploiting the sparsity of F.

    ``R``, ``f_b`` and ``w_b`` are the attitude and the bias-corrected IMU values the step was
    linearised at; ``n`` is the number of states (15 + 6 with a clone); ``qscale`` multiplies the
    white-noise variances (gaps).
    """
    _propagate_cov(P, n, R, f_b[0], f_b[1], f_b[2], w_b[0], w_b[1], w_b[2], dt, prm, qscale)


@njit(cache=True)
def _propagate_cov(P, n, R, f0, f1, f2, w0, w1, w2, dt, prm, qscale):
    """:func:`propagate_cov` on scalars, with no array allocated: it runs once per IMU sample, where an allocation
    costs as much as a tenth of the arithmetic."""
    # F's blocks: A = -R [f]x dt (dv/dtheta), B = -R dt (dv/dba), C = -[w]x dt (dtheta/dtheta minus I), as
    # scalars a<row><col>, b<row><col> (numpy's 3x3 products are BLAS calls, dearer than the sums)
    a00, a01, a02 = -(R[0, 1] * f2 - R[0, 2] * f1) * dt, -(R[0, 2] * f0 - R[0, 0] * f2) * dt, -(R[0, 0] * f1 - R[0, 1] * f0) * dt
    a10, a11, a12 = -(R[1, 1] * f2 - R[1, 2] * f1) * dt, -(R[1, 2] * f0 - R[1, 0] * f2) * dt, -(R[1, 0] * f1 - R[1, 1] * f0) * dt
    a20, a21, a22 = -(R[2, 1] * f2 - R[2, 2] * f1) * dt, -(R[2, 2] * f0 - R[2, 0] * f2) * dt, -(R[2, 0] * f1 - R[2, 1] * f0) * dt
    b00, b01, b02 = -R[0, 0] * dt, -R[0, 1] * dt, -R[0, 2] * dt
    b10, b11, b12 = -R[1, 0] * dt, -R[1, 1] * dt, -R[1, 2] * dt
    b20, b21, b22 = -R[2, 0] * dt, -R[2, 1] * dt, -R[2, 2] * dt
    c0, c1, c2 = w0 * dt, w1 * dt, w2 * dt
    # rows, in place: P <- F P. Row blocks P, V, TH each read only the old rows after them (V, then TH and
    # BA, then TH and BG), so they are updated in that order; TH's three rows read one another: per column,
    # the three new values are formed before any is written.
    for j in range(n):
        th0, th1, th2 = P[TH_ID, j], P[TH_ID + 1, j], P[TH_ID + 2, j]
        ba0, ba1, ba2 = P[BA_ID, j], P[BA_ID + 1, j], P[BA_ID + 2, j]
        for i in range(3):
            P[P_ID + i, j] += dt * P[V_ID + i, j]
        s = P[V_ID, j]
        s += a00 * th0 + b00 * ba0
        s += a01 * th1 + b01 * ba1
        s += a02 * th2 + b02 * ba2
        P[V_ID, j] = s
        s = P[V_ID + 1, j]
        s += a10 * th0 + b10 * ba0
        s += a11 * th1 + b11 * ba1
        s += a12 * th2 + b12 * ba2
        P[V_ID + 1, j] = s
        s = P[V_ID + 2, j]
        s += a20 * th0 + b20 * ba0
        s += a21 * th1 + b21 * ba1
        s += a22 * th2 + b22 * ba2
        P[V_ID + 2, j] = s
        P[TH_ID, j] = th0 - dt * P[BG_ID, j] + c2 * th1 + (-c1) * th2
        P[TH_ID + 1, j] = th1 - dt * P[BG_ID + 1, j] + (-c2) * th0 + c0 * th2
        P[TH_ID + 2, j] = th2 - dt * P[BG_ID + 2, j] + c1 * th0 + (-c0) * th1
    # columns, in place: P <- (F P) F^T, the same order on the column blocks
    for i in range(n):
        th0, th1, th2 = P[i, TH_ID], P[i, TH_ID + 1], P[i, TH_ID + 2]
        ba0, ba1, ba2 = P[i, BA_ID], P[i, BA_ID + 1], P[i, BA_ID + 2]
        for j in range(3):
            P[i, P_ID + j] += dt * P[i, V_ID + j]
        s = P[i, V_ID]
        s += th0 * a00 + ba0 * b00
        s += th1 * a01 + ba1 * b01
        s += th2 * a02 + ba2 * b02
        P[i, V_ID] = s
        s = P[i, V_ID + 1]
        s += th0 * a10 + ba0 * b10
        s += th1 * a11 + ba1 * b11
        s += th2 * a12 + ba2 * b12
        P[i, V_ID + 1] = s
        s = P[i, V_ID + 2]
        s += th0 * a20 + ba0 * b20
        s += th1 * a21 + ba1 * b21
        s += th2 * a22 + ba2 * b22
        P[i, V_ID + 2] = s
        P[i, TH_ID] = th0 - dt * P[i, BG_ID] + th1 * c2 + th2 * (-c1)
        P[i, TH_ID + 1] = th1 - dt * P[i, BG_ID + 1] + th0 * (-c2) + th2 * c0
        P[i, TH_ID + 2] = th2 - dt * P[i, BG_ID + 2] + th0 * c1 + th1 * (-c0)
    # Gauss-Markov biases: F has exp(-dt/tau) on the bias diagonal (identity for a random walk), exact for the
    # decoupled bias block: its first-order 1 - dt/tau went below -1 for a correlation time under half the interval
    # and the filter diverged (tau = 1 ms at 10 Hz, a simulate review)
    fa, fg = np.exp(-prm[PRM_KBA] * dt), np.exp(-prm[PRM_KBG] * dt)
    if fa != 1.0 or fg != 1.0:
        for i in range(3):
            for j in range(n):
                P[BA_ID + i, j] *= fa
                P[BG_ID + i, j] *= fg
            for j in range(n):
                P[j, BA_ID + i] *= fa
                P[j, BG_ID + i] *= fg
    qa = prm[PRM_QA] * prm[PRM_QA] * dt * qscale
    qg = prm[PRM_QG] * prm[PRM_QG] * dt * qscale
    qba = prm[PRM_QBA] * prm[PRM_QBA] * discretize.gm_interval(prm[PRM_KBA], dt)
    qbg = prm[PRM_QBG] * prm[PRM_QBG] * discretize.gm_interval(prm[PRM_KBG], dt)
    for i in range(3):
        P[V_ID + i, V_ID + i] += qa
        P[TH_ID + i, TH_ID + i] += qg
        P[BA_ID + i, BA_ID + i] += qba
        P[BG_ID + i, BG_ID + i] += qbg
    linalg.symmetrize_into(P, n, P)


@njit(cache=True)
def continuous_model(R, f_b, w_b, prm, qscale):
    """The continuous error dynamics ``F_t`` (15x15) and white-noise spectral density ``Q_c`` (diagonal, 15)."""
    Ft = np.zeros((N_CORE, N_CORE))
    A = -(R @ skew3(f_b))
    C = -skew3(w_b)
    for i in range(3):
        Ft[P_ID + i, V_ID + i] = 1.0
        Ft[TH_ID + i, BG_ID + i] = -1.0
        for k in range(3):
            Ft[V_ID + i, TH_ID + k] = A[i, k]
            Ft[V_ID + i, BA_ID + k] = -R[i, k]
            Ft[TH_ID + i, TH_ID + k] = C[i, k]
        Ft[BA_ID + i, BA_ID + i] = -prm[PRM_KBA]
        Ft[BG_ID + i, BG_ID + i] = -prm[PRM_KBG]
    Qc = np.zeros(N_CORE)
    for i in range(3):
        Qc[V_ID + i] = prm[PRM_QA] * prm[PRM_QA] * qscale
        Qc[TH_ID + i] = prm[PRM_QG] * prm[PRM_QG] * qscale
        Qc[BA_ID + i] = prm[PRM_QBA] * prm[PRM_QBA]
        Qc[BG_ID + i] = prm[PRM_QBG] * prm[PRM_QBG]
    return Ft, Qc


@njit(cache=True)
def discrete_model(R, f_b, w_b, dt, prm, qscale, method):
    """``(Phi, Q_d)`` of the error dynamics over one IMU interval by the discretisation ``method``
    (:mod:`fusion_eval.filters.discretize`), linearised at ``R`` and the bias-corrected ``f_b``, ``w_b``; the
    nominal-state filter maps this ``Q_d`` into its own coordinates."""
    Phi = np.empty((N_CORE, N_CORE))
    Qd = np.empty((N_CORE, N_CORE))
    # Van Loan on the dynamics' structure (a quarter of the series' cost); the series where it declines
    if not (method == discretize.VAN_LOAN and van_loan_eskf(R, f_b, w_b, dt, prm, qscale, Phi, Qd)):
        Ft, Qc = continuous_model(R, f_b, w_b, prm, qscale)
        Phi, Qd = discretize.transition(Ft, Qc, dt, method)
    return Phi, Qd


@njit(cache=True)
def step(x, P, n, u0, u1, dt, qscale, prm, aux, cov):
    """One IMU interval: covariance linearised at the start-of-interval attitude and the midpoint,
    bias-corrected IMU values, then the midpoint mechanization."""
    if cov:
        method = int(prm[PRM_DISC])
        if method == discretize.FIRST_ORDER:                            # sparse, same result; no array allocated
            _propagate_cov(P, n, attitude(x), 0.5 * (u0[UF] + u1[UF]) - x[XBA], 0.5 * (u0[UF + 1] + u1[UF + 1]) - x[XBA + 1],
                           0.5 * (u0[UF + 2] + u1[UF + 2]) - x[XBA + 2], 0.5 * (u0[UW] + u1[UW]) - x[XBG],
                           0.5 * (u0[UW + 1] + u1[UW + 1]) - x[XBG + 1], 0.5 * (u0[UW + 2] + u1[UW + 2]) - x[XBG + 2],
                           dt, prm, qscale)
        else:
            fm = np.empty(3)
            wm = np.empty(3)
            for i in range(3):
                fm[i] = 0.5 * (u0[UF + i] + u1[UF + i]) - x[XBA + i]
                wm[i] = 0.5 * (u0[UW + i] + u1[UW + i]) - x[XBG + i]
            Phi, Qd = discrete_model(attitude(x), fm, wm, dt, prm, qscale, method)
            discretize.propagate(P, n, Phi, Qd)
            if aux.shape[0] == AUX_OWN + N_CORE * N_CORE:     # the RTS smoother's room: it keeps the one into each epoch
                q = AUX_OWN
                for i in range(N_CORE):
                    for j in range(N_CORE):
                        aux[q] = Phi[i, j]
                        q += 1
    mech_step(x, u0[UF:UF + 3], u0[UW:UW + 3], u1[UF:UF + 3], u1[UW:UW + 3], dt, prm[PRM_G])
    decay_biases(x, dt, prm)


predict_to = compiled_loop(__name__, step, record_cov_by_index)

BIAS_KEYS = {
    "imu.accel_bias_corr_time_s": S(3600.0, "Gauss-Markov bias model: accelerometer bias correlation time, s", positive=True,
                                    reads="filter", only_with=("filter.bias_model", "gauss_markov")),
    "imu.gyro_bias_corr_time_s": S(3600.0, "Gauss-Markov bias model: gyro bias correlation time, s", positive=True,
                                   reads="filter", only_with=("filter.bias_model", "gauss_markov")),
}


@njit(cache=True)
def inject_state(x, xc, dx, n):
    """Inject the error ``dx`` into the nominal state (and the clone, when ``n`` covers it), in place."""
    for i in range(3):
        x[XP + i] += dx[P_ID + i]
        x[XV + i] += dx[V_ID + i]
        x[XBA + i] += dx[BA_ID + i]
        x[XBG + i] += dx[BG_ID + i]
    rmul_exp3(attitude(x), dx[TH_ID:TH_ID + 3])
    if n > N_CORE:
        for i in range(3):
            xc[CLONE_P + i] += dx[CP_ID + i]
        rmul_exp3(xc[CLONE_R:CLONE_R + 9].reshape((3, 3)), dx[CTH_ID:CTH_ID + 3])


@njit(cache=True)
def inject_reset(x, xc, P, n, dx):
    """Inject the error ``dx`` into the nominal state (and clone), then reset: ``P <- G P G^T``
    with ``G = I - [dtheta/2]x`` on each attitude block (Sola, eq. 287), identity elsewhere, so the product is
    done as row and column operations on those blocks (:func:`linalg.reset_attitude_block`)."""
    inject_state(x, xc, dx, n)
    linalg.reset_attitude_block(P, n, TH_ID, dx[TH_ID:TH_ID + 3])
    if n > N_CORE:
        linalg.reset_attitude_block(P, n, CTH_ID, dx[CTH_ID:CTH_ID + 3])


@njit(cache=True)
def inject_reset_dense(x, xc, P, n, dx):
    """:func:`inject_reset` with the dense ``G P G^T`` (the tests' oracle)."""
    inject_state(x, xc, dx, n)
    G = np.eye(n)
    G[TH_ID:TH_ID + 3, TH_ID:TH_ID + 3] -= 0.5 * skew3(dx[TH_ID:TH_ID + 3])
    if n > N_CORE:
        G[CTH_ID:CTH_ID + 3, CTH_ID:CTH_ID + 3] -= 0.5 * skew3(dx[CTH_ID:CTH_ID + 3])
    Pn = np.ascontiguousarray(P[:n, :n])
    newP = G @ Pn @ G.T
    P[:n, :n] = newP


@njit(cache=True)
def boxminus_vec(x, xc, x0, xc0, n):
    """``(x, clone) [-] (x0, clone0)`` over the first ``n`` error states (right perturbations on attitudes)."""
    d = np.zeros(n)
    R, R0 = attitude(x), attitude(x0)
    dth = log3(mul_tn(R0, R))
    for i in range(3):
        d[P_ID + i] = x[XP + i] - x0[XP + i]
        d[V_ID + i] = x[XV + i] - x0[XV + i]
        d[TH_ID + i] = dth[i]
        d[BA_ID + i] = x[XBA + i] - x0[XBA + i]
        d[BG_ID + i] = x[XBG + i] - x0[XBG + i]
    if n > N_CORE:
        Rc = xc[CLONE_R:CLONE_R + 9].reshape((3, 3))
        Rc0 = xc0[CLONE_R:CLONE_R + 9].reshape((3, 3))
        dthc = log3(mul_tn(Rc0, Rc))
        for i in range(3):
            d[CP_ID + i] = xc[CLONE_P + i] - xc0[CLONE_P + i]
            d[CTH_ID + i] = dthc[i]
    return d


@njit(cache=True)
def boxplus_into(x, xc, x0, xc0, dx, n):
    """``(x, clone) <- (x0, clone0) [+] dx`` (:func:`inject_state` from a given state, no reset of P)."""
    x[:] = x0
    xc[:] = xc0
    inject_state(x, xc, dx, n)


class ErrorStateKF(ErrorStateBase):
    """The ESKF. Holds the nominal state, the error covariance ``P`` and at most one cloned pose.

    Prediction runs in the compiled loop (:meth:`predict_to`); updates take an observation model
    (:mod:`fusion_eval.filters.observations`) returning the textbook ``H, r, R``. Its error state is the
    canonical one, so ``D = I`` and the plain EKF update runs in compiled kernels.
    """

    name = "error_state"
    process_model = "imu"
    label = "error-state (ESKF: 15-state error, injection and reset)"
    layout = LAYOUT
    pairs = tuple((b, b) for b in LAYOUT.blocks)
    targets = {"P": "p", "V": "v", "TH": "R", "BA": "ba", "BG": "bg", "CP": "clone.p", "CTH": "clone.R"}
    _step = staticmethod(step)
    _predict = staticmethod(predict_to)
    _record_cov = staticmethod(record_cov_by_index)
    keys = {**discretize.KEYS, **BIAS_KEYS}
    bias_models = ("random_walk", "constant", "gauss_markov")

    @classmethod
    def run_params(cls, s, gravity_mps2: float) -> np.ndarray:
        return imu_model.run_params(s, gravity_mps2)

    compiled_update = True
    _inject_kernel = staticmethod(inject_reset)     # the compiled replay's injection (D = I)
    _rts_boxminus = staticmethod(boxminus_vec)      # the compiled RTS interval (fusion_eval.smoothing.compiled)
    _rts_boxplus = staticmethod(boxplus_into)

    def keeps_transition(self) -> bool:
        return int(self.arrays.prm[PRM_DISC]) != discretize.FIRST_ORDER     # Van Loan's or the second-order series

    def own_jacobian(self, Hc: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(Hc[:, :self.n])          # D = I: the canonical error is this state

    def inject(self, dx: np.ndarray) -> None:
        inject_reset(self.xv, self.clone.vec, self.P, self.n, dx)

    # the generic right-perturbation operations, compiled (the iterated update and the smoother call them often)
    def boxminus(self, snap) -> np.ndarray:
        c0 = self.clone.vec if snap[1] is None else snap[1]
        return boxminus_vec(self.xv, self.clone.vec, snap[0], c0, self.n)

    def boxplus_from(self, snap, dx: np.ndarray) -> None:
        c0 = self.clone.vec.copy() if snap[1] is None else snap[1]
        boxplus_into(self.xv, self.clone.vec, snap[0], c0, np.ascontiguousarray(dx, float), self.n)


def dead_reckon(x0: NominalState, prm: np.ndarray, t: np.ndarray, u: np.ndarray, k0: int) -> np.ndarray:
    """Pure IMU integration from ``x0`` at sample ``k0`` through every later sample: the recorded nominal
    vectors ``(N, NOMINAL.n)`` (NaN before ``k0``)."""
    x = x0.vec.copy()
    a = new_arrays(x, np.zeros((N_CORE, N_CORE)), np.ascontiguousarray(t, float), np.ascontiguousarray(u, float), k0,
                   np.ascontiguousarray(prm, float), np.array([np.inf, 1.0]), np.zeros(1), np.zeros(N_CORE, np.int64),
                   record=False)
    a.rec_x[k0] = x
    predict_to(a, N_CORE, k0 + 1, float(t[-1]), False)
    return a.rec_x


def dead_reckon_poses(x0: NominalState, prm: np.ndarray, t: np.ndarray, u: np.ndarray, k0: int,
                      chunk: int = 65_536) -> tuple[np.ndarray, np.ndarray]:
    """:func:`dead_reckon`'s positions ``(N - k0, 3)`` and rotation matrices ``(N - k0, 3, 3)`` from sample ``k0``
    on, the same numbers (tested): integrated ``chunk`` samples at a time into one reused record, so that a long
    drive's dead reckoning does not hold its whole nominal state (22 numbers per sample: 121 MiB of fresh pages on a
    simulated hour at 200 Hz, for the 12 it keeps)."""
    t = np.ascontiguousarray(t, float)
    u = np.ascontiguousarray(u, float)
    prm = np.ascontiguousarray(prm, float)
    N = t.size
    x = x0.vec.copy()
    p_out = np.empty((N - k0, 3))
    R_out = np.empty((N - k0, 3, 3))
    first = positions_attitudes(x[None, :])
    p_out[0], R_out[0] = first[0][0], first[1][0]
    rec = np.empty((min(chunk, N - k0) + 1, x.size))
    one = slice(0, 1)                # a sample's stamp and input row: replaced below  # not a state index
    a = new_arrays(x, np.zeros((N_CORE, N_CORE)), t[one], u[one], 0, prm, np.array([np.inf, 1.0]), np.zeros(1),
                   np.zeros(N_CORE, np.int64), record=False)
    c0 = k0                                        # the sample the state sits at
    while c0 < N - 1:
        c1 = min(c0 + chunk, N - 1)                # through sample c1, each step as the whole-drive loop takes it
        a = a._replace(t=t[c0:c1 + 1], u=u[c0:c1 + 1], last=np.concatenate([[t[c0]], u[c0]]),
                       rec_x=rec[:c1 - c0 + 1])
        predict_to(a, N_CORE, 1, float(t[c1]), False)
        p, R = positions_attitudes(rec[1:c1 - c0 + 1])
        p_out[c0 + 1 - k0:c1 + 1 - k0], R_out[c0 + 1 - k0:c1 + 1 - k0] = p, R
        c0 = c1
    return p_out, R_out


def positions_attitudes(rec_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(N, 3)`` and attitudes ``(N, 3, 3)`` of recorded nominal vectors."""
    u = unpack(rec_x)
    return u["p"], u["R"]
