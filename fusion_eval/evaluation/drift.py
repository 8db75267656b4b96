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


def _rot_angle(R: np.ndarray) -> np.ndarray:
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.arccos(np.clip(c, -1.0, 1.0))


def kitti_drift(T_gt: np.ndarray, T_est: np.ndarray, lengths=LENGTHS_M, step: int = STEP_FRAMES) -> DriftResult | None:
    """Drift of ``T_est`` (N, 4, 4) against ``T_gt`` (N, 4, 4), poses paired by index. None if the
    trajectory is shorter than the shortest length."""
    if T_gt.shape != T_est.shape:
        raise ValueError("ground truth and estimate must have the same number of poses")
    dist = _path_lengths(T_gt)
    first = np.arange(0, len(dist), step)
    inv = np.linalg.inv
    # the first frames' inverses once for every length (each matrix's inverse is its own: the same numbers as
    # inverting each length's subset; 8 lengths x 3 stacks of inverses took 1 s on a simulated hour at 200 Hz)
    inv_gt, inv_est = inv(T_gt[first]), inv(T_est[first])
    rows = []
    for L in lengths:
        last = np.searchsorted(dist, dist[first] + L, side="right")   # first index with dist > dist[first] + L
        ok = last < len(dist)
        j = last[ok]
        if j.size == 0:
            continue
        d_gt = inv_gt[ok] @ T_gt[j]
        d_est = inv_est[ok] @ T_est[j]
        E = inv(d_est) @ d_gt
        t_err = np.linalg.norm(E[:, :3, 3], axis=1) / L
        r_err = _rot_angle(E[:, :3, :3]) / L
        rows.append((L, t_err, r_err))
    if not rows:
        return None
    t_all = np.concatenate([r[1] for r in rows])
    r_all = np.concatenate([r[2] for r in rows])
    per = {L: {"t_err_pct": float(np.mean(t) * 100), "r_err_deg_per_m": float(np.degrees(np.mean(r))),
               "segments": int(t.size)} for L, t, r in rows}
    return DriftResult(float(np.mean(t_all) * 100), float(np.degrees(np.mean(r_all))), int(t_all.size), per)
