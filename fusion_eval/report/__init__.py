"""The report layer: it only writes. Files (:mod:`.files`), Markdown (:mod:`.markdown`), plots (:mod:`.plots`).

A run is written in two phases so that a run can start the first while evo still evaluates the estimates
in other processes: :func:`write_filter_outputs` needs only the filter's output (TUM files and the plots of
the filter), :func:`write_evaluation` the evaluation (result zips, metrics, configuration, the plots of
the metrics, the report). :func:`write_run` does both. Every file goes through
:class:`fusion_eval.outputs.StagedDir`: written atomically, the directory appearing only when complete.
"""

from __future__ import annotations

from ..outputs import StagedDir
from . import files
from .markdown import report_md

FILTER_PLOTS = ["trajectories.png", "ape_over_time.png", "biases.png", "fused_error_3sigma.png"]


def write_filter_outputs(out: StagedDir, series: dict, filt, fused_err: dict, make_plots: bool, pool=None) -> list:
    """TUM files and the plots that need no evaluation, each a job of its own on ``pool`` when given (so that
    they spread over the workers). Returns the futures to wait for (or nothing: done here); the plots the
    report lists are :func:`filter_plots` (``ape_over_time.png`` is drawn with the metrics, in
    :func:`write_evaluation`)."""
    jobs = [(_write_tums, out, series)]
    if make_plots:
        from . import plots

        jobs += [(plots.plot_trajectories, out.path("trajectories.png"), series),
                 (plots.plot_biases, out.path("biases.png"), filt.fused.t_s, filt.accel_bias_b, filt.gyro_bias_b,
                  filt.sigma),
                 (plots.plot_error_sigma, out.path("fused_error_3sigma.png"), fused_err["t_s"], fused_err["err_w_m"],
                  fused_err["sigma_w_m"], fused_err.get("smoothed"))]
    if pool is None:
        for j in jobs:
            j[0](*j[1:])
        return []
    return [pool.submit(*j) for j in jobs]


def filter_plots(make_plots: bool) -> list[str]:
    """The plots :func:`write_filter_outputs` draws."""
    return list(FILTER_PLOTS) if make_plots else []


def _write_tums(out: StagedDir, series: dict) -> None:
    for name, fname in files.TUM_FILES.items():
        s = series.get(name)
        if s is not None:
            out.write_text(fname, files.tum_text(name, s))


def write_evaluation(out: StagedDir, res, plots_written: list[str], pool=None) -> None:
    """Result zips, metrics (JSON, CSV), the resolved configuration, the plots that need the metrics (on
    ``pool`` when given, while this process writes the rest), and the report."""
    for ev in res.evals.values():
        for name, data in ev.zips.items():
            out.write_bytes(name, data)
    out.write_text("metrics.json", files.metrics_json(res.metrics))
    out.write_text("metrics.csv", files.metrics_csv(res.evals, res.ratios))
    if res.metrics.get("trials"):
        from ..tables import csv_text
        from ..trials import csv_rows

        out.write_text("trials.csv", csv_text(*csv_rows(res.metrics["trials"]), float_format="{:.6g}"))
    out.write_text("config.resolved.yaml", files.resolved_config(res.cfg, res.resolved_extra))
    jobs = []
    plots_written = list(plots_written)
    if plots_written:
        from . import plots

        t0 = float(res.filt.fused.t_s[0])
        jobs.append((plots.plot_ape_over_time, out.path("ape_over_time.png"), res.evals, t0))
        if any(ev.drift for ev in res.evals.values()):
            jobs.append((plots.plot_drift, out.path("kitti_drift.png"), res.evals))
            plots_written.append("kitti_drift.png")
        if res.consistency.get("nees"):
            jobs.append((plots.plot_consistency, out.path("consistency.png"), res.consistency, t0))
            plots_written.append("consistency.png")
        if res.metrics.get("trials"):
            jobs.append((plots.plot_trials, out.path("trials.png"), res.metrics["trials"]))
            plots_written.append("trials.png")
        if res.segments and "fused" in res.evals:
            jobs.append((plots.plot_segment_map, out.path("segments_map.png"), res.evals, res.segments))
            plots_written.append("segments_map.png")
    futures = [pool.submit(*j) for j in jobs] if pool is not None else [j[0](*j[1:]) for j in jobs]
    out.write_text("report.md", report_md(res.dataset, res.config_source, res.evals, res.ratios, res.cfg,
                                          res.prep.applied, res.prep.gnss_info, res.metrics, plots_written))
    if pool is not None:
        for f in futures:
            f.result()


def write_run(out: StagedDir, res, pool=None) -> None:
    """Every output of ``fusion-eval run`` for an evaluated run."""
    make_plots = res.cfg["output"]["plots"]
    for f in write_filter_outputs(out, res.series, res.filt, res.fused_error, make_plots, pool):
        f.result()
    write_evaluation(out, res, filter_plots(make_plots), pool)
