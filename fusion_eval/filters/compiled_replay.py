"""The replay's event loop in compiled code: prediction to each event, the observation's model, the gated
Joseph update, injection and reset, adaptive noise, cloning and recording, for a chunk of events per call.

It runs when the formulation declares a compiled injection (``FilterBase.compiled_inject``, with its error
state the canonical one, ``D = I``) and every enabled observation binds a compiled kernel
(``Bound.kernel``), with no iterated update and no batch smoother (an RTS smoother's forward record, the epochs
and the states before each clone, is kept by the loop itself); otherwise :func:`fusion_eval.replay.replay`
steps the events from Python (``filter.replay: python`` forces that path). Both paths run the same models
(each observation's Python model is its kernel) and the same kernels for propagation and update, and give
the same estimate (``tests/test_compiled_replay.py``: 1e-9 m).

Numba cannot hold a list of different compiled functions, so the loop is generated from a template for each
formulation and set of observation kernels, dispatching on the event's kind; the copy is cached beside the
formulation's module under a name carrying the digest of the template and of every kernel's source (numba's
cache would not see a change in a function the loop calls).
"""

from __future__ import annotations

import sys

import numpy as np
from numba import njit

from .. import codegen
from ..errors import FilterDivergedError
from .layout import CLONE
from . import linalg
from .linalg import joseph_update_into
from ..smoothing.record import epoch_index, store_prior, store_row
from .observations.base import M_MAX, N_MAX, matched_variance

OK, BAD_RESIDUAL, BAD_CORRECTION, BAD_STATE = 0, 1, 2, 3
MESSAGES = {BAD_RESIDUAL: "non-finite residual", BAD_CORRECTION: "non-finite correction",
            BAD_STATE: "non-finite state or negative variance after an update"}
# st: the loop's integer state
ST_N, ST_K, ST_CLONED = 0, 1, 2
CHUNK_EVENTS = 2000      # not a state index: events per compiled call (a call costs tens of microseconds)
CLONE_P, CLONE_R = CLONE.start("p"), CLONE.start("R")

_LOOP = '''
def {name}(a, st, xc, clone_t, times, kinds, index, j0, j1, gates, clone_after, n_core, clone_rows, xp, xr,
           ad_nb, ad_blocks, ad_rate, ad_var, ad_hist, ad_count, nis_out, ok_out, ld_out, H, r, Rm, wn, wm, dx, cols,
           rec_on, rst, n_max, ep_t, ep_k, ep_n, ep_x, ep_c, ep_aux, ep_u, ep_P, cl_t, cl_k, cl_n, cl_x, cl_c, cl_aux,
           cl_u, cl_P, clone_epoch, pr_P, pr_ok, pr_phi, {datas}):
    m_last = H.shape[0]                   # (a chunk's first kernel: every row)
    for j in range(j0, j1):
        t = times[j]
        kind = kinds[j]
        i = index[j]
        n = st[{st_n}]
        st[{st_k}] = _predict(a, n, st[{st_k}], max(t, a.last[0]), np.bool_(True))   # plain bool: propagate's note
        if rec_on:                # the smoother's record of the prior of the epoch this stamp opens
            store_prior(a.P, n, n_max, ep_t, rst[0], a.last[0], pr_P, pr_ok, a.aux, pr_phi)
        # every kernel starts from zeros, as each Python call does (kernel_model): one that writes only its non-zero
        # entries would otherwise inherit the last event's, a silent difference between the two paths (an extension
        # author's review: 2.81 m against 3.19); the rows the last kernel wrote are the only ones not zero
        H[:m_last, :] = 0.0
        r[:m_last] = 0.0
        Rm[:m_last, :m_last] = 0.0
{dispatch}
        m_last = max(m, 0)
        nis_out[j] = np.nan
        if m > 0:
            nb = ad_nb[kind]
            for b in range(nb):
                for p in range(ad_blocks[kind, b, 0], ad_blocks[kind, b, 1]):
                    for q in range(ad_blocks[kind, b, 0], ad_blocks[kind, b, 1]):
                        Rm[p, q] *= ad_var[kind, b]
            for p in range(m):
                if not np.isfinite(r[p]):
                    return {bad_residual}, j
                for q in range(m):
                    if not np.isfinite(Rm[p, q]):
                        return {bad_residual}, j
            nis, ok = joseph_update_into(a.P, n, H, m, r, Rm, gates[kind], wn, wm, dx, cols)
            if not np.isfinite(nis):
                return {bad_correction}, j
            for d in range(n):
                if not np.isfinite(dx[d]):
                    return {bad_correction}, j
            nis_out[j] = nis
            ok_out[j] = ok
            ld = 0.0                # log det S from its Cholesky factor (left in wm[1]): the innovation likelihood
            for p in range(m):
                ld += 2.0 * np.log(wm[1][p, p])
            ld_out[j] = ld
            if ok:
                _inject(a.x, xc, a.P, n, dx[:n])
                good = True
                for d in range(n):
                    v = a.P[d, d]
                    if not (np.isfinite(v) and v >= 0.0):
                        good = False
                for d in range(3):
                    if not np.isfinite(a.x[xp + d]):
                        good = False
                if not good:
                    return {bad_state}, j
                k = st[{st_k}]
                if k > 0 and abs(a.t[k - 1] - a.last[0]) < 1e-9:      # the state sits on a sample: record it
                    a.rec_x[k - 1, :] = a.x
                    _record_cov(a.P, n, a.x, a.aux, a.cidx, a.rec_Pdiag[k - 1], a.rec_Ppt[k - 1])
                if nb > 0:        # covariance matching toward E[r_b^T S_bb^-1 r_b / dim] = 1, as AdaptiveScale
                    S = wm[0]     # the innovation covariance, before the update
                    for b in range(nb):
                        lo, hi = ad_blocks[kind, b, 0], ad_blocks[kind, b, 1]
                        qb = block_nis(S, lo, hi, r, wm[2], dx) / (hi - lo)     # dx is free after the injection
                        ad_var[kind, b] = matched_variance(ad_var[kind, b], qb, ad_rate[kind])
                    c = ad_count[kind]
                    ad_hist[kind, c, 0] = a.last[0]
                    ad_hist[kind, c, 1] = ad_var[kind, 0]
                    ad_hist[kind, c, 2] = ad_var[kind, 1]
                    ad_count[kind] = c + 1
        if clone_after[kind]:     # stochastic cloning
            if rec_on:            # the smoother's record of the joint state before the clone is replaced
                clone_epoch[rst[1]] = epoch_index(ep_t, rst[0], a.last[0])
                store_row(a, st[{st_k}], n, xc, n_max, rst[1], cl_t, cl_k, cl_n, cl_x, cl_c, cl_aux, cl_u, cl_P)
                rst[1] += 1
            mc = clone_covariance(a.P, n_core, clone_rows)
            for d in range(3):
                xc[{clone_p} + d] = a.x[xp + d]
            for d in range(9):
                xc[{clone_r} + d] = a.x[xr + d]
            st[{st_n}] = n_core + mc
            st[{st_cloned}] = 1
            clone_t[0] = a.last[0]
        # the smoother's epoch: the filter after everything at this stamp, written once, after its last event (lidar,
        # GNSS and the constraint share stamps: each event rewrote the row before); a chunk's last event writes it
        # too, which the next chunk's events at that stamp rewrite
        if rec_on and (j + 1 >= j1 or times[j + 1] != t):
            i = epoch_index(ep_t, rst[0], a.last[0])
            store_row(a, st[{st_k}], st[{st_n}], xc, n_max, i, ep_t, ep_k, ep_n, ep_x, ep_c, ep_aux, ep_u, ep_P)
            rst[0] = i + 1
    return {ok}, j1
'''




_CACHE: dict = {}


def compiled_loop(formulation):
    """The event loop of a formulation class, dispatching on every registered observation kernel
    (:data:`fusion_eval.filters.observations.KERNELS`): one compiled loop per formulation, whichever
    observations a run enables."""
    from .observations import KERNELS

    if formulation in _CACHE:
        return _CACHE[formulation]
    mod = sys.modules[formulation._predict.py_func.__module__]
    name = "_replay"          # its file is named by the template and every source it can reach (codegen.build)
    dispatch = "\n".join(f"        {'if' if c == 0 else 'elif'} kind == {c}:\n            m = _k{c}(a.x, xc, d{c}[i], H, r, Rm)"
                         for c in range(len(KERNELS)))
    dispatch += "\n        else:\n            m = 0"
    src = _LOOP.format(name=name, datas=", ".join(f"d{c}" for c in range(len(KERNELS))), dispatch=dispatch,
                       st_n=ST_N, st_k=ST_K, st_cloned=ST_CLONED, clone_p=CLONE_P, clone_r=CLONE_R, ok=OK,
                       bad_residual=BAD_RESIDUAL, bad_correction=BAD_CORRECTION, bad_state=BAD_STATE)
    ns = {"np": np, "_predict": formulation._predict, "_inject": formulation._inject_kernel,
          "_record_cov": formulation._record_cov, "joseph_update_into": joseph_update_into, "block_nis": linalg.block_nis, "clone_covariance": linalg.clone_covariance,
          "matched_variance": matched_variance, "epoch_index": epoch_index, "store_row": store_row, "store_prior": store_prior,
          "__name__": mod.__name__}
    ns.update({f"_k{c}": k for c, k in enumerate(KERNELS)})
    fn = codegen.build(mod.__name__, name, src, ns)[name]
    fn.__qualname__ = name
    _CACHE[formulation] = njit(cache=True)(fn)
    return _CACHE[formulation]


def usable(kf, bound, smoother, iterations: int, mode: str) -> bool:
    """Whether the compiled loop can run this replay (see the module docstring)."""
    from .observations import KERNELS

    # the RTS smoother's record is kept by the loop itself; the batch smoother collects factors from Python
    rts = smoother is not None and getattr(smoother, "name", None) == "rts" and kf.recorder is smoother.rec
    return (mode != "python" and getattr(kf, "_inject_kernel", None) is not None and (smoother is None or rts)
            and iterations <= 1 and (kf.recorder is None or rts) and bool(bound)
            and all(b.kernel is not None and b.kernel.fn in KERNELS for b in bound))


def run(kf, bound, times: np.ndarray, which: np.ndarray, index: np.ndarray, order: np.ndarray, progress=None,
        monitor=None):
    """Replay the events through ``kf`` in compiled chunks, in the order ``order``; returns each event's NIS
    and acceptance in that order (NIS NaN where an event updated nothing), and writes the adapted noise
    back to each observation's state. ``monitor(j, nis, logdet_S, dof)``, called after each chunk with the first
    ``j`` events' records (views) and every event's dof, may raise to stop the replay (a tune's pruning)."""
    from .layout import NOMINAL
    from .observations import KERNELS

    loop = compiled_loop(type(kf))
    nk = len(KERNELS)
    slot = np.array([KERNELS.index(b.kernel.fn) for b in bound], np.int64)    # bound position -> kernel slot
    ts, kinds, idx = (np.ascontiguousarray(v[order]) for v in (times.astype(float), slot[which.astype(np.int64)],
                                                                   index.astype(np.int64)))
    n_ev = ts.size
    st = np.array([kf.n, kf.k_next, int(kf.cloned)], np.int64)
    clone_t = np.array([np.nan if kf.clone_t is None else kf.clone_t])
    gates, clone_after, ad_rate = np.full(nk, np.inf), np.zeros(nk, np.bool_), np.zeros(nk)
    ad_nb, ad_blocks, ad_var = np.zeros(nk, np.int64), np.zeros((nk, 2, 2), np.int64), np.ones((nk, 2))
    datas = [np.zeros((0, 1)) for _ in range(nk)]
    for b, c in zip(bound, slot):
        gates[c], clone_after[c], ad_rate[c] = b.gate, b.kernel.clone_after, b.kernel.adapt_rate
        ad_nb[c] = len(b.kernel.adapt_blocks)
        for q, (lo, hi) in enumerate(b.kernel.adapt_blocks):
            ad_blocks[c, q] = lo, hi
        if b.adapt is not None:
            ad_var[c] = b.adapt.var
        datas[c] = np.ascontiguousarray(b.kernel.data, float)
    ad_hist = np.zeros((nk, max((b.t_s.size for b in bound), default=0), 3))
    ad_count = np.zeros(nk, np.int64)
    nis_out, ok_out, ld_out = np.full(n_ev, np.nan), np.zeros(n_ev, np.bool_), np.full(n_ev, np.nan)
    H, r, Rm = np.zeros((M_MAX, N_MAX)), np.zeros(M_MAX), np.zeros((M_MAX, M_MAX))
    wn, wm, dx, cols = linalg.workspace(N_MAX, M_MAX)
    clone_rows = np.ascontiguousarray(kf.layout.clone_rows(), np.int64)
    # chunks of events: progress, and a Ctrl-C that numba's loop cannot see is taken between them
    chunk = max(1, min(CHUNK_EVENTS, n_ev // 50 if progress is not None or monitor is not None else CHUNK_EVENTS))
    if monitor is not None:
        dof_slot = np.zeros(nk)
        for b, c in zip(bound, slot):
            dof_slot[c] = b.dof
        dof_ev = dof_slot[kinds]
    rec = kf.recorder
    if rec is not None:               # an RTS smoother's record, kept by the loop (EpochRecord.epoch / before_clone)
        rst = np.array([rec.epochs.size, rec.clones.size], np.int64)
        ep, cl = rec.epochs, rec.clones
        stores = (ep.t, ep.k_next, ep.n, ep.x, ep.c, ep.aux, ep.u, ep.P, cl.t, cl.k_next, cl.n, cl.x, cl.c, cl.aux, cl.u,
                  cl.P, rec.clone_epoch, rec.prior_P, rec.prior_ok, rec.prior_phi)
        n_max = ep.n_max
    else:
        rst, n_max = np.zeros(2, np.int64), 0
        f1, i1, f2 = np.zeros(1), np.zeros(1, np.int64), np.zeros((1, 1))
        stores = (f1, i1, i1, f2, f2, f2, f2, f2, f1, i1, i1, f2, f2, f2, f2, f2, i1, f2, np.zeros(1, np.bool_), f2)
    j = 0
    try:
        while j < n_ev:
            status, j_stop = loop(kf.arrays, st, kf.clone.vec, clone_t, ts, kinds, idx, j, min(n_ev, j + chunk), gates,
                                  clone_after, kf.layout.n_core, clone_rows, NOMINAL.start("p"), NOMINAL.start("R"),
                                  ad_nb, ad_blocks, ad_rate, ad_var, ad_hist, ad_count, nis_out, ok_out, ld_out, H, r, Rm,
                                  wn, wm, dx, cols, rec is not None, rst, n_max, *stores, *datas)
            _sync(kf, st, clone_t)
            if rec is not None:
                rec.epochs.size, rec.clones.size = int(rst[0]), int(rst[1])
            if status != OK:
                # which observation's update, so that a stream with corrupted values is named (GNSS thousands of
                # km off once diverged with no word on the cause)
                b = bound[int(which[order[j_stop]])] if 0 <= j_stop < n_ev else None
                what = MESSAGES[status] + (f" (update {int(idx[j_stop]) + 1} of the {b.name} stream)" if b is not None else "")
                raise FilterDivergedError(f"filter diverged at t={kf.t:.3f} s: {what}")
            j = j_stop
            if progress is not None:
                progress(j / n_ev)
            if monitor is not None:
                monitor(j, nis_out[:j], ld_out[:j], dof_ev)
    except np.linalg.LinAlgError as exc:
        _sync(kf, st, clone_t)
        raise FilterDivergedError(f"filter diverged at t={kf.t:.3f} s: innovation covariance not invertible ({exc})") \
            from None
    for b, c in zip(bound, slot):
        if b.adapt is not None:
            b.adapt.var[:] = ad_var[c]
            if ad_count[c]:                 # one (k, 3) block; none when no update was accepted
                b.adapt.history.append(ad_hist[c, :ad_count[c]].copy())
    return nis_out, ok_out, ld_out


def _sync(kf, st, clone_t) -> None:
    """The Python side of the filter after a compiled chunk (the arrays are shared)."""
    kf.n, kf.k_next, kf.cloned = int(st[ST_N]), int(st[ST_K]), bool(st[ST_CLONED])
    kf.clone_t = None if np.isnan(clone_t[0]) else float(clone_t[0])
