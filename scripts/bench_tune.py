#!/usr/bin/env python3
"""Issue 16's figures: the time of a 100-trial tune against one default run measured in the same session (target
<= 20x on 2 cores), and what the tuner finds on kitti-00 and, blind, on the other raw drives.

    python scripts/bench_tune.py [--trials 100] [--skip-quality]

Quality cases (each a study of --trials trials, -j 2): kitti-00 with IMU + lidar + GNSS under the no-truth ``nll`` and
the truth ``fused.ape.rmse`` objectives; kitti-00 with IMU + GNSS only (``imu-gnss`` space) under both, with the raw
drives of ../shared/data/kitti-raw/2011_09_30/ held out. Prints the fused APE RMSE of the default and tuned configs.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RAW = ROOT.parent / "shared" / "data" / "kitti-raw" / "2011_09_30"
CLI = [sys.executable, "-m", "fusion_eval", "-q"]


def timed(args) -> float:
    t0 = time.perf_counter()
    subprocess.run(CLI + args, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def ape(rec) -> dict:
    out = {}
    for st in (rec or {}).get("steps", []):
        out.setdefault(Path(st["dataset"]).name, []).append(st["metrics"]["fused.ape.rmse"])
    return {k: sum(v) / len(v) for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--skip-quality", action="store_true")
    ap.add_argument("--seeds", type=int, default=3, help="Monte-Carlo seeds per drive of the quality studies (the "
                    "objective's mean over them; the held-out figures are means over as many)")
    ap.add_argument("--study-seeds", type=int, default=1, help="repeat each quality study with sampler seeds 0..N-1")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        timed(["run", "--out", str(tmp / "warm"), "--no-plots"])          # numba's cache warm for both
        runs = [timed(["run", "--out", str(tmp / f"r{i}"), "--no-plots"]) for i in range(3)]
        one = sorted(runs)[1]
        t_tune = timed(["tune", "--objective", "nll", "--trials", str(a.trials), "-j", "2", "--batch", "2",
                        "-o", str(tmp / "t"), "--no-plots"])
        t_full = timed(["tune", "--objective", "nll", "--trials", str(a.trials), "-j", "2", "--batch", "2",
                        "-o", str(tmp / "t-full"), "--no-plots", "--no-prune"])
        states = [r["state"] for r in csv.DictReader((tmp / "t" / "trials.csv").open())]
        best = {k: json.loads((tmp / k / "best.json").read_text())["values"][0] for k in ("t", "t-full")}
        print(f"one default run {one:.2f} s (median of 3); tune, {a.trials} trials, nll, -j 2: {t_tune:.1f} s = "
              f"{t_tune / one:.1f}x one run (target <= 20x); {states.count('PRUNED')} trials pruned (inside the "
              f"replay: nll); without pruning {t_full:.1f} s = {t_full / one:.1f}x, pruned/unpruned "
              f"{t_tune / t_full:.2f}; best nll {best['t']:.5f} pruned, {best['t-full']:.5f} unpruned")
        if a.skip_quality:
            return
        held = [str(RAW / d) for d in sorted(p.name for p in RAW.glob("*_sync"))] if RAW.is_dir() else []
        cases = [("IMU+lidar+GNSS", "noise", (), "nll", []), ("IMU+lidar+GNSS", "noise", (), "fused.ape.rmse", []),
                 ("IMU+GNSS", "imu-gnss", ("-s", "filter.lidar_update=none"), "nll", held),
                 ("IMU+GNSS", "imu-gnss", ("-s", "filter.lidar_update=none"), "fused.ape.rmse", held)]
        for i, (what, space, sets, obj, test), sd in ((i, c, sd) for i, c in enumerate(cases) for sd in range(a.study_seeds)):
            out = tmp / f"q{i}-{sd}"
            args = ["tune", "--space", space, *sets, "--objective", obj, "--trials", str(a.trials), "-j", "2",
                    "--batch", "2", "--seeds", str(a.seeds), "--seed", str(sd), "-o", str(out), "--no-plots"] + \
                [x for d in test for x in ("--test", d)]
            dt = timed(args)
            d = json.loads((out / "default.json").read_text())
            b = json.loads((out / "best.json").read_text())
            dflt = {**ape(d["train"]), **ape(d.get("test"))}
            tuned = {**ape(b["train"]), **ape(b.get("test"))}
            cells = ", ".join(f"{k}: {dflt[k]:.3f} -> {tuned.get(k, float('nan')):.3f}" for k in dflt)
            print(f"{what}, objective {obj}, sampler seed {sd}, {a.seeds} MC seeds ({dt:.0f} s): fused APE RMSE m, "
                  f"default -> tuned: {cells}", flush=True)

if __name__ == "__main__":
    main()
