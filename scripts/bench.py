#!/usr/bin/env python3
"""Benchmarks of issue 2: the filter's IMU samples per second and the wall time of a whole default run.

    python scripts/bench.py [--samples 1000000] [--runs 3]

Prints, on this machine:
  1. propagation throughput (mechanization + covariance, compiled kernels) for the 15-state filter and
     with a cloned pose (21 states), over a synthetic IMU stream;
  2. the replay of data/kitti-00 (IMU + lidar + GNSS updates), in IMU samples per second;
  3. the wall time of `fusion-eval -q run` on the default dataset with plots, after a warm-up run that
     fills numba's cache (median of --runs).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fusion_eval import session  # noqa: E402
from fusion_eval.config import Settings, load_config  # noqa: E402
from fusion_eval.filters.formulations.base import canonical_prior_std, gap_of  # noqa: E402
from fusion_eval.filters.formulations.eskf import ErrorStateKF  # noqa: E402
from fusion_eval.filters.formulations.imu_model import imu_inputs  # noqa: E402
from fusion_eval.filters.state import NominalState  # noqa: E402
from fusion_eval.prepare import prepare, settings_for  # noqa: E402
from fusion_eval.replay import replay  # noqa: E402


def propagation_rate(n_samples: int, clone: bool, discretization: str = "first_order") -> float:
    rng = np.random.default_rng(0)
    t = np.arange(n_samples) * 0.01
    f = np.tile([0.0, 0.0, 9.81], (n_samples, 1)) + rng.normal(size=(n_samples, 3)) * 0.1
    w = rng.normal(size=(n_samples, 3)) * 0.01
    s = Settings(load_config(None, ("imu.accel_noise_mps2_sqrthz=0.3", "imu.gyro_noise_dps_sqrthz=0.1",
                                    f"filter.discretization={discretization}")))
    prm = ErrorStateKF.run_params(s, 9.81)
    x0 = NominalState(np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3))
    kf = ErrorStateKF(x0, np.diag(canonical_prior_std(s) ** 2), prm, t, imu_inputs(f, w), 0, gap_of(s, t))
    if clone:
        kf.clone_pose()
    kf.predict_to(t[100])  # compile / load from cache
    t0 = time.perf_counter()
    kf.predict_to(t[-1])
    return (n_samples - 101) / (time.perf_counter() - t0)


def replay_rate() -> tuple[float, float, int]:
    ds = session.dataset(ROOT / "data" / "kitti-00")
    cfg = session.resolve(session.request(config=ROOT / "configs" / "default.yaml"), ds)
    prep = prepare(ds, cfg)
    s = settings_for(cfg, prep)
    imu_only = replay(prep, s).imu_only  # warm-up
    t0 = time.perf_counter()
    out = replay(prep, s, imu_only=imu_only)
    dt = time.perf_counter() - t0
    return out.n_imu_samples / dt, dt, out.n_imu_samples


def run_wall(runs: int) -> list[float]:
    exe = Path(sys.executable).parent / "fusion-eval"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "fusion_eval"]
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(runs + 1):
            t0 = time.perf_counter()
            subprocess.run(cmd + ["-q", "run", "--out", f"{tmp}/r{i}"], check=True, cwd=ROOT)
            if i > 0:   # the first run compiles or loads the numba cache
                times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--runs", type=int, default=3, help="timed default runs (0: skip them)")
    a = ap.parse_args()
    r15 = propagation_rate(a.samples, clone=False)
    r21 = propagation_rate(a.samples, clone=True)
    print(f"propagation, 15 states:            {r15:12,.0f} IMU samples/s  (first order; target >= 250,000)")
    print(f"propagation, 21 states (clone):    {r21:12,.0f} IMU samples/s")
    n_vl = max(a.samples // 20, 2000)          # the matrix exponential is slow: fewer samples
    v15 = propagation_rate(n_vl, clone=False, discretization="van_loan")
    v21 = propagation_rate(n_vl, clone=True, discretization="van_loan")
    print(f"propagation, Van Loan, 15 / 21:    {v15:12,.0f} / {v21:,.0f} IMU samples/s  "
          f"({r15 / v15:.1f}x / {r21 / v21:.1f}x the first-order cost per sample)")
    rr, dt, n = replay_rate()
    print(f"replay of kitti-00 with updates:   {rr:12,.0f} IMU samples/s  ({n} samples, "
          f"4.4k lidar + 0.5k GNSS updates, {dt * 1000:.0f} ms)")
    if a.runs < 1:
        return
    times = run_wall(a.runs)
    print(f"fusion-eval run (default, plots):  {statistics.median(times):12.2f} s wall, median of {len(times)} "
          f"(all: {', '.join(f'{t:.2f}' for t in times)}; target < 5 s)")


if __name__ == "__main__":
    main()
