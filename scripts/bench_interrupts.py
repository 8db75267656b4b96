#!/usr/bin/env python3
"""Issue 15's interrupt figures: how long ``run`` and ``sweep`` take to exit after SIGINT / SIGTERM, and what they
leave behind.

    python scripts/bench_interrupts.py [--repeats 3] [--cold 10]

For each case it starts the command, waits until it is writing (``run``: its staging folder exists; ``sweep``: two
runs are recorded), sends the signal, and prints the seconds to exit (min / median / max over the repeats; target
<= 2 s), the exit code, whether a staging folder or a process of the command's group is left, and for the sweep how
many runs were recorded and whether the rerun redid none of them. ``--cold N`` adds N runs with an empty numba cache
(a fresh install's first run, which compiles for about a minute), each sent SIGINT at another moment of the
compilation: how many exit 130 (none lost, none with a traceback) and how long after the signal.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from conftest import make_slice, wait_for  # noqa: E402

CLI = [sys.executable, "-m", "fusion_eval"]


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)     # as a terminal's foreground command, even from a background job


def _start(args, cwd, env=None):
    return subprocess.Popen(CLI + args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, stdin=subprocess.DEVNULL, env=env, preexec_fn=_default_sigint)


def cold_case(delay_s: float, tmp: Path) -> tuple[float, int, bool]:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp / "numba-cache"))
    p = _start(["run", "--out", str(tmp / "out")], tmp, env=env)
    time.sleep(delay_s)
    t0 = time.time()
    os.kill(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=300)
    return time.time() - t0, p.returncode, "Traceback" in err or "Exception ignored" in err


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def run_case(sig: int, tmp: Path) -> tuple[float, int, bool, bool]:
    out = tmp / "out"
    p = _start(["run", "--out", str(out)], tmp)
    wait_for(lambda: any(tmp.glob(".out.partial-*")), 120)
    time.sleep(0.5)
    t0 = time.time()
    os.kill(p.pid, sig)
    p.communicate(timeout=60)
    dt = time.time() - t0
    time.sleep(0.5)
    return dt, p.returncode, bool(list(tmp.glob(".out.*"))), _group_alive(p.pid)


def sweep_case(sig: int, tmp: Path) -> tuple[float, int, int, bool]:
    ds = make_slice(tmp / "ds", 300)
    grid = tmp / "grid.yaml"
    grid.write_text("settings:\n" + "".join(f"  s{i}: {{imu.gyro_noise_dps_sqrthz: {0.002 * (i + 1)}}}\n" for i in range(8)))
    out = tmp / "sw"
    args = ["sweep", str(ds), "--grid", str(grid), "--out", str(out), "--jobs", "2", "--no-batch"]
    p = _start(args, tmp)
    wait_for(lambda: len(list((out / "records").glob("*.json"))) >= 2, 300)
    t0 = time.time()
    os.kill(p.pid, sig)
    p.communicate(timeout=60)
    dt = time.time() - t0
    kept = {f.stem for f in (out / "records").glob("*.json")}
    r = subprocess.run(CLI + args, cwd=tmp, capture_output=True, text=True)
    ok = f"{len(kept)} already recorded" in r.stdout + r.stderr and r.returncode == 0
    return dt, p.returncode, len(kept), ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cold", type=int, default=0, metavar="N", help="N runs signalled during numba's compilation")
    a = ap.parse_args()
    if a.cold:
        res = []
        for i in range(a.cold):                          # moments spread over the ~60 s of compilation
            with tempfile.TemporaryDirectory() as tmp:
                res.append(cold_case(1.0 + 40.0 * i / max(a.cold - 1, 1), Path(tmp)))
        dts = sorted(r[0] for r in res)
        print(f"run   SIGINT during compilation ({a.cold} moments, 1-41 s after start): exit 130 in "
              f"{sum(r[1] == 130 for r in res)}, lost (exit 0) {sum(r[1] == 0 for r in res)}, traceback "
              f"{sum(r[2] for r in res)}; exit after {dts[0]:.2f} / {statistics.median(dts):.2f} / {dts[-1]:.2f} s")
    with tempfile.TemporaryDirectory() as warm:        # numba's cache compiled once, as on a user's second run
        subprocess.run(CLI + ["-q", "run", "--out", str(Path(warm) / "w"), "--no-plots"], check=True)
    for name, sig in (("SIGINT", signal.SIGINT), ("SIGTERM", signal.SIGTERM)):
        res = []
        for _ in range(a.repeats):
            with tempfile.TemporaryDirectory() as tmp:
                res.append(run_case(sig, Path(tmp)))
        dts = [r[0] for r in res]
        print(f"run   {name}: exit after {min(dts):.2f} / {statistics.median(dts):.2f} / {max(dts):.2f} s (min/median/max), "
              f"codes {sorted({r[1] for r in res})}, staging left {any(r[2] for r in res)}, processes left {any(r[3] for r in res)}")
    res = []
    for _ in range(a.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            res.append(sweep_case(signal.SIGINT, Path(tmp)))
    dts = [r[0] for r in res]
    print(f"sweep SIGINT: exit after {min(dts):.2f} / {statistics.median(dts):.2f} / {max(dts):.2f} s, codes "
          f"{sorted({r[1] for r in res})}, runs recorded {[r[2] for r in res]}, rerun redid none: {all(r[3] for r in res)}")


if __name__ == "__main__":
    main()
