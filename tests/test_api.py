"""The public Python API, called as a user would: fe.load_dataset, fe.run, Result, fe.evaluate."""

from __future__ import annotations

import json

import numpy as np
import pytest

import fusion_eval as fe
from conftest import shared_path, without_provenance
from fusion_eval.errors import ConfigError, FusionEvalError


def _close(a, b, path="", tol=1e-12):
    """Nested dicts/lists equal, numbers to ``tol`` (relative)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (path, set(a) ^ set(b))
        for k in a:
            _close(a[k], b[k], f"{path}.{k}", tol)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _close(x, y, f"{path}[{i}]", tol)
    elif isinstance(a, float) or isinstance(b, float):
        assert abs(a - b) <= tol * max(1.0, abs(b)), (path, a, b)
    else:
        assert a == b, (path, a, b)


@pytest.fixture(scope="module")
def api_result(kitti_slice):
    return fe.run(fe.load_dataset(kitti_slice))


@pytest.mark.slow
def test_run_returns_the_metrics_of_the_command_line(api_result, slice_run):
    written = json.loads((slice_run / "metrics.json").read_text())
    assert written.pop("provenance")["inputs"]          # the file also says what made the figures; the API returns them
    _close(json.loads(json.dumps(api_result.metrics)), written)


@pytest.mark.slow
def test_write_produces_exactly_the_files_of_run_out(api_result, slice_run, tmp_path):
    out = api_result.write(tmp_path / "out")
    cli = sorted(p.name for p in slice_run.iterdir() if p.name != "check.md")
    assert sorted(p.name for p in out.iterdir()) == cli
    for name in cli:
        a, b = (out / name).read_bytes(), (slice_run / name).read_bytes()
        if name in ("report.md", "report.html", "metrics.json"):     # the provenance: the command line and the minute
            a, b = without_provenance(a), without_provenance(b)
        assert a == b, name


def test_trajectories_are_evo_trajectories(api_result):
    from evo.core.trajectory import PoseTrajectory3D

    tr = api_result.trajectories
    assert set(tr) == {"fused", "lidar", "gnss", "imu_only", "groundtruth"}
    assert isinstance(tr["fused"], PoseTrajectory3D) and tr["fused"].num_poses == len(api_result.series["fused"])
    assert np.allclose(tr["fused"].positions_xyz, api_result.series["fused"].p_w_m)


@pytest.mark.slow
def test_overrides_are_plain_python_values(kitti_slice):
    ds = fe.load_dataset(kitti_slice)
    a = fe.run(ds, overrides={"gnss.rate_hz": 2.0, "gnss.noise_std_m": [2.0, 2.0, 4.0]})
    assert a.metrics["gnss_degradation"]["rate_hz"] == 2.0 and a.config["gnss"]["noise_std_m"] == [2.0, 2.0, 4.0]
    b = fe.run(ds, overrides={"gnss": {"rate_hz": 2.0, "noise_std_m": [2.0, 2.0, 4.0]}})     # nested form
    _close(a.metrics, b.metrics)
    c = fe.run(ds, config={"filter": {"use_gnss": False}}, variant="nominal")
    assert c.config["filter"]["formulation"] == "nominal_state" and "gnss" not in c.metrics["nis"]
    with pytest.raises(ConfigError, match="unknown key 'gnss.rate'"):
        fe.run(ds, overrides={"gnss.rate": 2.0})
    with pytest.raises(ConfigError, match="gnss.rate_hz must be > 0"):
        fe.run(ds, overrides={"gnss.rate_hz": -1.0})


def test_errors_are_the_packages_exceptions_with_one_line_messages(tmp_path):
    with pytest.raises(FusionEvalError) as e:
        fe.load_dataset(tmp_path / "nope")
    assert "dataset not found" in str(e.value) and "\n" not in str(e.value)


@pytest.mark.slow
def test_evaluate_matches_evo_on_kitti_00(tmp_path):
    gt = shared_path("kitti-odometry", "00", "00_gt_kitti.txt")
    est = shared_path("kitti-odometry", "00", "00_poses_kitti.txt")
    m = fe.evaluate(gt, est, alignment="se3")
    assert m["estimates"]["00_poses_kitti"]["ape"]["translation_m"]["rmse"] == pytest.approx(3.515636, abs=2e-6)
    # evo trajectories (or pose series) work as well as files
    from fusion_eval.datasets.trajectory_file import read_trajectory
    ref = read_trajectory(gt).traj
    traj = read_trajectory(est).traj
    ref.meta["name"], traj.meta["name"] = "gt", "kiss-icp"
    m2 = fe.evaluate(ref, traj, alignment="se3")
    assert m2["estimates"]["kiss-icp"]["ape"]["translation_m"]["rmse"] == pytest.approx(3.515636, abs=2e-6)
    with pytest.raises(ConfigError, match="--alignment must be one of"):
        fe.evaluate(ref, traj, alignment="bogus")
    with pytest.raises(ConfigError, match="expected a PoseSeries, an evo PoseTrajectory3D or a trajectory file path"):
        fe.evaluate(ref, 42)
    # a KITTI pose file without times is matched by index: it cannot be compared with stamped poses
    with pytest.raises(FusionEvalError, match="both have stamps, or both be matched by index"):
        fe.evaluate(shared_path("kitti-odometry", "00", "00_gt_tum.txt"), est)


@pytest.mark.slow
def test_writing_a_run_leaves_the_hosts_matplotlib_as_it_was(kitti_slice, tmp_path):
    """res.write() imported the plots, which set matplotlib's backend to Agg and its axes.titley for the whole
    process: a notebook's inline figures stopped showing (an API review). The plots draw on figures of their own."""
    import subprocess
    import sys

    code = f"""
import matplotlib
matplotlib.use("svg")
import fusion_eval as fe
before = (matplotlib.get_backend(), matplotlib.rcParams["axes.titley"])
res = fe.run(fe.load_dataset({str(kitti_slice)!r}))
res.write({str(tmp_path / 'o')!r})
import pathlib
assert any(pathlib.Path({str(tmp_path / 'o')!r}).glob("*.png"))
print(before == (matplotlib.get_backend(), matplotlib.rcParams["axes.titley"]), before)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().startswith("True"), out.stdout


@pytest.mark.parametrize("call, needle", [
    (lambda fe: fe.run(None, overrides=[("gnss.rate_hz", 2.0)]), "overrides: expected a mapping"),
    (lambda fe: fe.load_dataset(5), "dataset: expected a path"),
    (lambda fe: fe.run({"imu": 1}), "dataset: expected a path"),
    (lambda fe: fe.run(None, config=42), "config: expected a file path"),
    (lambda fe: fe.run(None, progress=5), "progress: expected a callable"),
])
def test_api_arguments_of_the_wrong_kind_are_the_packages_errors(call, needle):
    """They raised AttributeError and TypeError from deep inside (an API review)."""
    import fusion_eval as fe
    from fusion_eval.errors import FusionEvalError

    with pytest.raises(FusionEvalError, match=needle):
        call(fe)
