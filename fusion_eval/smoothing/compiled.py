"""The RTS backward pass in one compiled call: each interval between two recorded epochs, and the clones undone.

Between two epochs (lidar/GNSS stamps) the filter only predicts. The backward pass recomputes those IMU
intervals with the formulation's own step (the transition of each from an augmented covariance, as in
:meth:`fusion_eval.smoothing.rts.RTS.segment`) and walks them backwards: the correction, the gain in its plain or
clone-conditional form, the injection on the manifold, the record at each IMU sample. Every point of an interval is
smoothed from the interval's end at once (the gains of IMU-only steps multiply out), so the end's prior is factored
once per interval rather than once per sample; the Python path steps sample by sample (the textbook recursion) and
is the oracle of this one: the same estimate to rounding. Stepped from Python an interval costs ~50-100 us in calls
and small arrays, more than the filter's own replay at 100 Hz; here the whole pass is one call. Like the filter's
loop (:mod:`fusion_eval.filters.propagate`), the function is written once as source and instantiated with each
formulation's step, ``[-]``, ``[+]`` and covariance record, for the formulations that have them compiled
(``_rts_boxminus``/``_rts_boxplus``: the ESKF and the right-invariant EKF); the others keep the Python path.
"""

from __future__ import annotations

import sys

import numpy as np
from numba import njit

from .. import codegen
from . import kernels

_SEGMENT = '''
def {name}(x_a, aux, c, P_a, n, nc, t, u, gap, prm, k, t0, u0, t_b, xs_x, xs_c, Ps, rcond, cidx,
           out_x, out_Pdiag, out_Ppt, pr_row, pr_has, n_max, phi_row):
    N = t.shape[0]
    kb = k
    while kb < N and t[kb] <= t_b:
        kb += 1
    m = kb - k + 2                                # points: the epoch, every sample, the partial step to t_b
    X = np.empty((m, x_a.shape[0]))
    A = np.empty((m, nc, nc))
    PH = np.empty((m, nc, nc))
    KJ = np.full(m, -1, np.int64)
    nb = n - nc
    B = np.empty((m, nc, nb))
    x = x_a.copy()
    X[0] = x
    if nb > 0:
        A0, B0, Dinv = _condition(P_a, nc, rcond)
        D = np.ascontiguousarray(P_a[nc:, nc:])
        A[0] = A0
        B[0] = B0
    else:
        A[0] = P_a
        Dinv = np.zeros((0, 0))
        D = np.zeros((0, 0))
    P_end = P_a                                   # the joint prior at the interval's end, where the record kept it
    j = 0
    j_kept = -1
    uu0 = u0.copy()
    while k < N:
        if t[k] <= t_b:                           # up to the next sample
            dt, u1, ks = t[k] - t0, u[k], k
        elif t_b > t0:                            # the partial step to t_b, the input interpolated there
            dt, ks = t_b - t0, -1
            u1 = uu0 + (t_b - t0) / (t[k] - t0) * (u[k] - uu0)
        else:
            break
        if dt > 0.0:
            is_gap = k > 0 and t[k] - t[k - 1] > gap[0]
            qs = gap[1] if is_gap else 1.0
            if pr_has and (ks < 0 or t[k] == t_b):
                # the step into epoch b, whose prior and transition the forward pass kept: only the state
                PH[j] = phi_row.reshape((nc, nc))
                _step(x, A[j], 0, uu0, u1, dt, qs, prm, aux, np.bool_(False))  # plain bool: propagate's note
                j += 1
                P_end = _unpack(pr_row, n_max, n)
                j_kept = j
                X[j] = x
                if nb > 0:
                    Ac, Bp = _condition_given(P_end, nc, Dinv)
                    A[j] = Ac
                    B[j] = Bp
                else:
                    A[j] = P_end
            else:
                Pa = _augmented(A[j], nc)
                _step(x, Pa, 2 * nc, uu0, u1, dt, qs, prm, aux, np.bool_(True))
                if ks >= 0 and is_gap:                    # the motion a gap hid, where the forward
                    # loop added it (by the interval, as it does: not 'qs != 1', false with imu.gap_noise_scale=1)
                    _gap_motion(Pa, x, cidx, gap, t[k] - t[k - 1])
                j += 1
                A[j] = Pa[:nc, :nc]
                PH[j - 1] = Pa[:nc, nc:]
                X[j] = x
                if nb > 0:
                    B[j] = np.ascontiguousarray(PH[j - 1]) @ B[j - 1]
        KJ[j] = ks                                # the epoch itself may sit on sample k (dt = 0)
        if ks < 0:
            break
        t0 = t[k]
        uu0 = u[k].copy()
        k += 1
    xs = xs_x.copy()
    cs = xs_c.copy()
    P = Ps.copy()
    if j == 0:
        return xs, cs, P
    # Only the IMU acts inside the interval, so the gains of its steps multiply out: every point i is smoothed
    # from the end j directly (C = P_i Phi(j,i)^T (P_j^-)^-1), with one factorisation of the end's prior for the
    # whole interval and Phi(j,i) accumulated backward (docs/rts_smoother.md, section 3)
    if j_kept != j:
        P_end = _assemble(np.ascontiguousarray(A[j]), np.ascontiguousarray(B[j]), D, Dinv) if nb > 0 else A[j].copy()
    e = _boxminus(xs, cs, X[j], c, n)
    dP = P - P_end
    BD_end = np.ascontiguousarray(B[j]) @ Dinv if nb > 0 else np.zeros((nc, 0))
    # a single step (a 10 Hz IMU with an update at every sample): S^-1 (Phi A) by substitution; a longer interval
    # accumulates M = S^-1 Phi(j, i) from S's inverse, one product per point
    M = np.zeros((0, 0)) if j == 1 else _pinv(np.ascontiguousarray(A[j]), rcond)
    for i in range(j - 1, -1, -1):
        Ai = np.ascontiguousarray(A[i])
        if j == 1:
            G = _gain_t(np.ascontiguousarray(A[1]), np.ascontiguousarray(PH[0]), Ai, rcond)
        else:
            M = M @ np.ascontiguousarray(PH[i])
            G = M @ Ai
        if nb > 0:
            Pi = P_a if i == 0 else _assemble(Ai, np.ascontiguousarray(B[i]), D, Dinv)
            d, P = _interval_clone(G, np.ascontiguousarray(B[i]), Dinv, BD_end, e, dP, Pi)
        else:
            d, P = _interval_plain(G, Ai, e, dP)
        _boxplus(xs, cs, X[i], c, d, n)
        if i > 0 and KJ[i] >= 0:
            out_x[KJ[i], :] = xs
            _record_cov(P, n, xs, aux, cidx, out_Pdiag[KJ[i]], out_Ppt[KJ[i]])
    return xs, cs, P


def {name_pass}(ep_t, ep_k, ep_n, ep_x, ep_c, ep_aux, ep_u, ep_P, n_ep, cl_n, cl_x, cl_c, cl_P, clone_epoch, n_cl,
                n_max, nc, t, u, gap, prm, rcond, cidx, out_x, out_Pdiag, out_Ppt, pr_P, pr_ok, pr_phi):
    N = t.shape[0]
    last = n_ep - 1
    xs = ep_x[last].copy()
    cs = ep_c[last].copy()
    P = _unpack(ep_P[last], n_max, ep_n[last])
    ci = n_cl - 1
    for b in range(last, -1, -1):
        k = ep_k[b] - 1                               # the sample epoch b sits on, if any
        if 0 <= k < N and abs(t[k] - ep_t[b]) < 1e-9:
            out_x[k, :] = xs
            _record_cov(P, P.shape[0], xs, ep_aux[b], cidx, out_Pdiag[k], out_Ppt[k])
        if b == 0:
            break
        while ci >= 0 and clone_epoch[ci] > b:
            ci -= 1
        while ci >= 0 and clone_epoch[ci] == b:       # undo the clones taken at b, the last first
            Pt = _unpack(cl_P[ci], n_max, cl_n[ci])
            e = _boxminus(xs, cs, cl_x[ci], cl_c[ci], nc)
            d, P = _uncondition(Pt, nc, e, np.ascontiguousarray(P[:nc, :nc]), rcond)
            _boxplus(xs, cs, cl_x[ci], cl_c[ci], d, Pt.shape[0])
            ci -= 1
        a = b - 1
        xs, cs, P = {name}(ep_x[a].copy(), ep_aux[a].copy(), ep_c[a], _unpack(ep_P[a], n_max, ep_n[a]), P.shape[0], nc,
                           t, u, gap, prm, ep_k[a], ep_t[a], ep_u[a], ep_t[b], xs, cs, np.ascontiguousarray(P), rcond,
                           cidx, out_x, out_Pdiag, out_Ppt, pr_P[min(b, pr_P.shape[0] - 1)], b < pr_ok.shape[0] and pr_ok[b],
                           n_max, pr_phi[min(b, pr_phi.shape[0] - 1)])
'''


def compiled_pass(cls):
    """``backward_pass(...)`` for the formulation class ``cls``: the whole RTS backward pass over an
    :class:`~fusion_eval.smoothing.record.EpochRecord` (see :meth:`RTS.run`), or None when the formulation has no
    compiled ``[-]``/``[+]``; compiled into and cached beside the formulation's module."""
    if vars(cls).get("_rts_boxminus") is None:      # declared by the class itself: a subclass may derive state
        return None
    got = _CACHE.get(cls)
    if got is not None:
        return got
    mod = sys.modules[cls.__module__]
    calls = {"_step": cls._step, "_boxminus": cls._rts_boxminus, "_boxplus": cls._rts_boxplus,
             "_record_cov": cls._record_cov, "_condition": kernels.condition, "_augmented": kernels.augmented,
             "_assemble": kernels.assemble, "_interval_plain": kernels.interval_plain,
             "_interval_clone": kernels.interval_clone, "_pinv": kernels.pinv_sym, "_gain_t": kernels.gain_t,
             "_uncondition": kernels.uncondition, "_unpack": kernels.unpack_upper,
             "_condition_given": kernels.condition_given, "_gap_motion": cls._gap_motion}
    name, name_pass = "_rts_segment", "_rts_pass"    # the file is named by every source they reach (codegen.build)
    ns = {**calls, "np": np, "__name__": cls.__module__}
    codegen.build(mod.__name__, name_pass, _SEGMENT.format(name=name, name_pass=name_pass), ns)
    for nm in (name, name_pass):                       # the segment first: the pass calls it by its global name
        ns[nm].__qualname__ = nm
        ns[nm] = njit(cache=True)(ns[nm])
    _CACHE[cls] = ns[name_pass]
    return _CACHE[cls]


_CACHE: dict = {}
