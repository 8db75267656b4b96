"""Nominal-state EKF: the full state ``x = [p, v, q, ba, bg]`` (16, quaternion (w, x, y, z)) is itself
propagated and updated; a cloned pose adds ``[p_c, q_c]`` (7). After each update the quaternions are
normalised and ``P`` is mapped through the normalisation's Jacobian ``(I - q q^T)`` (for a unit q).

Quaternions here are Hamilton, ``(w, x, y, z)``, body to world, as in Sola's "Quaternion kinematics for
the error-state Kalman filter"; the rest of the package sees only rotation matrices and scipy's
``(x, y, z, w)``. The state itself is propagated by the same midpoint mechanization as the ESKF; the
covariance by the Jacobian of that step with respect to the full state (``docs/nominal_state.md``), with
the ESKF's discrete process noise by ``filter.discretization`` mapped into the quaternion (:func:`nominal_F_Q`)::

    dp'/dq = T^2/2 d(R(q) a)/dq,   dv'/dq = T d(R(q) a)/dq,   d(R(q)a)/dq = 2 [w a + v x a | v.a I + v a^T - a v^T - w [a]x]
    dp'/dba = -T^2/2 R,  dv'/dba = -T R,  dq'/dq = [q{wT}]_R,  dq'/dbg = -T/2 [q]_L [0; I]

Observation models are written for the canonical error state; with the pair ``(TH, Q)`` their Jacobian
with respect to this state is ``H = H_canonical D``, ``dtheta/dq = 2 Xi(q)^T`` on each quaternion
(``q (x) [1, dtheta/2] = q + Xi(q) dtheta / 2``). So the attitude innovation is the rotation vector of
``R_pred^T R_obs``, as for the ESKF, rather than a difference of quaternions (which has a sign ambiguity
and a rank-deficient covariance).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..layout import CANONICAL, Layout
from ..linalg import symmetrize_into
from ..mech import XBA, XBG, attitude, mech_step, skew3
from ..propagate import compiled_loop, record_pose_cov
from .base import FilterBase
from . import imu_model
from .eskf import discrete_model
from .imu_model import PRM_DISC, PRM_G, UF, UW

LAYOUT = Layout("nominal-state EKF", [("P", 3), ("V", 3), ("Q", 4), ("BA", 3), ("BG", 3)],
                clone=[("CP", 3), ("CQ", 4)], clone_of={"CP": "P", "CQ": "Q"})
NP_ID, NV_ID, NQ_ID, NBA_ID, NBG_ID = (LAYOUT.start(b) for b in ("P", "V", "Q", "BA", "BG"))
NC_Q_ID = LAYOUT.start("CQ")
N_NOM = LAYOUT.n_core
PAIRS = (("P", "P"), ("V", "V"), ("TH", "Q"), ("BA", "BA"), ("BG", "BG"), ("CP", "CP"), ("CTH", "CQ"))

# scratch: the sign references of the state's and the clone's quaternions (see aligned_quat)
AUX = Layout("nominal-state scratch", [("q", 4), ("qc", 4)])
QUAT = Layout("quaternion (w, x, y, z)", [("w", 1), ("v", 3)])
QV0, QV1 = QUAT.start("v"), QUAT["v"].stop
AQ, AQC = AUX.sl("q"), AUX.sl("qc")
AQ0 = AUX.start("q")

TH0 = CANONICAL.start("TH")
CP0, CV0, CBA0, CBG0 = (CANONICAL.start(b) for b in ("P", "V", "BA", "BG"))
N_CANON = CANONICAL.n_core


@njit(cache=True)
def rot_to_quat(R):
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    q = np.empty(4)
    if tr > 0.0:
        s = np.sqrt(tr + 1.0) * 2.0
        q[0] = 0.25 * s
        q[1] = (R[2, 1] - R[1, 2]) / s
        q[2] = (R[0, 2] - R[2, 0]) / s
        q[3] = (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2.0
        q[0] = (R[2, 1] - R[1, 2]) / s
        q[1] = 0.25 * s
        q[2] = (R[0, 1] + R[1, 0]) / s
        q[3] = (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2.0
        q[0] = (R[0, 2] - R[2, 0]) / s
        q[1] = (R[0, 1] + R[1, 0]) / s
        q[2] = 0.25 * s
        q[3] = (R[1, 2] + R[2, 1]) / s
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2.0
        q[0] = (R[1, 0] - R[0, 1]) / s
        q[1] = (R[0, 2] + R[2, 0]) / s
        q[2] = (R[1, 2] + R[2, 1]) / s
        q[3] = 0.25 * s
    if q[0] < 0.0:
        q = -q
    return q / np.sqrt(q @ q)


@njit(cache=True)
def quat_to_rot(q):
    w, x, y, z = q[0], q[1], q[2], q[3]
    R = np.empty((3, 3))
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)
    return R


@njit(cache=True)
def quat_L(q):
    """[q]_L with q (x) p = [q]_L p."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


@njit(cache=True)
def quat_R(q):
    """[q]_R with p (x) q = [q]_R p."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])


@njit(cache=True)
def xi(q):
    """Xi(q) = [q]_L[:, v]: the right perturbation q (x) [1, dtheta/2] adds Xi(q) dtheta / 2."""
    return quat_L(q)[:, QV0:QV1].copy()


@njit(cache=True)
def dRa_dq(q, a):
    """d(R(q) a)/dq, 3x4 (Sola, eq. 174)."""
    w = q[0]
    v = q[QV0:QV1]
    out = np.empty((3, 4))
    out[:, 0] = w * a + np.cross(v, a)
    out[:, QV0:QV1] = (v @ a) * np.eye(3) + np.outer(v, a) - np.outer(a, v) - w * skew3(a)
    return 2.0 * out


@njit(cache=True)
def quat_of_rotvec(phi):
    """``q{phi}``: the unit quaternion (w, x, y, z) of the rotation vector ``phi``."""
    th = np.sqrt(phi @ phi)
    q = np.empty(4)
    q[0] = np.cos(0.5 * th)
    if th > 1e-12:
        q[QV0:QV1] = np.sin(0.5 * th) / th * phi
    else:
        q[QV0:QV1] = 0.5 * phi
    return q


@njit(cache=True)
def nominal_F_Q(q, a_b, w_b, dt, prm, qscale):
    """Jacobian F (16x16) of one mechanization step with respect to the full state, and the step's discrete process
    noise in this filter's coordinates, ``M Q_d M^T``: ``Q_d`` the canonical error dynamics' over the step by
    ``filter.discretization`` (:func:`.eskf.discrete_model`, the ESKF's own) and ``M`` the identity but ``Xi(q') / 2``
    from the attitude error into the quaternion at the step's end ``q'`` (where ``Q_d`` is expressed). The first-order
    ``Q_d`` puts the noise of the step on v and q alone; at 10 Hz and across an IMU gap the noise's path through the
    step (the accelerometer's into p, the gyro's into v and p, Van Loan's) is what the error-state filter has and this
    one lacked: with it this filter left the ESKF after every KITTI gap (kitti-00 0.870 m against 0.758)."""
    R = quat_to_rot(q)
    F = np.eye(N_NOM)
    J = dRa_dq(q, a_b)
    for i in range(3):
        F[NP_ID + i, NV_ID + i] = dt
        for j in range(4):
            F[NP_ID + i, NQ_ID + j] = 0.5 * dt * dt * J[i, j]
            F[NV_ID + i, NQ_ID + j] = dt * J[i, j]
        for j in range(3):
            F[NP_ID + i, NBA_ID + j] = -0.5 * dt * dt * R[i, j]
            F[NV_ID + i, NBA_ID + j] = -dt * R[i, j]
    # the gyro bias turns the end attitude that the step's mean acceleration reads (mech_step: R1 f1 beside R0 f0):
    # dv'/dbg = T^2/2 R [a]x, dp'/dbg = T^3/4 R [a]x (left out until a finite-difference audit; the ESKF's Phi had them)
    Ra = R @ skew3(a_b)
    for i in range(3):
        for j in range(3):
            F[NV_ID + i, NBG_ID + j] = 0.5 * dt * dt * Ra[i, j]
            F[NP_ID + i, NBG_ID + j] = 0.25 * dt * dt * dt * Ra[i, j]
    qR = quat_R(quat_of_rotvec(w_b * dt))            # dq'/dq: q' = q (x) q{w T}
    F[NQ_ID:NQ_ID + 4, NQ_ID:NQ_ID + 4] = qR
    F[NQ_ID:NQ_ID + 4, NBG_ID:NBG_ID + 3] = -0.5 * dt * xi(q)
    _, Qd = discrete_model(R, a_b, w_b, dt, prm, qscale, int(prm[PRM_DISC]))
    M = np.zeros((N_NOM, N_CANON))
    for i in range(3):
        M[NP_ID + i, CP0 + i] = 1.0
        M[NV_ID + i, CV0 + i] = 1.0
        M[NBA_ID + i, CBA0 + i] = 1.0
        M[NBG_ID + i, CBG0 + i] = 1.0
    M[NQ_ID:NQ_ID + 4, TH0:TH0 + 3] = 0.5 * xi(qR @ q)
    Q = M @ Qd @ M.T
    return F, 0.5 * (Q + Q.T)


@njit(cache=True)
def aligned_quat(R, qref):
    """The quaternion of R in the hemisphere of ``qref``: P's quaternion block belongs to one sign, so
    the sign must stay continuous (rot_to_quat alone flips it when the heading passes 180 degrees)."""
    q = rot_to_quat(R)
    if q @ qref < 0.0:
        q = -q
    return q


@njit(cache=True)
def step(x, P, n, u0, u1, dt, qscale, prm, aux, cov):
    """``P <- F P F^T + Q`` (clone blocks unchanged) at the start-of-interval quaternion in the sign of P
    and the bias-corrected midpoint IMU values; then the midpoint mechanization and the sign reference."""
    if cov:
        fm = 0.5 * (u0[UF:UF + 3] + u1[UF:UF + 3]) - x[XBA:XBA + 3]
        wm = 0.5 * (u0[UW:UW + 3] + u1[UW:UW + 3]) - x[XBG:XBG + 3]
        F, Q = nominal_F_Q(aligned_quat(attitude(x), aux[AQ0:AQ0 + 4]), fm, wm, dt, prm, qscale)
        Pn = np.ascontiguousarray(P[:n, :n])
        Fa = np.eye(n)
        Fa[:N_NOM, :N_NOM] = F
        newP = Fa @ Pn @ Fa.T
        newP[:N_NOM, :N_NOM] += Q
        symmetrize_into(P, n, newP)
    mech_step(x, u0[UF:UF + 3], u0[UW:UW + 3], u1[UF:UF + 3], u1[UW:UW + 3], dt, prm[PRM_G])
    aux[AQ0:AQ0 + 4] = aligned_quat(attitude(x), aux[AQ0:AQ0 + 4])


@njit(cache=True)
def record_cov(P, n, x, aux, cidx, diag_out, ppt_out):
    """The canonical core covariance ``D P D^T``: identity rows from ``cidx``, ``2 Xi(q)^T`` on the attitude."""
    q = aligned_quat(attitude(x), aux[AQ0:AQ0 + 4])
    D = np.zeros((cidx.shape[0], N_NOM))
    for i in range(cidx.shape[0]):
        if cidx[i] >= 0:
            D[i, cidx[i]] = 1.0
    D[TH0:TH0 + 3, NQ_ID:NQ_ID + 4] = 2.0 * xi(q).T
    C = D @ np.ascontiguousarray(P[:N_NOM, :N_NOM]) @ D.T
    for i in range(cidx.shape[0]):
        diag_out[i] = C[i, i]
    record_pose_cov(C, ppt_out)


@njit(cache=True)
def gap_motion(P, x, cidx, gap, gap_s):
    """:func:`~fusion_eval.filters.propagate.add_gap_motion` on the quaternion: the unknown rotation ``dtheta`` a gap
    of ``gap_s`` hid (``gap[2] gap_s^2`` per axis) enters the quaternion as ``Xi(q) dtheta / 2``, so its block gains
    ``gap[2] gap_s^2 Xi Xi^T / 4`` (either sign of ``q``); by index it was left out, the attitude having no block of
    the canonical one's size (a review). The velocity's is the canonical one's."""
    X = xi(rot_to_quat(attitude(x)))
    sr = 0.25 * gap[2] * gap_s * gap_s
    for i in range(4):
        for j in range(4):
            s = 0.0
            for k in range(3):
                s += X[i, k] * X[j, k]
            P[NQ_ID + i, NQ_ID + j] += sr * s
    for i in range(3):
        P[NV_ID + i, NV_ID + i] += gap[3] * gap_s * gap_s


predict_to = compiled_loop(__name__, step, record_cov, gap_motion)


class NominalStateEKF(FilterBase):
    name = "nominal_state"
    process_model = "imu"
    label = "nominal-state EKF on the full state [p, v, q, ba, bg] with quaternion normalisation"
    layout = LAYOUT
    pairs = PAIRS
    _step = staticmethod(step)
    _predict = staticmethod(predict_to)
    _record_cov = staticmethod(record_cov)
    _gap_motion = staticmethod(gap_motion)
    smoothable = False
    keys: dict = {}            # filter.discretization (its process noise) is the ESKF's key (declared once, there)

    @classmethod
    def run_params(cls, s, gravity_mps2: float) -> np.ndarray:
        return imu_model.run_params(s, gravity_mps2)

    def initial_aux(self) -> np.ndarray:
        aux = np.zeros(AUX.n)
        aux[AQ] = rot_to_quat(self.x.R_wb)     # sign reference of the state's quaternion (see aligned_quat)
        aux[AQC] = aux[AQ]
        return aux

    def _q(self) -> np.ndarray:
        return aligned_quat(self.x.R_wb, self.aux[AQ])

    def _qc(self) -> np.ndarray:
        return aligned_quat(self.clone.R_wb, self.aux[AQC])

    def quats(self) -> dict[str, np.ndarray]:
        out = {"Q": self._q()}
        if self.cloned:
            out["CQ"] = self._qc()
        return out

    def _vec(self) -> np.ndarray:
        L = self.layout
        v = np.empty(self.n)
        x = self.x
        v[L.sl("P")], v[L.sl("V")], v[L.sl("Q")], v[L.sl("BA")], v[L.sl("BG")] = x.p_w_m, x.v_w_mps, self._q(), x.ba_b, x.bg_b
        if self.n > L.n_core:
            v[L.sl("CP")], v[L.sl("CQ")] = self.clone.p_w_m, self._qc()
        return v

    def snapshot(self):
        return self._vec()

    def boxminus(self, snap) -> np.ndarray:
        d = self._vec() - snap
        # the same rotation, in the hemisphere of the snapshot's quaternion
        for b in ("Q", "CQ"):
            s = self.layout.sl(b)
            if self.layout[b].stop <= self.n and np.dot(self._vec()[s], snap[s]) < 0:
                d[s] = -self._vec()[s] - snap[s]
        return d

    def boxplus_from(self, snap, dx: np.ndarray) -> None:
        L = self.layout
        v = snap + dx
        x = self.x
        x.p_w_m[:], x.v_w_mps[:] = v[L.sl("P")], v[L.sl("V")]
        q = v[L.sl("Q")] / np.linalg.norm(v[L.sl("Q")])
        x.R_wb[:] = quat_to_rot(q)
        self.aux[AQ] = q                            # the corrected quaternion keeps the snapshot's sign
        x.ba_b[:], x.bg_b[:] = v[L.sl("BA")], v[L.sl("BG")]
        if self.n > L.n_core:
            self.clone.p_w_m[:] = v[L.sl("CP")]
            qc = v[L.sl("CQ")] / np.linalg.norm(v[L.sl("CQ")])
            self.clone.R_wb[:] = quat_to_rot(qc)
            self.aux[AQC] = qc

    def after_correction(self, dx: np.ndarray) -> None:
        # normalisation q <- q/|q|: P <- J P J^T with J = I - q q^T on each quaternion block
        J = np.eye(self.n)
        for b, q in self.quats().items():
            s = self.layout.sl(b)
            J[s, s] -= np.outer(q, q)
        self.P[:self.n, :self.n] = J @ self.P[:self.n, :self.n] @ J.T

    def on_clone(self) -> None:
        self.aux[AQC] = self._q()                   # the clone's quaternion block is a copy of the state's

