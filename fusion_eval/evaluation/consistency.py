"""Filter consistency against a known truth: NEES of position and attitude from the filter's covariance.

NEES_k = e_k^T P_k^-1 e_k, chi-square with 3 degrees of freedom when the filter is consistent. The
attitude error uses the filter's own convention, the right perturbation ``R_true = R_est Exp(e)``.
"""

from __future__ import annotations

import numpy as np

from ..filters.layout import POSE
from ..so3 import log_so3
from ..stats import chi2_ppf


def nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``e^T P^-1 e`` for errors ``(N, d)`` and covariances ``(N, d, d)``."""
    return np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])


def pose_nees(p_est: np.ndarray, R_est: np.ndarray, p_true: np.ndarray, R_true: np.ndarray,
              P_pos_att: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and attitude NEES per epoch (each 3 dof)."""
    e_p = p_true - p_est
    e_th = log_so3(np.einsum("nji,njk->nik", R_est, R_true))
    p, th = POSE.sl("P"), POSE.sl("TH")
    return nees(e_p, P_pos_att[:, p, p]), nees(e_th, P_pos_att[:, th, th])


def fraction_inside(values: np.ndarray, dof: int, prob: float = 0.95) -> tuple[float, float, float]:
    """The two-sided ``prob`` chi-square interval for ``dof`` and the fraction of ``values`` inside it."""
    lo, hi = chi2_ppf(np.array([(1 - prob) / 2, (1 + prob) / 2]), dof)
    return float(np.mean((values >= lo) & (values <= hi))), float(lo), float(hi)


def summary(values: np.ndarray, dof: int, prob: float = 0.95) -> dict:
    frac, lo, hi = fraction_inside(values, dof, prob)
    return {"epochs": int(values.size), "dof": dof, "mean": float(np.mean(values)), "bounds_95": [lo, hi],
            "fraction_in_95": frac}


def innovation_nll(nis: np.ndarray, logdet_S: np.ndarray, dof: int | np.ndarray) -> float:
    """The mean negative log-likelihood of the innovations, ``0.5 (r^T S^-1 r + ln det S + m ln 2 pi)`` per update
    (rejected ones included: a gate must not hide what the model failed to predict); NaN where the replay did not
    record ``ln det S`` (an iterated update stepped from Python). ``dof``: one for all updates, or per update."""
    ld = np.asarray(logdet_S, float)
    if ld.size == 0 or ld.size != np.size(nis) or not np.all(np.isfinite(ld)):
        return float("nan")
    return float(np.mean(0.5 * (np.asarray(nis, float) + ld + dof * np.log(2.0 * np.pi))))


def innovation_summary(nis_sections: dict) -> dict:
    """Objectives that need no ground truth, over every observation: ``nll_per_update``, the innovations' negative
    log-likelihood per update (the prediction-error form of the likelihood of the data under the filter's noise
    settings); ``nis_calibration``, the mean over observations of ``ln(mean NIS / dof)^2 + ((f95 - 0.95) / 0.1)^2``
    (0 for a consistent filter: each term is 1 when the mean NIS is off by a factor e, or when 85 % instead of 95 %
    of the NIS fall inside their 95 % interval)."""
    n = sum(d["epochs"] for d in nis_sections.values())
    nll = [d["nll_mean"] * d["epochs"] for d in nis_sections.values()]
    cal = [float(np.log(d["mean"] / d["dof"]) ** 2 + ((d["fraction_in_95"] - 0.95) / 0.1) ** 2)
           if d["epochs"] and d["mean"] > 0 else float("inf") for d in nis_sections.values()]
    return {"updates": int(n), "nll_per_update": float(sum(nll) / n) if n else float("nan"),
            "nis_calibration": float(np.mean(cal)) if cal else float("nan")}
