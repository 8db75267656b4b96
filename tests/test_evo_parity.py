"""Our APE/RPE equal what evo's own command line prints for the same TUM files (to 1e-6)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from evo.tools import file_interface


def _evo_cli(name: str) -> str:
    exe = Path(sys.executable).parent / name
    if exe.exists():
        return str(exe)
    found = shutil.which(name)
    if not found:
        pytest.skip(f"{name} (evo's command line) not found next to {sys.executable} nor on PATH")
    return found


def _span_args(run_dir) -> list[str]:
    """evo's --t_start/--t_end of the run's common span (metrics.json), as the report prints them."""
    from fusion_eval.evaluation.span import evo_options

    sp = json.loads((run_dir / "metrics.json").read_text())["evaluation"]["span"]
    return evo_options(sp if sp["mode"] == "common" else None).split()


def _run(tmp_path, tool, args, tag):
    z = tmp_path / f"{tag}.zip"
    subprocess.run([_evo_cli(tool), "tum", *args, "--save_results", str(z), "--no_warnings"], check=True,
                   capture_output=True, text=True, timeout=300)
    return file_interface.load_res_file(z).stats


CASES = [
    # (our metrics key, evo command, extra args)
    (("ape", "translation_m"), "evo_ape", []),
    (("ape", "rotation_deg"), "evo_ape", ["-r", "angle_deg"]),
    (("rpe_1frame", "translation_m"), "evo_rpe", ["--delta", "1", "--delta_unit", "f"]),
    (("rpe_1frame", "rotation_deg"), "evo_rpe", ["--delta", "1", "--delta_unit", "f", "-r", "angle_deg"]),
    (("rpe_100m", "translation_m"), "evo_rpe", ["--delta", "100", "--delta_unit", "m"]),
]


@pytest.mark.slow
@pytest.mark.parametrize("estimate", ["fused", "lidar"])
@pytest.mark.parametrize("key,tool,extra", CASES, ids=["-".join(c[0]) for c in CASES])
def test_metrics_equal_evo_command_line(slice_run, tmp_path, estimate, key, tool, extra):
    ours = json.loads((slice_run / "metrics.json").read_text())["estimates"][estimate][key[0]][key[1]]
    stats = _run(tmp_path, tool, [str(slice_run / "groundtruth.tum"), str(slice_run / f"{estimate}.tum"), *extra,
                                  *_span_args(slice_run)], f"{estimate}-{'-'.join(key)}")
    for s in ("rmse", "mean", "median", "std", "min", "max"):
        assert abs(ours[s] - stats[s]) <= 1e-6, (s, ours[s], stats[s])


@pytest.mark.slow
def test_gnss_ape_equals_evo_command_line(slice_run, tmp_path):
    ours = json.loads((slice_run / "metrics.json").read_text())["estimates"]["gnss"]["ape"]["translation_m"]
    stats = _run(tmp_path, "evo_ape", [str(slice_run / "groundtruth.tum"), str(slice_run / "gnss.tum"),
                                       *_span_args(slice_run)], "gnss")
    assert abs(ours["rmse"] - stats["rmse"]) <= 1e-6
