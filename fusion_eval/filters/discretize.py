"""Discretisation of a linear(ised) error dynamics ``dx' = F_t dx + w``, ``E[w w^T] = Q_c delta(t)`` over one
IMU interval ``T``: the transition ``Phi`` and the discrete process noise ``Q_d`` (compiled).

``filter.discretization`` chooses among:

* ``first_order``: ``Phi = I + F_t T``, ``Q_d = Q_c T``. Drops the ``T^2/2`` coupling of position with attitude
  and accelerometer bias (through the velocity), which is what a 10 Hz IMU feels.
* ``second_order``: ``Phi = I + F_t T + (F_t T)^2/2`` and the trapezoidal ``Q_d = T/2 (Phi Q_c Phi^T + Q_c)``
  (positive semi-definite, unlike the second-order truncation of Van Loan's integral, which is indefinite for
  this F and made the filter diverge).
* ``van_loan``: exact for the linearised model: ``Phi = expm(F_t T)`` and ``Q_d = int_0^T Phi(s) Q_c Phi(s)^T ds``,
  the two blocks of the exponential of Van Loan's matrix ``[[-F_t, Q_c], [0, F_t^T]] T`` (C. F. Van Loan,
  "Computing integrals involving the matrix exponential", IEEE TAC 1978). They are summed here as the two
  Taylor series of that block-triangular exponential, ``Phi = sum A^k / k!`` and
  ``Q_d = sum_k T^k / k! L^(k-1)(Q_c)`` with ``L(X) = F_t X + X F_t^T``, after scaling the interval until
  ``|F_t T| <= 2`` (a car's 10 Hz step is about 1.5: no doubling, whose three dense products cost as much
  as the series) and doubling back with ``Q(2T) = Q(T) + Phi(T) Q(T) Phi(T)^T``, ``Phi(2T) = Phi(T)^2``
  (exact), so a long IMU gap is as accurate as a 10 ms step. ``F_t`` has ~40 non-zeros of 225: every
  product of the series is a sparse one, 8x cheaper than the exponential of the 30x30 matrix it replaces
  (:func:`van_loan_block`, kept as the tests' oracle) for the same result to rounding.

The tests check ``van_loan`` against scipy's ``expm`` and against a finely sub-stepped integration of
``P' = F_t P + P F_t^T + Q_c`` (to 1e-9), and the local error of ``second_order`` as ``O(T^3)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..spec import S
from . import linalg

FIRST_ORDER, SECOND_ORDER, VAN_LOAN = 1, 2, 3
METHODS = {"first_order": FIRST_ORDER, "second_order": SECOND_ORDER, "van_loan": VAN_LOAN}
DOC = ("discretisation of the error-state propagation over one IMU interval: 'first_order' (F = I + F_t T, "
       "Q_d = Q_c T), 'second_order' (Phi to T^2, trapezoidal Q_d), 'van_loan' (exact for the linearised model) or "
       "'auto': van_loan below 100 Hz (the median IMU interval above 10 ms), first_order from 100 Hz on; the odometer + gyro "
       "process model has first_order only")
# 'auto': where the first-order step drops terms that matter. The dropped T^2/2 coupling is of relative size
# |g T|^2 / 2: 0.48 at 10 Hz (KITTI), 0.5 % at 100 Hz, 0.1 % at 200 Hz, while Van Loan costs 8-10x the
# first-order step per sample (measured: the simulated drives at 100 Hz give the same APE either way)
AUTO_VAN_LOAN_ABOVE_S = 0.0101

# the key of the formulations that discretise a continuous error dynamics
KEYS = {"filter.discretization": S("auto", DOC, choices=(*METHODS, "auto"))}


def resolve_auto(method: str, t_s: np.ndarray) -> str:
    """``filter.discretization`` with 'auto' resolved from the IMU stamps ``t_s`` (s)."""
    if method != "auto":
        return method
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else np.inf
    return "van_loan" if dt > AUTO_VAN_LOAN_ABOVE_S else "first_order"

# Taylor order after scaling to a norm below 1/2: the remainder is below 0.5^13/13! ~ 2e-14 relative
_TAYLOR_ORDER = 12


@njit(cache=True)
def expm(A):
    """The matrix exponential by scaling and squaring of a Taylor series (the norm scaled below 1/2)."""
    n = A.shape[0]
    norm = np.max(np.sum(np.abs(A), axis=1))
    s = 0
    while norm > 0.5:
        norm *= 0.5
        s += 1
    As = A * (0.5 ** s)
    E = np.eye(n)
    term = np.eye(n)
    for k in range(1, _TAYLOR_ORDER + 1):
        term = (term @ As) * (1.0 / k)
        E = E + term
        # a 10 ms step has a norm of a few 1e-2: the series has converged to rounding long before order 12
        if np.max(np.abs(term)) < 1e-17:
            break
    for _ in range(s):
        E = E @ E
    return E


_MAX_TERMS = 40           # |A| <= 2: the k-th term is below 2^k/k!, rounding level (1e-17 relative) by k = 27


@njit(cache=True)
def _csr(A):
    """``A``'s non-zeros by rows (``ptr``, ``cols``, ``vals``): the series' products touch only those (~40 of 225)."""
    n = A.shape[0]
    ptr = np.empty(n + 1, np.int64)
    cols = np.empty(n * n, np.int64)
    vals = np.empty(n * n)
    c = 0
    for i in range(n):
        ptr[i] = c
        for k in range(n):
            if A[i, k] != 0.0:
                cols[c] = k
                vals[c] = A[i, k]
                c += 1
    ptr[n] = c
    return ptr, cols, vals


@njit(cache=True)
def _csr_row(ptr, cols, vals, scale, i, X, row):
    """``row <- scale * (A X)[i, :]`` for the sparse ``A`` of :func:`_csr`."""
    for j in range(X.shape[1]):
        row[j] = 0.0
    for e in range(ptr[i], ptr[i + 1]):
        v = vals[e] * scale
        src = cols[e]
        for j in range(X.shape[1]):
            row[j] += v * X[src, j]


@njit(cache=True)
def van_loan(Ft, Qc, dt):
    """Exact ``Phi = expm(F_t T)`` and ``Q_d = int_0^T Phi(s) Q_c Phi(s)^T ds`` (``Qc``: the full density, (n, n)),
    by the sparse Taylor series of the block-triangular exponential with scaling and doubling (module docstring).

    One pass per term over ``A``'s rows forms the next term of both series, adds it to its sum and takes its
    largest entry (the stopping test), with no scratch matrix zeroed or rescanned: the per-term cost is the
    sparse products themselves (about half of what separate passes cost at 15 states)."""
    n = Ft.shape[0]
    norm = 0.0
    for i in range(n):
        r = 0.0
        for k in range(n):
            r += abs(Ft[i, k])
        norm = max(norm, r * dt)
    s = 0
    while norm > 2.0:
        norm *= 0.5
        s += 1
    h = dt * 0.5 ** s
    ptr, cols, vals = _csr(Ft)
    Phi = np.eye(n)
    term = np.eye(n)
    nxt = np.empty((n, n))
    row = np.empty(n)
    Y = Qc * h
    Q = Y.copy()
    AY = np.empty((n, n))
    # |Phi| >= 1 (its diagonal) and |Q_d| is about |Y_1| = h max(Q_c) or more (the integrand Phi Q_c Phi^T keeps
    # Q_c's diagonal, up to the biases' decay over the step; later terms may be larger, at |F_t h| up to 2): the
    # series stop once their terms fall below rounding relative to those, without rescanning the sums
    q_ref = 0.0
    for i in range(n):
        for j in range(n):
            q_ref = max(q_ref, abs(Y[i, j]))
    for k in range(1, _MAX_TERMS):
        c_phi = h / k                      # A^k / k! = (h F_t / k) A^(k-1) / (k-1)!
        c_y = h / (k + 1)                  # Y_{k+1} = (A Y_k + Y_k A^T) / (k + 1), A Y_k the transpose of Y_k A^T
        t_max = 0.0
        y_max = 0.0
        for i in range(n):
            _csr_row(ptr, cols, vals, c_phi, i, term, row)
            for j in range(n):
                x = row[j]
                nxt[i, j] = x
                Phi[i, j] += x
                t_max = max(t_max, abs(x))
            _csr_row(ptr, cols, vals, c_y, i, Y, row)
            for j in range(n):
                AY[i, j] = row[j]
        term, nxt = nxt, term
        for i in range(n):
            for j in range(i, n):
                y = AY[i, j] + AY[j, i]            # exactly symmetric: so is every sum of these
                Y[i, j] = y
                Y[j, i] = y
                Q[i, j] += y
                if j != i:
                    Q[j, i] += y
                y_max = max(y_max, abs(y))
        if t_max <= 1e-17 and y_max <= 1e-17 * q_ref:
            break
    for _ in range(s):
        Q = Q + Phi @ Q @ Phi.T
        Phi = Phi @ Phi
    return Phi, (0.5 * (Q + Q.T) if s > 0 else Q)   # Q is exactly symmetric before any doubling


@njit(cache=True)
def van_loan_block(Ft, Qc, dt):
    """The same ``(Phi, Q_d)`` from the exponential of the whole 30x30 Van Loan matrix (the tests' oracle)."""
    n = Ft.shape[0]
    # Q_d is linear in Q_c: the density is scaled to a unit maximum so that both blocks of the exponential
    # converge to full relative precision (expm stops its series on an absolute criterion)
    qs = np.max(np.abs(Qc))
    qs = qs if qs > 0.0 else 1.0
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -Ft * dt
    M[n:, n:] = Ft.T * dt
    M[:n, n:] = Qc * (dt / qs)
    E = expm(M)
    Phi = np.ascontiguousarray(E[n:, n:].T)
    Qd = (Phi @ np.ascontiguousarray(E[:n, n:])) * qs
    return Phi, 0.5 * (Qd + Qd.T)


@njit(cache=True)
def _phi_second(Ft, dt):
    FT = Ft * dt
    return np.eye(Ft.shape[0]) + FT + 0.5 * (FT @ FT)


@njit(cache=True)
def second_order(Ft, Qc, dt):
    """``Phi = I + F_t T + (F_t T)^2 / 2`` and ``Q_d = T/2 (Phi Q_c Phi^T + Q_c)`` (``Qc``: (n, n))."""
    Phi = _phi_second(Ft, dt)
    Qd = 0.5 * dt * (Phi @ Qc @ Phi.T + Qc)
    return Phi, 0.5 * (Qd + Qd.T)


@njit(cache=True)
def transition_full(Ft, Qc, dt, method):
    """``(Phi, Q_d)`` by ``method`` (one of :data:`METHODS`' values) for a full noise density ``Qc`` (n, n)."""
    if method == VAN_LOAN:
        return van_loan(Ft, Qc, dt)
    if method == SECOND_ORDER:
        Phi, Qd = second_order(Ft, Qc, dt)
    else:
        Phi, Qd = np.eye(Ft.shape[0]) + Ft * dt, Qc * dt
    _exact_decay(Ft, Qc, dt, Phi, Qd)
    return Phi, Qd


@njit(cache=True)
def gm_interval(k, dt):
    """The variance a unit-density driving noise adds to a Gauss-Markov state of decay rate ``k`` over ``dt``:
    ``(1 - exp(-2 k dt)) / (2 k)`` (``dt`` for a random walk, ``k = 0``)."""
    if k * dt < 1e-9:
        return dt
    return -np.expm1(-2.0 * k * dt) / (2.0 * k)


@njit(cache=True)
def _exact_decay(Ft, Qc, dt, Phi, Qd):
    """A state that only decays (a Gauss-Markov bias: its row of ``F_t`` holds nothing but ``-1/tau`` on the
    diagonal) gets its exact ``exp(-dt/tau)`` and variance, in place: the series' ``1 - dt/tau`` went below -1 for a
    correlation time under half the interval, and the filter diverged (a simulate review)."""
    n = Ft.shape[0]
    for i in range(n):
        k = -Ft[i, i]
        if k <= 0.0:
            continue
        alone = True
        for j in range(n):
            if j != i and (Ft[i, j] != 0.0 or Qc[i, j] != 0.0):
                alone = False
                break
        if alone:
            e = np.exp(-k * dt)
            for j in range(n):
                Phi[i, j] = 0.0
                Qd[i, j] = 0.0
                Qd[j, i] = 0.0
            Phi[i, i] = e
            Qd[i, i] = Qc[i, i] * gm_interval(k, dt)


@njit(cache=True)
def transition(Ft, Qc, dt, method):
    """``(Phi, Q_d)`` for a diagonal noise density (``Qc``: the diagonal, (n,))."""
    return transition_full(Ft, np.diag(Qc), dt, method)


@njit(cache=True)
def propagate(P, n, Phi, Qd):
    """``P <- Phi P Phi^T + Q_d`` as :func:`propagate_dense` computes it, on ``Phi``'s non-zeros: an error state's
    transition is mostly zero blocks (the ESKF's: 75-87 non-zeros of 225; identity on the position and bias
    blocks), so both products go through ``Phi``'s rows (:func:`_csr`) and only the upper triangle of the
    symmetric result is formed, then mirrored (exactly symmetric, as :func:`linalg.symmetrize_into` leaves the
    dense one). About a third of the dense products' work, and no BLAS call on 15 x 15 blocks, whose dispatch
    costs as much as their arithmetic."""
    m = Phi.shape[0]
    ptr, cols, vals = _csr(Phi)
    T = np.zeros((m, n))                      # Phi P[:m, :n]
    for i in range(m):
        for e in range(ptr[i], ptr[i + 1]):
            v = vals[e]
            src = cols[e]
            for j in range(n):
                T[i, j] += v * P[src, j]
    for i in range(m):                        # (Phi P) Phi^T + Q_d, the upper triangle, mirrored
        for j in range(i, m):
            s = 0.0
            for e in range(ptr[j], ptr[j + 1]):
                s += T[i, cols[e]] * vals[e]
            v = s + 0.5 * (Qd[i, j] + Qd[j, i])
            P[i, j] = v
            P[j, i] = v
    for i in range(m):                        # the constant states after the leading ones (a pose clone)
        for j in range(m, n):
            v = T[i, j]
            P[i, j] = v
            P[j, i] = v


@njit(cache=True)
def propagate_dense(P, n, Phi, Qd):
    """``P <- Phi P Phi^T + Q_d`` by dense products (the tests' oracle of :func:`propagate`) on the leading
    ``m = Phi.shape[0]`` states of the first ``n``; the states after them (a pose clone) are constant, so only their
    cross-covariance with the leading states changes."""
    m = Phi.shape[0]
    newc = Phi @ np.ascontiguousarray(P[:m, :m]) @ np.ascontiguousarray(Phi.T) + Qd
    if n > m:
        cross = Phi @ np.ascontiguousarray(P[:m, m:n])
        P[:m, m:n] = cross
        P[m:n, :m] = cross.T
    P[:m, :m] = newc
    linalg.symmetrize_into(P, n, P)
