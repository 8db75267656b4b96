"""``fusion-eval sweep``: many runs over noise settings, variants and datasets, locally or on Dask.

A sweep file (YAML) names what to run::

    datasets: [data/kitti-00]            # or given on the command line
    variants: [eskf]                     # configs/variants names or YAML paths (default: the plain defaults)
    config: base.yaml                    # optional base configuration for every run
    plots: false                         # per-run plots
    grid:                                # a product grid over configuration keys ...
      imu.gyro_noise_dps_sqrthz: [0.05, 0.1, 0.2]
    settings:                            # ... and/or named settings ...
      tight: {lidar.relative_att_std_deg: 0.02}
    random:                              # ... and/or N log-uniform samples, seeded
      n: 8
      seed: 0
      ranges: {imu.gyro_noise_dps_sqrthz: [0.01, 1.0]}

Every run is keyed on a hash of its dataset and resolved configuration; its outputs go to
``runs/<id>/`` (as for ``fusion-eval run``) and its record (metrics or error) to ``records/<id>.json``,
written atomically as it completes. Running the sweep again skips runs that have a record, so an
interrupted sweep loses nothing; the summary (``sweep.csv``, ``sweep.md``, plots, ``best.yaml``,
:mod:`.sweep_summary`) is rebuilt from the records.

Relative paths in a sweep file (datasets, ``config``) are taken from the working directory, else from the
sweep file's folder, else from the project the sweep file belongs to (the checkout, or the shipped tree
for a shipped sweep such as ``noise5``). Every path a task carries is absolute, so a worker started in
any directory (a Dask worker on another host with the same paths) runs it.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import logging
import math
import os
import shutil
import time
import traceback
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .. import interrupts, resources, session, yaml_lines
from .. import trials as mc
from ..config import check_value, read_yaml, schema
from ..errors import ConfigError, FilterDivergedError, FusionEvalError
from ..log_context import prefixed
from ..batch import FILTER_ONLY_KEYS, batch_key  # noqa: F401 - FILTER_ONLY_KEYS: part of this module's API
from .. import locks
from ..outputs import dataset_roots, resumable_dir
from ..provenance import fingerprint
from ..variants import resolve_variant

log = logging.getLogger(__name__)

MAX_SETTINGS = 100_000      # a sweep's settings: beyond, a typo (a 400^3 grid once filled 600 MB before running anything)
SWEEP_KEYS = {"datasets", "variants", "config", "plots", "grid", "settings", "random", "trials", "objective"}


@dataclass(frozen=True)
class Task:
    id: str
    dataset: str
    variant: str
    variant_path: str | None      # absolute
    setting: str
    overrides: dict
    base_config: dict | None
    plots: bool
    out_root: str                 # absolute
    trial: int = 0                # Monte-Carlo trial: the seeds of every random element plus this
    batch: str = ""               # runs with one batch key share their data preparation (batch_key)
    ship: bool = False            # a cluster worker: write the run in a local folder and send its files back


BATCH_MAX = 8            # runs per batch at most: an interrupted batch is redone whole; smaller keeps both cores busy
# the last batch's loaded and prepared data in this (worker) process, by sweep folder and batch key: the later batches
# of a key that BATCH_MAX cut up reuse it, so a worker loads and prepares (time offsets, unfiltered evaluations) once
# per key, not once per batch (noise64 on kitti-00: 9 batches on 2 workers; that work was a quarter of the sweep's
# CPU). Emptied when a sweep ends in this process (--jobs 1), so nothing outlives the sweep that read it
_PREPARED: dict = {}


def _num(v):
    return float(v) if isinstance(v, str) else v


def load_sweep(path: Path) -> dict:
    body = read_yaml(path, "sweep file")
    if not isinstance(body, dict):
        raise ConfigError(f"{path}: a sweep file is a mapping with grid, settings or random")
    bad = set(body) - SWEEP_KEYS
    if bad:
        raise ConfigError(f"{yaml_lines.at(path, body, sorted(bad)[0])}: unknown sweep key {sorted(bad)[0]!r} (known: {', '.join(sorted(SWEEP_KEYS))})")
    for key, kind, what in (("grid", dict, "a mapping of configuration keys to lists of values"),
                            ("settings", dict, "a mapping of setting names to {key: value}"),
                            ("random", dict, "a mapping with n, seed and ranges"),
                            ("datasets", list, "a list of dataset paths"), ("variants", list, "a list of variant names"),
                            ("plots", bool, "true or false"), ("config", str, "a configuration file path"),
                            ("objective", str, "what the summary ranks by, as --objective (fused.rpe_100m.rmse, ...)")):
        if key in body and body[key] is not None and not isinstance(body[key], kind):
            raise ConfigError(f"{yaml_lines.at(path, body, key)}: '{key}' must be {what}, got {body[key]!r}")
    for key in ("datasets", "variants"):          # each entry a name or path (a blank '-' entry was a traceback)
        bad = next((v for v in body.get(key) or () if not isinstance(v, str) or not v.strip()), "ok")
        if bad != "ok":
            raise ConfigError(f"{yaml_lines.at(path, body, key)}: every entry of '{key}' must be a "
                              f"{'variant name or YAML path' if key == 'variants' else 'dataset path'}, got {bad!r}")
    tr = body.get("trials", 1)
    if isinstance(tr, bool) or not isinstance(tr, int) or tr < 1:
        raise ConfigError(f"{yaml_lines.at(path, body, 'trials')}: 'trials' must be a whole number >= 1 (Monte-Carlo trials of every setting), got {tr!r}")
    rnd = body.get("random")
    if rnd:
        n, seed, ranges = rnd.get("n"), rnd.get("seed", 0), rnd.get("ranges")
        if isinstance(n, bool) or not isinstance(n, int) or n <= 0 or isinstance(seed, bool) or not isinstance(seed, int):
            raise ConfigError(f"{yaml_lines.at(path, rnd, 'n')}: random needs an integer n > 0 and an integer seed, got n={n!r}, seed={seed!r}")
        if not isinstance(ranges, dict) or not ranges or not all(
                isinstance(v, list) and len(v) == 2 and all(_isnum(x) for x in v) for v in ranges.values()):
            raise ConfigError(f"{yaml_lines.at(path, rnd, 'ranges')}: random ranges must map keys to [low, high] numbers, got {ranges!r}")
    return body


def _isnum(v) -> bool:
    try:
        return math.isfinite(float(v)) and not isinstance(v, bool)
    except (TypeError, ValueError):
        return False


def settings_of(body: dict, where: str) -> list[tuple[str, dict]]:
    """(name, {key: value}) for every setting: 'default' first, then named, grid and random ones."""
    out: list[tuple[str, dict]] = [("default", {})]

    known = schema()

    def check(key, value, mapping):
        at = yaml_lines.at(where, mapping, key)            # the line of the key in the sweep file
        if key not in known:
            import difflib

            close = difflib.get_close_matches(str(key), list(known), n=3)
            raise ConfigError(f"{at}: unknown configuration key {key!r} in the sweep"
                              + (f" (did you mean {', '.join(close)}?)" if close else ""))
        if key in getattr(mapping, "empty", ()):     # 'gnss.rate_hz:' with nothing after it: YAML's null
            raise ConfigError(f"{at}: {key} has no value (write null for null)")
        return check_value(key, known[key], value, at)

    for name, ov in (body.get("settings") or {}).items():
        if str(name) == "default":          # it was "setting names must be unique", with no line
            raise ConfigError(f"{yaml_lines.at(where, body.get('settings'), name)}: 'default' is the name of the run "
                              "with no setting, which every sweep makes; name this setting otherwise")
        if not isinstance(ov, dict):
            raise ConfigError(f"{yaml_lines.at(where, body.get('settings'), name)}: setting {name!r} must map configuration "
                              "keys to values")
        out.append((str(name), {k: check(k, v, ov) for k, v in ov.items()}))
    grid = body.get("grid") or {}
    rnd = body.get("random")
    if grid:
        gkeys = list(grid)
        for k in gkeys:
            if not isinstance(grid[k], list) or not grid[k]:
                raise ConfigError(f"{yaml_lines.at(where, grid, k)}: grid key {k!r} needs a non-empty list of values")
            if len(set(map(repr, grid[k]))) != len(grid[k]):
                raise ConfigError(f"{yaml_lines.at(where, grid, k)}: grid key {k!r} lists a value twice: {grid[k]!r}")
        size = math.prod(len(grid[k]) for k in gkeys) + (int(rnd["n"]) if rnd else 0)
        if size > MAX_SETTINGS:
            raise ConfigError(f"{where}: the sweep has {size:,} settings, more than {MAX_SETTINGS:,} (a grid of "
                              f"{' x '.join(str(len(grid[k])) for k in gkeys)}); sweep fewer values, or use random")
        for combo in itertools.product(*(grid[k] for k in gkeys)):
            ov = {k: check(k, v, grid) for k, v in zip(gkeys, combo)}
            out.append((",".join(f"{k}={v}" for k, v in ov.items()), ov))
    if rnd:
        n, seed, ranges = int(rnd["n"]), int(rnd.get("seed", 0)), rnd["ranges"]
        if n > MAX_SETTINGS:
            raise ConfigError(f"{yaml_lines.at(where, rnd, 'n')}: random n={n:,} is more than {MAX_SETTINGS:,} settings")
        for k, (lo, hi) in ranges.items():
            if not (0 < _num(lo) < _num(hi)):
                raise ConfigError(f"{yaml_lines.at(where, ranges, k)}: random range of {k!r} must be 0 < low < high "
                                  f"(log-uniform), got [{lo}, {hi}]")
            if k in known and known[k].choices:
                raise ConfigError(f"{yaml_lines.at(where, ranges, k)}: {k!r} takes one of {', '.join(map(str, known[k].choices))}"
                                  ": a choice, not a range (put it in grid)")
        rng = np.random.default_rng(seed)
        for i in range(n):
            ov = {}
            for k, (lo, hi) in ranges.items():
                lo, hi = _num(lo), _num(hi)
                ov[k] = check(k, float(math.exp(rng.uniform(math.log(lo), math.log(hi)))), ranges)
            out.append((f"random-{i:03d}", ov))
    names = [n for n, _ in out]
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise ConfigError(f"{where}: setting names must be unique: {twice!r} is made twice (a named setting and a grid "
                          "or random one)")
    if len(out) == 1:
        raise ConfigError(f"{where}: nothing to sweep (give grid, settings or random)")
    return out


def swept_keys(body: dict) -> list[str]:
    keys: list[str] = []
    for src in ((body.get("settings") or {}).values(), [body.get("grid") or {}], [(body.get("random") or {}).get("ranges") or {}]):
        for d in src:
            for k in d:
                if k not in keys:
                    keys.append(k)
    return keys


def _distinct(paths: list) -> list:
    """The datasets once each: a folder and its own manifest are one dataset (a sweep given both ran every setting twice
    and counted the drive twice in its cross-dataset mean; found by a corrupted-input review)."""
    seen: dict = {}
    out = []
    for p in paths:
        r = Path(p).resolve()
        key = r / "dataset.yaml" if r.is_dir() and (r / "dataset.yaml").is_file() else r
        if key in seen:
            log.warning("%s is the dataset %s again: swept once", p, seen[key])
            continue
        seen[key] = p
        out.append(p)
    return out


def plan(sweep_path: Path, datasets: list[str], out_dir: Path, variant_dir: Path | None = None,
         trials: int | None = None) -> tuple[list[Task], dict]:
    """Every (dataset, variant, setting, trial) run of a sweep, each with absolute paths. ``trials``: Monte-Carlo
    trials of every setting (default: the sweep file's ``trials``, else 1)."""
    body = load_sweep(sweep_path)
    n_trials = mc.check_count(trials if trials is not None else body.get("trials", 1))
    here = Path(sweep_path).resolve().parent
    project = resources.project_root_of(sweep_path)
    given = list(datasets)
    datasets = given or [str(d) for d in (body.get("datasets") or [])]
    if not datasets:
        raise ConfigError(f"{sweep_path}: no datasets (give them in the sweep file or on the command line)")
    # datasets on the command line are the user's (working directory); those in the file are the file's
    paths = _distinct([resources.find(d) if given else resources.find(d, here, project) for d in datasets])
    base = None
    if body.get("config"):
        base = load_sweep_config(resources.find(body["config"], here, project))
    if variant_dir is None:
        variant_dir = resources.find(resources.VARIANTS, project)
    variants = body.get("variants") or ["default"]
    vpaths = {v: (None if v == "default" else str(resolve_variant(v, variant_dir).resolve())) for v in variants}
    settings = settings_of(body, str(sweep_path))
    seeds = [k for k in swept_keys(body) if k in mc.seed_keys()]
    if seeds:
        # a seed ranked as a setting: gnss.seed 3 came first at 0.631 m against the default's 0.753 and went into
        # best.yaml (a statistics review); tune refuses them as keys that change the data
        raise ConfigError(f"{sweep_path}: {', '.join(seeds)} is swept, but a seed is not a setting to rank: it changes "
                          "the random draw, which moves the fused APE by about 11 % on its own; average every setting "
                          "over seeds with --trials N (or 'trials: N' in the sweep file)")
    n_runs = len(paths) * len(variants) * len(settings) * n_trials
    if n_runs > MAX_SETTINGS:
        raise ConfigError(f"{sweep_path}: the sweep plans {n_runs:,} runs ({len(paths)} datasets x {len(variants)} variants x "
                          f"{len(settings)} settings x {n_trials} trials), more than {MAX_SETTINGS:,}")
    out_root = str(Path(out_dir).resolve())
    tasks = []
    for ds_path in paths:
        ds = session.dataset(ds_path)
        ds_abs = str(Path(ds_path).resolve())
        data = fingerprint(ds.description)      # the files as they are: changed data is not a recorded run
        scored: list[tuple[str, dict]] = []     # every run of a dataset is ranked against the others: scored alike
        for v in variants:
            for name, ov in settings:
                cfg0 = session.resolve(session.request(config=base, variant=vpaths[v], overrides=ov), ds)
                scored.append((f"variant {v!r} setting {name!r}", cfg0))
                for i in range(n_trials):
                    ov_i = {**ov, **mc.trial_overrides(cfg0, i)} if i else ov
                    cfg = mc.apply(cfg0, i)
                    key = json.dumps({"dataset": ds_abs, "data": data, "config": cfg}, sort_keys=True)
                    rid = hashlib.sha256(key.encode()).hexdigest()[:12]
                    tasks.append(Task(rid, ds_abs, v, vpaths[v], name, ov_i, base, bool(body.get("plots", False)), out_root,
                                      i, batch_key(ds_abs, cfg)))
        # what the ranked figure (the fused APE) depends on; an RPE distance or a segment length may be swept (their
        # columns are named by it)
        session.same_evaluation(*zip(*scored), str(sweep_path), "a sweep ranks its runs of a dataset by their APE; "
                                "set these evaluation keys for all of them (the sweep's config:), not in a setting or "
                                "variant", keys=("association", "alignment", "t_max_diff_s", "span"))
        first, seeds = scored[0][0], mc.effective_seeds(scored[0][1])
        for other, c in scored[1:]:
            if mc.effective_seeds(c) != seeds:
                # a variant file setting its own gnss.seed ranked against the others on its seed (0.347 against 0.323 m,
                # 7 %, with no word; a diff review): refused as a seed swept as a setting is
                spell = lambda d: ", ".join(f"{a}={b}" for a, b in sorted(d.items()))   # noqa: E731
                raise ConfigError(f"{sweep_path}: {other} draws its random elements with other seeds "
                                  f"({spell(mc.effective_seeds(c))}) than {first} ({spell(seeds)}): a seed is not a setting "
                                  "to rank; take the seed out of the variant, and average over seeds with --trials N")
    ids = [t.id for t in tasks]
    if len(set(ids)) != len(ids):
        log.warning("some settings resolve to the same configuration; they share one run")
    return tasks, body


def load_sweep_config(path: Path) -> dict:
    body = read_yaml(path, "sweep base config") or {}
    if not isinstance(body, dict):
        raise ConfigError(f"{path}: the sweep's base config must be a mapping of sections")
    return body


def run_task(task: Task) -> dict:
    """Run one sweep entry; never raises for a failed run (the failure is the record)."""
    from ..pipeline import run_to_dir

    root = _run_root(task)

    def work():
        req = session.request(config=task.base_config, variant=task.variant_path, overrides=_overrides(task))
        return run_to_dir(task.dataset, req, root / "runs" / task.id, overwrite=True, jobs=1,
                          wait_lock_s=RUN_LOCK_WAIT_S)
    return _finish(task, _record(task, work), root)


def _run_root(task: Task) -> Path:
    """Where a run writes its folder: the sweep's own (a local pool, or a cluster on a shared filesystem) or, on a
    cluster worker (``ship``), a local temporary folder whose files go back to the client with the record."""
    import tempfile

    return Path(tempfile.mkdtemp(prefix="fusion-eval-run-")) if task.ship else Path(task.out_root)


def _finish(task: Task, rec: dict, root: Path) -> dict:
    if task.ship:
        import shutil

        folder = root / "runs" / task.id
        rec["files"] = ({f.relative_to(folder).as_posix(): f.read_bytes() for f in sorted(folder.rglob("*")) if f.is_file()}
                        if folder.is_dir() else {})
        shutil.rmtree(root, ignore_errors=True)
    else:
        # written here too (the submitting process writes it again, the same bytes): a sweep killed between this
        # run's end and the collection of its result keeps it
        write_record(Path(task.out_root), rec)
    return rec


def _overrides(task: Task) -> dict:
    return {**task.overrides, **({} if task.plots else {"output.plots": False})}


def _record(task: Task, work: Callable, extra_s: float = 0.0) -> dict:
    """The record of one entry: ``work()``'s metrics, or its error (a bug's traceback kept): a failed run
    never stops a sweep."""
    t0 = time.perf_counter()
    rec = {"id": task.id, "dataset": task.dataset, "variant": task.variant, "setting": task.setting,
           "overrides": task.overrides, "trial": task.trial}
    label = f"run {task.id} ({task.dataset}, {task.variant}, {task.setting}" + (f", trial {task.trial})" if task.trial else ")")
    try:
        with np.errstate(all="ignore"), prefixed(label):
            res = work()
        rec.update(status="ok", error=None, metrics=res.metrics)
    except FilterDivergedError as exc:     # its own status: a setting that makes the filter diverge is a finding
        rec.update(status="diverged", error=str(exc), metrics=None)
    except FusionEvalError as exc:
        rec.update(status="failed", error=str(exc), metrics=None)
    except Exception as exc:  # noqa: BLE001 - a bug in one run must not stop the sweep; its traceback is kept
        interrupts.reraise_if_received()          # (a Ctrl-C inside compiled code is not the run's failure)
        rec.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(), metrics=None)
    rec["runtime_s"] = round(time.perf_counter() - t0 + extra_s, 3)
    return rec


RUN_LOCK_WAIT_S = 600.0     # a retried run waits this long for a lost worker still writing it


def run_batch(tasks: list[Task]) -> list[dict]:
    """Run sweep entries that share a batch key (:func:`batch_key`): the dataset loaded and prepared once, the
    unfiltered estimates evaluated once, then each entry's filter replayed, evaluated and written as
    :func:`run_task` would (the same files and metrics; ``tests/test_sweep_check.py``). Each record is written
    as its run completes (the submitting process writes it again, the same bytes), so a killed batch keeps its
    finished runs. Never raises."""
    from ..outputs import StagedDir
    from ..pipeline import filter_and_evaluate, share
    from ..pool import Inline

    if len(tasks) == 1:
        return [run_task(tasks[0])]
    recs, cfgs, reqs = [], [], []
    t_load = time.perf_counter()
    try:
        key = (tasks[0].out_root, tasks[0].batch)       # this sweep's (a persistent Dask worker serves several)
        kept = _PREPARED.get(key)
        ds, sh, pool = kept if kept is not None else (session.dataset(tasks[0].dataset), None, Inline())
        for task in tasks:
            reqs.append(session.request(config=task.base_config, variant=task.variant_path, overrides=_overrides(task)))
            cfgs.append(session.resolve(reqs[-1], ds))
        if sh is None:
            _PREPARED.clear()                # one preparation held per worker: the next key's replaces it
            with np.errstate(all="ignore"):
                sh = share(ds, cfgs[0], pool)
            _PREPARED[key] = (ds, sh, pool)
    except Exception:  # noqa: BLE001 - the preparation failed (or a bug): each entry runs alone and says why
        interrupts.reraise_if_received()
        return [run_task(t) for t in tasks]
    shared_s = (time.perf_counter() - t_load) / len(tasks)
    for task, req, cfg in zip(tasks, reqs, cfgs):
        root = _run_root(task)

        def work():
            with StagedDir(root / "runs" / task.id, overwrite=True, wait_lock_s=RUN_LOCK_WAIT_S) as out:
                return filter_and_evaluate(ds, cfg, sh, pool, dataset_path=task.dataset, config_source=req.source,
                                           out=out)
        rec = _record(task, work, shared_s)
        rec["batch"] = task.batch
        # the later runs on this preparation (this batch's, a later batch's of the key on this worker) link the first
        # finished one's files of the shared estimates; not a cluster worker's, shipped back and removed
        if sh.files_from is None and not task.ship and rec.get("status") == "ok":
            sh.files_from = root / "runs" / task.id
        recs.append(_finish(task, rec, root))
    return recs


def batches(todo: list[Task], jobs: int) -> list[list[Task]]:
    """The runs grouped by batch key, cut into chunks of at most :data:`BATCH_MAX` and at most an equal share of
    the workers (so that a sweep of one batch still spreads over every core), of sizes that differ by one at most:
    17 runs make 6 + 6 + 5, not 8 + 8 + 1, whose single run would load and prepare the data alone."""
    groups: dict[str, list[Task]] = {}
    for t in todo:
        groups.setdefault(t.batch or t.id, []).append(t)
    out = []
    for g in groups.values():
        size = max(1, min(BATCH_MAX, math.ceil(len(g) / max(jobs, 1))))
        k = math.ceil(len(g) / size)
        ends = [round(i * len(g) / k) for i in range(k + 1)]
        out += [g[ends[i]:ends[i + 1]] for i in range(k)]
    return out


def write_record(out_dir: Path, rec: dict) -> None:
    d = Path(out_dir) / "records"
    d.mkdir(parents=True, exist_ok=True)
    tmp = d / f".{rec['id']}.json.tmp"
    tmp.write_text(json.dumps(rec, indent=1, default=float), encoding="utf-8")
    os.replace(tmp, d / f"{rec['id']}.json")


def read_records(out_dir: Path) -> dict[str, dict]:
    d = Path(out_dir) / "records"
    out = {}
    for f in sorted(d.glob("*.json")) if d.is_dir() else []:
        try:
            out[f.stem] = json.loads(f.read_text(encoding="utf-8"))
        except json.JSONDecodeError:
            log.warning("%s: unreadable record, the run will be done again", f)
    return out


def _cleanup_partials(out_dir: Path) -> None:
    runs = Path(out_dir) / "runs"
    for p in runs.glob(".*.partial-*") if runs.is_dir() else []:
        shutil.rmtree(p, ignore_errors=True)   # left by a killed run: that run has no record and is redone


def execute(tasks: list[Task], out_dir: Path, jobs: int | None, scheduler: str | None, dask_local: bool,
            retry_failed: bool = False, progress: Callable[[int, int, int, int], None] | None = None,
            batch: bool = True) -> dict:
    """Run every task without a record; records are written as runs (or batches, :func:`run_batch`) complete.
    ``batch`` False runs every task on its own. Returns counts."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    _cleanup_partials(out_dir)
    done = read_records(out_dir)
    unique: dict[str, Task] = {}
    for t in tasks:
        unique.setdefault(t.id, t)
    todo = [t for t in unique.values() if t.id not in done or (retry_failed and done[t.id]["status"] != "ok")]
    skipped = len(unique) - len(todo)
    n_ok = n_fail = 0
    total = len(todo)
    if progress:
        progress(0, 0, total, skipped)
    if not todo:
        return {"run": 0, "failed": 0, "skipped": skipped}
    jobs = jobs or os.cpu_count() or 1

    def finished(rec):
        nonlocal n_ok, n_fail
        files = rec.pop("files", None)
        if files is not None:            # a cluster worker's run folder, sent back: written here, atomically
            from ..outputs import StagedDir

            with StagedDir(out_dir / "runs" / rec["id"], overwrite=True) as out:
                for name, data in files.items():
                    out.write_bytes(name, data)
        write_record(out_dir, rec)
        if rec["status"] == "ok":
            n_ok += 1
        else:
            n_fail += 1
            log.warning("run %s (%s, %s) %s: %s", rec["id"], rec["dataset"], rec["setting"], rec["status"], rec["error"])
        if progress:
            progress(n_ok, n_fail, total - n_ok - n_fail, skipped)

    def interrupted(exc: KeyboardInterrupt) -> KeyboardInterrupt:
        """The same interrupt (Ctrl-C or SIGTERM), saying what is kept and how to resume: the records on disk, which
        the workers write as each run ends (counted as batches came back, a five-run batch interrupted after four
        said '1 of 5 runs are recorded'; an interruption review)."""
        try:
            now = read_records(out_dir)
        except (OSError, ValueError):
            now = {}
        # (with --retry-failed a failed record is one this command redoes: not kept; a diff review)
        kept = max(n_ok + n_fail + skipped,
                   sum(t in now and (not retry_failed or now[t].get("status") == "ok") for t in unique))
        return type(exc)(f"{kept} of {len(unique)} runs are recorded in {out_dir}/records; run the same command again "
                         f"to do the {len(unique) - kept} left (finished runs are not redone)")

    work = batches(todo, jobs) if batch else [[t] for t in todo]
    shared = [w for w in work if len(w) > 1]
    if shared:
        log.info("%d of %d runs differ only in filter settings: %s, each loading and preparing the data once",
                 sum(map(len, shared)), len(todo), "1 batch" if len(shared) == 1 else f"{len(shared)} batches")
    if scheduler or dask_local:
        from dask.distributed import as_completed

        from ..pool import dask_client

        if scheduler:
            # remote workers may not share this filesystem: each writes its run locally and sends the files back
            work = [[dataclasses.replace(t, ship=True) for t in w] for w in work]
        try:
            with dask_client(scheduler, jobs if dask_local else 0) as client:
                futures = [client.submit(run_batch, w, key=f"fusion-eval-{w[0].id}-{len(w)}", pure=False)
                           for w in work]
                for fut in as_completed(futures):
                    for rec in fut.result():
                        finished(rec)
        except KeyboardInterrupt as exc:
            # while the cluster starts or runs: what is recorded, not "no output directory was written" (a review)
            raise interrupted(exc) from None
        except ConfigError:
            # an address nobody answers, after its 30 s: no empty folder left (its lock is this sweep's own)
            if not any(p.is_file() and p.name != ".sweep.lock" for p in out_dir.rglob("*")):
                shutil.rmtree(out_dir, ignore_errors=True)
            raise
    elif jobs == 1:
        try:
            for w in work:
                for rec in run_batch(w):
                    finished(rec)
        except KeyboardInterrupt as exc:
            raise interrupted(exc) from None
        finally:
            _PREPARED.clear()
    else:
        import multiprocessing as mp
        from concurrent.futures import as_completed as cf_completed

        from ..pool import Pool

        consumed: set = set()
        with Pool(max_workers=jobs, mp_context=mp.get_context("spawn")) as pool:
            futs = [pool.submit(run_batch, w) for w in work]
            try:
                for f in cf_completed(futs):
                    consumed.add(f)
                    for rec in f.result():
                        finished(rec)
            except KeyboardInterrupt as exc:
                # every run that finished is kept: the batches done but not yet collected are recorded now (their
                # workers wrote the records too); the rest are cancelled and their workers killed by the pool
                for f in futs:
                    if f not in consumed and f.done() and not f.cancelled() and f.exception() is None:
                        for rec in f.result():
                            finished(rec)
                raise interrupted(exc) from None
    return {"run": n_ok, "failed": n_fail, "skipped": skipped}


def run_sweep(sweep: str | Path, datasets: list[str], out_dir: Path, jobs: int | None = None, variant_dir: Path | None = None,
              scheduler: str | None = None, dask_local: bool = False, retry_failed: bool = False,
              summarize_only: bool = False, plots: bool = True,
              progress_for: Callable[[int], Callable | None] | None = None, trials: int | None = None,
              batch: bool = True, objective: str | None = None) -> dict:
    """Plan, run (unless ``summarize_only``) and summarise a sweep; ``sweep`` a file or a shipped sweep's name.
    ``progress_for(total)`` gives the progress callback of :func:`execute`; ``objective``: what the summary ranks
    by (default: the sweep file's ``objective``, else the fused APE RMSE). Returns the counts and the summary."""
    from ..datasets.manifest import declares_ground_truth
    from .sweep_summary import ranking, write_summary

    if scheduler and dask_local:
        raise ConfigError("give either --scheduler or --dask local, not both")
    if jobs is not None and jobs < 1:
        raise ConfigError("--jobs must be >= 1")
    sweep_path = resources.sweep_file(str(sweep))
    tasks, body = plan(sweep_path, datasets, out_dir, variant_dir, trials)
    objective = objective or body.get("objective")
    if objective is None and not any(declares_ground_truth(resources.find(d)) for d in {t.dataset for t in tasks}):
        # nothing scored to rank by: the innovations' likelihood, said (it ran every run, then refused the APE: a trial)
        objective = "nll"
        log.warning("the sweep's drives have no ground truth: ranked by nll (the innovations' likelihood per update); "
                    "--objective nis ranks by their calibration")
    ranking(objective)                # a malformed objective is refused before any run
    if not summarize_only:
        resumable_dir(out_dir, ("records", "runs"), "sweep", dataset_roots(*{t.dataset for t in tasks}))
    counts = {"run": 0, "failed": 0, "skipped": 0}
    if summarize_only:
        if not (Path(out_dir) / "records").is_dir():
            raise ConfigError(f"{out_dir}: no sweep records here (nothing to summarize)")
    try:
        if not summarize_only:
            progress = progress_for(len({t.id for t in tasks})) if progress_for else None
            # two sweeps into one folder would each run what the other had not recorded yet, one replacing the
            # other's finished runs (a run's own lock only made the second wait for it): the second is refused
            (Path(out_dir) / "records").mkdir(exist_ok=True)      # a sweep killed at once is still one to resume
            with locks.held(Path(out_dir) / ".sweep.lock",
                           lambda pid: f"{out_dir}: another fusion-eval sweep (pid {pid}) is running in this folder; "
                                       "wait for it (then run this one again to resume it), or choose another --out"):
                counts = execute(tasks, out_dir, jobs, scheduler, dask_local, retry_failed, progress=progress,
                                 batch=batch)
        summary = write_summary(tasks, out_dir, swept_keys(body), plots=plots, grid_keys=list(body.get("grid") or {}),
                                objective=objective)
    except KeyboardInterrupt as exc:
        if exc.args:                  # the runs' own account (execute: how many are recorded)
            raise
        # each summary file is written whole, but a Ctrl-C between them left sweep.csv and best.yaml without sweep.md
        # under 'no output directory was written' (a corrupted-input review), and so did one after the last run was
        # recorded, before the summary began (a failure-injection review)
        raise type(exc)(f"every finished run is recorded in {out_dir}/records, but the summary was cut short "
                        "(sweep.md, best.yaml, report.html and the plots may be missing or from an earlier summary): "
                        f"`fusion-eval sweep --grid {sweep} --out {out_dir} --summarize-only` rebuilds it") from None
    return {"counts": counts, "summary": summary, "tasks": tasks}
