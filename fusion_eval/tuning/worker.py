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

from .. import interrupts
from ..log_context import prefixed
from .objectives import Objective, flatten

# Pruning reports. Each (drive, seed) step reports the objective's running mean at its end; where the objective is
# the innovation NLL alone, also at these fractions of the replay's events (the NLL per update over the events so
# far, in the running mean with the steps before): a hopeless trial stops inside the replay, before its evaluation.
CHECKPOINTS = (0.25, 0.5, 0.75)
REPORTS = len(CHECKPOINTS) + 1      # reports per step; step i's are indices i * REPORTS + 0 .. REPORTS - 1 (its end)

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
    prune_above: tuple[tuple[int, float], ...] = ()   # (report index, threshold): stop when report > threshold


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


class _Pruned(Exception):
    """Raised by :class:`_NllWatch` inside the replay: the trial is pruned."""


def _nll_weight(job: Job) -> float | None:
    """The objective 0 as a multiple of the innovation NLL (its weight), or None if it is anything else."""
    terms = job.objectives[0].terms
    return sum(w for w, _ in terms) if all(k == "innovations.nll_per_update" for _, k in terms) else None


class _NllWatch:
    """The NLL per update of the replay's first events at each checkpoint: the same quantity as
    ``innovations.nll_per_update`` (``0.5 (NIS + ln det S + m ln 2 pi)`` over every update, rejected ones included),
    over the events so far. Records each checkpoint's report; raises :class:`_Pruned` above its threshold."""

    def __init__(self, weight: float, before: list[float], step: int, thresholds: dict[int, float]):
        self.weight, self.before, self.step, self.thresholds = weight, before, step, thresholds
        self.reports: list[float] = []

    def __call__(self, j: int, nis: np.ndarray, logdet_S: np.ndarray, dof: np.ndarray) -> None:
        while len(self.reports) < len(CHECKPOINTS) and j >= CHECKPOINTS[len(self.reports)] * dof.size:
            k = int(CHECKPOINTS[len(self.reports)] * dof.size)
            value = (sum(self.before) + self.weight * nll_so_far(nis[:k], logdet_S[:k], dof[:k])) / (len(self.before) + 1)
            self.reports.append(value)
            thr = self.thresholds.get(self.step * REPORTS + len(self.reports) - 1)
            if thr is not None and math.isfinite(value) and value > thr:     # NaN (no update yet): never pruned on
                raise _Pruned


def nll_so_far(nis: np.ndarray, logdet_S: np.ndarray, dof: np.ndarray) -> float:
    """The innovations' NLL per update over a replay's events (NaN NIS: an event that updated nothing), by the
    formula of the metric (:func:`fusion_eval.evaluation.consistency.innovation_nll`); over all of them it is
    ``innovations.nll_per_update`` (tested)."""
    from ..evaluation.consistency import innovation_nll

    sel = np.isfinite(nis)
    return innovation_nll(nis[sel], logdet_S[sel], dof[sel]) if sel.any() else math.nan


def _step(job: Job, path: str, seed: int, watch: _NllWatch | None = None) -> dict:
    from .. import session
    from .. import trials as mc
    from ..errors import FilterDivergedError, FusionEvalError
    from ..pipeline import filter_and_evaluate
    from ..pool import Inline

    rec = {"dataset": path, "seed": seed}
    try:
        if watch is not None:
            rec["checkpoints"] = watch.reports          # filled during the replay
        ds = _dataset(path)
        req = session.request(config=job.base_config, sets=job.sets, overrides={**job.overrides, "output.plots": False})
        cfg = mc.apply(session.resolve(req, ds), seed)
        pool = Inline()
        sh = _shared(ds, path, cfg, pool)
        with np.errstate(all="ignore"):
            res = filter_and_evaluate(ds, cfg, sh, pool, dataset_path=path, config_source=req.source, monitor=watch)
        flat = flatten(res.metrics)
        rec.update(status="ok", values=[o.value(flat) for o in job.objectives], metrics=flat,
                   resolved={k: _resolved(res.metrics, k) for k in ("imu_noise", "auto_settled")})
    except _Pruned:
        rec.update(status="pruned", error=None)
    except FilterDivergedError as exc:
        rec.update(status="diverged", error=str(exc))
    except FusionEvalError as exc:
        rec.update(status="failed", error=str(exc))
    except Exception as exc:  # noqa: BLE001 - a bug in one trial must not end the study; its traceback is kept
        interrupts.reraise_if_received()          # (a Ctrl-C inside compiled code is not the trial's failure)
        rec.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())
    return rec


def _resolved(metrics: dict, key: str):
    return (metrics.get("preprocessing") or {}).get(key)


def score(job: Job) -> dict:
    """The trial's record: every (drive, seed) step with its metrics, the objectives' means over the steps, and a
    status: ok, pruned (a report of objective 0, inside a replay or at a step's end, went above the median of the
    finished trials' reports at that point), diverged or failed (the first step that did, with its message)."""
    steps = []
    pairs = [(p, s) for p in job.datasets for s in range(job.seeds)]
    thresholds = dict(job.prune_above)
    weight = _nll_weight(job)
    for i, (path, seed) in enumerate(pairs):
        before = [s["values"][0] for s in steps]
        watch = _NllWatch(weight, before, i, thresholds) if weight is not None else None
        with prefixed(f"trial {job.number} ({path}" + (f", seed {seed})" if job.seeds > 1 else ")")):
            st = _step(job, path, seed, watch)
        steps.append(st)
        if st["status"] != "ok":
            return {"number": job.number, "status": st["status"], "error": st["error"], "steps": steps, "values": None}
        running = float(np.mean([s["values"][0] for s in steps]))
        thr = thresholds.get(i * REPORTS + REPORTS - 1)
        if thr is not None and i < len(pairs) - 1 and running > thr:
            return {"number": job.number, "status": "pruned", "error": None, "steps": steps, "values": None}
    values = [float(np.mean([s["values"][k] for s in steps])) for k in range(len(job.objectives))]
    bad = [o.name for o, v in zip(job.objectives, values) if not math.isfinite(v)]
    if bad:
        return {"number": job.number, "status": "failed", "steps": steps, "values": None,
                "error": f"objective {bad[0]!r} is not finite on {job.datasets[0]} (a metric this run has no value for)"}
    return {"number": job.number, "status": "ok", "error": None, "steps": steps, "values": values}
