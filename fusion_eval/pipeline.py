"""``fusion-eval run``: dataset -> prepared streams -> filter replay -> evo evaluation -> outputs."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .config import to_filter_params
from .datasets.manifest import load_dataset
from .evaluation import EstimateEvaluation, evaluate, ratio
from .outputs import StagedDir
from .prepare import prepare
from .replay import replay
from .report import write_outputs
from .types import PoseSeries

log = logging.getLogger(__name__)


@dataclass
class RunSummary:
    out_dir: Path
    metrics: dict
    evals: dict
    timings_s: dict


def run(dataset_path: Path, cfg: dict, config_name: str, out_dir: Path, overwrite: bool = False,
        progress: Callable[[float], None] | None = None) -> RunSummary:
    timings = {}
    StagedDir(out_dir, overwrite=overwrite).check()
    t = time.perf_counter()
    ds = load_dataset(dataset_path)
    timings["load"] = time.perf_counter() - t
    log.info("loaded %s: %d IMU samples, %s GNSS fixes, %s lidar poses, %s ground-truth poses", ds.name, len(ds.imu),
             len(ds.gnss) if ds.gnss else 0, len(ds.lidar) if ds.lidar else 0, len(ds.groundtruth) if ds.groundtruth else 0)
    t = time.perf_counter()
    prep = prepare(ds, cfg)
    fp = to_filter_params(cfg, prep.gravity_mps2)
    timings["prepare"] = time.perf_counter() - t
    t = time.perf_counter()
    filt = replay(prep, fp, progress=progress)
    timings["filter"] = time.perf_counter() - t

    t = time.perf_counter()
    series: dict[str, PoseSeries] = {"groundtruth": prep.groundtruth, "fused": filt.fused, "imu_only": filt.imu_only}
    if prep.lidar is not None:
        series["lidar"] = prep.lidar
    if prep.gnss is not None:
        g = prep.gnss
        series["gnss"] = PoseSeries(t_s=g.t_s, p_w_m=g.p_w_m, q_wb_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (len(g), 1)),
                                    has_orientation=False, source=g.source)
    ev_cfg = cfg["evaluation"]
    evals: dict[str, EstimateEvaluation] = {}
    for name in ("fused", "lidar", "gnss", "imu_only"):
        if name in series:
            evals[name] = evaluate(prep.groundtruth, series[name], name, ev_cfg["t_max_diff_s"], ev_cfg["rpe_delta_m"])
    ratios = {"fused_over_lidar": ratio(evals.get("fused"), evals.get("lidar")),
              "fused_over_gnss": ratio(evals.get("fused"), evals.get("gnss"))}
    timings["evaluate"] = time.perf_counter() - t

    t = time.perf_counter()
    resolved_extra = {"dataset": {"path": str(dataset_path), "name": ds.name,
                                  "manifest": ds.description.get("manifest"),
                                  "attribution": ds.description.get("attribution"),
                                  "streams": ds.description.get("streams")},
                      "applied": prep.applied, "config_source": config_name}
    with StagedDir(out_dir, overwrite=overwrite) as out:
        metrics = write_outputs(out, dataset=ds.name, config_name=config_name, cfg=cfg, resolved_extra=resolved_extra,
                                series=series, evals=evals, ratios=ratios, applied=prep.applied,
                                gnss_info=prep.gnss_info, filt=filt, make_plots=cfg["output"]["plots"])
    timings["write"] = time.perf_counter() - t
    return RunSummary(out_dir=Path(out_dir), metrics=metrics, evals=evals, timings_s=timings)
