"""Nominal-state EKF: the full state ``x = [p, v, q, ba, bg]`` (16, quaternion (w, x, y, z)) is itself
propagated and updated; a cloned pose adds ``[p_c, q_c]`` (7). After each update the quaternions are
normalised and ``P`` is mapped through the normalisation's Jacobian ``(I - q q^T)`` (for a unit q).

Observation models are written for the canonical error state; their Jacobian with respect to this
state is ``H = H_canonical D`` with ``D = d(error)/d(x)``: identity on p, v, the biases, and
``dtheta/dq = 2 Xi(q)^T`` on each quaternion (``q (x) [1, dtheta/2] = q + Xi(q) dtheta / 2``). So the
attitude innovation is the rotation vector of ``R_pred^T R_obs``, as for the ESKF, rather than a
difference of quaternions (which has a sign ambiguity and a rank-deficient covariance). The
derivation is in ``docs/nominal_state.md``.
"""

from __future__ import annotations

import numpy as np

from . import nominal_kernels as nk
from . import propagate as pr
from .base import FilterBase
from .kernels import N_CORE
from .state import NominalState

NQ = nk.NQ_ID


class NominalStateEKF(FilterBase):
    name = "nominal_state"
    n_core = nk.N_NOM

    def __init__(self, x0: NominalState, P0_err: np.ndarray, prm: np.ndarray, imu_t, imu_f, imu_w, k0: int):
        self.x = x0.copy()
        n_max = nk.N_NOM + nk.N_NOM_CLONE
        self.P = np.zeros((n_max, n_max))
        # the error-state prior mapped into the full state: P_q = Xi P_theta Xi^T / 4
        self.qref = nk.rot_to_quat(self.x.R_wb)     # sign reference of the state's quaternion (see aligned_quat)
        self.qcref = self.qref.copy()
        E = self._E(self.qref)
        self.P[:nk.N_NOM, :nk.N_NOM] = E @ P0_err @ E.T
        self.n = nk.N_NOM
        self.prm = prm
        self.imu_t, self.imu_f, self.imu_w = imu_t, imu_f, imu_w
        N = imu_t.size
        self.rec_p, self.rec_v, self.rec_ba, self.rec_bg = (np.full((N, 3), np.nan) for _ in range(4))
        self.rec_R = np.full((N, 3, 3), np.nan)
        self.rec_Pdiag = np.full((N, N_CORE), np.nan)
        self.rec_Ppt = np.full((N, 6, 6), np.nan)
        self.last = np.concatenate([[imu_t[k0]], imu_f[k0], imu_w[k0]])
        self.k_next = k0 + 1
        self.clone_p: np.ndarray | None = None
        self.clone_R: np.ndarray | None = None
        self.record(k0)

    @staticmethod
    def _E(q: np.ndarray) -> np.ndarray:
        """d(full state)/d(canonical error) for the 15 core states: Xi(q)/2 on the attitude."""
        E = np.zeros((nk.N_NOM, N_CORE))
        for a, b in ((0, 0), (3, 3), (10, 9), (13, 12)):
            E[a:a + 3, b:b + 3] = np.eye(3)
        E[NQ:NQ + 4, 6:9] = 0.5 * nk.xi(q)
        return E

    def predict_to(self, t_target: float) -> None:
        x = self.x
        self.k_next = pr.predict_to(x.p_w_m, x.v_w_mps, x.R_wb, x.ba_b, x.bg_b, self.P, self.n, self.last,
                                    self.imu_t, self.imu_f, self.imu_w, self.k_next, float(t_target), self.prm,
                                    pr.COV_NOMINAL, self.rec_p, self.rec_v, self.rec_R, self.rec_ba, self.rec_bg,
                                    self.rec_Pdiag, self.rec_Ppt, self.qref)

    def _q(self) -> np.ndarray:
        return nk.aligned_quat(self.x.R_wb, self.qref)

    def _qc(self) -> np.ndarray:
        return nk.aligned_quat(self.clone_R, self.qcref)

    def D(self) -> np.ndarray:
        D = np.zeros((21, self.n))
        for a, b in ((0, 0), (3, 3), (9, 10), (12, 13)):
            D[a:a + 3, b:b + 3] = np.eye(3)
        D[6:9, NQ:NQ + 4] = 2.0 * nk.xi(self._q()).T
        if self.n > nk.N_NOM:
            D[15:18, nk.NC_P_ID:nk.NC_P_ID + 3] = np.eye(3)
            D[18:21, nk.NC_Q_ID:nk.NC_Q_ID + 4] = 2.0 * nk.xi(self._qc()).T
        return D

    def _vec(self) -> np.ndarray:
        x = self.x
        v = np.concatenate([x.p_w_m, x.v_w_mps, self._q(), x.ba_b, x.bg_b])
        if self.n > nk.N_NOM:
            v = np.concatenate([v, self.clone_p, self._qc()])
        return v

    def snapshot(self):
        return self._vec()

    def boxminus(self, snap) -> np.ndarray:
        d = self._vec() - snap
        # the same rotation, in the hemisphere of the snapshot's quaternion
        for i in (NQ, nk.NC_Q_ID):
            if i < self.n and np.dot(self._vec()[i:i + 4], snap[i:i + 4]) < 0:
                d[i:i + 4] = -self._vec()[i:i + 4] - snap[i:i + 4]
        return d

    def boxplus_from(self, snap, dx: np.ndarray) -> None:
        v = snap + dx
        x = self.x
        x.p_w_m[:], x.v_w_mps[:] = v[0:3], v[3:6]
        q = v[NQ:NQ + 4] / np.linalg.norm(v[NQ:NQ + 4])
        x.R_wb[:] = nk.quat_to_rot(q)
        self.qref = q.copy()                        # the corrected quaternion keeps the snapshot's sign
        x.ba_b[:], x.bg_b[:] = v[10:13], v[13:16]
        if self.n > nk.N_NOM:
            self.clone_p = v[16:19].copy()
            qc = v[19:23] / np.linalg.norm(v[19:23])
            self.clone_R = nk.quat_to_rot(qc)
            self.qcref = qc.copy()

    def after_correction(self, dx: np.ndarray) -> None:
        # normalisation q <- q/|q|: P <- J P J^T with J = I - q q^T on each quaternion block
        J = np.eye(self.n)
        q = self._q()
        J[NQ:NQ + 4, NQ:NQ + 4] -= np.outer(q, q)
        if self.n > nk.N_NOM:
            qc = self._qc()
            J[nk.NC_Q_ID:nk.NC_Q_ID + 4, nk.NC_Q_ID:nk.NC_Q_ID + 4] -= np.outer(qc, qc)
        self.P[:self.n, :self.n] = J @ self.P[:self.n, :self.n] @ J.T

    def clone_rows(self) -> np.ndarray:
        return np.r_[0:3, NQ:NQ + 4]

    def clone_pose(self) -> None:
        super().clone_pose()
        self.qcref = self._q().copy()               # the clone's quaternion block is a copy of the state's

    def record(self, k: int) -> None:
        x = self.x
        self.rec_p[k], self.rec_v[k], self.rec_R[k] = x.p_w_m, x.v_w_mps, x.R_wb
        self.rec_ba[k], self.rec_bg[k] = x.ba_b, x.bg_b
        self.rec_Pdiag[k], self.rec_Ppt[k] = nk.canonical_cov(self.P, self._q())
