"""``compare`` on a drive without ground truth: the variants set side by side by their innovations, the one thing
the data alone can judge them by (README "A drive without ground truth").

Each variant's NIS per stream (mean over its dof, the share inside the 95 % interval) and the two figures `tune`
and `sweep` rank by: the innovations' negative log-likelihood per update and the NIS calibration. The likelihood
ranks only variants that fuse the same streams (it is the likelihood of the data they were given: a variant that
fuses GNSS too has another set of data, and its figure is not comparable), so the ranking is within each such group.
"""

from __future__ import annotations

import json
import math

from ..datasets.tum import format_tum
from ..evaluation.consistency import innovation_summary
from ..evaluation.run_metrics import measured_observations, consistency
from ..provenance import header_line, input_files
from ..report import html
from ..report.files import versions
from ..tables import csv_text, markdown
from ..variants import folder_name
from .. import yaml_lines


def innovation_rows(runs) -> list[dict]:
    """One row per variant: its streams, NLL per update, NIS calibration, and per stream the mean NIS over the dof
    and the share inside the 95 % interval; ranked by NLL among the variants of the same streams."""
    rows = []
    for r in runs:
        nis = consistency(None, r.filt)["nis"]
        inn = innovation_summary(nis, measured_observations()) if nis else {"updates": 0, "nll_per_update": math.nan,
                                                                  "nis_calibration": math.nan}
        rows.append({"variant": r.name, "streams": "+".join(sorted(nis)), "updates": inn["updates"],
                     "nll_per_update": inn["nll_per_update"], "nis_calibration": inn["nis_calibration"],
                     **{f"{k}_mean_nis_over_dof": d["mean"] / d["dof"] for k, d in nis.items()},
                     **{f"{k}_fraction_in_95": d["fraction_in_95"] for k, d in nis.items()},
                     "runtime_s": r.runtime_s})
    for group in {row["streams"] for row in rows}:
        same = sorted((row for row in rows if row["streams"] == group and math.isfinite(row["nll_per_update"])),
                      key=lambda row: row["nll_per_update"])
        for i, row in enumerate(same, 1):
            row["rank_nll"] = i
    return rows


# NLL per update closer than this is no difference to rank by (a 0.1 % likelier datum; eskf against constant-bias on
# kitti-00: 9e-6 apart)
NLL_TIE = 1e-3


def ranking_notes(rows: list[dict]) -> list[str]:
    """What the ranks mean: within each group of variants fusing the same streams, and a first place won by under
    :data:`NLL_TIE` per update said to be no difference that matters."""
    groups = list(dict.fromkeys(row["streams"] for row in rows))
    out = []
    if len(groups) > 1:
        out.append(f"ranked by NLL within each set of fused streams ({', '.join(groups)}): the likelihood of other "
                   "data does not compare")
    for g in groups:
        ranked = sorted((row for row in rows if row["streams"] == g and "rank_nll" in row), key=lambda row: row["rank_nll"])
        if len(ranked) > 1 and ranked[1]["nll_per_update"] - ranked[0]["nll_per_update"] < NLL_TIE:
            out.append(f"{ranked[0]['variant']} leads {ranked[1]['variant']} by "
                       f"{ranked[1]['nll_per_update'] - ranked[0]['nll_per_update']:.2g} per update: under {NLL_TIE:g}, "
                       "no difference that matters")
    return out


def _markdown(dataset: str, rows: list[dict], plots: bool, notes: list[str]) -> str:
    streams = sorted({k.removesuffix("_mean_nis_over_dof") for row in rows for k in row if k.endswith("_mean_nis_over_dof")})
    header = ["variant", "fused streams", "rank by NLL", "NLL per update", "NIS calibration",
              *(f"{k} NIS/dof, inside 95 %" for k in streams), "filter [s]"]
    body = [[row["variant"], row["streams"], row.get("rank_nll", "n/a"), row["nll_per_update"], row["nis_calibration"],
             *(f"{row[f'{k}_mean_nis_over_dof']:.3f}, {row[f'{k}_fraction_in_95'] * 100:.1f} %"
               if f"{k}_mean_nis_over_dof" in row else "n/a" for k in streams), row["runtime_s"]]
            for row in rows]          # (NaN prints as n/a: tables.cell)
    L = [f"# fusion-eval compare: {dataset}", "", header_line(), "", "## No ground truth", "",
         "The drive has no groundtruth stream: no variant is scored (no APE, RPE or NEES). The variants are set side by "
         "side by their innovations, each stream against the filter's prediction in its own stated noise: the negative "
         "log-likelihood per update (lower: the data are likelier under the variant's models and noise) and the NIS "
         "calibration (0 for a consistent filter). The likelihood ranks variants that fuse the same streams only: one "
         "fusing more streams is judged on other data. A variant that fits its innovations best is the most consistent, "
         "not necessarily the most accurate: a sensor whose errors are not white (lidar odometry drifts) is fitted "
         "best by a noise its drift does not show.", ""]
    L += markdown(header, body, align="llrrr" + "l" * len(streams) + "r", decimals=[0, 0, 0, 6, 4, *[0] * len(streams), 2])
    if notes:
        L += [""] + [f"- {n[0].upper()}{n[1:]}." for n in notes]
    if plots:
        L += ["", "## Plots", "", "![biases.png](biases.png)"]
    L += ["", "Files: `compare.json`, `compare.csv`, `variants/<name>/fused.tum` (score them against a reference you "
          "have elsewhere with `fusion-eval evaluate`) and each variant's `config.resolved.yaml`.", ""]
    return "\n".join(L)


def compare_without_truth(ds, variants: list[str], cfgs: list[dict], staged, make_plots: bool, stages, out_dir) -> dict:
    """Replay every variant on ``ds`` (no ground truth) and write the innovations' comparison into ``staged``."""
    from .compare import replay_variants

    stages.start("variants", len(variants))
    runs, _ = replay_variants(ds, variants, cfgs, stages.advance)
    stages.start("write")
    rows = innovation_rows(runs)
    notes = ranking_notes(rows)
    with staged as out:
        result = {"dataset": ds.name, "variants": variants, "ground_truth": False, "rows": rows, "notes": notes}
        warned = {r.name: list(r.warnings) for r in runs if r.warnings}
        if warned:
            result["warnings"] = warned
        out.write_text("compare.json", json.dumps(result, indent=2, default=float) + "\n")
        cols = list(dict.fromkeys(k for row in rows for k in row))
        out.write_text("compare.csv", csv_text(cols, rows))
        md = _markdown(ds.name, rows, make_plots, notes)
        out.write_text("compare.md", md)
        taken: set = set()
        for r in runs:
            folder = folder_name(r.name, taken)
            out.write_text(f"variants/{folder}/fused.tum", format_tum(r.filt.fused, f"fusion-eval compare: variant {r.name}"))
            out.write_text(f"variants/{folder}/config.resolved.yaml", yaml_lines.dump({**r.cfg, "versions": versions()}))
        if make_plots:
            from ..report import plots

            plots.plot_compare_biases(out.path("biases.png"), runs)
        out.write_text("report.html", html.page(md, out.path("."), inputs=input_files(ds.description)))
    return {**result, "out_dir": str(out_dir)}
