"""A sensor's own frame clock recovered from the stamps of the IMU packets its frames were matched to.

KITTI's "sync" drives pick, for each camera/lidar frame, the OXTS packet nearest to it: the packets sit on
the OXTS 100 Hz grid, so the stamp a frame inherits is its true time +/- 5 ms (steps of 0.10 or 0.11 s for
a 0.1037 s scan period), with the odd glitch (a packet tens of ms early) and the provider-filled packets
at the start. At 10 m/s, 5 ms is 5 cm along track per increment: more than the lidar odometry's own
error. The scanner's period is smooth (it drifts by parts per thousand over minutes), so a robust local
straight-line fit of stamp against frame index recovers the frame times to about a millisecond.
"""

from __future__ import annotations

import numpy as np

# a residual beyond this after the first fit is a glitch, not quantisation (which is within +/- 5 ms)
_OUTLIER_S = 0.012


def _local_line(i: np.ndarray, t: np.ndarray, w: np.ndarray, k: int) -> np.ndarray:
    """Weighted least-squares line through ``(i, t)`` over the frames ``[j-k, j+k]``, evaluated at each ``j``
    (window sums by cumulative sums: O(n))."""
    n = i.size
    x = i - i[0]
    t0 = t[w > 0][0] if (w > 0).any() else 0.0
    y = np.where(w > 0, t - t0, 0.0)

    def wsum(v):
        c = np.concatenate(([0.0], np.cumsum(v)))
        lo = np.clip(np.arange(n) - k, 0, n)
        hi = np.clip(np.arange(n) + k + 1, 0, n)
        return c[hi] - c[lo]

    s0, s1, s2 = wsum(w), wsum(w * x), wsum(w * x * x)
    sy, sxy = wsum(w * y), wsum(w * x * y)
    det = s0 * s2 - s1 * s1
    with np.errstate(invalid="ignore", divide="ignore"):
        b = (s0 * sxy - s1 * sy) / det
        a = (sy - b * s1) / s0
    return t0 + a + b * x


def smooth_frame_times(t_s: np.ndarray, valid: np.ndarray, half_window_s: float) -> tuple[np.ndarray, dict]:
    """Frame times from matched packet stamps ``t_s`` (one per frame; ``valid`` False for filled packets).

    Returns the smoothed times and a summary (``residual_std_ms`` of the kept stamps about the fit, ``glitches``:
    stamps set aside as outliers, ``window_frames``). Needs at least 3 valid stamps in every window."""
    t = np.asarray(t_s, float)
    n = t.size
    i = np.arange(n, dtype=float)
    w = np.asarray(valid, bool).astype(float)
    if w.sum() < 3:
        return t.copy(), {"residual_std_ms": float("nan"), "glitches": 0, "window_frames": 0}
    period = float(np.median(np.diff(t[w > 0]))) if w.sum() > 1 else 0.1
    k = max(2, int(round(half_window_s / max(period, 1e-6))))
    fit = _local_line(i, t, w, k)
    keep = (w > 0) & (np.abs(t - fit) <= _OUTLIER_S)
    fit = _local_line(i, t, keep.astype(float), k)
    bad = ~np.isfinite(fit)
    if bad.any():                      # a window without enough stamps: keep what was there
        fit[bad] = t[bad]
    res = (t - fit)[keep]
    return fit, {"residual_std_ms": float(res.std() * 1e3) if res.size else float("nan"),
                 "glitches": int(((w > 0) & ~keep).sum()), "window_frames": int(2 * k + 1)}
