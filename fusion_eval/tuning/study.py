"""The study loop of ``fusion-eval tune``: Optuna asks, the workers score, Optuna is told.

Trials run in generations of ``batch`` (``--batch``, 4 unless given): every trial of a generation is asked, scored in
parallel (the process pool or a Dask cluster, the executors of ``sweep``, with ``jobs`` workers) and told in trial
order, so a seeded study is the same on any executor, any number of workers and any machine. (The generation was
``-j``, whose default follows the cores: one seed gave two studies on two machines, and nothing recorded which; nor the
sampler's random start, which followed ``--trials``, so that a study extended by a second run could not be rebuilt:
it is fixed when the study is made and kept in it. A reproducibility review.) The study lives in an Optuna journal file
(``<out>/study.journal``): a tune that is interrupted (Ctrl-C, SIGTERM, SIGKILL) resumes where it stopped when the
same command runs again (trials that were running are enqueued again with their values), and two ``tune``
processes pointed at one ``--out`` share the study.
"""

from __future__ import annotations

import contextlib

import datetime
import json
import logging
import os
import socket
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .. import interrupts, provenance
from ..errors import ConfigError, OutputError
from ..locks import alive
from ..outputs import atomic_write, resumable_dir
from .objectives import Objective
from .space import Space
from .worker import REPORTS, Job, score

log = logging.getLogger(__name__)

STUDY = "fusion-eval-tune"
MIN_FOR_PRUNING = 5          # finished trials before the median rule prunes (Optuna's MedianPruner default)


@dataclass
class Setup:
    space: Space
    objectives: tuple[Objective, ...]
    train: tuple[str, ...]
    test: tuple[str, ...]
    n_trials: int
    out_dir: Path
    sampler: str = "tpe"
    seed: int = 0
    seeds: int = 1
    base_config: dict | None = None
    sets: tuple[str, ...] = ()
    jobs: int = 1
    batch: int = 4                  # trials asked per generation: the study depends on it, not on jobs
    scheduler: str | None = None
    dask_local: bool = False
    prune: bool = True
    meta: dict = field(default_factory=dict)

    def job(self, number: int, overrides: dict, datasets, prune_above=()) -> Job:
        return Job(number, overrides, self.base_config, self.sets, tuple(datasets), self.seeds, self.objectives, tuple(prune_above))


def _optuna():
    import warnings

    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    return optuna


def n_startup(n_trials: int) -> int:
    """TPE's random start-up trials for a study made for ``n_trials`` (kept in the study when it is made)."""
    return min(10, max(2, n_trials // 5))


def _sampler(s: Setup, startup: int | None = None):
    optuna = _optuna()
    if s.sampler == "cmaes":
        if len(s.objectives) > 1:
            raise ConfigError("--sampler cmaes optimises one objective; give one --objective or use tpe")
        return optuna.samplers.CmaEsSampler(seed=s.seed, warn_independent_sampling=False)
    # multivariate TPE models the noise keys jointly (they trade off against each other); constant_liar keeps the
    # trials of one generation apart
    return optuna.samplers.TPESampler(seed=s.seed, multivariate=True, constant_liar=True,
                                      n_startup_trials=n_startup(s.n_trials) if startup is None else startup)


def open_study(s: Setup):
    """The study in ``<out>/study.journal``, created or resumed; refuses one made for another space or objectives."""
    optuna = _optuna()
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    sampler = _sampler(s)                   # a bad sampler choice is refused before the folder is made
    resumable_dir(s.out_dir, ("study.journal",), "tune")
    journal = s.out_dir / "study.journal"
    storage = JournalStorage(JournalFileBackend(str(journal), lock_obj=_flock(journal)))
    directions = ["minimize"] * len(s.objectives)
    study = optuna.create_study(study_name=STUDY, storage=storage, sampler=sampler, directions=directions,
                                load_if_exists=True)
    ident = {"space": s.space.digest(), "objectives": [o.name for o in s.objectives], "train": list(s.train),
             "seeds": s.seeds, "base_config": s.base_config, "sets": list(s.sets), "pruning_reports": REPORTS}
    if any(o.name == "nis" for o in s.objectives):
        # its definition changed (the constraint's pseudo-observations left out): a study scored the old way is not
        # resumed under the new one (a diff review: new trials were ranked against old scores)
        ident["nis_definition"] = "the measured streams' observations"
    old = study.user_attrs.get("ident")
    maker = study.user_attrs.get("ident_owner")
    host = socket.gethostname()
    # a study with no trial yet whose maker is gone (a start that failed: a scheduler out of reach, a Ctrl-C while the
    # default was scored) holds nothing to keep: it takes the new settings (it locked the folder to the old ones; a tune
    # review), and the default is scored again under them; not while its maker still scores the default (two studies
    # were mixed in one folder so: a review of the diff)
    abandoned = (old is not None and old != ident and not study.trials and maker is not None and maker[0] == host
                 and not alive(maker[1]))
    if old is None or abandoned:
        if abandoned:
            (s.out_dir / "default.json").unlink(missing_ok=True)
        study.set_user_attr("ident", ident)
        study.set_user_attr("ident_owner", [host, os.getpid()])
    elif old != ident:
        diff = next(k for k in ident if ident[k] != old.get(k))
        raise ConfigError(f"{s.out_dir}: holds a study of another {diff.replace('_', ' ')} ({old.get(diff)!r}); "
                          "give another --out or the same settings to resume it")
    startup = study.user_attrs.get("n_startup_trials")
    if startup is None or old is None or abandoned:
        study.set_user_attr("n_startup_trials", n_startup(s.n_trials))
    elif s.sampler == "tpe":
        study.sampler = _sampler(s, int(startup))       # as made: an extended study goes on as it began
    # every command that opened the study, in order: with the seed, --batch and the sampler's start-up kept in the
    # study, they rebuild it (tune.md lists them). One attribute each, never a read-modify-write of a list: two tunes
    # sharing the study would lose an entry
    study.set_user_attr(f"command {len(study.trials):06d} {time.time_ns():020d} {host} {os.getpid()}",
                        [provenance.date_utc(), provenance.command_line(), s.batch])
    return study


def commands(study) -> list:
    """``[date, command line, batch]`` of every command that opened the study, in the order they did."""
    return [v for k, v in sorted(study.user_attrs.items()) if k.startswith("command ")]


def _flock(journal: Path):
    """A lock that the kernel releases when its holder dies: Optuna's default (a symlink) outlives a SIGKILL, and
    the next ``tune`` would wait its 30 s grace period for it. None (Optuna's default) where ``fcntl`` is missing."""
    try:
        import fcntl
    except ImportError:                     # not POSIX
        return None
    from optuna.storages.journal._file import BaseJournalFileLock      # public in no release yet

    class FlockLock(BaseJournalFileLock):
        def __init__(self, path: str):
            self.path, self.fd = path, None

        def acquire(self) -> bool:
            fd = os.open(self.path, os.O_CREAT | os.O_RDWR, 0o644)
            fcntl.flock(fd, fcntl.LOCK_EX)
            self.fd = fd
            return True

        def release(self) -> None:
            if self.fd is not None:
                fcntl.flock(self.fd, fcntl.LOCK_UN)
                os.close(self.fd)
                self.fd = None

    return FlockLock(str(journal.with_name(journal.name + ".lock")))


OWNERLESS_STALE_S = 60.0      # a running trial with no owner this long after it started: left by a stopped process


def _requeue_stale(study) -> int:
    """Trials left running by a process of this host that is gone (killed): failed, and enqueued again."""
    optuna = _optuna()
    host, n = socket.gethostname(), 0
    for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
        owner = t.system_attrs.get("fusion_eval_owner") or t.user_attrs.get("owner")
        if not owner:
            # a trial is given its owner as it is asked for: one without an owner a minute on was left by a process
            # stopped in between (a study from before the deferred signal above)
            started = t.datetime_start
            if started is None or (datetime.datetime.now() - started).total_seconds() < OWNERLESS_STALE_S:
                continue
        elif owner[0] != host or alive(owner[1]):
            continue
        try:
            study._storage.set_trial_user_attr(t._trial_id, "interrupted", True)            # noqa: SLF001
            study._storage.set_trial_state_values(t._trial_id, optuna.trial.TrialState.FAIL)  # noqa: SLF001
        except optuna.exceptions.UpdateFinishedTrialError:
            continue              # another process sharing the study requeued it first (a review of the diff)
        study.enqueue_trial(t.params, skip_if_exists=False)
        n += 1
    return n


def counted(study) -> int:
    """Trials that count toward ``--trials``: finished (complete, pruned, failed but not interrupted) or running."""
    optuna = _optuna()
    S = optuna.trial.TrialState
    return sum(1 for t in study.get_trials(deepcopy=False)
               if t.state in (S.COMPLETE, S.PRUNED, S.RUNNING) or (t.state == S.FAIL and not t.user_attrs.get("interrupted")))


def prune_thresholds(study, n_steps: int) -> tuple[tuple[int, float], ...]:
    """(report index, the median of the finished trials' reports there) for every report before the last step's
    end that at least :data:`MIN_FOR_PRUNING` finished trials made (the median rule, at each report)."""
    optuna = _optuna()
    done = [t for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))]
    out = []
    for idx in range(n_steps * REPORTS - 1):
        vals = [t.intermediate_values[idx] for t in done if idx in t.intermediate_values]
        if len(vals) >= MIN_FOR_PRUNING:
            out.append((idx, float(statistics.median(vals))))
    return tuple(out)


class Executor:
    """``map`` of :func:`score` over a generation, in order: this process, the pool or Dask."""

    def __init__(self, s: Setup):
        self.s, self._pool, self._client, self._stack = s, None, None, contextlib.ExitStack()

    def __enter__(self):
        s = self.s
        if s.scheduler or s.dask_local:
            from ..pool import dask_client

            self._client = self._stack.enter_context(dask_client(s.scheduler, s.jobs if s.dask_local else 0))
        elif s.jobs > 1:
            import multiprocessing as mp

            from ..pool import Pool

            self._pool = self._stack.enter_context(Pool(max_workers=s.jobs, mp_context=mp.get_context("spawn")))
        return self

    def __exit__(self, exc_type, exc, tb):
        return self._stack.__exit__(exc_type, exc, tb)

    def map(self, jobs: list[Job]) -> list[dict]:
        if self._client is not None:
            futs = self._client.map(score, jobs, pure=False)
            return self._client.gather(futs)
        if self._pool is not None:
            return [f.result() for f in [self._pool.submit(score, j) for j in jobs]]
        return [score(j) for j in jobs]


def write_json(path: Path, body) -> None:
    atomic_write(path, json.dumps(body, indent=1, default=_jsonable))


def _jsonable(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return str(v)


def run_study(s: Setup, progress: Callable[[int, int, float | None], None] | None = None) -> dict:
    """Open or resume the study, score the default configuration once, run trials until ``n_trials`` count, and
    return what the report needs."""
    optuna = _optuna()
    study = open_study(s)
    rec_dir = s.out_dir / "trials"
    rec_dir.mkdir(exist_ok=True)
    stale = _requeue_stale(study)
    if stale:
        log.info("%d trials interrupted by a killed tune are run again", stale)
    cfg0 = default_config(s)      # once: the first trial's values and the report's default column (a dataset load)
    with Executor(s) as ex:
        default = _default(s, ex)
        if not study.trials:
            start = _default_point(s, default, cfg0)
            if start:       # the first trial is the default configuration (as far as the space holds it)
                study.enqueue_trial(start)
        n_steps = len(s.train) * s.seeds
        host, pid = socket.gethostname(), os.getpid()
        asked: list = []
        try:
            while True:
                # a process sharing the study that was killed left its trials running: run again, not counted (the
                # survivor ended one short of --trials, saying it was done; a tune review)
                if _requeue_stale(study):
                    log.info("trials of a killed tune sharing this study are run again")
                left = s.n_trials - counted(study)
                if progress:
                    progress(min(counted(study), s.n_trials), s.n_trials, _best_value(study),
                             failed=sum(t.user_attrs.get("status") in ("failed", "diverged")
                                        for t in study.get_trials(deepcopy=False)))
                if left <= 0:
                    break
                thresholds = prune_thresholds(study, n_steps) if s.prune and len(s.objectives) == 1 else ()
                asked = []
                for _ in range(min(s.batch, left)):
                    # a Ctrl-C inside ask(), before the trial had an owner, left it running for good (it was the
                    # default configuration's trial once; a tune review): the signal waits for the block's end
                    with interrupts.deferred():
                        t = study.ask()
                        t.set_user_attr("owner", [host, pid])
                        asked.append((t, s.space.overrides({p.key: p.suggest(t) for p in s.space.params})))
                results = ex.map([s.job(t.number, ov, s.train, thresholds) for t, ov in asked])
                for (t, ov), rec in zip(list(asked), results):
                    # one trial told whole, then dropped from those to give back: a signal among the tells met a
                    # told trial in the clean-up below, whose update Optuna refuses, and the command said 'no
                    # output directory was written' beside the kept journal (an interruption review)
                    with interrupts.deferred():
                        _tell(study, t, ov, rec, rec_dir)
                        asked.pop(0)
        except KeyboardInterrupt as exc:
            for t, _ in asked:        # not scored: enqueued again for the next run of the command
                t.set_user_attr("interrupted", True)
                study.tell(t, state=optuna.trial.TrialState.FAIL)
                study.enqueue_trial(t.params, skip_if_exists=False)
            raise type(exc)(f"{counted(study)} of {s.n_trials} trials are kept in {s.out_dir}/study.journal; run the "
                            "same command again to go on") from None
        except OSError as exc:
            if exc.filename is not None:
                raise
            # Optuna's journal, appended to by its own code: "No space left on device" named no file (a
            # failure-injection review)
            raise OutputError(f"{s.out_dir / 'study.journal'}: cannot write ({exc.strerror or exc}); the trials "
                              "written before are kept") from None
        best = _best(study, s)
        if best is not None and s.test:
            best["test"] = ex.map([s.job(best["number"], best["overrides"], s.test)])[0]
    return {"study": study, "default": default, "best": best, "default_config": cfg0}


def _default(s: Setup, ex: Executor) -> dict:
    """The default configuration scored on the training and held-out drives, once per study (``default.json``);
    it also checks that every objective names a metric the runs have."""
    path = s.out_dir / "default.json"
    if path.exists():
        body = json.loads(path.read_text(encoding="utf-8"))
        # a study resumed with held-out drives it did not have (or other ones): the default is scored on those
        # too, or the report would compare the tuned values on them with nothing
        held = sorted({st["dataset"] for st in (body.get("test") or {}).get("steps", [])})
        if not s.test or held == sorted(s.test):
            return body
        train, test = body["train"], ex.map([s.job(-1, {}, s.test)])[0]
    else:
        recs = ex.map([s.job(-1, {}, s.train)] + ([s.job(-1, {}, s.test)] if s.test else []))
        train, test = recs[0], (recs[1] if s.test else None)
    for part, rec in (("training", train), ("held-out", test)):
        if rec is None:
            continue
        first = rec["steps"][0]
        if first["status"] == "ok":          # an objective the runs have no metric for: named, with close ones
            for o in s.objectives:
                o.check(first["metrics"], first["dataset"])
        if rec["status"] != "ok":
            raise ConfigError(f"the default configuration {rec['status']} on a {part} drive: {rec['error']}")
    body = {"train": train, "test": test}
    write_json(path, body)
    return body


def default_config(s: Setup) -> dict:
    """The configuration the default run of the first training drive resolves to: the built-in defaults, the base
    config, the --set items and the drive's manifest's suggested settings (a simulated drive's datasheet noise: trial 0
    took the built-in values instead, scored 0.7025 against the default run's 0.7165, and the report called the
    tuned values the default's; found by a corrupted-input review)."""
    from .. import session

    return session.resolve(session.request(config=s.base_config, sets=s.sets), session.dataset(s.train[0]))


def _default_point(s: Setup, default: dict, cfg0: dict | None = None) -> dict:
    """The default configuration's value of every tuned key inside its range (:func:`default_config`), or for an 'auto'
    the value the default run settled on (the IMU noise it estimated, the lidar frame it chose, ...). Keys without
    one are sampled: then the first trial is not the default, and the report compares the tuned values with the
    default run itself."""
    got = default["train"]["steps"][0].get("resolved") or {}
    resolved, settled = got.get("imu_noise") or {}, got.get("auto_settled") or {}
    out = {}
    cfg0 = default_config(s) if cfg0 is None else cfg0
    for p in s.space.params:
        sect, key = p.key.split(".", 1)
        v = cfg0.get(sect, {}).get(key)
        if v == "auto":
            v = resolved.get(key, settled.get(p.key))
        if p.choices is not None:
            if v in p.choices:
                out[p.key] = v
        elif p.shape is None and isinstance(v, (int, float)) and p.low <= v <= p.high:
            out[p.key] = float(v)
    return out


def _tell(study, t, overrides: dict, rec: dict, rec_dir: Path) -> None:
    optuna = _optuna()
    if len(study.directions) == 1:        # what the median rule compares: see worker.REPORTS
        ok = []
        for i, st in enumerate(rec["steps"]):
            for c, v in enumerate(st.get("checkpoints") or []):
                if v == v:                    # not NaN
                    t.report(float(v), i * REPORTS + c)
            if st["status"] != "ok":
                break
            ok.append(st["values"][0])
            t.report(float(sum(ok) / len(ok)), i * REPORTS + REPORTS - 1)
    t.set_user_attr("status", rec["status"])
    t.set_user_attr("overrides", overrides)
    if rec["error"]:
        t.set_user_attr("error", rec["error"])
    write_json(rec_dir / f"{t.number:05d}.json", {**rec, "overrides": overrides, "params": t.params})
    if rec["status"] == "ok":
        study.tell(t, rec["values"] if len(rec["values"]) > 1 else rec["values"][0])
    elif rec["status"] == "pruned":
        study.tell(t, state=optuna.trial.TrialState.PRUNED)
    else:
        study.tell(t, state=optuna.trial.TrialState.FAIL)


def _best_value(study) -> float | None:
    try:
        return study.best_value if len(study.directions) == 1 else None
    except ValueError:
        return None


def _best(study, s: Setup) -> dict | None:
    """The tuned trial: the best one (one objective), or the Pareto trial best in the first objective."""
    try:
        front = study.best_trials
    except ValueError:
        return None
    if not front:
        return None
    t = min(front, key=lambda t: (t.values[0], t.number))
    rec = json.loads((s.out_dir / "trials" / f"{t.number:05d}.json").read_text(encoding="utf-8"))
    return {"number": t.number, "values": list(t.values), "params": t.params, "overrides": t.user_attrs["overrides"],
            "train": rec, "front": [{"number": f.number, "values": list(f.values), "params": f.params}
                                    for f in sorted(front, key=lambda f: f.values[0])]}
