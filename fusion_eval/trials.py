"""Monte-Carlo trials: one configuration repeated over N seeds of every random element, summarised per metric.

A run's random elements are its degradations (GNSS fixes, GNSS velocity, the odometer's added noise), each
drawn from a seed key of the configuration. Trial ``i`` adds ``i`` to every seed key that is set (``gnss.seed``,
and any other ``*.seed`` key given a value; those left null follow ``gnss.seed``), so trial 0 is the run
itself and the trials are reproducible. A simulated drive's sensor noise is in its files: to vary it,
simulate with other ``--seed`` values.

Per metric (every path :func:`fusion_eval.evaluation.keys.flatten` gives): the mean, the standard deviation
(``ddof=1``), min, max, median, the 2.5 and 97.5 percentiles of the trials (``p2.5``, ``p97.5``; with under 40
trials they are about the min and the max), the 95 % interval where one more run falls (Student's t prediction
interval, ``pi95_run``: mean +/- t s sqrt(1 + 1/n); the percentiles of 5 trials cover about 67 % of new draws, and
were the report's "95 % of trials": a statistics review) and the 95 % confidence interval of the mean (``ci95_mean``).
"""

from __future__ import annotations

import math
import re

import numpy as np

from .config import schema
from .errors import ConfigError
from .evaluation import keys

STATS = ("mean", "std", "min", "max", "median", "p2.5", "p97.5", "pi95_run", "ci95_mean")
# shown in reports and tables, in this order
HEADLINE = ("fused.ape.translation_m.rmse", "fused.ape.rotation_deg.rmse", "lidar.ape.translation_m.rmse",
            "gnss.ape.translation_m.rmse", "ratios.fused_over_lidar", "ratios.fused_over_gnss",
            "nees.position.fraction_in_95", "nees.attitude.fraction_in_95")
# with a smoother (smoother.method), after those
SMOOTHED = ("smoothed.ape.translation_m.rmse", "smoothed.ape.rotation_deg.rmse", "ratios.smoothed_over_fused",
            "ratios.smoothed_over_lidar", "ratios.smoothed_over_gnss", "nees_smoothed.position.fraction_in_95",
            "nees_smoothed.attitude.fraction_in_95")


def headline(sec: dict) -> tuple[str, ...]:
    """The headline paths of a trials section: the smoothed ones only when the runs had a smoother."""
    return HEADLINE + tuple(p for p in SMOOTHED if p in sec["stats"])


MAX_TRIALS = 10_000     # Monte-Carlo trials of one run or setting: beyond, a typo (1e23 once ran until killed)


def check_count(n: int) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_TRIALS:
        raise ConfigError(f"--trials must be a whole number from 1 to {MAX_TRIALS:,}, got {n!r}")
    return n


def seed_keys() -> tuple[str, ...]:
    """Every configuration key that seeds a random element."""
    return tuple(k for k in schema() if k.split(".")[-1] == "seed")


def trial_overrides(cfg: dict, i: int) -> dict:
    """The dotted overrides of trial ``i``: each seed key that has a value, plus ``i``."""
    out = {}
    for k in seed_keys():
        sect, key = k.split(".")
        v = cfg.get(sect, {}).get(key)
        if v is not None:
            out[k] = int(v) + i
    return out


def apply(cfg: dict, i: int) -> dict:
    """A resolved configuration with trial ``i``'s seeds (a copy; trial 0 is ``cfg`` itself)."""
    if i == 0:
        return cfg
    out = {s: dict(v) if isinstance(v, dict) else v for s, v in cfg.items()}
    for k, v in trial_overrides(cfg, i).items():
        sect, key = k.split(".")
        out[sect][key] = v
    return out


def _t95(dof: float) -> float:
    """Student's t 97.5 % quantile for ``dof`` degrees of freedom (what ``scipy.stats.t.ppf`` computes, bit for bit,
    without importing scipy.stats)."""
    from scipy.special import stdtrit

    return float(stdtrit(dof, 0.975))


def stats(values) -> dict:
    """The statistics of one metric over the trials (NaN-free values)."""
    v = np.asarray(values, float)
    n = v.size
    if n == 0:
        return {"n": 0}
    mean = float(v.mean())
    std = float(v.std(ddof=1)) if n > 1 else 0.0
    t = _t95(n - 1) if n > 1 else float("nan")
    half = t * std / math.sqrt(n) if n > 1 else float("nan")
    run = t * std * math.sqrt(1.0 + 1.0 / n) if n > 1 else float("nan")
    return {"n": int(n), "mean": mean, "std": std, "min": float(v.min()), "max": float(v.max()),
            "median": float(np.median(v)), "p2.5": float(np.percentile(v, 2.5)), "p97.5": float(np.percentile(v, 97.5)),
            "pi95_run": [mean - run, mean + run], "ci95_mean": [mean - half, mean + half]}


def summarize(per_trial: list[dict]) -> dict:
    """``{path: stats}`` over the trials' flattened metrics (a path missing in a trial is left out of it). The
    interval of one more run is kept inside what the figure can be: not below 0 for a figure that is never negative
    in the trials (an APE, a NEES), not above 1 for a fraction (2 trials of a NEES fraction gave 0.75 .. 1.085: a
    diff review)."""
    flats = [keys.flatten(m) for m in per_trial]
    paths = list(dict.fromkeys(p for f in flats for p in f))
    out = {p: stats([f[p] for f in flats if p in f]) for p in paths}
    for p, st in out.items():
        if "pi95_run" in st and st.get("n", 0) > 1:
            lo, hi = st["pi95_run"]
            if st["min"] >= 0.0:
                lo = max(lo, 0.0)
            if "fraction" in p.rsplit(".", 1)[-1] and st["max"] <= 1.0:
                hi = min(hi, 1.0)
            st["pi95_run"] = [lo, hi]
    return out


NOTHING_RANDOM = ("the fused estimate's figures are identical over the {n} trials: nothing it uses depends on a seed "
                  "(no degraded GNSS or odometer is fused; a simulated drive's sensor noise is in its files: vary it with "
                  "simulate --seed), so its spread and 95 % intervals say nothing")


def nothing_random_line(n: int) -> str:
    """:data:`NOTHING_RANDOM` as a report's bold sentence (run's report.md, sweep.md)."""
    text = NOTHING_RANDOM.format(n=n)
    return f"**{text[:1].upper()}{text[1:]}.**"


# a lead below this share of the better figure, from one run each with the same seeds, is called out: the differences
# of variants under one seed spread by 0.1-2 % of kitti-00's fused APE over seeds (paired std over 10 seeds: no-nhc
# 0.8 %, a tuned config 1.8 %; a statistics review, 2026-12-06)
SMALL_LEAD = 0.05
# the same for entries drawn with different seeds (unpaired): one GNSS seed moves kitti-00's fused APE by about 11 % of
# its mean (std over seeds; README, "Monte-Carlo trials"), so a lead under about 2.7 of that is inside what seeds do
UNPAIRED_LEAD = 0.30
# a lead over paired trials whose whole 95 % interval lies under this share of the figure: it holds, but is too small
# to matter (nominal-state against error-state on kitti-00: 0.05 %, 10 of 10 seeds)
PRACTICAL_LEAD = 0.01


def effective_seeds(cfg: dict) -> dict:
    """Every seed key of a resolved configuration with the seed it draws with (a null one follows ``gnss.seed``):
    two runs whose dicts are equal draw their random elements alike (their comparison is paired)."""
    base = (cfg.get("gnss") or {}).get("seed")
    out = {}
    for k in seed_keys():
        sect, key = k.split(".")
        v = (cfg.get(sect) or {}).get(key)
        out[k] = base if v is None else v
    return out


def one_draw_note(better: float, worse: float, n_trials: int, what: str, how: str = "--trials 5",
                  streams: list[str] | None = None, paired: bool = True) -> str | None:
    """A sentence under a ranking made from one run of each entry, when the runs fuse ``streams`` drawn with a seed
    (:func:`seeded_streams`; None: not known) and ``better`` leads ``worse`` by less than seeds can move it: under
    :data:`SMALL_LEAD` for runs drawn with the same seeds (``paired``), under :data:`UNPAIRED_LEAD` for runs drawn
    with different ones, whose figures move apart by a whole seed's spread (a 19 % 'lead' of one variant over itself
    under another seed was said with no word: a statistics review). Two equal figures are said to be equal. None
    when the ranking is on means of trials, the lead is larger, or nothing fused is random (a student ranked noise
    settings 0.754-0.758 m apart, inside a seed spread of 0.08 m, and took the 'best' as found; another was told to
    run trials of a comparison with nothing random in it)."""
    if n_trials > 1 or not (math.isfinite(better) and math.isfinite(worse)) or better <= 0 or worse < better:
        return None
    if worse == better:
        return (f"The first two figures are equal ({better:.6g}): this ranking does not order them"
                + (" (a configuration equal to another, or a setting that changes nothing here)." if paired else "."))
    lead = (worse - better) / better
    if lead >= (SMALL_LEAD if paired else UNPAIRED_LEAD) or streams == []:
        return None
    what_random = f"the {' and '.join(streams)} these runs fuse" if streams else "the runs' random elements"
    if not paired:
        return (f"{what} {lead * 100:.2g} % from one run each, drawn with different seeds of {what_random}: an "
                "unpaired comparison, and one seed moves a figure by about 11 % of its mean (the fused APE on "
                f"kitti-00). Give both the same seeds, or `{how}`, to rank them.")
    return (f"{what} {lead * 100:.2g} % from one run each, with the same seeds of {what_random}. Under one seed the "
            "difference of two configurations moves less than each figure does (by 0.1-2 % of the fused APE on "
            f"kitti-00 from seed to seed, each figure by about 11 %), but one seed does not rank them: `{how}` ranks "
            "on the means over seeds, each trial of every entry with the same seeds.")


def seeded_streams(m: dict) -> list[str]:
    """The streams a run's filter fused that were drawn with a seed (a degraded GNSS, GNSS velocity or odometer):
    what makes its fused figures move from one seed to the next. Empty: the fused estimate is the same on every
    seed (a GNSS degraded but not fused is only the unfiltered GNSS estimate's)."""
    nis = m.get("nis") or {}
    pre = m.get("preprocessing") or {}
    out = ["degraded GNSS"] if "gnss" in nis and (m.get("gnss_degradation") or {}).get("degraded") else []
    out += [f"degraded {k}" for k, info in pre.items() if isinstance(info, dict) and info.get("degraded") and k in nis]
    if pre.get("odometer_added_noise_std_mps") and "odometer" in nis:
        out.append("odometer noise")
    return out


def rerun_commands(datasets, n_trials: int, config: str = "best.yaml") -> list[str]:
    """The ``fusion-eval run`` commands that reproduce a figure made on ``datasets`` over ``n_trials`` Monte-Carlo
    trials with ``config`` (a sweep's or a tune's ``best.yaml``: its hint ran kitti-00 and one trial, 0.965 m against a
    sweep's 0.650; a reproducibility review)."""
    import shlex

    trials = f" --trials {n_trials}" if n_trials > 1 else ""
    return [f"fusion-eval run {shlex.quote(str(d))} -c {config}{trials}" for d in datasets]


def paired_lead(per_trial: dict[str, list], what: str = "fused APE", unit: str = " m", relative: bool = True,
                seeds: dict | None = None) -> tuple[str, dict] | None:
    """The best entry against the next, paired over the trials every entry finished (trial i of each draws its
    random elements with the same seed offset): the mean difference of their figures with its 95 % interval
    (Student's t), and how many trials the best wins; overlapping intervals of the two means said nothing of a lead
    that every seed showed (a review: 0.007-0.020 m on each of four seeds). ``relative`` (an error figure, whose zero
    is no error): the lead as a share of the next's mean too, and a lead that holds but whose whole interval is under
    :data:`PRACTICAL_LEAD` of the figure is said to be too small to matter; two entries equal in every trial are said
    to be equal (both were 'may rank with more trials': a statistics review). ``seeds``: each entry's
    :func:`effective_seeds`; two entries drawn with other seeds are not paired (a variant setting its own gnss.seed
    was 'paired' over trials of seeds 0-2 against 3-5: a diff review), and get Welch's interval of the difference of
    their means instead. ``per_trial``: {entry: [figure per trial]} (None or NaN for a failed trial: the ranking is
    over the trials every entry finished, the pair over those both finished)."""
    def done(k, i):
        return per_trial[k][i] is not None and math.isfinite(per_trial[k][i])

    # a variant that finished no trial is not ranked (it left no trial that every variant finished: a review)
    rows = [k for k, v in per_trial.items() if any(done(k, i) for i in range(len(v)))]
    if len(rows) < 2:
        return None
    n = min(len(per_trial[k]) for k in rows)
    ok = [i for i in range(n) if all(done(k, i) for k in rows)]
    if len(ok) < 2:
        return None
    means = {k: float(np.mean([per_trial[k][i] for i in ok])) for k in rows}
    best, nxt = sorted(means, key=means.get)[:2]
    paired = not seeds or seeds.get(best) == seeds.get(nxt)
    if paired:
        both = [i for i in range(n) if done(best, i) and done(nxt, i)]
        d = np.array([per_trial[nxt][i] - per_trial[best][i] for i in both])
        st = stats(d)
        diff, (lo, hi), count = st["mean"], st["ci95_mean"], int(d.size)
        wins, equal = int(np.sum(d > 0)), bool(np.all(d == 0))
        ref = abs(float(np.mean([per_trial[nxt][i] for i in both])))
        head = f"Ranking over {count} paired trials (trial i of each with the same seeds): "
    else:
        a, b = (np.array([per_trial[k][i] for i in range(len(per_trial[k])) if done(k, i)]) for k in (best, nxt))
        diff, (lo, hi) = _welch(b, a)
        count, wins, equal, ref = int(min(a.size, b.size)), None, False, abs(float(b.mean()))
        head = (f"Ranking over {a.size} and {b.size} trials, unpaired: **{best}** and **{nxt}** draw with other seeds "
                "(a variant that sets its own), so their trials do not pair; ")
    held = lo > 0
    share = diff / ref if relative and ref > 0 else math.nan
    small = held and relative and ref > 0 and hi < PRACTICAL_LEAD * ref
    if equal:
        text = head + (f"**{best}** and **{nxt}** have the same {what} in every trial: nothing ranks them, however "
                       "many trials.")
    else:
        pct = f" ({share * 100:.2g} %)" if math.isfinite(share) else ""
        text = head + (f"**{best}** leads **{nxt}** in {what} by {diff:.4g}{unit}{pct} on average "
                       f"[95 % interval {lo:.4g}, {hi:.4g}{'' if paired else ', Welch'}]"
                       + (f", lower in {wins} of {count} trials: " if paired else ": "))
        text += (f"the lead holds, but all of its interval is under {PRACTICAL_LEAD * 100:.0f} % of the figure: for practical "
                 "purposes the two are equal." if small else "the lead holds." if held else
                 "the interval includes 0, so these trials do not rank the two; more trials (--trials) may.")
    return text, {"best": best, "next": nxt, "mean_difference": diff, "share": share, "ci95": [lo, hi],
                  "wins": wins, "trials": count, "holds": bool(held), "practically_equal": bool(small or equal),
                  "identical": equal, "paired": paired}


def _welch(b: np.ndarray, a: np.ndarray) -> tuple[float, tuple[float, float]]:
    """mean(b) - mean(a) and its 95 % interval (Welch's t, unequal variances)."""
    va, vb = (float(x.var(ddof=1)) / x.size if x.size > 1 else math.nan for x in (a, b))
    diff = float(b.mean() - a.mean())
    se2 = va + vb
    if not se2 > 0:
        return diff, (math.nan, math.nan)
    dof = se2 ** 2 / (va ** 2 / (a.size - 1) + vb ** 2 / (b.size - 1))
    half = _t95(dof) * math.sqrt(se2)
    return diff, (diff - half, diff + half)


def all_equal(values: list) -> bool:
    """Whether two or more trials' figures are one and the same (a run with no random element)."""
    vals = [v for v in values if v is not None]
    return len(vals) > 1 and all(v == vals[0] for v in vals)


def section(cfg: dict, per_trial: list[dict]) -> dict:
    """The ``trials`` section of a metrics.json (a failed trial is ``{"failed": message}``: listed, not averaged);
    ``identical``: every trial gave the same fused figures (nothing random to vary: said in the report)."""
    ok = [m for m in per_trial if "failed" not in m]
    same = all_equal([keys.flatten(m).get(HEADLINE[0]) for m in ok])
    return {"n": len(per_trial), "identical": same, "seeds": [trial_overrides(cfg, i) for i in range(len(per_trial))],
            "failed": [{"trial": i, "error": m["failed"]} for i, m in enumerate(per_trial) if "failed" in m],
            "stats": summarize(ok),
            "per_trial": [{"trial": i, **({"failed": m["failed"]} if "failed" in m else
                                          {p: v for p, v in keys.flatten(m).items() if p in HEADLINE + SMOOTHED})}
                          for i, m in enumerate(per_trial)]}


def csv_rows(sec: dict) -> tuple[list[str], list[dict]]:
    """``trials.csv``: one row per trial, its seeds and headline metrics."""
    seed_cols = sorted({k for s in sec["seeds"] for k in s})
    cols = ["trial", *seed_cols, *headline(sec), "failed"]
    rows = [{**{"trial": r["trial"], "failed": r.get("failed", "")}, **sec["seeds"][r["trial"]],
             **{p: r.get(p) for p in headline(sec)}} for r in sec["per_trial"]]
    return cols, rows


def _row_format(*values: float):
    """One number format for a whole row: four significant digits of its largest value, the same decimals for
    every column (so that 0.7631 and 0.7890 line up, instead of 0.7631 and 0.789)."""
    big = max((abs(v) for v in values if math.isfinite(v)), default=0.0)
    nd = max(0, 3 - math.floor(math.log10(big))) if big > 0 else 3
    if nd > 8:                                   # a tiny quantity: exponents say more than a row of zeros
        return lambda v: f"{v:.3e}"
    return lambda v: f"{v:.{nd}f}"


def markdown(sec: dict, plotted: bool = True) -> list[str]:
    """The report's table of the headline metrics over the trials (``plotted``: ``trials.png`` was written; with
    --no-plots the report pointed to a file that was not there: a student's review)."""
    from .tables import markdown as md

    rows = []
    for p in headline(sec):
        s = sec["stats"].get(p)
        if not s or not s.get("n"):
            continue
        lo, hi = s["ci95_mean"]
        rlo, rhi = s.get("pi95_run") or (math.nan, math.nan)
        f = _row_format(s["mean"], s["min"], s["max"])
        rows.append([p, f(s["mean"]), f(s["std"]), f(s["min"]), f(s["max"]),
                     "" if math.isnan(rlo) else f"{f(rlo)} .. {f(rhi)}", "" if math.isnan(lo) else f"{f(lo)} .. {f(hi)}"])
    seeds = sec["seeds"]
    L = ["## Monte-Carlo trials", "",
         f"{sec['n']} trials over the seeds of every random element (trial i adds i to "
         f"{', '.join(sorted(seeds[0])) or 'the seeds'}); trial 0's outputs are the files of this folder; per trial: "
         f"`trials.csv`{', `trials.png`' if plotted else ''}.", ""]
    if sec.get("identical"):
        L += [nothing_random_line(sec["n"]), ""]
    if sec.get("failed"):
        L += [f"{len(sec['failed'])} trials failed and are not in the statistics: "
              + "; ".join(f"trial {f['trial']}: {f['error']}" for f in sec["failed"]), ""]
    return L + md(["metric", "mean", "std", "min", "max", "one more run, 95 %", "95 % CI of the mean"], rows,
                  align="lrrrrll") + [""]


def _mean_of(values: list):
    """The mean of one table field over the trials: numbers, lists of numbers elementwise, dicts per key."""
    vals = [v for v in values if v is not None]
    if not vals:
        return None
    v0 = vals[0]
    if isinstance(v0, bool) or isinstance(v0, str):
        return v0
    if isinstance(v0, (int, float)):
        return float(np.mean(vals))
    if isinstance(v0, (list, tuple)):
        return np.mean(np.asarray(vals, float), axis=0).tolist()
    if isinstance(v0, dict):
        return {k: _mean_of([v.get(k) for v in vals]) for k in v0}
    return v0


def aggregate_rows(tables: list[list[dict]], by: tuple[str, ...], spread: str = "ape_trans_rmse_m") -> list[dict]:
    """Rows of several trials' tables averaged field by field, matched on the ``by`` fields; each row also gets
    ``trials`` and the spread of ``spread`` (``<spread>_std``, ``<spread>_ci95``)."""
    out = []
    for row in tables[0]:
        key = tuple(row.get(b) for b in by)
        same = [r for t in tables for r in t if tuple(r.get(b) for b in by) == key]
        agg = {k: (row[k] if k in by else _mean_of([r.get(k) for r in same])) for k in row}
        st = stats([r[spread] for r in same if r.get(spread) is not None])
        agg.update({"trials": len(same), f"{spread}_std": st.get("std"), f"{spread}_ci95": st.get("ci95_mean")})
        out.append(agg)
    return out


def _kind(message: str) -> str:
    """A warning without its figures: the same finding in two trials (a NIS of 87.1 in one, 100.3 in another)."""
    return re.sub(r"[-+]?\d[\d.,]*(?:e[-+]?\d+)?", "#", message)


def warnings(first: list[str], others: list[list[str]]) -> list[str]:
    """What the trials after the first said, summed up: a finding the first trial (the run) said too is counted
    once, one it did not is said once with the trials that found it (ten trials repeated each warning ten times,
    with no word of which trial said which; a review). ``first``: the run's warnings; ``others``: each later
    trial's."""
    seen = {_kind(m) for m in first}
    new: dict[str, tuple[str, list[int]]] = {}
    repeated = set()
    for i, msgs in enumerate(others, start=1):
        kinds = {}
        for m in msgs:
            kinds.setdefault(_kind(m), m)          # one finding said twice in a trial: its first figures
        for k, m in kinds.items():
            if k in seen:
                repeated.add(i)
            else:
                new.setdefault(k, (m, []))[1].append(i)
    n = len(others) + 1
    out = [f"{_trial_list(trials, n)}: {m}" for m, trials in new.values()]
    if repeated:
        out.append(f"{_trial_list(sorted(repeated), n)} repeated warnings above, with figures of their own")
    return out


def _trial_list(trials: list[int], n: int) -> str:
    head = ", ".join(str(i) for i in trials[:8]) + (f" and {len(trials) - 8} more" if len(trials) > 8 else "")
    return f"{'trial' if len(trials) == 1 else 'trials'} {head} (of 0..{n - 1})"
