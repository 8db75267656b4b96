"""Per-segment breakdown: the error of each estimate in windows along the route (every N metres of the
ground truth's path, or every N seconds), to show where fusion helps and where it hurts."""

from __future__ import annotations

import numpy as np

from ..types import PoseSeries


def route_distance(gt: PoseSeries) -> np.ndarray:
    """Cumulative path length of the ground truth at its stamps, m."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt.p_w_m, axis=0), axis=1))])


def breakdown(gt: PoseSeries, errors: dict[str, tuple[np.ndarray, np.ndarray]], segment_m: float,
              segment_s: float | None = None, worst: int = 5, primary: str = "fused", secondary: str | None = "lidar") -> dict:
    """Windows along the route with each estimate's APE RMSE inside.

    ``errors`` maps an estimate's name to ``(stamps, APE translation errors)``. Returns ``{"by", "length",
    "segments": [...], "worst": [...]}``; each segment holds its start/end distance and time and, per
    estimate, the RMSE and the number of poses (estimates with no pose in a window get None).
    """
    d_gt = route_distance(gt)
    t0 = gt.t_s[0]
    by_time = segment_s is not None
    L = float(segment_s if by_time else segment_m)

    def key(t):
        return np.floor((t - t0) / L) if by_time else np.floor(np.interp(t, gt.t_s, d_gt) / L)

    n_seg = int(key(np.array([gt.t_s[-1]]))[0]) + 1
    segs = []
    for k in range(n_seg):
        lo, hi = k * L, (k + 1) * L
        if by_time:
            m = (gt.t_s - t0 >= lo) & (gt.t_s - t0 < hi)
        else:
            m = (d_gt >= lo) & (d_gt < hi)
        if not m.any():
            continue
        seg = {"index": k, "start_m": float(d_gt[m][0]), "end_m": float(d_gt[m][-1]),
               "start_s": float(gt.t_s[m][0] - t0), "end_s": float(gt.t_s[m][-1] - t0), "rmse_m": {}, "poses": {}}
        for name, (t, e) in errors.items():
            sel = key(t) == k
            seg["rmse_m"][name] = float(np.sqrt(np.mean(e[sel] ** 2))) if sel.any() else None
            seg["poses"][name] = int(sel.sum())
        segs.append(seg)
    ranked = sorted((s for s in segs if s["rmse_m"].get(primary) is not None), key=lambda s: -s["rmse_m"][primary])
    return {"by": "time" if by_time else "distance", "length": L, "segments": segs, "primary": primary,
            "secondary": secondary if secondary in errors else None, "worst": [s["index"] for s in ranked[:worst]]}
