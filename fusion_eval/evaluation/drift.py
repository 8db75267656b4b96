"""The KITTI odometry drift metric (what evo lacks), as the KITTI odometry devkit defines it.

For every first frame i = 0, 10, 20, ... and every length L in 100, 200, ..., 800 m, the last frame j is
the first one whose ground-truth path length from i exceeds L; the error of the relative motion,
``E = (T_est,i^-1 T_est,j)^-1 (T_gt,i^-1 T_gt,j)``, gives a translational error ``|t(E)| / L`` and a
rotational error ``angle(E) / L``. The averages over all (i, L) pairs are the reported figures:
translation in percent, rotation in deg/m (the devkit's unit; deg/100 m is 100 times it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

LENGTHS_M = (100, 200, 300, 400, 500, 600, 700, 800)
STEP_FRAMES = 10


@dataclass(frozen=True)
class DriftResult:
    t_err_pct: float            # mean translational error, %
    r_err_deg_per_m: float      # mean rotational error, deg/m
    segments: int               # number of (first frame, length) pairs
    per_length: dict            # length -> {"t_err_pct", "r_err_deg_per_m", "segments"}

    def as_dict(self) -> dict:
        return {"t_err_pct": self.t_err_pct, "r_err_deg_per_m": self.r_err_deg_per_m,
                "r_err_deg_per_100m": self.r_err_deg_per_m * 100, "segments": self.segments,
                "per_length": {str(k): v for k, v in self.per_length.items()}}


def _path_lengths(T_gt: np.ndarray) -> np.ndarray:
    steps = np.linalg.norm(np.diff(T_gt[:, :3, 3], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


@njit(cache=True, inline="always")
def _inv3(A, out):
    """The general inverse of a 3x3 block (adjugate over determinant), as the devkit inverts whole matrices:
    a pose file's rotation need not be exactly orthonormal, so no transpose."""
    a, b, c = A[0, 0], A[0, 1], A[0, 2]
    d, e, f = A[1, 0], A[1, 1], A[1, 2]
    g, h, i = A[2, 0], A[2, 1], A[2, 2]
    c00, c10, c20 = e * i - f * h, f * g - d * i, d * h - e * g
    r = 1.0 / (a * c00 + b * c10 + c * c20)
    out[0, 0], out[0, 1], out[0, 2] = c00 * r, (c * h - b * i) * r, (b * f - c * e) * r
    out[1, 0], out[1, 1], out[1, 2] = c10 * r, (a * i - c * g) * r, (c * d - a * f) * r
    out[2, 0], out[2, 1], out[2, 2] = c20 * r, (b * g - a * h) * r, (a * e - b * d) * r


@njit(cache=True)
def _errors(T_gt, T_est, first, last, length_m):
    """``|t(E)| / L`` and ``angle(E) / L`` of each pair (first[m], last[m]), with
    ``E = (T_est,i^-1 T_est,j)^-1 (T_gt,i^-1 T_gt,j)`` on the rotation and translation blocks of affine poses
    (bottom row 0 0 0 1). One loop: numpy's stacked ``inv`` costs ~1.5 us a matrix, 0.8 s per estimate on a
    simulated hour at 200 Hz; this is equal to it within 1e-12 (tested)."""
    n = first.shape[0]
    t_err = np.empty(n)
    r_err = np.empty(n)
    Ag = np.empty((3, 3))
    Ae = np.empty((3, 3))
    Ri = np.empty((3, 3))
    dRg = np.empty((3, 3))
    dRe = np.empty((3, 3))
    dt = np.empty(3)
    for m in range(n):
        i, j = first[m], last[m]
        _inv3(T_gt[i, :3, :3], Ag)
        _inv3(T_est[i, :3, :3], Ae)
        for r in range(3):
            for c in range(3):
                sg = 0.0
                se = 0.0
                for q in range(3):
                    sg += Ag[r, q] * T_gt[j, q, c]
                    se += Ae[r, q] * T_est[j, q, c]
                dRg[r, c] = sg
                dRe[r, c] = se
            sg = 0.0
            se = 0.0
            for q in range(3):
                sg += Ag[r, q] * (T_gt[j, q, 3] - T_gt[i, q, 3])
                se += Ae[r, q] * (T_est[j, q, 3] - T_est[i, q, 3])
            dt[r] = sg - se                     # t(E) = dRe^-1 (t_gt - t_est) of the two relative motions
        _inv3(dRe, Ri)
        trace = 0.0
        norm2 = 0.0
        for r in range(3):
            s = 0.0
            for q in range(3):
                s += Ri[r, q] * dt[q]
                trace += Ri[r, q] * dRg[q, r]
            norm2 += s * s
        t_err[m] = np.sqrt(norm2) / length_m
        r_err[m] = np.arccos(min(1.0, max(-1.0, 0.5 * (trace - 1.0)))) / length_m
    return t_err, r_err


def kitti_drift(T_gt: np.ndarray, T_est: np.ndarray, lengths=LENGTHS_M, step: int = STEP_FRAMES) -> DriftResult | None:
    """Drift of ``T_est`` (N, 4, 4) against ``T_gt`` (N, 4, 4), poses paired by index. None if the
    trajectory is shorter than the shortest length."""
    if T_gt.shape != T_est.shape:
        raise ValueError("ground truth and estimate must have the same number of poses")
    dist = _path_lengths(T_gt)
    first = np.arange(0, len(dist), step)
    T_gt = np.ascontiguousarray(T_gt, dtype=np.float64)
    T_est = np.ascontiguousarray(T_est, dtype=np.float64)
    rows = []
    for L in lengths:
        last = np.searchsorted(dist, dist[first] + L, side="right")   # first index with dist > dist[first] + L
        ok = last < len(dist)
        if not ok.any():
            continue
        t_err, r_err = _errors(T_gt, T_est, first[ok], last[ok], float(L))
        rows.append((L, t_err, r_err))
    if not rows:
        return None
    t_all = np.concatenate([r[1] for r in rows])
    r_all = np.concatenate([r[2] for r in rows])
    per = {L: {"t_err_pct": float(np.mean(t) * 100), "r_err_deg_per_m": float(np.degrees(np.mean(r))),
               "segments": int(t.size)} for L, t, r in rows}
    return DriftResult(float(np.mean(t_all) * 100), float(np.degrees(np.mean(r_all))), int(t_all.size), per)
