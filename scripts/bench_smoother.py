#!/usr/bin/env python3
"""What the smoothers add to a run: the filter's replay timed with and without ``smoother.method=rts`` (and
``batch`` when GTSAM is installed), in alternation in one process (the machines are shared: read the ratio).

    python scripts/bench_smoother.py [DATASET ...] [--runs 5] [--set KEY=VALUE ...]

Default dataset: the shipped kitti-00. Prints per dataset and method the median replay time, the median added time
and its ratio to the replay (issue 12's targets: RTS <= 1x; the batch estimate on kitti-00 within 30 s), the smoother
alone, and what it kept (epochs and bytes per epoch; keyframes and factors).
"""

from __future__ import annotations

import argparse
import statistics
import time

from fusion_eval import session
from fusion_eval.prepare import prepare, settings_for
from fusion_eval.replay import replay


def prepared(ds, sets, method):
    cfg = session.resolve(session.request(sets=(*sets, f"smoother.method={method}")), ds)
    prep = prepare(ds, cfg)
    return prep, settings_for(cfg, prep)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("datasets", nargs="*", default=["data/kitti-00"])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--set", dest="sets", action="append", default=[])
    a = ap.parse_args()
    try:
        import gtsam  # noqa: F401
        methods = ("rts", "batch")
    except ImportError:
        methods = ("rts",)
    for path in a.datasets:
        ds = session.dataset(path)
        p0, s0 = prepared(ds, a.sets, "none")
        for method in methods:
            bench(path, ds, p0, s0, a, method)


def bench(path, ds, p0, s0, a, method) -> None:
    p1, s1 = prepared(ds, a.sets, method)
    replay(p1, s1)                      # compile and warm the caches
    plain, added, back = [], [], []
    for _ in range(a.runs):
        t = time.perf_counter()
        replay(p0, s0)
        t_plain = time.perf_counter() - t
        t = time.perf_counter()
        f = replay(p1, s1)
        t_sm = time.perf_counter() - t
        plain.append(t_plain)
        added.append((t_sm - t_plain) / t_plain)
        back.append(f.smoother_info["backward_s"])
    info = f.smoother_info
    kept = (f"{info['epochs']} epochs, {info['clones']} clones, {info['bytes_per_epoch']} bytes per epoch, record "
            f"{info['record_bytes'] / 1e6:.1f} MB" if method == "rts" else
            f"{info['keyframes']} keyframes, {info['factors']} factors, {info['iterations']} LM iterations")
    print(f"{path} {method}: replay {statistics.median(plain):.3f} s; the smoother adds {statistics.median(added):.2f}x "
          f"the replay (min {min(added):.2f}, max {max(added):.2f}); the smoother alone {statistics.median(back):.3f} s; "
          f"{kept}")


if __name__ == "__main__":
    main()
