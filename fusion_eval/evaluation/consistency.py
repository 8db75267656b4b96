"""Filter consistency against a known truth: NEES of position and attitude from the filter's covariance.

NEES_k = e_k^T P_k^-1 e_k, chi-square with 3 degrees of freedom when the filter is consistent. The
attitude error uses the filter's own convention, the right perturbation ``R_true = R_est Exp(e)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..filters.layout import PACKED, POSE, pack_pose_cov
from ..so3 import _quats, _relative_rotvec
from ..stats import chi2_ppf


def nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``e^T P^-1 e`` for errors ``(N, d)`` and covariances ``(N, d, d)``."""
    return np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])


@njit(cache=True, inline="always", error_model="numpy")
def _quad3(P, pk, a, e0, e1, e2):
    """``e^T C^-1 e`` for the 3x3 block ``C`` at ``a`` of a packed symmetric ``P`` (``pk``: the packing's index of
    each entry), by the adjugate: a solve's figure, NaN or inf where ``C`` is singular."""
    p00, p01, p02 = P[pk[a, a]], P[pk[a, a + 1]], P[pk[a, a + 2]]
    p11, p12, p22 = P[pk[a + 1, a + 1]], P[pk[a + 1, a + 2]], P[pk[a + 2, a + 2]]
    c00, c01, c02 = p11 * p22 - p12 * p12, p02 * p12 - p01 * p22, p01 * p12 - p02 * p11
    c11, c12, c22 = p00 * p22 - p02 * p02, p01 * p02 - p00 * p12, p00 * p11 - p01 * p01
    det = p00 * c00 + p01 * c01 + p02 * c02
    q = (e0 * (c00 * e0 + c01 * e1 + c02 * e2) + e1 * (c01 * e0 + c11 * e1 + c12 * e2)
         + e2 * (c02 * e0 + c12 * e1 + c22 * e2))
    return q / det


@njit(cache=True, error_model="numpy")       # a singular covariance: inf or NaN, not an exception
def _pose_nees(p_est, q_est, p_true, q_true, P, pk, i_p, i_th, n_pos, n_att):
    th = np.empty((1, 3))
    for n in range(p_est.shape[0]):
        n_pos[n] = _quad3(P[n], pk, i_p, p_true[n, 0] - p_est[n, 0], p_true[n, 1] - p_est[n, 1],
                          p_true[n, 2] - p_est[n, 2])
        _relative_rotvec(q_est[n], q_true[n], th, 0)          # Log(R_est^T R_true)
        n_att[n] = _quad3(P[n], pk, i_th, th[0, 0], th[0, 1], th[0, 2])


def pose_nees_q(p_est: np.ndarray, q_est_xyzw: np.ndarray, p_true: np.ndarray, q_true_xyzw: np.ndarray,
                P_pos_att_packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and attitude NEES per epoch (each 3 dof) of poses given by quaternions ``(x, y, z, w)``, with the
    covariances packed as the filters record them (``(N, 21)``, :data:`~fusion_eval.filters.layout.PACKED`): the
    attitude error is the rotation vector of ``R_est^T R_true`` (scipy's ``as_rotvec``). One compiled loop with no
    stack-sized temporaries (the matrices, products and solves took 0.7 s and ~200 MB on a simulated hour)."""
    f = [np.ascontiguousarray(a, dtype=float) for a in (p_est, q_est_xyzw, p_true, q_true_xyzw, P_pos_att_packed)]
    n_pos, n_att = np.empty(len(f[0])), np.empty(len(f[0]))
    _pose_nees(*f, PACKED, POSE.sl("P").start, POSE.sl("TH").start, n_pos, n_att)
    return n_pos, n_att


def pose_nees(p_est: np.ndarray, R_est: np.ndarray, p_true: np.ndarray, R_true: np.ndarray,
              P_pos_att: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and attitude NEES per epoch (each 3 dof) of poses given by rotation matrices and ``(N, 6, 6)``
    covariances (:func:`pose_nees_q`)."""
    return pose_nees_q(p_est, _quats(R_est).reshape(-1, 4), p_true, _quats(R_true).reshape(-1, 4),
                       pack_pose_cov(P_pos_att))


def fraction_inside(values: np.ndarray, dof: int, prob: float = 0.95) -> tuple[float, float, float]:
    """The two-sided ``prob`` chi-square interval for ``dof`` and the fraction of ``values`` inside it."""
    lo, hi = chi2_ppf(np.array([(1 - prob) / 2, (1 + prob) / 2]), dof)
    return float(np.mean((values >= lo) & (values <= hi))), float(lo), float(hi)


def independent_epochs(values: np.ndarray) -> float:
    """The effective number of independent epochs of a series: ``N / tau`` with ``tau = 1 + 2 sum rho_k``, its
    autocorrelations summed while positive (Geyer's initial positive sequence), by one FFT. A filter's errors wander:
    4,400 epochs of kitti-00 hold about as many independent ones as its minutes."""
    x = np.asarray(values, float)
    n = x.size
    if n < 3 or not np.all(np.isfinite(x)):
        return float(n)
    x = x - x.mean()
    var = float(x @ x)
    if var <= 0.0:
        return float(n)
    f = np.fft.rfft(x, 2 * n)
    rho = np.fft.irfft(f * np.conj(f))[:n] / var
    neg = np.flatnonzero(rho[1:] <= 0.0)         # not a state index: lags from 1
    k = int(neg[0]) if neg.size else n - 1
    tau = 1.0 + 2.0 * float(np.sum(rho[1:k + 1]))   # not a state index
    return float(min(n, max(1.0, n / tau)))


def mean_bounds(dof: int, n_eff: float, prob: float = 0.95) -> tuple[float, float]:
    """The ``prob`` interval of the mean of a consistent filter's NEES or NIS over ``n_eff`` independent epochs: the
    mean of ``n_eff`` chi-square(``dof``) values is chi-square(``n_eff dof``) / ``n_eff``."""
    k = n_eff * dof
    lo, hi = chi2_ppf(np.array([(1 - prob) / 2, (1 + prob) / 2]), k)
    return float(lo / n_eff), float(hi / n_eff)


def summary(values: np.ndarray, dof: int, prob: float = 0.95) -> dict:
    """Epochs, mean, the per-epoch chi-square interval and the fraction inside it, and for the mean its own interval
    over the series' independent epochs (:func:`independent_epochs`), which the report's verdict takes: a fixed 1.5x
    of the dof called 16 of 58 simulated runs with the simulator's own noise over- or underconfident (a rate review)."""
    frac, lo, hi = fraction_inside(values, dof, prob)
    n_eff = independent_epochs(values)
    return {"epochs": int(values.size), "dof": dof, "mean": float(np.mean(values)), "bounds_95": [lo, hi],
            "fraction_in_95": frac, "independent_epochs": round(n_eff, 1),
            "mean_bounds_95": list(mean_bounds(dof, n_eff, prob))}


def innovation_nll(nis: np.ndarray, logdet_S: np.ndarray, dof: int | np.ndarray) -> float:
    """The mean negative log-likelihood of the innovations, ``0.5 (r^T S^-1 r + ln det S + m ln 2 pi)`` per update
    (rejected ones included: a gate must not hide what the model failed to predict); NaN where the replay did not
    record ``ln det S`` (an iterated update stepped from Python). ``dof``: one for all updates, or per update."""
    ld = np.asarray(logdet_S, float)
    if ld.size == 0 or ld.size != np.size(nis) or not np.all(np.isfinite(ld)):
        return float("nan")
    return float(np.mean(0.5 * (np.asarray(nis, float) + ld + dof * np.log(2.0 * np.pi))))


def innovation_summary(nis_sections: dict, measured=None) -> dict:
    """Objectives that need no ground truth, over every observation: ``nll_per_update``, the innovations' negative
    log-likelihood per update (the prediction-error form of the likelihood of the data under the filter's noise
    settings); ``nis_calibration``, the mean over the measured streams' observations (``measured``: their names;
    None = all; all where none is measured) of ``ln(mean NIS / dof)^2 + ((f95 - 0.95) / 0.1)^2`` (0 for a consistent
    filter: each term is 1 when the mean NIS is off by a factor e, or when 85 % instead of 95 % of the NIS fall inside
    their 95 % interval). A pseudo-observation (the non-holonomic constraint) is left out of the calibration: its NIS
    is near zero wherever the vehicle does not slip, by design, and its term outweighed every sensor's (28.7 of a
    simulated robot's 28.8: a user trial), which no sensor noise setting moves."""
    n = sum(d["epochs"] for d in nis_sections.values())
    nll = [d["nll_mean"] * d["epochs"] for d in nis_sections.values()]
    calibrated = {k: d for k, d in nis_sections.items() if measured is None or k in measured} or nis_sections
    cal = [float(np.log(d["mean"] / d["dof"]) ** 2 + ((d["fraction_in_95"] - 0.95) / 0.1) ** 2)
           if d["epochs"] and d["mean"] > 0 else float("inf") for d in calibrated.values()]
    return {"updates": int(n), "nll_per_update": float(sum(nll) / n) if n else float("nan"),
            "nis_calibration": float(np.mean(cal)) if cal else float("nan")}
