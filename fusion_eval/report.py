"""Run outputs: TUM trajectories, metrics (JSON, CSV), evo result zips, Markdown report, plots.

Every file goes through :class:`fusion_eval.outputs.StagedDir`, so each is written atomically and
the directory appears only when complete. Nothing time- or machine-dependent is written (no wall
times, no absolute paths beyond the inputs), so the same inputs and seed give the same bytes.
"""

from __future__ import annotations

import copy
import csv
import io
import json
import platform

import numpy as np
import yaml
from evo.tools import file_interface

from . import __version__, plots
from .datasets.tum import format_tum
from .evaluation import STATS, EstimateEvaluation
from .interp import interpolate_poses
from .outputs import StagedDir
from .types import PoseSeries

ESTIMATES = ("fused", "lidar", "gnss", "imu_only")
TUM_FILES = {"fused": "fused.tum", "lidar": "lidar.tum", "gnss": "gnss.tum", "imu_only": "imu_only.tum",
             "groundtruth": "groundtruth.tum"}


def versions() -> dict:
    """Versions of Python and of the packages that produced the numbers (read from metadata, no imports)."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"fusion-eval": __version__, "python": platform.python_version()}
    for pkg in ("numpy", "scipy", "evo", "numba", "pymap3d", "matplotlib", "pandas", "pyyaml", "click"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


def _strip_arrays(d: dict) -> dict:
    return {k: v for k, v in d.items() if k not in ("t_s", "values")}


def build_metrics(dataset: str, evals: dict[str, EstimateEvaluation], ratios: dict, applied: dict,
                  gnss_info: dict | None, extra: dict | None = None) -> dict:
    est = {}
    for name, ev in evals.items():
        est[name] = {"poses": ev.poses, "matched_poses": ev.matched_poses, **ev.metrics}
        if ev.drift is not None:
            est[name]["kitti_drift"] = ev.drift
        if ev.alignment_params is not None:
            est[name]["alignment"] = ev.alignment_params
        if ev.note:
            est[name]["note"] = ev.note
    extra = extra or {}
    cons = extra.get("consistency", {})
    first = next(iter(evals.values()), None)
    return {"dataset": dataset,
            "evaluation": {"association": getattr(first, "association", "nearest"),
                           "alignment": getattr(first, "alignment", "none")},
            "estimates": est, "ratios": ratios,
            "nis": {k: _strip_arrays(v) for k, v in cons.get("nis", {}).items()},
            "nees": {k: _strip_arrays(v) for k, v in cons.get("nees", {}).items()},
            "segments": extra.get("segments"),
            "gnss_degradation": gnss_info, "preprocessing": applied}


def metrics_csv(evals: dict[str, EstimateEvaluation], ratios: dict) -> str:
    cols = ["estimate", "poses", "matched_poses"]
    rows = []
    groups = []
    for ev in evals.values():
        for g, d in ev.metrics.items():
            for rel in d:
                if (g, rel) not in groups:
                    groups.append((g, rel))
    for g, rel in groups:
        cols += [f"{g}_{rel}_{s}" for s in STATS]
    cols += ["fused_over_this_ape_rmse"]
    for name, ev in evals.items():
        row = {"estimate": name, "poses": ev.poses, "matched_poses": ev.matched_poses}
        for g, rel in groups:
            d = (ev.metrics.get(g) or {}).get(rel)
            for s in STATS:
                row[f"{g}_{rel}_{s}"] = "" if not d else f"{d[s]:.6f}"
        r = ratios.get(f"fused_over_{name}")
        row["fused_over_this_ape_rmse"] = "" if r is None else f"{r:.6f}"
        rows.append(row)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def _drift_section(m: dict) -> list[str]:
    rows = [(k, v["kitti_drift"]) for k, v in m["estimates"].items() if v.get("kitti_drift")]
    if not rows:
        return []
    L = ["", "## KITTI drift metric", "",
         "Averaged over all segments of 100, 200, ..., 800 m starting every 10 frames (the KITTI odometry devkit's definition).", "",
         "| estimate | translational error [%] | rotational error [deg/100 m] | segments |", "|---|---:|---:|---:|"]
    L += [f"| {k} | {d['t_err_pct']:.3f} | {d['r_err_deg_per_100m']:.4f} | {d['segments']} |" for k, d in rows]
    return L


def _consistency_section(m: dict) -> list[str]:
    L = ["", "## Filter consistency", "",
         "| quantity | epochs | dof | mean | 95 % interval | fraction inside |", "|---|---:|---:|---:|---|---:|"]
    for label, group in (("NEES", m.get("nees") or {}), ("NIS", m.get("nis") or {})):
        for k, d in group.items():
            lo, hi = d["bounds_95"]
            L.append(f"| {label} {k} | {d['epochs']} | {d['dof']} | {d['mean']:.2f} | [{lo:.2f}, {hi:.2f}] | "
                     f"{d['fraction_in_95'] * 100:.1f} % |")
    L += ["", "NEES uses the filter's covariance and its error against the ground truth; NIS the innovations alone. A "
          "consistent filter has a mean near the dof and about 95 % inside; a mean well below means the filter is "
          "conservative (noise too large), well above overconfident."]
    return L


def _segments_section(m: dict) -> list[str]:
    seg = m.get("segments")
    if not seg or not seg["segments"]:
        return []
    skip = ("imu_only",)   # dead reckoning's kilometres would drown the table
    names = [k for k in seg["segments"][0]["rmse_m"] if k not in skip and any(s["rmse_m"].get(k) is not None for s in seg["segments"])]
    a, b = seg.get("primary", "fused"), seg.get("secondary")
    unit = "m" if seg["by"] == "distance" else "s"
    L = ["", f"## Per-segment breakdown (every {seg['length']:g} {unit} along the route)", "",
         "| segment | route [m] | time [s] | " + " | ".join(f"{n} APE RMSE [m]" for n in names)
         + (f" | {a} - {b} [m] |" if b else " |"), "|---|---|---|" + "---:|" * (len(names) + bool(b))]
    for s in seg["segments"]:
        r = s["rmse_m"]
        cells = " | ".join("n/a" if r.get(n) is None else f"{r[n]:.3f}" for n in names)
        diff = ""
        if b:
            diff = " | " + ("n/a" if r.get(a) is None or r.get(b) is None else f"{r[a] - r[b]:+.3f}")
        L.append(f"| {s['index']} | {s['start_m']:.0f}-{s['end_m']:.0f} | {s['start_s']:.0f}-{s['end_s']:.0f} | {cells}{diff} |")
    by_i = {s["index"]: s for s in seg["segments"]}
    L += ["", f"Worst segments for {a}: " + ", ".join(
        f"{i} ({by_i[i]['start_m']:.0f}-{by_i[i]['end_m']:.0f} m, {by_i[i]['rmse_m'][a]:.3f} m)" for i in seg["worst"]) + ".", ""]
    return L


def _fmt(d, key="rmse", nd=3):
    if not d:
        return "n/a"
    return f"{d[key]:.{nd}f}"


def report_md(dataset: str, config_name: str, evals: dict, ratios: dict, cfg: dict, applied: dict,
              gnss_info: dict | None, metrics: dict, plots_written: list[str]) -> str:
    L = [f"# fusion-eval run: {dataset}", "", f"Configuration: `{config_name}`; lidar update: "
         f"**{cfg['filter']['lidar_update']}**, GNSS fused: **{'yes' if cfg['filter']['use_gnss'] else 'no'}**, "
         f"bias model: **{cfg['filter']['bias_model']}**.", "",
         "## Summary against ground truth (evo, no alignment)", "",
         "| estimate | matched poses | APE trans RMSE [m] | APE trans mean / max [m] | APE rot RMSE [deg] | "
         f"RPE trans 1 frame RMSE [m] | RPE rot 1 frame RMSE [deg] | RPE trans {cfg['evaluation']['rpe_delta_m']:g} m RMSE [m] |",
         "|---|---:|---:|---:|---:|---:|---:|---:|"]
    dm = f"rpe_{cfg['evaluation']['rpe_delta_m']:g}m"
    for name in ESTIMATES:
        ev = evals.get(name)
        if ev is None:
            continue
        m = ev.metrics
        ape_t = (m.get("ape") or {}).get("translation_m")
        L.append(f"| {name} | {ev.matched_poses}/{ev.poses} | {_fmt(ape_t)} | "
                 f"{_fmt(ape_t, 'mean')} / {_fmt(ape_t, 'max')} | {_fmt((m.get('ape') or {}).get('rotation_deg'))} | "
                 f"{_fmt((m.get('rpe_1frame') or {}).get('translation_m'), nd=4)} | "
                 f"{_fmt((m.get('rpe_1frame') or {}).get('rotation_deg'), nd=4)} | "
                 f"{_fmt((m.get(dm) or {}).get('translation_m'))} |")
    L.append("")
    for k, v in ratios.items():
        if v is None:
            continue
        other = k.replace("fused_over_", "")
        verdict = "better" if v < 1 else "worse"
        L.append(f"- Fused APE RMSE / {other} APE RMSE = **{v:.3f}** (fusion is {verdict} than {other} alone, "
                 f"{abs(1 - v) * 100:.1f} % {'lower' if v < 1 else 'higher'}).")
    for name, ev in evals.items():
        if ev.note:
            L.append(f"- {name}: {ev.note}.")
    ev0 = metrics.get("evaluation", {})
    L += ["", f"Association: **{ev0.get('association', 'nearest')}**"
          + (f" (nearest stamp within {cfg['evaluation']['t_max_diff_s']} s)" if ev0.get("association") == "nearest" else
             " (reference interpolated at the estimate's stamps: linear position, SLERP rotation)")
          + f"; alignment: **{ev0.get('alignment', 'none')}**. Matched poses are in the table above."]
    L += _drift_section(metrics) + _consistency_section(metrics) + _segments_section(metrics)
    L += ["## GNSS degradation", ""]
    if gnss_info is None:
        L.append("The dataset has no GNSS stream.")
    elif not gnss_info.get("degraded", True):
        L.append(f"The GNSS stream is a receiver's output (the manifest does not mark it for degradation): used as it is, "
                 f"{gnss_info['fixes_used']} fixes; std given to the filter: {gnss_info['std_given_to_filter_m']}.")
    else:
        rate = "every fix kept" if gnss_info["rate_hz"] is None else f"decimated to {gnss_info['rate_hz']:g} Hz"
        L.append(f"KITTI's OXTS position is the GPS/INS solution that is also the ground truth, so it was degraded: "
                 f"{rate} ({gnss_info['fixes_in']} -> {gnss_info['fixes_after_decimation']} fixes), white noise with std "
                 f"{gnss_info['noise_std_m']} m (E, N, U; seed {gnss_info['seed']}), outages {gnss_info['outages_s'] or 'none'} s "
                 f"({gnss_info['fixes_in_outages']} fixes removed); {gnss_info['fixes_used']} fixes used. "
                 f"Std given to the filter: {gnss_info['std_given_to_filter_m']}.")
    L += ["", "## Pre-processing applied", "",
          f"- Start: t = {applied['t_start_s']:.6f} s (first IMU sample covered by ground truth"
          f"{' and lidar' if cfg['filter']['lidar_update'] != 'none' else ''}).",
          f"- Filled-in IMU packets: {applied['imu_filled_samples']} ({applied['imu_filled_packets']}); filled-in "
          "ground-truth and GNSS packets are never used.",
          f"- Gyro lag correction: {applied['gyro_lag_s'] * 1000:.1f} ms.",
          f"- Time offsets [s]: {applied['time_offset_s']}.",
          f"- Gravity: {applied['gravity_mps2']:.5f} m/s^2."]
    if "lidar_anchor_t_s" in applied:
        L.append(f"- Lidar odometry anchored at the ground-truth pose at t = {applied['lidar_anchor_t_s']:.6f} s; "
                 f"{'resampled on the IMU stamps' if cfg['lidar']['interpolate_to_imu'] else 'at its own stamps'}.")
    if plots_written:
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots_written]
    L += ["", "## Configuration", "", "```yaml", yaml.safe_dump(cfg, sort_keys=False).rstrip(), "```", ""]
    return "\n".join(L)


def write_evo_results(out: StagedDir, ev: EstimateEvaluation) -> list[str]:
    """evo result zips (``evo_res`` reads them), one per metric: ``<metric>_<estimate>.zip``."""
    names = []
    for key, res in ev.results.items():
        zname = f"{key}_{ev.name}.zip"
        if key.startswith("rpe"):
            # the RPE zips keep evo's statistics and error arrays (what evo_res reads); the reduced copies of the
            # trajectories that evo_rpe adds cost most of the writing time and are in the APE zips in full
            res = copy.copy(res)
            res.trajectories = {}
        file_interface.save_res_file(out.path(zname), res, confirm_overwrite=False)
        out.normalize_zip(zname)
        names.append(zname)
    return names


def write_series_and_plots(out: StagedDir, series: dict[str, PoseSeries], filt, make_plots: bool) -> list[str]:
    """TUM files and the plots that need no evaluation (run while evo evaluates in other processes)."""
    for name, fname in TUM_FILES.items():
        s = series.get(name)
        if s is not None:
            hdr = f"fusion-eval {__version__} {name}: timestamp tx ty tz qx qy qz qw (world = local ENU, body = IMU)"
            if not s.has_orientation:
                hdr += "\nposition only: quaternions are identity placeholders"
            out.write_text(fname, format_tum(s, hdr))
    if not make_plots:
        return []
    gt = series["groundtruth"]
    plots.plot_trajectories(out.path("trajectories.png"), series)
    plots.plot_biases(out.path("biases.png"), filt.fused.t_s, filt.accel_bias_b, filt.gyro_bias_b, filt.sigma)
    # ground truth interpolated at the fused stamps inside its span
    gt_i = interpolate_poses(gt, filt.fused.t_s)
    sel = np.isin(filt.fused.t_s, gt_i.t_s)
    plots.plot_error_sigma(out.path("fused_error_3sigma.png"), gt_i.t_s, filt.fused.p_w_m[sel] - gt_i.p_w_m,
                           filt.sigma[sel])
    return ["trajectories.png", "ape_over_time.png", "biases.png", "fused_error_3sigma.png"]


def write_results(out: StagedDir, *, dataset: str, config_name: str, cfg: dict, resolved_extra: dict,
                  evals: dict[str, EstimateEvaluation], ratios: dict, applied: dict, gnss_info: dict | None, filt,
                  plots_written: list[str], extra: dict | None = None, pool=None) -> dict:
    """Metrics, resolved configuration, the plots that need the metrics (on ``pool`` when given, while
    this process writes the rest), and the report."""
    metrics = build_metrics(dataset, evals, ratios, applied, gnss_info, extra)
    out.write_text("metrics.json", json.dumps(metrics, indent=2, sort_keys=False) + "\n")
    out.write_text("metrics.csv", metrics_csv(evals, ratios))
    resolved = {**cfg, **resolved_extra, "versions": versions()}
    out.write_text("config.resolved.yaml", yaml.safe_dump(resolved, sort_keys=False))
    jobs = []
    if plots_written:
        t0 = float(filt.fused.t_s[0])
        jobs.append((plots.plot_ape_over_time, out.path("ape_over_time.png"), evals, t0))
        plots_written = list(plots_written)
        if any(ev.drift for ev in evals.values()):
            jobs.append((plots.plot_drift, out.path("kitti_drift.png"), evals))
            plots_written.append("kitti_drift.png")
        if extra and extra.get("consistency", {}).get("nees"):
            jobs.append((plots.plot_consistency, out.path("consistency.png"), extra["consistency"], t0))
            plots_written.append("consistency.png")
        if extra and extra.get("segments") and "fused" in evals:
            jobs.append((plots.plot_segment_map, out.path("segments_map.png"), evals, extra["segments"]))
            plots_written.append("segments_map.png")
    futures = [pool.submit(*j) for j in jobs] if pool is not None else [j[0](*j[1:]) for j in jobs]
    out.write_text("report.md", report_md(dataset, config_name, evals, ratios, cfg, applied, gnss_info, metrics,
                                          plots_written))
    for f in futures:
        if pool is not None:
            f.result()
    return metrics
