"""What every formulation shares: initialisation from the canonical prior, the (iterated) Kalman update,
stochastic cloning, recording.

Observation models (:mod:`fusion_eval.filters.observations`) are written once, for the canonical error
state (:data:`~fusion_eval.filters.layout.CANONICAL`). A formulation relates its own state to it by pairs of
blocks; from them the layout module builds ``D = d(canonical)/d(own)``, so the formulation's observation
matrix is ``H = H_canonical D``, and the same map carries its covariance to the canonical one for reports.
A formulation supplies its layout and pairs, its compiled step and covariance recording (instantiated into
the shared loop of :mod:`fusion_eval.filters.propagate`), how to add a correction to its state
(``boxplus_from``), how to measure the difference of two states (``boxminus``), and what to do to ``P``
after a correction (the error-state reset, the nominal-state normalisation).

The iterated update (IEKF) re-linearises at the latest iterate::

    x_{i+1} = x_0 [+] K_i (r_i + H_i (x_i [-] x_0)),   K_i = P_0 H_i^T (H_i P_0 H_i^T + R)^-1

until the step is below ``tol`` or ``iterations`` is reached, then updates ``P`` once with the last
``K, H`` (Joseph form). With one iteration it is the plain EKF update.
"""

from __future__ import annotations

import numpy as np

from ...errors import FilterDivergedError
from ...so3 import skew
from .. import linalg
from ..mech import exp3, log3
from ..layout import CANONICAL, Layout, canonical_index, canonical_map, own_from_canonical
from ..propagate import LAST_T, add_gap_motion, new_arrays
from ..state import ClonePose, NominalState, ObservationModel
from .imu_model import imu_inputs, imu_params



def canonical_prior_std(s) -> np.ndarray:
    """1-sigma of the canonical core error state at the start, from the ``init.*`` settings (SI)."""
    i = s.init
    std = np.empty(CANONICAL.n_core)
    std[CANONICAL.sl("P")] = i.pos_std_m
    std[CANONICAL.sl("V")] = i.vel_std_mps
    th = CANONICAL.sl("TH")
    std[th] = [i.roll_pitch_std_rad, i.roll_pitch_std_rad, i.yaw_std_rad]
    std[CANONICAL.sl("BA")] = i.accel_bias_std_mps2
    std[CANONICAL.sl("BG")] = i.gyro_bias_std_rps
    return std


def bias_decays(s) -> tuple[float, float]:
    """Accelerometer and gyro bias decay rates 1/tau (1/s) under the Gauss-Markov bias model, else 0: the random
    walk is the limit tau -> inf, the constant bias that with no driving noise."""
    if s.filter.bias_model != "gauss_markov":
        return 0.0, 0.0
    return 1.0 / s.imu.accel_bias_corr_time_s, 1.0 / s.imu.gyro_bias_corr_time_s


def bias_walks(s) -> tuple[float, float]:
    """Accelerometer and gyro bias random-walk densities (SI) under the configured bias model: the constant
    model keeps the bias states (their initial uncertainty is estimated away) with no random walk."""
    if s.filter.bias_model == "constant":
        return 0.0, 0.0
    return s.imu.accel_bias_rw_mps3_sqrthz, s.imu.gyro_bias_rw_rps2_sqrthz


def gap_of(s, t: np.ndarray) -> tuple[float, float, float, float]:
    """An interval longer than ``imu.gap_factor`` median intervals is a gap: its white noise is scaled by
    ``imu.gap_noise_scale`` (std), i.e. its variance by the square, and at its end the motion it hid is added
    (:data:`fusion_eval.filters.propagate` ``_LOOP``): the variances of the unknown turn rate and acceleration,
    rad^2/s^2 and m^2/s^4."""
    gap_dt = s.imu.gap_factor * float(np.median(np.diff(t))) if t.size > 1 else np.inf
    return gap_dt, s.imu.gap_noise_scale ** 2, s.imu.gap_turn_rate_rps ** 2, s.imu.gap_accel_mps2 ** 2


class FilterBase:
    """Common machinery. Subclasses set the class attributes and the compiled ``_predict``/``_record_cov``."""

    name = "base"                   # filter.formulation
    process_model = "imu"           # filter.process_model
    bias_models = ("random_walk", "constant")   # filter.bias_model values its process model implements
    # filter.discretization values its process model implements (the ESKF's, the nominal and invariant filters' all)
    discretizations = ("first_order", "second_order", "van_loan")
    layout: Layout
    pairs: tuple[tuple[str, str], ...]
    keys: dict = {}                 # configuration keys this formulation owns
    streams: tuple[str, ...] = ()   # dataset streams its process model needs
    # own blocks -> the nominal quantity they correct ('p', 'v', 'R', 'ba', 'bg', 'k', 'clone.p', 'clone.R')
    targets: dict[str, str] = {}
    _step = None            # the compiled step (also what the tests check the Jacobian of)
    _predict = None
    _record_cov = None
    # the motion an IMU gap hid, added to the own covariance (propagate.add_gap_motion: the canonical blocks by index)
    _gap_motion = staticmethod(add_gap_motion)
    clone_t = None          # stamp of the cloned pose
    recorder = None         # an RTS smoother's forward record (fusion_eval.smoothing.record), when smoothing
    transition_room = False  # whether reserve_transition gave its scratch room for the step's transition
    # whether the RTS smoother runs over it: its error coordinates must be minimal (a 4-parameter quaternion's
    # norm direction makes the backward gains ill-posed; measured to diverge on the simulation)
    smoothable = True

    def __init__(self, x0: NominalState, P0: np.ndarray, prm: np.ndarray, t: np.ndarray, u: np.ndarray, k0: int,
                 gap: tuple[float, ...] = (np.inf, 1.0, 0.0, 0.0), extra_var: dict[str, float] | None = None):
        """``P0``: the canonical core prior (15x15); ``u``: the input rows at the stamps ``t``; the filter
        sits at sample ``k0``. ``extra_var``: variances of own blocks that have no canonical counterpart."""
        L = self.layout
        self.xv = x0.vec.copy()
        self.x = NominalState.from_vector(self.xv)
        self.clone = ClonePose()
        self.cloned = False
        self.n = L.n_core
        self.P = np.zeros((L.n, L.n))
        self.aux = self.initial_aux()
        self.P[:L.n_core, :L.n_core] = self.own_prior(P0)
        for b, var in (extra_var or {}).items():
            self.P[L.sl(b), L.sl(b)] = np.eye(L[b].size) * var
        self.cidx = canonical_index(L, self.pairs)
        self.arrays = new_arrays(self.xv, self.P, np.ascontiguousarray(t, float), np.ascontiguousarray(u, float), k0,
                                 np.ascontiguousarray(prm, float), np.array(gap, float), self.aux, self.cidx)
        self.k_next = k0 + 1
        self.after_correction_state()
        self.record(k0)

    @classmethod
    def from_run(cls, run, s) -> "FilterBase":
        """The filter for a prepared run (``run.imu``, ``run.x0``, ``run.k_start``, ``run.gravity_mps2``) and
        the SI settings ``s``, sitting at the start sample."""
        t = run.imu.t_s
        P0 = np.diag(canonical_prior_std(s) ** 2)
        return cls(run.x0, P0, cls.run_params(s, run.gravity_mps2), t, cls.run_inputs(run), run.k_start, gap_of(s, t),
                   cls.run_extra_var(s))

    @classmethod
    def run_inputs(cls, run) -> np.ndarray:
        return imu_inputs(run.imu.f_b_mps2, run.imu.w_b_rps)

    @classmethod
    def run_params(cls, s, gravity_mps2: float) -> np.ndarray:
        qba, qbg = bias_walks(s)
        return imu_params(gravity_mps2, s.imu.accel_noise_mps2_sqrthz, s.imu.gyro_noise_rps_sqrthz, qba, qbg)

    @classmethod
    def run_extra_var(cls, s) -> dict[str, float]:
        return {}

    # ---- hooks -------------------------------------------------------------------------------
    def own_prior(self, P0: np.ndarray) -> np.ndarray:
        """The prior of the own core state from the canonical one, ``E P0 E^T`` (``E`` from the pairs)."""
        E = own_from_canonical(self.layout, self.pairs, self.layout.n_core, self.quats())[:, :CANONICAL.n_core]
        return E @ P0 @ E.T

    def initial_aux(self) -> np.ndarray:
        return np.zeros(1)

    def keeps_transition(self) -> bool:
        """Whether its compiled step writes the transition of each step into room after its own scratch
        (:meth:`reserve_transition`): where that transition is dear to recompute (a dense discretization), the RTS
        smoother then keeps each epoch's prior and transition instead of recomputing the interval into it."""
        return False

    def reserve_transition(self) -> None:
        """Give the step room after its own scratch for its transition (:meth:`keeps_transition`), filled with NaN:
        the record takes what the step wrote and refills it (``record.store_prior``), so a transition the step did
        not write shows as NaN in the smoothed estimate rather than as a plausible one. Once per filter."""
        if not self.transition_room:
            self.aux = np.concatenate([self.aux, np.full(self.layout.n_core ** 2, np.nan)])
            self.arrays = self.arrays._replace(aux=self.aux)
            self.transition_room = True

    def quats(self) -> dict[str, np.ndarray]:
        """The quaternions (w, x, y, z) of the own quaternion blocks, for the canonical map."""
        return {}

    def snapshot(self):
        raise NotImplementedError

    def boxminus(self, snap) -> np.ndarray:             # current state [-] snap, own coordinates (n,)
        raise NotImplementedError

    def boxplus_from(self, snap, dx: np.ndarray) -> None:
        raise NotImplementedError

    def after_correction(self, dx: np.ndarray) -> None:  # reset / normalisation applied to P
        pass

    def after_correction_state(self) -> None:            # derived nominal quantities (odometer + gyro velocity)
        pass

    def on_clone(self) -> None:
        pass

    def odometer_scale(self, rec_x: np.ndarray) -> np.ndarray | None:
        """The recorded odometer scale error, for formulations that estimate one (None otherwise)."""
        return None

    # ---- shared ------------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return float(self.arrays.last[LAST_T])

    @property
    def rec_x(self) -> np.ndarray:
        return self.arrays.rec_x

    def D(self) -> np.ndarray:
        """``d(canonical error)/d(own state)`` at the current estimate, ``(21, n)``."""
        return canonical_map(self.layout, self.pairs, self.n, self.quats())

    def predict_to(self, t_target: float) -> None:
        """Propagate the state and covariance to ``t_target`` (recording at each sample passed)."""
        self.k_next = self._predict(self.arrays, self.n, self.k_next, float(t_target), True)

    def record(self, k: int) -> None:
        a = self.arrays
        a.rec_x[k] = self.xv
        self._record_cov(self.P, self.n, self.xv, self.aux, self.cidx, a.rec_Pdiag[k], a.rec_Ppt[k])

    def _check(self, what: str) -> None:
        # a non-finite or negative variance shows on the diagonal (NaN spreads through every product)
        d = self.P.diagonal()[:self.n]
        if not (np.isfinite(d).all() and (d >= 0).all() and np.isfinite(self.x.p_w_m).all()):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: {what}")

    def model_args(self):
        return self.x, self.clone.p_w_m, self.clone.R_wb

    def innovation_cov(self, Hc: np.ndarray, Rm: np.ndarray) -> np.ndarray:
        """The innovation covariance ``S = H P H^T + R`` at the current estimate (``Hc``: canonical columns)."""
        H = Hc @ self.D()
        n = self.n
        return H @ self.P[:n, :n] @ H.T + Rm

    def update(self, model: ObservationModel, iterations: int = 1, tol: float = 1e-8,
               gate: float = np.inf) -> tuple[float, bool]:
        """Update with an observation model (called as ``model(x, clone_p, clone_R)``); returns the NIS and
        whether the update was applied (an innovation with NIS above ``gate`` is rejected). The plain EKF
        update of a formulation with ``compiled_update`` runs in compiled kernels (:meth:`update_compiled`)."""
        if iterations > 1 or not self.compiled_update:
            return self.update_iterated(model, iterations, tol, gate)
        return self.update_compiled(model, gate)

    compiled_update = False      # formulations that define own_jacobian and inject
    last_S = None                # the innovation covariance of the last compiled update (adaptive noise reads it)

    def own_jacobian(self, Hc: np.ndarray) -> np.ndarray:
        """``H`` over the own state from the canonical columns ``Hc``."""
        return np.ascontiguousarray(Hc @ self.D())

    def inject(self, dx: np.ndarray) -> None:
        """Add a correction of the own state to the estimate (and reset ``P`` where the formulation needs it)."""
        raise NotImplementedError

    def update_compiled(self, model: ObservationModel, gate: float = np.inf) -> tuple[float, bool]:
        """The plain EKF update: the Joseph update of ``P`` in compiled kernels, then :meth:`inject`."""
        Hc, r, Rm = model(*self.model_args())
        if not (np.isfinite(r).all() and np.isfinite(Rm).all()):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite residual")
        try:
            dx, nis, ok, self.last_S = linalg.joseph_update_s(self.P, self.n, self.own_jacobian(Hc), r,
                                                              np.ascontiguousarray(Rm, float), gate)
        except np.linalg.LinAlgError as exc:
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: innovation covariance not invertible ({exc})") from None
        if not (np.all(np.isfinite(dx)) and np.isfinite(nis)):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite correction")
        if not ok:
            return float(nis), False
        self.inject(dx)
        self._check("non-finite state or negative variance after an update")
        self._record_if_on_sample()
        return float(nis), True

    def update_iterated(self, model: ObservationModel, iterations: int = 1, tol: float = 1e-8,
                        gate: float = np.inf) -> tuple[float, bool]:
        n = self.n
        P0 = self.P[:n, :n].copy()
        if not np.all(np.isfinite(P0)):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite covariance")
        snap = self.snapshot()
        dx_prev = None
        nis = None
        for it in range(max(1, iterations)):
            Hc, r, Rm = model(*self.model_args())
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(Rm))):
                raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite residual")
            H = np.ascontiguousarray(Hc @ self.D())
            try:
                K, Sinv = linalg.gain(self.P, n, H, np.ascontiguousarray(Rm, float))
            except np.linalg.LinAlgError as exc:
                raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: innovation covariance not invertible ({exc})") from None
            if it == 0:
                nis = float(r @ Sinv @ r)
                # the innovations' likelihood (tune's nll) takes log det S of the S this NIS is of (it was NaN for
                # the iterated update: its nll read nan in compare's and sweep's tables)
                self.last_S = np.linalg.inv(Sinv)
                if nis > gate:
                    return nis, False
                dx = K @ r
            else:
                dx = K @ (r + H @ self.boxminus(snap))
            self.boxplus_from(snap, dx)
            if dx_prev is not None and np.linalg.norm(dx - dx_prev) < tol:
                break
            dx_prev = dx
        linalg.joseph(self.P, n, K, H, np.ascontiguousarray(Rm, float))   # P still holds P0 here
        self.after_correction(dx)
        self.after_correction_state()
        self._check("non-finite state or negative variance after an update")
        if not np.all(np.isfinite(dx)):
            raise FilterDivergedError(f"filter diverged at t={self.t:.3f} s: non-finite correction")
        self._record_if_on_sample()
        return nis, True

    def _record_if_on_sample(self) -> None:
        t = self.arrays.t
        if self.k_next > 0 and abs(t[self.k_next - 1] - self.t) < 1e-9:
            self.record(self.k_next - 1)

    def clone_pose(self) -> None:
        """Stochastic cloning: append a copy of the current pose to the state (replacing any clone)."""
        if self.recorder is not None:
            self.recorder.before_clone(self)
        core = self.layout.n_core
        self.n = core + linalg.clone_covariance(self.P, core, np.ascontiguousarray(self.layout.clone_rows(), np.int64))
        self.clone.set(self.x.p_w_m, self.x.R_wb)
        self.clone_t = self.t           # the stamp of the pose the clone holds (the batch smoother's between-factor)
        self.cloned = True
        self.on_clone()


class ErrorStateBase(FilterBase):
    """A filter on an error state: additive errors on vector blocks, right perturbations on attitudes.

    ``targets`` maps each own block to the nominal quantity it corrects; ``boxplus``/``boxminus`` and the
    reset ``G = I - [dtheta/2]x`` on each attitude block (Sola, eq. 287) follow from it."""

    def _value(self, where: str):
        obj, _, q = where.rpartition(".")
        src = self.clone if obj == "clone" else self.x
        return src, q

    def _own_blocks(self):
        L = self.layout
        return [L[b] for b in (*L.core, *(L.clone if self.n > L.n_core else ()))]

    def snapshot(self):
        return self.xv.copy(), self.clone.vec.copy() if self.cloned else None

    def boxminus(self, snap) -> np.ndarray:
        x0 = NominalState.from_vector(snap[0])
        c0 = None if snap[1] is None else ClonePose(snap[1])
        out = []
        for b in self._own_blocks():
            src, q = self._value(self.targets[b.name])
            base = c0 if src is self.clone else x0
            if q == "R":
                out.append(log3(base.R_wb.T @ src.R_wb))   # compiled: the smoother calls it per sample
            else:
                out.append(np.atleast_1d(_get(src, q) - _get(base, q)))
        return np.concatenate(out)

    def boxplus_from(self, snap, dx: np.ndarray) -> None:
        x0 = NominalState.from_vector(snap[0])
        c0 = None if snap[1] is None else ClonePose(snap[1])
        for b in self._own_blocks():
            src, q = self._value(self.targets[b.name])
            base = c0 if src is self.clone else x0
            if q == "R":
                src.R_wb[:] = base.R_wb @ exp3(np.ascontiguousarray(dx[b.sl]))
            elif q == "k":
                src.k_odo = base.k_odo + float(dx[b.start])
            else:
                _get(src, q)[:] = _get(base, q) + dx[b.sl]

    def after_correction(self, dx: np.ndarray) -> None:
        G = np.eye(self.n)
        for b in self._own_blocks():
            if self.targets[b.name].endswith("R"):
                G[b.sl, b.sl] -= 0.5 * skew(dx[b.sl])
        self.P[:self.n, :self.n] = G @ self.P[:self.n, :self.n] @ G.T


_ATTR = {"p": "p_w_m", "v": "v_w_mps", "ba": "ba_b", "bg": "bg_b", "k": "_k"}


def _get(obj, q: str):
    return getattr(obj, _ATTR[q])

