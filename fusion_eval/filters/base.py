"""What every filter formulation shares: the (iterated) Kalman update, stochastic cloning, recording.

Observation models (:mod:`fusion_eval.filters.observations`) are written once, for the *canonical*
error state of the ESKF, ``[dp, dv, dtheta, dba, dbg, dp_c, dtheta_c]`` (21 columns). A formulation
gives the Jacobian ``D = d(canonical error)/d(own state)`` at its current estimate, so its own
observation matrix is ``H = H_canonical D``; the same matrix maps its covariance to the canonical one
for reports. Each formulation supplies ``D``, how to add a correction to its state (``boxplus``), how
to measure the difference of two states (``boxminus``), and what to do to ``P`` after a correction
(the ESKF's reset, the nominal-state EKF's quaternion normalisation).

The iterated update (IEKF) re-linearises at the latest iterate::

    x_{i+1} = x_0 [+] K_i (r_i + H_i (x_i [-] x_0)),   K_i = P_0 H_i^T (H_i P_0 H_i^T + R)^-1

until the step is below ``tol`` or ``iterations`` is reached, then updates ``P`` once with the last
``K, H`` (Joseph form). With one iteration it is the plain EKF update.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..errors import FilterDivergedError

ObservationModel = Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]]


class FilterBase:
    """Common machinery; subclasses set ``n``, ``P``, ``x``, ``clone_p``, ``clone_R`` and the hooks."""

    name = "base"
    uses_accelerometer = True

    # ---- hooks -------------------------------------------------------------------------------
    def D(self) -> np.ndarray:                          # (21, n)
        raise NotImplementedError

    def snapshot(self):
        raise NotImplementedError

    def boxminus(self, snap) -> np.ndarray:             # current state [-] snap, own coordinates (n,)
        raise NotImplementedError

    def boxplus_from(self, snap, dx: np.ndarray) -> None:
        raise NotImplementedError

    def after_correction(self, dx: np.ndarray) -> None:  # reset / normalisation applied to P
        pass

    def clone_rows(self) -> np.ndarray:                 # rows of own state that the clone copies
        raise NotImplementedError

    def record(self, k: int) -> None:
        raise NotImplementedError

    # ---- shared ------------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return float(self.last[0])

    def _check(self, what: str) -> None:
        # a non-finite or negative variance shows on the diagonal (NaN spreads through every product)
        d = self.P.diagonal()[:self.n]
        if not (np.isfinite(d).all() and (d >= 0).all() and np.isfinite(self.x.p_w_m).all()):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: {what}")

    def update(self, model: ObservationModel, iterations: int = 1, tol: float = 1e-8) -> float:
        """Update with an observation model (called as ``model(x, clone_p, clone_R)``); returns the NIS."""
        return self.update_iterated(model, iterations, tol)

    def update_iterated(self, model: ObservationModel, iterations: int = 1, tol: float = 1e-8) -> float:
        n = self.n
        P0 = self.P[:n, :n].copy()
        if not np.all(np.isfinite(P0)):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite covariance")
        snap = self.snapshot()
        dx_prev = None
        nis = None
        for it in range(max(1, iterations)):
            Hc, r, Rm = model(self.x, self.clone_p, self.clone_R)
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(Rm))):
                raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite residual")
            H = Hc @ self.D()
            PHt = P0 @ H.T
            S = H @ PHt + Rm
            try:
                Sinv = np.linalg.inv(0.5 * (S + S.T))
            except np.linalg.LinAlgError as exc:
                raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: innovation covariance not invertible ({exc})") from None
            K = PHt @ Sinv
            if it == 0:
                nis = float(r @ Sinv @ r)
                dx = K @ r
            else:
                dx = K @ (r + H @ self.boxminus(snap))
            self.boxplus_from(snap, dx)
            if dx_prev is not None and np.linalg.norm(dx - dx_prev) < tol:
                break
            dx_prev = dx
        IKH = np.eye(n) - K @ H
        newP = IKH @ P0 @ IKH.T + K @ Rm @ K.T     # Joseph form: stays symmetric positive semi-definite
        self.P[:n, :n] = 0.5 * (newP + newP.T)
        self.after_correction(dx)
        self._check("non-finite state or negative variance after an update")
        if not np.all(np.isfinite(dx)):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite correction")
        self._record_if_on_sample()
        return nis

    def _record_if_on_sample(self) -> None:
        if self.k_next > 0 and abs(self.imu_t[self.k_next - 1] - self.t) < 1e-9:
            self.record(self.k_next - 1)

    def clone_pose(self) -> None:
        """Stochastic cloning: append a copy of the current pose to the state (replacing any clone)."""
        rows = self.clone_rows()
        core = self.n_core
        m = rows.size
        Pc = self.P[:core, :core]
        self.P[core:core + m, :core] = Pc[rows]                  # J P with J selecting the pose rows
        self.P[:core, core:core + m] = Pc[:, rows]
        self.P[core:core + m, core:core + m] = Pc[np.ix_(rows, rows)]
        self.n = core + m
        self.clone_p = self.x.p_w_m.copy()
        self.clone_R = self.x.R_wb.copy()
