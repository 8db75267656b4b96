"""``fusion-eval run``: dataset -> prepared streams -> filter replay -> evo evaluation -> outputs."""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import time
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .config import Settings, load_config
from .datasets.manifest import load_dataset
from .evaluation import EstimateEvaluation, evaluate, ratio
from .outputs import StagedDir
from .prepare import prepare
from .replay import dead_reckoning, replay
from .report import write_evo_results, write_results, write_series_and_plots
from .types import PoseSeries

log = logging.getLogger(__name__)


@dataclass
class RunSummary:
    out_dir: Path
    metrics: dict
    evals: dict
    timings_s: dict


def resolve_config(ds, config_path: Path | None, sets: tuple[str, ...], extra_layers: tuple = ()) -> dict:
    """Defaults < the manifest's suggested settings < ``extra_layers`` < the config file < ``sets``."""
    layers = ((ds.description["config"], f"{ds.description['manifest']} (config)"),) if ds.description.get("config") else ()
    return load_config(config_path, sets, layers=layers + tuple(extra_layers))


def run(dataset_path: Path, config_path: Path | None, sets: tuple[str, ...], out_dir: Path, overwrite: bool = False,
        progress: Callable[[float], None] | None = None, jobs: int | None = None, extra_layers: tuple = ()) -> RunSummary:
    """Load the dataset, resolve the configuration (defaults < the manifest's suggested settings <
    ``extra_layers`` < the config file < ``--set``), run, evaluate and write every output atomically
    into ``out_dir``. ``jobs=1`` evaluates in this process (inside a sweep's worker)."""
    timings = {}
    StagedDir(out_dir, overwrite=overwrite).check()
    load_config(config_path, sets, layers=tuple(extra_layers))  # fail on a bad configuration before reading data
    t = time.perf_counter()
    ds = load_dataset(dataset_path)
    cfg = resolve_config(ds, config_path, sets, extra_layers)
    config_name = Path(config_path).stem if config_path else "default"
    timings["load"] = time.perf_counter() - t
    log.debug("loaded %s: %d IMU samples, %s GNSS fixes, %s lidar poses, %s ground-truth poses", ds.name, len(ds.imu),
             len(ds.gnss) if ds.gnss else 0, len(ds.lidar) if ds.lidar else 0, len(ds.groundtruth) if ds.groundtruth else 0)
    t = time.perf_counter()
    prep = prepare(ds, cfg)
    fp = Settings(cfg)
    timings["prepare"] = time.perf_counter() - t
    series: dict[str, PoseSeries] = {"groundtruth": prep.groundtruth}
    if prep.lidar is not None:
        series["lidar"] = prep.lidar
    if prep.gnss is not None:
        series["gnss"] = prep.gnss.as_poses()
    resolved_extra = {"dataset": {"path": str(dataset_path), "name": ds.name,
                                  "manifest": ds.description.get("manifest"),
                                  "attribution": ds.description.get("attribution"),
                                  "streams": ds.description.get("streams")},
                      "applied": prep.applied, "config_source": config_name}
    ev_cfg = cfg["evaluation"]

    def submit_eval(pool, name):
        return pool.submit(_evaluate_and_save, out, prep.groundtruth, series[name], name, ev_cfg["t_max_diff_s"],
                           ev_cfg["rpe_delta_m"], ev_cfg["association"], ev_cfg["alignment"])

    with StagedDir(out_dir, overwrite=overwrite) as out:
        # evo's metrics loop over poses in Python. The unfiltered estimates are evaluated in worker
        # processes while this one runs the filter; then the fused and dead-reckoning estimates and
        # the plots that need no metrics, heaviest first, so both cores stay busy.
        with _executor(jobs) as pool:
            series["imu_only"] = dead_reckoning(prep, fp)
            futures = {n: submit_eval(pool, n) for n in ("lidar", "gnss") if n in series}
            t = time.perf_counter()
            # overflow in absurd settings is reported as divergence (exit 3), not as numpy warnings
            with np.errstate(over="ignore", invalid="ignore"):
                filt = replay(prep, fp, progress=progress, imu_only=series["imu_only"])
            timings["filter"] = time.perf_counter() - t
            t = time.perf_counter()
            series["fused"] = filt.fused
            futures.update({n: submit_eval(pool, n) for n in ("fused", "imu_only")})
            plots_future = pool.submit(write_series_and_plots, out, series, filt, cfg["output"]["plots"])
            plots_written = plots_future.result()
            evals: dict[str, EstimateEvaluation] = {n: futures[n].result() for n in ("fused", "lidar", "gnss", "imu_only")
                                                    if n in futures}
            ratios = {"fused_over_lidar": ratio(evals.get("fused"), evals.get("lidar")),
                      "fused_over_gnss": ratio(evals.get("fused"), evals.get("gnss"))}
            timings["evaluate"] = time.perf_counter() - t
            extra = beyond_evo(prep.groundtruth, evals, filt, ev_cfg)
            metrics = write_results(out, dataset=ds.name, config_name=config_name, cfg=cfg, resolved_extra=resolved_extra,
                                    evals=evals, ratios=ratios, applied=prep.applied, gnss_info=prep.gnss_info, filt=filt,
                                    extra=extra, pool=pool, plots_written=plots_written)
    timings["evaluate_and_write"] = time.perf_counter() - t
    return RunSummary(out_dir=Path(out_dir), metrics=metrics, evals=evals, timings_s=timings)


def _evaluate_and_save(out: StagedDir, reference: PoseSeries, estimate: PoseSeries, name: str, t_max_diff_s: float,
                       rpe_delta_m: float, association: str = "nearest", alignment: str = "none") -> EstimateEvaluation:
    """Evaluate one estimate and write its evo result zips (in a worker: the zips are large to send back)."""
    ev = evaluate(reference, estimate, name, t_max_diff_s, rpe_delta_m, association, alignment)
    write_evo_results(out, ev)
    ev.results = {}
    return ev


def beyond_evo(gt: PoseSeries, evals: dict, filt, ev_cfg: dict) -> dict:
    """What evo lacks: filter consistency (NEES against the ground truth, NIS) and the per-segment breakdown
    (the KITTI drift metric is computed with each estimate's evaluation)."""
    from .consistency import pose_nees, summary
    from .interp import interpolate_poses
    from .segments import breakdown

    out: dict = {"consistency": {"nis": {k: {**summary(d["nis"], d["dof"]), "t_s": d["t_s"], "values": d["nis"]}
                                         for k, d in filt.nis.items()}}}
    gi = interpolate_poses(gt, filt.fused.t_s)
    sel = np.isin(filt.fused.t_s, gi.t_s)
    n_pos, n_att = pose_nees(filt.fused.p_w_m[sel], filt.fused.R_wb()[sel], gi.p_w_m, gi.R_wb(), filt.P_pos_att[sel])
    ok = np.isfinite(n_pos) & np.isfinite(n_att)
    out["consistency"]["nees"] = {"position": {**summary(n_pos[ok], 3), "t_s": gi.t_s[ok], "values": n_pos[ok]},
                                  "attitude": {**summary(n_att[ok], 3), "t_s": gi.t_s[ok], "values": n_att[ok]}}
    errs = {k: (ev.ape_t_s, ev.ape_err_m) for k, ev in evals.items() if ev.ape_err_m is not None}
    out["segments"] = breakdown(gt, errs, ev_cfg["segment_m"], ev_cfg["segment_s"])
    return out


class _Inline:
    """A stand-in executor that runs the work in this process (jobs=1)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def submit(self, fn, *args):
        fut: Future = Future()
        try:
            fut.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - re-raised by .result()
            fut.set_exception(exc)
        return fut


def _executor(jobs: int | None):
    jobs = os.cpu_count() or 1 if jobs is None else jobs
    if jobs <= 1:
        return _Inline()
    # fork: the workers inherit the imported modules and the data, so they start in milliseconds
    return ProcessPoolExecutor(max_workers=min(jobs, 4), mp_context=mp.get_context("fork"))
