"""The outputs of ``fusion-eval tune``: ``best.yaml`` (a config for ``-c``), ``trials.csv``, ``tune.md`` and the
plots (optimization history, parameter importances, parallel coordinates; Optuna's matplotlib figures)."""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path


from ..outputs import atomic_write
from ..provenance import dataset_files, header_line
from ..report import html
from ..tables import markdown as markdown_table
from ..trials import one_draw_note, rerun_commands
from .study import Setup, default_config, write_json

FUSED_APE = "fused.ape.rmse"


def default_wins(res: dict) -> bool:
    """Whether the default configuration scores better than the best trial on the training drives (first objective):
    possible when the space cannot hold the default's values (an 'auto' a choice list lacks, a value out of range)."""
    best, default = res.get("best"), res.get("default") or {}
    d, t = _obj(default.get("train"), 0), _obj((best or {}).get("train"), 0)
    return best is not None and math.isfinite(d) and math.isfinite(t) and d < t


def default_yaml(s: Setup, res: dict) -> str:
    """``best.yaml`` when no trial beat the default configuration: the default itself (nothing overridden)."""
    d, t = _obj(res["default"]["train"], 0), _obj(res["best"]["train"], 0)
    return (f"# fusion-eval tune: no trial of {s.out_dir} beat the default configuration on "
            f"{', '.join(Path(x).name for x in s.train)} ({s.objectives[0].name} {d:.6g}, the best trial "
            f"{res['best']['number']} {t:.6g}): this is the default (the base config and --set items only; the best trial is in best.json)\n"
            + _use_lines(s) + _config_yaml(s, {}))


def _use_lines(s: Setup) -> str:
    """How ``best.yaml`` reproduces the objective it states: on each training drive, with the study's Monte-Carlo
    seeds as a run's trials."""
    return "".join(f"# {'use: ' if i == 0 else '  and: '}{c}\n" for i, c in enumerate(rerun_commands(s.train, s.seeds)))


def _config_yaml(s: Setup, overrides: dict) -> str:
    """What every trial ran with, as one configuration file: the base config (``-c``), the ``--set`` items, then
    ``overrides`` (a trial's values): ``fusion-eval run -c best.yaml`` replays that trial, not the space's keys on
    the built-in defaults (a tune of ``-c lidar-imu.yaml`` would otherwise run with GNSS)."""
    from .. import session, yaml_lines

    return yaml_lines.dump(session.config_file(session.request(config=s.base_config, sets=s.sets, overrides=overrides)),
                           sort_keys=True)


def best_yaml(s: Setup, best: dict) -> str:
    head = (f"# fusion-eval tune: trial {best['number']} of {s.out_dir}, objective "
            f"{', '.join(o.name for o in s.objectives)} = {', '.join(f'{v:.6g}' for v in best['values'])} on "
            f"{', '.join(Path(d).name for d in s.train)}\n" + _use_lines(s))
    return head + _config_yaml(s, best["overrides"])


def trials_csv(study, s: Setup) -> str:
    keys = [p.key for p in s.space.params]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["number", "state", "status", *[o.name for o in s.objectives], *keys, "duration_s"])
    for t in study.get_trials(deepcopy=False):
        vals = list(t.values) if t.values is not None else [""] * len(s.objectives)
        dur = t.duration.total_seconds() if t.duration is not None else ""
        w.writerow([t.number, t.state.name, t.user_attrs.get("status", ""), *vals,
                    *[t.params.get(k, "") for k in keys], dur])
    return buf.getvalue()


def _mean(rec: dict | None, key: str) -> float:
    if not rec or rec.get("status") != "ok":
        return math.nan
    vals = [st["metrics"].get(key, math.nan) for st in rec["steps"]]
    return sum(vals) / len(vals) if vals else math.nan


def _per_drive(rec: dict | None, key: str) -> dict[str, float]:
    out: dict = {}
    for st in (rec or {}).get("steps", []):
        if st["status"] == "ok":
            out.setdefault(Path(st["dataset"]).name, []).append(st["metrics"].get(key, math.nan))
    return {k: sum(v) / len(v) for k, v in out.items()}


def _v(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_v(x) for x in v) + "]"
    return str(v)


def _f(v) -> str:
    # six digits: an nll per update near -13 that trials move by 0.002 printed as -13.2 throughout (a user trial)
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.6g}"


def markdown(s: Setup, res: dict, runtime_s: float) -> str:
    import optuna

    study, default, best = res["study"], res["default"], res["best"]
    S = optuna.trial.TrialState
    states = [t.state for t in study.get_trials(deepcopy=False)]
    status = [t.user_attrs.get("status") for t in study.get_trials(deepcopy=False)]
    L = [f"# fusion-eval tune: {', '.join(o.name for o in s.objectives)}", "",  header_line(), "",
         f"Space `{s.space.path}`, sampler {s.sampler} (seed {s.seed}); training drives "
         f"{', '.join(Path(d).name for d in s.train)}; held-out drives "
         f"{', '.join(Path(d).name for d in s.test) or 'none'}; {s.seeds} Monte-Carlo seed(s) per drive.", "",
         _sampler_line(s, res["study"]), "",
         f"Trials: {states.count(S.COMPLETE)} complete, {states.count(S.PRUNED)} pruned, "
         f"{status.count('diverged')} diverged, {status.count('failed')} failed "
         f"({runtime_s:.0f} s in this session).", ""]
    if best is None:
        return "\n".join(L + ["No trial completed: nothing is tuned.", ""])
    done = [t.values[0] for t in study.get_trials(deepcopy=False) if t.state == S.COMPLETE and t.values]
    if len(done) >= 3 and max(done) - min(done) <= 1e-12 * max(abs(max(done)), 1.0):
        # gnss.ape.rmse as the objective: every trial scored 2.30298 and the report suggested more trials (a review)
        L += [f"**Every one of the {len(done)} complete trials scored the same objective ({_f(done[0])})**: no key of the "
              f"space moves `{s.objectives[0].name}` (the unfiltered GNSS's APE depends on no filter setting, say): "
              "choose an objective of the filter's estimate (fused.ape.rmse, nll, nis).", ""]
    rows = []
    resolved = ((default["train"]["steps"][0].get("resolved") or {}).get("imu_noise") or {})
    cfg0 = res.get("default_config") or default_config(s)      # the default run's (the manifest's suggestions included)
    for key, v in best["overrides"].items():
        sect, k = key.split(".", 1)
        d = cfg0.get(sect, {}).get(k)
        if d == "auto" and k in resolved:
            d = f"auto ({resolved[k]:.4g} from the data)"
        fixed = " (fixed)" if key in s.space.fixed else ""
        rows.append([f"{key}{fixed}", _v(d), _v(v)])
    L += ["## Tuned values", ""] + markdown_table(["key", "default", "tuned"], rows) + [""]
    if default_wins(res):           # the default's values were not all in the space: trial 0 was not the default
        L += [f"**No trial beat the default configuration** on the training drives ({_f(_obj(default['train'], 0))} "
              f"against the best trial's {_f(_obj(best['train'], 0))}; the space cannot hold every default value, so "
              "the first trial was not the default): `best.yaml` is the default configuration, the best trial is in "
              "`best.json`. More trials, or a space that holds the default's values, may find better ones.", ""]
    elif best["number"] == 0:       # trial 0 is the default configuration (study.py enqueues it first)
        L += ["**No trial beat the first one, the default configuration**: the tuned values are the default's. "
              "More trials, or a wider space, may find better ones.", ""]
    rows, gaps = [], []
    n_obj = len(s.objectives)       # every objective's pair of columns (a two-objective study showed the first only)
    for part, d_rec, t_rec in (("training", default["train"], best["train"]),
                               ("held-out", default.get("test"), best.get("test"))):
        if d_rec is None:
            continue
        gaps.append((part, _obj(d_rec, 0), _obj(t_rec, 0)))
        rows.append([f"{part} (mean)", *(_f(x) for k in range(n_obj) for x in (_obj(d_rec, k), _obj(t_rec, k))),
                     _f(_mean(d_rec, FUSED_APE)), _f(_mean(t_rec, FUSED_APE))])
        da, ta = _per_drive(d_rec, FUSED_APE), _per_drive(t_rec, FUSED_APE)
        per = [(_per_drive_obj(d_rec, k), _per_drive_obj(t_rec, k)) for k in range(n_obj)]
        for name in da:
            rows.append([f"{part}: {name}", *(_f(x) for do, to in per for x in (do.get(name), to.get(name))),
                         _f(da[name]), _f(ta.get(name))])
    obj_cols = ([c for o in s.objectives for c in (f"{o.name} (default)", f"{o.name} (tuned)")] if n_obj > 1
                else ["objective (default)", "objective (tuned)"])
    header = ["drives", *obj_cols, "fused APE RMSE m (default)", "fused APE RMSE m (tuned)"]
    # drives without ground truth: every step finished but none has an APE (not: every one failed)
    finished = [st for rec in (default.get("train"), best.get("train")) for st in (rec or {}).get("steps", [])]
    if finished and all(st["status"] == "ok" for st in finished) and all(r[-1] == r[-2] == "n/a" for r in rows):
        header, rows = header[:-2], [r[:-2] for r in rows]
        L += ["## Objective, default against tuned", "", "The drives have no ground truth: no fused APE (README 'A drive "
              "without ground truth').", ""] + markdown_table(header, rows)
    else:
        L += ["## Objective and fused APE, default against tuned", ""] + markdown_table(header, rows)
    L += ["", _generalisation(gaps, relative=s.objectives[0].is_error), ""]
    d_ape, t_ape = _mean(default["train"], FUSED_APE), _mean(best["train"], FUSED_APE)
    # (equal figures: the table and the verdict above already say the tuned values are the default's)
    note = one_draw_note(t_ape, d_ape, s.seeds, "The tuned values' fused APE on the training drives leads the default's by",
                         "--seeds 3") if t_ape != d_ape else None
    if note:
        L += [note, ""]
    if len(s.objectives) > 1:
        L += ["## Pareto front", ""] + markdown_table(["trial"] + [o.name for o in s.objectives],
                                                [[f["number"]] + [_f(v) for v in f["values"]] for f in best["front"]])
        L.append("")
    L += ["Files: `best.yaml` (use with `fusion-eval run -c best.yaml`), `trials.csv`, `trials/<n>.json` (every "
          "trial's metrics per drive), `default.json`, `study.journal` (Optuna's; the same command resumes it), and, "
          "unless `--no-plots`, the plots `history.png`, `importance.png`, `parallel.png`.", ""]
    return "\n".join(L)


def _sampler_line(s: Setup, study) -> str:
    """What a seeded study depends on beyond the command's space, objectives and drives, and the commands that made it
    (a study extended by a second run is rebuilt by running them in order)."""
    startup = study.user_attrs.get("n_startup_trials")
    how = (f"TPE (multivariate, constant liar) with {startup} random start-up trials (fixed when the study was made)"
           if s.sampler == "tpe" and startup is not None else s.sampler)
    from .study import commands

    cmds = commands(study)
    made = "; ".join(f"`{c}` (generations of {b}, {d})" for d, c, b in cmds)
    return (f"Sampler: {how}, seed {s.seed}; trials asked in generations of {s.batch} (`--batch`: the study depends on "
            f"it, not on `-j` or the machine), scored {s.jobs} at a time. Made by: {made or 'this command'}.")


def _obj(rec: dict | None, k: int) -> float:
    if not rec or rec.get("status") != "ok":
        return math.nan
    return rec["values"][k] if rec.get("values") else math.nan


def _per_drive_obj(rec: dict | None, k: int = 0) -> dict[str, float]:
    out: dict = {}
    for st in (rec or {}).get("steps", []):
        if st["status"] == "ok":
            out.setdefault(Path(st["dataset"]).name, []).append(st["values"][k])
    return {k: sum(v) / len(v) for k, v in out.items()}


def _worse(d: float) -> str:
    """How much worse than the default, in words: a best trial that is the default itself is 'equal' (it read
    '-0 worse'; a tune review)."""
    return "equal to it" if d == 0 else f"{d:.4g} worse"


def _generalisation(gaps, relative: bool = True) -> str:
    """Whether the gain on the training drives holds on the held-out ones (overfitting shows as a gap)."""
    if gaps and all(math.isfinite(x) for x in gaps[0][1:]) and gaps[0][1] - gaps[0][2] <= 0 and len(gaps) < 2:
        return (f"The tuned values are no better than the default on the training drives "
                f"({_worse(gaps[0][2] - gaps[0][1])}); no held-out drives (give --test).")
    if len(gaps) < 2 or not all(math.isfinite(x) for _, a, b in gaps for x in (a, b)):
        return "No held-out drives: whether the tuned values generalise is not measured (give --test)."
    (_, d_tr, t_tr), (_, d_te, t_te) = gaps
    g_tr, g_te = d_tr - t_tr, d_te - t_te
    if g_tr <= 0:
        held = ("the same as the default's" if g_te == 0 else
                f"{abs(g_te):.4g} {'better' if g_te > 0 else 'worse'}")
        return (f"The tuned values are no better than the default on the training drives ({_worse(-g_tr)}); on the "
                f"held-out drives they are {held}.")
    if g_te < 0:
        return (f"Overfitting: the tuned values improve the objective on the training drives by {g_tr:.4g} but make it "
                f"worse on the held-out drives by {-g_te:.4g}.")
    # gains as shares of the default's figure where the objective is a positive error (an APE): drives of other error
    # levels compared by their absolute gains read equal relative gains (7 % on simple-07's 0.42 m and on kitti-00's
    # 0.75 m) as 'partly overfitted' (a statistics review); the innovations' nll, whose zero is arbitrary, stays
    # absolute (``relative``: the objective is an error, objectives.Objective.is_error)
    rel = relative and d_tr > 0 and d_te > 0
    a_tr, a_te = (g_tr / d_tr, g_te / d_te) if rel else (g_tr, g_te)
    say = (lambda g, d: f"{g:.4g} ({g / d:.1%} of the default's)") if rel else (lambda g, d: f"{g:.4g}")   # noqa: E731
    if a_te < 0.5 * a_tr:
        return (f"Partly overfitted: the gain on the held-out drives ({say(g_te, d_te)}) is less than half the gain on "
                f"the training drives ({say(g_tr, d_tr)}).")
    return (f"The gain holds on the held-out drives: {say(g_te, d_te)} there against {say(g_tr, d_tr)} on the training "
            "drives.")


TUNE_PLOTS = ("history.png", "importance.png", "parallel.png")


def plots(study, s: Setup) -> list[str]:
    import warnings

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import optuna.visualization.matplotlib as ovm

    written = []
    target = (lambda t: t.values[0]) if len(s.objectives) > 1 else None
    name = s.objectives[0].name
    figs = [("history.png", lambda: ovm.plot_optimization_history(study, target=target, target_name=name)),
            ("importance.png", lambda: ovm.plot_param_importances(study, target=target, target_name=name)),
            ("parallel.png", lambda: ovm.plot_parallel_coordinate(study, target=target, target_name=name))]
    for fname, make in figs:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                ax = make()
            except (ValueError, RuntimeError, ZeroDivisionError):      # too few complete trials for this plot
                continue
        fig = ax.figure if hasattr(ax, "figure") else ax.flat[0].figure
        fig.set_size_inches(9, 5)
        fig.tight_layout()
        tmp = s.out_dir / f".{fname}.tmp.png"
        fig.savefig(tmp, dpi=100)
        plt.close(fig)
        os.replace(tmp, s.out_dir / fname)
        written.append(fname)
    return written


def write(s: Setup, res: dict, runtime_s: float, with_plots: bool = True) -> list[str]:
    out = s.out_dir
    files = []
    if res["best"] is not None:
        atomic_write(out / "best.yaml", default_yaml(s, res) if default_wins(res) else best_yaml(s, res["best"]))
        write_json(out / "best.json", res["best"])
        files += ["best.yaml", "best.json"]
    atomic_write(out / "trials.csv", trials_csv(res["study"], s))
    md = markdown(s, res, runtime_s)
    atomic_write(out / "tune.md", md)
    files += ["trials.csv", "tune.md"]
    if with_plots and res["best"] is not None:
        files += plots(res["study"], s)
    for stale in set(TUNE_PLOTS) - set(files):         # an earlier report's (a resumed tune with --no-plots kept them)
        (out / stale).unlink(missing_ok=True)
    atomic_write(out / "report.html", html.page(md, out, [f for f in files if f.endswith(".png")],
                                                inputs=dataset_files([*s.train, *s.test])))
    return files + ["report.html"]
