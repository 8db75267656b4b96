#!/usr/bin/env python3
"""The two tables of issue 14, printed as Markdown:

    python scripts/parity_tables.py [--layouts-only | --parity-only] [--duration 120]

1. ``evaluate`` against evo: every file of ``../shared/data/evo-test-data`` (and the ROS_example.bag topics) x every
   alignment evo offers x both sync methods: evo's APE translation RMSE (its own pipeline: file_interface, sync_with,
   main_ape.ape) next to ours, and the largest difference over the six pose relations and six statistics;
2. one simulated drive (urban, automotive, seed 0) through every layout the simulator writes: the fused, lidar and
   GNSS APE RMSE of each, and the largest difference from the KITTI layout over every APE/RPE statistic.
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import fusion_eval as fe  # noqa: E402


def parity() -> None:
    from evo.core.sync_method import SyncMethod

    import test_evaluate_parity as t  # the cases and evo's pipeline, as the tests run them

    print("| case | association | alignment | evo APE trans RMSE [m] | fusion-eval [m] | max abs diff, 6 relations x 6 stats |")
    print("|---|---|---|---:|---:|---:|")
    for case in t.CASES:
        cid, sub, ref, est = case
        loaded = t._evo_load(sub, ref, est)
        for association in ("nearest", "interpolate"):
            if sub == "kitti" and association == "interpolate":
                continue
            sm = SyncMethod.interpolation if association == "interpolate" else SyncMethod.nearest_time
            for alignment in t.EVO_ALIGN:
                ours = t._ours(sub, ref, est, association, alignment)
                worst, evo_rmse = 0.0, None
                for rel in t.ALL_RELATIONS:
                    res = t._evo_ape(copy.deepcopy(loaded), sm, alignment, rel)
                    got = ours["ape"][t.keys.RELATION_KEYS[rel]]
                    worst = max(worst, max(abs(got[s] - float(res.stats[s])) for s in t.keys.STATS))
                    if rel == "trans_part":
                        evo_rmse = float(res.stats["rmse"])
                print(f"| {cid} | {association} | {alignment} | {evo_rmse:.6f} | "
                      f"{ours['ape']['translation_m']['rmse']:.6f} | {worst:.1e} |")


def layouts(duration_s: float) -> None:
    from fusion_eval.simulate.dataset import simulate

    import test_layouts as t

    with tempfile.TemporaryDirectory() as tmp:
        ms = {}
        for layout in ("kitti", *t.LAYOUTS):
            simulate(Path(tmp) / layout, "urban", duration_s, seed=0, grade="automotive", sets=(f"output.layout={layout}",))
            ms[layout] = fe.run(Path(tmp) / layout).metrics
        ref = dict(t._stats(ms["kitti"]))
        print(f"| layout | fused APE RMSE [m] | lidar [m] | GNSS [m] | max abs diff from KITTI, {len(ref)} APE/RPE statistics |")
        print("|---|---:|---:|---:|---:|")
        for layout, m in ms.items():
            got = dict(t._stats(m))
            worst = max(abs(got[k] - v) for k, v in ref.items())
            e = m["estimates"]
            print(f"| {layout} | {e['fused']['ape']['translation_m']['rmse']:.9f} | {e['lidar']['ape']['translation_m']['rmse']:.6f} | "
                  f"{e['gnss']['ape']['translation_m']['rmse']:.6f} | {worst:.1e} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts-only", action="store_true")
    ap.add_argument("--parity-only", action="store_true")
    ap.add_argument("--duration", type=float, default=120.0, help="simulated seconds of the layouts' drive")
    a = ap.parse_args()
    if not a.layouts_only:
        parity()
        print()
    if not a.parity_only:
        layouts(a.duration)


if __name__ == "__main__":
    main()
