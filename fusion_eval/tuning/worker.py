"""One tune trial scored on its drives: in a pool worker, on a Dask worker, or in this process.

A worker keeps the drives it loaded and their preparations (keyed as a sweep's batches are,
:func:`fusion_eval.commands.sweep.batch_key`): a trial that changes only what the filter reads (IMU and lidar
noise) replays the filter on the prepared data; one that changes the GNSS std the filter is told prepares again
(0.3 s on kitti-00). Nothing is written: the metrics come back to the study.
"""

from __future__ import annotations

import math
import traceback
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .objectives import Objective, flatten

_DATASETS: "OrderedDict[str, object]" = OrderedDict()
_SHARED: "OrderedDict[str, object]" = OrderedDict()
_KEEP = 8          # preparations kept per worker (a few drives x a few GNSS settings; each holds the drive's arrays)


@dataclass(frozen=True)
class Job:
    number: int                              # the study's trial number; -1 for the default configuration
    overrides: dict                          # --set style
    base_config: dict | None
    sets: tuple[str, ...]                    # --set items of every trial (before the trial's own values)
    datasets: tuple[str, ...]                # absolute paths
    seeds: int                               # Monte-Carlo seeds per drive (trials.apply)
    objectives: tuple[Objective, ...]
    prune_above: tuple[float, ...] = ()      # step i: stop when the running mean of objective 0 exceeds it


def _dataset(path: str):
    from .. import session

    if path not in _DATASETS:
        _DATASETS[path] = session.dataset(path)
        while len(_DATASETS) > _KEEP:
            _DATASETS.popitem(last=False)
    return _DATASETS[path]


def _shared(ds, path: str, cfg: dict, pool):
    from ..batch import batch_key
    from ..pipeline import share

    key = batch_key(path, cfg)
    if key not in _SHARED:
        with np.errstate(all="ignore"):
            _SHARED[key] = share(ds, cfg, pool)
        while len(_SHARED) > _KEEP:
            _SHARED.popitem(last=False)
    _SHARED.move_to_end(key)
    return _SHARED[key]


def _step(job: Job, path: str, seed: int) -> dict:
    from .. import session
    from .. import trials as mc
    from ..errors import FilterDivergedError, FusionEvalError
    from ..pipeline import filter_and_evaluate
    from ..pool import Inline

    rec = {"dataset": path, "seed": seed}
    try:
        ds = _dataset(path)
        req = session.request(config=job.base_config, sets=job.sets, overrides={**job.overrides, "output.plots": False})
        cfg = mc.apply(session.resolve(req, ds), seed)
        pool = Inline()
        sh = _shared(ds, path, cfg, pool)
        with np.errstate(all="ignore"):
            res = filter_and_evaluate(ds, cfg, sh, pool, dataset_path=path, config_source=req.source)
        flat = flatten(res.metrics)
        rec.update(status="ok", values=[o.value(flat) for o in job.objectives], metrics=flat,
                   resolved={k: _resolved(res.metrics, k) for k in ("imu_noise",)})
    except FilterDivergedError as exc:
        rec.update(status="diverged", error=str(exc))
    except FusionEvalError as exc:
        rec.update(status="failed", error=str(exc))
    except Exception as exc:  # noqa: BLE001 - a bug in one trial must not end the study; its traceback is kept
        rec.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())
    return rec


def _resolved(metrics: dict, key: str):
    return (metrics.get("preprocessing") or {}).get(key)


def score(job: Job) -> dict:
    """The trial's record: every (drive, seed) step with its metrics, the objectives' means over the steps, and a
    status: ok, pruned (its running mean of objective 0 went above the median of the finished trials at that step),
    diverged or failed (the first step that did, with its message)."""
    steps = []
    pairs = [(p, s) for p in job.datasets for s in range(job.seeds)]
    for i, (path, seed) in enumerate(pairs):
        st = _step(job, path, seed)
        steps.append(st)
        if st["status"] != "ok":
            return {"number": job.number, "status": st["status"], "error": st["error"], "steps": steps, "values": None}
        running = float(np.mean([s["values"][0] for s in steps]))
        if i < len(job.prune_above) and i < len(pairs) - 1 and running > job.prune_above[i]:
            return {"number": job.number, "status": "pruned", "error": None, "steps": steps, "values": None}
    values = [float(np.mean([s["values"][k] for s in steps])) for k in range(len(job.objectives))]
    bad = [o.name for o, v in zip(job.objectives, values) if not math.isfinite(v)]
    if bad:
        return {"number": job.number, "status": "failed", "steps": steps, "values": None,
                "error": f"objective {bad[0]!r} is not finite on {job.datasets[0]} (a metric this run has no value for)"}
    return {"number": job.number, "status": "ok", "error": None, "steps": steps, "values": values}
