"""The summary of a sweep, rebuilt from its records: ``sweep.csv``, ``sweep.md``, plots, ``best.yaml``."""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np
import yaml

from .sweep import METRIC_COLUMNS, Task, read_records


def _get(m: dict, path: tuple):
    d = m.get("estimates", {})
    for p in path:
        if not isinstance(d, dict) or p not in d or d[p] is None:
            return None
        d = d[p]
    return d


def rows_of(tasks: list[Task], out_dir: Path, keys: list[str]) -> list[dict]:
    recs = read_records(out_dir)
    rows = []
    seen = set()
    for t in tasks:
        key = (t.id, t.dataset, t.variant, t.setting)
        if key in seen:
            continue
        seen.add(key)
        r = recs.get(t.id)
        row = {"id": t.id, "dataset": t.dataset, "variant": t.variant, "setting": t.setting}
        for k in keys:
            row[k] = t.overrides.get(k, "")
        if r is None:
            row.update(status="pending", error="")
        else:
            m = r.get("metrics") or {}
            for col, path in METRIC_COLUMNS:
                row[col] = _get(m, path)
            ratios = m.get("ratios") or {}
            row["fused_over_lidar"] = ratios.get("fused_over_lidar")
            row["fused_over_gnss"] = ratios.get("fused_over_gnss")
            row.update(runtime_s=r.get("runtime_s"), status=r["status"], error=r.get("error") or "")
        rows.append(row)
    return rows


def _atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_summary(tasks: list[Task], out_dir: Path, keys: list[str], plots: bool = True,
                  grid_keys: list[str] | None = None) -> dict:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = rows_of(tasks, out_dir, keys)
    cols = ["id", "dataset", "variant", "setting", *keys, *(c for c, _ in METRIC_COLUMNS), "fused_over_lidar",
            "fused_over_gnss", "runtime_s", "status", "error"]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else (f"{r[k]:.6g}" if isinstance(r.get(k), float) else r[k])) for k in cols})
    _atomic(out_dir / "sweep.csv", buf.getvalue())

    ok = [r for r in rows if r["status"] == "ok"]
    metric = "fused_ape_trans_rmse_m"
    L = ["# fusion-eval sweep", "",
         f"{len(rows)} runs: {len(ok)} finished, {sum(r['status'] == 'failed' for r in rows)} failed, "
         f"{sum(r['status'] == 'pending' for r in rows)} pending. Ranked by fused APE translation RMSE (lower is better).", ""]
    datasets = sorted({r["dataset"] for r in rows})
    for ds in datasets:
        sub = sorted((r for r in ok if r["dataset"] == ds), key=lambda r: r[metric])
        L += [f"## {ds}", "", "| rank | variant | setting | APE trans RMSE [m] | APE rot RMSE [deg] | RPE 1 frame [m] | "
              "fused/lidar | fused/GNSS | time [s] |", "|---:|---|---|---:|---:|---:|---:|---:|---:|"]
        for i, r in enumerate(sub, 1):
            L.append(f"| {i} | {r['variant']} | {r['setting']} | {_f(r[metric])} | {_f(r['fused_ape_rot_rmse_deg'])} | "
                     f"{_f(r['fused_rpe_1frame_trans_rmse_m'], 4)} | {_f(r['fused_over_lidar'])} | {_f(r['fused_over_gnss'])} | "
                     f"{_f(r['runtime_s'], 1)} |")
        L.append("")
    # averaged across datasets: only settings that finished on every dataset
    avg = {}
    for r in ok:
        avg.setdefault((r["variant"], r["setting"]), []).append(r[metric])
    full = {k: float(np.mean(v)) for k, v in avg.items() if len(v) == len(datasets)}
    ranked = sorted(full.items(), key=lambda kv: kv[1])
    if len(datasets) > 1:
        L += ["## Averaged across datasets", "", "| rank | variant | setting | mean APE trans RMSE [m] |", "|---:|---|---|---:|"]
        L += [f"| {i} | {v} | {s} | {m:.3f} |" for i, ((v, s), m) in enumerate(ranked, 1)]
        L.append("")
    failed = [r for r in rows if r["status"] == "failed"]
    if failed:
        L += ["## Failed runs", "", "| dataset | variant | setting | error |", "|---|---|---|---|"]
        L += [f"| {r['dataset']} | {r['variant']} | {r['setting']} | {r['error']} |" for r in failed]
        L.append("")
    best = None
    if ranked:
        (bv, bs), bm = ranked[0]
        bt = next(t for t in tasks if t.variant == bv and t.setting == bs)
        best = {"variant": bv, "setting": bs, "mean_fused_ape_trans_rmse_m": bm}
        # a configuration file `fusion-eval run -c best.yaml` takes: the variant's file, then the setting
        cfg = yaml.safe_load(Path(bt.variant_path).read_text()) if bt.variant_path else {}
        cfg = cfg or {}
        for sect, body in _nest(bt.overrides).items():
            cfg.setdefault(sect, {}).update(body)
        _atomic(out_dir / "best.yaml", f"# best of the sweep: variant {bv}, setting {bs}\n"
                f"# mean fused APE translation RMSE across datasets: {bm:.6f} m\n"
                "# use it as: fusion-eval run -c best.yaml\n" + yaml.safe_dump(cfg, sort_keys=False))
        L += [f"Best: variant `{bv}`, setting `{bs}` (mean fused APE RMSE {bm:.3f} m); see `best.yaml`.", ""]
    written = []
    if plots and ok:
        from . import plots as P

        written = P.plot_sweep(out_dir, rows, keys, metric, tasks, best, grid_keys or [])
        L += [f"![{p}]({p})" for p in written]
    _atomic(out_dir / "sweep.md", "\n".join(L) + "\n")
    return {"rows": rows, "best": best, "plots": written}


def _f(x, nd=3):
    return "n/a" if x is None or x == "" else f"{x:.{nd}f}"


def _nest(ov: dict) -> dict:
    out: dict = {}
    for k, v in ov.items():
        s, n = k.split(".")
        out.setdefault(s, {})[n] = v
    return out
