"""``fusion-eval evaluate``: the full report for existing trajectory files (any localization system's output).

Files are TUM (8 values per line) or KITTI poses (12 values per line), recognised by their column count.
KITTI files take their stamps from a times file (``--ref-times``, ``--times``); without one, poses are
matched by index (frame i gets the stamp i seconds).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..datasets import kitti_poses, tum
from ..datasets._text import read_text
from ..errors import ConfigError, DataFormatError
from ..evaluation.run_metrics import estimate_metrics
from ..evaluation.segments import breakdown
from ..evaluation.trajectory import EstimateEvaluation, evaluate
from ..outputs import StagedDir
from ..report.markdown import drift_section, fmt_stat, segments_section
from ..so3 import matrix_to_quat_xyzw
from ..tables import markdown
from ..types import PoseSeries


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


ASSOCIATIONS = ("nearest", "interpolate")
ALIGNMENTS = ("none", "origin", "se3", "sim3", "4dof")


def validate_options(association: str, alignment: str, t_max_diff_s: float, rpe_delta_m: float, segment_m: float,
                     segment_s: float | None) -> None:
    """Refuse options ``evaluate`` cannot honour, naming the option."""
    if association not in ASSOCIATIONS:
        raise ConfigError(f"--association must be one of {', '.join(ASSOCIATIONS)}, got {association!r}")
    if alignment not in ALIGNMENTS:
        raise ConfigError(f"--alignment must be one of {', '.join(ALIGNMENTS)}, got {alignment!r}")
    for name, v in (("--t-max-diff", t_max_diff_s), ("--rpe-delta-m", rpe_delta_m), ("--segment-m", segment_m),
                    ("--segment-s", segment_s)):
        if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ConfigError(f"{name} must be a finite number > 0, got {v}")


def evaluate_series(ref: PoseSeries, estimates: dict[str, PoseSeries], association: str = "nearest",
                    alignment: str = "none", t_max_diff_s: float = 0.01, rpe_delta_m: float = 100.0,
                    segment_m: float = 100.0, segment_s: float | None = None,
                    about: dict | None = None) -> tuple[dict, dict[str, EstimateEvaluation]]:
    """evo's APE/RPE, the KITTI drift metric and the per-segment breakdown of each estimate against ``ref``:
    the ``metrics.json`` of ``fusion-eval evaluate`` and the evaluations behind it. ``about`` adds, per
    estimate, where it came from (file, how its stamps were obtained)."""
    evals = {name: evaluate(ref, est, name, t_max_diff_s, rpe_delta_m, association, alignment)
             for name, est in estimates.items()}
    names = list(evals)
    errs = {k: (ev.ape_t_s, ev.ape_err_m) for k, ev in evals.items() if ev.ape_err_m is not None}
    seg = breakdown(ref, errs, segment_m, segment_s, primary=names[0], secondary=names[1] if len(names) > 1 else None) \
        if errs else None
    est_m = {k: {**((about or {}).get(k) or {}), **estimate_metrics(ev)} for k, ev in evals.items()}
    metrics = {"evaluation": {"association": association, "alignment": alignment, "t_max_diff_s": t_max_diff_s,
                              "rpe_delta_m": rpe_delta_m},
               "estimates": est_m, "segments": seg}
    return metrics, evals


def run_evaluate(reference: Path, estimates: list[Path], out_dir: Path, ref_times: Path | None, times: Path | None,
                 association: str, alignment: str, t_max_diff_s: float, rpe_delta_m: float, segment_m: float,
                 segment_s: float | None, overwrite: bool, make_plots: bool) -> dict:
    validate_options(association, alignment, t_max_diff_s, rpe_delta_m, segment_m, segment_s)
    staged = StagedDir(out_dir, overwrite=overwrite)
    staged.check()
    ref, ref_how = read_trajectory(reference, ref_times)
    series, about = {}, {}
    for p in estimates:
        est, how = read_trajectory(p, times)
        name = Path(p).stem
        while name in series or name == "groundtruth":
            name += "_"
        if how.startswith("frame index") != ref_how.startswith("frame index"):
            raise DataFormatError(p, None, "the reference and the estimates must both have stamps, or both be matched by index")
        series[name] = est
        about[name] = {"file": str(p), "stamps": how}
    m, evals = evaluate_series(ref, series, association, alignment, t_max_diff_s, rpe_delta_m, segment_m, segment_s, about)
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
