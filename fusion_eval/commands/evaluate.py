"""``fusion-eval evaluate``: the full report for existing trajectory files (any localization system's output).

Files are TUM (8 values per line) or KITTI poses (12 values per line), recognised by their column count.
KITTI files take their stamps from a times file (``--ref-times``, ``--times``); without one, poses are
matched by index (frame i gets the stamp i seconds).
"""

from __future__ import annotations

import json
from pathlib import Path

from ..datasets.trajectory_file import read_trajectory
from ..evaluation.estimates import evaluate_series, validate_options
from ..outputs import StagedDir
from ..report.markdown import drift_section, fmt_stat, segments_section
from ..tables import markdown


def run_evaluate(reference: Path, estimates: list[Path], out_dir: Path, ref_times: Path | None, times: Path | None,
                 association: str, alignment: str, t_max_diff_s: float, rpe_delta_m: float, segment_m: float,
                 segment_s: float | None, overwrite: bool, make_plots: bool, engine: str = "arrays") -> dict:
    validate_options(association, alignment, t_max_diff_s, rpe_delta_m, segment_m, segment_s, engine)
    staged = StagedDir(out_dir, overwrite=overwrite)
    staged.check()
    ref, ref_how = read_trajectory(reference, ref_times)
    series, about = {}, {}
    for p in estimates:
        est, how = read_trajectory(p, times)
        name = Path(p).stem
        while name in series or name == "groundtruth":
            name += "_"
        series[name] = est
        about[name] = {"file": str(p), "stamps": how}
    m, evals = evaluate_series(ref, series, association, alignment, t_max_diff_s, rpe_delta_m, segment_m, segment_s, about,
                               ref_stamps=ref_how, engine=engine)
    metrics = {"reference": str(reference), "reference_stamps": ref_how, **m}
    with staged as out:
        out.write_text("metrics.json", json.dumps(metrics, indent=2) + "\n")
        written = []
        if make_plots:
            from ..report import plots

            plots.plot_generic_trajectories(out.path("trajectories.png"), ref, series)
            plots.plot_ape_over_time(out.path("ape_over_time.png"), evals, float(ref.t_s[0]))
            written = ["trajectories.png", "ape_over_time.png"]
            if any(ev.drift for ev in evals.values()):
                plots.plot_drift(out.path("kitti_drift.png"), evals)
                written.append("kitti_drift.png")
            if metrics["segments"]:
                plots.plot_segment_map(out.path("segments_map.png"), evals, metrics["segments"])
                written.append("segments_map.png")
        out.write_text("report.md", _report(metrics, written))
    return metrics


def _report(m: dict, plots: list[str]) -> str:
    e = m["evaluation"]
    L = [f"# fusion-eval evaluate: {Path(m['reference']).name}", "",
         f"Reference stamps: {m['reference_stamps']}. Association: **{e['association']}**"
         + (f" (within {e['t_max_diff_s']} s)" if e["association"] == "nearest" else " (reference interpolated at the estimate's stamps)")
         + f"; alignment: **{e['alignment']}**.", ""]
    rows = []
    for k, d in m["estimates"].items():
        ape = d.get("ape") or {}
        rpe = d.get("rpe_1frame") or {}
        rows.append([k, d["stamps"], f"{d['matched_poses']}/{d['poses']}", fmt_stat(ape.get("translation_m")),
                     f"{fmt_stat(ape.get('translation_m'), 'mean')} / {fmt_stat(ape.get('translation_m'), 'max')}",
                     fmt_stat(ape.get("rotation_deg")), fmt_stat(rpe.get("translation_m"), nd=4),
                     fmt_stat(rpe.get("rotation_deg"), nd=4)])
    L += markdown(["estimate", "stamps", "matched poses", "APE trans RMSE [m]", "APE trans mean / max [m]",
                   "APE rot RMSE [deg]", "RPE trans 1 frame RMSE [m]", "RPE rot 1 frame RMSE [deg]"], rows, align="llrrrrrr")
    for k, d in m["estimates"].items():
        if d.get("note"):
            L.append(f"\n- {k}: {d['note']}.")
        if d.get("alignment"):
            L.append(f"\n- {k}: alignment {json.dumps(d['alignment'])}.")
    L += drift_section(m) + segments_section(m)
    if plots:
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    return "\n".join(L) + "\n"
