"""``fusion-eval compare``: several filter variants on one dataset, in one table and a few plots.

Each variant is a configuration overlay (``configs/variants/<name>.yaml`` or a path) applied on top of
the defaults, the manifest's suggested settings and the optional base ``--config``; ``--set`` applies
to every variant. The unfiltered estimates (lidar odometry, GNSS, IMU dead reckoning) come from the
first variant's streams and are evaluated once.
"""

from __future__ import annotations

import csv
import io
import re
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from .config import Settings, load_config
from .datasets.manifest import load_dataset
from .datasets.tum import format_tum
from .errors import ConfigError
from .evaluation import evaluate, ratio
from .outputs import StagedDir
from .pipeline import _executor
from .prepare import prepare
from .replay import replay
from .report import versions
from .types import PoseSeries

log = logging.getLogger(__name__)

VARIANT_DIR = Path("configs/variants")


def resolve_variant(name: str, variant_dir: Path) -> Path:
    p = Path(name)
    if p.suffix in (".yaml", ".yml") and p.exists():
        return p
    cand = variant_dir / f"{name}.yaml"
    if cand.exists():
        return cand
    known = sorted(f.stem for f in variant_dir.glob("*.yaml")) if variant_dir.is_dir() else []
    raise ConfigError(f"unknown variant {name!r} (no {cand}; known: {', '.join(known) or 'none'})")


@dataclass
class VariantRun:
    name: str
    cfg: dict
    filt: object
    ev: object
    runtime_s: float


def _nees_fraction(gt: PoseSeries, filt) -> float | None:
    """Fraction of epochs whose position NEES (against the ground truth) is inside the 95 % interval."""
    from .consistency import fraction_inside, pose_nees
    from .interp import interpolate_poses

    gi = interpolate_poses(gt, filt.fused.t_s)
    sel = np.isin(filt.fused.t_s, gi.t_s)
    n_pos, _ = pose_nees(filt.fused.p_w_m[sel], filt.fused.R_wb()[sel], gi.p_w_m, gi.R_wb(), filt.P_pos_att[sel])
    n_pos = n_pos[np.isfinite(n_pos)]
    return float(fraction_inside(n_pos, 3)[0]) if n_pos.size else None


def folder_name(name: str, taken: set) -> str:
    """A safe, unique folder name for a variant (a path given as a variant must not leave the output)."""
    base = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(name).stem) or "variant"
    out, i = base, 1
    while out in taken:
        i += 1
        out = f"{base}-{i}"
    taken.add(out)
    return out


def body_velocity(poses: PoseSeries) -> np.ndarray:
    """Body-frame velocity ``R^T v`` (forward, lateral, vertical) of poses that carry a velocity."""
    return np.einsum("nji,nj->ni", poses.R_wb(), poses.v_w_mps)


def compare(dataset_path: Path, variants: list[str], variant_dir: Path, base_config: Path | None, sets: tuple[str, ...],
            out_dir: Path, overwrite: bool = False, make_plots: bool = True,
            progress: Callable[[float], None] | None = None) -> dict:
    staged = StagedDir(out_dir, overwrite=overwrite)
    staged.check()
    if len(set(variants)) != len(variants) or not variants:
        raise ConfigError("--variants needs one or more distinct names")
    paths = [resolve_variant(v, variant_dir) for v in variants]
    ds = load_dataset(dataset_path)
    layers = []
    if ds.description.get("config"):
        layers.append((ds.description["config"], f"{ds.description['manifest']} (config)"))
    if base_config is not None:
        if not Path(base_config).exists():
            raise ConfigError(f"{base_config}: config file not found")
        layers.append((yaml.safe_load(Path(base_config).read_text()) or {}, str(base_config)))
    cfgs = [load_config(p, sets, layers=tuple(layers)) for p in paths]   # all validated before any work

    runs: list[VariantRun] = []
    base_prep = None
    for i, (name, cfg) in enumerate(zip(variants, cfgs)):
        t0 = time.perf_counter()
        prep = prepare(ds, cfg)
        base_prep = base_prep or prep
        with np.errstate(over="ignore", invalid="ignore"):
            filt = replay(prep, Settings(cfg))
        runs.append(VariantRun(name, cfg, filt, None, time.perf_counter() - t0))
        log.info("variant %s: filtered in %.2f s", name, runs[-1].runtime_s)
        if progress:
            progress((i + 1) / (len(variants) + 1))

    gt = base_prep.groundtruth
    ev_cfg = cfgs[0]["evaluation"]
    unfiltered: dict[str, PoseSeries] = {"imu_only": runs[0].filt.imu_only}
    if base_prep.lidar is not None:
        unfiltered["lidar"] = base_prep.lidar
    if base_prep.gnss is not None:
        unfiltered["gnss"] = base_prep.gnss.as_poses()
    with _executor(None) as pool:
        args = (ev_cfg["t_max_diff_s"], ev_cfg["rpe_delta_m"], ev_cfg["association"], ev_cfg["alignment"])
        fut_v = [pool.submit(evaluate, gt, r.filt.fused, r.name, *args) for r in runs]
        fut_u = {k: pool.submit(evaluate, gt, s, k, *args) for k, s in unfiltered.items()}
        for r, f in zip(runs, fut_v):
            r.ev = f.result()
            r.ev.results = {}
        evs_u = {k: f.result() for k, f in fut_u.items()}
    if progress:
        progress(1.0)

    table = []
    for r in runs:
        m = r.ev.metrics
        row = {"variant": r.name, "estimate": "fused", "matched_poses": r.ev.matched_poses,
               "ape_trans_rmse_m": m["ape"]["translation_m"]["rmse"], "ape_rot_rmse_deg": m["ape"]["rotation_deg"]["rmse"],
               "rpe_1frame_trans_rmse_m": (m.get("rpe_1frame") or {}).get("translation_m", {}).get("rmse"),
               f"rpe_{ev_cfg['rpe_delta_m']:g}m_trans_rmse_m": ((m.get(f"rpe_{ev_cfg['rpe_delta_m']:g}m") or {}).get("translation_m") or {}).get("rmse"),
               "fused_over_lidar": ratio(r.ev, evs_u.get("lidar")), "fused_over_gnss": ratio(r.ev, evs_u.get("gnss")),
               "final_accel_bias_mps2": r.filt.accel_bias_b[-1].tolist(),
               "final_gyro_bias_dph": (np.degrees(r.filt.gyro_bias_b[-1]) * 3600).tolist(),
               "nis_mean": {k: float(np.mean(v["nis"])) for k, v in r.filt.nis.items()},
               "kitti_drift_t_err_pct": (r.ev.drift or {}).get("t_err_pct"),
               "kitti_drift_r_err_deg_per_100m": (r.ev.drift or {}).get("r_err_deg_per_100m"),
               "nees_position_in_95": _nees_fraction(gt, r.filt),
               "runtime_s": round(r.runtime_s, 3)}
        vb = body_velocity(r.filt.fused)
        row["body_velocity_rms_mps"] = {"lateral": float(np.sqrt(np.mean(vb[:, 1] ** 2))),
                                        "vertical": float(np.sqrt(np.mean(vb[:, 2] ** 2)))}
        table.append(row)
    for k, ev in evs_u.items():
        m = ev.metrics
        table.append({"variant": "(unfiltered)", "estimate": k, "matched_poses": ev.matched_poses,
                      "ape_trans_rmse_m": m["ape"]["translation_m"]["rmse"],
                      "ape_rot_rmse_deg": (m["ape"].get("rotation_deg") or {}).get("rmse"),
                      "rpe_1frame_trans_rmse_m": ((m.get("rpe_1frame") or {}).get("translation_m") or {}).get("rmse"),
                      "kitti_drift_t_err_pct": (ev.drift or {}).get("t_err_pct"),
                      "kitti_drift_r_err_deg_per_100m": (ev.drift or {}).get("r_err_deg_per_100m")})
    gt_vb = body_velocity(gt) if gt.v_w_mps is not None else None
    truth_body = None if gt_vb is None else {"lateral": float(np.sqrt(np.mean(gt_vb[:, 1] ** 2))),
                                             "vertical": float(np.sqrt(np.mean(gt_vb[:, 2] ** 2)))}

    # per-segment breakdown: every variant and the unfiltered lidar and GNSS, windows along the route
    from .segments import breakdown

    errs = {r.name: (r.ev.ape_t_s, r.ev.ape_err_m) for r in runs if r.ev.ape_err_m is not None}
    errs.update({k: (ev.ape_t_s, ev.ape_err_m) for k, ev in evs_u.items() if k != "imu_only" and ev.ape_err_m is not None})
    seg = breakdown(gt, errs, ev_cfg["segment_m"], ev_cfg["segment_s"], primary=runs[0].name,
                    secondary="lidar" if "lidar" in errs else None)

    with staged as out:
        result = {"dataset": ds.name, "variants": variants, "rows": table, "groundtruth_body_velocity_rms_mps": truth_body,
                  "segments": seg}
        out.write_text("compare.json", json.dumps(result, indent=2) + "\n")
        out.write_text("compare.csv", _csv(table))
        from .report import _segments_section

        out.write_text("compare.md", _markdown(ds.name, table, truth_body, make_plots)
                       + "\n".join(_segments_section({"segments": seg})) + "\n")
        taken: set = set()
        for r in runs:
            folder = folder_name(r.name, taken)
            out.write_text(f"variants/{folder}/fused.tum", format_tum(r.filt.fused, f"fusion-eval compare: variant {r.name}"))
            out.write_text(f"variants/{folder}/config.resolved.yaml",
                           yaml.safe_dump({**r.cfg, "versions": versions()}, sort_keys=False))
        if make_plots:
            from . import plots

            plots.plot_compare_ape(out.path("ape_over_time.png"), runs, evs_u, float(runs[0].filt.fused.t_s[0]))
            plots.plot_compare_biases(out.path("biases.png"), runs)
            plots.plot_compare_body_velocity(out.path("body_velocity.png"), runs, gt, gt_vb)
    return result


def _csv(rows: list[dict]) -> str:
    cols = ["variant", "estimate", "matched_poses", "ape_trans_rmse_m", "ape_rot_rmse_deg", "rpe_1frame_trans_rmse_m",
            "fused_over_lidar", "fused_over_gnss", "kitti_drift_t_err_pct", "kitti_drift_r_err_deg_per_100m",
            "nees_position_in_95", "runtime_s"]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else (f"{r[k]:.6f}" if isinstance(r.get(k), float) else r[k])) for k in cols})
    return buf.getvalue()


def _f(x, nd=3):
    return "n/a" if x is None else f"{x:.{nd}f}"


def _pct(x) -> str:
    return "" if x is None else f"{x * 100:.1f} %"


def _bv(bv) -> str:
    return "" if not bv else f"{bv['lateral']:.3f} / {bv['vertical']:.3f}"


def _markdown(name: str, rows: list[dict], truth_body, plots: bool) -> str:
    L = [f"# fusion-eval compare: {name}", "",
         "| variant | estimate | APE trans RMSE [m] | APE rot RMSE [deg] | RPE trans 1 frame [m] | fused/lidar | fused/GNSS | "
         "KITTI drift [%] / [deg/100 m] | NEES pos in 95 % | "
         "lateral / vertical body velocity RMS [m/s] | final gyro bias [deg/h] | mean NIS | filter time [s] |",
         "|---|---|---:|---:|---:|---:|---:|---|---:|---|---|---|---:|"]
    for r in rows:
        bv = r.get("body_velocity_rms_mps")
        L.append(f"| {r['variant']} | {r['estimate']} | {_f(r['ape_trans_rmse_m'])} | {_f(r.get('ape_rot_rmse_deg'))} | "
                 f"{_f(r.get('rpe_1frame_trans_rmse_m'), 4)} | {_f(r.get('fused_over_lidar'))} | {_f(r.get('fused_over_gnss'))} | "
                 f"{_f(r.get('kitti_drift_t_err_pct'))} / {_f(r.get('kitti_drift_r_err_deg_per_100m'))} | "
                 f"{_pct(r.get('nees_position_in_95'))} | "
                 f"{_bv(bv)} | "
                 f"{'' if 'final_gyro_bias_dph' not in r else ', '.join(f'{b:.1f}' for b in r['final_gyro_bias_dph'])} | "
                 f"{'' if 'nis_mean' not in r else ', '.join(f'{k} {v:.2f}' for k, v in r['nis_mean'].items())} | "
                 f"{r.get('runtime_s', '')} |")
    if truth_body:
        L += ["", f"Ground truth body velocity RMS: lateral {truth_body['lateral']:.3f} m/s, vertical {truth_body['vertical']:.3f} m/s."]
    if plots:
        L += ["", "![APE over time](ape_over_time.png)", "![biases](biases.png)", "![body velocity](body_velocity.png)"]
    return "\n".join(L) + "\n"
