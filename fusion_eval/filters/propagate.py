"""The one loop over IMU samples that every filter uses (compiled), with a per-formulation step.

The loop steps the state from the sample it sits at through every sample up to a target time, then to the
target itself with the inputs interpolated there (so an observation is applied at its own time), marks
the intervals that are gaps (longer than the gap threshold, however an observation splits them) by
scaling the white process noise, and records the nominal state and the canonical covariance at each
sample passed. What a formulation supplies is its step and how to record its covariance:

``step(x, P, n, u0, u1, dt, qscale, prm, aux, cov)``
    propagates the nominal vector ``x`` (layout ``NOMINAL``) and, when ``cov``, ``P[:n, :n]`` over one
    interval with the input rows ``u0 -> u1`` (``qscale`` multiplies the white-noise variances);
``record_cov(P, n, x, aux, cidx, diag_out, ppt_out)``
    writes the canonical error variances (15) and the 6x6 covariance of ``[dp, dtheta]`` (for NEES), packed
    (its upper triangle, :data:`~fusion_eval.filters.layout.PACKED`).

Everything the loop reads and writes travels in one :class:`FilterArrays` record. Numba compiles a
function that receives another compiled function as an argument once per argument and cannot cache
it (and converting it costs ~45 us per call), so the loop is written here once, as source, and each
formulation instantiates it with its own step and recording (:func:`compiled_loop`); each copy is
cached in its formulation's module.

Compiled callers pass ``cov`` as ``np.bool_(True)``, not ``True``: numba types a constant argument as a literal
and compiles the callee again for it, and the ESKF's step and loop are most of a first run's compilation (a
default run's cold start compiled each twice; ``tests/test_compiled_replay.py`` holds every compiled caller to it).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

from .. import codegen
from .layout import CANONICAL, PACKED, POSE_BLOCKS, POSE_PACKED_N

# ``last``: the time, then the input row the state sits at
LAST_T, LAST_U = 0, 1

FilterArrays = namedtuple("FilterArrays", [
    "x",          # (NOMINAL.n,) nominal state, in place
    "P",          # (n_max, n_max) covariance of the formulation's own state, in place
    "last",       # (1 + m,) the time and the input row the state currently sits at
    "t",          # (N,) sample stamps, s
    "u",          # (N, m) input rows (IMU: f_b, w_b; odometer + gyro: v, w_b)
    "prm",        # the formulation's parameter record (named indices in its module)
    "gap",        # (4,) gap threshold (s), the white-noise variance scale of a gap, and the variances of the
                  # unknown turn rate and acceleration a gap hid (rad^2/s^2, m^2/s^4)
    "aux",        # formulation scratch (e.g. the nominal filter's quaternion sign reference)
    "cidx",       # (15,) own index of each canonical core state, -1 where the map is not the identity
    "rec_x",      # (N, NOMINAL.n) recorded nominal states
    "rec_Pdiag",  # (N, 15) recorded canonical variances (replay's output takes their square roots in place)
    "rec_Ppt",    # (N, 21) recorded covariance of [dp, dtheta], packed (layout.PACKED)
])

_LOOP = '''
def {name}(a, n, k, t_target, cov):
    N = a.t.shape[0]
    u0 = a.last[{u}:].copy()
    t0 = a.last[{t}]
    while k < N and a.t[k] <= t_target:
        dt = a.t[k] - t0
        # a gap is a long interval between two samples, however an observation splits it
        is_gap = k > 0 and a.t[k] - a.t[k - 1] > a.gap[0]
        qscale = a.gap[1] if is_gap else 1.0
        if dt > 0.0:
            _step(a.x, a.P, n, u0, a.u[k], dt, qscale, a.prm, a.aux, cov)
            if cov and is_gap:        # (not 'qscale != 1': imu.gap_noise_scale=1 switched the motion off too)
                # the first sample after a gap: the motion the gap hid, an unknown turn rate and acceleration over
                # its T seconds, added to the attitude and velocity ((rate T)^2, (accel T)^2), where the formulation's
                # blocks are the canonical ones. Here, not spread over the gap: inside it the inputs are interpolated,
                # not measured, and fixes there would correct the attitude against a made-up motion (measured)
                _gap_motion(a.P, a.x, a.cidx, a.gap, a.t[k] - a.t[k - 1])
        t0 = a.t[k]
        u0 = a.u[k]                 # a view: the inputs are never written
        a.rec_x[k, :] = a.x
        if cov:
            _record_cov(a.P, n, a.x, a.aux, a.cidx, a.rec_Pdiag[k], a.rec_Ppt[k])
        k += 1
    if t_target > t0 and k < N:
        frac = (t_target - t0) / (a.t[k] - t0)
        u1 = u0 + frac * (a.u[k] - u0)
        qscale = a.gap[1] if (k > 0 and a.t[k] - a.t[k - 1] > a.gap[0]) else 1.0
        _step(a.x, a.P, n, u0, u1, t_target - t0, qscale, a.prm, a.aux, cov)
        t0 = t_target
        u0 = u1
    a.last[{t}] = t0
    a.last[{u}:] = u0
    return k
'''
_TH, _V = CANONICAL.start("TH"), CANONICAL.start("V")


@njit(cache=True)
def add_gap_motion(P, x, cidx, gap, gap_s):
    """The motion an IMU gap of ``gap_s`` hid, added to the covariance ``P`` at its end: ``(gap[2] gap_s^2)`` to each
    axis of the attitude's variance and ``(gap[3] gap_s^2)`` to the velocity's (``gap``: :func:`fusion_eval.filters.
    formulations.base.gap_of`), for a formulation whose attitude and velocity blocks are the canonical ones
    (``cidx``; ``x``, the nominal state, unused here). A formulation with other coordinates (the invariant error, a
    quaternion) supplies its own (``FilterBase._gap_motion``), mapping the same canonical variances into them; the
    filter's loop and both smoother paths call the formulation's."""
    for i in range(3):
        j = cidx[_TH + i]
        if j >= 0:
            P[j, j] += gap[2] * gap_s * gap_s
        j = cidx[_V + i]
        if j >= 0:
            P[j, j] += gap[3] * gap_s * gap_s


def compiled_loop(module_name: str, step, record_cov, gap_motion=add_gap_motion):
    """``predict_to(arrays, n, k_next, t_target, cov) -> k_next`` for one formulation.

    Propagates through every sample ``k_next, k_next + 1, ...`` with a stamp ``<= t_target``, recording
    the state at each, then to ``t_target`` itself (the input interpolated linearly there, and ``last``
    set to that interpolated input). ``cov`` False propagates the state alone (dead reckoning).
    ``gap_motion``: the formulation's :func:`add_gap_motion` (its own when its coordinates are not the canonical
    ones). The copy is compiled from a file of its own (:func:`fusion_eval.codegen.build`), named by the template and
    the sources it can reach, so a change of either invalidates every cached copy.
    """
    name = "_predict_to"
    ns = {"_step": step, "_record_cov": record_cov, "_gap_motion": gap_motion, "np": np, "__name__": module_name}
    fn = codegen.build(module_name, name, _LOOP.format(name=name, t=LAST_T, u=LAST_U), ns)[name]
    fn.__qualname__ = name
    return njit(cache=True)(fn)


_PT = CANONICAL.index(*POSE_BLOCKS)


@njit(cache=True)
def record_pose_cov(C, ppt_out):
    """The [dp, dtheta] block of a canonical covariance ``C`` into a record row, packed (:data:`PACKED`)."""
    for a in range(_PT.shape[0]):
        for b in range(a, _PT.shape[0]):
            ppt_out[PACKED[a, b]] = C[_PT[a], _PT[b]]


@njit(cache=True)
def record_cov_by_index(P, n, x, aux, cidx, diag_out, ppt_out):
    """The canonical covariance of a formulation whose blocks equal canonical ones (``cidx``); states
    it does not have are NaN."""
    for i in range(cidx.shape[0]):
        j = cidx[i]
        diag_out[i] = P[j, j] if j >= 0 else np.nan
    for a in range(_PT.shape[0]):
        ia = cidx[_PT[a]]
        for b in range(a, _PT.shape[0]):
            ib = cidx[_PT[b]]
            ppt_out[PACKED[a, b]] = P[ia, ib] if (ia >= 0 and ib >= 0) else np.nan


def new_arrays(x: np.ndarray, P: np.ndarray, t: np.ndarray, u: np.ndarray, k0: int, prm: np.ndarray, gap: np.ndarray,
               aux: np.ndarray, cidx: np.ndarray, record: bool = True) -> FilterArrays:
    """The record of one filter run, sitting at sample ``k0`` (the recording arrays NaN until written)."""
    N = t.size
    rows = N if record else 1
    return FilterArrays(x=x, P=P, last=np.concatenate([[t[k0]], u[k0]]), t=t, u=u, prm=prm, gap=gap, aux=aux, cidx=cidx,
                        rec_x=np.full((N, x.size), np.nan), rec_Pdiag=np.full((rows, CANONICAL.n_core), np.nan),
                        rec_Ppt=np.full((rows, POSE_PACKED_N), np.nan))
