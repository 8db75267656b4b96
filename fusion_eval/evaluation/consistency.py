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
