#!/usr/bin/env python3
"""The wall time of the default run against another revision, timed in alternation (A B A B ...), as ratios.

    python scripts/bench_versions.py REV [--runs 5] [--args '-q run --no-plots']

Checks REV out into a temporary git worktree and runs ``python -m fusion_eval ARGS --out ...`` there and in this
checkout with the same interpreter, after one warm-up each (numba's cache); prints each side's median and the
median of the pairwise ratios this / REV (a shared, noisy machine drifts; the pairs do not).
"""

from __future__ import annotations

import argparse
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def timed(cwd: Path, args: list[str], out: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "fusion_eval", *args, "--out", str(out)], cwd=cwd, check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("rev")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--args", default="-q run")
    a = ap.parse_args()
    args = shlex.split(a.args)
    with tempfile.TemporaryDirectory() as tmp:
        other = Path(tmp) / "other"
        subprocess.run(["git", "worktree", "add", "--detach", str(other), a.rev], cwd=ROOT, check=True,
                       capture_output=True)
        shared = ROOT.parent / "shared"
        if shared.exists():     # ../shared beside the other checkout too: the same relative data paths work in both
            (Path(tmp) / "shared").symlink_to(shared)
        try:
            mine, theirs = [], []
            for i in range(a.runs + 1):
                t_mine = timed(ROOT, args, Path(tmp) / f"a{i}")
                t_theirs = timed(other, args, Path(tmp) / f"b{i}")
                if i > 0:                    # the first pair fills numba's caches
                    mine.append(t_mine)
                    theirs.append(t_theirs)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(other)], cwd=ROOT, capture_output=True)
    ratios = [m / t for m, t in zip(mine, theirs)]
    print(f"fusion-eval {a.args}: this checkout {statistics.median(mine):.2f} s, {a.rev} {statistics.median(theirs):.2f} s "
          f"(medians of {a.runs}); ratio this/{a.rev}: median {statistics.median(ratios):.3f} "
          f"(min {min(ratios):.3f}, max {max(ratios):.3f})")


if __name__ == "__main__":
    main()
