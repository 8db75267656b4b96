"""The run engine: dataset -> prepared streams -> filter replay -> evo evaluation -> (optionally) outputs.

:func:`execute` does one run in memory and returns a :class:`RunResult`; given a staging directory it
also writes every output, overlapping the writing with the evaluation. ``fusion-eval run``, each run of a
sweep (:func:`run_to_dir`) and the Python API (:func:`fusion_eval.run`) all go through it.
"""

from __future__ import annotations

import logging
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from . import report, session
from . import trials as mc
from .datasets.truth import truth_imu_biases
from .errors import ConfigError, DataRangeError, FusionEvalError
from .evaluation import span
from .evaluation.run_metrics import (ESTIMATES, consistency, fused_error, ratio_metrics, run_metrics, segments,
                                     smoother_section, stated_noise)
from .evaluation.trajectory import EstimateEvaluation, evaluate
from .log_context import collected
from .memory import release_free_heap
from .outputs import StagedDir, dataset_roots
from .pool import executor
from .progress import as_stages
from .prepare import Prepared, auto_settled, offsets_note, prepare, settings_for
from .replay import FilterOutput, dead_reckoning, replay
from .types import Dataset, PoseSeries

log = logging.getLogger(__name__)


@dataclass
class RunResult:
    """Everything one run computed (the content of its output directory, in memory)."""

    dataset: str
    cfg: dict                                # resolved configuration, human units
    config_source: str
    prep: Prepared
    filt: FilterOutput
    series: dict[str, PoseSeries]            # groundtruth, lidar, gnss, imu_only, fused
    evals: dict[str, EstimateEvaluation]     # fused, lidar, gnss, imu_only (with their evo result zips)
    ratios: dict
    consistency: dict
    segments: dict | None
    fused_error: dict
    metrics: dict                            # = metrics.json
    resolved_extra: dict                     # informational sections of config.resolved.yaml
    timings_s: dict = field(default_factory=dict)
    out_dir: Path | None = None              # where it was written (run_to_dir)
    truth_biases: object = None              # a simulated drive's true IMU biases as the bias plot draws them
                                             # (datasets.truth.TruthBiases, report.thin.truth_biases)


def evaluate_estimate(reference: PoseSeries, estimate: PoseSeries, name: str, ev_cfg: dict,
                      zip_dir: Path | None = None, zip_trajectories: bool = False,
                      route: bool = False) -> EstimateEvaluation:
    """evo's metrics of one estimate and its evo result files (in a worker: the files travel back as bytes,
    smaller than the result objects they are made of). With ``zip_dir`` (the run's staging folder) the worker
    writes them there itself, and the estimate's TUM file beside them (it holds the estimate: another job would
    need a copy): on a long drive they are hundreds of MB that the main process need not hold. ``zip_trajectories``:
    ``output.zip_trajectories``; ``route``: keep the associated reference positions (the segment map's primary
    estimate; sent back for no other, a long estimate's are 17 MB)."""
    # the RPE results without their reduced trajectories: the result files do not hold them (report.files.evo_zips)
    # a run's world frame is local ENU: up is z (the per-segment horizontal / vertical split; a 4dof alignment)
    ev = evaluate(reference, estimate, name, ev_cfg["t_max_diff_s"], ev_cfg["rpe_delta_m"], ev_cfg["association"],
                  ev_cfg["alignment"], ev_cfg["engine"], rpe_trajectories=False, up_axis="z")
    if zip_dir is not None:
        report.files.write_evo_zips(ev, zip_dir, zip_trajectories)
        report.files.write_tum(Path(zip_dir) / report.files.TUM_FILES[name], name, estimate)
        ev.zips = {}
    else:
        ev.zips = report.files.evo_zips(ev, zip_trajectories)
    ev.results = {}
    if not route:
        ev.ref_p_m = None
    return ev


def plot_truth_biases(description: dict, imu_time_offset_s: float, t_first: float, t_last: float):
    """A simulated drive's true IMU biases as the bias plot draws them against an estimate plotted over
    ``t_first..t_last`` (:func:`fusion_eval.report.thin.truth_biases`); None for a dataset without them."""
    truth = truth_imu_biases(description, imu_time_offset_s)
    return None if truth is None else report.thin.truth_biases(truth, t_first, t_last)


def trial_metrics(ds: Dataset, cfg: dict) -> tuple[dict, list[str]]:
    """One Monte-Carlo trial's metrics and warnings (in a worker: nothing written, nothing said, nothing else sent
    back). Its log lines repeat the main run's, once per trial: the informational ones are dropped, the warnings
    returned for the run to sum up (:func:`fusion_eval.trials.warnings`)."""
    with collected(show=False) as said:       # (nothing reaches the console from inside: INFO lines neither)
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                return execute(ds, cfg, jobs=1).metrics, said
        except FusionEvalError as exc:          # a diverged trial is a result, counted in the summary
            return {"failed": str(exc)}, said


@dataclass
class Shared:
    """What runs of one dataset with one preparation share, whatever the filter's own settings: the prepared
    streams, the unfiltered estimates (dead reckoning from the same start) and their evaluations."""

    prep: Prepared
    series: dict[str, PoseSeries]            # groundtruth, lidar, gnss, imu_only
    span: tuple
    ref: PoseSeries                          # the reference cropped to the common span
    futures: dict                            # name -> future of an unfiltered estimate's evaluation
    timings: dict
    written: tuple = ()                      # estimates whose TUM and result files their evaluations wrote
    handles: dict = field(default_factory=dict)   # "ref" and the series as the pool's jobs take them (pool.share)
    truth_biases: object = None              # future of a simulated drive's true biases for the bias plot, or None
    # a finished run's folder whose files of the shared estimates (the truth's, the lidar's, the GNSS's, dead
    # reckoning's: the same bytes in every run on this preparation) later runs take as hard links (a sweep's batch)
    files_from: Path | None = None


def share(ds: Dataset, cfg: dict, pool, zip_dir: Path | None = None) -> Shared:
    """Prepare ``ds`` for ``cfg`` and start evaluating the unfiltered estimates on ``pool``: while the filter runs,
    not after it, where they queued behind the fused estimate's (dead reckoning of a simulated hour at 200 Hz
    is 720,001 poses too). With ``zip_dir`` (one run's folder) dead reckoning's evaluation writes its files there."""
    t = time.perf_counter()
    prep = prepare(ds, cfg)
    timings = {"prepare": time.perf_counter() - t}
    gt = prep.groundtruth
    series: dict[str, PoseSeries] = {} if gt is None else {"groundtruth": gt}
    if prep.lidar is not None:
        series["lidar"] = prep.lidar
    if prep.gnss is not None:
        series["gnss"] = prep.gnss.as_poses()
    ev_cfg = cfg["evaluation"]
    if gt is None:
        # a drive without ground truth: nothing is scored; the estimates are written, the innovations summarised
        series["imu_only"] = dead_reckoning(prep, settings_for(cfg, prep))
        return Shared(prep, series, None, None, {}, timings, handles={n: pool.share(s) for n, s in series.items()})
    # the fused estimate and dead reckoning cover the IMU samples from the start on
    spans = {n: span.stream_coverage(n, series[n], prep.applied) for n in ("lidar", "gnss") if n in series}
    spans["fused"] = (float(prep.imu.t_s[prep.k_start]), float(prep.imu.t_s[-1]))
    try:
        sp = span.span_for(ev_cfg["span"], gt, spans)
    except DataRangeError as exc:
        raise DataRangeError(f"{exc} {offsets_note(prep.applied)}".rstrip()) from None
    short = span.short_span_warning(sp, gt, (float(prep.imu.t_s[0]), float(prep.imu.t_s[-1])),
                                    {n: spans[n] for n in ("lidar", "gnss") if n in spans})
    if short:            # said with the data's warnings (stderr, report.md, metrics.json)
        log.warning("%s", short)
        prep.applied["data_warnings"] = [*prep.applied.get("data_warnings", ()), short]
    ref = span.crop(gt, sp)              # as evo's --t_start/--t_end: the reference reduced to the span
    series["imu_only"] = dead_reckoning(prep, settings_for(cfg, prep))
    # before the first job, which forks the workers: they hold these already (pool.share)
    handles = {"ref": pool.share(ref), **{n: pool.share(s) for n, s in series.items()}}
    # a simulated drive's true biases, for the bias plot (None for real data): read on a worker while this process
    # filters (a simulated hour's table is 79 MB of text, 0.7 s), only what the plot draws sent back; the first job,
    # so that the main process never waits for it behind the evaluations
    truth = pool.submit(plot_truth_biases, ds.description, prep.applied["time_offset_s"]["imu"],
                        *report.thin.plotted_span(prep.imu.t_s[prep.k_start:])) \
        if cfg["output"]["plots"] and ds.description.get("truth") else None
    zt = cfg["output"]["zip_trajectories"]
    futures = {n: pool.submit(evaluate_estimate, handles["ref"], handles[n], n, ev_cfg, None, zt)
               for n in ("lidar", "gnss") if n in series}
    futures["imu_only"] = pool.submit(evaluate_estimate, handles["ref"], handles["imu_only"], "imu_only", ev_cfg, zip_dir,
                                      zt)
    return Shared(prep, series, sp, ref, futures, timings, written=("imu_only",) if zip_dir is not None else (),
                  handles=handles, truth_biases=truth)


def execute(ds: Dataset, cfg: dict, *, dataset_path: str | Path | None = None, config_source: str = "default",
            progress: Callable[[float], None] | None = None, jobs: int | None = None,
            out: StagedDir | None = None, trials: int = 1) -> RunResult:
    """Run the configured filter on ``ds`` and evaluate it (and every unfiltered estimate) with evo.

    With ``out`` (an open :class:`StagedDir`) every output of ``fusion-eval run`` is written into it. evo's
    metrics loop over poses in Python: the unfiltered estimates are evaluated in worker processes while this
    one runs the filter, then the fused and dead-reckoning ones alongside the plots that need no metrics, so
    both cores stay busy. ``jobs=1`` does everything in this process.

    With ``trials`` > 1 the run is trial 0 of that many Monte-Carlo trials (:mod:`fusion_eval.trials`): the
    others run on the same pool, and ``metrics["trials"]`` summarises every metric over all of them.
    """
    stages = as_stages(progress)
    if trials > 1 and ds.groundtruth is None:
        # trials average the scores over GNSS draws; a drive without truth has none (its trials.csv was all blanks)
        raise ConfigError(f"dataset {ds.name!r} has no groundtruth stream: --trials averages scores against it; run "
                          "without --trials (the innovations are in report.md)")
    plots = out is not None and cfg["output"]["plots"]
    # with trials, the run's own warnings: the later trials' are summed up against them
    with executor(jobs, preload=("fusion_eval.report.plots",) if plots else ()) as pool, \
            (collected() if trials > 1 else nullcontext(None)) as said:
        stages.start("prepare")
        sh = share(ds, cfg, pool, zip_dir=out.path(".") if out is not None else None)
        return filter_and_evaluate(ds, cfg, sh, pool, dataset_path=dataset_path,
                                   config_source=config_source, progress=stages, out=out, trials=trials, said=said)


def filter_and_evaluate(ds: Dataset, cfg: dict, sh: Shared, pool, *, dataset_path: str | Path | None = None,
                        config_source: str = "default", progress: Callable[[float], None] | None = None,
                        out: StagedDir | None = None, trials: int = 1, monitor=None,
                        said: list[str] | None = None) -> RunResult:
    """The filter's part of a run on prepared data (:func:`share`): replay, evaluate, summarise, write. ``cfg``
    may differ from the one ``sh`` was prepared with only in what the filter alone reads (a sweep's noise
    settings, :func:`fusion_eval.commands.sweep.batch_key`). ``monitor``: see :func:`fusion_eval.replay.replay`.
    ``said``: the warnings this run has said so far (:func:`fusion_eval.log_context.collected`; without it, its
    data warnings), against which the later trials' are summed up. The files of the shared estimates are hard links to
    ``sh.files_from``'s where it is set."""
    prep, gt, ev_cfg = sh.prep, sh.prep.groundtruth, cfg["evaluation"]
    timings = dict(sh.timings)
    s = settings_for(cfg, prep)
    series = dict(sh.series)
    n_trials = mc.check_count(trials)
    stages = as_stages(progress)
    trial_futs = [pool.submit(trial_metrics, ds, mc.apply(cfg, i)) for i in range(1, n_trials)]
    t = time.perf_counter()
    stages.start("filter")
    # overflow in absurd settings is reported as divergence (exit 3), not as numpy warnings
    with np.errstate(over="ignore", invalid="ignore"):
        filt = replay(prep, s, progress=None if progress is None else stages, imu_only=series["imu_only"],
                      monitor=monitor)
    timings["filter"] = time.perf_counter() - t
    release_free_heap()                  # the replay's scratch, before the evaluations' results arrive
    t = time.perf_counter()
    series["fused"] = filt.fused
    if filt.smoothed is not None:
        series["smoothed"] = filt.smoothed.fused
        timings["smoother"] = filt.smoother_info["backward_s"]
    futures = dict(sh.futures)
    # this run's own estimates write their result files into its folder from the worker; shared ones (a batch
    # writes them into every run's folder) come back as bytes
    zip_dir = out.path(".") if out is not None else None
    own = [n for n in ("fused", "smoothed") if n in series and sh.ref is not None]
    # the segment map colours the fused estimate's route (run_metrics.segments' primary)
    futures.update({n: pool.submit(evaluate_estimate, sh.handles["ref"], series[n], n, ev_cfg, zip_dir,
                                   cfg["output"]["zip_trajectories"], n == "fused") for n in own})
    own += list(sh.written)                  # set only for a run with a folder (execute)
    # a batch's shared estimates: their TUM files and result zips as links to an earlier run's (a sweep of 65 runs
    # wrote 273 MB, most of it these files again, and formatted the TUM text each time)
    linked, linked_tums = set(), []
    link_from = sh.files_from if out is not None else None
    if link_from is not None:
        for n in sh.series:
            f = report.files.TUM_FILES.get(n)
            if f and series.get(n) is not None and n not in own and out.link(f, link_from / f):
                linked.add(f)
                linked_tums.append(n)
    truth_b = sh.truth_biases.result() if sh.truth_biases is not None else None
    err = fused_error(gt, filt, att_vel=cfg["output"]["plots"]) if gt is not None else None
    # the TUM files and the filter's plots, each a job of its own, alongside the evaluations
    first = report.write_filter_outputs(out, series, filt, err, cfg["output"]["plots"], pool, truth_biases=truth_b,
                                        tums_written=own + linked_tums, handles=sh.handles,
                                        spans=report.spans_of(cfg, prep.gnss_info, filt.fused.t_s),
                                        start_frame=report.start_frame(prep.applied)) if out is not None else []
    # the NEES needs no metric: computed here while the workers evaluate, not after (0.7 s on a simulated hour); over
    # the evaluated span, as every metric of the report (over the whole truth it counted 4 epochs more on kitti-00)
    cons = consistency(sh.ref, filt)         # (without ground truth: the NIS alone)
    names = [n for n in ESTIMATES if n in futures]
    stages.start("evaluate", len(names))
    evals = {}
    for n in names:
        evals[n] = futures[n].result()
        stages.advance()
    timings["evaluate"] = time.perf_counter() - t
    if gt is not None and evals["fused"].matched_poses < 2:
        # a run whose estimate meets no ground truth has no result: say why instead of reporting 'n/a' with exit 0
        f = series["fused"]
        raise DataRangeError(f"the fused estimate ({len(f)} poses, {f.t_s[0]:.3f}..{f.t_s[-1]:.3f} s) matches "
                             f"{evals['fused'].matched_poses} ground-truth poses ({gt.source}: {len(gt)} poses, "
                             f"{gt.t_s[0]:.3f}..{gt.t_s[-1]:.3f} s) within evaluation.t_max_diff_s = {ev_cfg['t_max_diff_s']} s "
                             f"{offsets_note(prep.applied)}".rstrip())
    for n in linked_tums:                   # (the shared estimates' evaluations: their zips came back as bytes)
        for z in getattr(evals.get(n), "zips", None) or {}:
            if out.link(z, link_from / z):
                linked.add(z)
    ratios = ratio_metrics(evals)
    # windows along the evaluated span (the whole truth gave a last window to 3712 m in a report whose span ends at
    # 3707 m, and figures that `evaluate --t-start/--t-end` on the run's files did not reproduce: an audit)
    seg = segments(sh.ref, evals, ev_cfg) if gt is not None else None
    # this run's: a batch's runs share the preparation's record but not their noise scales
    applied = {**prep.applied, "auto_settled": auto_settled(cfg, prep.resolved, prep.applied)}
    idle = session.inactive_warnings(ds, cfg)         # this run's settings that do nothing (not the shared preparation's)
    for w in idle:
        log.warning("%s", w)
    if idle:
        applied["data_warnings"] = [*idle, *applied.get("data_warnings", [])]
    metrics = run_metrics(ds.name, evals, ratios, ev_cfg, applied, prep.gnss_info, cons, seg, sh.span,
                          smoother=smoother_section(filt), stated=stated_noise(prep, cfg))
    if n_trials > 1:
        stages.start("trials", n_trials)
        stages.advance()                      # trial 0: this run
        per_trial, later = [metrics], []
        for f in trial_futs:
            m, w = f.result()
            per_trial.append(m)
            later.append(w)
            stages.advance()
        # the run's: said here, its data warnings, and its evaluations' (said in the pool's workers)
        run_said = [*(said or ()), *metrics.get("preprocessing", {}).get("data_warnings", ()),
                    *(w for e in evals.values() for w in e.said)]
        for w in mc.warnings(run_said, later):
            log.warning("%s", w)
        metrics["trials"] = mc.section(cfg, per_trial)
        if metrics["trials"]["identical"]:
            log.warning(mc.NOTHING_RANDOM.format(n=n_trials))
    dataset_path = ds.description.get("path") if dataset_path is None else dataset_path
    resolved_extra = {"dataset": {"path": None if dataset_path is None else str(dataset_path), "name": ds.name,
                                  "manifest": ds.description.get("manifest"),
                                  "attribution": ds.description.get("attribution"),
                                  "streams": ds.description.get("streams")},
                      "applied": applied, "config_source": config_source}
    res = RunResult(ds.name, cfg, config_source, prep, filt, series, evals, ratios, cons, seg, err, metrics,
                    resolved_extra, timings, truth_biases=truth_b)
    if out is not None:
        t = time.perf_counter()
        stages.start("write")
        for f in first:
            f.result()
            stages.advance()
        report.write_evaluation(out, res, report.filter_plots(cfg["output"]["plots"], gt is not None), pool, advance=stages.advance,
                                linked=linked)
        timings["write"] = time.perf_counter() - t
    return res


def run_to_dir(dataset_path: str | Path | None, req: session.ConfigRequest, out_dir: Path, overwrite: bool = False,
               progress: Callable[[float], None] | None = None, jobs: int | None = None, trials: int = 1,
               wait_lock_s: float = 0.0) -> RunResult:
    """Load the dataset (None: the default), resolve the configuration, run, evaluate and write every output
    atomically into ``out_dir`` (nothing is left behind when it fails)."""
    from . import resources

    staged = StagedDir(out_dir, overwrite=overwrite, wait_lock_s=wait_lock_s,
                       inputs=dataset_roots(resources.default_dataset() if dataset_path is None else dataset_path))
    staged.check()
    mc.check_count(trials)               # before any data is read
    stages = as_stages(progress)
    stages.start("load")
    t = time.perf_counter()
    ds = session.dataset(dataset_path)
    cfg = session.resolve(req, ds)
    release_free_heap()                  # the readers' buffers, before the run's peak
    load_s = time.perf_counter() - t
    log.debug("loaded %s: %d IMU samples, %s GNSS fixes, %s lidar poses, %s ground-truth poses", ds.name, len(ds.imu),
              len(ds.gnss) if ds.gnss else 0, len(ds.lidar) if ds.lidar else 0, len(ds.groundtruth) if ds.groundtruth else 0)
    with staged as out:
        res = execute(ds, cfg, dataset_path=dataset_path, config_source=req.source, progress=stages, jobs=jobs, out=out,
                      trials=trials)
    res.timings_s["load"] = load_s
    res.out_dir = Path(out_dir)
    return res
