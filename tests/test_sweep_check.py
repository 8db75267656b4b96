"""fusion-eval sweep (process pool and Dask, resume, failures) and fusion-eval check (exit codes, rules)."""

from __future__ import annotations

import re
import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import lock_held_elsewhere
from fusion_eval.cli import main

SETTINGS = """
variants: [eskf]
settings:
  a: {imu.gyro_noise_dps_sqrthz: 0.05}
  b: {imu.gyro_noise_dps_sqrthz: 0.2}
  c: {lidar.relative_pos_std_frac: 0.005}
  d: {lidar.relative_pos_std_frac: 0.02}
  e: {gnss.std_m: [0.5, 0.5, 1.0]}
"""


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    from conftest import make_slice

    return make_slice(tmp_path_factory.mktemp("sw") / "short", 300)


def _sweep_file(tmp_path: Path, extra: str = "") -> Path:
    p = tmp_path / "sweep.yaml"
    p.write_text(SETTINGS + extra)
    return p


def _rows(out: Path) -> dict:
    return {r["setting"]: r for r in csv.DictReader((out / "sweep.csv").read_text().splitlines())}


@pytest.mark.slow
def test_sweep_process_pool_and_dask_give_identical_metrics(small, tmp_path):
    sw = _sweep_file(tmp_path)
    a, b = tmp_path / "pool", tmp_path / "dask"
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(a), "--jobs", "2"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(b), "--dask", "local", "--jobs", "2"])
    assert r.exit_code == 0, r.output
    ra, rb = _rows(a), _rows(b)
    assert set(ra) == {"default", "a", "b", "c", "d", "e"} and all(v["status"] == "ok" for v in ra.values())
    for k in ra:
        assert ra[k]["fused_ape_trans_rmse_m"] == rb[k]["fused_ape_trans_rmse_m"] != ""
        assert ra[k]["id"] == rb[k]["id"]
    md = (a / "sweep.md").read_text()
    assert re.search(r"\|\s*1\s*\|", md) and "Best:" in md and (a / "best.yaml").exists() and (a / "sweep_params.png").exists()
    assert "data:image/png;base64," in (a / "report.html").read_text()
    # the runs' outputs are those of `fusion-eval run`
    rid = ra["a"]["id"]
    assert (a / "runs" / rid / "metrics.json").exists() and (a / "runs" / rid / "fused.tum").exists()
    # a summary without plots leaves none of an earlier one's (they read as this one's; a failure-injection review)
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(a), "--summarize-only",
                                  "--no-plots"])
    assert r.exit_code == 0, r.output
    assert not list(a.glob("*.png")) and "sweep_params.png" not in (a / "sweep.md").read_text()


@pytest.mark.slow
def test_diverging_setting_is_recorded_as_diverged_and_the_rest_finish(small, tmp_path):
    sw = _sweep_file(tmp_path, "  boom: {init.vel_std_mps: 1.0e+11, init.pos_std_m: 1.0e+11}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1"])
    assert r.exit_code == 0, r.output
    rows = _rows(out)
    assert rows["boom"]["status"] == "diverged" and "diverged" in rows["boom"]["error"]
    assert sum(v["status"] == "ok" for v in rows.values()) == 6
    md = (out / "sweep.md").read_text()
    assert "## Diverged runs" in md and "1 diverged, 0 failed" in md


def test_a_second_sweep_into_a_running_sweeps_folder_is_refused(small, tmp_path):
    """Two sweeps into one folder each ran what the other had not recorded yet, and replaced each other's finished
    runs (a run's own lock only made the second wait): the second is refused while the first lives; a killed one's
    lock is taken over (test_interrupted_sweep_resumes_without_losing_runs)."""
    sw = _sweep_file(tmp_path)
    out = tmp_path / "s"
    out.mkdir()
    (out / "records").mkdir()
    with lock_held_elsewhere(out / ".sweep.lock") as holder:
        r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1"])
        assert r.exit_code == 2 and f"another fusion-eval sweep (pid {holder.pid}) is running in this folder" in r.stderr
        assert "\n" not in r.stderr.strip() and not list((out / "records").iterdir()) and not (out / "runs").exists()
        assert (out / ".sweep.lock").exists()              # the holder's lock is left to it


@pytest.mark.slow
def test_interrupted_sweep_resumes_without_losing_runs(small, tmp_path):
    sw = _sweep_file(tmp_path)
    out = tmp_path / "s"
    cmd = [sys.executable, "-m", "fusion_eval", "-q", "sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1"]
    proc = subprocess.Popen(cmd, start_new_session=True)
    deadline = time.time() + 240
    while time.time() < deadline and len(list((out / "records").glob("*.json"))) < 2:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)          # a hard kill, mid-run
    proc.wait()
    before = {p.name: p.read_bytes() for p in (out / "records").glob("*.json")}
    assert 2 <= len(before) < 6
    from fusion_eval.commands.sweep import plan

    ids = {t.id for t in plan(sw, [str(small)], out)[0]}
    assert {n[:-5] for n in before} <= ids, (sorted(before), sorted(ids))   # the same runs, planned in this process
    r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1"])
    assert r.exit_code == 0, r.output
    assert f"{len(before)} already recorded" in r.output
    after = {p.name: p.read_bytes() for p in (out / "records").glob("*.json")}
    assert len(after) == 6 and all(after[k] == v for k, v in before.items())
    assert all(v["status"] == "ok" for v in _rows(out).values())
    assert not list((out / "runs").glob(".*partial*"))


def _metrics(tmp_path: Path, name: str, scale: float) -> Path:
    m = {"estimates": {"fused": {"ape": {"translation_m": {"rmse": 1.0 * scale, "max": 3.0}}},
                       "lidar": {"ape": {"translation_m": {"rmse": 7.0}}}},
         "ratios": {"fused_over_lidar": scale / 7.0}}
    p = tmp_path / name
    p.write_text(json.dumps(m))
    return p


def test_check_exit_codes_and_rules(tmp_path):
    base = _metrics(tmp_path, "base.json", 1.0)
    same = _metrics(tmp_path, "same.json", 1.01)
    worse = _metrics(tmp_path, "worse.json", 1.2)
    run = CliRunner().invoke
    r = run(main, ["check", str(same), "--baseline", str(base), "--rtol", "0.05", "--junit", str(tmp_path / "j.xml")])
    assert r.exit_code == 0, r.output
    assert 'failures="0"' in (tmp_path / "j.xml").read_text() and (tmp_path / "check.md").exists()
    r = run(main, ["check", str(worse), "--baseline", str(base), "--rtol", "0.05", "--junit", str(tmp_path / "j.xml")])
    assert r.exit_code == 1 and "REGRESSION" in r.output
    assert 'failures="2"' in (tmp_path / "j.xml").read_text()
    r = run(main, ["check", str(worse), "--baseline", str(base), "--rtol", "0.5"])
    assert r.exit_code == 0
    r = run(main, ["check", str(same), "--baseline", str(base), "--require", "fused.ape.rmse < lidar.ape.rmse",
                   "--require", "fused.ape.translation_m.max <= 3"])
    assert r.exit_code == 0 and "holds" in r.output
    r = run(main, ["check", str(same), "--baseline", str(base), "--require", "fused.ape.rmse > 2"])
    assert r.exit_code == 1 and "FAILS" in r.output
    (tmp_path / "bad.json").write_text("{not json")
    r = run(main, ["check", str(tmp_path / "bad.json"), "--baseline", str(base)])
    assert r.exit_code == 2 and "bad.json:1: not valid JSON" in r.stderr
    for rule in ("fused.ape.rmse <", "__import__('os') < 1", "nope.x < 1", "fused.ape.rmse < nan", "fused.ape.rmse < inf"):
        r = run(main, ["check", str(same), "--baseline", str(base), "--require", rule])
        assert r.exit_code == 2, (rule, r.output)
    r = run(main, ["check", str(worse), "--baseline", str(tmp_path / "nb.json"), "--update-baseline"])
    assert r.exit_code == 0 and (tmp_path / "nb.json").read_text() == worse.read_text()


@pytest.mark.parametrize("value,needle", [(None, "has no value for it"), (float("nan"), "holds nan there"),
                                          ("fast", "holds 'fast' there")])
def test_check_refuses_a_baseline_lacking_a_gated_metric(tmp_path, value, needle):
    """A baseline without the gated estimate, or with NaN or a string there, would let anything pass: exit 2."""
    cur = _metrics(tmp_path, "cur.json", 1.0)
    body = json.loads(cur.read_text())
    if value is None:
        del body["estimates"]["fused"]
    else:
        body["estimates"]["fused"]["ape"]["translation_m"]["rmse"] = value
    (tmp_path / "base.json").write_text(json.dumps(body))
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(tmp_path / "base.json")])
    assert r.exit_code == 2 and needle in r.stderr and "fused.ape" in r.stderr and "Traceback" not in r.output


def test_check_tolerance_is_the_sum_of_atol_and_rtol_and_its_edge_passes(tmp_path):
    """current > baseline + atol + rtol |baseline| regresses; at the edge it passes (the README's rule; a mutation
    review found neither the sum nor the edge held by a test)."""
    base = _metrics(tmp_path, "base.json", 1.0)
    edge = _metrics(tmp_path, "edge.json", 1.25)          # exact in binary: 1.0 + 0.25
    both = _metrics(tmp_path, "both.json", 1.4)           # within 0.25 + 0.25 x 1.0, beyond either alone
    run = CliRunner().invoke
    r = run(main, ["check", str(edge), "-b", str(base), "--atol", "0.25", "--rtol", "0", "--summary", str(tmp_path / "c.md")])
    assert r.exit_code == 0, r.output
    r = run(main, ["check", str(both), "-b", str(base), "--atol", "0.25", "--rtol", "0.25", "--summary", str(tmp_path / "c.md")])
    assert r.exit_code == 0, r.output
    r = run(main, ["check", str(both), "-b", str(base), "--atol", "0.25", "--rtol", "0", "--summary", str(tmp_path / "c.md")])
    assert r.exit_code == 1 and "REGRESSION" in r.output, r.output


def test_check_accepts_a_sweep_csv(tmp_path):
    cols = "id,dataset,variant,setting,fused_ape_trans_rmse_m,fused_ape_rot_rmse_deg,fused_rpe_1frame_trans_rmse_m,status,error\n"
    (tmp_path / "b.csv").write_text(cols + "x,d,eskf,default,1.0,0.5,0.1,ok,\n")
    (tmp_path / "c.csv").write_text(cols + "x,d,eskf,default,1.5,0.5,0.1,ok,\n")
    r = CliRunner().invoke(main, ["check", str(tmp_path / "c.csv"), "--baseline", str(tmp_path / "b.csv")])
    assert r.exit_code == 1 and "d/eskf/default.fused_ape_trans_rmse_m" in r.output
    # a second row of one run let the last win: a regressed first row passed (a corrupted-input review)
    (tmp_path / "dup.csv").write_text(cols + "x,d,eskf,default,1.5,0.5,0.1,ok,\nx,d,eskf,default,1.0,0.5,0.1,ok,\n")
    r = CliRunner().invoke(main, ["check", str(tmp_path / "dup.csv"), "--baseline", str(tmp_path / "b.csv")])
    assert r.exit_code == 2 and "dup.csv:3: a second row for dataset d, variant eskf, setting default (the first at " \
                                "line 2)" in r.stderr, r.output
    # a per-trial file (sweep_trials.csv): each trial is its own metric, so a regressed trial 0 fails (the last trial's
    # row stood for every one: a review)
    tcols = "trial," + cols
    (tmp_path / "bt.csv").write_text(tcols + "0,x,d,eskf,default,1.0,0.5,0.1,ok,\n1,x,d,eskf,default,1.1,0.5,0.1,ok,\n")
    (tmp_path / "ct.csv").write_text(tcols + "0,x,d,eskf,default,1.5,0.5,0.1,ok,\n1,x,d,eskf,default,1.1,0.5,0.1,ok,\n")
    r = CliRunner().invoke(main, ["check", str(tmp_path / "ct.csv"), "--baseline", str(tmp_path / "bt.csv")])
    assert r.exit_code == 1 and "d/eskf/default#trial0.fused_ape_trans_rmse_m" in r.output, r.output
    # a swept setting's column is an input, not a figure: -m '*' gated it as if lower were better (a review)
    scols = "id,dataset,variant,setting,imu.gyro_noise_scale,fused_ape_trans_rmse_m,status,error\n"
    (tmp_path / "bs.csv").write_text(scols + "x,d,eskf,s1,1.0,1.0,ok,\n")
    (tmp_path / "cs.csv").write_text(scols + "x,d,eskf,s1,2.0,1.0,ok,\n")
    r = CliRunner().invoke(main, ["check", str(tmp_path / "cs.csv"), "--baseline", str(tmp_path / "bs.csv"), "-m", "*"])
    assert r.exit_code == 0 and "gyro_noise_scale" not in r.output and "fused_ape_trans_rmse_m" in r.output, r.output


def test_check_gives_its_verdict_where_its_summary_cannot_be_written_beside_the_metrics(tmp_path):
    """A run folder on a read-only share: check exited 2 with no verdict, naming its temporary file (a
    failure-injection review). The default summary is best effort; one asked for with --summary is not."""
    base = _metrics(tmp_path, "base.json", 1.0)
    same = _metrics(tmp_path, "same.json", 1.01)
    (tmp_path / "check.md").mkdir()                          # in the way of the summary, as a read-only folder is
    r = CliRunner().invoke(main, ["check", str(same), "-b", str(base)])
    assert r.exit_code == 0 and "no check.md written" in r.stderr and "ok" in r.stdout, r.output
    r = CliRunner().invoke(main, ["check", str(same), "-b", str(base), "--summary", str(tmp_path / "check.md")])
    assert r.exit_code == 2 and "cannot write" in r.stderr


def test_a_seed_swept_as_a_setting_is_refused(small, tmp_path):
    """gnss.seed 3 as a 'setting' ranked first at 0.631 m against the default's 0.753 and went into best.yaml (a
    statistics review): a seed is averaged over with --trials, not ranked."""
    grid = tmp_path / "g.yaml"
    grid.write_text("settings:\n  lucky: {gnss.seed: 3}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(grid), "--out", str(out)])
    assert r.exit_code == 2 and "gnss.seed is swept, but a seed is not a setting to rank" in r.stderr, r.output
    assert "--trials N" in r.stderr and not out.exists()
    # a variant file that sets its own seed is the same ranking on a seed (0.347 against 0.323 m, 7 %, no word: a
    # diff review)
    (tmp_path / "eskf3.yaml").write_text("gnss:\n  seed: 3\n")
    grid.write_text(f"variants: [eskf, {tmp_path / 'eskf3.yaml'}]\nsettings:\n  a: {{imu.gyro_noise_dps_sqrthz: 0.01}}\n")
    r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(grid), "--out", str(out)])
    assert r.exit_code == 2 and "eskf3.yaml' setting 'default' draws its random elements with other seeds (gnss.seed=3" \
        in r.stderr, r.output
    assert not out.exists()


@pytest.mark.parametrize("command", ["sweep", "tune"])
def test_a_scheduler_nobody_answers_leaves_no_folder(small, tmp_path, monkeypatch, command):
    """One line naming the option, and no empty folder (its own lock file once counted as a record: a diff review);
    tune said only Dask's "Timed out trying to connect to ..." (both now go through pool.dask_client)."""
    import dask.distributed

    def nobody(*_a, **_k):
        raise OSError("Timed out trying to connect")
    monkeypatch.setattr(dask.distributed, "Client", nobody)
    out = tmp_path / "s"
    how = ["--grid", str(_sweep_file(tmp_path))] if command == "sweep" else ["--objective", "nll", "--trials", "2"]
    r = CliRunner().invoke(main, [command, str(small), *how, "--out", str(out), "--scheduler", "tcp://127.0.0.1:9"])
    assert r.exit_code == 2 and "--scheduler tcp://127.0.0.1:9: no Dask scheduler answers there" in r.stderr, r.output
    assert not out.exists()


def test_check_tolerances_per_metric_pattern(tmp_path):
    """One --atol across metres, degrees and ratios was a CI user's complaint: PATTERN=VALUE sets the tolerance of the
    metrics a glob matches (the last match wins), a bare value every other's; a pattern matching nothing is refused."""
    base = _metrics(tmp_path, "base.json", 1.0)
    worse = _metrics(tmp_path, "worse.json", 1.2)        # fused APE +0.2 m, ratio +0.029
    run = CliRunner().invoke
    r = run(main, ["check", str(worse), "-b", str(base), "--rtol", "0", "--atol", "0.25"])
    assert r.exit_code == 0, r.output
    r = run(main, ["check", str(worse), "-b", str(base), "--rtol", "0", "--atol", "0.25", "--atol", "ratios.*=0.01"])
    assert r.exit_code == 1 and "ratios.fused_over_lidar" in r.output and r.output.count("REGRESSION") == 1, r.output
    assert "atol 0.25, 0.01 for `ratios.*`" in (tmp_path / "check.md").read_text()
    for order, code in ((("fused.ape.*=0.1", "fused.*=0.3"), 0), (("fused.*=0.3", "fused.ape.*=0.1"), 1)):
        r = run(main, ["check", str(worse), "-b", str(base), "--rtol", "0.5", "--rtol", order[0], "--rtol", order[1]])
        assert r.exit_code == code, (order, r.output)                 # the last matching pattern wins: +20 % in APE
    r = run(main, ["check", str(worse), "-b", str(base), "--atol", "fused.ap.*=0.05"])
    assert r.exit_code == 2 and "'fused.ap.*' matches none of the compared metrics" in r.stderr, r.output
    for bad in ("-1", "x=nan", "abc"):
        r = run(main, ["check", str(worse), "-b", str(base), "--atol", bad])
        assert r.exit_code == 2 and "expected a finite number >= 0, or PATTERN=NUMBER" in r.stderr, (bad, r.output)
    from fusion_eval.commands.check import Tolerance, check

    assert Tolerance.parse("--atol", ("0.1", "a*=2", "ab*=3"), 0.0).of("abc") == 3.0
    assert check(worse, base, rtol=0.5, atol=0.0).ok          # the API still takes plain numbers
    import numpy as np

    assert check(worse, base, rtol="0.5").ok and check(worse, base, rtol=np.float32(0.5)).ok   # one value, any type
    from fusion_eval.commands.check import compare_metrics, load_metrics

    cur, base_m = load_metrics(_metrics(tmp_path, "same2.json", 1.01), None)[0], load_metrics(base, None)[0]
    assert [r.verdict for r in compare_metrics(cur, base_m, ("fused.ape.rmse",), (), ())] == ["ok"]  # +1 %: 0.05 as check()


def test_check_matches_a_sweep_csv_made_in_another_folder_by_dataset_name(tmp_path):
    """A sweep records each dataset's absolute path; a baseline made in another checkout (CI's workspace) must still
    match, and rules name the dataset as sweep.md does. Two datasets of one name at two paths keep their paths."""
    cols = "id,dataset,variant,setting,fused_ape_trans_rmse_m,status,error\n"
    (tmp_path / "b.csv").write_text(cols + "x,/ci/a/data/kitti-00,eskf,default,1.0,ok,\n")
    (tmp_path / "c.csv").write_text(cols + "x,/home/me/data/kitti-00,eskf,default,1.5,ok,\n")
    r = CliRunner().invoke(main, ["check", str(tmp_path / "c.csv"), "--baseline", str(tmp_path / "b.csv")])
    assert r.exit_code == 1 and "kitti-00/eskf/default.fused_ape_trans_rmse_m" in r.output and "/home" not in r.output
    r = CliRunner().invoke(main, ["check", str(tmp_path / "c.csv"), "-b", str(tmp_path / "b.csv"), "--rtol", "1",
                                  "--require", "kitti-00/eskf/default.fused_ape_trans_rmse_m < 2"])
    assert r.exit_code == 0, r.output
    # rules and patterns in the path-style keys of before still work (aliases)
    r = CliRunner().invoke(main, ["check", str(tmp_path / "c.csv"), "-b", str(tmp_path / "c.csv"), "-m", "/home/me/data/*",
                                  "--require", "/home/me/data/kitti-00/eskf/default.fused_ape_trans_rmse_m < 2"])
    assert r.exit_code == 0 and "kitti-00/eskf/default.fused_ape_trans_rmse_m" in r.output, r.output
    # a manifest file is named by its stem, a folder's dataset.yaml by the folder
    from fusion_eval.resources import dataset_label

    assert [dataset_label(p) for p in ("/a/configs/datasets/simple-00.yaml", "/a/sims/urban/dataset.yaml", "/a/kitti-00")] \
        == ["simple-00", "urban", "kitti-00"]
    (tmp_path / "two.csv").write_text(cols + "x,/p/kitti-00,eskf,default,1.0,ok,\ny,/q/kitti-00,eskf,default,2.0,ok,\n")
    r = CliRunner().invoke(main, ["check", str(tmp_path / "two.csv"), "-b", str(tmp_path / "two.csv"), "--require",
                                  "/q/kitti-00/eskf/default.fused_ape_trans_rmse_m > /p/kitti-00/eskf/default.fused_ape_trans_rmse_m"])
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("body,needle", [
    ("random: 5\n", "'random' must be"),
    ("settings: [a, b]\n", "'settings' must be"),
    ("random: {n: abc, ranges: {imu.gyro_noise_dps_sqrthz: [0.01, 1]}}\n", "integer n > 0"),
    ("random: {n: 3, ranges: {imu.gyro_noise_dps_sqrthz: [0.01]}}\n", "[low, high]"),
    ("variants: eskf\nsettings: {a: {imu.gyro_noise_dps_sqrthz: 0.1}}\n", "'variants' must be a list"),
    ("plots: 'no'\nsettings: {a: {imu.gyro_noise_dps_sqrthz: 0.1}}\n", "'plots' must be true or false"),
    ("settings: {a: {imu.nope: 1}}\n", "unknown configuration key"),
    # found by corrupting sweep files: each names its line now, and a sweep too large to plan is refused (a 400^3
    # grid and random n = 1e9 once ran for minutes with no output)
    ("grid:\n  imu.gyro_noise_dps_sqrthz: [0.1, -1]\n", "bad.yaml:2: imu.gyro_noise_dps_sqrthz must be >= 0"),
    ("grid:\n  imu.gyro_noise_dps_sqrthz: [0.1, 0.1]\n", "bad.yaml:2: grid key 'imu.gyro_noise_dps_sqrthz' lists a value twice"),
    ("random:\n  n: 1000000000\n  ranges: {imu.gyro_noise_dps_sqrthz: [0.01, 1]}\n", "bad.yaml:2: random n=1,000,000,000 is more than"),
    ("grid:\n  imu.gyro_noise_dps_sqrthz: [" + ", ".join(f"{0.01 * (i + 1):g}" for i in range(400)) + "]\n"
     "  imu.accel_noise_mps2_sqrthz: [" + ", ".join(f"{0.01 * (i + 1):g}" for i in range(400)) + "]\n",
     "the sweep has 160,000 settings, more than 100,000 (a grid of 400 x 400)"),
    ("random:\n  n: 3\n  ranges:\n    imu.gyro_noise_dps_sqrthz: [1.0, 0.01]\n", "bad.yaml:4: random range of"),
    ("random:\n  n: 3\n  ranges:\n    filter.formulation: [0.1, 1]\n", "bad.yaml:4: 'filter.formulation' takes one of"),
    # a blank or non-text entry was a traceback (found by a corrupted-input review)
    ("variants:\n  - eskf\n  -\n  - nominal\nsettings: {a: {imu.gyro_noise_dps_sqrthz: 0.1}}\n",
     "bad.yaml:1: every entry of 'variants' must be a variant name or YAML path, got None"),
    ("variants: [5]\nsettings: {a: {imu.gyro_noise_dps_sqrthz: 0.1}}\n", "got 5"),
    # an empty value was null, as in a configuration file once (found by a review of the diff)
    ("settings:\n  lowrate:\n    gnss.rate_hz:\n", "bad.yaml:3: gnss.rate_hz has no value (write null for null)"),
    ("settings: {lowrate: {gnss.rate_hz: }}\n", "gnss.rate_hz has no value"),
])
def test_malformed_sweep_files_are_one_line_errors(small, tmp_path, body, needle):
    sw = tmp_path / "bad.yaml"
    sw.write_text(body)
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and needle in r.stderr and "\n" not in r.stderr.strip(), r.output


@pytest.mark.slow
def test_best_yaml_is_a_configuration_run_accepts(small, tmp_path):
    sw = tmp_path / "s.yaml"
    sw.write_text("variants: [nominal]\nsettings:\n  a: {imu.gyro_noise_dps_sqrthz: 0.05}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["-q", "run", str(small), "-c", str(out / "best.yaml"), "--no-plots", "--out",
                                  str(tmp_path / "r")])
    assert r.exit_code == 0, r.output
    cfg = (tmp_path / "r" / "config.resolved.yaml").read_text()
    assert "formulation: nominal_state" in cfg        # the variant's own settings are in best.yaml
    # its hint names the dataset the figure is of (`run -c best.yaml` ran kitti-00: a reproducibility review)
    assert f"# use it as: fusion-eval run {small} -c best.yaml\n" in (out / "best.yaml").read_text(encoding="utf-8")
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(tmp_path / "none"),
                                  "--summarize-only"])
    assert r.exit_code == 2 and "no sweep records" in r.stderr


def test_grid_random_and_named_settings_are_planned(small, tmp_path):
    """Every kind of setting of a sweep file, checked against the schema (the shipped grid2d among them)."""
    from fusion_eval import resources
    from fusion_eval.commands.sweep import load_sweep, plan, settings_of

    sw = tmp_path / "all.yaml"
    sw.write_text("settings:\n  a: {imu.gyro_noise_dps_sqrthz: 0.05}\n"
                  "grid:\n  imu.gyro_noise_dps_sqrthz: [0.03, 0.3]\n  lidar.relative_pos_std_frac: [0.003, 0.03]\n"
                  "random: {n: 3, seed: 1, ranges: {imu.accel_noise_mps2_sqrthz: [0.1, 1.0]}}\n")
    names = [n for n, _ in settings_of(load_sweep(sw), str(sw))]
    assert names[:2] == ["default", "a"] and len(names) == 1 + 1 + 4 + 3 and names[-1] == "random-002"
    assert "imu.gyro_noise_dps_sqrthz=0.03,lidar.relative_pos_std_frac=0.003" in names
    tasks, body = plan(resources.sweep_file("grid2d"), [str(small)], tmp_path / "o")
    assert len(tasks) == 10 and {t.setting for t in tasks} >= {"default", "imu.gyro_noise_dps_sqrthz=0.3,lidar.relative_pos_std_frac=0.03"}
    bad = tmp_path / "bad.yaml"
    bad.write_text("grid:\n  imu.nope: [1, 2]\n")
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(bad), "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "unknown configuration key 'imu.nope'" in r.stderr


@pytest.mark.slow
def test_batched_sweep_equals_runs_made_one_by_one(small, tmp_path, monkeypatch):
    """Runs that differ only in filter settings share one preparation; their records and files are those of
    runs made alone (and the GNSS setting, which the preparation reads, is a batch of its own)."""
    from fusion_eval.commands.sweep import batches, plan

    # the reports' header carries the minute of the run: fixed, so that two sweeps across a minute's turn compare
    # equal byte for byte (it failed in CI once, 15:22 against 15:23)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")

    sw = _sweep_file(tmp_path)
    tasks = plan(sw, [str(small)], tmp_path / "x")[0]
    groups = batches(tasks, 1)
    by_setting = {t.setting: len(g) for g in groups for t in g}
    # a, b give the gyro density; default, c, d leave it 'auto' (estimated by the preparation): two batches
    assert by_setting["a"] == by_setting["b"] == 2 and by_setting["default"] == by_setting["d"] == 3
    assert by_setting["e"] == 1
    a, b = tmp_path / "batch", tmp_path / "alone"
    for out, flag in ((a, "--batch"), (b, "--no-batch")):
        r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1", flag])
        assert r.exit_code == 0, r.output
    recs_a = {p.name: json.loads(p.read_text()) for p in (a / "records").glob("*.json")}
    recs_b = {p.name: json.loads(p.read_text()) for p in (b / "records").glob("*.json")}
    assert recs_a.keys() == recs_b.keys() and len(recs_a) == 6
    for k in recs_a:
        assert recs_a[k]["status"] == recs_b[k]["status"] == "ok"
        assert recs_a[k]["metrics"] == recs_b[k]["metrics"], k
    rid = next(iter(recs_a))[:-5]
    files_a = sorted(p.name for p in (a / "runs" / rid).iterdir())
    assert files_a == sorted(p.name for p in (b / "runs" / rid).iterdir())
    for f in ("fused.tum", "metrics.json", "report.md"):
        assert (a / "runs" / rid / f).read_bytes() == (b / "runs" / rid / f).read_bytes(), f
    # the shared estimates' files: in a batch, links to its first run's (273 MB for a sweep of 65 runs before, most of
    # it these files again), the same bytes as a run made alone writes; the run's own files are its own
    shared = ("lidar.tum", "gnss.tum", "imu_only.tum", "groundtruth.tum", "ape_translation_lidar.zip",
              "rpe_100m_translation_imu_only.zip")
    for g in (g for g in groups if len(g) > 1):
        first, *rest = (a / "runs" / t.id for t in g)
        for run in rest:
            for f in shared:
                assert (run / f).stat().st_ino == (first / f).stat().st_ino, (run.name, f)
                assert (run / f).read_bytes() == (b / "runs" / run.name / f).read_bytes(), (run.name, f)
            assert (run / "fused.tum").stat().st_ino != (first / "fused.tum").stat().st_ino


def test_a_file_system_without_hard_links_gets_copies(tmp_path, monkeypatch):
    from fusion_eval.outputs import StagedDir

    src = tmp_path / "src.tum"
    src.write_bytes(b"1 2 3\n")

    def refuse(*_a, **_k):
        raise OSError(1, "Operation not permitted")
    monkeypatch.setattr(os, "link", refuse)
    with StagedDir(tmp_path / "out") as out:
        assert out.link("lidar.tum", src)
        # a source gone meanwhile (its run's folder replaced): no link, no copy, no error; the caller writes its own
        assert not out.link("gnss.tum", tmp_path / "gone.tum") and not out.path("gnss.tum").exists()
    got = tmp_path / "out" / "lidar.tum"
    assert got.read_bytes() == b"1 2 3\n" and got.stat().st_ino != src.stat().st_ino


def test_a_batch_whose_preparation_fails_records_each_run_as_failed(small, tmp_path, monkeypatch):
    """A failure (even a bug) while preparing a batch never ends the sweep: each run is then made alone and
    recorded with its error, as a run outside a batch would be."""
    import fusion_eval.pipeline as pl
    from fusion_eval.commands import sweep as sw

    tasks = sw.plan(_sweep_file(tmp_path), [str(small)], tmp_path / "s")[0]
    group = next(g for g in sw.batches(tasks, 1) if len(g) > 1)

    def boom(*_a, **_k):
        raise ValueError("a bug in the preparation")
    monkeypatch.setattr(pl, "prepare", boom)
    recs = sw.run_batch(group)
    assert [r["status"] for r in recs] == ["failed"] * len(group)
    assert all("ValueError: a bug in the preparation" in r["error"] for r in recs)


@pytest.mark.slow
def test_the_batches_of_one_key_prepare_once_per_worker(small, tmp_path, monkeypatch):
    """A key's runs cut into several batches (BATCH_MAX) load and prepare the data once per worker process, not
    once per batch; the records are those of runs made alone, and nothing is kept once the sweep ends."""
    import fusion_eval.pipeline as pl
    from fusion_eval.commands import sweep as sw

    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    monkeypatch.setattr(sw, "BATCH_MAX", 2)
    calls = []
    orig = pl.prepare
    monkeypatch.setattr(pl, "prepare", lambda *a, **k: calls.append(1) or orig(*a, **k))
    grid = _sweep_file(tmp_path, "  f: {lidar.relative_pos_std_frac: 0.04}\n")     # default, c, d, f: one key
    tasks = sw.plan(grid, [str(small)], tmp_path / "p")[0]
    groups = [g for g in sw.batches(tasks, 1) if len(g) > 1]
    assert len({g[0].batch for g in groups}) < len(groups)                       # a key cut into two batches
    a, b = tmp_path / "batch", tmp_path / "alone"
    for out, flag in ((a, "--batch"), (b, "--no-batch")):
        calls.clear()
        r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(grid), "--out", str(out), "--jobs", "1", flag])
        assert r.exit_code == 0, r.output
        if flag == "--batch":                                                   # one preparation per key (e
            assert len(calls) == len({t.batch for t in tasks}) and not sw._PREPARED   # alone), none kept after
    recs_a = {p.name: json.loads(p.read_text()) for p in (a / "records").glob("*.json")}
    recs_b = {p.name: json.loads(p.read_text()) for p in (b / "records").glob("*.json")}
    assert recs_a.keys() == recs_b.keys() and len(recs_a) == 7
    for k in recs_a:
        assert recs_a[k]["metrics"] == recs_b[k]["metrics"], k


@pytest.mark.parametrize("n, jobs, sizes", [(17, 2, [6, 6, 5]), (16, 2, [8, 8]), (9, 2, [5, 4]), (5, 1, [5]),
                                            (65, 2, [8, 7, 7, 7, 7, 7, 7, 7, 8]), (1, 2, [1]), (3, 8, [1, 1, 1])])
def test_batches_are_cut_into_near_equal_chunks(n, jobs, sizes):
    """At most BATCH_MAX runs and an equal share of the workers per batch, sizes differing by one at most: no
    trailing batch of one run (which would load and prepare the data alone), every run once, in order."""
    from fusion_eval.commands.sweep import Task, batches

    tasks = [Task(id=f"r{i}", dataset="d", variant="v", variant_path=None, setting=str(i), overrides={},
                  base_config=None, plots=False, out_root="o", batch="k") for i in range(n)]
    got = batches(tasks, jobs)
    assert sorted(map(len, got)) == sorted(sizes) and [t.id for g in got for t in g] == [t.id for t in tasks]


def test_check_says_when_the_baseline_is_of_another_dataset(tmp_path):
    base, cur = _metrics(tmp_path, "base.json", 1.0), _metrics(tmp_path, "cur.json", 1.0)
    for p, name in ((base, "kitti-00"), (cur, "simple-05")):
        m = json.loads(p.read_text())
        m["dataset"] = name
        p.write_text(json.dumps(m))
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base), "--summary", str(tmp_path / "c.md")])
    # refused, not warned: simple-06's run passed against kitti-00's baseline with exit 0 (a review)
    assert r.exit_code == 2 and "is of dataset 'simple-05' and the baseline" in r.stderr and "of 'kitti-00'" in r.stderr
    assert (tmp_path / "c.md").read_text().startswith("# fusion-eval check: ERROR")


def test_check_says_when_the_files_were_drawn_with_other_seeds(tmp_path):
    """8 of 19 other GNSS seeds of the same code failed the shipped 5 % gate as REGRESSION, and a 5-trial mean against a
    20-trial baseline too, with no word (a statistics review): said, since the verdict is then the seeds'."""
    from fusion_eval.commands.check import _other_draws

    base, cur = _metrics(tmp_path, "base.json", 1.0), _metrics(tmp_path, "cur.json", 1.2)
    for p, seed in ((base, 0), (cur, 5)):
        m = json.loads(p.read_text())
        m["gnss_degradation"] = {"degraded": True, "seed": seed}
        p.write_text(json.dumps(m))
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base), "--summary", str(tmp_path / "c.md")])
    assert r.exit_code == 1 and "GNSS was degraded with seed 5 and the baseline's with 0" in r.stderr, r.output
    r = CliRunner().invoke(main, ["check", str(base), "--baseline", str(base), "--summary", str(tmp_path / "c.md")])
    assert r.exit_code == 0 and "degraded with seed" not in r.stderr
    deg = [{"degraded": True, "seed": 0}] * 2
    t5, t20 = {"n": 5, "seeds": [{"gnss.seed": i} for i in range(5)]}, {"n": 20, "seeds": [{"gnss.seed": i} for i in range(20)]}
    (w,) = _other_draws(deg, [t5, t20], "mean")
    assert "the mean over 5 trials and the baseline's over 20" in w
    shifted = {"n": 5, "seeds": [{"gnss.seed": i + 3} for i in range(5)]}
    (w,) = _other_draws(deg, [t5, shifted], "mean")
    assert "drawn with other seeds" in w
    assert _other_draws(deg, [t5, dict(t5)], "mean") == [] and _other_draws(deg, [t5, t20], None) == []
    assert _other_draws([{"degraded": False, "seed": 1}, {"degraded": False, "seed": 2}], [None, None], None) == []


def test_check_refuses_metrics_scored_otherwise_than_the_baseline(tmp_path):
    """An aligned APE checked against an unaligned baseline passed (found by a corrupted-input review); the same
    scoring with another engine or span bounds compares."""
    ev = {"association": "nearest", "alignment": "none", "t_max_diff_s": 0.01, "rpe_delta_m": 100.0, "engine": "arrays",
          "span": {"mode": "common", "t0_s": 0.0}}
    base, cur = _metrics(tmp_path, "base.json", 1.0), _metrics(tmp_path, "cur.json", 0.5)
    for p, e in ((base, ev), (cur, {**ev, "engine": "evo", "span": {"mode": "common", "t0_s": 0.1}})):
        p.write_text(json.dumps({**json.loads(p.read_text()), "evaluation": e}))
    assert CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base)]).exit_code == 0
    cur.write_text(json.dumps({**json.loads(cur.read_text()), "evaluation": {**ev, "alignment": "se3"}}))
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base)])
    assert r.exit_code == 2, r.output
    assert (f"error: {cur} was evaluated with evaluation.alignment = 'se3' and the baseline {base} with 'none': their "
            "figures do not compare") in r.output
    # the baseline CI gates on records its scoring too (it once held none, and nothing was compared)
    from conftest import ROOT

    shipped = ROOT / "configs" / "baselines" / "kitti-00.json"
    assert json.loads(shipped.read_text())["evaluation"]["alignment"] == "none"
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(shipped)])
    assert r.exit_code == 2 and "evaluation.alignment = 'se3'" in r.output, r.output
    # a setting only one file records is not compared
    base.write_text(json.dumps({**json.loads(base.read_text()), "evaluation": {"association": "nearest"}}))
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base)])
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("value,name", [(-1.0, "base.json"), (1e300, "base.json"), (-0.2, "cur.json")])
def test_check_refuses_an_impossible_error_figure(tmp_path, value, name):
    """A negative APE or one beyond a million km gates nothing (1e300 lets every regression pass): exit 2 naming the
    file and the metric. A negative log-likelihood, which may well be negative, is compared as usual."""
    cur = _metrics(tmp_path, "cur.json", 1.0)
    body = json.loads(cur.read_text())
    body["estimates"]["fused"]["ape"]["translation_m"]["rmse"] = value
    (tmp_path / name).write_text(json.dumps(body))
    base = tmp_path / "base.json"
    if name == "cur.json":
        base.write_text(json.dumps(json.loads(_metrics(tmp_path, "b0.json", 1.0).read_text())))
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base)])
    assert r.exit_code == 2 and f"{name}: fused.ape.translation_m.rmse is {value:g}" in r.stderr, r.output
    body = json.loads(_metrics(tmp_path, "n.json", 1.0).read_text())
    body.setdefault("nis", {})["lidar"] = {"nll_mean": -25.0}
    (tmp_path / "n.json").write_text(json.dumps(body))
    r = CliRunner().invoke(main, ["check", str(tmp_path / "n.json"), "--baseline", str(tmp_path / "n.json"), "-m", "nis.*"])
    assert r.exit_code == 0, r.output


def test_check_trial_stat_asked_of_runs_without_trials_is_an_error(tmp_path):
    cur = _metrics(tmp_path, "cur.json", 1.0)
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(cur), "--trial-stat", "median"])
    assert r.exit_code == 2 and "--trial-stat applies to the metrics of a run with --trials" in r.stderr
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(cur)])       # the default statistic: fine
    assert r.exit_code == 0


@pytest.mark.parametrize("trials", [{"n": 3}, 5, {"stats": {"estimates.fused.ape.translation_m.rmse": 1.0}}])
def test_check_refuses_a_trials_section_it_cannot_read(tmp_path, trials):
    """A 'trials' that is not run --trials' section was a KeyError, TypeError or AttributeError traceback (found by a
    corrupted-input review); --trial-stat none still reads the file's own values."""
    cur = _metrics(tmp_path, "cur.json", 1.0)
    body = json.loads(cur.read_text())
    body["trials"] = trials
    cur.write_text(json.dumps(body))
    base = _metrics(tmp_path, "base.json", 1.0)
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base)])
    assert r.exit_code == 2 and "its 'trials' is not the trials section" in r.stderr and "Traceback" not in r.output
    assert CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base), "--trial-stat", "none"]).exit_code == 0


@pytest.mark.slow
def test_a_sweeps_warnings_name_their_run_and_setting(tmp_path):
    """Warnings of a sweep's runs went to stderr with no setting, and sweep.md had none (found by a new-user
    review): each names its run and setting now, and sweep.md lists them by setting."""
    sw = tmp_path / "sweep.yaml"
    # (the motion of kitti-00's IMU gaps frozen too: added at each gap's end, it reopens the covariance there)
    sw.write_text("variants: [eskf]\nsettings:\n  frozen: {imu.gyro_noise_dps_sqrthz: 1.0e-9, "
                  "imu.accel_noise_mps2_sqrthz: 1.0e-9, imu.gap_turn_rate_dps: 0.0, imu.gap_accel_mps2: 0.0}\n")
    out = tmp_path / "s"
    drive = Path(__file__).resolve().parents[1] / "data" / "kitti-00"       # long enough for the NIS to tell
    r = CliRunner().invoke(main, ["sweep", str(drive), "--grid", str(sw), "--out", str(out), "--jobs", "1", "--no-plots"])
    assert r.exit_code == 0, r.output
    assert _rows(out)["frozen"]["status"] == "ok", _rows(out)["frozen"]
    said = [ln for ln in r.stderr.splitlines() if "does not follow this stream" in ln]
    assert said and all(re.search(r"warning: run \w+ \(.*kitti-00, eskf, frozen\): ", ln) for ln in said), said
    assert "noise settings far below the data's" in said[0]
    md = (out / "sweep.md").read_text()
    assert "## Warnings" in md and re.search(r"- `.*kitti-00` eskf / frozen: .*does not follow this stream", md)
    assert "eskf / default:" not in md


@pytest.mark.slow
def test_a_sweep_resumed_after_its_data_changed_runs_again(small, tmp_path):
    """The run id hashed the dataset's path and the configuration only: a sweep resumed after the lidar poses were
    corrupted kept the old figures ('2 already recorded'; found by a corrupted-input review)."""
    import shutil

    drive = tmp_path / "d"
    shutil.copytree(small, drive)
    sw = tmp_path / "sweep.yaml"
    sw.write_text("variants: [eskf]\nsettings:\n  a: {imu.gyro_noise_dps_sqrthz: 0.05}\n")
    out = tmp_path / "s"
    args = ["sweep", str(drive), "--grid", str(sw), "--out", str(out), "--jobs", "1", "--no-plots"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    first = _rows(out)
    r = CliRunner().invoke(main, args)
    assert "2 already recorded" in r.output
    poses = drive / "lidar" / "poses.txt"
    lines = poses.read_text().splitlines()
    v = lines[50].split()
    v[3] = f"{float(v[3]) + 5.0:.6f}"                      # one pose 5 m off
    lines[50] = " ".join(v)
    poses.write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert "0 already recorded" in r.output
    again = _rows(out)
    assert {k: v["id"] for k, v in again.items()}.keys() == first.keys()
    assert all(again[k]["id"] != first[k]["id"] for k in first)


def test_the_data_fingerprint_is_the_same_however_the_path_is_written(small, monkeypatch):
    """It hashed the paths as written: 'data/kitti-00', its absolute path and 'kitti-00' from data/ gave three run
    ids, so a sweep resumed from elsewhere ran everything again (found by a review of the diff)."""
    from fusion_eval import session
    from fusion_eval.provenance import fingerprint

    a = fingerprint(session.dataset(small).description)
    monkeypatch.chdir(small.parent)
    assert fingerprint(session.dataset(small.name).description) == a
    assert fingerprint(session.dataset(Path(small.name) / ".." / small.name).description) == a


def test_a_sweep_in_which_no_run_finished_fails_and_writes_no_best_yaml(small, tmp_path):
    """Every run failed (here the base config's lidar clock leaves no overlap with the IMU): the summary still
    lists each error, but the sweep exits non-zero, naming the first, and neither writes nor announces a best.yaml."""
    base = tmp_path / "base.yaml"
    base.write_text("lidar:\n  time_offset_s: 300.0\n")
    sw = tmp_path / "sweep.yaml"
    sw.write_text(f"config: {base}\nsettings:\n  a: {{imu.gyro_noise_dps_sqrthz: 0.2}}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1"])
    assert r.exit_code == 2, r.output
    last = r.output.strip().splitlines()[-1]
    assert last.startswith("error: no run of the sweep finished (2 failed or diverged") and "best.yaml" not in r.output
    assert f"{out}/sweep.md" in last and "the first, " in last
    assert not (out / "best.yaml").exists() and "## Failed runs" in (out / "sweep.md").read_text()


def test_a_sweep_refuses_settings_scored_differently(small, tmp_path):
    """A setting {evaluation.alignment: se3} was ranked against unaligned runs and won as 'best' (best.yaml held only
    the alignment; found by a corrupted-input review); compare and tune refused it already."""
    sw = tmp_path / "sweep.yaml"
    sw.write_text("settings:\n  a: {evaluation.alignment: se3}\n")
    r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(sw), "--out", str(tmp_path / "s")])
    assert r.exit_code == 2, r.output
    assert (f"error: {sw}: variant 'default' setting 'a' sets evaluation.alignment = 'se3' and variant 'default' "
            "setting 'default' 'none': a sweep ranks its runs of a dataset by their APE") in r.output
    assert not (tmp_path / "s").exists()


@pytest.mark.slow
def test_every_key_declared_filter_only_leaves_the_prepared_data_as_it_is(small):
    """A sweep's runs that differ only in keys declared ``reads="filter"`` share one preparation of the data
    (fusion_eval/batch.py, derived from the declarations): each such key, set to two values, gives the same prepared
    data, byte for byte. A key the preparation reads, declared so by mistake, would score every run of a batch on the
    first one's data."""
    import pickle

    from fusion_eval import session
    from fusion_eval.batch import FILTER_ONLY_KEYS
    from fusion_eval.config import schema
    from fusion_eval.prepare import prepare

    assert {"imu.gyro_noise_dps_sqrthz", "lidar.relative_pos_std_m", "gnss.std_scale", "init.pos_std_m"} <= set(FILTER_ONLY_KEYS)
    ds = session.dataset(small)
    specs = schema()

    def two_values(spec):
        if spec.kind == "choice":
            return [c for c in spec.choices if c != "auto"][:2]
        if spec.kind == "bool":
            return [True, False]
        v = spec.default if isinstance(spec.default, (int, float)) and spec.default else 0.05
        v = v[0] if isinstance(v, list) else v
        return ([v] * 3, [2 * v] * 3) if spec.kind == "vec3" else (v, 2 * v if spec.below is None else v / 2)

    def prepared(key, value):
        return pickle.dumps(prepare(ds, session.resolve(session.request(overrides={key: value}), ds)))
    for key in FILTER_ONLY_KEYS:
        a, b = two_values(specs[key])
        assert prepared(key, a) == prepared(key, b), key


def test_a_json_key_given_twice_and_a_setting_named_default_are_refused(tmp_path):
    """A baseline whose second "ratios" held 99 passed every check (json keeps the last of two keys), and a sweep
    setting named 'default' was "setting names must be unique" with no line (found by a corrupted-input review)."""
    base = _metrics(tmp_path, "base.json", 1.0)
    cur = _metrics(tmp_path, "cur.json", 1.0)
    base.write_text(base.read_text()[:-1] + ', "ratios": {"fused_over_lidar": 99.0}}')
    r = CliRunner().invoke(main, ["check", str(cur), "--baseline", str(base)])
    assert r.exit_code == 2 and f"error: {base}: key 'ratios' given twice in one JSON object" in r.output, r.output
    sw = tmp_path / "sweep.yaml"
    sw.write_text("settings:\n  default: {imu.gyro_noise_dps_sqrthz: 0.2}\n")
    r = CliRunner().invoke(main, ["sweep", str(tmp_path), "--grid", str(sw), "--out", str(tmp_path / "s")])
    assert r.exit_code == 2 and f"error: {sw}:2: 'default' is the name of the run with no setting" in r.output, r.output


@pytest.mark.slow
def test_each_run_of_a_batch_reports_its_own_noise_scale(small, tmp_path):
    """Runs that share a preparation (a batch) differ in the filter's noise scales: the IMU noise each one runs with
    (the estimate times its scale, metrics.json's preprocessing.auto_settled and report.md) is its own; it was the
    first run's, recorded by the shared preparation (found by a review of the Spec.reads change)."""
    sw = tmp_path / "sweep.yaml"
    sw.write_text("settings:\n  g: {imu.accel_noise_scale: 2.0}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1"])
    assert r.exit_code == 0 and "2 of 2 runs differ only in filter settings: 1 batch," in r.output, r.output
    recs = {r["setting"]: r for r in (json.loads(p.read_text()) for p in (out / "records").glob("*.json"))}
    settled = {k: v["metrics"]["preprocessing"]["auto_settled"]["imu.accel_noise_mps2_sqrthz"] for k, v in recs.items()}
    assert settled["g"] == pytest.approx(2.0 * settled["default"], rel=1e-12), settled


def test_a_dataset_given_as_its_folder_and_as_its_manifest_is_swept_once(kitti_slice, tmp_path, caplog):
    """A sweep given a drive's folder and its dataset.yaml ran everything twice and counted the drive twice in its
    cross-dataset mean (a corrupted-input review)."""
    from fusion_eval.commands.sweep import plan

    (tmp_path / "g.yaml").write_text("settings:\n  a: {gnss.noise_std_m: [1.0, 1.0, 2.0]}\n")
    tasks, _ = plan(tmp_path / "g.yaml", [str(kitti_slice), str(kitti_slice / "dataset.yaml")], tmp_path / "out")
    assert len({t.dataset for t in tasks}) == 1 and len(tasks) == 2          # the default and the setting
    assert "is the dataset" in caplog.text and "swept once" in caplog.text


@pytest.mark.slow
def test_a_sweep_ranks_by_the_objective_it_is_given(small, tmp_path):
    """sweep ranked by the fused APE alone; a user tuning for drift or smoothness needs another figure. The
    objective (tune's syntax) is its own column, orders the table and picks best.yaml; --summarize-only ranks the
    recorded runs again; a key no run has is refused without touching the summary."""
    sw = tmp_path / "sweep.yaml"
    sw.write_text("variants: [eskf]\ntrials: 2\nsettings:\n  a: {imu.gyro_noise_dps_sqrthz: 0.05}\n"
                  "  b: {imu.gyro_noise_dps_sqrthz: 0.6}\n")
    out = tmp_path / "s"
    obj = "fused.rpe_1frame.rmse"
    r = CliRunner().invoke(main, ["sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1",
                                  "--no-plots", "--objective", obj])
    assert r.exit_code == 0, r.output
    rows = _rows(out)
    col = "fused_rpe_1frame_trans_rmse_m"
    for row in rows.values():           # the objective's column is the mean of the trials' own figure
        assert abs(float(row[obj]) - float(row[col])) <= 1e-6 * float(row[col]) and row["trials"] == "2"
        assert float(row[f"{obj}_std"]) >= 0
    order = sorted(rows, key=lambda s: float(rows[s][obj]))
    md = (out / "sweep.md").read_text()
    assert f"Ranked by the mean {obj} (lower is better)" in md
    table = [ln.split("|")[3].strip() for ln in md.splitlines() if re.match(r"\|\s+\d+ \| eskf", ln)]
    assert table == order
    assert f"setting {order[0]}" in (out / "best.yaml").read_text().splitlines()[0]
    assert f"best: variant eskf, setting {order[0]}: mean {obj} " in r.output
    # again from the records, by the APE: the default's column and wording, no objective column
    before = (out / "sweep.csv").read_text()
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(out), "--summarize-only",
                                  "--no-plots", "--objective", "smoothed.ape.rmse"])
    assert r.exit_code == 2 and "no finished run has the metric 'smoothed.ape.rmse'" in r.stderr
    assert (out / "sweep.csv").read_text() == before
    sw.write_text(sw.read_text() + "objective: fused.ape.rmse\n")
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(out), "--summarize-only",
                                  "--no-plots"])
    assert r.exit_code == 0, r.output
    assert obj not in (out / "sweep.csv").read_text().splitlines()[0]
    md = (out / "sweep.md").read_text()
    assert "Ranked by the mean fused APE translation RMSE" in md
    # every cell under its own header (the default's row lost its APE cell once, shifting the rest one column left)
    head = next(ln for ln in md.splitlines() if ln.startswith("|   rank"))
    names = [c.strip() for c in head.strip("|").split("|")]
    rows = _rows(out)
    for ln in (ln for ln in md.splitlines() if re.match(r"\|\s+\d+ \| eskf", ln)):
        cells = dict(zip(names, (c.strip() for c in ln.strip("|").split("|"))))
        row = rows[cells["setting"]]
        assert float(cells["fused APE trans RMSE [m]"]) == pytest.approx(float(row["fused_ape_trans_rmse_m"]), abs=6e-4)
        assert float(cells["std [m]"]) == pytest.approx(float(row["fused_ape_trans_rmse_m_std"]), abs=6e-4)
        assert float(cells["APE rot RMSE [deg]"]) == pytest.approx(float(row["fused_ape_rot_rmse_deg"]), abs=6e-4)
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(tmp_path / "t"),
                                  "--objective", "fsued.ape.rmse"])
    assert r.exit_code == 2 and "'fsued.ape.rmse' is no metric key" in r.stderr and not (tmp_path / "t").exists()


def test_check_gates_a_smoothed_run_on_a_baseline_without_a_smoother(tmp_path):
    """A run with `smoother.method=rts` checked against the shipped baseline (made without a smoother) exited 2 for
    the smoothed metrics the baseline lacks (a review): with the default metrics they are said and not gated, the rest
    is gated; named with --metric, or a baseline lacking the fused estimate, it is still refused."""
    base = _metrics(tmp_path, "base.json", 1.0)
    body = json.loads(base.read_text())
    body["estimates"]["smoothed"] = {"ape": {"translation_m": {"rmse": 0.6}}}
    body["ratios"]["smoothed_over_lidar"] = 0.6 / 7.0
    (tmp_path / "cur.json").write_text(json.dumps(body))
    run = CliRunner().invoke
    r = run(main, ["check", str(tmp_path / "cur.json"), "--baseline", str(base)])
    assert r.exit_code == 0, r.output
    assert "not gated: 2 metric(s) of the smoothed estimate(s)" in r.stderr
    body["estimates"]["fused"]["ape"]["translation_m"]["rmse"] = 1.5              # the gated rest still fails
    (tmp_path / "worse.json").write_text(json.dumps(body))
    assert run(main, ["check", str(tmp_path / "worse.json"), "--baseline", str(base)]).exit_code == 1
    r = run(main, ["check", str(tmp_path / "cur.json"), "--baseline", str(base), "--metric", "smoothed.*"])
    assert r.exit_code == 2 and "has no value for it" in r.stderr


def test_a_baseline_with_a_smoothed_section_of_nulls_is_refused_not_called_without_one(tmp_path):
    """A baseline whose smoothed metrics are null was read as having none, and the check passed ungated (a diff
    review): it holds them, as NaN, and is refused."""
    base = _metrics(tmp_path, "base.json", 1.0)
    body = json.loads(base.read_text())
    body["estimates"]["smoothed"] = {"ape": {"translation_m": {"rmse": None}}}
    (tmp_path / "nulls.json").write_text(json.dumps(body))
    body["estimates"]["smoothed"] = {"ape": {"translation_m": {"rmse": 0.6}}}
    (tmp_path / "cur.json").write_text(json.dumps(body))
    r = CliRunner().invoke(main, ["check", str(tmp_path / "cur.json"), "--baseline", str(tmp_path / "nulls.json")])
    assert r.exit_code == 2 and "smoothed.ape" in r.stderr and "not gated" not in r.stderr, r.output


def test_a_drift_glob_gates_on_errors_not_on_the_segment_count():
    """'fused.kitti_drift.*' gated on kitti_drift.segments, a count: a longer drive's more segments read as a
    regression (a non-car review)."""
    from fusion_eval.evaluation import keys

    m = {"estimates": {"fused": {"kitti_drift": {"t_err_pct": 0.5, "r_err_deg_per_m": 0.002, "r_err_deg_per_100m": 0.2,
                                                 "segments": 41, "per_length": {}}}}}
    flat = keys.flatten(m)
    assert set(flat) == {"fused.kitti_drift.t_err_pct", "fused.kitti_drift.r_err_deg_per_m",
                         "fused.kitti_drift.r_err_deg_per_100m"}


def test_check_gates_errors_only_and_says_what_it_cannot_gate(tmp_path):
    """A review: NEES/NIS means (best at their dof) and shares inside the 95 % interval (best at 0.95) were gated
    as errors, lower is better: a NEES share rising from 0.67 to 0.77 was a REGRESSION, exit 1, and the reverse
    "better". Named, they are refused; caught by a glob, left out and said; a sweep or tune will not rank by them."""
    base, cur = _metrics(tmp_path, "base.json", 1.0), _metrics(tmp_path, "cur.json", 1.0)
    for p, share in ((base, 0.67), (cur, 0.77)):
        m = json.loads(p.read_text())
        m["nees"] = {"position": {"mean": 6.0, "dof": 3, "fraction_in_95": share}}
        p.write_text(json.dumps(m))
    run = CliRunner().invoke
    r = run(main, ["check", str(cur), "--baseline", str(base), "-m", "nees.position.fraction_in_95"])
    assert r.exit_code == 2 and "is a consistency figure, best at its dof" in r.stderr and "--require" in r.stderr
    r = run(main, ["check", str(cur), "--baseline", str(base), "-m", "nees.position.*", "-m", "fused.ape.rmse"])
    assert r.exit_code == 0 and "not gated: 2 figure(s)" in r.stderr and "REGRESSION" not in r.output, r.output
    r = run(main, ["check", str(cur), "--baseline", str(base), "--require", "nees.position.fraction_in_95 > 0.7"])
    assert r.exit_code == 0
    from fusion_eval.errors import ConfigError
    from fusion_eval.tuning import objectives

    with pytest.raises(ConfigError, match="nees.position.fraction_in_95 is a consistency figure"):
        objectives.parse("nees.position.fraction_in_95")
    objectives.parse("nis.lidar.nll_mean")                   # a likelihood: lower is better


def test_a_check_that_cannot_be_made_replaces_the_earlier_summary_and_junit(tmp_path):
    """A PASS summary and JUnit file from an earlier check stayed in place when the next one exited 2 (a review)."""
    base, cur = _metrics(tmp_path, "base.json", 1.0), _metrics(tmp_path, "cur.json", 1.0)
    md, xml = tmp_path / "s.md", tmp_path / "j.xml"
    r = CliRunner().invoke(main, ["check", str(cur), "-b", str(base), "--summary", str(md), "--junit", str(xml)])
    assert r.exit_code == 0 and "PASS" in md.read_text()
    bad = tmp_path / "nan.json"
    bad.write_text(base.read_text().replace('"rmse": 1.0', '"rmse": NaN'))
    r = CliRunner().invoke(main, ["check", str(cur), "-b", str(bad), "--summary", str(md), "--junit", str(xml)])
    assert r.exit_code == 2
    assert md.read_text().startswith("# fusion-eval check: ERROR") and "holds nan there" in md.read_text()
    assert 'errors="1"' in xml.read_text() and "holds nan there" in xml.read_text()


def test_update_baseline_refuses_what_the_next_check_would_refuse_and_a_value_that_is_no_number_is_named(tmp_path):
    """A review: a NaN metric and a sweep.csv written as a .json baseline were written with exit 0 and refused by the
    next check; NaN or a string in the current file read as MISSING with a blank value."""
    base = _metrics(tmp_path, "base.json", 1.0)
    bad = tmp_path / "nan.json"
    bad.write_text(base.read_text().replace('"rmse": 1.0', '"rmse": NaN'))
    r = CliRunner().invoke(main, ["check", str(bad), "-b", str(tmp_path / "nb.json"), "--update-baseline"])
    assert r.exit_code == 2 and "holds nan, not a finite number" in r.stderr and not (tmp_path / "nb.json").exists()
    r = CliRunner().invoke(main, ["check", str(bad), "-b", str(base)])
    assert r.exit_code == 1 and "INVALID" in r.output and "nan" in r.output, r.output
    csvf = tmp_path / "sweep.csv"
    csvf.write_text("id,dataset,variant,setting,fused_ape_trans_rmse_m,status\n1,kitti-00,eskf,default,0.7,ok\n")
    r = CliRunner().invoke(main, ["check", str(csvf), "-b", str(tmp_path / "nb.json"), "--update-baseline"])
    assert r.exit_code == 2 and "must be a .csv file too" in r.stderr and not (tmp_path / "nb.json").exists()


def test_a_sweep_with_a_failed_run_writes_everything_and_exits_1(small, tmp_path):
    """A CI script saw exit 0 and, under -q, not a word when a run failed (a review); diverged runs are results of a
    noise sweep and keep exit 0."""
    sw = tmp_path / "sweep.yaml"
    sw.write_text("settings:\n  nognss: {gnss.outages_s: [[0, 100000]]}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1"])
    assert r.exit_code == 1, r.output
    assert "error: 1 of 2 runs of the sweep failed" in r.stderr and "the first, " in r.stderr
    assert (out / "sweep.md").exists() and (out / "best.yaml").exists()


@pytest.mark.slow
def test_a_failed_trial_counts_as_a_failed_run_though_its_setting_has_a_mean(small, tmp_path):
    """Under --trials a setting with one failed trial is 'ok' in sweep.csv (the mean of the others); the exit-1 rule
    read those folded rows and passed such a sweep (a diff review). The failed runs are counted before the fold."""
    import json as _json

    from fusion_eval.commands import sweep as sw
    from fusion_eval.commands.sweep_summary import write_summary

    sw_file = tmp_path / "sweep.yaml"
    sw_file.write_text("settings:\n  a: {imu.gyro_noise_dps_sqrthz: 0.2}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw_file), "--out", str(out), "--jobs", "1",
                                  "--trials", "2"])
    assert r.exit_code == 0, r.output
    tasks = sw.plan(sw_file, [str(small)], out, trials=2)[0]
    victim = next(t for t in tasks if t.trial == 1 and t.setting == "a")
    rec_path = out / "records" / f"{victim.id}.json"
    rec = _json.loads(rec_path.read_text())
    rec.update(status="failed", error="a bug")
    rec_path.write_text(_json.dumps(rec))
    summary = write_summary(tasks, out, ["imu.gyro_noise_dps_sqrthz"], plots=False)
    row = next(x for x in summary["rows"] if x["setting"] == "a")
    assert row["status"] == "ok" and row["failed_trials"] == 1
    assert summary["failed_runs"] == [{"id": victim.id, "error": "a bug"}] and summary["runs"] == 4


@pytest.mark.slow
def test_a_quiet_sweep_on_a_local_dask_cluster_prints_no_run_warnings(small, tmp_path):
    """-q promises nothing below errors; a local Dask cluster's workers, whose stderr is the terminal, started with
    Dask's logging and printed every run's warnings (a reproducibility review)."""
    sw = tmp_path / "g.yaml"
    sw.write_text("settings:\n  bad: {imu.gyro_noise_dps_sqrthz: 0.00001, lidar.relative_att_std_deg: 0.0001}\n",
                  encoding="utf-8")
    r = subprocess.run([sys.executable, "-m", "fusion_eval", "-q", "sweep", str(small), "--grid", str(sw), "--out",
                        str(tmp_path / "o"), "--dask", "local", "--jobs", "2"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "Warnings" in (tmp_path / "o" / "sweep.md").read_text(encoding="utf-8")      # there were some, in the summary
    assert "NIS" not in r.stderr and "NEES" not in r.stderr, r.stderr


@pytest.mark.slow
def test_a_swept_setting_that_does_nothing_is_said_per_run_in_the_summary(small, tmp_path):
    """A sweep of lidar.relative_pos_std_m under the absolute lidar update gave identical rows with no word (a
    configuration audit); said per run in sweep.md, each with its own value, though the batch shares one preparation."""
    sw = tmp_path / "g.yaml"
    sw.write_text("variants: [lidar-absolute]\nsettings:\n  a: {lidar.relative_pos_std_m: 0.3}\n"
                  "  b: {lidar.relative_pos_std_m: 0.6}\n", encoding="utf-8")
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(tmp_path / "o"),
                                  "--jobs", "1"])
    assert r.exit_code == 0, r.output
    md = (tmp_path / "o" / "sweep.md").read_text(encoding="utf-8")
    assert "lidar-absolute / a: lidar.relative_pos_std_m=0.3 does nothing here" in md
    assert "lidar-absolute / b: lidar.relative_pos_std_m=0.6 does nothing here" in md


def test_an_interrupted_retry_of_failed_runs_counts_only_the_runs_it_need_not_redo(tmp_path, monkeypatch):
    """With --retry-failed the failed records are the runs to redo: interrupted at once, it said '9 of 9 recorded ...
    0 left' with 3 failed runs still to do (a diff review)."""
    from fusion_eval.commands import sweep

    tasks = [sweep.Task(id=f"r{i}", dataset="d", variant="v", variant_path=None, setting=f"s{i}", overrides={},
                        base_config=None, plots=False, out_root=str(tmp_path), batch="b") for i in range(9)]
    for i, t in enumerate(tasks):
        sweep.write_record(tmp_path, {"id": t.id, "status": "ok" if i < 6 else "failed"})

    def interrupted(_batch):
        raise KeyboardInterrupt
    monkeypatch.setattr(sweep, "run_batch", interrupted)
    with pytest.raises(KeyboardInterrupt, match="6 of 9 runs are recorded .* to do the 3 left"):
        sweep.execute(tasks, tmp_path, jobs=1, scheduler=None, dask_local=False, retry_failed=True)
    extra = sweep.Task(id="new", dataset="d", variant="v", variant_path=None, setting="new", overrides={},
                       base_config=None, plots=False, out_root=str(tmp_path), batch="b")
    with pytest.raises(KeyboardInterrupt, match="9 of 10 runs are recorded .* to do the 1 left"):
        sweep.execute(tasks + [extra], tmp_path, jobs=1, scheduler=None, dask_local=False)   # failed ones kept


@pytest.mark.slow
def test_across_datasets_only_settings_finished_on_every_dataset_are_averaged(small, tmp_path):
    """A setting that failed on one dataset has a mean over the others only: ranked beside complete ones, a setting
    that fails on the hard drive would win on the easy one (a mutation review: nothing held it)."""
    import json as _json
    import shutil as _shutil

    from fusion_eval.commands import sweep as sw
    from fusion_eval.commands.sweep_summary import write_summary

    other = tmp_path / "other"
    _shutil.copytree(small, other)
    sw_file = tmp_path / "sweep.yaml"
    sw_file.write_text("settings:\n  a: {imu.gyro_noise_dps_sqrthz: 0.2}\n  b: {imu.gyro_noise_dps_sqrthz: 0.3}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), str(other), "--grid", str(sw_file), "--out", str(out),
                                  "--jobs", "1"])
    assert r.exit_code == 0, r.output
    tasks = sw.plan(sw_file, [str(small), str(other)], out)[0]
    for t in tasks:                   # 'a' best by far on the first dataset, failed on the second
        if t.setting != "a":
            continue
        p = out / "records" / f"{t.id}.json"
        rec = _json.loads(p.read_text())
        if Path(t.dataset) == other:
            rec.update(status="failed", error="a bug")
        else:
            rec["metrics"]["estimates"]["fused"]["ape"]["translation_m"]["rmse"] = 1e-3
        p.write_text(_json.dumps(rec))
    summary = write_summary(tasks, out, ["imu.gyro_noise_dps_sqrthz"], plots=False)
    assert summary["best"]["setting"] != "a"
    md = (out / "sweep.md").read_text(encoding="utf-8")
    table = md.split("## Averaged across datasets", 1)[1].split("##", 1)[0]
    assert "| a " not in table.replace("  ", " ") and "default" in table
