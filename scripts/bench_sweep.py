#!/usr/bin/env python3
"""Figures of issue 5: the five-setting noise study on data/kitti-00 with --jobs 2 against one run, and a
sweep killed mid-way and resumed.

    python scripts/bench_sweep.py
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def cli() -> list[str]:
    exe = Path(sys.executable).parent / "fusion-eval"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "fusion_eval"]


def timed(args: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cli() + args, check=True, cwd=ROOT)
    return time.perf_counter() - t0


def main() -> None:
    sweep = str(ROOT / "configs" / "sweeps" / "noise5.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        timed(["-q", "run", "--out", f"{tmp}/warm"])          # numba cache
        one = timed(["-q", "run", "--out", f"{tmp}/one"])
        jobs2 = timed(["-q", "sweep", "--grid", sweep, "--out", f"{tmp}/sweep", "--jobs", "2"])
        print(f"one fusion-eval run (default, plots):            {one:6.1f} s")
        print(f"sweep noise5.yaml (6 runs: default + 5), --jobs 2: {jobs2:6.1f} s  ({6 * one / jobs2:.1f}x one run's rate)")
        print((Path(tmp) / "sweep" / "sweep.md").read_text())
        # resume: kill a sweep after two runs are recorded, run it again
        out = Path(tmp) / "killed"
        p = subprocess.Popen(cli() + ["-q", "sweep", "--grid", sweep, "--out", str(out), "--jobs", "1"], cwd=ROOT,
                             start_new_session=True)
        while len(list((out / "records").glob("*.json"))) < 2:
            time.sleep(0.2)
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        n = len(list((out / "records").glob("*.json")))
        print(f"killed the sweep (SIGKILL) with {n} of 6 runs recorded")
        r = subprocess.run(cli() + ["sweep", "--grid", sweep, "--out", str(out), "--jobs", "2"], cwd=ROOT,
                           capture_output=True, text=True, check=True)
        print("resumed:", r.stdout.strip().splitlines()[0])


if __name__ == "__main__":
    main()
