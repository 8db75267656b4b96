"""Chi-square quantiles without importing ``scipy.stats`` (half a second of start-up on these machines), and the
moving mean the data checks average an IMU stream with, and the runs of a mask they look for.

``scipy.stats.chi2.ppf(q, k)`` is ``2 * gammaincinv(k / 2, q)``; this is that expression, so the values are
the same to the last bit (``tests/test_config.py`` compares them).
"""

from __future__ import annotations

import numpy as np


def chi2_ppf(q, dof):
    """The ``q`` quantile of the chi-square distribution with ``dof`` degrees of freedom."""
    from scipy.special import gammaincinv

    return 2.0 * gammaincinv(np.asarray(dof, float) / 2.0, q)


def true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs of consecutive True in ``mask``: their first indices and the indices just after them (half-open)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[False], np.asarray(mask, bool), [False]]).astype(np.int8)))
    return edges[::2], edges[1::2]


def moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    """The mean of every ``n`` consecutive rows of ``x`` (``len(x) - n + 1`` rows), by one cumulative sum."""
    x = np.asarray(x, float)
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    return (c[n:] - c[:-n]) / n
