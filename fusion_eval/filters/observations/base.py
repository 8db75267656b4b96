"""What an observation module declares, and the pieces observation models share.

An observation is one module holding one :class:`Observation` (registered in
:mod:`fusion_eval.filters.observations`). It declares in one place:

* ``name`` (the key of its NIS in reports, its column in ``compare``), ``label`` and ``dof``;
* ``streams``: the dataset streams it needs (a missing one is a one-line error naming the key that
  enabled the observation);
* ``keys``: its configuration keys with units and bounds (the configuration schema takes them from here);
* ``blocks``: the canonical error-state blocks its Jacobian uses (a formulation without them refuses it);
* ``enabled(cfg)``: whether the configuration turns it on;
* ``bind(run, s)``: when it fires, at its stream's stamps or at a rate (``Bound.t_s``), and its model at each
  event: the textbook ``(H, r, R)`` with ``H`` over the canonical columns, ``r = z - h(x_hat)``;
* optionally a compiled ``kernel`` of its model, which the replay's compiled event loop calls
  (:mod:`fusion_eval.filters.compiled_replay`; ``Bound.kernel``): ``kernel(x, xc, row, H, r, Rm) -> m`` writes
  the first ``m`` rows of ``H`` (canonical columns), ``r`` and ``Rm`` from the nominal vector ``x``, the clone
  vector ``xc`` and the event's data ``row`` (``m = 0``: nothing to update). The module's Python model is
  that kernel called through :func:`kernel_model`, so the model is written once;
* optionally a chi-square gate (``gate_key``: the probability of the innovation's chi-square interval
  beyond which an update is rejected), extra streams it brings (``extra_streams``) and a simulated sensor
  for ``fusion-eval simulate`` (``simulate``).

Attitude residuals are ``Log(R_hat^T R_obs)``, so that a right perturbation ``R_obs = R_hat Exp(dtheta)``
gives ``r = dtheta``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit

from ..layout import CANONICAL, CLONE, NOMINAL, Layout
from ..state import ObservationModel

N_MAX = CANONICAL.n
P, V, TH = CANONICAL.sl("P"), CANONICAL.sl("V"), CANONICAL.sl("TH")
CP, CTH = CANONICAL.sl("CP"), CANONICAL.sl("CTH")
# the same positions as integers, for the compiled kernels
P_ID, V_ID, TH_ID, CP_ID, CTH_ID = (CANONICAL.start(b) for b in ("P", "V", "TH", "CP", "CTH"))
XP, XV, XR = (NOMINAL.start(b) for b in ("p", "v", "R"))
CLONE_P, CLONE_R = CLONE.start("p"), CLONE.start("R")
M_MAX = 6           # not a state index: the most residual rows a kernel writes (H: M_MAX x N_MAX)


@njit(cache=True)
def matched_variance(var, q, rate):
    """One step of the adaptive noise (covariance matching): the variance scale ``var`` moved toward
    ``E[q] = 1`` for a block's normalised innovation ``q`` (NIS / dim), multiplicatively and bounded so one
    wild innovation cannot swing it. The Python models and the compiled replay both take this step."""
    v = var * (1.0 + rate * (min(q, 10.0) - 1.0))
    return min(max(v, 1e-3), 1e3)


@dataclass
class Kernel:
    """An observation's compiled model bound to a run: the kernel and one data row per event.

    ``clone_after``: the event clones the pose after its update (relative pose). ``adapt_blocks``: the residual
    row ranges whose noise is matched online to the innovations (``adapt_rate``: the forgetting rate; the
    scales are those of :class:`Bound.adapt`)."""

    fn: Callable
    data: np.ndarray                    # (events, width) float64
    clone_after: bool = False
    adapt_blocks: tuple = ()            # ((start, stop), ...) residual rows
    adapt_rate: float = 0.0


def kernel_model(kernel, x, clone_p=None, clone_R=None, row=None, rm_scale=None):
    """``(H, r, Rm)`` of a compiled kernel, for the Python callers (``x``: a :class:`~fusion_eval.filters.state.NominalState`);
    ``rm_scale``: ``((start, stop, factor), ...)`` diagonal blocks of ``Rm`` scaled by the adaptive noise (the
    compiled replay scales them the same way)."""
    xc = np.zeros(CLONE.n)
    if clone_p is not None:
        xc[CLONE.sl("p")] = clone_p
        xc[CLONE.sl("R")] = np.asarray(clone_R, float).ravel()
    H, r, Rm = np.zeros((M_MAX, N_MAX)), np.zeros(M_MAX), np.zeros((M_MAX, M_MAX))
    m = kernel(np.ascontiguousarray(x.vec, float), xc, np.ascontiguousarray(row, float), H, r, Rm)
    for lo, hi, f in rm_scale or ():
        Rm[lo:hi, lo:hi] *= f
    return H[:m], r[:m], Rm[:m, :m]


@dataclass
class Bound:
    """An observation bound to one run's data: its event stamps and its model at each event.

    ``model(j)`` returns the model of event j, called as ``model(x, clone_p, clone_R)`` (an iterated update
    re-evaluates it at each iterate), or None when event j updates nothing (the first lidar frame of the
    relative form, which only clones); ``after(kf, j)`` runs after the update (cloning).
    """

    name: str
    dof: int
    t_s: np.ndarray
    model: Callable[[int], ObservationModel | None]
    after: Callable | None = None
    gate: float = np.inf
    on_result: Callable | None = None   # (t, r, S, nis, accepted) after each update: adaptive noise
    summary: Callable | None = None     # () -> dict for the report (e.g. the adapted noise scales)
    kernel: Kernel | None = None        # the compiled model, for the compiled replay (None: Python only)
    adapt: object | None = None         # the adaptive noise state the compiled replay writes back (AdaptiveScale)

    def apply(self, kf, j: int, iterations: int = 1, tol: float = 1e-8) -> tuple[float, bool] | None:
        m = self.model(j)
        if m is None:
            res = None
        elif self.on_result is not None:
            Hc, r, Rm = m(*kf.model_args())
            plain = iterations <= 1 and kf.compiled_update
            # the innovation covariance before the update changes P: the one the compiled update used, else formed here
            S = None if plain else kf.innovation_cov(Hc, Rm)
            once = m if iterations > 1 else (lambda *_: (Hc, r, Rm))     # the plain update needs no re-evaluation
            res = kf.update(once, iterations, tol, self.gate)
            self.on_result(kf.t, r, kf.last_S if plain else S, *res)
        else:
            res = kf.update(m, iterations, tol, self.gate)
        if self.after is not None:
            self.after(kf, j)
        return res


class Observation:
    """One observation model: the declarations above as class attributes, ``enabled`` and ``bind``."""

    name: str = ""
    label: str = ""
    dof: int = 0
    streams: tuple[str, ...] = ()
    keys: dict = {}
    blocks: frozenset = frozenset()
    enabled_by: str = ""                # the key that turns it on (named in errors)
    gate_key: str | None = None
    extra_streams: tuple = ()           # datasets.streams.StreamSpec of streams only this observation reads
    sim_keys: dict = {}                 # simulator settings of its simulated sensor (``simulate``)
    kernel = None                       # its compiled model (``kernel(x, xc, row, H, r, Rm) -> m``), if it has one
    # an absolute measurement of the world (GNSS): runs of innovations far beyond their bound amid consistent ones
    # are a jump of the stream (multipath, a receiver's reset, a change of datum), said in the report with the gate
    # that rejects them; not of a relative or a pseudo-observation, whose runs are the filter's own
    jumps: bool = False
    # keys of other observations it reads (a shared setting), and its own keys that something else reads while it is
    # off: neither is said to do nothing when it is off (:func:`fusion_eval.filters.observations.inactive_settings`)
    also_reads: frozenset = frozenset()
    read_elsewhere: frozenset = frozenset()

    @property
    def enable_with(self) -> dict:
        """The settings that turn it on (``--set`` keys and values)."""
        return {self.enabled_by: True}

    @property
    def disable_with(self) -> dict:
        """The settings that turn it off (named in errors)."""
        return {self.enabled_by: False}

    def enabled(self, cfg: dict) -> bool:
        return all(cfg[k.split(".")[0]][k.split(".")[1]] == v for k, v in self.enable_with.items())

    def resolve_for(self, cfg: dict, description: dict) -> None:
        """Settle this observation's dataset-dependent ``auto`` settings in a run's configuration (in place), from
        the dataset's manifest (``description``); an unresolved ``auto`` reads as off."""

    def bind(self, run, s) -> Bound:
        raise NotImplementedError

    def gate(self, s, dof: int | None = None) -> float:
        """The NIS above which an update is rejected (inf when the gate is off); ``dof`` when the observation
        observes fewer rows than it declares."""
        if self.gate_key is None:
            return np.inf
        sect, key = self.gate_key.split(".")
        prob = getattr(getattr(s, sect), key)
        if prob is None:
            return np.inf
        from ...stats import chi2_ppf

        return float(chi2_ppf(prob, self.dof if dof is None else dof))

    simulate = None                     # optional: (motion, sim_settings, rng, out) -> manifest stream entries


def rows_inside(t_s: np.ndarray, t0: float, t_end: float) -> np.ndarray:
    """Rows of a stream whose stamps fall inside the run ``[t0, t_end]`` (1 ns slack at the start)."""
    return np.flatnonzero((t_s >= t0 - 1e-9) & (t_s <= t_end))


# data row of a body-velocity observation: observed v_b, std per axis, and which axes it observes (1) or not (0)
BODY_VELOCITY_ROW = Layout("body velocity data row", [("v", 3), ("std", 3), ("used", 3), ("axes", 9)])
_BV, _BSTD, _BUSED, _BAXES = (BODY_VELOCITY_ROW.start(b) for b in ("v", "std", "used", "axes"))
IDENTITY_AXES = np.eye(3).ravel()


@njit(cache=True)
def body_velocity_rows(x, row, H, r, Rm):
    """Velocity along the vehicle's axes ``c_q^T v_b``, ``v_b = R^T v``, compiled: the observed axes (one row each;
    0 forward, 1 lateral, 2 vertical), each axis ``c_q`` given in the IMU frame (row ``q`` of the data row's
    ``axes``: the identity when the IMU is aligned with the vehicle), with ``d/d dv = c_q^T R^T`` and
    ``d/d dtheta = c_q^T [v_b]x = (c_q x v_b)^T``. Each observation that uses it wraps it in a kernel of its own
    (the compiled replay dispatches on the kernel)."""
    vb = np.empty(3)
    for q in range(3):
        vb[q] = (x[XR + q] * x[XV] + x[XR + 3 + q] * x[XV + 1] + x[XR + 6 + q] * x[XV + 2])
    m = 0
    for q in range(3):
        if row[_BUSED + q] == 0.0:
            continue
        a = _BAXES + 3 * q
        for k in range(H.shape[1]):
            H[m, k] = 0.0
        for k in range(Rm.shape[1]):
            Rm[m, k] = 0.0
            Rm[k, m] = 0.0
        for k in range(3):                                # c^T R^T
            H[m, V_ID + k] = (row[a] * x[XR + 3 * k] + row[a + 1] * x[XR + 3 * k + 1]
                              + row[a + 2] * x[XR + 3 * k + 2])
        H[m, TH_ID] = row[a + 1] * vb[2] - row[a + 2] * vb[1]       # c x v_b
        H[m, TH_ID + 1] = row[a + 2] * vb[0] - row[a] * vb[2]
        H[m, TH_ID + 2] = row[a] * vb[1] - row[a + 1] * vb[0]
        r[m] = row[_BV + q] - (row[a] * vb[0] + row[a + 1] * vb[1] + row[a + 2] * vb[2])
        Rm[m, m] = row[_BSTD + q] * row[_BSTD + q]
        m += 1
    return m
