#!/usr/bin/env python3
"""Figures of issue 7: RMSE of the lidar/radar tracker on generated data (5 seeds, each sensor set) and the
NIS statistics, and the RTS smoother's (``track --smooth``) beside them; with a path argument, also on that
measurement file (e.g. the public EKF dataset).

    python scripts/bench_track.py [MEASUREMENTS.txt]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fusion_eval.tracking.ekf import TrackParams, rmse, run_track, smooth  # noqa: E402
from fusion_eval.tracking.measurements import read_measurements  # noqa: E402
from fusion_eval.tracking.report import nis_summary  # noqa: E402
from fusion_eval.tracking.simulate import simulate_track  # noqa: E402


def show(label: str, m) -> None:
    for s in ("both", "lidar", "radar"):
        res = smooth(run_track(m, TrackParams(sensors=s)))
        e, es = rmse(res), rmse(res, smoothed=True)
        nis = ", ".join(f"NIS {k} mean {d['mean']:.2f}, {d['fraction_above_95'] * 100:.1f} % above 95 % line"
                        for k, d in nis_summary(res).items())
        print(f"{label:<22} {s:<6} RMSE [px py vx vy] = [{e[0]:.4f} {e[1]:.4f} {e[2]:.4f} {e[3]:.4f}], smoothed (RTS) "
              f"[{es[0]:.4f} {es[1]:.4f} {es[2]:.4f} {es[3]:.4f}] = {np.round(es / e, 2).tolist()} x  {nis}")


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        allr = []
        for seed in range(5):
            p = Path(tmp) / f"s{seed}.txt"
            p.write_text(simulate_track(seed=seed))
            m = read_measurements(p)
            show(f"generated seed {seed}", m)
            allr.append(rmse(run_track(m, TrackParams())))
        print(f"mean over seeds, both sensors: {np.round(np.mean(allr, axis=0), 4).tolist()}")
    if len(sys.argv) > 1:
        show(Path(sys.argv[1]).name, read_measurements(Path(sys.argv[1])))


if __name__ == "__main__":
    main()
