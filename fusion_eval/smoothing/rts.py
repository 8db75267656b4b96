"""The Rauch-Tung-Striebel smoother over any registered formulation (``smoother.method: rts``).

Backward pass on the formulation's own error coordinates (derivation: ``docs/rts_smoother.md``). For an
interval ``j -> j+1`` with the filter's posterior ``x_j, P_j`` at ``j``, transition ``Phi_j`` and prior
``x_{j+1}^-, P_{j+1}^-``, and the smoothed ``x^s_{j+1}, P^s_{j+1}``::

    C_j     = P_j Phi_j^T (P_{j+1}^-)^-1
    x^s_j   = x_j [+] C_j (x^s_{j+1} [-] x_{j+1}^-)
    P^s_j   = P_j + C_j (P^s_{j+1} - P_{j+1}^-) C_j^T

``[+]`` and ``[-]`` are the formulation's own ``boxplus_from``/``boxminus`` (injection on the manifold: right
perturbation for the ESKF, the SE_2(3) exponential for the invariant filter; the nominal-state EKF is not smoothed,
see ``docs/rts_smoother.md``). Between two recorded epochs (:mod:`.record`) the intervals are recomputed with the
formulation's compiled step, which also yields ``Phi_j``: it propagates an augmented covariance whose extra rows
are a constant copy of the core state (the contract every step already keeps for a pose clone), so the cross
block becomes ``Phi_j`` with no formulation code written twice. A stochastic clone is undone in the backward
pass by conditioning the old clone on the smoothed current state (the clone is a copy of a past pose; later
data depend on it only through the current state).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..filters import propagate
from ..filters.propagate import LAST_U
from . import kernels
from .compiled import compiled_pass
from .record import EpochRecord


@dataclass
class Smoothed:
    """The smoothed record at the IMU samples ``k0 ..``: nominal vectors and canonical covariances (as the
    filter records them)."""

    rec_x: np.ndarray        # (N, NOMINAL.n)
    rec_Pdiag: np.ndarray    # (N, 15)
    rec_Ppt: np.ndarray      # (N, 21): the 6x6 of [dp, dtheta], packed (filters.layout.PACKED)


RCOND = 1e-10       # relative eigenvalue of a correlation matrix below which a direction is degenerate


def rts_step(P_j: np.ndarray, Phi_j: np.ndarray, P_prior: np.ndarray, e: np.ndarray, Ps_next: np.ndarray):
    """One backward step with a full transition ``Phi_j``: the correction ``C e`` to add to the posterior at j
    and the smoothed covariance there (also what the tracking filters use)."""
    return kernels.backward(np.ascontiguousarray(P_j, float), np.ascontiguousarray(Phi_j, float),
                            np.ascontiguousarray(P_prior, float), np.ascontiguousarray(e, float),
                            np.ascontiguousarray(Ps_next, float), RCOND)


class _Workspace:
    """The finished filter object, reused to evaluate its own ``[+]``/``[-]`` at recorded states."""

    def __init__(self, kf):
        self.kf = kf

    def load(self, x, c, aux, u, n) -> None:
        """Put a recorded state into the filter object (with the input row it sat at: a formulation may derive
        part of its state from it, as the odometer + gyro model derives the velocity)."""
        kf = self.kf
        kf.arrays.last[LAST_U:] = u
        kf.xv[:] = x
        kf.clone.vec[:] = c
        kf.aux[:aux.size] = aux
        kf.n = int(n)
        kf.cloned = kf.n > kf.layout.n_core

    def minus(self, a, b, n) -> np.ndarray:
        """``a [-] b`` over the first ``n`` own states; ``a``, ``b``: ``(x, clone, aux, input row)``."""
        self.load(*b, n)
        snap = self.kf.snapshot()
        self.load(*a, n)
        return self.kf.boxminus(snap)

    def plus(self, b, d, n):
        """``b [+] d`` as ``(x, clone, aux, input row)``."""
        self.load(*b, n)
        kf = self.kf
        kf.boxplus_from(kf.snapshot(), d)
        kf.after_correction_state()
        return kf.xv.copy(), kf.clone.vec.copy(), kf.aux.copy(), b[3]


class RTS:
    """The backward pass over a finished filter ``kf`` and its :class:`EpochRecord`."""

    def __init__(self, kf, rec: EpochRecord, python: bool = False):
        self.kf, self.rec = kf, rec
        self.python = python                # step each IMU interval from Python (the oracle of the compiled one)
        self.ws = _Workspace(kf)
        a = kf.arrays
        self.t, self.u, self.gap, self.prm = a.t, a.u, a.gap, a.prm
        self.nc = kf.layout.n_core

    # ---- the forward intervals between two epochs, recomputed ----------------------------------
    def _step(self, x, aux, A, u0, u1, dt, qscale, gap_s=0.0):
        """One interval with the formulation's compiled step on the covariance ``A`` of the core (a clone is
        constant, so it needs no propagation): the propagated ``A`` and the core transition ``Phi``. ``gap_s``: the
        length of the IMU gap this step ends, at its first sample after it (its hidden motion added, as the forward
        loop adds it), else 0."""
        nc = self.nc
        Pa = kernels.augmented(A, nc)        # a constant copy of the core: its cross block becomes Phi
        self.kf._step(x, Pa, 2 * nc, u0, u1, dt, qscale, self.prm, aux, True)
        if gap_s > 0.0:
            self.kf._gap_motion(Pa, x, self.kf.cidx, self.gap, gap_s)
        return np.ascontiguousarray(Pa[:nc, :nc]), np.ascontiguousarray(Pa[:nc, nc:])

    def segment(self, a: int, t_b: float):
        """The points from epoch ``a`` to ``t_b`` as the forward loop stepped them (:mod:`..filters.propagate`),
        and the core transitions between consecutive points. Each point is ``[x, aux, A, B, P, sample or -1]``:
        with a clone ``c``, ``A`` is the core's covariance given ``c`` and ``B`` the cross block (``P`` the joint);
        without one, ``A = P``."""
        ep = self.rec.epochs
        t, u, gap = self.t, self.u, self.gap
        nc = self.nc
        x, aux, P = ep.x[a].copy(), ep.aux[a].copy(), self.cov(ep, a)
        n = P.shape[0]
        if n > nc:
            A, B, Dinv = kernels.condition(P, nc, RCOND)
            self._D, self._Dinv = np.ascontiguousarray(P[nc:, nc:]), Dinv
        else:
            A, B = P, None
        u0, t0, k = ep.u[a].copy(), float(ep.t[a]), int(ep.k_next[a])
        points, phis = [[x.copy(), aux.copy(), A, B, P, -1, u0.copy()]], []
        N = t.size
        # the prior of epoch a + 1 and the transition into it, where the forward pass kept them: the step into that
        # epoch then only moves the state
        ok = self.rec.prior_ok
        prior = (kernels.unpack_upper(self.rec.prior_P[a + 1], ep.n_max, n)
                 if a + 1 < ok.size and ok[a + 1] else None)

        def advance(u1, dt, qscale, sample, last=False, gap_s=0.0):
            nonlocal A, B
            if prior is not None and last:
                phi = self.rec.prior_phi[a + 1].reshape(nc, nc).copy()
                self.kf._step(x, A, 0, u0, u1, dt, qscale, self.prm, aux, False)
                Pj = prior
                if B is not None:
                    A, B = kernels.condition_given(Pj, self.nc, self._Dinv)
                else:
                    A = Pj
            else:
                A, phi = self._step(x, aux, A, u0, u1, dt, qscale, gap_s)
                if B is not None:
                    B = phi @ B
                    Pj = kernels.assemble(A, B, self._D, self._Dinv)
                else:
                    Pj = A
            points.append([x.copy(), aux.copy(), A, B, Pj, sample, np.array(u1, float)])
            phis.append(phi)

        while k < N and t[k] <= t_b:
            dt = t[k] - t0
            if dt > 0.0:
                is_gap = k > 0 and t[k] - t[k - 1] > gap[0]
                advance(u[k], dt, gap[1] if is_gap else 1.0, k, t[k] == t_b, t[k] - t[k - 1] if is_gap else 0.0)
            else:
                points[-1][5] = k
            t0, u0 = t[k], u[k].copy()
            k += 1
        if t_b > t0 and k < N:
            frac = (t_b - t0) / (t[k] - t0)
            advance(u0 + frac * (u[k] - u0), t_b - t0, gap[1] if (k > 0 and t[k] - t[k - 1] > gap[0]) else 1.0, -1, True)
        return points, phis

    def cov(self, store, i: int) -> np.ndarray:
        return kernels.unpack_upper(store.P[i], store.n_max, int(store.n[i]))

    # ---- undoing a clone ---------------------------------------------------------------------
    def _unclone(self, i: int, xs, Ps):
        """From the smoothed state after clone record ``i`` to the smoothed state before it (with the old clone)."""
        cl, nc = self.rec.clones, self.nc
        pre = (cl.x[i], cl.c[i], cl.aux[i], cl.u[i])
        Pt = self.cov(cl, i)
        e = self.ws.minus(xs, pre, nc)
        d, P = kernels.uncondition(Pt, nc, e, np.ascontiguousarray(Ps[:nc, :nc]), RCOND)
        return self.ws.plus(pre, d, Pt.shape[0]), P

    # ---- the backward pass -------------------------------------------------------------------
    def run(self, k0: int) -> Smoothed:
        kf, ep = self.kf, self.rec.epochs
        N = self.t.size
        out = Smoothed(np.full((N, kf.xv.size), np.nan), np.full((N, kf.arrays.rec_Pdiag.shape[1]), np.nan),
                       np.full((N,) + kf.arrays.rec_Ppt.shape[1:], np.nan))
        fast = None if self.python else compiled_pass(type(kf))
        if fast is not None:                      # the whole pass in one compiled call (the same steps, below)
            cl = self.rec.clones
            fast(ep.t, ep.k_next, ep.n, ep.x, ep.c, ep.aux, ep.u, ep.P, ep.size, cl.n, cl.x, cl.c, cl.P,
                 self.rec.clone_epoch, cl.size, ep.n_max, self.nc, self.t, self.u, self.gap, self.prm, RCOND, kf.cidx,
                 out.rec_x, out.rec_Pdiag, out.rec_Ppt, self.rec.prior_P, self.rec.prior_ok, self.rec.prior_phi)
            return out
        clones_of: dict[int, list[int]] = {}
        for i in range(self.rec.clones.size):
            clones_of.setdefault(int(self.rec.clone_epoch[i]), []).append(i)
        last = ep.size - 1
        xs = (ep.x[last].copy(), ep.c[last].copy(), ep.aux[last].copy(), ep.u[last].copy())   # last: smoothed = filtered
        Ps = self.cov(ep, last)
        for b in range(last, 0, -1):
            self._emit(out, self._sample_at(b), xs, Ps)
            for i in reversed(clones_of.get(b, [])):
                xs, Ps = self._unclone(i, xs, Ps)
            points, phis = self.segment(b - 1, float(ep.t[b]))
            n = Ps.shape[0]
            cj = ep.c[b - 1]                      # the clone is constant between epochs
            for j in range(len(phis) - 1, -1, -1):
                xj, auxj, Aj, Bj, Pj, kj, uj = points[j]
                xp, auxp, Ap, _, Pp, _, up = points[j + 1]
                e = self.ws.minus(xs, (xp, cj, auxp, up), n)
                if Bj is None:
                    d, Ps = kernels.backward(Pj, phis[j], Pp, e, Ps, RCOND)
                else:
                    d, Ps = kernels.backward_clone(Aj, Bj, self._Dinv, phis[j], Ap, e, Ps, Pj, Pp, RCOND)
                xs = self.ws.plus((xj, cj, auxj, uj), d, n)
                if j > 0:                         # point 0 is epoch b-1, emitted with its own clones undone
                    self._emit(out, kj, xs, Ps)
        self._emit(out, self._sample_at(0), xs, Ps)
        return out

    def _sample_at(self, i: int) -> int:
        """The sample epoch ``i`` sits on, or -1."""
        ep = self.rec.epochs
        k = int(ep.k_next[i]) - 1
        return k if 0 <= k < self.t.size and abs(self.t[k] - ep.t[i]) < 1e-9 else -1

    def _emit(self, out: Smoothed, k: int, xs, Ps) -> None:
        if k < 0:
            return
        kf = self.kf
        x, _, aux, _ = xs
        out.rec_x[k] = x
        P = np.ascontiguousarray(Ps)
        kf._record_cov(P, P.shape[0], x, aux, kf.cidx, out.rec_Pdiag[k], out.rec_Ppt[k])


def smooth(kf, rec: EpochRecord, k0: int, python: bool = False) -> Smoothed:
    """Run the RTS backward pass over a finished replay (``python``: every interval stepped from Python)."""
    return RTS(kf, rec, python).run(k0)


class RtsSmoother:
    """``smoother.method: rts`` in the replay (:mod:`fusion_eval.smoothing`)."""

    name = "rts"

    @staticmethod
    def check(cfg: dict, formulation) -> None:
        if not formulation.smoothable:
            raise ConfigError(f"smoother.method=rts is not available with filter.formulation={formulation.name}: its "
                              "4-parameter quaternion error makes the backward gains ill-posed; use "
                              "filter.formulation=error_state or invariant")

    def __init__(self, kf, s, n_events: int):
        # the filter records the state before each clone; and each epoch's prior where recomputing an interval's
        # covariance is dear (Van Loan's or the second-order series: 10 Hz IMUs) and the formulation can step into
        # an epoch with its transition alone
        priors = kf.keeps_transition()
        self.rec = kf.recorder = EpochRecord(kf, n_events, priors)
        self.rec.epoch(kf)
        # filter.replay: python steps the backward pass from Python too (it reached only the forward loop: a
        # configuration audit)
        self.python = s.filter.replay == "python"

    def epoch(self, kf) -> None:
        self.rec.epoch(kf)

    def before_update(self, kf, bound, j: int) -> None:
        self.rec.prior(kf)                   # the covariance just predicted to this stamp (a new epoch's prior)

    def after_update(self, kf, res) -> None:
        pass

    def finish(self, kf, k0: int) -> tuple[Smoothed, dict]:
        t0 = time.perf_counter()
        sm = smooth(kf, self.rec, k0, python=self.python)
        rec = self.rec
        stepped = "python" if self.python or compiled_pass(type(kf)) is None else "compiled"
        return sm, {"method": self.name, "backward_pass": stepped, "epochs": int(rec.epochs.size),
                    "clones": int(rec.clones.size),
                    "bytes_per_epoch": rec.bytes_per_epoch(), "bytes_per_clone": rec.clones.bytes_per_row(),
                    "record_bytes": rec.nbytes(),
                    "backward_s": time.perf_counter() - t0}


__all__ = ["Smoothed", "smooth", "rts_step", "RtsSmoother"]
