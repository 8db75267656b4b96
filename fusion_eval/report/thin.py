"""What the filter's plots draw, reduced where the full series live (numpy only, no matplotlib).

A plot 1000 pixels wide shows no more than a few thousand points. The run draws its plots in worker processes:
sending them a long drive's full series (an hour at 200 Hz: 720,000 poses, each series tens of MB) cost the
main process hundreds of MB of pickles and the workers as much again, to draw the same pixels. The reductions
here are the ones the plots applied themselves; what is computed over every epoch (the share of epochs inside
3 sigma, the ground truth's extent) is computed here over every epoch, so the PNGs are the same bytes.
"""

from __future__ import annotations

import numpy as np


def every(n: int, at_most: int = 2500) -> slice | np.ndarray:
    """The indices of at most ``at_most`` of ``n`` points, evenly strided, and always the last: a plot 1000 pixels
    wide shows no more, and its end is the series' end (a stride of 13 over a simulated 300 s at 100 Hz stopped
    0.09 s short, and the bias plot's "final" values were not the filter's final biases). The last point counts in
    the budget, so that thinning what was thinned changes nothing."""
    step = max(1, -(-(n - 1) // max(at_most - 1, 1)))
    if step == 1 or n == 0 or (n - 1) % step == 0:
        return slice(None, None, step)
    return np.r_[np.arange(0, n, step), n - 1]


def inside_3sigma_pct(e: np.ndarray, sg: np.ndarray) -> list[float]:
    """Per column, the percentage of epochs whose error is inside its +/-3 sigma (NaN: no sigma for that state)."""
    return [float(np.mean(np.abs(e[:, i]) <= 3 * sg[:, i]) * 100) if np.isfinite(sg[:, i]).any() else float("nan")
            for i in range(e.shape[1])]


def error_sigma(t_s: np.ndarray, err: np.ndarray, sigma: np.ndarray, smoothed=None) -> dict:
    """An error-against-3-sigma panel set's data: ``t_s``, ``err``, ``sigma`` (N, 3) and the smoother's
    ``(err, sigma)`` thinned by :func:`every`, and ``inside`` (filter, smoother): the shares of all epochs."""
    k = every(t_s.size)
    return {"t_s": t_s[k], "err": np.ascontiguousarray(err[k]), "sigma": np.ascontiguousarray(sigma[k]),
            "smoothed": None if smoothed is None else tuple(np.ascontiguousarray(a[k]) for a in smoothed),
            "inside": (inside_3sigma_pct(err, sigma), None if smoothed is None else inside_3sigma_pct(*smoothed))}


def att_vel(av: dict) -> dict:
    """:func:`fusion_eval.evaluation.run_metrics.fused_att_vel_error`'s dict as the attitude/velocity plot draws
    it: ``att`` and ``vel`` (None without a velocity), each :func:`error_sigma`, and ``vel_truth``."""
    sm = av.get("smoothed")
    att = error_sigma(av["t_s"], av["att_err_b_rad"], av["att_sigma_b_rad"], None if sm is None else (sm[0], sm[1]))
    vel = None
    if av.get("vel_err_w_mps") is not None:
        vel = error_sigma(av["t_s"], av["vel_err_w_mps"], av["vel_sigma_w_mps"],
                          None if sm is None or sm[2] is None else (sm[2], sm[3]))
    return {"att": att, "vel": vel, "vel_truth": av.get("vel_truth")}


def biases(t_s: np.ndarray, ba: np.ndarray, bg: np.ndarray, sigma: np.ndarray, truth=None) -> tuple:
    """The bias plot's arguments thinned by :func:`every` (``truth``: :func:`truth_biases` over the plotted span)."""
    k = every(t_s.size)
    if truth is not None and t_s.size:
        truth = truth_biases(truth, *plotted_span(t_s))
    return t_s[k], ba[k], bg[k], sigma[k], truth


def plotted_span(t_s: np.ndarray) -> tuple[float, float]:
    """The first and last of the stamps ``t_s`` that :func:`every` keeps."""
    kept = t_s[every(t_s.size)]
    return float(kept[0]), float(kept[-1])


def truth_biases(truth, t_first: float, t_last: float):
    """The true biases the bias plot draws against an estimate plotted over ``t_first..t_last``
    (:func:`plotted_span`): those inside it, thinned by :func:`every` (copies). Taking them again from the result
    changes nothing (at most 2,500 points are kept whole), so a run keeps only these from the start: a simulated
    hour's table is 38 MB."""
    from dataclasses import replace

    inside = np.flatnonzero((truth.t_s >= t_first) & (truth.t_s <= t_last))
    tk = inside[every(inside.size)]
    return replace(truth, t_s=truth.t_s[tk], accel_b_mps2=truth.accel_b_mps2[tk], gyro_b_rps=truth.gyro_b_rps[tk])


PATH_POINTS = 20000       # a path of 20,000 points is smooth at a plot's size


def paths(series: dict) -> tuple[dict, tuple]:
    """East/North/Up paths with their stamps, ``(n, 4)`` (E, N, U, t), of each series thinned to :data:`PATH_POINTS`,
    and the ground truth's extent ``(lo, hi, start)`` over all its poses (E, N, U: the axes fit it)."""
    out = {}
    for n, s in series.items():
        if s is not None and len(s):
            k = every(len(s), PATH_POINTS)
            out[n] = np.ascontiguousarray(np.column_stack([s.p_w_m[k], np.asarray(s.t_s)[k]]))
    # (a drive without ground truth: the axes fit the fused estimate)
    gt = series["groundtruth" if "groundtruth" in series else "fused"].p_w_m
    return out, (gt.min(axis=0), gt.max(axis=0), gt[0].copy())


def envelope(y: np.ndarray, at_most: int = 5000) -> np.ndarray:
    """Indices that keep a long series' look: above ``at_most`` points, the minimum and the maximum of each of
    ``at_most / 2`` consecutive bins, in order (a stride would drop the peaks a reader looks for). Shorter series
    are kept whole, so a plot of a short drive is unchanged; so is an envelope's own output (up to ``at_most + 2``
    points: each bin's two and both ends), so a series reduced here draws the same points in the plot."""
    n = len(y)
    if n <= at_most + 2:
        return np.arange(n)
    b = -(-n // (at_most // 2))
    m = -(-n // b)
    # NaN (a gap) and the padding never win a bin: +inf for the minimum, -inf for the maximum
    y = np.asarray(y, float)
    blocks_lo = np.concatenate([np.where(np.isnan(y), np.inf, y), np.full(m * b - n, np.inf)]).reshape(m, b)
    blocks_hi = np.concatenate([np.where(np.isnan(y), -np.inf, y), np.full(m * b - n, -np.inf)]).reshape(m, b)
    base = np.arange(m) * b
    k = np.concatenate([base + np.argmin(blocks_lo, axis=1), base + np.argmax(blocks_hi, axis=1), [0, n - 1]])
    return np.unique(np.minimum(k, n - 1))


def _lean(ev, **arrays):
    """``ev`` without its result files, evo objects and error parts (no plot reads them), with ``arrays`` replaced."""
    from dataclasses import replace

    return replace(ev, zips={}, results={}, **{"ape_hv_m": None, **arrays})


def ape_curves(evals: dict) -> dict:
    """The APE-over-time plot's evaluations: each APE series reduced to its :func:`envelope` (what the plot
    draws), nothing else of the arrays."""
    out = {}
    for n, ev in evals.items():
        if ev.ape_err_m is None:
            out[n] = _lean(ev, ref_p_m=None)
            continue
        k = envelope(ev.ape_err_m)
        out[n] = _lean(ev, ape_t_s=ev.ape_t_s[k], ape_err_m=ev.ape_err_m[k], ref_p_m=None)
    return out


def drift_only(evals: dict) -> dict:
    """The drift plot's evaluations: their KITTI drift figures, no arrays."""
    return {n: _lean(ev, ape_t_s=None, ape_err_m=None, ref_p_m=None) for n, ev in evals.items()}


def segment_map(evals: dict, seg: dict) -> dict:
    """The segment map's evaluations: the two it compares (whole: it colours every point of the route)."""
    keep = {seg.get("primary", "fused"), seg.get("secondary")}
    return {n: _lean(ev) for n, ev in evals.items() if n in keep}


def consistency(cons: dict) -> dict:
    """The NEES/NIS plot's data: each series reduced to its :func:`envelope` (summaries over every epoch kept)."""
    def reduce(d):
        if isinstance(d, dict) and "values" in d and "t_s" in d:
            v = np.asarray(d["values"])
            k = envelope(v)
            return {**d, "values": v[k], "t_s": np.asarray(d["t_s"])[k]}
        if isinstance(d, dict):
            return {key: reduce(val) for key, val in d.items()}
        return d
    return reduce(cons)
