"""A sweep on a real dask cluster (issue 15): a ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1,
started in another working directory than the sweep's, which gives relative paths; one worker is killed mid-sweep.
Every run must be recorded exactly once, with its outputs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import make_slice, wait_for

DASK = Path(sys.executable).with_name("dask")


def _scheduler_address(sched_file: Path) -> str | None:
    try:
        return json.loads(sched_file.read_text(encoding="utf-8"))["address"]
    except (OSError, ValueError, KeyError):
        return None


@pytest.mark.slow
@pytest.mark.skipif(not DASK.exists(), reason="needs dask's command line (pip install 'dask[distributed]')")
def test_sweep_on_a_real_cluster_survives_a_killed_worker(tmp_path):
    elsewhere = tmp_path / "workers"
    elsewhere.mkdir()
    here = tmp_path / "user"
    here.mkdir()
    make_slice(here / "ds", 200)
    (here / "grid.yaml").write_text("settings:\n" + "".join(
        f"  s{i}: {{imu.gyro_noise_dps_sqrthz: {0.002 * (i + 1)}}}\n" for i in range(7)))
    sched_file = tmp_path / "scheduler.json"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    procs = [subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], cwd=elsewhere, env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    try:
        # dask writes the file in place (not renamed into place): it exists empty, or half-written, before it parses
        assert wait_for(lambda: _scheduler_address(sched_file) is not None, 60)
        address = _scheduler_address(sched_file)
        for _ in range(2):
            procs.append(subprocess.Popen([str(DASK), "worker", address, "--nthreads", "1", "--nworkers", "1",
                                           "--no-dashboard", "--host", "127.0.0.1"], cwd=elsewhere, env=env,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        sweep = subprocess.Popen([sys.executable, "-m", "fusion_eval", "-q", "sweep", "ds", "--grid", "grid.yaml",
                                  "--out", "sw", "--scheduler", address, "--no-batch"], cwd=here, env=env,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        # kill one worker once the first runs are recorded (its running task goes to the other worker)
        assert wait_for(lambda: len(list((here / "sw" / "records").glob("*.json"))) >= 2 or sweep.poll() is not None, 600)
        os.killpg(procs[1].pid, signal.SIGKILL)
        out, err = sweep.communicate(timeout=900)
        assert sweep.returncode == 0, err
        recs = [json.loads(f.read_text()) for f in (here / "sw" / "records").glob("*.json")]
        ids = [r["id"] for r in recs]
        assert len(ids) == len(set(ids)) == 8                       # the 7 settings and the default, once each
        assert all(r["status"] == "ok" for r in recs), [r.get("error") for r in recs]
        for r in recs:
            assert (here / "sw" / "runs" / r["id"] / "metrics.json").exists()
        assert not list(elsewhere.rglob("metrics.json"))          # nothing written relative to the workers' directory
    finally:
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
