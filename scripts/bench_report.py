#!/usr/bin/env python3
"""Issue 17's figures on every drive here: the report's size, the longest stretch without progress, ``-q``'s output,
the page in Chromium, and what the report costs, as a ratio to ``evo_ape`` on the same run's files.

    python scripts/bench_report.py [--drives kitti-00 simple-00 ...] [--no-browser]

Per drive (the embedded kitti-00, the four SiMpLE drives of ../shared/data, and the plain KITTI raw drives, IMU +
GNSS):
  - ``fusion-eval run`` (plots on, numba's cache warm) timed as a user runs it, against one
    ``evo_ape tum groundtruth.tum fused.tum`` on the files it wrote, timed right after (the ratio);
  - the size of report.html and the figures it embeds (target < 5 MB);
  - the longest time between two progress events of the same run in process (a stage start, an advance, the
    filter's fraction; target: no stage longer than 1 s without one; on a terminal the bar's clock also moves);
  - ``fusion-eval -q run``: the lines on stdout and stderr (target: exactly one, the output path, and none);
  - the page in headless Chromium: console messages (target: none).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "data"
RAW = SHARED / "kitti-raw"

DRIVES = {"kitti-00": ROOT / "data" / "kitti-00",
          **{f"simple-{n}": ROOT / "configs" / "datasets" / f"simple-{n}.yaml" for n in ("00", "05", "06", "07")},
          **{p.name.replace("_sync", ""): p for p in sorted(RAW.glob("*/*_sync"))}}
BIN = Path(sys.executable).parent


def timed(cmd, **kw) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    return time.perf_counter() - t0, r


class Gaps:
    """A progress recorder: the longest time between two events, and the stage it fell in."""

    def __init__(self):
        from fusion_eval.progress import Stages

        class Rec(Stages):
            def start(s, name, total=None):
                self.event(name)

            def advance(s, n=1):
                self.event(None)

            def __call__(s, fraction):
                self.event(None)

        self.rec, self.stage, self.t, self.worst = Rec(), None, time.perf_counter(), (0.0, None)

    def event(self, stage):
        now = time.perf_counter()
        if now - self.t > self.worst[0]:
            self.worst = (now - self.t, self.stage)
        self.t, self.stage = now, stage or self.stage


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drives", nargs="*", default=list(DRIVES))
    ap.add_argument("--no-browser", action="store_true")
    a = ap.parse_args()
    from fusion_eval import session
    from fusion_eval.pipeline import run_to_dir

    chromium = None if a.no_browser else next((shutil.which(c) for c in ("chromium", "chromium-browser")
                                                if shutil.which(c)), None)
    fe = [str(BIN / "fusion-eval")]
    print(f"{'drive':<24} {'run [s]':>8} {'evo_ape [s]':>11} {'ratio':>6} {'html [MB]':>9} {'figs':>4} "
          f"{'longest gap [s] (stage)':>24} {'-q out/err lines':>16} {'console':>7}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run(fe + ["-q", "run", "--out", str(tmp / "warm"), "--no-plots"], check=True, capture_output=True)
        for name in a.drives:
            path = DRIVES[name]
            if not path.exists():
                print(f"{name:<24} skipped: {path} not here")
                continue
            out = tmp / name
            t_run, r = timed(fe + ["run", str(path), "--out", str(out)])
            if r.returncode != 0:
                print(f"{name:<24} run failed: {r.stderr.strip().splitlines()[-1]}")
                continue
            t_evo, _ = timed([str(BIN / "evo_ape"), "tum", str(out / "groundtruth.tum"), str(out / "fused.tum")])
            page = (out / "report.html").read_text()
            gaps = Gaps()
            run_to_dir(path, session.request(), tmp / f"{name}-gaps", progress=gaps.rec)
            gaps.event(None)
            _, q = timed(fe + ["-q", "run", str(path), "--out", str(tmp / f"{name}-q"), "--no-plots"])
            console = "-"
            if chromium:
                _, c = timed([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                              f"--user-data-dir={tmp / 'profile'}", "--virtual-time-budget=5000",
                              "--enable-logging=stderr", "--v=0", f"--screenshot={tmp / (name + '.png')}",
                              (out / "report.html").resolve().as_uri()], timeout=120)
                console = str(sum(":CONSOLE" in ln or "Uncaught" in ln for ln in c.stderr.splitlines()))
            gap, stage = gaps.worst
            print(f"{name:<24} {t_run:>8.2f} {t_evo:>11.2f} {t_run / t_evo:>6.1f} "
                  f"{(out / 'report.html').stat().st_size / 1e6:>9.2f} {page.count('data:image/png;base64,'):>4} "
                  f"{f'{gap:.2f} ({stage})':>24} "
                  f"{f'{len(q.stdout.splitlines())}/{len(q.stderr.splitlines())}':>16} {console:>7}", flush=True)


if __name__ == "__main__":
    main()
