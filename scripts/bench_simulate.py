#!/usr/bin/env python3
"""Figures of issue 3: simulation speed, and the ESKF checked against simulated truth.

    python scripts/bench_simulate.py [--kitti-layout]

Prints, on this machine:
  1. the wall time of `fusion-eval simulate` for one hour at 200 Hz (csv layout; with --kitti-layout
     also the one-file-per-packet KITTI layout, which is bound by file creation);
  2. for a 5-minute urban loop, automotive grade, 100 Hz IMU, with the true noise parameters:
     the fraction of epochs whose position and attitude NEES lie inside the 95 % chi-square interval,
     and the final IMU bias errors in units of the filter's sigma, for IMU + GNSS + lidar map matching
     and for IMU + GNSS alone.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fusion_eval import session  # noqa: E402
from fusion_eval.evaluation.consistency import fraction_inside, pose_nees  # noqa: E402
from fusion_eval.datasets.manifest import load_dataset  # noqa: E402
from fusion_eval.prepare import prepare, settings_for  # noqa: E402
from fusion_eval.replay import replay  # noqa: E402


def cli() -> list[str]:
    exe = Path(sys.executable).parent / "fusion-eval"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "fusion_eval"]


def sim_time(tmp: str, layout: str) -> float:
    t0 = time.perf_counter()
    subprocess.run(cli() + ["-q", "simulate", f"{tmp}/hour-{layout}", "--duration", "3600", "--set", "imu.rate_hz=200",
                            "--set", f"output.layout={layout}"], check=True)
    return time.perf_counter() - t0


def consistency(tmp: str, mode: str, extra: tuple[str, ...]) -> None:
    d = Path(tmp) / f"urban-{mode}"
    if not d.exists():
        subprocess.run(cli() + ["-q", "simulate", str(d), "--profile", "urban", "--duration", "300", "--seed", "1",
                                "--set", f"lidar.mode={mode}", "--set", "output.layout=csv"], check=True)
    ds = load_dataset(d)
    cfg = session.resolve(session.request(sets=extra), ds)
    prep = prepare(ds, cfg)
    out = replay(prep, settings_for(cfg, prep))
    gt = prep.groundtruth
    i = np.searchsorted(gt.t_s, out.fused.t_s)
    n_pos, n_att = pose_nees(out.fused.p_w_m, out.fused.R_wb(), gt.p_w_m[i], gt.R_wb()[i], out.P_pos_att)
    truth = np.loadtxt(d / "truth" / "imu_biases.csv", delimiter=",", skiprows=1)
    k = np.searchsorted(truth[:, 0], out.fused.t_s[-1] - 1e-6)
    err_a = (out.accel_bias_b[-1] - truth[k, 1:4]) / out.sigma[-1, 9:12]
    err_g = (out.gyro_bias_b[-1] - truth[k, 4:7]) / out.sigma[-1, 12:15]
    fused = np.sqrt(np.mean(np.sum((out.fused.p_w_m - gt.p_w_m[i]) ** 2, axis=1)))
    label = "IMU + GNSS + map matching" if "filter.lidar_update=none" not in extra else "IMU + GNSS"
    print(f"{label:<28} NEES pos: mean {n_pos.mean():.2f}, {fraction_inside(n_pos, 3)[0] * 100:.1f} % inside; "
          f"att: mean {n_att.mean():.2f}, {fraction_inside(n_att, 3)[0] * 100:.1f} % inside; APE {fused:.3f} m")
    print(f"{'':<28} final bias error / sigma: accel {np.round(err_a, 2).tolist()}, gyro {np.round(err_g, 2).tolist()}; "
          f"gyro bias error {np.degrees(np.abs(out.gyro_bias_b[-1] - truth[k, 4:7])).max() * 3600:.2f} deg/h max, "
          f"accel {np.abs(out.accel_bias_b[-1] - truth[k, 1:4]).max() * 1000:.2f} mm/s^2 max")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kitti-layout", action="store_true", help="also time the one-file-per-packet layout (slow)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(cli() + ["-q", "simulate", f"{tmp}/warm", "--duration", "5"], check=True)   # numba cache
        print(f"simulate 1 h at 200 Hz, csv layout:   {sim_time(tmp, 'csv'):6.1f} s  (target < 10 s)")
        if a.kitti_layout:
            print(f"simulate 1 h at 200 Hz, KITTI layout: {sim_time(tmp, 'kitti'):6.1f} s  (720,001 packet files)")
        consistency(tmp, "map_matching", ())
        consistency(tmp, "map_matching", ("filter.lidar_update=none",))


if __name__ == "__main__":
    main()
