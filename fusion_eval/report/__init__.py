"""The report layer: it only writes. Files (:mod:`.files`), Markdown (:mod:`.markdown`), plots (:mod:`.plots`),
the self-contained page (:mod:`.html`).

A run is written in two phases so that a run can start the first while evo still evaluates the estimates
in other processes: :func:`write_filter_outputs` needs only the filter's output (TUM files and the plots of
the filter), :func:`write_evaluation` the evaluation (result zips, metrics, configuration, the plots of
the metrics, the report). :func:`write_run` does both. Every file goes through
:class:`fusion_eval.outputs.StagedDir`: written atomically, the directory appearing only when complete.
"""

from __future__ import annotations

import numpy as np

from .. import provenance
from ..outputs import StagedDir
from . import files, html, thin
from .markdown import metrics_tex, report_md, report_md_no_truth


def draw(name: str, *args) -> None:
    """``plots.<name>(*args)``, with matplotlib imported where the plot is drawn: the run's plots are jobs of its
    worker processes (which import it as they start, :func:`fusion_eval.pool.executor`'s ``preload``), and the main
    process, which only submits them, never pays the second of importing it."""
    from . import plots

    getattr(plots, name)(*args)


FILTER_PLOTS = ["trajectories.png", "ape_over_time.png", "biases.png", "fused_error_3sigma.png",
                "fused_error_att_vel_3sigma.png"]


def write_filter_outputs(out: StagedDir, series: dict, filt, fused_err: dict, make_plots: bool, pool=None,
                         truth_biases=None, tums_written=(), handles=None, spans=(), start_frame: bool = False) -> list:
    """TUM files and the plots that need no evaluation, each a job of its own on ``pool`` when given (so that
    they spread over the workers). Returns the futures to wait for (or nothing: done here); the plots the
    report lists are :func:`filter_plots` (``ape_over_time.png`` is drawn with the metrics, in
    :func:`write_evaluation`). ``fused_err``: :func:`fusion_eval.evaluation.run_metrics.fused_error`;
    ``truth_biases``: the true IMU biases on the filter's clock where the dataset knows them (a simulated drive,
    :func:`fusion_eval.datasets.truth.truth_imu_biases`), drawn over the estimated ones; ``tums_written``: the
    estimates whose TUM files another job writes (the one evaluating them, :func:`fusion_eval.pipeline.evaluate_estimate`).
    A job gets only what it draws (:mod:`.thin`): a long drive's series would cost their size again in pickles;
    ``handles``: series as the pool's workers already hold them (:meth:`fusion_eval.pool.Pool.share`); ``spans``:
    :func:`spans_of`, shaded on the error plots too (where the covariance grows, and why: a review found an outage's
    +/-5 m band with no word of it there); ``start_frame``: the world is the start's levelled frame (no GNSS and no
    truth: :mod:`fusion_eval.calibration.initial_state`), not ENU."""
    handles = handles or {}
    if fused_err is not None and len(fused_err["t_s"]) and len(filt.fused.t_s):      # the error plots count their time from their own first stamp
        shift = float(filt.fused.t_s[0]) - float(fused_err["t_s"][0])
        spans = [(a + shift, b + shift, label) for a, b, label in spans]
    jobs = [(files.write_tum, out.path(files.TUM_FILES[n]), n, handles.get(n, s)) for n, s in series.items()
            if s is not None and n in files.TUM_FILES and n not in tums_written]
    if make_plots:
        jobs += [(draw, "plot_trajectories", out.path("trajectories.png"), *thin.paths(series), start_frame),
                 (draw, "plot_biases", out.path("biases.png"),
                  *thin.biases(filt.fused.t_s, filt.accel_bias_b, filt.gyro_bias_b, filt.sigma, truth_biases))]
    if make_plots and fused_err is not None:      # (no error without ground truth)
        jobs += [(draw, "plot_error_sigma", out.path("fused_error_3sigma.png"),
                  thin.error_sigma(fused_err["t_s"], fused_err["err_w_m"], fused_err["sigma_w_m"], fused_err.get("smoothed")),
                  spans),
                 (draw, "plot_att_vel_error_sigma", out.path("fused_error_att_vel_3sigma.png"),
                  thin.att_vel(fused_err["att_vel"]), spans)]
    if pool is None:
        for j in jobs:
            j[0](*j[1:])
        return []
    return [pool.submit(*j) for j in jobs]


def start_frame(applied: dict) -> bool:
    """Whether a run's world frame is its start's levelled frame (a start from the data without GNSS)."""
    return (applied.get("init_state") or {}).get("frame") == "start"


def filter_plots(make_plots: bool, truth: bool = True) -> list[str]:
    """The plots :func:`write_filter_outputs` draws (``truth``: the drive has ground truth, its errors are drawn;
    ``ape_over_time.png`` is drawn with the metrics)."""
    if not make_plots:
        return []
    return list(FILTER_PLOTS) if truth else [p for p in FILTER_PLOTS if p in ("trajectories.png", "biases.png")]


IMU_GAP_MIN_S = 1.0        # a hole in the fused record this long is shaded (KITTI's dropped packets: 1.6-1.8 s)


def route_spans(res) -> list[tuple[float, float, str]]:
    """The spans of a run to shade on its time plots, in seconds from the filter's start: the configured GNSS outages
    and the holes in the fused record (the IMU's dropped packets), each ``(start, end, label)``."""
    return spans_of(res.cfg, res.metrics.get("gnss_degradation"), res.filt.fused.t_s)


def spans_of(cfg: dict, gnss_info: dict | None, fused_t_s) -> list[tuple[float, float, str]]:
    """:func:`route_spans` from the configuration, the GNSS degradation's record and the fused stamps."""
    out = []
    gd = gnss_info or {}
    if cfg["filter"].get("use_gnss"):
        out += [(float(a), float(b), "GNSS outage") for a, b in gd.get("outages_s") or []]
    t = np.asarray(fused_t_s, float)
    if t.size > 2:
        dt = np.diff(t)
        for i in np.flatnonzero(dt > max(IMU_GAP_MIN_S, 5 * float(np.median(dt)))):
            out.append((float(t[i] - t[0]), float(t[i + 1] - t[0]), "no IMU data (gap)"))
    return out


def write_evaluation(out: StagedDir, res, plots_written: list[str], pool=None, advance=None, linked=()) -> None:
    """Result zips, metrics (JSON, CSV, LaTeX), the resolved configuration, the plots that need the metrics (on
    ``pool`` when given, while this process writes the rest), and the reports (Markdown, HTML). ``advance()`` is
    called as each file group and plot is done (progress). ``linked``: files already in ``out`` (a sweep batch's
    shared estimates, :meth:`fusion_eval.outputs.StagedDir.link`), not written again."""
    advance = advance or (lambda n=1: None)
    # the input files' checksums (0.14 s on kitti-00's 4546 OXTS files) on a worker, while this process writes
    dataset = res.resolved_extra.get("dataset") or {}
    inputs = pool.submit(provenance.input_files, dataset) if pool is not None else None
    for ev in res.evals.values():
        for name, data in ev.zips.items():
            if name not in linked:
                out.write_bytes(name, data)
    if res.evals:         # (a drive without ground truth has no scores to tabulate)
        out.write_text("metrics.csv", files.metrics_csv(res.evals, res.ratios, (res.metrics.get("trials") or {}).get("n")))
        out.write_text("metrics.tex", metrics_tex(res.dataset, res.evals, res.cfg, res.metrics))
    if res.metrics.get("trials"):
        from ..tables import csv_text
        from ..trials import csv_rows

        out.write_text("trials.csv", csv_text(*csv_rows(res.metrics["trials"]), float_format="{:.6g}"))
    config = files.resolved_config(res.cfg, res.resolved_extra)
    out.write_text("config.resolved.yaml", config)
    advance()
    jobs = []
    plots_written = list(plots_written)
    if plots_written:
        t0 = float(res.filt.fused.t_s[0])
        if res.evals:
            jobs.append((draw, "plot_ape_over_time", out.path("ape_over_time.png"), thin.ape_curves(res.evals), t0,
                         "time since start [s]", route_spans(res)))
        if any(ev.drift for ev in res.evals.values()):
            jobs.append((draw, "plot_drift", out.path("kitti_drift.png"), thin.drift_only(res.evals)))
            plots_written.append("kitti_drift.png")
        if res.consistency.get("nees") or (not res.evals and res.consistency.get("nis")):
            jobs.append((draw, "plot_consistency", out.path("consistency.png"), thin.consistency(res.consistency), t0))
            plots_written.append("consistency.png")
        if not res.evals and res.consistency.get("nis"):
            # a drive without ground truth: where on the route the measured streams disagree (the segment map's place)
            from ..evaluation.run_metrics import measured_observations

            measured = {k: d for k, d in res.consistency["nis"].items() if k in measured_observations()}
            if measured:
                route = thin.paths({"fused": res.filt.fused})[0]["fused"]
                # every update (the windows' means: the envelope kept for the time plot would bias them to its peaks)
                nis = {k: {"t_s": np.asarray(d["t_s"]), "values": np.asarray(d["values"]), "dof": d["dof"]}
                       for k, d in measured.items()}
                jobs.append((draw, "plot_innovation_map", out.path("innovations_map.png"), route, nis,
                             start_frame(res.resolved_extra["applied"])))
                plots_written.append("innovations_map.png")
        if res.metrics.get("trials"):
            jobs.append((draw, "plot_trials", out.path("trials.png"), res.metrics["trials"]))
            plots_written.append("trials.png")
        if res.segments and "fused" in res.evals:
            jobs.append((draw, "plot_segment_map", out.path("segments_map.png"), thin.segment_map(res.evals, res.segments),
                         res.segments))
            plots_written.append("segments_map.png")
    futures = []
    for j in jobs:
        if pool is None:
            j[0](*j[1:])
            advance()
        else:
            futures.append(pool.submit(*j))
            futures[-1].add_done_callback(lambda _f: advance())
    md = (report_md if res.evals else report_md_no_truth)(
        res.dataset, res.config_source, res.evals, res.ratios, res.cfg, res.resolved_extra["applied"], res.prep.gnss_info,
        res.metrics, plots_written)
    out.write_text("report.md", md)
    inputs = inputs.result() if inputs is not None else provenance.input_files(dataset)
    # what made the figures, machine-readable beside them: a metrics.json compared with another can be told from one
    # of other code or other input files (the report.html's table; checksums here were missing: a reproducibility review)
    out.write_text("metrics.json", files.metrics_json({**res.metrics, "provenance": provenance.block(inputs, config)}))
    advance()
    for f in futures:
        f.result()
    out.write_text("report.html", html.page(md, out.path("."), inputs=inputs))   # embeds the plots: they are done
    advance()


def write_run(out: StagedDir, res, pool=None) -> None:
    """Every output of ``fusion-eval run`` for an evaluated run."""
    make_plots = res.cfg["output"]["plots"]
    for f in write_filter_outputs(out, res.series, res.filt, res.fused_error, make_plots, pool, res.truth_biases,
                                  spans=route_spans(res), start_frame=start_frame(res.resolved_extra["applied"])):
        f.result()
    write_evaluation(out, res, filter_plots(make_plots, bool(res.evals)), pool)
