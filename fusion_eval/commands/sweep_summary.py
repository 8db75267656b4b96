"""The summary of a sweep, rebuilt from its records: ``sweep.csv``, ``sweep.md``, plots, ``best.yaml``.

The metric columns come from :func:`fusion_eval.evaluation.keys.summary_columns` for the per-distance
RPE length each run was evaluated with, so a sweep over ``evaluation.rpe_delta_m`` keeps its columns.
"""

from __future__ import annotations

import difflib
import logging
import math
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from .. import session, yaml_lines
from ..outputs import atomic_write
from ..evaluation import keys as mk
from ..provenance import dataset_files, header_line
from ..resources import dataset_label
from ..report import html
from ..tables import cell, csv_text, markdown
from ..trials import NOTHING_RANDOM, nothing_random_line, one_draw_note, rerun_commands, seeded_streams
from .sweep import Task, read_records

log = logging.getLogger(__name__)

METRIC = mk.RANK_COLUMN
DEFAULT_OBJECTIVE = "fused.ape.rmse"
_DEFAULT_TERMS = {((1.0, "fused.ape.rmse"),), ((1.0, "fused.ape.translation_m.rmse"),)}


@dataclass(frozen=True)
class Ranking:
    """What a sweep ranks its settings by: an objective as ``tune`` takes it (a metric key of ``metrics.json``,
    ``nll``, ``nis`` or a weighted sum), lower is better. ``column``: its column in ``sweep.csv`` (the fused APE's
    own column for the default), ``label``: how the tables and plots name it."""

    objective: object                       # fusion_eval.tuning.objectives.Objective
    column: str
    label: str

    @property
    def is_default(self) -> bool:
        return self.column == METRIC

    def value(self, metrics: dict):
        """The objective of one run's metrics; None where the run lacks a term (a smoother's key in a run with none)."""
        v = self.objective.value(mk.flatten(metrics))
        return None if math.isnan(v) else v


def ranking(text: str | None) -> Ranking:
    """The :class:`Ranking` of ``--objective`` (or the sweep file's ``objective:``; default the fused APE RMSE)."""
    from ..errors import ConfigError
    from ..evaluation.run_metrics import ESTIMATES
    from ..tuning import objectives

    obj = objectives.parse(text or DEFAULT_OBJECTIVE)
    # the first word of a key is checked now (a sweep would otherwise run to its end before the summary refuses it)
    families = (*ESTIMATES, "ratios", "innovations", "nis", "nees", "nees_smoothed")
    for _, key in obj.terms:
        if key.split(".")[0] not in families:
            raise ConfigError(f"--objective {obj.name!r}: {key!r} is no metric key: a key starts with one of "
                              f"{', '.join(families)} (e.g. fused.ape.rmse, fused.rpe_100m.rmse; or nll, nis)")
    if obj.terms in _DEFAULT_TERMS:
        return Ranking(obj, METRIC, "fused APE translation RMSE [m]")
    name = "".join(obj.name.split())
    spelled = "+".join(k if w == 1 else f"{w:g}*{k}" for w, k in obj.terms)
    return Ranking(obj, name, name if spelled == name else f"{name} ({spelled})")


def _check_ranked(rank: Ranking, rows: list[dict], recs: dict[str, dict]) -> None:
    """Refuse an objective that no finished run has (a typo, a smoother's key without a smoother), naming close
    keys: the records stay, and ``--summarize-only --objective`` ranks them again without running anything."""
    from ..errors import ConfigError

    done = [recs[r["id"]] for r in rows if r["status"] == "ok" and recs.get(r["id"], {}).get("metrics")]
    if not done or any(r.get(rank.column) is not None for r in rows if r["status"] == "ok"):
        return
    flat = mk.flatten(done[0]["metrics"])
    missing = next(k for _, k in rank.objective.terms if k not in flat)
    close = difflib.get_close_matches(missing, list(flat), n=3)
    hint = f"did you mean {', '.join(close)}?" if close else "`fusion-eval check --help` names the keys"
    if done[0]["metrics"].get("ground_truth") is False:     # nothing is scored: the innovations rank
        hint = "the drives have no ground truth, so no run has a score: rank by --objective nll or nis"
    raise ConfigError(f"--objective {rank.objective.name!r}: no finished run has the metric {missing!r} ({hint}); the "
                      f"{len(done)} runs are recorded: `--summarize-only --objective KEY` ranks them without running again")


def _get(m: dict, path: tuple):
    d = m.get("estimates", {})
    for p in path:
        if not isinstance(d, dict) or p not in d or d[p] is None:
            return None
        d = d[p]
    return d


def consistency_columns(m: dict) -> dict:
    """A run's consistency, for the sweep's columns: the fused estimate's position NEES (mean, share inside its 95 %
    interval), each stream's mean NIS and, where a stream's noise adapted itself to its innovations, the factors it
    applied to the configured std (medians over the second half of the drive). A swept noise can buy a lower APE
    with an overconfident filter, and an adaptive noise rescales the very setting that was swept (a student's
    review: 'imu-noisy' ranked last because the lidar noise adapted down to 0.03x, which nothing in the sweep said)."""
    out = {}
    pos = (m.get("nees") or {}).get("position") or {}
    if pos.get("mean") is not None:
        out["nees_pos_mean"] = pos["mean"]
        out["nees_pos_in95_frac"] = pos.get("fraction_in_95")
    for k, d in (m.get("nis") or {}).items():
        out[f"nis_{k}_mean"] = d.get("mean")
        a = d.get("adapt") or {}
        if a:
            out[f"{k}_noise_pos_x"] = a.get("pos_std_factor_median")
            out[f"{k}_noise_att_x"] = a.get("att_std_factor_median")
    return out


def rows_of(tasks: list[Task], recs: dict[str, dict], keys: list[str], rank: Ranking | None = None
            ) -> tuple[list[dict], list[str]]:
    """One row per run (and the metric columns found, in order), from the sweep's records; with a ``rank`` other
    than the default, its objective in its own column (the first metric column)."""
    rows, metric_cols = [], []
    seen = set()
    for t in tasks:
        key = (t.id, t.dataset, t.variant, t.setting)
        if key in seen:
            continue
        seen.add(key)
        r = recs.get(t.id)
        row = {"id": t.id, "dataset": t.dataset, "variant": t.variant, "setting": t.setting, "trial": t.trial}
        for k in keys:
            row[k] = t.overrides.get(k, "")
        if r is None:
            row.update(status="pending", error="")
        else:
            m = r.get("metrics") or {}
            for col, path in mk.summary_columns(mk.rpe_delta_of(m)):
                row[col] = _get(m, path)
                if col not in metric_cols:
                    metric_cols.append(col)
            if "smoothed" in (m.get("estimates") or {}):       # a run with a smoother: its estimate beside the filter's
                for col, path in mk.smoothed_columns():
                    row[col] = _get(m, path)
                    if col not in metric_cols:
                        metric_cols.append(col)
            if rank is not None and not rank.is_default:
                row[rank.column] = rank.value(m) if r["status"] == "ok" and m else None
                if rank.column not in metric_cols:
                    metric_cols.insert(0, rank.column)
            for col, v in consistency_columns(m).items():
                row[col] = v
                if col not in metric_cols:
                    metric_cols.append(col)
            ratios = m.get("ratios") or {}
            row["fused_over_lidar"] = ratios.get("fused_over_lidar")
            row["fused_over_gnss"] = ratios.get("fused_over_gnss")
            sp = (m.get("evaluation") or {}).get("span") or {}
            row["span_s"] = sp.get("from_groundtruth_start_s")
            row.update(runtime_s=r.get("runtime_s"), status=r["status"], error=r.get("error") or "")
        rows.append(row)
    if not metric_cols:
        metric_cols = [c for c, _ in mk.summary_columns(mk.DEFAULT_RPE_DELTA_M)]
        if rank is not None and not rank.is_default:
            metric_cols.insert(0, rank.column)
    return rows, metric_cols


def _over_trials(rows: list[dict], keys: list[str], metric: str = METRIC) -> list[dict]:
    """One row per (dataset, variant, setting): the means of its finished trials (``trials``, the std of the
    ranked ``metric``, ``failed_trials``); a setting none of whose trials finished keeps its first trial's status."""
    from ..trials import aggregate_rows

    by = ("dataset", "variant", "setting")
    groups: dict = {}
    for r in rows:
        groups.setdefault(tuple(r[b] for b in by), []).append(r)
    out = []
    for group in groups.values():
        ok = [r for r in group if r["status"] == "ok" and r.get(metric) is not None]
        n_failed = sum(r["status"] in ("failed", "diverged") for r in group)
        if not ok:
            out.append({**group[0], "trials": 0, "failed_trials": n_failed})
            continue
        agg = aggregate_rows([[r] for r in ok], by, spread=metric)[0]
        agg.update(id=ok[0]["id"], trial="mean", failed_trials=n_failed, status="ok",
                   error="; ".join(r["error"] for r in group if r["status"] == "failed"))
        agg.pop(f"{metric}_ci95", None)
        out.append(agg)
    return out


def _paired_lead(rows: list[dict], metric: str, n_trials: int, rank) -> tuple[str, dict] | None:
    """The best setting against the next over the paired trials (trial i of every setting draws with the same seeds),
    their figure averaged across the datasets in each trial: a best named from means 0.0004 m apart, with a std of 0.08
    m beside them, got no word either way (a statistics review). None with one setting or no paired trials."""
    from ..trials import paired_lead

    datasets = {r["dataset"] for r in rows}
    per: dict = {}
    ran: dict = {}
    for r in rows:
        ran.setdefault((r["variant"], r["setting"]), set()).add(r["id"])
        if r["status"] == "ok" and r.get(metric) is not None:
            per.setdefault((r["variant"], r["setting"]), {}).setdefault(r["trial"], []).append(r[metric])
    # settings that ran the same configuration (one equal to the default) are one entry, named together: the best was
    # 'equal in every trial' to itself under another name, and the real runner-up never given (a diff review)
    names: dict = {}
    for key in per:
        names.setdefault(frozenset(ran[key]), []).append(f"{key[0]}/{key[1]}")
    if len(names) < 2:
        return None
    # one figure per trial: the mean over the datasets, where the trial finished on every one (as the ranking averages)
    per_trial = {" = ".join(names[frozenset(ran[(v, s)])]): [
        float(np.mean(by[i])) if len(by.get(i, ())) == len(datasets) else None for i in range(n_trials)]
        for (v, s), by in per.items() if names[frozenset(ran[(v, s)])][0] == f"{v}/{s}"}
    what = ("fused APE" if rank.is_default else rank.objective.name) + (" (mean over the datasets)" if len(datasets) > 1 else "")
    return paired_lead(per_trial, what, " m" if rank.is_default else "", relative=rank.objective.is_error)


def _span_note(rows: list[dict]) -> str:
    """Whether the runs of one dataset were scored over the same span (each run's common span depends on the
    coverage of its estimates: a GNSS rate or an outage at an end moves it)."""
    spans = {tuple(round(v, 3) for v in r["span_s"]) for r in rows if r.get("span_s")}
    if not spans:
        return "Span: each estimate over its own poses."
    if len(spans) == 1:
        a, b = next(iter(spans))
        return f"Span: every run and estimate over {a:.2f} .. {b:.2f} s after the ground truth's first pose."
    lo, hi = max(a for a, _ in spans), min(b for _, b in spans)
    return (f"Span: the runs' common spans differ ({len(spans)} distinct; all cover {lo:.2f} .. {hi:.2f} s after the ground "
            "truth's first pose): their figures are not over exactly the same stretch.")


SWEEP_PLOTS = ("sweep_params.png", "sweep_heatmap.png", "sweep_best_vs_default.png")   # what plots.plot_sweep draws


def write_summary(tasks: list[Task], out_dir: Path, keys: list[str], plots: bool = True,
                  grid_keys: list[str] | None = None, objective: str | None = None) -> dict:
    """``sweep.csv``, ``sweep.md``, ``report.html``, ``best.yaml`` and the plots, from the records. ``objective``:
    what the settings are ranked by (:func:`ranking`; default the fused APE translation RMSE)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rank = ranking(objective)
    metric = rank.column
    recs = read_records(out_dir)          # once: the table and the warnings read the same records
    rows, metric_cols = rows_of(tasks, recs, keys, rank)
    _check_ranked(rank, rows, recs)
    cols = ["id", "dataset", "variant", "setting", *keys, *metric_cols, "fused_over_lidar", "fused_over_gnss", "runtime_s",
            "status", "error"]
    n_trials = 1 + max((t.trial for t in tasks), default=0)
    # the failed runs, counted before the trials fold into settings (a setting with one failed trial is 'ok' there)
    failed_runs = [{"id": r["id"], "error": r.get("error") or "failed"} for r in rows if r["status"] == "failed"]
    n_runs = len(rows)
    if n_trials > 1:
        # every trial in sweep_trials.csv; everything below is over the means of each setting's trials
        atomic_write(out_dir / "sweep_trials.csv", csv_text(["trial", *cols], rows, float_format="{:.6g}"))
        lead = _paired_lead(rows, metric, n_trials, rank)
        rows = _over_trials(rows, keys, metric)
        cols = [*cols[:-2], "trials", f"{metric}_std", "failed_trials", "status", "error"]
    atomic_write(out_dir / "sweep.csv", csv_text(cols, rows, float_format="{:.6g}"))

    finished = [r for r in rows if r["status"] == "ok"]
    ok = [r for r in finished if r.get(metric) is not None]
    ranked_by = f"Ranked by {'the mean ' if n_trials > 1 else ''}{rank.label if not rank.is_default else 'fused APE translation RMSE'} (lower is better)."
    L = ["# fusion-eval sweep", "", header_line(), "",
         f"{len(rows)} runs: {len(finished)} finished, {sum(r['status'] == 'diverged' for r in rows)} "
         f"diverged, {sum(r['status'] == 'failed' for r in rows)} failed, {sum(r['status'] == 'pending' for r in rows)} pending. {ranked_by}", ""]
    if n_trials > 1:       # (it replaced the header line and left "6 runs: 6 finished" after "12 runs done")
        multi = [r for r in ok if (r.get("trials") or 0) > 1]      # (one finished trial has a std of 0 too)
        if multi and all(r.get(f"{metric}_std") == 0 for r in multi):
            log.warning(NOTHING_RANDOM.format(n=n_trials))
            L.insert(5, "\n" + nothing_random_line(n_trials))
        L[4] = (f"{len(rows)} settings x {n_trials} Monte-Carlo trials (the seeds of every random element; "
                f"{len(rows) * n_trials} runs): {len(finished)} settings with finished trials, "
                f"{len(rows) - len(finished)} without. The figures are means over each setting's finished "
                f"trials (std of the ranked figure in its own column; every trial in sweep_trials.csv). {ranked_by}")
    unranked = len(finished) - len(ok)
    if unranked:        # a run whose metrics lack a term of the objective: listed, never ranked as if it were best
        L += [f"{unranked} finished runs have no {rank.objective.name} and are not ranked (their figures are in "
              "sweep.csv).", ""]
    datasets = sorted({r["dataset"] for r in rows})
    rot, rpe = mk.column("fused", mk.APE, "rotation_deg", "rmse"), mk.column("fused", mk.RPE_FRAME, "translation_m", "rmse")
    own = [] if rank.is_default else [rank.objective.name]     # the ranked figure, where it is not the APE column
    for ds in datasets:
        sub = sorted((r for r in ok if r["dataset"] == ds), key=lambda r: r[metric])
        sd = [r.get(f"{metric}_std") for r in sub] if n_trials > 1 else None
        nees = any(r.get("nees_pos_mean") is not None for r in sub)
        adapted = [k for k in dict.fromkeys(c[:-len("_noise_pos_x")] for r in sub for c in r
                                            if c.endswith("_noise_pos_x") and r[c] is not None)]
        header = ["rank", "variant", "setting", *own, *(["std"] if sd and own else []), "fused APE trans RMSE [m]",
                  *(["std [m]"] if sd and not own else []), "APE rot RMSE [deg]", "RPE 1 frame [m]", "fused/lidar",
                  "fused/GNSS", *(["NEES pos (3 dof)"] if nees else []), *(f"{k} noise x pos / att" for k in adapted),
                  "time [s]"]
        body = [[i, r["variant"], r["setting"], *([r[metric]] if own else []), *([sd[i - 1]] if sd and own else []),
                 r.get(METRIC), *([sd[i - 1]] if sd and not own else []), r.get(rot), r.get(rpe), r["fused_over_lidar"],
                 r["fused_over_gnss"], *([r.get("nees_pos_mean")] if nees else []),
                 *(_factors(r, k) for k in adapted), r["runtime_s"]] for i, r in enumerate(sub, 1)]
        align = "rll" + "r" * len(own) + ("r" if sd else "") + "rrrrr" + "r" * nees + "r" * len(adapted) + "r"
        decimals = [0, 0, 0, *([4] * len(own)), *([4] if sd and own else []), 3, *([3] if sd and not own else []),
                    3, 4, 3, 3, *([2] if nees else []), *([0] * len(adapted)), 1]
        # a column no run has a figure for is left out (drives without ground truth: five columns of n/a; a trial)
        keep = [j for j in range(len(header)) if j < 3 or any(row[j] is not None for row in body)]
        # (from the records' own flag: every run failing on a drive with truth leaves the APE empty too; a review)
        no_truth = bool(sub) and all((recs.get(r["id"]) or {}).get("metrics", {}).get("ground_truth") is False
                                     for r in sub)
        L += [f"## {dataset_label(ds)}", "", f"`{ds}`. " + ("No ground truth: nothing is scored; the runs are ranked "
                                                           "by their innovations." if no_truth else _span_note(sub)),
              ""] + markdown([header[j] for j in keep], [[row[j] for j in keep] for row in body],
                             align="".join(align[j] for j in keep), decimals=[decimals[j] for j in keep])
        if adapted:
            L += ["", f"{', '.join(adapted)} noise adapted itself to its innovations in these runs "
                  f"(`{adapted[0]}.noise_adapt`): the factors it applied to the configured std (medians over the second "
                  "half of each drive) say how much of a swept noise setting the adaptation undid; set "
                  f"`{adapted[0]}.noise_adapt: none` in the settings to compare fixed noise values."]
        L.append("")
    # averaged across datasets: only settings that finished on every dataset
    avg: dict = {}
    for r in ok:
        avg.setdefault((r["variant"], r["setting"]), []).append(r[metric])
    full = {k: float(np.mean(v)) for k, v in avg.items() if len(v) == len(datasets)}
    ranked = sorted(full.items(), key=lambda kv: kv[1])
    mean_label = "mean fused APE trans RMSE [m]" if rank.is_default else f"mean {rank.objective.name}"
    if len(datasets) > 1:
        L += ["## Averaged across datasets", ""] + markdown(
            ["rank", "variant", "setting", mean_label],
            [[i, v, s, m] for i, ((v, s), m) in enumerate(ranked, 1)], align="rllr")
        L.append("")
    for status, title in (("diverged", "Diverged runs (exit 3 for run: the settings make the filter lose the data)"),
                          ("failed", "Failed runs")):
        bad = [r for r in rows if r["status"] == status]
        if bad:
            L += [f"## {title}", ""] + markdown(["dataset", "variant", "setting", "error"],
                                               [[r["dataset"], r["variant"], r["setting"], r["error"]] for r in bad],
                                               align="llll")
            L.append("")
    warned = _warnings(tasks, recs)
    if warned:            # each run's report has them; here they say which setting raised which
        L += ["## Warnings", "", "As each run's report gives them (the data's, and the streams its filter did not "
              "follow: with a swept noise setting, often the setting's doing):", ""] + warned + [""]
    best = None
    if ranked:
        (bv, bs), bm = ranked[0]
        bt = next(t for t in tasks if t.variant == bv and t.setting == bs)
        best = {"variant": bv, "setting": bs, "objective": rank.objective.name, "mean_objective": bm}
        if rank.is_default:
            best["mean_fused_ape_trans_rmse_m"] = bm
        what = "fused APE translation RMSE" if rank.is_default else rank.objective.name
        unit = " m" if rank.is_default else ""
        # a configuration file `fusion-eval run -c best.yaml` takes: the base config, the variant's file, the setting
        cfg = session.config_file(session.request(config=bt.base_config, variant=bt.variant_path, overrides=bt.overrides))
        caveat = _overconfident_best(ok, bv, bs)
        atomic_write(out_dir / "best.yaml", f"# best of the sweep: variant {bv}, setting {bs}\n"
                f"# mean {what} across datasets: {bm:.6f}{unit}\n"
                + "".join(f"# {line}\n" for line in textwrap.wrap(caveat or "", 112))
                + "".join(f"# {line}\n" for line in _use_lines(datasets, n_trials)) + yaml_lines.dump(cfg))
        L += [f"Best: variant `{bv}`, setting `{bs}` (mean {what} {cell(bm)}{unit}); see `best.yaml`.", ""]
        if caveat:
            L += [caveat, ""]
            best["caveat"] = caveat
        streams = list(dict.fromkeys(s for r in recs.values() if r.get("status") == "ok"
                                     for s in seeded_streams(r.get("metrics") or {})))
        # the next configuration that ran something else: a setting equal to the default (or to another) shares
        # its runs, and the best 'led the next by 0 %', itself (a cross-command consistency review)
        runs = {}
        for t in tasks:
            runs.setdefault((t.variant, t.setting), set()).add(t.id)
        nxt = next((m for key, m in ranked[1:] if runs.get(key) != runs.get((bv, bs))), None)
        note = one_draw_note(bm, nxt, n_trials, "The best leads the next by", streams=streams) if nxt is not None else None
        if note:
            L += [note, ""]
            best["note"] = note
        if n_trials > 1 and lead:
            L += [lead[0], ""]
            best["ranking"] = lead[1]
    else:                 # nothing ranked (every run failed): an earlier summary's best.yaml would name a run of no record
        (out_dir / "best.yaml").unlink(missing_ok=True)
    written = []
    if plots and ok:
        from ..report import plots as P

        written = P.plot_sweep(out_dir, rows, keys, metric, tasks, best, grid_keys or [],
                               defaults=default_values(tasks, out_dir, keys),
                               metric_label=None if rank.is_default else rank.label)
        L += [f"![{p}]({p})" for p in written]
    for stale in set(SWEEP_PLOTS) - set(written):
        # an earlier summary's plot this one does not draw (another grid's heatmap, another ranking's best against
        # the default, --no-plots) read as this one's (a failure-injection review)
        (out_dir / stale).unlink(missing_ok=True)
    md = "\n".join(L) + "\n"
    atomic_write(out_dir / "sweep.md", md)
    atomic_write(out_dir / "report.html", html.page(md, out_dir, inputs=dataset_files(t.dataset for t in tasks)))
    return {"rows": rows, "best": best, "plots": written, "ranking": rank, "failed_runs": failed_runs, "runs": n_runs}


def _factors(r: dict, stream: str) -> str:
    pos, att = r.get(f"{stream}_noise_pos_x"), r.get(f"{stream}_noise_att_x")
    return "" if pos is None else f"{pos:.2f} / {att:.2f}" if att is not None else f"{pos:.2f}"


def _overconfident_best(ok: list[dict], variant: str, setting: str) -> str | None:
    """A caveat for a best setting whose filter is overconfident and less consistent than the default setting's on
    some dataset (position NEES mean above :data:`~fusion_eval.report.markdown.VERDICT_RATIO` x its 3 dof and above
    that factor of the default's): its lower APE was bought by trusting a stream more than its noise allows, which
    a drive with other noise will punish (a student's review: 'gnss-trusted' ranked first with a NEES of 14.4 against
    the default's 7.0, and nothing said so)."""
    from ..report.markdown import VERDICT_RATIO

    worse = []
    for r in ok:
        if (r["variant"], r["setting"]) != (variant, setting) or r.get("nees_pos_mean") is None:
            continue
        ref = next((d for d in ok if (d["dataset"], d["variant"], d["setting"]) == (r["dataset"], variant, "default")),
                   None)
        ref_nees = None if ref is None else ref.get("nees_pos_mean")
        if r["nees_pos_mean"] > VERDICT_RATIO * 3 and (ref_nees is None or r["nees_pos_mean"] > VERDICT_RATIO * ref_nees):
            worse.append(f"`{dataset_label(r['dataset'])}` {r['nees_pos_mean']:.1f}" +
                         ("" if ref_nees is None else f" (the default {ref_nees:.1f})"))
    if not worse:
        return None
    return (f"Caveat: the best setting's filter is overconfident: its position NEES mean is {', '.join(worse)} for 3 "
            "dof. Its lower error comes with a covariance that understates it, which usually means a stream trusted "
            "more than its noise allows on these drives; check it on a drive it was not chosen on before adopting it.")


def _use_lines(datasets: list[str], n_trials: int) -> list[str]:
    """How ``best.yaml`` reproduces the figure it states: on the sweep's dataset(s), with its Monte-Carlo trials."""
    cmds = rerun_commands(datasets, n_trials)
    return ["use it as: " + cmds[0]] + [f"       and: {c}" for c in cmds[1:]] + \
        (["(the figure above is the mean over these datasets)"] if len(cmds) > 1 else [])


def _warnings(tasks: list[Task], recs: dict[str, dict]) -> list[str]:
    """One line per warning of a finished run, naming the run's dataset, variant, setting (and trial); a warning of
    the data that every run of a dataset gives is listed once, for the dataset."""
    per_run: list[tuple[Task, list[str]]] = []
    seen = set()
    for t in tasks:
        r = recs.get(t.id)
        if r is None or t.id in seen or r.get("status") != "ok":
            continue
        seen.add(t.id)
        per_run.append((t, list(((r.get("metrics") or {}).get("preprocessing") or {}).get("data_warnings") or [])))
    out = []
    for ds in dict.fromkeys(t.dataset for t, _ in per_run):
        runs = [(t, ws) for t, ws in per_run if t.dataset == ds]
        common = set.intersection(*(set(ws) for _, ws in runs)) if runs else set()
        out += [f"- `{ds}` (every run): {w}" for w in sorted(common)]
        for t, ws in runs:
            trial = f", trial {t.trial}" if t.trial else ""
            out += [f"- `{ds}` {t.variant} / {t.setting}{trial}: {w}" for w in ws if w not in common]
    return out


def default_values(tasks: list[Task], out_dir: Path, keys: list[str]) -> dict[tuple[str, str], dict]:
    """The value each swept key took in the 'default' setting's run, per (dataset, variant): where the plots put
    the default. The setting has no overrides, so its values are those the run resolved (defaults < dataset
    manifest < sweep config < variant) as its ``config.resolved.yaml`` records them, an 'auto' one as the
    estimate the run applied (``applied.imu_noise``). A key the run did not record (no run folder, a failed
    run) is left out."""
    out: dict[tuple[str, str], dict] = {}
    for t in tasks:
        if t.setting != "default" or t.trial != 0 or (t.dataset, t.variant) in out:
            continue
        f = Path(out_dir) / "runs" / t.id / "config.resolved.yaml"
        try:
            cfg = yaml.safe_load(f.read_text(encoding="utf-8")) if f.is_file() else None
        except (OSError, yaml.YAMLError):
            cfg = None
        if not isinstance(cfg, dict):
            continue
        applied = cfg.get("applied") or {}
        vals = {}
        for k in keys:
            sect, _, name = k.partition(".")
            v = (cfg.get(sect) or {}).get(name)
            if v == "auto":
                v = (applied.get(f"{sect}_noise") or {}).get(name, applied.get(name))
            if mk.is_number(v):
                vals[k] = float(v)
        out[(t.dataset, t.variant)] = vals
    return out
