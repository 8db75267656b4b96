"""Monte-Carlo trials: the seeds of every random element, the statistics over trials, and --trials in run,
compare, sweep and check."""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import stats as st

import fusion_eval as fe
from fusion_eval import trials as mc
from fusion_eval.cli import main
from fusion_eval.config import load_config


def test_every_seed_that_is_set_moves_with_the_trial():
    cfg = load_config(None, ("gnss.seed=7", "gnss_velocity.seed=3"))
    assert set(mc.seed_keys()) >= {"gnss.seed", "gnss_velocity.seed"}
    assert mc.trial_overrides(cfg, 2) == {"gnss.seed": 9, "gnss_velocity.seed": 5}
    plain = load_config(None, ())
    assert mc.trial_overrides(plain, 4) == {"gnss.seed": 4}       # gnss_velocity.seed null: it follows gnss.seed
    assert mc.apply(plain, 0) is plain and mc.apply(plain, 3)["gnss"]["seed"] == 3 and plain["gnss"]["seed"] == 0


def test_statistics_over_trials():
    v = np.array([0.71, 0.80, 0.76, 0.66, 0.74])
    s = mc.stats(v)
    half = st.t.ppf(0.975, v.size - 1) * v.std(ddof=1) / np.sqrt(v.size)
    assert s["mean"] == pytest.approx(v.mean()) and s["std"] == pytest.approx(v.std(ddof=1))
    assert s["ci95_mean"] == pytest.approx([v.mean() - half, v.mean() + half])
    assert (s["min"], s["max"], s["n"]) == (0.66, 0.80, 5)
    rows = mc.aggregate_rows([[{"v": "a", "x": 1.0, "b": [1.0, 2.0], "nis": {"l": 2.0}}],
                              [{"v": "a", "x": 3.0, "b": [3.0, 4.0], "nis": {"l": 4.0}}]], ("v",), spread="x")
    assert rows[0]["x"] == 2.0 and rows[0]["b"] == [2.0, 3.0] and rows[0]["nis"] == {"l": 3.0} and rows[0]["trials"] == 2
    with pytest.raises(Exception, match="whole number"):
        mc.check_count(0)


def test_run_with_trials_summarises_every_metric_and_check_gates_on_the_mean(kitti_slice, tmp_path):
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--trials", "3", "--out", str(out), "--no-plots"])
    assert r.exit_code == 0, r.output
    m = json.loads((out / "metrics.json").read_text())
    tr = m["trials"]
    assert tr["n"] == 3 and [s["gnss.seed"] for s in tr["seeds"]] == [0, 1, 2]
    per = [p["fused.ape.translation_m.rmse"] for p in tr["per_trial"]]
    assert len(set(per)) == 3                                   # the seeds do change the result
    assert per[0] == m["estimates"]["fused"]["ape"]["translation_m"]["rmse"]   # trial 0 is the run itself
    s = tr["stats"]["fused.ape.translation_m.rmse"]
    assert s["mean"] == pytest.approx(np.mean(per)) and s["std"] == pytest.approx(np.std(per, ddof=1))
    # the lidar has no random element: the same in every trial
    assert tr["stats"]["lidar.ape.translation_m.rmse"]["std"] == 0.0
    rows = list(csv.DictReader((out / "trials.csv").read_text().splitlines()))
    assert [int(x["trial"]) for x in rows] == [0, 1, 2]
    assert "## Monte-Carlo trials" in (out / "report.md").read_text()
    # the tables of metrics.tex and metrics.csv are trial 0's, and say so (they gave one seed with no word; a review)
    assert "Trial 0 of 3 Monte-Carlo trials (one seed" in (out / "metrics.tex").read_text()
    assert {(r["trial"], r["trials"]) for r in csv.DictReader((out / "metrics.csv").read_text().splitlines())} == {("0", "3")}
    # check compares the mean over trials (or trial 0's own value with --trial-stat none)
    base = tmp_path / "base.json"
    base.write_text(json.dumps({**m, "trials": None}))
    mean_rule = f"fused.ape.rmse == {s['mean']!r}"
    r = CliRunner().invoke(main, ["check", str(out / "metrics.json"), "-b", str(base), "-m", "fused.ape.*", "--require", mean_rule,
                                  "--rtol", "1"])
    assert r.exit_code == 0 and "holds" in r.output, r.output
    # and says so, in its console, check.md and JUnit file (they gave the mean under the plain path with no word)
    said = "the mean over each file's Monte-Carlo trials (metrics: 3 trials; baseline: one run)"
    assert said in r.output and said in (out / "check.md").read_text()
    r = CliRunner().invoke(main, ["check", str(out / "metrics.json"), "-b", str(base), "-m", "fused.ape.*", "--require", mean_rule,
                                  "--rtol", "1", "--junit", str(tmp_path / "j.xml")])
    assert said in (tmp_path / "j.xml").read_text()
    r = CliRunner().invoke(main, ["check", str(out / "metrics.json"), "-b", str(base), "-m", "fused.ape.*", "--require", mean_rule,
                                  "--trial-stat", "none", "--rtol", "1"])
    assert "Values:" not in (out / "check.md").read_text()
    assert r.exit_code == 1 and "FAILS" in r.output


@pytest.mark.slow
def test_compare_and_sweep_with_trials_report_means(kitti_slice, tmp_path):
    out = tmp_path / "cmp"
    r = CliRunner().invoke(main, ["compare", str(kitti_slice), "--variants", "eskf,constant-bias", "--trials", "2",
                                  "--out", str(out), "--no-plots"])
    assert r.exit_code == 0, r.output
    c = json.loads((out / "compare.json").read_text())
    # the terminal's table: the translation's std beside its mean, not after the rotation column
    e = next(x for x in c["rows"] if x["variant"] == "eskf" and x["estimate"] == "fused")
    assert re.search(rf"eskf +fused +{e['ape_trans_rmse_m']:.3f} \+/- {e['ape_trans_rmse_m_std']:.3f} +{e['ape_rot_rmse_deg']:.3f}\n",
                     r.stdout), r.stdout
    assert c["trials"]["n"] == 2 and len(c["trials"]["per_trial"]) == 2
    for row in c["rows"]:
        per = [next(x for x in t if x["variant"] == row["variant"] and x["estimate"] == row["estimate"])["ape_trans_rmse_m"]
               for t in c["trials"]["per_trial"]]
        assert row["ape_trans_rmse_m"] == pytest.approx(np.mean(per)) and row["trials"] == 2
    md = (out / "compare.md").read_text()
    assert "Means over 2 Monte-Carlo trials" in md
    # the per-segment windows are trial 0's, under the means: said (a cross-command review)
    assert "Trial 0's windows (one seed; the table above gives the means over the 2 trials)" in md
    # a count stays a count in compare.csv (the trials' mean wrote 4405.000000; a review)
    assert all(re.fullmatch(r"\d+", row["matched_poses"])
               for row in csv.DictReader((out / "compare.csv").read_text().splitlines()))
    lo, hi = e["ape_trans_rmse_m_ci95"]          # the 95 % interval of the mean, as the README says (an audit)
    assert lo <= e["ape_trans_rmse_m"] <= hi and f" [{lo:.3f}, {hi:.3f}]" in md
    # the lead of the best over the next, paired over the same seeds (a review: overlapping intervals of the means
    # said nothing of a lead every seed showed)
    rk = c["trials"]["ranking"]
    fused = {v: [next(x for x in t if x["variant"] == v and x["estimate"] == "fused")["ape_trans_rmse_m"]
                 for t in c["trials"]["per_trial"]] for v in ("eskf", "constant-bias")}
    d = np.subtract(fused[rk["next"]], fused[rk["best"]])
    assert rk["mean_difference"] == pytest.approx(d.mean()) and rk["wins"] == int(np.sum(d > 0)) and rk["trials"] == 2
    assert f"**{rk['best']}** leads **{rk['next']}**" in md

    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"datasets: [{kitti_slice}]\nvariants: [eskf]\ntrials: 2\nsettings:\n  quiet: {{imu.accel_noise_mps2_sqrthz: 0.1}}\n")
    out = tmp_path / "sw"
    r = CliRunner().invoke(main, ["-q", "sweep", "--grid", str(sweep), "--out", str(out), "--no-plots", "--jobs", "1"])
    assert r.exit_code == 0, r.output
    per = list(csv.DictReader((out / "sweep_trials.csv").read_text().splitlines()))
    mean = list(csv.DictReader((out / "sweep.csv").read_text().splitlines()))
    assert len(per) == 4 and len(mean) == 2
    for row in mean:
        vals = [float(p["fused_ape_trans_rmse_m"]) for p in per if p["setting"] == row["setting"]]
        assert float(row["fused_ape_trans_rmse_m"]) == pytest.approx(np.mean(vals), rel=1e-5)
        assert row["trials"] == "2"
    md = (out / "sweep.md").read_text().splitlines()
    # the header line kept, and the count in settings and runs (it said "2 runs: 2 finished" of 4 runs)
    assert md[2].startswith("fusion-eval ") and md[4].startswith("2 settings x 2 Monte-Carlo trials") and "4 runs" in md[4]
    # the best against the next, paired over the seeds, as compare gives it (a sweep named its best from means 0.0004 m
    # apart with a std of 0.08 beside them and no word either way: a statistics review)
    per_set = {s_: [float(p["fused_ape_trans_rmse_m"]) for p in sorted(per, key=lambda p: p["trial"])
                    if p["setting"] == s_] for s_ in ("default", "quiet")}
    best = min(per_set, key=lambda k: np.mean(per_set[k]))
    other = "quiet" if best == "default" else "default"
    text = "\n".join(md)
    assert f"**eskf/{best}** leads **eskf/{other}** in fused APE by" in text, text
    d = np.subtract(per_set[other], per_set[best]).mean()
    said = re.search(r"in fused APE by ([0-9.e-]+) m \(", text)
    assert said and float(said.group(1)) == pytest.approx(d, rel=1e-3, abs=1e-6), text


def test_a_trial_keeps_its_log_lines_to_itself_and_returns_its_warnings(kitti_slice, caplog):
    """A trial repeats the main run's preparation and evaluation: its INFO lines (the estimated gyro lag, ...) and its
    warnings would print once per trial. Nothing of it prints; its warnings come back for the run to sum up, and the
    package's level and propagation are restored after it."""
    import logging

    from fusion_eval import session
    from fusion_eval.pipeline import trial_metrics

    ds = session.dataset(kitti_slice)
    # a GNSS stated 5-10x too precise: the NIS warnings of every trial
    cfg = session.resolve(session.request(sets=("imu.gyro_lag_s=auto", "gnss.std_m=0.2")), ds)
    pkg = logging.getLogger("fusion_eval")
    pkg.setLevel(logging.INFO)
    with caplog.at_level(logging.INFO, logger="fusion_eval"):
        m, said = trial_metrics(ds, cfg)
    assert "failed" not in m and m["estimates"]["fused"]["ape"]["translation_m"]["rmse"] > 0
    assert not [r for r in caplog.records if r.name.startswith("fusion_eval")]
    assert any(w.startswith("gnss: ") and "NIS" in w for w in said)
    assert pkg.level == logging.INFO and pkg.propagate


def test_the_later_trials_warnings_are_summed_up_against_the_runs():
    """Ten trials printed each warning ten times with no word of the trial: a finding the run said is counted once
    (figures aside), a new one said once with its trials."""
    run = ["gnss: median NIS 87.13 for 3 dof (29x): the filter does not follow this stream"]
    later = [["gnss: median NIS 100.3 for 3 dof (33x): the filter does not follow this stream"],
             [],
             ["gnss: median NIS 1e+03 for 3 dof (333x): the filter does not follow this stream",
              "filter diverged at t=12.5 s", "filter diverged at t=13.0 s"]]
    out = mc.warnings(run, later)
    assert out == ["trial 3 (of 0..3): filter diverged at t=12.5 s",
                   "trials 1, 3 (of 0..3) repeated warnings above, with figures of their own"]
    assert mc.warnings(run, [[], []]) == []
    many = mc.warnings([], [["x"]] * 10)
    assert many == ["trials 1, 2, 3, 4, 5, 6, 7, 8 and 2 more (of 0..10): x"]


def test_the_trials_table_gives_each_row_one_number_format():
    from fusion_eval.trials import _row_format

    f = _row_format(0.7631, 0.7211, 0.789)
    assert [f(v) for v in (0.7631, 0.0367, 0.789)] == ["0.7631", "0.0367", "0.7890"]
    assert _row_format(13258.3, 13258.3, 13258.3)(0.0) == "0"
    assert _row_format(2e-9, 1e-9, 3e-9)(1.5e-9) == "1.500e-09"


@pytest.mark.slow
def test_trials_of_a_run_with_nothing_random_say_so(tmp_path, kitti_slice, caplog):
    """A simulated drive's noise is in its files and its GNSS is used as it is: N trials were N identical rows
    and a zero-width '95 % CI' with no word (found by a new-user review)."""
    import logging

    from fusion_eval.simulate.dataset import simulate
    from fusion_eval.trials import markdown

    simulate(tmp_path / "sim", "urban", 20.0, 1, "automotive", (), jobs=1)
    with caplog.at_level(logging.WARNING):
        sim = fe.run(tmp_path / "sim", trials=2).metrics["trials"]
    assert sim["identical"] and "nothing it uses depends on a seed" in caplog.text
    assert any(ln.startswith("**The fused estimate's figures are identical over the 2 trials") for ln in markdown(sim))
    assert not fe.run(kitti_slice, trials=2).metrics["trials"]["identical"]       # the GNSS degradation varies


def test_the_trials_section_names_trials_png_only_when_it_was_drawn():
    """With --trials and --no-plots the report pointed to a trials.png that was not written (a student's review)."""
    from fusion_eval.trials import markdown as trials_md

    sec = {"n": 3, "seeds": [{"gnss.seed": 0}], "stats": {}, "identical": False, "failed": []}
    assert "`trials.csv`, `trials.png`." in "\n".join(trials_md(sec))
    text = "\n".join(trials_md(sec, plotted=False))
    assert "`trials.csv`." in text and "trials.png" not in text


def test_warnings_kept_to_a_block_reach_no_enclosing_collection():
    """With one worker a trial runs in the run's own process: its warnings, kept to itself, must not count as the
    run's (they would then be 'repeated', and a finding only that trial raised never said)."""
    import logging

    from fusion_eval.log_context import collected

    log = logging.getLogger("fusion_eval.test")
    with collected() as run:
        log.warning("the run's")
        with collected(show=False) as trial:
            log.warning("the trial's")
        log.warning("the run's again")
    assert run == ["the run's", "the run's again"] and trial == ["the trial's"]


def test_the_runs_evaluation_warnings_from_the_pool_are_not_said_again_as_the_trials(kitti_slice, caplog):
    """Trial 0's evaluations run in the pool's workers, which print their warnings there: the summary of the later
    trials did not know them and said each again as 'trials 1, 2: ...' (a review of the diff). The trials' repeats
    are one line. (Without the pool, trial 0's are the run's own: test_warnings_kept_to_a_block_reach_no_enclosing_
    collection holds the later trials' apart.)"""
    jobs = 2
    import logging

    with caplog.at_level(logging.WARNING, logger="fusion_eval"):
        fe.run(kitti_slice, overrides={"evaluation.rpe_delta_m": 100000}, trials=3, jobs=jobs)
    said = [r.getMessage() for r in caplog.records if r.name == "fusion_eval.pipeline"]
    assert "trials 1, 2 (of 0..2) repeated warnings above, with figures of their own" in said, said
    assert not [m for m in said if m.startswith("trials 1, 2 (of 0..2): ")], said


def test_a_paired_lead_is_said_with_its_interval_and_held_only_when_it_excludes_zero():
    from fusion_eval.trials import paired_lead

    text, info = paired_lead({"a": [1.00, 1.10, 0.95, 1.05], "b": [1.02, 1.12, 0.97, 1.07], "c": [2.0, 2.0, 2.0, None]})
    assert info["best"] == "a" and info["next"] == "b" and info["wins"] == 4 and info["holds"]
    assert info["mean_difference"] == pytest.approx(0.02) and "the lead holds" in text
    _, info = paired_lead({"a": [1.0, 1.2, 0.9], "b": [1.1, 1.0, 1.05]})
    assert not info["holds"] and info["ci95"][0] < 0 < info["ci95"][1]
    assert paired_lead({"a": [1.0], "b": [1.1]}) is None            # one trial: no interval
    # a failed trial is left out of every pair, and the ranking is over the trials all finished (b led a's three
    # by 0.1 but was called the second, "by -0.1 m", from its failed fourth trial's 2.0: a review)
    _, info = paired_lead({"a": [1.0, 1.0, 1.0, None], "b": [0.9, 0.9, 0.9, 2.0]})
    assert info["best"] == "b" and info["trials"] == 3 and info["wins"] == 3
    assert paired_lead({"a": [1.0, float("nan")], "b": [1.1, 1.2]}) is None
    _, info = paired_lead({"a": [1.0, 1.1, 1.2], "b": [1.2, 1.3, 1.4], "c": [None, None, None]})   # c finished none
    assert info["best"] == "a" and info["next"] == "b" and info["trials"] == 3


def test_the_interval_of_one_more_run_is_a_t_prediction_interval():
    """The report's '95 % of trials' was the 2.5-97.5 percentiles of the trials: about the min and max of 5, which cover
    some 67 % of new draws (a statistics review). One more run falls in mean +/- t s sqrt(1 + 1/n), 95 %."""
    from scipy.stats import t as student

    from fusion_eval.trials import stats

    v = [0.70, 0.80, 0.75, 0.72, 0.78]
    st = stats(v)
    half = student.ppf(0.975, 4) * np.std(v, ddof=1) * np.sqrt(1 + 1 / 5)
    assert st["pi95_run"] == pytest.approx([np.mean(v) - half, np.mean(v) + half], rel=1e-12)
    assert st["pi95_run"][0] < min(v) and st["pi95_run"][1] > max(v)
    assert st["p2.5"] == np.percentile(v, 2.5) and st["p97.5"] == np.percentile(v, 97.5)
    # its coverage of new draws, over many 5-trial sets of a normal figure: 95 %, where the percentiles' is far below
    rng = np.random.default_rng(1)
    sets, new = rng.normal(0.75, 0.08, (4000, 5)), rng.normal(0.75, 0.08, 4000)
    runs = [stats(x)["pi95_run"] for x in sets]
    cover = np.mean([lo <= y <= hi for (lo, hi), y in zip(runs, new)])
    pct = np.mean([np.percentile(x, 2.5) <= y <= np.percentile(x, 97.5) for x, y in zip(sets, new)])
    assert 0.93 < cover < 0.97 and pct < 0.75, (cover, pct)


def test_a_paired_lead_too_small_to_matter_and_equal_entries_are_said_so():
    """nominal-state against error-state on kitti-00: 0.000386 m (0.05 %) on 9 of 10 seeds was 'the lead holds', and two
    identical variants 'may' be ranked by more trials (a statistics review)."""
    from fusion_eval.trials import paired_lead

    base = [0.70, 0.80, 0.75, 0.72, 0.78]
    text, info = paired_lead({"eskf": base, "nominal": [b + 0.0004 + 1e-5 * i for i, b in enumerate(base)]})
    assert info["holds"] and info["practically_equal"] and not info["identical"]
    assert "for practical purposes the two are equal" in text and "(0.056 %)" in text, text
    text, info = paired_lead({"a": base, "b": list(base)})
    assert info["identical"] and "have the same fused APE in every trial: nothing ranks them" in text
    text, info = paired_lead({"a": base, "b": [b + 0.05 for b in base]})
    assert info["holds"] and not info["practically_equal"] and text.endswith("the lead holds.")
    _, info = paired_lead({"a": [1.0, 1.1, 1.2], "b": [1.0, 1.2, 1.3]})       # a tie is no win
    assert info["wins"] == 2 and info["trials"] == 3


def test_entries_drawn_with_other_seeds_are_not_paired_and_a_figure_of_arbitrary_zero_gets_no_share():
    """A variant setting its own gnss.seed was 'paired' over trials of seeds 0-2 against 3-5, and nll got '(0.088 %)'
    and 'practically equal' (its zero is arbitrary; a reference of 0 printed 'nan %'): a diff review."""
    from scipy.stats import ttest_ind

    from fusion_eval.trials import paired_lead

    a, b = [0.70, 0.80, 0.75, 0.72], [0.90, 0.95, 0.85, 0.99]
    text, info = paired_lead({"eskf": a, "eskf3": b}, seeds={"eskf": {"gnss.seed": 0}, "eskf3": {"gnss.seed": 3}})
    assert not info["paired"] and info["wins"] is None and "unpaired" in text and "Welch" in text, text
    # Welch's interval: 0 outside it exactly where Welch's two-sided test rejects at 5 %
    assert info["holds"] == (ttest_ind(b, a, equal_var=False).pvalue < 0.05)
    _, same = paired_lead({"eskf": a, "eskf3": b}, seeds={"eskf": {"gnss.seed": 0}, "eskf3": {"gnss.seed": 0}})
    assert same["paired"] and same["wins"] == 4
    text, info = paired_lead({"a": [-0.2, -0.3, -0.2], "b": [0.0, 0.0, 0.0]}, "nll", "", relative=False)
    assert " %)" not in text and "nan" not in text and not info["practically_equal"], text
    text, _ = paired_lead({"a": [-0.2, -0.3, -0.2], "b": [0.0, 0.0, 0.0]}, "x", "")
    assert "nan" not in text, text


def test_the_interval_of_one_more_run_stays_inside_what_the_figure_can_be():
    from fusion_eval.trials import summarize

    per = [{"nees": {"attitude": {"fraction_in_95": f}}, "estimates": {"fused": {"ape": {"translation_m": {"rmse": a}}}}}
           for f, a in ((0.80, 0.3), (1.0, 0.9))]
    st = summarize(per)
    lo, hi = st["nees.attitude.fraction_in_95"]["pi95_run"]
    assert hi == 1.0 and lo >= 0.0
    assert st["fused.ape.translation_m.rmse"]["pi95_run"][0] == 0.0


def test_a_sweeps_settings_that_share_their_runs_are_one_entry_in_the_paired_ranking():
    """A setting equal to the default was 'equal in every trial' to the best, and the real runner-up never given."""
    from types import SimpleNamespace

    from fusion_eval.commands.sweep_summary import _paired_lead

    rows = []
    for i, (d, noisy) in enumerate(((0.40, 0.50), (0.45, 0.55))):
        rows += [{"dataset": "ds", "variant": "eskf", "setting": "default", "trial": i, "id": f"d{i}", "status": "ok",
                  "m": d},
                 {"dataset": "ds", "variant": "eskf", "setting": "same", "trial": i, "id": f"d{i}", "status": "ok",
                  "m": d},
                 {"dataset": "ds", "variant": "eskf", "setting": "noisy", "trial": i, "id": f"n{i}", "status": "ok",
                  "m": noisy}]
    rank = SimpleNamespace(is_default=True, objective=SimpleNamespace(name="fused APE", is_error=True))
    text, info = _paired_lead(rows, "m", 2, rank)
    assert info["best"] == "eskf/default = eskf/same" and info["next"] == "eskf/noisy", text
    assert info["mean_difference"] == pytest.approx(0.10)


@pytest.mark.slow
def test_compare_trials_of_a_variant_with_its_own_seed_are_not_paired(kitti_slice, tmp_path):
    (tmp_path / "eskf3.yaml").write_text("gnss:\n  seed: 3\n", encoding="utf-8")
    out = tmp_path / "cmp"
    r = CliRunner().invoke(main, ["-q", "compare", str(kitti_slice), "--variants", f"eskf,{tmp_path / 'eskf3.yaml'}",
                                  "--trials", "2", "--out", str(out), "--no-plots"])
    assert r.exit_code == 0, r.output
    c = json.loads((out / "compare.json").read_text(encoding="utf-8"))
    assert c["trials"]["ranking"]["paired"] is False and "unpaired" in (out / "compare.md").read_text(encoding="utf-8")
