"""One configuration session: the layers, a resolved configuration read back, metric names that follow the
settings, and sweeps whose tasks run from any directory."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import ROOT
from fusion_eval import session
from fusion_eval.cli import main
from fusion_eval.config import Settings, merge_layers, parse_overrides
from fusion_eval.errors import ConfigError


def test_layers_merge_in_order(kitti_slice, tmp_path):
    base = tmp_path / "base.yaml"
    base.write_text("imu:\n  gyro_noise_dps_sqrthz: 0.2\n  accel_noise_mps2_sqrthz: 0.4\n")
    var = tmp_path / "var.yaml"
    var.write_text("imu:\n  gyro_noise_dps_sqrthz: 0.3\n")
    req = session.request(config=base, variant=var, sets=("imu.accel_noise_mps2_sqrthz=0.5",),
                          overrides={"lidar.relative_pos_std_frac": 0.02})
    cfg = session.resolve(req, session.dataset(kitti_slice))
    assert cfg["imu"]["gyro_noise_dps_sqrthz"] == 0.3           # variant over base
    assert cfg["imu"]["accel_noise_mps2_sqrthz"] == 0.5         # --set over base
    assert cfg["lidar"]["relative_pos_std_frac"] == 0.02
    assert req.source == "var"
    with pytest.raises(ConfigError, match="unknown section 'imuu'"):
        session.request(overrides={"imuu.x": 1})


def test_manifest_suggestions_sit_between_the_defaults_and_the_user(tmp_path):
    from conftest import make_slice

    d = make_slice(tmp_path / "ds", 120)
    m = d / "dataset.yaml"
    m.write_text(m.read_text() + "config:\n  imu:\n    gyro_noise_dps_sqrthz: 0.2\n    accel_noise_mps2_sqrthz: 0.6\n")
    ds = session.dataset(d)
    cfg = session.resolve(session.request(sets=("imu.accel_noise_mps2_sqrthz=0.7",)), ds)
    assert cfg["imu"]["gyro_noise_dps_sqrthz"] == 0.2 and cfg["imu"]["accel_noise_mps2_sqrthz"] == 0.7
    # Python overrides come after --set items
    cfg = session.resolve(session.request(sets=("imu.accel_noise_mps2_sqrthz=0.7",),
                                          overrides={"imu.accel_noise_mps2_sqrthz": 0.8}), ds)
    assert cfg["imu"]["accel_noise_mps2_sqrthz"] == 0.8
    m.write_text(m.read_text() + "    nope: 1\n")
    n_lines = len(m.read_text().splitlines())
    with pytest.raises(ConfigError, match=rf"dataset.yaml:{n_lines}: unknown key 'imu.nope'"):   # its line
        session.resolve(session.request(), session.dataset(d))


def test_settings_are_built_from_the_schema_alone():
    cfg = merge_layers([parse_overrides({"init.yaw_std_deg": 2.0})])
    s = Settings(cfg)
    assert s.init.yaw_std_rad == pytest.approx(2.0 * 3.141592653589793 / 180)
    assert s.filter.nhc_max_turn_rate_rps == 0.13                 # already SI: unchanged


def test_resolved_configuration_reruns_to_identical_metrics(kitti_slice, slice_run, tmp_path):
    out = tmp_path / "again"
    r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "-c", str(slice_run / "config.resolved.yaml"),
                                  "--out", str(out), "--no-plots"])
    assert r.exit_code == 0, r.output
    a = json.loads((slice_run / "metrics.json").read_text())
    b = json.loads((out / "metrics.json").read_text())
    assert a["estimates"] == b["estimates"] and a["nis"] == b["nis"] and a["nees"] == b["nees"]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    from conftest import make_slice

    return make_slice(tmp_path_factory.mktemp("ses") / "short", 300)


@pytest.mark.slow
def test_rpe_distance_follows_the_setting_through_run_sweep_and_check(small, tmp_path):
    sw = tmp_path / "sw.yaml"
    sw.write_text("settings:\n  short: {evaluation.rpe_delta_m: 50}\n")
    out = tmp_path / "s"
    r = CliRunner().invoke(main, ["-q", "sweep", str(small), "--grid", str(sw), "--out", str(out), "--jobs", "1", "--no-plots"])
    assert r.exit_code == 0, r.output
    rows = {row["setting"]: row for row in csv.DictReader((out / "sweep.csv").read_text().splitlines())}
    assert rows["short"]["fused_rpe_50m_trans_rmse_m"] != "" and rows["default"]["fused_rpe_100m_trans_rmse_m"] != ""
    run = out / "runs" / rows["short"]["id"] / "metrics.json"
    m = json.loads(run.read_text())
    assert m["evaluation"]["rpe_delta_m"] == 50.0 and "rpe_50m" in m["estimates"]["fused"]
    r = CliRunner().invoke(main, ["check", str(run), "--baseline", str(run)])
    assert r.exit_code == 0 and "fused.rpe_50m.translation_m.rmse" in r.output, r.output
    r = CliRunner().invoke(main, ["check", str(out / "sweep.csv"), "--baseline", str(out / "sweep.csv")])
    assert r.exit_code == 0 and "fused_rpe_50m_trans_rmse_m" in r.output and "fused_rpe_100m_trans_rmse_m" in r.output


@pytest.mark.slow
def test_sweep_tasks_carry_absolute_paths_and_run_from_another_directory(small, tmp_path, monkeypatch):
    from fusion_eval.commands.sweep import plan

    vdir = tmp_path / "myvariants"
    vdir.mkdir()
    (vdir / "tight.yaml").write_text("lidar:\n  relative_att_std_deg: 0.02\n")
    work = tmp_path / "work"
    work.mkdir()
    (work / "sw.yaml").write_text("variants: [tight]\nsettings:\n  a: {imu.gyro_noise_dps_sqrthz: 0.05}\n")
    rel_ds = os.path.relpath(small, work)
    monkeypatch.chdir(work)
    tasks, _ = plan(Path("sw.yaml"), [rel_ds], Path("out"), vdir)
    assert all(Path(t.dataset).is_absolute() and Path(t.variant_path).is_absolute() and Path(t.out_root).is_absolute()
               for t in tasks)
    # a worker started elsewhere (another directory, another process) runs the task as it was sent
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    code = ("import pickle, sys; from fusion_eval.commands.sweep import run_task; "
            "rec = run_task(pickle.loads(sys.stdin.buffer.read())); print(rec['status'], rec.get('error'))")
    import pickle

    p = subprocess.run([sys.executable, "-c", code], input=pickle.dumps(tasks[1]), cwd=elsewhere, capture_output=True,
                       timeout=300, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert p.returncode == 0 and p.stdout.decode().startswith("ok"), p.stdout.decode() + p.stderr.decode()
    assert (work / "out" / "runs" / tasks[1].id / "metrics.json").exists()
    r = CliRunner().invoke(main, ["-q", "sweep", rel_ds, "--grid", "sw.yaml", "--out", "o2", "--jobs", "1", "--no-plots",
                                  "--variant-dir", str(vdir)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["-q", "sweep", rel_ds, "--grid", "sw.yaml", "--out", "o3", "--jobs", "1", "--no-plots"])
    assert r.exit_code == 2 and "unknown variant 'tight'" in r.stderr


@pytest.mark.slow
def test_shipped_sweeps_variants_and_dataset_are_found_from_any_directory(tmp_path, monkeypatch):
    from fusion_eval import resources
    from fusion_eval.commands.sweep import plan

    monkeypatch.chdir(tmp_path)
    sweep = resources.sweep_file("noise5")
    assert sweep.is_file() and sweep.name == "noise5.yaml"
    tasks, _ = plan(sweep, [], Path("out"))
    assert {Path(t.dataset).name for t in tasks} == {"kitti-00"} and len(tasks) == 6
    assert all(Path(t.variant_path).parent.name == "variants" for t in tasks)
    assert resources.default_dataset().is_dir() and (resources.variant_dir() / "nominal.yaml").is_file()


def test_a_resolved_config_of_another_drive_run_without_dataset_is_said(tmp_path, caplog):
    """`run -c <results>/config.resolved.yaml` with no DATASET ran the default drive, whatever drive the file was
    written for, with no word (a reproducibility review); a DATASET given, or the same drive, says nothing."""
    from fusion_eval import session

    f = tmp_path / "config.resolved.yaml"
    f.write_text("filter:\n  nhc: false\ndataset:\n  path: /data/drive_0018\n  name: 2011_09_30_drive_0018_sync\n",
                 encoding="utf-8")
    req = session.request(config=f)
    with caplog.at_level("WARNING"):
        session.resolve(req, session.dataset(None))
    assert "written by a run on the dataset '2011_09_30_drive_0018_sync' (/data/drive_0018)" in caplog.text
    assert "give the DATASET" in caplog.text
    caplog.clear()
    session._SAID.clear()                # (said once per file: the one said above would hide a second saying)
    with caplog.at_level("WARNING"):
        session.resolve(req, session.dataset("data/kitti-00"))
        f.write_text("filter:\n  nhc: false\ndataset:\n  name: kitti-00\n", encoding="utf-8")
        session.resolve(session.request(config=f), session.dataset(None))
    assert "written by a run" not in caplog.text


def test_run_with_a_resolved_config_of_another_drive_and_no_dataset_says_so(tmp_path, kitti_slice, monkeypatch):
    """`fusion-eval run -c <results>/config.resolved.yaml` (no DATASET): the command settles the default's path itself,
    and the warning above never fired from it (a review of the diff)."""
    from fusion_eval import resources

    monkeypatch.setattr(resources, "default_dataset", lambda: kitti_slice)       # a short default to run
    f = tmp_path / "config.resolved.yaml"
    f.write_text("dataset:\n  path: /data/drive_0018\n  name: 2011_09_30_drive_0018_sync\n", encoding="utf-8")
    r = CliRunner().invoke(main, ["run", "-c", str(f), "--no-plots", "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert "was written by a run on the dataset '2011_09_30_drive_0018_sync'" in r.stderr


def test_a_setting_of_an_observation_that_is_off_is_said():
    """A sweep of lidar.relative_pos_std_m under filter.lidar_update=absolute gave identical rows, and odometer.* without
    the odometer, with no word (a configuration audit): said as a data warning (in the report and a sweep's summary),
    unless an enabled observation shares the key or something else reads it."""
    from fusion_eval import session

    ds = session.dataset("data/kitti-00")
    cases = [(("filter.lidar_update=absolute", "lidar.relative_pos_std_m=0.5"),
              "lidar.relative_pos_std_m=0.5 does nothing here: it is a setting of the lidar relative pose"),
             (("odometer.speed_std_mps=0.3",), "(filter.odometer_update=true does)"),
             (("filter.lidar_update=relative", "lidar.relative_pos_std_m=0.5"), None),
             (("filter.lidar_update=absolute", "lidar.gate_prob=0.999"), None),           # the absolute pose's gate too
             (("filter.nhc=false", "filter.odometer_update=true", "filter.nhc_travel_yaw_mrad=3"), None),   # shared
             (("filter.use_gnss=false", "gnss.lever_arm_b_m=[0, 0, 1]"), None),            # the GNSS checks take it
             (("filter.use_gnss=false", "gnss.std_scale=2"), "gnss.std_scale=2.0 does nothing here"),
             # a key declared to act only under another's value (Spec.only_with)
             (("imu.gyro_bias_corr_time_s=600",), "imu.gyro_bias_corr_time_s=600.0 does nothing here: it applies only "
                                                  "with filter.bias_model=gauss_markov (this configuration has "
                                                  "filter.bias_model=random_walk)"),
             (("filter.bias_model=gauss_markov", "imu.gyro_bias_corr_time_s=600"), None)]
    from fusion_eval.session import inactive_warnings as _inactive

    for sets, said in cases:
        words = " ".join(_inactive(ds, session.resolve(session.request(sets=sets), ds)))
        assert (said in words) if said else "does nothing" not in words, (sets, words)
    # a manifest's own suggestions, which a run's config.resolved.yaml repeats, are not the user's
    ds.description["config"] = {"lidar": {"relative_pos_std_frac": 0.005}}
    cfg = session.resolve(session.request(sets=("filter.lidar_update=absolute", "lidar.relative_pos_std_frac=0.005")), ds)
    assert _inactive(ds, cfg) == []
