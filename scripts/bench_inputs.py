#!/usr/bin/env python3
"""The input-reading figure of issue 14, as ratios to a reference measured in the same run:

    python scripts/bench_inputs.py [--minutes 60] [--rate 200] [--repeats 5]

Writes one IMU stream of ``--minutes`` at ``--rate`` Hz (random samples, POSIX stamps) as the generic CSV the
simulator's ``csv_log`` layout writes (``imu.csv``: 17 significant digits, stamps with 9 decimals), as a EuRoC
``imu0/data.csv``, and as ``sensor_msgs/Imu`` in a ROS 1 bag, a ROS 2 sqlite3 bag and a ROS 2 MCAP bag; then times the
manifest's reader of each (the path ``fusion-eval run`` takes) in alternation with the CSV reader, and prints the
median time and the median of the per-round ratios to the CSV (target for the bags: <= 2x). Every reader's samples
are checked equal to the CSV's. A last row times ``pandas.read_csv`` of the same CSV alone, as a floor.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fusion_eval.datasets import csv_stream, euroc, rosbag  # noqa: E402
from fusion_eval.datasets._text import s_to_ns  # noqa: E402
from fusion_eval.datasets.streams import ReadContext  # noqa: E402
from fusion_eval.types import ImuSeries  # noqa: E402


def write_inputs(root: Path, n: int, rate: float) -> dict:
    rng = np.random.default_rng(1)
    t = 1767225600.0 + np.arange(n) / rate
    imu = ImuSeries(t_s=t, f_b_mps2=rng.normal(size=(n, 3)), w_b_rps=rng.normal(size=(n, 3)) * 0.1)
    g = lambda a: np.char.mod("%.17g", a)  # noqa: E731
    cols = [np.char.mod("%.9f", t), *g(imu.f_b_mps2).T, *g(imu.w_b_rps).T]
    (root / "imu.csv").write_text("t_s,ax,ay,az,wx,wy,wz\n" + "\n".join(",".join(r) for r in zip(*cols)) + "\n")
    (root / "mav0" / "imu0").mkdir(parents=True)
    cols = [s_to_ns(t).astype(str), *g(imu.w_b_rps).T, *g(imu.f_b_mps2).T]
    (root / "mav0" / "imu0" / "data.csv").write_text("#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n"
                                                     + "\n".join(",".join(r) for r in zip(*cols)) + "\n")
    stream = [rosbag.BagStream("/imu/data", "imu", imu, "imu_link")]
    rosbag.write_bag(root / "imu.bag", "rosbag1", stream)
    rosbag.write_bag(root / "imu_db3", "rosbag2", stream)
    rosbag.write_bag(root / "imu_mcap", "rosbag2", stream, storage="mcap")
    return {"t": t, "imu": imu}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=200.0)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    n = int(a.minutes * 60 * a.rate)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        ref = write_inputs(root, n, a.rate)
        print(f"{n:,} IMU samples ({a.minutes:g} min at {a.rate:g} Hz) written in {time.perf_counter() - t0:.1f} s")
        ctx = ReadContext(root=root, manifest=root / "dataset.yaml", origin=None, oxts=None)
        csv_entry = {"format": "csv", "path": "imu.csv", "columns": ["t", "ax", "ay", "az", "wx", "wy", "wz"]}
        readers = {
            "generic CSV (imu.csv)": lambda: csv_stream.read_imu(csv_entry, ctx),
            "EuRoC imu0/data.csv": lambda: euroc.read_imu({"path": "mav0/imu0/data.csv"}, ctx),
            "ROS 1 bag": lambda: rosbag.read_imu(root / "imu.bag", "/imu/data"),
            "ROS 2 bag, sqlite3": lambda: rosbag.read_imu(root / "imu_db3", "/imu/data"),
            "ROS 2 bag, MCAP": lambda: rosbag.read_imu(root / "imu_mcap", "/imu/data"),
            # a floor, not a reader: pandas' C parser on the same file, with no checks and no exact stamps
            "pandas.read_csv alone": lambda: pd.read_csv(root / "imu.csv", engine="c"),
        }
        times: dict[str, list[float]] = {k: [] for k in readers}
        for _ in range(a.repeats):
            for name, f in readers.items():
                t1 = time.perf_counter()
                s = f()
                times[name].append(time.perf_counter() - t1)
                if not name.startswith("pandas"):
                    assert np.array_equal(s.t_s, ref["t"]) and np.array_equal(s.f_b_mps2, ref["imu"].f_b_mps2), name
        base = times["generic CSV (imu.csv)"]
        print(f"{'reader':<24} {'median s':>9} {'x CSV (median of rounds)':>25}")
        for name, ts in times.items():
            ratios = [x / b for x, b in zip(ts, base)]
            print(f"{name:<24} {statistics.median(ts):9.3f} {statistics.median(ratios):25.2f}")


if __name__ == "__main__":
    main()
