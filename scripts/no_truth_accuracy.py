"""How far a run without ground truth gets: each drive run through a manifest without its groundtruth stream (the
filter starting from the data), its fused estimate then scored with evo's APE against the truth it did not see,
beside the run started from the truth and the GNSS alone (README "A drive without ground truth").

    python scripts/no_truth_accuracy.py            # kitti-00, SiMpLE 05/06/07, raw 2011_09_30 0018/0020/0027
    python scripts/no_truth_accuracy.py --quick    # kitti-00 and raw 0018

Prints one Markdown table: APE translation RMSE (unaligned) and the start's errors against the truth's pose with the
stds the start stated. Needs ../shared/data for all but kitti-00.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"


def without_truth(manifest: Path, out: Path) -> Path:
    """``manifest`` without its groundtruth stream and lidar anchor, written to ``out`` with absolute paths."""
    text = manifest.read_text(encoding="utf-8")
    text, n = re.subn(r"  groundtruth:\n    format: kitti_oxts\n    path: [^\n]+\n", "", text)
    if n != 1:
        raise SystemExit(f"{manifest}: no kitti_oxts groundtruth stream to remove")
    text = re.sub(r"    anchor: groundtruth[^\n]*\n", "", text)
    text = re.sub(r"(path|file): ([^ }\n]+)", lambda m: f"{m.group(1)}: {(manifest.parent / m.group(2)).resolve()}", text)
    out.write_text(text, encoding="utf-8")
    return out


def raw_manifest(folder: Path, out: Path, truth: bool) -> Path:
    """A raw KITTI drive as IMU + GNSS (+ its OXTS solution as truth), a car."""
    oxts = folder / "oxts"
    out.write_text(f"name: {folder.name}\nplatform: car\ngeodetic_origin: first_fix\nstreams:\n"
                   f"  imu: {{format: kitti_oxts, path: {oxts}, gyro_lag_s: auto}}\n"
                   f"  gnss: {{format: kitti_oxts, path: {oxts}}}\n"
                   + (f"  groundtruth: {{format: kitti_oxts, path: {oxts}}}\n" if truth else ""), encoding="utf-8")
    return out


def start_errors(ds_truth, overrides: dict) -> dict:
    """The start from the data against the truth's pose at the same instant, and the stds it stated."""
    from fusion_eval import session
    from fusion_eval.interp import interpolate_pose_at
    from fusion_eval.prepare import prepare
    from fusion_eval.so3 import log_so3

    cfg = session.resolve(session.request(overrides=overrides), ds_truth)
    cfg["filter"].update(init_pose_from="data", init_velocity_from="data")
    prep = prepare(ds_truth, cfg)
    t = float(prep.imu.t_s[prep.k_start])
    p, R, v = interpolate_pose_at(prep.groundtruth, t)
    rot = np.degrees(log_so3(R.T @ prep.x0.R_wb))
    return {"tilt_deg": float(np.hypot(rot[0], rot[1])), "yaw_deg": float(abs(rot[2])),
            "pos_m": float(np.linalg.norm(prep.x0.p_w_m - p)), "vel_mps": float(np.linalg.norm(prep.x0.v_w_mps - v)),
            "std": prep.applied["init_state"]["std"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="kitti-00 and raw 0018 only")
    args = ap.parse_args()
    import fusion_eval as fe

    cases = [("kitti-00 (KISS-ICP + GNSS)", ROOT / "data" / "kitti-00" / "dataset.yaml", None)]
    if not args.quick:
        cases += [(f"SiMpLE {n} (SiMpLE + GNSS)", ROOT / "configs" / "datasets" / f"simple-{n}.yaml", None)
                  for n in ("05", "06", "07")]
    raw = ("0018",) if args.quick else ("0018", "0020", "0027")
    cases += [(f"raw 2011_09_30_{d} (IMU + GNSS)", None, SHARED / "kitti-raw" / "2011_09_30" / f"2011_09_30_drive_{d}_sync")
              for d in raw]
    print("| drive | fused from the data [m] | fused from the truth's start [m] | GNSS alone [m] | heading off / stated "
          "[deg] | tilt off / stated [deg] | position off / stated [m] |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for label, manifest, folder in cases:
            if folder is not None and not folder.is_dir() or manifest is not None and "shared" in manifest.read_text(
                    encoding="utf-8") and not SHARED.is_dir():
                print(f"| {label} | (needs {SHARED}) | | | | | |")
                continue
            sets = {} if folder is None else {"filter.lidar_update": "none"}
            if folder is None:
                blind, seen = without_truth(manifest, Path(tmp) / "blind.yaml"), manifest
            else:
                blind, seen = (raw_manifest(folder, Path(tmp) / f"{n}.yaml", t) for n, t in (("blind", False), ("seen", True)))
            a = fe.run(fe.load_dataset(blind), overrides=sets)
            ds_truth = fe.load_dataset(seen)
            b = fe.run(ds_truth, overrides=sets)
            ref = b.trajectories["groundtruth"]
            m = fe.evaluate(ref, a.trajectories["fused"])
            ape = next(iter(m["estimates"].values()))["ape"]["translation_m"]["rmse"]
            own = b.metrics["estimates"]
            err = start_errors(replace(ds_truth), sets)
            s = err["std"]
            print(f"| {label} | {ape:.3f} | {own['fused']['ape']['translation_m']['rmse']:.3f} | "
                  f"{own['gnss']['ape']['translation_m']['rmse']:.2f} | {err['yaw_deg']:.2f} / {s['yaw_std_deg']:.2f} | "
                  f"{err['tilt_deg']:.2f} / {s['roll_pitch_std_deg']:.2f} | {err['pos_m']:.2f} / {s['pos_std_m']:.2f} |",
                  flush=True)


if __name__ == "__main__":
    sys.exit(main())
