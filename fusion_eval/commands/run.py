"""``fusion-eval run``: one dataset through the configured filter, evaluated and written."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from .. import resources, session
from ..outputs import default_dir
from ..pipeline import RunResult, run_to_dir
from ..tables import cell


def default_out_dir(dataset: Path, config_name: str) -> Path:
    """``results/<dataset>-<config>-<time>`` (made unique by :func:`fusion_eval.outputs.default_dir`)."""
    ds_name = resources.dataset_label(dataset.resolve())
    return Path("results") / f"{ds_name}-{config_name}-{time.strftime('%Y%m%d-%H%M%S')}"


def run(dataset: Path | None, config: Path | None, sets: tuple[str, ...], out_dir: Path | None, overwrite: bool = False,
        progress: Callable[[float], None] | None = None, trials: int = 1) -> RunResult:
    req = session.request(config=config, sets=sets)           # a bad configuration fails before any data is read
    # None stays None down to the dataset's loading: the default, against which a -c file of another drive's run is said
    dataset = None if dataset is None else resources.find(dataset)
    if out_dir is not None:
        return run_to_dir(dataset, req, out_dir, overwrite=overwrite, progress=progress, trials=trials)
    # the name says when --set items changed the run ("default" alone would claim the defaults; output.* keys,
    # such as --no-plots, change only what is written)
    changed = any(not s.strip().startswith("output.") for s in sets)
    named = resources.default_dataset() if dataset is None else dataset
    with default_dir(default_out_dir(named, req.source + ("-set" if changed else ""))) as out_dir:
        return run_to_dir(dataset, req, out_dir, overwrite=overwrite, progress=progress, trials=trials)


def no_truth_summary(metrics: dict) -> str:
    """What ``run`` prints for a drive without ground truth: no scores, the innovations per stream."""
    lines = ["no ground truth: nothing scored (report.md: the start from the data and the innovations)",
             f"{'stream':<14} {'updates':>8} {'mean NIS / dof':>15} {'inside 95 %':>12}"]
    from ..evaluation.run_metrics import measured_observations

    measured = measured_observations()
    for k, d in (metrics.get("nis") or {}).items():
        lines.append(f"{k:<14} {d['epochs']:>8} {d['mean'] / d['dof']:>15.3f} {d['fraction_in_95'] * 100:>11.1f}%"
                     + ("" if k in measured else "  (a constraint: low where the vehicle does not slip)"))
    inn = metrics.get("innovations") or {}
    if inn.get("updates"):
        lines.append(f"innovations: NLL per update {inn['nll_per_update']:.4f}, NIS calibration {inn['nis_calibration']:.4f}")
    return "\n".join(lines)


def summary_table(metrics: dict) -> str:
    """The table ``run`` prints: per estimate the matched poses, APE translation and rotation, RPE per frame."""
    def stat(d, nd):
        return cell(d["rmse"] if d else None, nd)

    if metrics.get("ground_truth") is False:
        return no_truth_summary(metrics)
    tr = metrics.get("trials")
    # with trials, the table is the run's own (trial 0), whose files these are; the means follow it (a plot review:
    # the table's 0.758 m stood unlabelled above the 0.775 m mean)
    lines = [f"trial 0 of {tr['n']} (this run's files):"] if tr else []
    lines.append(f"{'estimate':<10} {'matched':>8} {'APE trans RMSE [m]':>19} {'APE rot RMSE [deg]':>19} "
                 f"{'RPE trans 1 frame [m]':>22}")
    for name, m in metrics["estimates"].items():
        ape = m.get("ape", {})
        rpe = (m.get("rpe_1frame") or {}).get("translation_m")
        lines.append(f"{name:<10} {m['matched_poses']:>8} {stat(ape.get('translation_m'), 3):>19} "
                     f"{stat(ape.get('rotation_deg'), 3):>19} {stat(rpe, 4):>22}")
    for k, v in metrics["ratios"].items():
        if v is not None:
            lines.append(f"{k.replace('_', ' ')} (APE RMSE): {v:.3f}")
    if tr:
        lines.append(f"over {tr['n']} trials (mean +/- std, 95 % CI of the mean):")
        for p in ("fused.ape.translation_m.rmse", "ratios.fused_over_lidar", "ratios.fused_over_gnss"):
            st = tr["stats"].get(p)
            if st and st.get("n"):
                lo, hi = st["ci95_mean"]
                lines.append(f"  {p}: {st['mean']:.3f} +/- {st['std']:.3f} ({lo:.3f} .. {hi:.3f})")
        if tr.get("failed"):
            lines.append(f"  {len(tr['failed'])} trials failed (see report.md)")
    return "\n".join(lines)
