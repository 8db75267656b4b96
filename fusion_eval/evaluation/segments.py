"""Per-segment breakdown: the error of each estimate in windows along the route (every N metres of the
ground truth's path, or every N seconds), to show where fusion helps and where it hurts."""

from __future__ import annotations

import numpy as np

from ..types import PoseSeries


def route_distance(gt: PoseSeries) -> np.ndarray:
    """Cumulative path length of the ground truth at its stamps, m."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt.p_w_m, axis=0), axis=1))])


MAX_SEGMENTS = 100_000       # a finer breakdown is a mistaken unit, not a report (and would take hours)


def breakdown(gt: PoseSeries, errors: dict[str, tuple[np.ndarray, np.ndarray]], segment_m: float,
              segment_s: float | None = None, worst: int = 5, primary: str = "fused", secondary: str | None = "lidar",
              parts: dict[str, np.ndarray] | None = None) -> dict:
    """Windows along the route with each estimate's APE RMSE inside.

    ``errors`` maps an estimate's name to ``(stamps, APE translation errors)``; ``parts`` (optional) an estimate's
    name to the horizontal and vertical parts of the same errors, ``(n, 2)``
    (:func:`fusion_eval.evaluation.trajectory.horizontal_vertical`). Returns ``{"by", "length", "segments": [...],
    "worst": [...]}``; each segment holds its start/end distance and time and, per estimate, the RMSE, the number of
    poses (estimates with no pose in a window get None) and, with ``parts``, ``rmse_h_m``/``rmse_v_m``: where the
    error lies (a student found that kitti-00's worst windows are vertical only from the TUM files).
    """
    parts = {k: v for k, v in (parts or {}).items() if v is not None and k in errors}
    d_gt = route_distance(gt)
    t0 = gt.t_s[0]
    by_time = segment_s is not None
    L = float(segment_s if by_time else segment_m)

    def key(t):
        return np.floor((t - t0) / L) if by_time else np.floor(np.interp(t, gt.t_s, d_gt) / L)

    n_seg = int(key(np.array([gt.t_s[-1]]))[0]) + 1
    if n_seg > MAX_SEGMENTS:
        from ..errors import ConfigError

        span = f"{gt.t_s[-1] - t0:.1f} s" if by_time else f"{d_gt[-1]:.1f} m"
        raise ConfigError(f"a segment of {L:g} {'s' if by_time else 'm'} cuts the route ({span}) into {n_seg:,} windows "
                          f"(at most {MAX_SEGMENTS:,}): give a segment length of at least "
                          f"{(gt.t_s[-1] - t0 if by_time else d_gt[-1]) / MAX_SEGMENTS:.3g} {'s' if by_time else 'm'}")
    # each estimate's poses grouped by window once (a stable sort keeps their order inside a window, so each
    # window's RMSE sums the same values in the same order as a mask would)
    groups = {}
    for name, (t, e) in errors.items():
        kk = key(t)
        order = np.argsort(kk, kind="stable")
        groups[name] = (e[order], np.searchsorted(kk[order], np.arange(n_seg + 1), side="left"),
                        parts[name][order] if name in parts else None)
    x_gt = gt.t_s - t0 if by_time else d_gt          # non-decreasing: a window is a run of samples
    segs = []
    for k in range(n_seg):
        lo, hi = k * L, (k + 1) * L
        a, b = np.searchsorted(x_gt, lo, side="left"), np.searchsorted(x_gt, hi, side="left")
        if a >= b:
            continue
        seg = {"index": k, "start_m": float(d_gt[a]), "end_m": float(d_gt[b - 1]),
               "start_s": float(gt.t_s[a] - t0), "end_s": float(gt.t_s[b - 1] - t0), "rmse_m": {}, "poses": {}}
        if parts:
            seg["rmse_h_m"], seg["rmse_v_m"] = {}, {}
        for name, (e_sorted, bounds, hv_sorted) in groups.items():
            sel = e_sorted[bounds[k]:bounds[k + 1]]
            seg["rmse_m"][name] = float(np.sqrt(np.mean(sel ** 2))) if sel.size else None
            seg["poses"][name] = int(sel.size)
            if hv_sorted is not None:
                hv = hv_sorted[bounds[k]:bounds[k + 1]]
                h, v = (float(x) for x in np.sqrt(np.mean(hv ** 2, axis=0))) if hv.size else (None, None)
                seg["rmse_h_m"][name], seg["rmse_v_m"][name] = h, v
        segs.append(seg)
    # the worst among full windows: the route's last stub (kitti-00's 3701-3707 m, a few poses) ranked among the five
    # worst on an RMSE of a handful of errors (a plot review); it stays in the table
    span = (lambda s: s["end_s"] - s["start_s"]) if by_time else (lambda s: s["end_m"] - s["start_m"])
    ranked = sorted((s for s in segs if s["rmse_m"].get(primary) is not None and span(s) >= 0.5 * L),
                    key=lambda s: -s["rmse_m"][primary])
    return {"by": "time" if by_time else "distance", "length": L, "segments": segs, "primary": primary,
            "secondary": secondary if secondary in errors else None, "worst": [s["index"] for s in ranked[:worst]]}
