"""What the forward pass keeps for the backward (RTS) pass: the filter at each observation epoch, and the
joint state before each stochastic clone.

The forward filter is recorded only where something other than the IMU happens: at each event stamp (after
every update and clone at that stamp), at the start and at the end. Between two such epochs the state and
covariance are a deterministic function of the first epoch's posterior and the IMU inputs, so the backward
pass recomputes them with the formulation's own compiled step (:mod:`fusion_eval.smoothing.rts`) instead of
storing every IMU sample: memory grows with the number of lidar/GNSS epochs, not with the IMU rate.

Per epoch: the nominal vector, the clone's nominal pose, the formulation's scratch (``aux``), the input row
the filter sits at, the next sample index and the covariance ``P[:n, :n]`` (upper triangle). A clone adds a
second such record, taken just before the clone replaces the previous one: the joint covariance of the current
state and the old clone, from which the backward pass recovers the old clone given the smoothed state
(``docs/rts_smoother.md``). With the 21-state ESKF that is 2,200 bytes per epoch and as much per lidar frame
(:meth:`EpochRecord.bytes_per_epoch`); with ``priors``, each epoch's prior covariance and the transition into it too
(1,850 + 1,800 bytes more).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..filters.propagate import LAST_T, LAST_U


@njit(cache=True)
def epoch_index(ep_t, size, t):
    """The epoch a record at ``t`` belongs to: the last one when it has the same stamp, else a new one."""
    return size - 1 if size > 0 and abs(ep_t[size - 1] - t) < 1e-12 else size


@njit(cache=True)
def store_row(a, k_next, n, xc, n_max, i, s_t, s_k, s_n, s_x, s_c, s_aux, s_u, s_P):
    """Row ``i`` of a store: the filter ``a`` (its :class:`FilterArrays`) with its next sample, state size and clone;
    the covariance's leading ``n x n`` block as the upper triangle of an ``n_max x n_max`` one. The Python record and
    the compiled event loop both write through it."""
    s_t[i] = a.last[LAST_T]
    s_k[i] = k_next
    s_n[i] = n
    _copy(a.x, s_x[i], a.x.shape[0])
    _copy(xc, s_c[i], xc.shape[0])
    _copy(a.aux, s_aux[i], s_aux.shape[1])        # the formulation's own scratch (not the transition room)
    _copy(a.last[LAST_U:], s_u[i], s_u.shape[1])
    pack_upper(a.P, n, n_max, s_P[i])


@njit(cache=True)
def _copy(src, dst, m):
    for q in range(m):
        dst[q] = src[q]


@njit(cache=True)
def pack_upper(P, n, n_max, out):
    """The leading ``n x n`` block of ``P`` as the upper triangle of an ``n_max x n_max`` one, row by row, zero
    beyond ``n`` (:func:`fusion_eval.smoothing.kernels.unpack_upper` reads it back). Branch-free inner loops over
    rows: at 21 states a test per entry cost more than the copy (1.2-2.7 us per record before, measured)."""
    q = 0
    for p in range(n_max):
        if p < n:
            for c in range(p, n):
                out[q] = P[p, c]
                q += 1
            for c in range(n, n_max):
                out[q] = 0.0
                q += 1
        else:
            for c in range(p, n_max):
                out[q] = 0.0
                q += 1



@njit(cache=True)
def store_prior(P, n, n_max, ep_t, size, t, pr_P, pr_ok, aux, pr_phi):
    """The covariance just predicted to ``t``, before anything happens at ``t``: the prior of the epoch that ``t``
    opens (a new stamp only), and the transition of the step into it (what the formulation's step left at the end
    of its scratch, ``FilterBase.keeps_transition``), kept so that the backward pass need recompute neither. The
    room is refilled with NaN: the next epoch's must be written by the steps into it."""
    i = epoch_index(ep_t, size, t)
    if i != size or i >= pr_ok.shape[0] or pr_ok[i]:       # not a new stamp, or no priors kept (see EpochRecord)
        return
    pack_upper(P, n, n_max, pr_P[i])
    m = pr_phi.shape[1]
    off = aux.shape[0] - m
    row = pr_phi[i]
    for q in range(m):
        row[q] = aux[off + q]
        aux[off + q] = np.nan
    pr_ok[i] = True


class _Store:
    """Preallocated rows of one kind of record (capacity known before the replay: one per event, plus two)."""

    def __init__(self, capacity: int, n_max: int, n_x: int, n_c: int, n_aux: int, n_u: int):
        self.n_max = n_max
        self.t = np.zeros(capacity)
        self.k_next = np.zeros(capacity, np.int64)
        self.n = np.zeros(capacity, np.int64)
        self.x = np.zeros((capacity, n_x))
        self.c = np.zeros((capacity, n_c))
        self.aux = np.zeros((capacity, n_aux))
        self.u = np.zeros((capacity, n_u))
        self.P = np.zeros((capacity, n_max * (n_max + 1) // 2))      # upper triangles
        self.size = 0

    def put(self, i: int, kf) -> None:
        store_row(kf.arrays, kf.k_next, kf.n, kf.clone.vec, self.n_max, i, self.t, self.k_next, self.n, self.x, self.c,
                  self.aux, self.u, self.P)

    def bytes_per_row(self) -> int:
        return int(sum(a[:1].nbytes for a in (self.t, self.k_next, self.n, self.x, self.c, self.aux, self.u, self.P)))


class EpochRecord:
    """The forward pass's record for the RTS smoother; attach it to a filter (``kf.recorder``) before the replay."""

    def __init__(self, kf, n_events: int, priors: bool = False):
        shape = (kf.layout.n, kf.xv.size, kf.clone.vec.size, kf.aux.size, kf.arrays.last.size - LAST_U)
        self.epochs = _Store(n_events + 2, *shape)
        self.clones = _Store(n_events + 1, *shape)
        self.clone_epoch = np.zeros(n_events + 1, np.int64)    # the epoch each clone record belongs to
        # each epoch's prior covariance (upper triangle) and the transition of the step into it, where the replay
        # kept them: with ``priors`` (where an interval's covariance is dear to recompute, as Van Loan's at 10 Hz), the
        # backward pass steps into an epoch with neither recomputed; +1,850 + 1,800 bytes per epoch with the 21-state
        # ESKF. The formulation's step writes the transition into room after its scratch (reserved here)
        n_max, rows, nc = kf.layout.n, (n_events + 2 if priors else 0), kf.layout.n_core
        self.prior_P = np.zeros((max(rows, 1), n_max * (n_max + 1) // 2))     # a row to index even when unused
        self.prior_phi = np.zeros((max(rows, 1), nc * nc))
        self.prior_ok = np.zeros(rows, np.bool_)
        if priors:
            kf.reserve_transition()

    def _epoch_index(self, t: float) -> int:
        return int(epoch_index(self.epochs.t, self.epochs.size, t))

    def epoch(self, kf) -> None:
        """Record the filter after everything that happened at its current stamp (one epoch per stamp)."""
        i = self._epoch_index(kf.t)
        self.epochs.put(i, kf)
        self.epochs.size = i + 1

    def prior(self, kf) -> None:
        """Record the covariance just predicted to the filter's stamp, before any update there (a new stamp only)."""
        store_prior(kf.arrays.P, kf.n, self.epochs.n_max, self.epochs.t, self.epochs.size, kf.t, self.prior_P,
                    self.prior_ok, kf.arrays.aux, self.prior_phi)

    def before_clone(self, kf) -> None:
        """Record the joint state of the filter and its old clone, just before a new clone replaces it."""
        c = self.clones
        self.clone_epoch[c.size] = self._epoch_index(kf.t)
        c.put(c.size, kf)
        c.size += 1

    def bytes_per_epoch(self) -> int:
        return self.epochs.bytes_per_row() + (self.prior_P[:1].nbytes + self.prior_phi[:1].nbytes + 1
                                              if self.prior_ok.size else 0)

    def nbytes(self) -> int:
        return self.bytes_per_epoch() * self.epochs.size + self.clones.bytes_per_row() * self.clones.size


__all__ = ["EpochRecord"]
