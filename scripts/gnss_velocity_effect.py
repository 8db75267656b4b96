#!/usr/bin/env python3
"""What fusing the GNSS velocity does: fused APE with and without it, on kitti-00 and on a simulated drive.

    python scripts/gnss_velocity_effect.py [--sim-duration 300]

Prints a Markdown table (APE translation and rotation RMSE, NIS of the velocity) measured with the public API.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import fusion_eval as fe  # noqa: E402

CASES = [
    ("IMU + relative lidar + GNSS (default)", {}),
    ("  + GNSS velocity (E, N, U)", {"filter.use_gnss_velocity": True}),
    ("  + GNSS velocity (E, N)", {"filter.use_gnss_velocity": True, "gnss_velocity.components": "en"}),
    ("IMU + GNSS", {"filter.lidar_update": "none"}),
    ("  + GNSS velocity (E, N, U)", {"filter.lidar_update": "none", "filter.use_gnss_velocity": True}),
    ("  + GNSS velocity (E, N)", {"filter.lidar_update": "none", "filter.use_gnss_velocity": True,
                                  "gnss_velocity.components": "en"}),
]


HEADER = ["| dataset | case | APE trans RMSE [m] | APE rot RMSE [deg] | NIS velocity mean (dof) |", "|---|---|---:|---:|---|"]


def table(name: str, ds) -> list[str]:
    rows = []
    for i, (label, ov) in enumerate(CASES):
        m = fe.run(ds, overrides=ov).metrics
        ape = m["estimates"]["fused"]["ape"]
        nis = m["nis"].get("gnss_velocity")
        rows.append(f"| {name if i == 0 else ''} | {label} | {ape['translation_m']['rmse']:.3f} | {ape['rotation_deg']['rmse']:.3f} | "
                    + ("" if nis is None else f"{nis['mean']:.2f} ({nis['dof']})") + " |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sim-duration", type=float, default=300.0)
    a = ap.parse_args()
    out = HEADER + table("kitti-00", fe.load_dataset(ROOT / "data" / "kitti-00"))
    with tempfile.TemporaryDirectory() as tmp:
        from fusion_eval.commands.simulate import simulate

        simulate(Path(tmp) / "urban", "urban", a.sim_duration, 0, "automotive", ("output.layout=csv",))
        out += table(f"simulated urban, {a.sim_duration:g} s", fe.load_dataset(Path(tmp) / "urban"))
    print("\n".join(out))


if __name__ == "__main__":
    main()
