"""``fusion-eval tune``: automatic noise tuning with Optuna (:mod:`fusion_eval.tuning`)."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path
from typing import Callable

from .. import resources
from ..errors import ConfigError, FusionEvalError
from ..tuning import objectives as obj
from ..tuning.report import write
from ..tuning.space import load_space
from ..tuning.study import Setup, run_study

TUNE_SPACES = "configs/tune"


def space_file(name: str) -> Path:
    """A space file: a path, else a shipped space by name (``noise`` -> ``configs/tune/noise.yaml``)."""
    p = resources.find(name)
    if p.exists():
        return p
    q = resources.find(Path(TUNE_SPACES) / (name if name.endswith((".yaml", ".yml")) else f"{name}.yaml"))
    if not q.exists():
        raise ConfigError(f"{name}: tune space not found (neither a file nor a shipped space such as 'noise')")
    return q


def run_tune(train: list[str], test: list[str], space: str, objectives: list[str], n_trials: int, out_dir: Path,
             sampler: str = "tpe", seed: int = 0, seeds: int = 1, config_path: Path | None = None, sets: tuple[str, ...] = (),
             jobs: int | None = None, scheduler: str | None = None, dask_local: bool = False, prune: bool = True,
             plots: bool = True, progress: Callable | None = None, batch: int = 4) -> dict:
    from .. import session
    from ..config import read_yaml

    if not objectives:
        raise ConfigError("give an --objective: nll or nis (no ground truth), or a metric key such as fused.ape.rmse")
    # one objective given twice ran as two, with duplicate columns (a review): compared by what they add up, an alias
    # and its full name, or a metric and its translation part's short key (fused.ape.rmse), being one
    same = [tuple(sorted((w, k.replace(".translation_m.", ".")) for w, k in obj.parse(o).terms)) for o in objectives]
    twice = next((i for i, t in enumerate(same) if t in same[:i]), None)
    if twice is not None:
        raise ConfigError(f"--objective {objectives[twice]!r} is the objective {objectives[same.index(same[twice])]!r} "
                          "again: a study's objectives are distinct")
    if scheduler and dask_local:
        raise ConfigError("give either --scheduler or --dask local, not both")
    if jobs is not None and jobs < 1:
        raise ConfigError("--jobs must be >= 1")
    if batch < 1:
        raise ConfigError("--batch must be >= 1")
    train_paths = [str(resources.find(d).resolve()) for d in (train or [resources.DEFAULT_DATASET])]
    test_paths = [str(resources.find(d).resolve()) for d in test]
    for p in train_paths + test_paths:
        if not Path(p).exists():
            raise ConfigError(f"{p}: dataset not found")
    # one drive given as its folder and as its manifest is one drive
    root = {p: str(Path(p).parent) if Path(p).is_file() else p for p in train_paths + test_paths}
    overlap = {root[p] for p in train_paths} & {root[p] for p in test_paths}
    if overlap:
        raise ConfigError(f"{sorted(overlap)[0]} is both a training and a held-out drive")
    s = Setup(space=load_space(space_file(space)), objectives=tuple(obj.parse(o) for o in objectives),
              train=tuple(train_paths), test=tuple(test_paths), n_trials=n_trials, out_dir=Path(out_dir).resolve(),
              sampler=sampler, seed=seed, seeds=seeds,
              base_config=_base(config_path, read_yaml), sets=tuple(sets),
              jobs=jobs or min(os.cpu_count() or 1, 4), batch=batch, scheduler=scheduler, dask_local=dask_local,
              prune=prune)
    session.request(sets=s.sets)         # a bad --set is refused before any work
    t0 = time.perf_counter()
    new_dir = not s.out_dir.exists()
    try:
        res = run_study(s, progress=progress)
    except ConfigError:
        # refused before any trial (an objective the runs have no metric for, the default configuration failing):
        # a folder this call made holds nothing worth keeping
        if new_dir and not any((s.out_dir / "trials").glob("*.json")):
            shutil.rmtree(s.out_dir, ignore_errors=True)
        raise
    except KeyboardInterrupt as exc:
        # the study's own account (how many trials are kept) where it gave one; else, once its folder exists, not
        # "no output directory was written" beside a journal of trials (a failure-injection review)
        if exc.args or not (s.out_dir / "study.journal").exists():
            raise
        raise type(exc)(f"the trials so far are kept in {s.out_dir}/study.journal; run the same command again to go "
                        "on") from None
    try:
        files = write(s, res, time.perf_counter() - t0, with_plots=plots)
    except KeyboardInterrupt as exc:
        raise type(exc)(f"every trial is kept in {s.out_dir}/study.journal, but the report was cut short (best.yaml, "
                        "tune.md, report.html and the plots may be missing or from an earlier run): run the same "
                        "command again to rewrite it") from None
    if res["best"] is None:
        # nothing tuned is a failure, as a sweep with nothing to rank: exit 0 and 'No trial completed' in tune.md hid it
        # (a corrupted-input review); the records stay, and the report says each trial's fate
        trials = res["study"].get_trials(deepcopy=False)
        first = next((t.user_attrs["error"] for t in trials if t.user_attrs.get("error")), None)
        raise FusionEvalError(f"no trial of the tune completed ({len(trials)} failed, diverged or pruned; every trial "
                              f"is in {s.out_dir}/trials.csv and tune.md)" + (f"; the first error: {first}" if first else ""))
    return {"setup": s, "result": res, "files": files, "runtime_s": time.perf_counter() - t0}


def _base(path: Path | None, read_yaml) -> dict | None:
    if path is None:
        return None
    body = read_yaml(Path(path), "tune base config") or {}
    if not isinstance(body, dict):
        raise ConfigError(f"{path}: the base configuration must be a mapping of sections")
    return body
