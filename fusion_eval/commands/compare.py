"""``fusion-eval compare``: several filter variants on one dataset, in one table and a few plots.

Each variant is a configuration overlay (a name in ``configs/variants`` or a path) applied on top of the
defaults, the manifest's suggested settings and the optional base ``--config``; ``--set`` applies to every
variant (:mod:`fusion_eval.session`). The unfiltered estimates (lidar odometry, GNSS, IMU dead reckoning)
come from the first variant's streams and are evaluated once; a variant whose prepared lidar or GNSS differs (its own
seed, rate or noise of the degraded GNSS, a lidar offset) has its ratios to them against the streams it fused.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from .. import compile_notice, session
from ..datasets.tum import format_tum
from ..errors import ConfigError, DataRangeError, FilterDivergedError
from .. import trials as mc
from ..evaluation import keys, span
from ..evaluation.run_metrics import (inconsistent_streams, nees, scored_warnings, segments, sparsely_matched,
                                       stated_noise, truth_velocity_w)
from ..evaluation.trajectory import evaluate, ratio
from ..filters import observations
from ..log_context import collected
from ..outputs import StagedDir, dataset_roots, default_dir, repeated_path
from ..prepare import check_streams
from ..pool import executor
from ..prepare import prepare, settings_for
from ..replay import replay
from ..report.files import versions
from ..report.markdown import segments_section
from ..progress import as_stages
from ..provenance import header_line, input_files
from ..report import html
from ..tables import cell, csv_text, latex, latex_document, markdown
from ..types import PoseSeries
from ..variants import folder_name, resolve_variant
from .. import yaml_lines

log = logging.getLogger(__name__)


@dataclass
class VariantRun:
    name: str
    cfg: dict
    filt: object
    ev: object
    runtime_s: float
    ev_smoothed: object = None      # the smoother's estimate, when the variant selects one
    warnings: tuple[str, ...] = ()  # the data's and the filter's, as a run of this variant reports them
    compile_s: float = 0.0          # numba's compilation inside the variant's first run (not in runtime_s)
    seeded: tuple[str, ...] = ()    # the fused streams drawn with a seed (:func:`fusion_eval.trials.seeded_streams`)
    applied: dict | None = None     # its preparation's record (what `auto` chose: the lidar frame the warnings name)
    nees: dict | None = None        # its NEES over the scored span (the warnings' and the table's, computed once)
    streams: dict | None = None     # its prepared lidar and GNSS, where they differ from the first variant's
    own_u: dict | None = None       # their evaluations: its estimate_over_* are against the streams it fused


def body_velocity(poses: PoseSeries) -> np.ndarray:
    """Body-frame velocity ``R^T v`` (forward, lateral, vertical) of poses that carry a velocity."""
    return np.einsum("nji,nj->ni", poses.R_wb(), poses.v_w_mps)


def _rms_lateral_vertical(vb: np.ndarray) -> dict:
    return {"lateral": float(np.sqrt(np.mean(vb[:, 1] ** 2))), "vertical": float(np.sqrt(np.mean(vb[:, 2] ** 2)))}


def replay_variants(ds, variants: list[str], cfgs: list[dict], advance=None) -> tuple[list[VariantRun], object]:
    """Every variant's filter over the same dataset (dead reckoning once, from the first variant's streams)."""
    runs: list[VariantRun] = []
    base_prep = None
    for i, (name, cfg) in enumerate(zip(variants, cfgs)):
        t0, c0 = time.perf_counter(), compile_notice.compile_seconds()
        try:
            prep = prepare(ds, cfg)
            base_prep = base_prep or prep
            with np.errstate(over="ignore", invalid="ignore"):
                filt = replay(prep, settings_for(cfg, prep), imu_only=runs[0].filt.imu_only if runs else None)
        except (ConfigError, DataRangeError, FilterDivergedError) as exc:
            # which of the variants failed (an error of the data alone did not say: a review); a file's error names it
            raise type(exc)(f"variant {name!r}: {exc}") from None
        compiled = compile_notice.compile_seconds() - c0       # numba's first compilation of this variant's kernels
        # the variant's settings that do nothing (run says them from filter_and_evaluate, which compare does not
        # go through: it was silent about them once they moved there; a diff review)
        idle = session.inactive_warnings(ds, cfg)
        for w in idle:
            log.warning("variant %s: %s", name, w)
        runs.append(VariantRun(name, cfg, filt, None, time.perf_counter() - t0 - compiled,
                               warnings=(*idle, *_warnings(name, prep, filt, cfg)),
                               compile_s=compiled, applied=prep.applied,
                               seeded=tuple(mc.seeded_streams({"nis": filt.nis, "gnss_degradation": prep.gnss_info,
                                                               "preprocessing": prep.applied})),
                               streams=_own_streams(prep, base_prep)))
        log.info("variant %s: filtered in %.2f s%s", name, runs[-1].runtime_s,
                 f" (and {compiled:.1f} s compiling)" if compiled > 0 else "")
        if advance:
            advance()
    return runs, base_prep


def _streams(prep) -> dict:
    return {k: v for k, v in (("lidar", prep.lidar), ("gnss", prep.gnss.as_poses() if prep.gnss is not None else None))
            if v is not None}


def _own_streams(prep, base_prep) -> dict | None:
    """The variant's prepared lidar and GNSS that differ from the first variant's (a variant file's gnss.seed,
    rate_hz or std, a lidar offset or extrinsic): its estimate_over_gnss and _lidar were against the first's streams,
    not the ones it fused (0.559 in compare against 0.606 in its own run: a configuration audit)."""
    if prep is base_prep:
        return None
    mine, base = _streams(prep), _streams(base_prep)
    diff = {k: v for k, v in mine.items() if k not in base
            or not (np.array_equal(v.t_s, base[k].t_s) and np.array_equal(v.p_w_m, base[k].p_w_m))}
    return diff or None


def _warnings(name: str, prep, filt, cfg: dict) -> tuple[str, ...]:
    """What ``run`` would warn of for this variant: the prepared data's warnings (already said on stderr by the
    preparation) and the streams its filter does not follow (said here: an accelerometer in g gave 184 m in the
    table with no word, where run named four streams)."""
    misfit = inconsistent_streams({k: {"values": d["nis"], "dof": d["dof"], "t_s": d["t_s"], "rejected": d.get("rejected", 0),
                                       **({"adapt": d["adapt"]} if "adapt" in d else {})} for k, d in filt.nis.items()},
                                  stated_noise(prep, cfg))
    for w in misfit:
        log.warning("variant %s: %s", name, w)
    return (*prep.applied.get("data_warnings", ()), *misfit)


def _evaluate_all(runs: list[VariantRun], base_prep, ev_cfg: dict, pool):
    """evo's metrics of every variant and unfiltered estimate, over one span (evaluation.span, the first
    variant's setting); returns the unfiltered series, their evaluations and the span."""
    gt = base_prep.groundtruth
    unfiltered: dict[str, PoseSeries] = {"imu_only": runs[0].filt.imu_only, **_streams(base_prep)}
    spans = {r.name: span.coverage(r.filt.fused) for r in runs}
    spans.update({k: span.stream_coverage(k, s, base_prep.applied) for k, s in unfiltered.items()})
    sp = span.span_for(ev_cfg["span"], gt, spans)
    short = span.short_span_warning(sp, gt, (float(base_prep.imu.t_s[0]), float(base_prep.imu.t_s[-1])),
                                    {n: spans[n] for n in ("lidar", "gnss") if n in spans})
    if short:            # of the data, so of every variant (compare.md and compare.json list each one's warnings)
        log.warning("%s", short)
        for r in runs:
            r.warnings = (*r.warnings, short)
    ref = span.crop(gt, sp)              # as evo's --t_start/--t_end: the reference reduced to the span
    args = (ev_cfg["t_max_diff_s"], ev_cfg["rpe_delta_m"], ev_cfg["association"], ev_cfg["alignment"])
    # the filters' world frame is local ENU; evaluation.engine as a run takes it (compare ignored it: an audit)
    kw = {"up_axis": "z", "engine_name": ev_cfg["engine"]}
    fut_v = [pool.submit(evaluate, ref, r.filt.fused, r.name, *args, **kw) for r in runs]
    fut_s = [pool.submit(evaluate, ref, r.filt.smoothed.fused, r.name, *args, **kw) if r.filt.smoothed is not None
             else None for r in runs]
    fut_u = {k: pool.submit(evaluate, ref, s, k, *args, **kw) for k, s in unfiltered.items()}
    fut_own = [{k: pool.submit(evaluate, ref, s, k, *args, **kw) for k, s in (r.streams or {}).items()} for r in runs]
    evs_u = {k: f.result() for k, f in fut_u.items()}
    for r, own in zip(runs, fut_own):
        r.own_u = {k: f.result() for k, f in own.items()} or None
    for w in sparsely_matched(evs_u, ev_cfg["association"], ev_cfg["t_max_diff_s"]):    # of the data: said once
        log.warning("%s", w)
        for r in runs:
            r.warnings = (*r.warnings, w)
    for r, f, fs in zip(runs, fut_v, fut_s):
        r.ev = f.result()
        r.ev.results = {}
        if r.ev.matched_poses < 2:
            # no result, as run says it (a variant meeting no ground truth stopped the table with a KeyError; a review)
            fu = r.filt.fused
            raise DataRangeError(f"variant {r.name}: the fused estimate ({len(fu)} poses, {fu.t_s[0]:.3f}..{fu.t_s[-1]:.3f} s) "
                                 f"matches {r.ev.matched_poses} ground-truth poses ({gt.source}: {len(gt)} poses) within "
                                 f"evaluation.t_max_diff_s = {ev_cfg['t_max_diff_s']} s")
        if fs is not None:
            r.ev_smoothed = fs.result()
            r.ev_smoothed.results = {}
        # what run warns of once the estimates are scored (a variant fusing the GNSS that ends far worse than it, or
        # far outside its own covariance), over the span every variant is scored on
        r.nees = nees(ref, r.filt)
        for w in (sparsely_matched({"fused": r.ev}, ev_cfg["association"], ev_cfg["t_max_diff_s"]) +
                  scored_warnings({"fused": r.ev, "gnss": _baseline(r, evs_u, "gnss")}, r.filt.nis, r.nees,
                                  r.applied or {}, (r.filt.nis.get("gnss") or {}).get("t_s", ()))):
            log.warning("variant %s: %s", r.name, w)
            r.warnings = (*r.warnings, w)
    return unfiltered, evs_u, sp


def _baseline(r: VariantRun, evs_u: dict, stream: str):
    """The evaluation of the unfiltered ``stream`` this variant fused: its own where its preparation differs."""
    return (r.own_u or {}).get(stream) or evs_u.get(stream)


def _table(runs: list[VariantRun], evs_u: dict, gt: PoseSeries, ev_cfg: dict) -> list[dict]:
    """compare's rows; ``gt``: the ground truth over the evaluated span (each variant's NEES is taken over it)."""
    table = []
    for r in runs:
        table.append(_variant_row(r, gt, evs_u, ev_cfg))
        if r.ev_smoothed is not None:
            table.append(_variant_row(VariantRun(r.name, r.cfg, r.filt.smoothed, r.ev_smoothed, r.runtime_s,
                                                 compile_s=r.compile_s, own_u=r.own_u), gt, evs_u,
                                      ev_cfg, estimate="smoothed"))
    for k, ev in evs_u.items():
        m = ev.metrics
        ape = m.get("ape") or {}         # none where no pose matched (a GNSS 30 ms off the truth's stamps: a traceback)
        table.append({"variant": "(unfiltered)", "estimate": k, "matched_poses": ev.matched_poses,
                      "ape_trans_rmse_m": (ape.get("translation_m") or {}).get("rmse"),
                      "ape_rot_rmse_deg": (ape.get("rotation_deg") or {}).get("rmse"),
                      "rpe_1frame_trans_rmse_m": ((m.get("rpe_1frame") or {}).get("translation_m") or {}).get("rmse"),
                      "kitti_drift_t_err_pct": (ev.drift or {}).get("t_err_pct"),
                      "kitti_drift_r_err_deg_per_100m": (ev.drift or {}).get("r_err_deg_per_100m")})
    return table


def trial_table(ds, variants: list[str], cfgs: list[dict]) -> tuple[list[dict], list[str]]:
    """One Monte-Carlo trial of a comparison: its table and its warnings, unsaid (in a worker; the comparison sums
    them up, :func:`fusion_eval.trials.warnings`)."""
    with collected(show=False) as said:
        runs, base_prep = replay_variants(ds, variants, cfgs)
        _, evs_u, sp = _evaluate_all(runs, base_prep, cfgs[0]["evaluation"], executor(1))
        return _table(runs, evs_u, span.crop(base_prep.groundtruth, sp), cfgs[0]["evaluation"]), said


def compare(dataset_path: Path | None, variants: list[str], variant_dir: Path | None, base_config: Path | None,
            sets: tuple[str, ...], out_dir: Path | None, overwrite: bool = False, make_plots: bool = True,
            progress: Callable[[float], None] | None = None, trials: int = 1) -> dict:
    args = (dataset_path, variants, variant_dir, base_config, sets)
    if out_dir is not None:
        return _compare(*args, out_dir, overwrite, make_plots, progress, trials)
    with default_dir(Path("results") / f"compare-{time.strftime('%Y%m%d-%H%M%S')}") as out_dir:
        return _compare(*args, out_dir, overwrite, make_plots, progress, trials)


def _compare(dataset_path: Path | None, variants: list[str], variant_dir: Path | None, base_config: Path | None,
             sets: tuple[str, ...], out_dir: Path, overwrite: bool, make_plots: bool,
             progress: Callable[[float], None] | None, trials: int) -> dict:
    staged = StagedDir(out_dir, overwrite=overwrite, inputs=dataset_roots(dataset_path))
    staged.check()
    n_trials = mc.check_count(trials)
    if len(set(variants)) != len(variants) or not variants:
        raise ConfigError("--variants needs one or more distinct names")
    paths = [resolve_variant(v, variant_dir) for v in variants]
    twice = repeated_path(paths)            # one file named twice (by name and by path) would run and show twice
    if twice:
        a, b = (variants[paths.index(q)] for q in twice)
        raise ConfigError(f"--variants names one variant twice: {a!r} and {b!r} are both {twice[1]}")
    reqs = [session.request(config=base_config, variant=p, sets=sets) for p in paths]   # all validated before any work
    stages = as_stages(progress)
    stages.start("load")
    ds = session.dataset(dataset_path)
    if ds.groundtruth is None and n_trials > 1:
        raise ConfigError(f"dataset {ds.name!r} has no groundtruth stream: --trials averages scores against it; "
                          "compare the variants' innovations without --trials")
    cfgs = [session.resolve(r, ds) for r in reqs]
    make_plots = make_plots and cfgs[0]["output"]["plots"]     # --set output.plots=false as --no-plots (an audit)
    session.same_evaluation([f"{v!r}" for v in variants], cfgs, "--variants", "compare scores every variant the same "
                            "way; set evaluation.* for all of them (-c or --set), not in a variant file")
    for v, c in zip(variants, cfgs):      # every variant's streams before the first runs (one failed after the others)
        try:
            check_streams(ds, c)
        except ConfigError as exc:
            raise ConfigError(f"--variants {v!r}: {exc}") from None

    if ds.groundtruth is None:
        from .compare_innovations import compare_without_truth

        return compare_without_truth(ds, variants, cfgs, staged, make_plots, stages, out_dir)
    with executor(None) as pool, collected() as said:
        # trials 1.. on the pool (each one a whole comparison) while this process does trial 0 and its files
        trial_futs = [pool.submit(trial_table, ds, variants, [mc.apply(c, i) for c in cfgs]) for i in range(1, n_trials)]
        stages.start("variants", len(variants))
        runs, base_prep = replay_variants(ds, variants, cfgs, stages.advance)
        gt = base_prep.groundtruth
        ev_cfg = cfgs[0]["evaluation"]
        stages.start("evaluate")
        unfiltered, evs_u, sp = _evaluate_all(runs, base_prep, ev_cfg, pool)
        ref = span.crop(gt, sp)          # the evaluated span: the NEES and the segments as the metrics
        table = _table(runs, evs_u, ref, ev_cfg)
        tables = [table]
        if trial_futs:
            stages.start("trials", n_trials)
            stages.advance()
        later = []
        for f in trial_futs:
            t, w = f.result()
            tables.append(t)
            later.append(w)
            stages.advance()
        # the comparison's own: said here and in its evaluations (in the pool's workers)
        own = [*said, *(w for r in runs for e in (r.ev, r.ev_smoothed) if e is not None for w in e.said),
               *(w for e in evs_u.values() for w in e.said)]
        for w in mc.warnings(own, later):
            log.warning("%s", w)
    stages.start("write")
    trials_info = None
    seeds = {v: mc.effective_seeds(c) for v, c in zip(variants, cfgs)}     # the ranking's and compare.md's
    if n_trials > 1:
        trials_info = {"n": n_trials, "seeds": [mc.trial_overrides(cfgs[0], i) for i in range(n_trials)],
                       "per_trial": tables}
        table = mc.aggregate_rows(tables, ("variant", "estimate"))
        lead = mc.paired_lead({v: [next((r.get("ape_trans_rmse_m") for r in t if r["variant"] == v and
                                         r["estimate"] == "fused"), None) for t in tables] for v in variants},
                              seeds=seeds)
        if lead:
            trials_info["ranking"] = lead[1]
            trials_info["ranking_note"] = lead[0]
        if all(mc.all_equal([r.get("ape_trans_rmse_m") for t in tables for r in t if r["variant"] == v
                             and r["estimate"] == "fused"]) for v in variants):
            log.warning(mc.NOTHING_RANDOM.format(n=n_trials))

    # the truth's velocity as the run's plots take it (its positions' rate where its own is off them: KITTI's Up)
    gt_vb = body_velocity(replace(gt, v_w_mps=truth_velocity_w(gt)[0])) if gt.v_w_mps is not None else None
    truth_body = None if gt_vb is None else _rms_lateral_vertical(gt_vb)

    # per-segment breakdown: every variant and the unfiltered lidar and GNSS, windows along the route
    seg_evals = {r.name: r.ev for r in runs}
    seg_evals.update({f"{r.name} smoothed": r.ev_smoothed for r in runs if r.ev_smoothed is not None})
    seg_evals.update({k: ev for k, ev in evs_u.items() if k != "imu_only"})
    seg = segments(ref, seg_evals, ev_cfg, primary=runs[0].name)

    with staged as out:
        result = {"dataset": ds.name, "variants": variants, "span": sp if sp is not None else {"mode": "own"},
                  "rows": table, "groundtruth_body_velocity_rms_mps": truth_body, "segments": seg}
        if trials_info:
            result["trials"] = trials_info
        warned = {r.name: list(r.warnings) for r in runs if r.warnings}
        if warned:
            result["warnings"] = warned
        out.write_text("compare.json", json.dumps(result, indent=2) + "\n")
        out.write_text("compare.csv", _csv(table, bool(trials_info)))
        md = (_markdown(ds.name, table, truth_body, make_plots, sp, n_trials, warned, ev_cfg["alignment"],
                        list(dict.fromkeys(s for r in runs for s in r.seeded)),
                        (trials_info or {}).get("ranking_note"), seeds)
              + "\n".join(segments_section({"segments": seg}, note=(
                  f"Trial 0's windows (one seed; the table above gives the means over the {n_trials} trials)."
                  if n_trials > 1 else ""))) + "\n")
        out.write_text("compare.md", md)
        out.write_text("compare.tex", _latex(ds.name, table, n_trials, ev_cfg["alignment"]))
        taken: set = set()
        for r in runs:
            folder = folder_name(r.name, taken)
            out.write_text(f"variants/{folder}/fused.tum", format_tum(r.filt.fused, f"fusion-eval compare: variant {r.name}"))
            if r.filt.smoothed is not None:
                out.write_text(f"variants/{folder}/smoothed.tum",
                               format_tum(r.filt.smoothed.fused, f"fusion-eval compare: variant {r.name}, smoothed"))
            out.write_text(f"variants/{folder}/config.resolved.yaml",
                           yaml_lines.dump({**r.cfg, "versions": versions()}))
        if make_plots:
            from ..report import plots

            plots.plot_compare_ape(out.path("ape_over_time.png"), runs, evs_u, float(runs[0].filt.fused.t_s[0]))
            plots.plot_compare_biases(out.path("biases.png"), runs)
            plots.plot_compare_body_velocity(out.path("body_velocity.png"), runs, [body_velocity(r.filt.fused) for r in runs],
                                             gt, gt_vb)
        out.write_text("report.html", html.page(md, out.path("."), inputs=input_files(ds.description)))
    return {**result, "out_dir": str(out_dir)}


def _variant_row(r: VariantRun, gt: PoseSeries, evs_u: dict, ev_cfg: dict, estimate: str = "fused") -> dict:
    m = r.ev.metrics
    d = keys.rpe_distance_group(ev_cfg["rpe_delta_m"])
    # the NEES of the fused estimate as the warnings took it; a smoothed row's own (the whole consistency section,
    # NIS and the smoothed NEES included, was computed again here for each row)
    nees_pos = (r.nees if r.nees is not None else nees(gt, r.filt)).get("position")
    row = {"variant": r.name, "estimate": estimate, "matched_poses": r.ev.matched_poses,
           "ape_trans_rmse_m": m["ape"]["translation_m"]["rmse"], "ape_rot_rmse_deg": m["ape"]["rotation_deg"]["rmse"],
           "rpe_1frame_trans_rmse_m": (m.get("rpe_1frame") or {}).get("translation_m", {}).get("rmse"),
           f"{d}_trans_rmse_m": ((m.get(d) or {}).get("translation_m") or {}).get("rmse"),
           "estimate_over_lidar": ratio(r.ev, _baseline(r, evs_u, "lidar")),
           "estimate_over_gnss": ratio(r.ev, _baseline(r, evs_u, "gnss")),
           "final_accel_bias_mps2": r.filt.accel_bias_b[-1].tolist(),
           "final_gyro_bias_dph": (np.degrees(r.filt.gyro_bias_b[-1]) * 3600).tolist(),
           # one column per registered observation, found by name
           "nis_mean": {k: float(np.mean(v["nis"])) for k, v in r.filt.nis.items()},
           "kitti_drift_t_err_pct": (r.ev.drift or {}).get("t_err_pct"),
           "kitti_drift_r_err_deg_per_100m": (r.ev.drift or {}).get("r_err_deg_per_100m"),
           "nees_position_in_95": None if not nees_pos else nees_pos["fraction_in_95"],
           "runtime_s": round(r.runtime_s, 3)}
    if r.compile_s > 0:
        row["compile_s"] = round(r.compile_s, 3)
    if r.own_u:           # the unfiltered streams this variant fused, where they are not the table's (the first's)
        row["own_streams_ape_trans_rmse_m"] = {k: ((ev.metrics.get("ape") or {}).get("translation_m") or {}).get("rmse")
                                               for k, ev in r.own_u.items()}
    row["body_velocity_rms_mps"] = _rms_lateral_vertical(body_velocity(r.filt.fused))
    return row


CSV_COLUMNS = ["variant", "estimate", "matched_poses", "ape_trans_rmse_m", "ape_rot_rmse_deg", "rpe_1frame_trans_rmse_m",
               "estimate_over_lidar", "estimate_over_gnss", "kitti_drift_t_err_pct", "kitti_drift_r_err_deg_per_100m",
               "nees_position_in_95", "runtime_s"]


def _csv(rows: list[dict], trials: bool) -> str:
    """``compare.csv``: compare.md's columns, one value per cell (the body velocity's two axes, the final gyro bias's
    three, and the mean NIS of each observation a row has, in the registry's order)."""
    order = [o.name for o in observations.REGISTRY]
    nis_names = sorted({k for r in rows for k in (r.get("nis_mean") or {})}, key=lambda k: (order.index(k) if k in order else 99, k))
    extra = (["body_velocity_lateral_rms_mps", "body_velocity_vertical_rms_mps"]
             + [f"final_gyro_bias_{a}_dph" for a in "xyz"] + [f"nis_mean_{k}" for k in nis_names])
    flat = []
    for r in rows:
        f = dict(r)
        bv = r.get("body_velocity_rms_mps") or {}
        f["body_velocity_lateral_rms_mps"], f["body_velocity_vertical_rms_mps"] = bv.get("lateral"), bv.get("vertical")
        for a, b in zip("xyz", r.get("final_gyro_bias_dph") or []):
            f[f"final_gyro_bias_{a}_dph"] = float(b)
        for k, v in (r.get("nis_mean") or {}).items():
            f[f"nis_mean_{k}"] = v
        mp = f.get("matched_poses")
        if isinstance(mp, float) and mp.is_integer():     # a count, whatever the trials' mean made of it
            f["matched_poses"] = int(mp)
        flat.append(f)
    cols = CSV_COLUMNS[:-1] + extra + CSV_COLUMNS[-1:] + (["trials", "ape_trans_rmse_m_std"] if trials else [])
    return csv_text(cols, flat)


def _pct(x) -> str:
    return "" if x is None else f"{x * 100:.1f} %"


def _latex(name: str, rows: list[dict], n_trials: int, alignment: str = "none") -> str:
    """``compare.tex``: the accuracy columns of the comparison, booktabs, for a paper."""
    header = ["variant", "estimate", "APE trans RMSE [m]", "APE rot RMSE [deg]", "RPE trans 1 frame [m]",
              "estimate/lidar", "estimate/GNSS"]
    body = [[r["variant"], r["estimate"],
             cell(r["ape_trans_rmse_m"]) + (f" ± {cell(r['ape_trans_rmse_m_std'])}" if "ape_trans_rmse_m_std" in r else ""),
             r.get("ape_rot_rmse_deg"), cell(r.get("rpe_1frame_trans_rmse_m"), 4), r.get("estimate_over_lidar"),
             r.get("estimate_over_gnss")] for r in rows]
    mean = f", mean over {n_trials} Monte-Carlo trials" if n_trials > 1 else ""
    return latex_document([latex(header, body, align="llrrrrr", caption=f"{name}: filter variants against ground truth "
                                 f"(evo, {keys.alignment_words(alignment)}{mean}).", label=f"tab:{name.replace('/', '-')}-compare")],
                          f"fusion-eval compare: {name}")


def _markdown(name: str, rows: list[dict], truth_body, plots: bool, sp: dict | None = None, n_trials: int = 1,
              warned: dict | None = None, alignment: str = "none", seeded: list[str] | None = None,
              ranking_note: str | None = None, seeds: dict | None = None) -> str:
    """compare.md. ``seeds``: each variant's :func:`fusion_eval.trials.effective_seeds` (None: taken as equal)."""
    order = [o.name for o in observations.REGISTRY]
    header = ["variant", "estimate", "APE trans RMSE [m]", "APE rot RMSE [deg]", "RPE trans 1 frame [m]", "estimate/lidar",
              "estimate/GNSS", "KITTI drift [%] / [deg/100 m]", "NEES pos in 95 %", "lateral / vertical body velocity RMS [m/s]",
              "final gyro bias [deg/h]", "mean NIS", "filter time [s]"]
    body = []
    for r in rows:
        bv = r.get("body_velocity_rms_mps")
        nis = r.get("nis_mean") or {}
        ape = cell(r["ape_trans_rmse_m"]) + (f" +/- {cell(r['ape_trans_rmse_m_std'])}" if "ape_trans_rmse_m_std" in r else "")
        ci = r.get("ape_trans_rmse_m_ci95")
        if ci and all(v is not None for v in ci):        # the README promised it; only compare.json had it (an audit)
            ape += f" [{cell(ci[0])}, {cell(ci[1])}]"
        body.append([r["variant"], r["estimate"], ape, cell(r.get("ape_rot_rmse_deg")),
                     cell(r.get("rpe_1frame_trans_rmse_m"), 4), cell(r.get("estimate_over_lidar")), cell(r.get("estimate_over_gnss")),
                     f"{cell(r.get('kitti_drift_t_err_pct'))} / {cell(r.get('kitti_drift_r_err_deg_per_100m'))}",
                     _pct(r.get("nees_position_in_95")), "" if not bv else f"{bv['lateral']:.3f} / {bv['vertical']:.3f}",
                     ", ".join(f"{b:.1f}" for b in r.get("final_gyro_bias_dph", [])),
                     ", ".join(f"{k} {nis[k]:.2f}" for k in sorted(nis, key=lambda k: order.index(k) if k in order else 99)),
                     cell(r.get("runtime_s"), 2) + (f" (+{r['compile_s']:.1f} compiling)" if r.get("compile_s") else "")])
    L = [f"# fusion-eval compare: {name}", "", header_line(), "", f"Span: {span.describe(sp)}.", ""]
    if n_trials > 1:
        L += [f"Means over {n_trials} Monte-Carlo trials (the seeds of every random element; APE: mean +/- std "
              "[95 % interval of the mean, Student's t]); the "
              "plots and trajectories are trial 0's, every trial's table is in compare.json.", ""]
    L += [f"## Summary against ground truth (evo, {keys.alignment_words(alignment)})", ""] + markdown(header, body, align="llrrrrrlllllr")
    fused = sorted((r for r in rows if r["estimate"] == "fused" and r.get("ape_trans_rmse_m") is not None),
                   key=lambda r: r["ape_trans_rmse_m"])
    note = mc.one_draw_note(fused[0]["ape_trans_rmse_m"], fused[1]["ape_trans_rmse_m"], n_trials,
                            "The best variant's fused APE leads the next by", streams=seeded,
                            paired=not seeds or seeds.get(fused[0]["variant"]) == seeds.get(fused[1]["variant"])) \
        if len(fused) > 1 else None
    if note:
        L += ["", note]
    if ranking_note:
        L += ["", ranking_note]
    own = {(r["variant"]): r["own_streams_ape_trans_rmse_m"] for r in rows if r.get("own_streams_ape_trans_rmse_m")}
    for v, d in own.items():          # the table's unfiltered rows are the first variant's streams (a review of the diff)
        L += ["", f"`{v}` degrades or shifts its streams otherwise than the first variant: its estimate/lidar and "
              f"estimate/GNSS are to the streams it fused ("
              + ", ".join(f"{k} alone {cell(a)} m" for k, a in d.items()) + "), not to the unfiltered rows."]
    if any(r.get("compile_s") for r in rows):
        L += ["", "Filter time: the variant's preparation and replay, without numba's compilation of its kernels on their "
              "first use in this installation (given apart; a later compare loads them from the cache)."]
    if warned:            # as a run's report says them, per variant: the figures above are suspect where they apply
        L += ["", "## Warnings", ""] + [f"- **{v}**: {w}." for v, ws in warned.items() for w in ws]
    if truth_body:
        L += ["", f"Ground truth body velocity RMS: lateral {truth_body['lateral']:.3f} m/s, vertical {truth_body['vertical']:.3f} m/s."]
    if plots:
        L += ["", "## Plots", "", "![APE over time](ape_over_time.png)", "![biases](biases.png)",
              "![body velocity](body_velocity.png)"]
    return "\n".join(L) + "\n"
