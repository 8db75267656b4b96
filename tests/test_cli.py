"""End to end: `fusion-eval run` on a short slice of the real drive; every output exists and parses."""

from __future__ import annotations

import re
import json
import zipfile
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from fusion_eval import __version__
from conftest import without_provenance
from fusion_eval.cli import main
from fusion_eval.datasets.tum import read_tum

TUMS = ("fused.tum", "lidar.tum", "gnss.tum", "imu_only.tum", "groundtruth.tum")
PLOTS = ("trajectories.png", "ape_over_time.png", "biases.png", "fused_error_3sigma.png", "fused_error_att_vel_3sigma.png")


def test_help_and_version():
    r = CliRunner().invoke(main, ["--help"])
    assert r.exit_code == 0 and "run" in r.output
    r = CliRunner().invoke(main, ["--version"])
    assert r.exit_code == 0 and __version__ in r.output
    r = CliRunner().invoke(main, ["run", "--help"])
    assert r.exit_code == 0 and "--set" in r.output and "--out" in r.output


@pytest.mark.slow
def test_every_output_exists_and_parses(slice_run):
    out = slice_run
    for name in TUMS:
        s = read_tum(out / name)
        assert len(s) > 10, name
    m = json.loads((out / "metrics.json").read_text())
    for est in ("fused", "lidar", "gnss", "imu_only"):
        e = m["estimates"][est]
        assert e["matched_poses"] > 10
        assert set(e["ape"]["translation_m"]) == {"rmse", "mean", "median", "std", "min", "max"}
    assert set(m["estimates"]["fused"]) >= {"ape", "rpe_1frame", "rpe_100m"}
    assert "rotation_deg" in m["estimates"]["fused"]["ape"] and "rotation_deg" not in m["estimates"]["gnss"]["ape"]
    assert m["ratios"]["fused_over_lidar"] > 0 and m["ratios"]["fused_over_gnss"] > 0
    assert m["gnss_degradation"]["rate_hz"] == 1.0
    csv = (out / "metrics.csv").read_text().splitlines()
    assert csv[0].startswith("estimate,") and len(csv) == 5
    cfg = yaml.safe_load((out / "config.resolved.yaml").read_text())
    assert cfg["filter"]["lidar_update"] == "relative" and cfg["versions"]["fusion-eval"] == __version__
    report = (out / "report.md").read_text()
    assert "GNSS degradation" in report and re.search(r"\| fused +\|", report)
    for p in PLOTS:
        assert (out / p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", p
    zips = sorted(out.glob("*.zip"))
    assert len(zips) == 19   # 3 estimates x (2 APE + 4 RPE) + GNSS APE translation
    from evo.tools import file_interface

    res = file_interface.load_res_file(out / "ape_translation_fused.zip")
    assert abs(res.stats["rmse"] - m["estimates"]["fused"]["ape"]["translation_m"]["rmse"]) < 1e-12
    with zipfile.ZipFile(zips[0]) as z:
        assert "stats.json" in z.namelist()
    assert not list(out.parent.glob(".*partial*"))
    # named by their estimates (evo's defaults made them alike, and `evo_res *.zip` refused them: found by a review)
    names = [file_interface.load_res_file(out / f"ape_translation_{e}.zip").info["est_name"] for e in ("fused", "lidar", "gnss")]
    assert names == ["fused", "lidar", "gnss"]
    r = subprocess.run([str(Path(sys.executable).parent / "evo_res"), *(str(out / f"ape_translation_{e}.zip") for e in
                                                                         ("fused", "lidar", "gnss"))],
                       capture_output=True, text=True)
    assert r.returncode == 0 and "fused" in r.stdout, r.stdout + r.stderr


def test_fused_beats_lidar_and_gnss_on_the_slice(slice_run):
    m = json.loads((slice_run / "metrics.json").read_text())
    ape = {k: v["ape"]["translation_m"]["rmse"] for k, v in m["estimates"].items()}
    assert ape["fused"] < ape["lidar"] and ape["fused"] < ape["gnss"]
    assert ape["imu_only"] > ape["fused"]


@pytest.mark.slow
def test_same_inputs_give_the_same_bytes(kitti_slice, slice_run, tmp_path):
    out2 = tmp_path / "again"
    res = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--out", str(out2)])
    assert res.exit_code == 0, res.output
    for f in sorted(p.name for p in slice_run.iterdir()):
        if f == "config.resolved.yaml":
            continue   # holds the output-independent dataset path, equal here, but keep the check on data files
        a, b = (slice_run / f).read_bytes(), (out2 / f).read_bytes()
        if f in ("report.md", "report.html", "metrics.json"):
            a, b = without_provenance(a), without_provenance(b)
        assert a == b, f


def test_usage_errors_are_one_line_naming_the_command():
    cases = {("run", "--trials", "0"): "fusion-eval run: Invalid value for '--trials'",
             ("run", "--bogus"): "fusion-eval run: No such option '--bogus'",
             ("runn",): "fusion-eval: No such command 'runn'. Did you mean 'run'?",
             ("--bogus",): "fusion-eval: No such option '--bogus'",
             ("check",): "fusion-eval check: Missing argument 'METRICS'"}
    for args, needle in cases.items():
        r = CliRunner().invoke(main, list(args), prog_name="fusion-eval")
        err = r.stderr.strip()
        assert r.exit_code == 2 and err.startswith("error: ") and needle in err and "\n" not in err, (args, r.output)
        assert err.endswith("--help)") and "Traceback" not in r.output
    r = CliRunner().invoke(main, [], prog_name="fusion-eval")          # no command at all: click's help, as before
    assert "Usage: fusion-eval" in r.output and "Commands:" in r.output


def test_existing_output_directory_is_kept_unless_overwrite(kitti_slice, slice_run):
    before = (slice_run / "metrics.json").read_bytes()
    r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--out", str(slice_run)])
    assert r.exit_code == 2 and "--overwrite" in r.output
    assert (slice_run / "metrics.json").read_bytes() == before


@pytest.mark.slow
def test_default_output_folders_are_unique_and_a_failed_run_leaves_none(kitti_slice, tmp_path, monkeypatch):
    """Two commands started in the same second without --out each get a folder (the second was refused as writing
    the first one's); a failing run leaves no empty folder behind; --set items show in the name."""
    import shutil

    from fusion_eval.outputs import default_dir

    base = tmp_path / "r1" / "x-default-20260101-000000"
    with default_dir(base) as a, default_dir(base) as b:
        assert (a, b) == (base, base.with_name(base.name + "-2")) and a.is_dir() and b.is_dir()
    with pytest.raises(KeyboardInterrupt), default_dir(tmp_path / "r2" / "deep" / "y") as c:
        assert c.is_dir()
        raise KeyboardInterrupt
    assert not (tmp_path / "r2").exists()

    bad = tmp_path / "bad"
    shutil.copytree(kitti_slice, bad)
    sorted((bad / "oxts" / "data").iterdir())[50].write_text("1 2 3\n")
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, ["-q", "run", str(bad), "--no-plots"])
    assert r.exit_code == 2 and not (tmp_path / "results").exists(), r.output
    r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--no-plots", "--set", "gnss.seed=3"])
    assert r.exit_code == 0 and [p.name.split("-2")[0] for p in (tmp_path / "results").iterdir()] == \
        [f"{kitti_slice.name}-default-set"], r.output


@pytest.mark.slow
def test_set_overrides_and_lidar_forms(kitti_slice, tmp_path):
    for form, extra in (("absolute", []), ("none", []), ("relative", ["--set", "lidar.interpolate_to_imu=false"]),
                        ("relative", ["--set", "filter.init_pose_from=lidar", "--set", "filter.init_velocity_from=gnss",
                                      "--set", "filter.bias_model=constant", "--set", "imu.gyro_lag_s=auto"])):
        out = tmp_path / f"{form}-{len(extra)}"
        r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--out", str(out), "--no-plots",
                                      "--set", f"filter.lidar_update={form}", "--set", "gnss.outages_s=[[20, 40]]", *extra])
        assert r.exit_code == 0, r.output
        m = json.loads((out / "metrics.json").read_text())
        # 1 Hz for 20 s, less a fix that may fall in the filled-in packets 347-361 (about 33-35 s)
        d = m["gnss_degradation"]
        assert d["outages_s"] == [[20.0, 40.0]] and d["fixes_in_outages"] in (19, 20)
        assert d["fixes_used"] == d["fixes_after_decimation"] - d["fixes_in_outages"]
        g = read_tum(out / "gnss.tum")
        t0 = read_tum(out / "fused.tum").t_s[0]
        assert not np.any((g.t_s >= t0 + 20) & (g.t_s < t0 + 40))
        assert not list(out.glob("*.png"))
        # the GNSS has no pose in the outage and the report says so beside the span (a student's review)
        n = m["estimates"]["gnss"]["matched_poses"]
        assert (f"The GNSS is scored on its {n} fixes inside the span and has none in its outage 20-40 s after the "
                "start") in (out / "report.md").read_text()
        fused = read_tum(out / "fused.tum")
        assert np.isfinite(fused.p_w_m).all()


HEAVY = ("matplotlib", "evo.tools.plot", "dask", "pandas")
_PROBE = ("import sys, runpy\nsys.argv = ['fusion-eval'] + sys.argv[1:]\n"
          "try:\n    runpy.run_module('fusion_eval', run_name='__main__')\nexcept SystemExit as e:\n    code = e.code\n"
          f"print('LOADED', code, ','.join(m for m in {HEAVY!r} if m in sys.modules))")


def _loaded(*args) -> tuple[int, list[str]]:
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _PROBE, *args], capture_output=True, text=True)
    line = next(s for s in out.stdout.splitlines() if s.startswith("LOADED"))
    _, code, mods = line.split(" ", 2) if line.count(" ") >= 2 else (*line.split(" "), "")
    return int(code or 0), [m for m in mods.split(",") if m]


@pytest.mark.slow
def test_help_and_check_import_no_plotting_dask_or_pandas(slice_run):
    """Start-up stays light: `--help` and `check` (a CI gate) load none of the heavy libraries."""
    assert _loaded("--help") == (0, [])
    m = str(slice_run / "metrics.json")
    code, mods = _loaded("check", m, "--baseline", m)
    assert code == 0 and mods == []
    # the probe does see them when a command loads them
    code, mods = _loaded("evaluate", str(slice_run / "groundtruth.tum"), str(slice_run / "fused.tum"), "--out",
                         str(slice_run.parent / "probe-eval"))
    assert code == 0 and "matplotlib" in mods


def test_options_that_would_be_ignored_are_refused(tmp_path):
    """An option given where it does not apply is a usage error naming it, before any work, rather than silently
    dropped (the user would believe a result was computed their way)."""
    cases = {("-q", "-v", "check", "m.json", "-b", "b.json"): "-q and -v ask for opposite things",
             ("evaluate", "a.tum", "b.tum", "-o", str(tmp_path / "e"), "--segment-m", "50", "--segment-s", "5"):
                 "--segment-m and --segment-s: give one",
             ("evaluate", "a.tum", "b.tum", "-o", str(tmp_path / "e"), "--up-axis", "z"):
                 "--up-axis does not apply with --alignment none",
             ("evaluate", "a.tum", "b.tum", "-o", str(tmp_path / "e"), "--alignment", "se3", "--up-axis", "z"):
                 "--up-axis does not apply with --alignment se3",
             ("evaluate", "a.tum", "b.tum", "-o", str(tmp_path / "e"), "--n-to-align", "10"):
                 "--n-to-align does not apply without an --alignment",
             ("track", "x.txt", "-o", str(tmp_path / "t"), "--sensors", "lidar", "--radar-var", "1", "1", "1"):
                 "--radar-var does not apply with --sensors lidar",
             ("track", "x.txt", "-o", str(tmp_path / "t"), "--sensors", "radar", "--lidar-var", "1", "1"):
                 "--lidar-var does not apply with --sensors radar",
             ("sweep", "--grid", "noise5", "-o", str(tmp_path / "s"), "--summarize-only", "--trials", "3", "-j", "2"):
                 "--jobs, --trials do not apply with --summarize-only"}
    for args, needle in cases.items():
        r = CliRunner().invoke(main, list(args), prog_name="fusion-eval")
        err = r.stderr.strip()
        assert r.exit_code == 2 and err.startswith("error: ") and needle in err and "\n" not in err, (args, r.output)
    # the same options where they apply are accepted (evaluate gets as far as its missing files)
    r = CliRunner().invoke(main, ["evaluate", "a.tum", "b.tum", "-o", str(tmp_path / "e"), "--alignment", "4dof",
                                  "--up-axis", "z", "--n-to-align", "10", "--segment-s", "5"], prog_name="fusion-eval")
    assert "does not apply" not in r.output and "a.tum" in r.stderr


def test_compare_refuses_one_variant_named_twice(tmp_path):
    from fusion_eval import resources

    r = CliRunner().invoke(main, ["compare", "--variants", f"eskf,{resources.variant_dir() / 'eskf.yaml'}", "-o",
                                  str(tmp_path / "c")], prog_name="fusion-eval")
    assert r.exit_code == 2 and "names one variant twice: 'eskf' and" in r.stderr and not (tmp_path / "c").exists()


@pytest.mark.slow
def test_overwrite_never_replaces_a_users_dataset(kitti_slice, tmp_path):
    """--overwrite deleted a user's own dataset folder, OXTS packets, lidar poses and calibration (a corrupted-input
    review), because any dataset.yaml counted as a folder fusion-eval wrote: only a simulated drive's does now."""
    import shutil

    victim = tmp_path / "my-drive"
    shutil.copytree(kitti_slice, victim)
    before = sorted(p.relative_to(victim) for p in victim.rglob("*"))
    r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--out", str(victim), "--overwrite", "--no-plots"])
    assert r.exit_code == 2 and "a dataset of your own is never replaced" in r.stderr
    assert sorted(p.relative_to(victim) for p in victim.rglob("*")) == before
    # a drive `simulate` wrote is its output, and simulate --overwrite replaces it
    sim = tmp_path / "sim"
    assert CliRunner().invoke(main, ["-q", "simulate", str(sim), "--duration", "20"]).exit_code == 0
    r = CliRunner().invoke(main, ["-q", "simulate", str(sim), "--duration", "20", "--seed", "1", "--overwrite"])
    assert r.exit_code == 0, r.output
    assert "name: sim-urban-automotive-s1" in (sim / "dataset.yaml").read_text()


@pytest.mark.parametrize("command", [["run"], ["compare", "--variants", "eskf"]])
def test_used_out_refused_before_the_numerics_load(tmp_path, command):
    """A second run into the same --out is refused at once (it waited 0.7 s for the numerics' imports), with the
    same one-line error and exit code as before, and without importing numba, evo or the pipeline."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    probe = ("import sys\nfrom fusion_eval.cli import main\n"
             f"try:\n    main({[*command, '--out', str(out)]!r}, prog_name='fusion-eval')\n"
             "except SystemExit as e:\n    print('exit', e.code)\n"
             "print('loaded', sorted(m for m in ('numba', 'evo', 'fusion_eval.pipeline') if m in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=tmp_path)
    assert "exists and is not empty" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert "exit 2" in r.stdout and "loaded []" in r.stdout, r.stdout


def test_a_failed_write_names_the_output_as_given_not_the_staging_folder():
    """A full disk named the hidden staging path .out.partial-PID/..., not --out (a corrupted-input review)."""
    from fusion_eval.cli import _as_given

    assert _as_given("/tmp/x/.out.partial-1234/fused.tum") == "/tmp/x/out/fused.tum"
    assert _as_given("/a/.b.c.partial-77") == "/a/b.c" and _as_given("/data/.hidden/x.txt") == "/data/.hidden/x.txt"
