#!/usr/bin/env python3
"""Why IMU + lidar can lose to the lidar alone without GNSS, and what `lidar.relative_frame` changes (issue 11):
body, world and heading frames.

    python scripts/odometry_frames.py [--only simple-06]

For each lidar drive (the embedded kitti-00 and the SiMpLE manifests), IMU + relative lidar without GNSS (IMU noise
of configs/lidar-imu.yaml), with body-frame and world-frame increments: APE translation RMSE of the fused estimate
and of the lidar, and against the ground truth (analysis only, nothing here sets a default): the yaw error RMS,
the horizontal and vertical position error RMS, and the mean lateral error of 1 s position increments in the
true body frame (a path that veers off the true heading shows there). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

DRIVES = [("kitti-00", ROOT / "data" / "kitti-00")] + [
    (f"simple-{s}", ROOT / "configs" / "datasets" / f"simple-{s}.yaml") for s in ("00", "05", "06", "07")]
NO_GNSS = {"filter.lidar_update": "relative", "filter.use_gnss": False,
           "imu.accel_noise_mps2_sqrthz": 0.3, "imu.gyro_noise_dps_sqrthz": 0.1}


def errors(est, gt) -> dict:
    """Yaw, horizontal, vertical and 1 s lateral-increment errors of ``est`` against ``gt`` at est's 1 s stamps."""
    from fusion_eval.interp import interpolate_poses
    from fusion_eval.so3 import quat_xyzw_to_matrix

    step = max(1, int(round(1.0 / np.median(np.diff(est.t_s)))))
    t = est.t_s[::step]
    g = interpolate_poses(gt, t)
    keep = np.isin(t, g.t_s)
    idx = np.flatnonzero(keep) * step
    P, Rm = est.p_w_m[idx], quat_xyzw_to_matrix(est.q_wb_xyzw[idx])
    Pg, Rg = g.p_w_m, quat_xyzw_to_matrix(g.q_wb_xyzw)
    yaw = np.arctan2(Rm[:, 1, 0], Rm[:, 0, 0]) - np.arctan2(Rg[:, 1, 0], Rg[:, 0, 0])
    yaw = np.degrees((yaw + np.pi) % (2 * np.pi) - np.pi)
    e = P - Pg
    d_est = np.einsum("nji,nj->ni", Rg[:-1], np.diff(P, axis=0))      # increments in the true body frame
    d_true = np.einsum("nji,nj->ni", Rg[:-1], np.diff(Pg, axis=0))
    return {"yaw_deg": float(np.sqrt(np.mean(yaw ** 2))), "horiz_m": float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, 1)))),
            "vert_m": float(np.sqrt(np.mean(e[:, 2] ** 2))), "lateral_cm": float(np.mean(d_est[:, 1] - d_true[:, 1]) * 100)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="", help="substring of the drive label")
    a = ap.parse_args()
    import fusion_eval as fe

    print("| drive | frame | fused APE [m] | lidar APE [m] | fused/lidar | yaw RMS fused / lidar [deg] | "
          "horizontal RMS fused / lidar [m] | vertical RMS fused / lidar [m] | 1 s lateral mean fused / lidar [cm] |")
    print("|---|---|---:|---:|---:|---|---|---|---|")
    for label, path in DRIVES:
        if a.only not in label:
            continue
        if not path.exists() or (path.suffix == ".yaml" and not (ROOT.parent / "shared" / "data").exists()):
            print(f"skipped {label}: its data is absent", file=sys.stderr)
            continue
        for frame in ("body", "world", "heading"):
            r = fe.run(path, overrides={**NO_GNSS, "lidar.relative_frame": frame})
            m = r.metrics["estimates"]
            fa, la = (m[k]["ape"]["translation_m"]["rmse"] for k in ("fused", "lidar"))
            gt = r.series["groundtruth"]
            ef, el = errors(r.series["fused"], gt), errors(r.series["lidar"], gt)
            print(f"| {label} | {frame} | {fa:.3f} | {la:.3f} | {fa / la:.2f} | {ef['yaw_deg']:.2f} / {el['yaw_deg']:.2f} | "
                  f"{ef['horiz_m']:.2f} / {el['horiz_m']:.2f} | {ef['vert_m']:.2f} / {el['vert_m']:.2f} | "
                  f"{ef['lateral_cm']:+.1f} / {el['lateral_cm']:+.1f} |")


if __name__ == "__main__":
    main()
