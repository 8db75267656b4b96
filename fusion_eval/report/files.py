"""Run outputs as files: TUM trajectories, metrics (JSON, CSV), evo result zips, the resolved configuration.

Nothing time- or machine-dependent is written (no wall times, no absolute paths beyond the inputs), so
the same inputs and seed give the same bytes; zips get fixed entry times.
"""

from __future__ import annotations

import copy
import functools
import io
import json
import math
import platform
import zipfile
from pathlib import Path

from .. import __version__, yaml_lines
from ..datasets.tum import tum_chunks
from ..evaluation.keys import STATS
from ..evaluation.trajectory import EstimateEvaluation
from ..outputs import atomic_file
from ..tables import csv_text
from ..types import PoseSeries

TUM_FILES = {"fused": "fused.tum", "smoothed": "smoothed.tum", "lidar": "lidar.tum", "gnss": "gnss.tum", "imu_only": "imu_only.tum",
             "groundtruth": "groundtruth.tum"}
FIXED_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def versions() -> dict:
    """Versions of Python and of the packages that produced the numbers (read from metadata, no imports; once per
    process: reading 14 packages' metadata cost 5 % of a sweep's CPU when every run read it again)."""
    return dict(_versions())


@functools.lru_cache(maxsize=1)
def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    from ..provenance import code_id

    out = {"fusion-eval": __version__, "fusion-eval-code": code_id(), "python": platform.python_version()}
    for pkg in ("numpy", "scipy", "evo", "numba", "pymap3d", "matplotlib", "pandas", "pyyaml", "click", "optuna", "dask",
                "tabulate", "markdown", "tqdm"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


def _tum_header(name: str, s: PoseSeries) -> str:
    hdr = f"fusion-eval {__version__} {name}: timestamp tx ty tz qx qy qz qw (world = local ENU, body = IMU)"
    if not s.has_orientation:
        hdr += "\nposition only: quaternions are identity placeholders"
    return hdr


def write_tum(path: Path, name: str, s: PoseSeries) -> None:
    """The estimate ``name``'s TUM file (:func:`fusion_eval.datasets.tum.tum_chunks` under a header naming it),
    streamed into ``path`` atomically."""
    with atomic_file(path) as fh:
        for chunk in tum_chunks(s, _tum_header(name, s)):
            fh.write(chunk)


def metrics_json(metrics: dict) -> str:
    """``metrics.json``'s text: strict JSON, a figure that is not a finite number written as ``null`` (Python's bare
    ``NaN`` is no JSON: an iterated update's innovation likelihood, which it does not compute, made the file unreadable
    for jq and JSON.parse; found by a corrupted-input review)."""
    return json.dumps(finite_or_null(metrics), indent=2, sort_keys=False, allow_nan=False) + "\n"


def finite_or_null(obj):
    """``obj`` with every float that is NaN or infinite replaced by None (dicts, lists and tuples walked)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v) for v in obj]
    return obj


def metrics_csv(evals: dict[str, EstimateEvaluation], ratios: dict, n_trials: int | None = None) -> str:
    """``metrics.csv``: one row per estimate; with ``n_trials`` (``--trials``) the rows are trial 0's, which the
    columns ``trial`` and ``trials`` say (the file gave one seed's figures with no word of it; a review)."""
    groups = []
    for ev in evals.values():
        for g, d in ev.metrics.items():
            for rel in d:
                if (g, rel) not in groups:
                    groups.append((g, rel))
    cols = ["estimate", "poses", "matched_poses"] + [f"{g}_{rel}_{s}" for g, rel in groups for s in STATS] + \
        ["fused_over_this_ape_rmse"] + (["trial", "trials"] if n_trials else [])
    rows = []
    for name, ev in evals.items():
        row = {"estimate": name, "poses": ev.poses, "matched_poses": ev.matched_poses,
               "fused_over_this_ape_rmse": ratios.get(f"fused_over_{name}"),
               **({"trial": 0, "trials": n_trials} if n_trials else {})}
        for g, rel in groups:
            d = (ev.metrics.get(g) or {}).get(rel)
            for s in STATS:
                row[f"{g}_{rel}_{s}"] = None if not d else float(d[s])
        rows.append(row)
    return csv_text(cols, rows)


def resolved_config(cfg: dict, extra: dict) -> str:
    """``config.resolved.yaml``: the configuration, then informational sections (the dataset, what was
    applied, the versions); ``-c`` accepts the file and ignores those sections."""
    return yaml_lines.dump({**cfg, **extra, "versions": versions()})


def _zip_names(ev: EstimateEvaluation, trajectories: bool):
    """``(file name, evo result, with its trajectories)`` per metric. Each zip keeps evo's statistics and arrays,
    which is what ``evo_res`` reads. With ``trajectories`` (evo's ``save_traj_in_zip``, off by default in evo and
    here: the run's TUM files hold the same poses, and on a long drive their text was most of the writing) only
    the APE translation zip carries the (associated) reference and estimate trajectories: the other zips of an
    estimate would hold copies of the same poses (or, for RPE, a reduced copy)."""
    return [(f"{key}_{ev.name}.zip", res, trajectories and key == "ape_translation") for key, res in ev.results.items()]


def evo_zips(ev: EstimateEvaluation, trajectories: bool = False) -> dict[str, bytes]:
    """evo result files (``evo_res`` reads them), one per metric: ``<metric>_<estimate>.zip`` -> bytes."""
    return {fname: result_zip(res, trajectories=traj) for fname, res, traj in _zip_names(ev, trajectories)}


def write_evo_zips(ev: EstimateEvaluation, folder: Path, trajectories: bool = False) -> None:
    """The files of :func:`evo_zips` written into ``folder``, each streamed into its file (a long drive's are
    hundreds of MB that need not be held whole)."""
    for fname, res, traj in _zip_names(ev, trajectories):
        with atomic_file(Path(folder) / fname) as fh:
            write_result_zip(fh, res, trajectories=traj)


def result_zip(res, trajectories: bool = True) -> bytes:
    """:func:`write_result_zip` as bytes."""
    buf = io.BytesIO()
    write_result_zip(buf, res, trajectories)
    return buf.getvalue()


def write_result_zip(dest, res, trajectories: bool = True) -> None:
    """An evo result file as ``evo.tools.file_interface.save_res_file`` writes it (``info.json``,
    ``stats.json``, one ``.npy`` per array, one ``.tum`` per trajectory) into the binary file ``dest``, with
    fixed entry times and sorted entries so that identical runs give identical bytes. The trajectories' text
    comes from the compiled writer (9 decimals) instead of ``np.savetxt``, which took most of the time of a
    run's writing, a chunk at a time."""
    import numpy as np
    from evo.core.trajectory import PoseTrajectory3D

    entries = {"info.json": json.dumps(res.info).encode(), "stats.json": json.dumps(res.stats).encode()}
    for name, array in res.np_arrays.items():
        buf = io.BytesIO()
        np.save(buf, array)
        entries[f"{name}.npy"] = buf.getvalue()
    for name, traj in (res.trajectories.items() if trajectories else ()):
        if not isinstance(traj, PoseTrajectory3D):      # a path without stamps: evo's own KITTI writer
            from evo.tools import file_interface

            raw = io.BytesIO()
            file_interface.save_res_file(raw, copy.copy(res), confirm_overwrite=False)
            dest.write(normalized_zip(raw.getvalue()))
            return
        poses = PoseSeries(t_s=np.asarray(traj.timestamps), p_w_m=traj.positions_xyz,
                           q_wb_xyzw=traj.orientations_quat_wxyz[:, [1, 2, 3, 0]], source=name)
        entries[f"{name}.tum"] = poses          # streamed below, in the entries' order
    with zipfile.ZipFile(dest, "w") as zout:          # uncompressed, as evo writes them
        for fname in sorted(entries):
            zi = zipfile.ZipInfo(fname, date_time=FIXED_ZIP_TIME)
            zi.external_attr = 0o644 << 16
            data = entries[fname]
            if isinstance(data, bytes):
                zout.writestr(zi, data)
                continue
            # the same bytes as writestr (a seekable file: the sizes are patched in after); ZIP64 where a TUM text
            # of rows at most 257 bytes could pass 2 GiB (a drive of days)
            with zout.open(zi, "w", force_zip64=len(data) * 257 > zipfile.ZIP64_LIMIT) as fh:
                for chunk in tum_chunks(data):
                    fh.write(chunk)


def normalized_zip(data: bytes) -> bytes:
    """The same zip with fixed entry times and sorted entries, so that identical runs give identical bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as zin, zipfile.ZipFile(buf, "w") as zout:
        for info in sorted(zin.infolist(), key=lambda i: i.filename):
            zi = zipfile.ZipInfo(info.filename, date_time=FIXED_ZIP_TIME)
            zi.compress_type = info.compress_type  # evo stores uncompressed; keep it so
            zi.external_attr = 0o644 << 16
            zout.writestr(zi, zin.read(info.filename))
    return buf.getvalue()
