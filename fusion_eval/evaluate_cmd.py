"""``fusion-eval evaluate``: the full report for existing trajectory files (any localization system's output).

Files are TUM (8 values per line) or KITTI poses (12 values per line), recognised by their column count.
KITTI files take their stamps from a times file (``--ref-times``, ``--times``); without one, poses are
matched by index (frame i gets the stamp i seconds).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .datasets import kitti_poses, tum
from .datasets._text import read_text
from .errors import DataFormatError
from .evaluation import EstimateEvaluation, evaluate
from .outputs import StagedDir
from .segments import breakdown
from .so3 import matrix_to_quat_xyzw
from .types import PoseSeries


def read_trajectory(path: Path, times: Path | None = None) -> tuple[PoseSeries, str]:
    """A TUM or KITTI trajectory; returns it and how its stamps were obtained."""
    path = Path(path)
    first = next((ln for ln in read_text(path, "a TUM or KITTI trajectory").splitlines()
                  if ln.strip() and not ln.lstrip().startswith("#")), "")
    n = len(first.split())
    if n == 8:
        return tum.read_tum(path), "TUM stamps"
    if n != 12:
        raise DataFormatError(path, None, f"expected a TUM (8 values per line) or KITTI (12 values) trajectory, got {n} values")
    T, lines = kitti_poses.read_kitti_poses(path)
    if times is not None:
        t, _ = kitti_poses.read_times(times)
        if t.size != T.shape[0]:
            raise DataFormatError(times, None, f"expected {T.shape[0]} times (one per pose of {path.name}), got {t.size}")
        how = f"times from {Path(times).name}"
    else:
        t, how = np.arange(T.shape[0], dtype=float), "frame index (no times file)"
    return PoseSeries(t_s=t, p_w_m=T[:, :3, 3], q_wb_xyzw=matrix_to_quat_xyzw(T[:, :3, :3]), source=str(path),
                      lines=lines), how


def run_evaluate(reference: Path, estimates: list[Path], out_dir: Path, ref_times: Path | None, times: Path | None,
                 association: str, alignment: str, t_max_diff_s: float, rpe_delta_m: float, segment_m: float,
                 segment_s: float | None, overwrite: bool, make_plots: bool) -> dict:
    staged = StagedDir(out_dir, overwrite=overwrite)
    staged.check()
    ref, ref_how = read_trajectory(reference, ref_times)
    names, evals = [], {}
    hows = {}
    for p in estimates:
        est, how = read_trajectory(p, times)
        name = Path(p).stem
        while name in names or name == "groundtruth":
            name += "_"
        names.append(name)
        hows[name] = how
        if how.startswith("frame index") != ref_how.startswith("frame index"):
            raise DataFormatError(p, None, "the reference and the estimates must both have stamps, or both be matched by index")
        evals[name] = evaluate(ref, est, name, t_max_diff_s, rpe_delta_m, association, alignment)
    errs = {k: (ev.ape_t_s, ev.ape_err_m) for k, ev in evals.items() if ev.ape_err_m is not None}
    seg = breakdown(ref, errs, segment_m, segment_s, primary=names[0], secondary=names[1] if len(names) > 1 else None) \
        if errs else None
    est_m = {}
    for k, ev in evals.items():
        est_m[k] = {"file": str(estimates[names.index(k)]), "stamps": hows[k], "poses": ev.poses,
                    "matched_poses": ev.matched_poses, **ev.metrics}
        if ev.drift:
            est_m[k]["kitti_drift"] = ev.drift
        if ev.alignment_params:
            est_m[k]["alignment"] = ev.alignment_params
        if ev.note:
            est_m[k]["note"] = ev.note
    metrics = {"reference": str(reference), "reference_stamps": ref_how,
               "evaluation": {"association": association, "alignment": alignment, "t_max_diff_s": t_max_diff_s},
               "estimates": est_m, "segments": seg}
    with staged as out:
        from .evaluation import ratio

        out.write_text("metrics.json", json.dumps(metrics, indent=2) + "\n")
        written = []
        if make_plots:
            from . import plots

            plots.plot_generic_trajectories(out.path("trajectories.png"), ref, {n: e for n, e in zip(names, _series(estimates, times))})
            plots.plot_ape_over_time(out.path("ape_over_time.png"), evals, float(ref.t_s[0]))
            written = ["trajectories.png", "ape_over_time.png"]
            if any(ev.drift for ev in evals.values()):
                plots.plot_drift(out.path("kitti_drift.png"), evals)
                written.append("kitti_drift.png")
            if seg:
                plots.plot_segment_map(out.path("segments_map.png"), evals, seg)
                written.append("segments_map.png")
        out.write_text("report.md", _report(metrics, evals, written, ratio))
    return metrics


def _series(paths, times):
    return [read_trajectory(p, times)[0] for p in paths]


def _report(m: dict, evals: dict[str, EstimateEvaluation], plots: list[str], ratio) -> str:
    from .report import _drift_section, _fmt, _segments_section

    e = m["evaluation"]
    L = [f"# fusion-eval evaluate: {Path(m['reference']).name}", "",
         f"Reference stamps: {m['reference_stamps']}. Association: **{e['association']}**"
         + (f" (within {e['t_max_diff_s']} s)" if e["association"] == "nearest" else " (reference interpolated at the estimate's stamps)")
         + f"; alignment: **{e['alignment']}**.", "",
         "| estimate | stamps | matched poses | APE trans RMSE [m] | APE trans mean / max [m] | APE rot RMSE [deg] | "
         "RPE trans 1 frame RMSE [m] | RPE rot 1 frame RMSE [deg] |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for k, d in m["estimates"].items():
        ape = d.get("ape") or {}
        rpe = d.get("rpe_1frame") or {}
        L.append(f"| {k} | {d['stamps']} | {d['matched_poses']}/{d['poses']} | {_fmt(ape.get('translation_m'))} | "
                 f"{_fmt(ape.get('translation_m'), 'mean')} / {_fmt(ape.get('translation_m'), 'max')} | "
                 f"{_fmt(ape.get('rotation_deg'))} | {_fmt(rpe.get('translation_m'), nd=4)} | {_fmt(rpe.get('rotation_deg'), nd=4)} |")
    for k, d in m["estimates"].items():
        if d.get("note"):
            L.append(f"\n- {k}: {d['note']}.")
        if d.get("alignment"):
            L.append(f"\n- {k}: alignment {json.dumps(d['alignment'])}.")
    L += _drift_section(m) + _segments_section(m)
    if plots:
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    return "\n".join(L) + "\n"
