"""fusion-eval tune (issue 16): the space and objectives are checked, a study runs end to end and writes its outputs,
resumes after SIGKILL, gives the same study on the pool and on Dask, recovers a simulated drive's noise without ground
truth, and beats the default with it."""

from __future__ import annotations

import re
import csv
import json
from types import SimpleNamespace
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from conftest import make_slice, wait_for
from fusion_eval.cli import main
from fusion_eval.errors import ConfigError
from fusion_eval.tuning import objectives
from fusion_eval.tuning.space import load_space

CLI = [sys.executable, "-m", "fusion_eval"]


def _space(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "space.yaml"
    p.write_text(body)
    return p


def test_the_space_refuses_keys_that_change_the_data_and_bad_ranges(tmp_path):
    ok = load_space(_space(tmp_path, "params:\n  imu.gyro_noise_dps_sqrthz: {low: 0.01, high: 0.1, log: true}\n"
                                     "  gnss.std_m: {low: 0.5, high: 5, log: true, shape: [1, 1, 2]}\n"
                                     "fixed:\n  lidar.noise_adapt: none\n"))
    assert ok.overrides({"gnss.std_m": 2.0, "imu.gyro_noise_dps_sqrthz": 0.05}) == {
        "lidar.noise_adapt": "none", "gnss.std_m": [2.0, 2.0, 4.0], "imu.gyro_noise_dps_sqrthz": 0.05}
    for body, words in [
        ("params:\n  gnss.noise_std_m: {low: 0.1, high: 1}\n", "changes the data"),
        ("params:\n  evaluation.t_max_diff_s: {low: 0.01, high: 0.1}\n", "changes the data"),
        ("params:\n  imu.nope: {low: 0.1, high: 1}\n", "unknown configuration key 'imu.nope'"),
        ("params:\n  imu.gyro_noise_dps_sqrthz: {low: 0.0, high: 1, log: true}\n", "low > 0"),
        ("params:\n  imu.gyro_noise_dps_sqrthz: {low: 1, high: 0.1}\n", "low < high"),
        ("params:\n  imu.gyro_noise_dps_sqrthz: {low: 0.1, high: .inf}\n", "low and high must be finite numbers"),
        ("params:\n  filter.discretization: {choices: [van_loan, first_order, van_loan]}\n", "lists a value twice"),
        ("params:\n  imu.gyro_noise_dps_sqrthz: {low: 0.1, high: 1, step: 2}\n", "unknown field 'step'"),
        ("params:\n  filter.discretization: {choices: [first_order, bogus]}\n", "discretization"),
        ("params: {}\n", "'params'"),
        ("params:\n  imu.gyro_noise_dps_sqrthz: {low: 0.1, high: 1}\nfixed:\n  imu.gyro_noise_dps_sqrthz: 0.2\n",
         "both tuned and fixed"),
    ]:
        with pytest.raises(ConfigError, match=words.replace("(", r"\(")):
            load_space(_space(tmp_path, body))
    # a bad key is named by its line in the space file
    with pytest.raises(ConfigError, match=r"space.yaml:3: imu.gyro_noise_dps_sqrthz: the range must be low < high"):
        load_space(_space(tmp_path, "params:\n  imu.accel_noise_scale: {low: 0.5, high: 2}\n"
                                    "  imu.gyro_noise_dps_sqrthz: {low: 1, high: 0.1}\n"))


def test_objectives_parse_aliases_and_weighted_sums_and_name_missing_keys():
    o = objectives.parse("0.5*fused.ape.rmse+0.5*fused.rpe_100m.rmse")
    assert o.terms == ((0.5, "fused.ape.rmse"), (0.5, "fused.rpe_100m.rmse")) and o.needs_truth
    assert o.value({"fused.ape.rmse": 1.0, "fused.rpe_100m.rmse": 3.0}) == 2.0
    n = objectives.parse("nll")
    assert n.terms == ((1.0, "innovations.nll_per_update"),) and not n.needs_truth
    with pytest.raises(ConfigError, match="did you mean fused.ape.rmse"):
        objectives.parse("fused.ape.rmsee").check({"fused.ape.rmse": 1.0}, "drive")
    with pytest.raises(ConfigError, match="weighted sum"):
        objectives.parse("2*")


def _tune(args, tmp_path, **kw):
    return CliRunner().invoke(main, ["-q", "tune", *args], catch_exceptions=False, **kw)


@pytest.mark.slow
def test_a_tune_writes_a_usable_best_config_and_every_trial(tmp_path):
    ds = make_slice(tmp_path / "ds", 400)
    test = make_slice(tmp_path / "held", 300, first=600)
    out = tmp_path / "tune"
    # a base config and a --set item: best.yaml must carry them (it held only the space's keys, and a run of it
    # went back to the built-in defaults: GNSS at 1 Hz and the constraint on)
    (tmp_path / "base.yaml").write_text("gnss:\n  rate_hz: 0.5\n")
    common = ["-c", str(tmp_path / "base.yaml"), "-s", "filter.nhc=false"]
    r = _tune([str(ds), "--test", str(test), "--objective", "fused.ape.rmse", "--trials", "6", "-j", "1",
               "-o", str(out), "--no-plots", *common], tmp_path)
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((out / "trials.csv").open()))
    assert len(rows) == 6 and all(r["state"] == "COMPLETE" for r in rows)
    assert len(list((out / "trials").glob("*.json"))) == 6
    md = (out / "tune.md").read_text()
    assert re.search(r"\| held-out \(mean\) +\|", md) and "## Tuned values" in md
    assert "Tuned values" in (out / "report.html").read_text()
    best = json.loads((out / "best.json").read_text())
    assert best["values"][0] == min(float(r["fused.ape.rmse"]) for r in rows)
    assert best["test"]["status"] == "ok"
    cfg = yaml.safe_load((out / "best.yaml").read_text())
    assert cfg["gnss"]["std_scale"] > 0 and set(cfg["imu"]) == {k.split(".")[1] for k in best["params"] if k.startswith("imu.")}
    assert cfg["gnss"]["rate_hz"] == 0.5 and cfg["filter"]["nhc"] is False
    assert f"# use: fusion-eval run {ds.resolve()} -c best.yaml\n" in (out / "best.yaml").read_text()
    assert "Made by: `" in md and "generations of 4" in md and "random start-up trials" in md
    # the tuned config reproduces its trial's figure in a plain run
    run = CliRunner().invoke(main, ["-q", "run", str(ds), "-c", str(out / "best.yaml"), "--out", str(tmp_path / "r"),
                                    "--no-plots"], catch_exceptions=False)
    assert run.exit_code == 0, run.output
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["estimates"]["fused"]["ape"]["translation_m"]["rmse"] == pytest.approx(best["values"][0], rel=1e-12)
    # the same command again: nothing left to do, the same best
    r2 = _tune([str(ds), "--test", str(test), "--objective", "fused.ape.rmse", "--trials", "6", "-j", "1",
                "-o", str(out), "--no-plots", *common], tmp_path)
    assert r2.exit_code == 0 and json.loads((out / "best.json").read_text())["number"] == best["number"]


def test_a_study_is_not_resumed_with_another_space_or_objective(tmp_path):
    ds = make_slice(tmp_path / "ds", 300)
    out = tmp_path / "tune"
    assert _tune([str(ds), "--objective", "nll", "--trials", "2", "-j", "1", "-o", str(out), "--no-plots"],
                 tmp_path).exit_code == 0
    r = CliRunner().invoke(main, ["tune", str(ds), "--objective", "nis", "--trials", "2", "-j", "1", "-o", str(out)])
    assert r.exit_code == 2 and "another objectives" in r.output, r.output
    # a study whose start failed before any trial (a scheduler out of reach, a Ctrl-C while the default was scored)
    # holds nothing: it takes the new settings (it locked the folder to the old ones; a tune review)
    from fusion_eval.errors import ConfigError
    from fusion_eval.tuning import study as st

    empty = tmp_path / "empty"
    first = SimpleNamespace(out_dir=empty, space=SimpleNamespace(digest=lambda: "a"), objectives=[SimpleNamespace(name="nll")],
                            train=[str(ds)], seeds=1, base_config=None, sets=(), sampler="tpe", seed=0, n_trials=2, batch=4)
    study = st.open_study(first)
    (empty / "default.json").write_text("{}")
    second = SimpleNamespace(**{**vars(first), "objectives": [SimpleNamespace(name="nis")]})
    # while its maker lives (still scoring the default), it is refused: two studies were mixed in one folder so
    with pytest.raises(ConfigError, match="another objectives"):
        st.open_study(second)
    import socket
    import subprocess
    import sys as _sys

    gone = subprocess.run([_sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    study.set_user_attr("ident_owner", [socket.gethostname(), int(gone.stdout)])       # a process that has ended
    assert st.open_study(second).user_attrs["ident"]["objectives"] == ["nis"]
    assert not (empty / "default.json").exists()
    # a nis study scored before the objective left the constraint's pseudo-observations out is not resumed under it
    old = st.open_study(second)
    ident = dict(old.user_attrs["ident"])
    assert ident.pop("nis_definition") == "the measured streams' observations"
    old.set_user_attr("ident", ident)
    old.enqueue_trial({})          # (a trial: not an abandoned start)
    with pytest.raises(ConfigError, match="another nis definition"):
        st.open_study(second)


def test_an_objective_given_twice_is_refused(tmp_path):
    r = CliRunner().invoke(main, ["tune", "--objective", "nll", "--objective", "nll", "-o", str(tmp_path / "t")])
    assert r.exit_code == 2 and "--objective 'nll' is the objective 'nll' again" in r.output and not (tmp_path / "t").exists()
    r = CliRunner().invoke(main, ["tune", "--objective", "fused.ape.rmse", "--objective", "fused.ape.translation_m.rmse",
                                  "-o", str(tmp_path / "t")])
    assert r.exit_code == 2 and "is the objective 'fused.ape.rmse' again" in r.output


def test_an_objective_the_runs_do_not_have_is_refused_naming_it(tmp_path):
    ds = make_slice(tmp_path / "ds", 300)
    r = CliRunner().invoke(main, ["tune", str(ds), "--objective", "fused.ape.rmsx", "--trials", "2", "-j", "1",
                                  "-o", str(tmp_path / "t")])
    assert r.exit_code == 2 and "fused.ape.rmsx" in r.output and "did you mean" in r.output, r.output
    assert not (tmp_path / "t").exists()          # refused before any trial: no folder left behind
    r = CliRunner().invoke(main, ["tune", str(ds), "--objective", "foo.bar", "--trials", "2", "-j", "1",
                                  "-o", str(tmp_path / "t2")])
    assert r.exit_code == 2 and "e.g. nll, nis, fused.ape.rmse" in r.output and not (tmp_path / "t2").exists(), r.output


def _trials(out: Path) -> list[dict]:
    return list(csv.DictReader((out / "trials.csv").open()))


@pytest.mark.slow
def test_a_tune_killed_at_random_moments_resumes_and_counts_every_trial_once(tmp_path):
    import random

    ds = make_slice(tmp_path / "ds", 400)
    out = tmp_path / "tune"
    args = CLI + ["-q", "tune", str(ds), "--objective", "nll", "--trials", "16", "-j", "2", "-o", str(out), "--no-plots"]
    rng = random.Random(3)
    for _ in range(3):
        p = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
        wait_for(lambda: (out / "trials").is_dir() and len(list((out / "trials").glob("*.json"))) >= 2, 120)
        time.sleep(rng.uniform(0.2, 3.0))
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
    r = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    rows = _trials(out)
    done = [r for r in rows if r["state"] in ("COMPLETE", "PRUNED")]
    assert len(done) == 16, [(r["number"], r["state"]) for r in rows]
    assert all(r["state"] in ("COMPLETE", "PRUNED", "FAIL") for r in rows)      # nothing left running
    assert {int(r["number"]) for r in done} <= {int(f.stem) for f in (out / "trials").glob("*.json")}


@pytest.mark.slow
def test_the_pool_and_dask_give_the_same_study_with_a_fixed_seed(tmp_path):
    ds = make_slice(tmp_path / "ds", 300)
    outs = []
    # one worker or two, the pool or Dask: one study (the generations were -j's, whose default follows the cores, so
    # that a seed gave two studies on two machines: a reproducibility review)
    for name, extra in (("pool", ["-j", "2"]), ("dask", ["-j", "2", "--dask", "local"]), ("serial", ["-j", "1"])):
        out = tmp_path / name
        r = subprocess.run(CLI + ["-q", "tune", str(ds), "--objective", "fused.ape.rmse", "--trials", "8",
                                  "--seed", "5", "-o", str(out), "--no-plots", *extra],
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        outs.append([{k: v for k, v in row.items() if k != "duration_s"} for row in _trials(out)])
    assert outs[0] == outs[1] == outs[2]
    assert len({row["fused.ape.rmse"] for row in outs[0]}) > 1


def test_a_study_keeps_its_random_start_and_the_commands_that_made_it(tmp_path):
    """TPE's random start followed --trials, so a study of 10 trials extended to 20 by a second run differed from
    trial 2 on from one made for 20, and tune.md named only the last command (a reproducibility review): the start is
    fixed when the study is made, and every command is kept."""
    from fusion_eval.tuning import study as st

    s = SimpleNamespace(out_dir=tmp_path / "t", space=SimpleNamespace(digest=lambda: "a"),
                        objectives=[SimpleNamespace(name="nll")], train=["d"], seeds=1, base_config=None, sets=(),
                        sampler="tpe", seed=0, n_trials=10, batch=4)
    assert st.open_study(s).user_attrs["n_startup_trials"] == 2
    again = st.open_study(SimpleNamespace(**{**vars(s), "n_trials": 40, "batch": 2}))
    assert again.user_attrs["n_startup_trials"] == 2 and again.sampler._n_startup_trials == 2
    assert [b for _, _, b in st.commands(again)] == [4, 2]
    fresh = st.open_study(SimpleNamespace(**{**vars(s), "out_dir": tmp_path / "u", "n_trials": 40}))
    assert fresh.user_attrs["n_startup_trials"] == 8 and fresh.sampler._n_startup_trials == 8


@pytest.fixture(scope="module")
def sim_drive(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "drive"
    r = subprocess.run(CLI + ["-q", "simulate", str(out), "-d", "180", "--grade", "consumer", "--seed", "2"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return out


# the simulator's consumer grade: what the no-truth objective must find. The accelerometer's white noise is tuned
# too but not asserted: with lidar increments at 10 Hz it does not show in the data (the NLL per update moves by
# 3e-5 between 0.0006 and 0.006 m/s^2/sqrt(Hz), against 0.01-0.2 for a factor 3 in the gyro or GNSS noise).
TRUE = {"imu.gyro_noise_dps_sqrthz": 0.015, "gnss.std_m": 2.0}


@pytest.mark.slow
def test_the_no_truth_objective_recovers_the_simulated_noise_within_a_factor_of_1_5(sim_drive, tmp_path):
    space = _space(tmp_path, "params:\n"
                   "  imu.accel_noise_mps2_sqrthz: {low: 0.0003, high: 0.03, log: true}\n"
                   "  imu.gyro_noise_dps_sqrthz: {low: 0.0015, high: 0.15, log: true}\n"
                   "  gnss.std_m: {low: 0.2, high: 20, log: true, shape: [1, 1, 2]}\n")
    out = tmp_path / "tune"
    r = subprocess.run(CLI + ["-q", "tune", str(sim_drive), "--space", str(space), "--objective", "nll", "--trials",
                              "60", "-j", "2", "-o", str(out), "--no-plots"], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    best = json.loads((out / "best.json").read_text())["params"]
    for key, true in TRUE.items():
        assert true / 1.5 <= best[key] <= true * 1.5, (key, best[key], true)


@pytest.mark.slow
def test_the_truth_objective_beats_the_default_config(sim_drive, tmp_path):
    # the built-in (KITTI) noise instead of the manifest's true values: a default to beat
    base = tmp_path / "base.yaml"
    base.write_text("imu: {accel_noise_mps2_sqrthz: auto, gyro_noise_dps_sqrthz: auto}\n")
    out = tmp_path / "tune"
    r = subprocess.run(CLI + ["-q", "tune", str(sim_drive), "-c", str(base), "--objective", "fused.ape.rmse",
                              "--trials", "20", "-j", "2", "-o", str(out), "--no-plots"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    default = json.loads((out / "default.json").read_text())["train"]["values"][0]
    best = json.loads((out / "best.json").read_text())["values"][0]
    assert best < 0.95 * default, (best, default)


def test_noise_scales_multiply_the_density_the_filter_uses_and_leave_the_estimate():
    from types import SimpleNamespace

    import numpy as np

    from fusion_eval.batch import batch_key
    from fusion_eval.config import default_config
    from fusion_eval.prepare import settings_for

    cfg = default_config()
    cfg["imu"].update(accel_noise_scale=2.0, gyro_noise_scale=0.5)
    prep = SimpleNamespace(resolved={"imu": {"accel_noise_mps2_sqrthz": 0.05, "gyro_noise_dps_sqrthz": 0.1}})
    s = settings_for(cfg, prep)
    assert s.imu.accel_noise_mps2_sqrthz == pytest.approx(0.1)
    assert s.imu.gyro_noise_rps_sqrthz == pytest.approx(np.radians(0.05))
    assert prep.resolved["imu"]["accel_noise_mps2_sqrthz"] == 0.05 and cfg["imu"]["accel_noise_mps2_sqrthz"] == "auto"
    # only the filter reads them: runs that differ in them share one preparation
    plain = default_config()
    assert batch_key("d", cfg) == batch_key("d", plain)


def test_the_replay_monitor_sees_the_nll_the_metrics_report(tmp_path):
    """Over all of a replay's events, the NLL the pruning watch computes is innovations.nll_per_update."""
    from fusion_eval import session
    from fusion_eval.pipeline import filter_and_evaluate, share
    from fusion_eval.pool import Inline
    from fusion_eval.tuning.worker import nll_so_far

    ds_path = make_slice(tmp_path / "ds", 400)
    ds = session.dataset(ds_path)
    cfg = session.resolve(session.request(overrides={"output.plots": False}), ds)
    seen = []
    res = filter_and_evaluate(ds, cfg, share(ds, cfg, Inline()), Inline(),
                              monitor=lambda j, nis, ld, dof: seen.append((j, nll_so_far(nis, ld, dof[:j]), dof.size)))
    assert len(seen) > 10 and [s[0] for s in seen] == sorted(s[0] for s in seen) and seen[-1][0] == seen[-1][2]
    assert seen[-1][1] == pytest.approx(res.metrics["innovations"]["nll_per_update"], rel=1e-12)


def test_a_hopeless_trial_is_pruned_inside_the_replay(tmp_path):
    """With thresholds below any trial's NLL, the watch stops the replay at its first checkpoint: the step is
    pruned with one report and no metrics (no evaluation ran); without thresholds the same trial completes."""
    from fusion_eval.tuning import objectives as O
    from fusion_eval.tuning.worker import CHECKPOINTS, REPORTS, Job, score

    ds = str(make_slice(tmp_path / "ds", 400))
    obj = (O.parse("nll"),)
    low = tuple((i, -1e9) for i in range(REPORTS))
    pruned = score(Job(0, {}, None, (), (ds,), 1, obj, low))
    assert pruned["status"] == "pruned" and pruned["values"] is None
    st = pruned["steps"][0]
    assert st["status"] == "pruned" and len(st["checkpoints"]) == 1 and "metrics" not in st
    done = score(Job(1, {}, None, (), (ds,), 1, obj, ()))
    assert done["status"] == "ok" and len(done["steps"][0]["checkpoints"]) == len(CHECKPOINTS)
    assert done["steps"][0]["checkpoints"][0] == pytest.approx(st["checkpoints"][0], rel=1e-12)
    # a truth objective has no report inside the replay (its value needs the evaluation)
    truth = score(Job(2, {}, None, (), (ds,), 1, (O.parse("fused.ape.rmse"),), low))
    assert truth["status"] == "ok" and "checkpoints" not in truth["steps"][0]


def test_prune_thresholds_are_medians_per_report_index():
    from types import SimpleNamespace

    from fusion_eval.tuning import study as S
    from fusion_eval.tuning.worker import REPORTS

    trials = [SimpleNamespace(intermediate_values={0: float(k), REPORTS - 1: 10.0 + k}) for k in range(5)]
    fake = SimpleNamespace(get_trials=lambda deepcopy=False, states=None: trials)
    th = dict(S.prune_thresholds(fake, 2))
    assert th == {0: 2.0, REPORTS - 1: 12.0}
    assert S.prune_thresholds(SimpleNamespace(get_trials=lambda deepcopy=False, states=None: trials[:4]), 2) == ()


@pytest.mark.slow
def test_the_first_trial_is_the_default_even_where_the_default_is_auto(tmp_path):
    """An 'auto' key of the space starts from what the default run settled on (the lidar frame it chose), so trial 0
    is the default configuration; if the space cannot hold a default value and no trial beats the default, the
    report says so and best.yaml is the default itself, not a worse trial."""
    from types import SimpleNamespace

    from fusion_eval.tuning import report as R
    from fusion_eval.tuning import study as S

    space = load_space(_space(tmp_path, "params:\n  lidar.relative_frame: {choices: [body, heading, world]}\n"
                                        "  imu.gyro_noise_dps_sqrthz: {low: 0.01, high: 1, log: true}\n"
                                        "  filter.formulation: {choices: [error_state, invariant]}\n"))
    default = {"train": {"status": "ok", "values": [0.75], "steps": [{"resolved": {
        "imu_noise": {"gyro_noise_dps_sqrthz": 0.13}, "auto_settled": {"lidar.relative_frame": "body"}}}]}}
    point = S._default_point(SimpleNamespace(space=space, base_config=None, sets=(), train=["data/kitti-00"]), default)
    assert point == {"lidar.relative_frame": "body", "imu.gyro_noise_dps_sqrthz": 0.13, "filter.formulation": "error_state"}
    # an 'auto' the configuration settles for the drive itself, not in the run's record: the constraint is on for
    # kitti-00's car (trial 0 had been a sampled 'false', 0.763 m against the default's 0.795 over three seeds)
    both = load_space(_space(tmp_path, "params:\n  filter.nhc: {choices: [true, false]}\n"))
    point = S._default_point(SimpleNamespace(space=both, base_config=None, sets=(), train=["data/kitti-00"]), default)
    assert point == {"filter.nhc": True}
    # the adaptive lidar noise's 'auto' is settled by the preparation, in the run's record (nis: GNSS is fused)
    from fusion_eval import prepare, session

    ds = session.dataset("data/kitti-00")
    cfg = session.resolve(session.request(), ds)
    assert prepare.auto_settled(cfg, {}, {"gravity_mps2": 9.81})["lidar.noise_adapt"] == "nis"

    best = {"number": 7, "values": [0.82], "overrides": {"lidar.relative_frame": "world"},
            "train": {"status": "ok", "values": [0.82]}}
    res = {"default": default, "best": best}
    assert R.default_wins(res) and not R.default_wins({**res, "best": {**best, "train": {"status": "ok", "values": [0.7]}}})
    s = SimpleNamespace(out_dir=tmp_path, train=["kitti-00"], objectives=[SimpleNamespace(name="fused.ape.rmse")],
                        base_config=None, sets=(), seeds=1)
    text = R.default_yaml(s, res)
    assert "no trial" in text and "0.75" in text and "0.82" in text and yaml.safe_load(text) == {}
    # with a base config and --set items, the default is those (what trial 0 ran with)
    s.base_config, s.sets = {"filter": {"use_gnss": False}}, ("imu.gyro_noise_dps_sqrthz=0.1",)
    assert yaml.safe_load(R.default_yaml(s, res)) == {"filter": {"use_gnss": False}, "imu": {"gyro_noise_dps_sqrthz": 0.1}}
    assert "no better than the default" in R._generalisation([("training", 0.75, 0.82)])
    # the default itself best: equal, not '-0 worse' (a tune review)
    same = R._generalisation([("training", 0.75, 0.75), ("held-out", 0.5, 0.5)])
    assert "(equal to it); on the held-out drives they are the same as the default's" in same and "-0" not in same
    # equal relative gains on drives of other error levels hold (7 % on kitti-00's 0.75 m and on simple-07's 0.42 m
    # read as 'partly overfitted' by their absolute gains: a statistics review); half the share does not
    held = R._generalisation([("training", 0.75, 0.6975), ("held-out", 0.42, 0.3906)])
    assert held.startswith("The gain holds on the held-out drives: 0.0294 (7.0% of the default's)"), held
    part = R._generalisation([("training", 0.75, 0.6975), ("held-out", 0.42, 0.41)])
    assert part.startswith("Partly overfitted") and "(2.4% of the default's)" in part, part
    # an objective that may be negative (the innovations' nll) compares absolute gains
    nll = R._generalisation([("training", 1.0, 0.8), ("held-out", 0.5, 0.45)], relative=False)
    assert nll.startswith("Partly overfitted: the gain on the held-out drives (0.05)") and "%" not in nll, nll
    from fusion_eval.tuning.objectives import parse

    assert parse("fused.ape.rmse").is_error and parse("0.5*fused.ape.rmse+0.5*fused.rpe_100m.rmse").is_error
    assert not parse("nll").is_error and not parse("nis").is_error


def test_a_study_resumed_with_held_out_drives_scores_the_default_on_them(tmp_path):
    """Held-out drives given first when the study is resumed: the default is scored on them too (it was scored once,
    on the training drive, so the report compared the tuned values on the held-out drives with nothing)."""
    ds = make_slice(tmp_path / "ds", 300)
    held = make_slice(tmp_path / "held", 300, first=600)
    out = tmp_path / "tune"
    args = [str(ds), "--objective", "fused.ape.rmse", "--trials", "2", "-j", "1", "-o", str(out), "--no-plots"]
    assert _tune(args, tmp_path).exit_code == 0
    assert json.loads((out / "default.json").read_text())["test"] is None
    r = _tune(args + ["--test", str(held)], tmp_path)
    assert r.exit_code == 0, r.output
    default = json.loads((out / "default.json").read_text())
    assert default["test"]["status"] == "ok" and {st["dataset"] for st in default["test"]["steps"]} == {str(held.resolve())}
    assert re.search(r"\| held-out \(mean\) +\| +[0-9.]+ +\| +[0-9.]+ +\|", (out / "tune.md").read_text())


@pytest.mark.slow
def test_the_first_trial_is_the_default_run_with_the_manifests_suggested_settings(tmp_path):
    """Trial 0 took the built-in values where a simulated drive's manifest suggests its datasheet noise (0.7025 against
    the default run's 0.7165), and tune.md called the tuned values the default's while its own table moved (a
    corrupted-input review): the default is the drive's resolved configuration."""
    import csv
    import json

    from click.testing import CliRunner

    from fusion_eval.cli import main
    from fusion_eval.simulate.dataset import simulate

    simulate(tmp_path / "s", "urban", 40.0, 0, "automotive", (), jobs=1)
    assert "accel_bias_rw_mps3_sqrthz: 3.0e-05" in (tmp_path / "s" / "dataset.yaml").read_text()
    r = CliRunner().invoke(main, ["tune", str(tmp_path / "s"), "--objective", "fused.ape.rmse", "--trials", "1",
                                  "--out", str(tmp_path / "t"), "--no-plots", "--jobs", "1"])
    assert r.exit_code == 0, r.output
    (row,) = list(csv.DictReader(open(tmp_path / "t" / "trials.csv")))
    assert float(row["imu.accel_bias_rw_mps3_sqrthz"]) == 3e-05
    default = json.loads((tmp_path / "t" / "default.json").read_text())
    assert float(row["fused.ape.rmse"]) == pytest.approx(default["train"]["values"][0], abs=1e-9)
    assert "| imu.accel_bias_rw_mps3_sqrthz |     3e-05 |" in (tmp_path / "t" / "tune.md").read_text()


def test_an_objective_no_tuned_key_moves_is_said(kitti_slice, tmp_path):
    """--objective gnss.ape.rmse ran every trial at one value and tune.md suggested more trials (a corrupted-input
    review): it says that no key of the space moves the objective."""
    from click.testing import CliRunner

    from fusion_eval.cli import main

    r = CliRunner().invoke(main, ["tune", str(kitti_slice), "--objective", "gnss.ape.rmse", "--trials", "3",
                                  "--out", str(tmp_path / "t"), "--no-plots", "--jobs", "1", "--no-prune"])
    assert r.exit_code == 0, r.output
    text = (tmp_path / "t" / "tune.md").read_text()
    assert "Every one of the 3 complete trials scored the same objective" in text and "no key of the space" in text


def test_a_running_trial_without_an_owner_is_run_again_once_it_is_stale(monkeypatch):
    """A Ctrl-C inside study.ask(), before the trial had its owner, left it running for good (the default
    configuration's trial, once; a tune review). The ask is now shielded from the signal; a trial left so by an
    older study is run again once it is a minute old, not while another process may be giving it its owner."""
    import optuna

    from fusion_eval.tuning import study as st

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    s = optuna.create_study()
    t = s.ask({"x": optuna.distributions.FloatDistribution(0.0, 1.0)})
    assert st._requeue_stale(s) == 0                                    # just asked: another process's, maybe
    monkeypatch.setattr(st, "OWNERLESS_STALE_S", -1.0)
    assert st._requeue_stale(s) == 1
    states = [x.state for x in s.get_trials(deepcopy=False)]
    assert states == [optuna.trial.TrialState.FAIL, optuna.trial.TrialState.WAITING]
    assert s.get_trials(deepcopy=False)[1].system_attrs["fixed_params"] == {"x": t.params["x"]}   # run again as it was


def test_a_worker_killed_is_one_line_not_a_traceback(monkeypatch, tmp_path):
    """kill -9 of a pool worker (what the OOM killer does) ended a tune in a BrokenProcessPool traceback (a tune
    review)."""
    from concurrent.futures.process import BrokenProcessPool

    from click.testing import CliRunner

    from fusion_eval.cli import main
    from fusion_eval.commands import run as run_cmd

    def broken(*a, **k):
        raise BrokenProcessPool("A process in the process pool was terminated abruptly")

    monkeypatch.setattr(run_cmd, "run_to_dir", broken)
    r = CliRunner().invoke(main, ["run", "--out", str(tmp_path / "o")])
    assert r.exit_code == 1, r.output
    assert r.output.strip().splitlines()[-1].startswith("error: a worker process of this command died")


def test_two_survivors_requeue_a_dead_trial_once_without_failing(tmp_path):
    """Two processes sharing a study each requeued a killed one's trial at a generation's start: the second's update
    of the trial the first had failed raised UpdateFinishedTrialError and ended that tune (a review of the diff)."""
    import socket

    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    from fusion_eval.tuning import study as st

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    path = str(tmp_path / "j.journal")
    a = optuna.create_study(study_name="s", storage=JournalStorage(JournalFileBackend(path)))
    t = a.ask({"x": optuna.distributions.FloatDistribution(0.0, 1.0)})
    t.set_user_attr("owner", [socket.gethostname(), 2 ** 22 + 12345])          # a pid no process has
    b = optuna.load_study(study_name="s", storage=JournalStorage(JournalFileBackend(path)))
    stale_b = b.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))   # b's view, before a requeues
    assert st._requeue_stale(a) == 1
    b.get_trials = lambda deepcopy=False, states=None: stale_b                  # b acts on what it had seen
    assert st._requeue_stale(b) == 0


def test_a_two_objective_studys_report_compares_both_objectives(tmp_path):
    """tune.md's default-against-tuned table gave the first objective only in a two-objective study (a tune review)."""
    ds = make_slice(tmp_path / "ds", 300)
    out = tmp_path / "t"
    r = _tune([str(ds), "--objective", "fused.ape.rmse", "--objective", "nll", "--trials", "2", "-j", "1", "-o", str(out),
               "--no-plots"], tmp_path)
    assert r.exit_code == 0, r.output
    md = (out / "tune.md").read_text()
    head = next(ln for ln in md.splitlines() if ln.startswith("| drives"))
    assert all(c in head for c in ("fused.ape.rmse (default)", "fused.ape.rmse (tuned)", "nll (default)", "nll (tuned)"))


def test_a_journal_that_cannot_be_written_is_named(tmp_path, monkeypatch):
    """A full disk under Optuna's journal ended a tune with "error: No space left on device", naming no file (a
    failure-injection review): the journal is named, in one line."""
    from fusion_eval.tuning import study as st

    def full(*_a, **_k):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(st, "_tell", full)
    ds = make_slice(tmp_path / "ds", 300)
    out = tmp_path / "tune"
    r = _tune([str(ds), "--objective", "fused.ape.rmse", "--trials", "2", "-j", "1", "-o", str(out), "--no-plots"],
              tmp_path)
    assert r.exit_code == 2 and f"{out / 'study.journal'}: cannot write (No space left on device)" in r.stderr, r.output


def test_a_signal_among_the_tells_keeps_the_journal_and_says_so(tmp_path, monkeypatch):
    """A Ctrl-C between two trials' tells met a told trial in the clean-up, whose update Optuna refuses: the command
    said 'no output directory was written' beside a kept journal (an interruption review). Each tell is whole."""
    import os
    import signal

    from fusion_eval.tuning import study as st

    real, calls = st._tell, []

    def tell_then_ctrl_c(*a, **k):
        real(*a, **k)
        calls.append(1)
        if len(calls) == 3:                     # the first of the second generation's tells: a Ctrl-C arrives
            os.kill(os.getpid(), signal.SIGINT)
    monkeypatch.setattr(st, "_tell", tell_then_ctrl_c)
    ds = make_slice(tmp_path / "ds", 300)
    out = tmp_path / "tune"
    r = CliRunner().invoke(main, ["-q", "tune", str(ds), "--objective", "fused.ape.rmse", "--trials", "6", "--batch",
                                  "2", "-j", "1", "-o", str(out), "--no-plots"])
    assert r.exit_code == 130 and "3 of 6 trials are kept" in r.output and "study.journal" in r.output, r.output
    r = _tune([str(ds), "--objective", "fused.ape.rmse", "--trials", "6", "--batch", "2", "-j", "1", "-o", str(out),
               "--no-plots"], tmp_path)
    assert r.exit_code == 0 and len(list((out / "trials").glob("*.json"))) >= 6, r.output
