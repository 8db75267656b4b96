"""Outputs of ``fusion-eval track``: estimates CSV, RMSE and NIS in JSON, and a plot."""

from __future__ import annotations

import json

import numpy as np
from ..stats import chi2_ppf

from ..outputs import StagedDir
from .ekf import TrackResult, rmse

DOF = {"L": 2, "R": 3}


def nis_summary(res: TrackResult) -> dict:
    out = {}
    for k, name in (("L", "lidar"), ("R", "radar")):
        v = res.nis[(res.kind == k) & np.isfinite(res.nis)]
        if v.size == 0:
            continue
        line = float(chi2_ppf(0.95, DOF[k]))
        out[name] = {"updates": int(v.size), "dof": DOF[k], "mean": float(v.mean()), "median": float(np.median(v)),
                     "chi2_95": line,
                     "fraction_above_95": float(np.mean(v > line))}
    return out


MISFIT_NIS_RATIO = 20.0      # a sensor whose median NIS is this many times its dof is not followed (as in a run)


def warnings_of(res: TrackResult, nis: dict, max_gap_s: float = 5.0) -> list[str]:
    """What the user must hear: a sensor the tracker does not follow (a timestamp in ms read as us made every
    prediction step 1000x short: lidar NIS 1.1e4 for 2 dof (median), RMSE 100x, and no word), skipped radar
    readings."""
    out = []
    for name, d in nis.items():
        if d["median"] > MISFIT_NIS_RATIO * d["dof"]:         # the median: one outlier does not make a unit error
            out.append(f"{name}: median NIS {d['median']:.4g} for {d['dof']} dof: the tracker does not follow this sensor; "
                       "check the units of the file (timestamps in microseconds, positions in m, angles in rad) and the "
                       "noise settings")
    if res.skipped:
        out.append(f"{res.skipped} radar reading(s) not used: the estimate within 0.1 mm of the sensor, where the radar "
                   "model cannot be linearised")
    if res.dropouts:
        out.append(f"{len(res.dropouts)} radar reading(s) of range 0 not used (dropouts): line(s) "
                   f"{_lines(res.dropouts)}")
    if res.restarts:
        line, gap = max(res.restarts, key=lambda r: r[1])
        out.append(f"{len(res.restarts)} gap(s) of over {max_gap_s:g} s between measurements (the longest {gap:.4g} s, "
                   f"before line {line}): the tracker restarted from the measurement after each (--max-gap), its "
                   "prediction across being worthless")
    return out


def _lines(lines, shown: int = 5) -> str:
    head = ", ".join(map(str, lines[:shown]))
    return head + (f" and {len(lines) - shown} more" if len(lines) > shown else "")


def nees_summary(res: TrackResult, smoothed: bool = False) -> dict | None:
    """The state's NEES against the truth (4 dof): mean and share above the 95 % line, as the NIS; per-axis 3-sigma
    shares looked healthy on a simulated file whose whole-state NEES was 5.2 for 4 dof (a review)."""
    x, P = (res.x_smoothed, res.P_smoothed) if smoothed else (res.x, res.P)
    if x is None or P is None:
        return None
    from ..evaluation.consistency import nees

    e = x - res.gt
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(P), axis=(1, 2))
    if not ok.any():
        return None
    try:
        v = nees(e[ok], P[ok])
    except np.linalg.LinAlgError:       # a singular covariance: no consistency figure to give
        return None
    line = float(chi2_ppf(0.95, 4))
    return {"epochs": int(v.size), "dof": 4, "mean": float(v.mean()), "median": float(np.median(v)), "chi2_95": line,
            "fraction_above_95": float(np.mean(v > line))}


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None        # strict JSON has no NaN (a one-line input has no RMSE)


def write_track_outputs(out: StagedDir, res: TrackResult, params, source: str, make_plots: bool) -> dict:
    import logging

    e = rmse(res)
    nis = nis_summary(res)
    warns = warnings_of(res, nis, params.max_gap_s)
    for w in warns:
        logging.getLogger(__name__).warning(w)
    from .. import provenance

    # what produced the figures and from which bytes (a track's outputs named neither: a reproducibility review)
    made = {**provenance.header(), "input_sha256": provenance.files([("input", source)])[0]["sha256"]}
    metrics = {"input": source, "produced_by": made, "sensors": params.sensors, "estimates": int(len(res.t_us)),
               "rmse": {"px": _finite(e[0]), "py": _finite(e[1]), "vx": _finite(e[2]), "vy": _finite(e[3])},
               "nis": nis, "nees": nees_summary(res), "warnings": warns,
               "restarts": [{"line": ln, "gap_s": g} for ln, g in res.restarts], "radar_dropouts": len(res.dropouts),
               "params": {"noise_ax": params.noise_ax, "noise_ay": params.noise_ay, "lidar_var": list(params.lidar_var),
                          "radar_var": list(params.radar_var), "max_gap_s": params.max_gap_s}}
    sm = res.x_smoothed is not None
    if sm:
        es = rmse(res, smoothed=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = es / e
        metrics["smoothed"] = {"method": "rts", "rmse": dict(zip(("px", "py", "vx", "vy"), map(_finite, es))),
                               "over_filter": dict(zip(("px", "py", "vx", "vy"), map(_finite, ratio))),
                               "nees": nees_summary(res, smoothed=True)}
    rows = ["timestamp_us,sensor,px,py,vx,vy,px_gt,py_gt,vx_gt,vy_gt,nis" + (",px_s,py_s,vx_s,vy_s" if sm else "")]
    for i in range(len(res.t_us)):
        rows.append(",".join([str(int(res.t_us[i])), str(res.kind[i])] + [f"{v:.6f}" for v in res.x[i]] +
                             [f"{v:.6f}" for v in res.gt[i]] + ["" if not np.isfinite(res.nis[i]) else f"{res.nis[i]:.6f}"]
                             + ([f"{v:.6f}" for v in res.x_smoothed[i]] if sm else [])))
    out.write_text("estimates.csv", "\n".join(rows) + "\n")
    out.write_text("metrics.json", json.dumps(metrics, indent=2) + "\n")
    if make_plots:
        _plot(out, res, metrics, params.max_gap_s)
    return metrics


def _gap_ends(t_s: np.ndarray, gap_s: float) -> np.ndarray:
    """The first stamps after each gap of over ``gap_s`` (of the whole series: a thinned one's strides are not gaps)."""
    return t_s[np.flatnonzero(np.diff(t_s) > gap_s) + 1]


def _broken(t_s: np.ndarray, gap_ends: np.ndarray, *arrays):
    """``t_s`` and ``arrays`` (rows along it) with a NaN row inserted before each of ``gap_ends``
    (:func:`_gap_ends`): the lines break there (an hour's gap was drawn as a straight error line under a narrow
    band)."""
    at = np.searchsorted(t_s, gap_ends)
    if at.size == 0:
        return (t_s, *arrays)
    return tuple(None if a is None else np.insert(np.asarray(a, float), at, np.nan, axis=0) for a in (t_s, *arrays))


def _plot(out: StagedDir, res: TrackResult, metrics: dict, gap_s: float = 5.0) -> None:
    from ..report.plots import subplots      # figures of their own: the host's backend is left as it is

    fig, ax = subplots(figsize=(8, 7))
    lid = res.kind == "L"
    rad = res.kind == "R"
    ax.plot(res.z[lid, 0], res.z[lid, 1], "o", ms=3, mfc="none", color="tab:blue", label="lidar")
    rz = res.z[rad]
    ax.plot(rz[:, 0] * np.cos(rz[:, 1]), rz[:, 0] * np.sin(rz[:, 1]), "x", ms=3, color="tab:orange", label="radar (to x, y)")
    # the estimates wide and under the truth, the truth a thin line over them: drawn over it, the estimate hid it (a
    # plot review)
    t_all = (res.t_us - res.t_us[0]) / 1e6
    ends = _gap_ends(t_all, gap_s)
    _, x_line, xs_line, gt_line = _broken(t_all, ends, res.x, res.x_smoothed, res.gt)
    ax.plot(x_line[:, 0], x_line[:, 1], "-", color="tab:red", lw=2.4, alpha=0.7, label="estimate")
    def three(r):
        units = {"px": "m", "py": "m", "vx": "m/s", "vy": "m/s"}
        return ", ".join(f"{k} " + ("n/a" if r[k] is None else f"{r[k]:.3f} {units[k]}") for k in ("px", "py", "vx", "vy"))

    title = f"RMSE {three(metrics['rmse'])}"
    if res.x_smoothed is not None:
        ax.plot(xs_line[:, 0], xs_line[:, 1], "-", color="tab:purple", lw=1.6, alpha=0.8, label="smoothed (RTS)")
        title += f"\nsmoothed: {three(metrics['smoothed']['rmse'])}"
    ax.plot(gt_line[:, 0], gt_line[:, 1], "-", color="black", lw=0.8, label="ground truth")
    ax.plot(res.gt[0, 0], res.gt[0, 1], ">", ms=8, color="black", mfc="white", label="start")
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="box")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(out.path("track.png"), dpi=110, metadata={"Software": None})
    fig.clear()
    fig, axes = subplots(2, 1, figsize=(9, 5), sharex=True)
    t = (res.t_us - res.t_us[0]) / 1e6
    for ax, k, name in ((axes[0], "L", "lidar"), (axes[1], "R", "radar")):
        m = (res.kind == k) & np.isfinite(res.nis)
        ax.plot(*_broken(t[m], ends, res.nis[m]), ".-", ms=3, lw=0.6, label=f"NIS {name}")
        if name in metrics["nis"]:
            d = metrics["nis"][name]
            ax.axhline(d["chi2_95"], color="tab:red", ls="--", label="95 % chi-square")
            ax.axhline(d["dof"], color="black", lw=0.6, label="dof: a consistent filter's mean")
            # the figures a reader checks the plot against (they were in metrics.json only: a plot review)
            ax.set_title(f"NIS {name}: mean {d['mean']:.2f} for {d['dof']} dof, {100 * d['fraction_above_95']:.1f} % "
                         "above the 95 % line (5 % if consistent)", fontsize=9, loc="left")
        ax.set_ylabel(f"NIS {name}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[1].set_xlabel("time [s]")
    fig.subplots_adjust(left=0.09, right=0.98, top=0.92, bottom=0.1, hspace=0.35)
    fig.savefig(out.path("nis.png"), dpi=110, metadata={"Software": None})
    fig.clear()
    if res.P is not None:
        _plot_errors(out, res, t, gap_s)


def _plot_errors(out: StagedDir, res: TrackResult, t: np.ndarray, gap_s: float = 5.0) -> None:
    """``errors.png``: each state's error against the truth over time with the filter's +/-3 sigma (and the
    smoother's), the run's error panels (:func:`fusion_eval.report.plots.error_sigma_panels`): where the error is,
    the first seconds' velocity (a plot review), and whether the covariance is honest."""
    from ..report import thin
    from ..report.plots import error_sigma_panels, subplots

    def sigma(P):
        return np.sqrt(np.maximum(np.einsum("nii->ni", P), 0.0))

    err, sg = res.x - res.gt, sigma(res.P)
    sm = None if res.x_smoothed is None or res.P_smoothed is None else (res.x_smoothed - res.gt, sigma(res.P_smoothed))
    names = ("px", "py", "vx", "vy")
    ends = _gap_ends(t, gap_s)
    fig, axes = subplots(4, 1, figsize=(10, 8), sharex=True)
    for cols, unit in ((slice(0, 2), "m"), (slice(2, 4), "m/s")):      # positions, then velocities
        d = thin.error_sigma(t, err[:, cols], sg[:, cols], None if sm is None else (sm[0][:, cols], sm[1][:, cols]))
        t_b, e_b, s_b, *smb = _broken(d["t_s"], ends, d["err"], d["sigma"], *(d["smoothed"] or ()))
        d = {**d, "t_s": t_b, "err": e_b, "sigma": s_b, "smoothed": tuple(smb) if smb else None}
        error_sigma_panels(axes[cols], d, names[cols], unit, titles=tuple(f"{n} error" for n in names[cols]))
    axes[0].legend(fontsize=7, loc="upper right", ncol=2)
    axes[-1].set_xlabel("time [s]")
    fig.subplots_adjust(left=0.09, right=0.98, top=0.95, bottom=0.07, hspace=0.4)
    fig.savefig(out.path("errors.png"), dpi=110, metadata={"Software": None})
    fig.clear()
