"""The one module that talks to evo: association, APE and RPE, and their statistics.

Everything here calls evo's own functions (``evo.main_ape.ape``, ``evo.main_rpe.rpe``,
``evo.core.sync.associate_trajectories``), the same code paths as the ``evo_ape``/``evo_rpe``
commands, so the numbers are evo's. Nothing is aligned: all estimates already live in the
ground truth's world frame.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass, field

import numpy as np
from evo.core import metrics, sync
from evo.core.filters import FilterException
from evo.core.result import Result
from evo.core.trajectory import PoseTrajectory3D
from evo.main_ape import ape as evo_ape
from evo.main_rpe import rpe as evo_rpe

from ..interp import interpolate_poses
from ..so3 import wxyz_to_xyzw, xyzw_to_wxyz
from ..types import PoseSeries
from . import engine, keys
from .alignment import apply_4dof, yaw_translation_fit
from .drift import kitti_drift

log = logging.getLogger(__name__)

STATS = keys.STATS


def to_evo(poses: PoseSeries, name: str) -> PoseTrajectory3D:
    """A (new, independent) evo trajectory of a pose series: the only place quaternions go to w-first order."""
    traj = PoseTrajectory3D(positions_xyz=np.array(poses.p_w_m), orientations_quat_wxyz=xyzw_to_wxyz(poses.q_wb_xyzw),
                            timestamps=np.array(poses.t_s))
    traj.meta["name"] = name
    return traj


def from_evo(traj: PoseTrajectory3D) -> PoseSeries:
    """A pose series of an evo trajectory (quaternions back to the package's (x, y, z, w) order)."""
    return PoseSeries(t_s=np.array(traj.timestamps), p_w_m=np.array(traj.positions_xyz),
                      q_wb_xyzw=wxyz_to_xyzw(np.array(traj.orientations_quat_wxyz)), source=traj.meta.get("name", "<evo>"))


@dataclass
class EstimateEvaluation:
    """evo's figures for one estimate against the reference."""

    name: str
    poses: int
    matched_poses: int
    metrics: dict = field(default_factory=dict)       # e.g. metrics["ape"]["translation_m"]["rmse"]
    results: dict = field(default_factory=dict)       # evo Result objects (dropped once serialised into zips)
    zips: dict = field(default_factory=dict)          # evo result files: name -> bytes (see report.files.evo_zips)
    ape_t_s: np.ndarray | None = None                 # stamps and APE translation errors, for plots
    ape_err_m: np.ndarray | None = None
    note: str | None = None
    association: str = "nearest"
    alignment: str = "none"
    alignment_params: dict | None = None
    drift: dict | None = None                         # KITTI drift metric (kitti_drift.DriftResult.as_dict)
    ref_p_m: np.ndarray | None = None                 # associated reference positions, for segment maps


def _stats(res: Result) -> dict:
    return {k: float(res.stats[k]) for k in STATS}


def associate(reference: PoseSeries, estimate: PoseSeries, method: str, t_max_diff_s: float):
    """Pairs of evo trajectories: ``nearest`` stamp within ``t_max_diff_s`` (evo's), or ``interpolate``:
    the reference interpolated at the estimate's stamps inside its span (linear position, SLERP)."""
    if method == "interpolate":
        ref_i = interpolate_poses(reference, estimate.t_s)
        keep = np.isin(estimate.t_s, ref_i.t_s)
        est = estimate.select(keep)
        if len(est) == 0:
            raise sync.SyncException("no estimate stamp inside the reference's span")
        return to_evo(ref_i, "groundtruth"), to_evo(est, estimate.source)
    return associate_nearest(to_evo(reference, "groundtruth"), to_evo(estimate, estimate.source), t_max_diff_s)


def associate_nearest(traj_1, traj_2, max_diff: float):
    """``evo.core.sync.associate_trajectories`` (nearest stamp, no offset) with the stamps matched on whole
    arrays (:func:`engine.matching_time_indices`) and the matched poses taken without deep copies: the same
    pair of trajectories (``tests/test_engine_parity.py``)."""
    second_longer = traj_2.num_poses > traj_1.num_poses
    short, long_ = (traj_1, traj_2) if second_longer else (traj_2, traj_1)
    i_short, i_long = engine.matching_time_indices(short.timestamps, long_.timestamps, max_diff)
    if i_short.size == 0:
        raise sync.SyncException(
            f"found no matching timestamps between {traj_1.name or 'first trajectory'} and "
            f"{traj_2.name or 'second trajectory'} with max. time diff {max_diff} (s) and time offset 0.0 (s)")
    short, long_ = _subset(short, i_short), _subset(long_, i_long)
    return (short, long_) if second_longer else (long_, short)


def _subset(traj, ids: np.ndarray):
    """The poses ``ids`` of an evo trajectory, as ``reduce_to_ids`` leaves a deep copy of it."""
    if traj._cache.has_poses_se3():          # noqa: SLF001 - a path given as matrices keeps them (as evo's does)
        return PoseTrajectory3D(poses_se3=np.asarray(traj.poses_se3)[ids], timestamps=np.asarray(traj.timestamps)[ids],
                                meta=copy.deepcopy(traj.meta), name=traj.name)
    return PoseTrajectory3D(positions_xyz=traj.positions_xyz[ids], orientations_quat_wxyz=traj.orientations_quat_wxyz[ids],
                            timestamps=np.asarray(traj.timestamps)[ids], meta=copy.deepcopy(traj.meta), name=traj.name)


ENGINES = ("arrays", "evo")


class _EvoLoops:
    """evo's own ``ape``/``rpe`` (its per-pose loops), on deep copies as ``evo_ape``/``evo_rpe`` would get them."""

    def __init__(self, ref_a, est_a):
        # evo caches the SE(3) matrices on first use; filling the cache once here means every deep copy
        # below carries it instead of rebuilding it (evo builds them in a Python loop).
        _ = ref_a.poses_se3, est_a.poses_se3
        self.ref_a, self.est_a = ref_a, est_a

    def se3(self):
        return np.array(self.ref_a.poses_se3), np.array(self.est_a.poses_se3)

    def ape(self, rel):
        return evo_ape(copy.deepcopy(self.ref_a), copy.deepcopy(self.est_a), rel)

    def rpe(self, rel, delta, unit):
        return evo_rpe(copy.deepcopy(self.ref_a), copy.deepcopy(self.est_a), rel, delta=delta, delta_unit=unit,
                       all_pairs=False)


class _Arrays:
    """The same results from :mod:`.engine` (whole arrays; the pairs of each delta selected once, by evo)."""

    def __init__(self, ref_a, est_a):
        self.ref_a, self.est_a = ref_a, est_a
        self.ref_T, self.est_T = engine.traj_se3(ref_a), engine.traj_se3(est_a)
        self._pairs: dict = {}

    def se3(self):
        return self.ref_T, self.est_T

    def ape(self, rel):
        return engine.ape_result(self.ref_a, self.est_a, rel, engine.ape_error(self.ref_T, self.est_T, rel))

    def rpe(self, rel, delta, unit):
        metrics.RPE(rel, delta, unit)                  # evo's argument checks, before any work
        if (delta, unit) not in self._pairs:
            self._pairs[(delta, unit)] = engine.rpe_pairs(self.ref_T, self.est_T, delta, unit)
        err, ids = engine.rpe_error(self.ref_T, self.est_T, rel, self._pairs[(delta, unit)])
        return engine.rpe_result(self.ref_a, self.est_a, rel, err, ids, delta, unit)


def _align(est_a, ref_a, alignment: str, arrays: bool):
    """The estimate moved by evo's ``origin``/``se3``/``sim3`` alignment, and the alignment's parameters."""
    if not arrays:
        est_a = copy.deepcopy(est_a)
        if alignment == "origin":
            return est_a, {"T": np.asarray(est_a.align_origin(ref_a)).tolist()}
        r, t, s = est_a.align(ref_a, correct_scale=alignment == "sim3")
    else:
        est_T, ref_T = engine.traj_se3(est_a), engine.traj_se3(ref_a)
        if alignment == "origin":
            moved, T = engine.align_origin(est_T, ref_T)
            return engine.with_poses(est_a, moved), {"T": T.tolist()}
        moved, (r, t, s) = engine.align_se3(est_T, est_a.positions_xyz, ref_a.positions_xyz, alignment == "sim3")
        est_a = engine.with_poses(est_a, moved)
    return est_a, {"rotation": np.asarray(r).tolist(), "translation_m": np.asarray(t).tolist(), "scale": float(s)}


def evaluate(reference: PoseSeries, estimate: PoseSeries, name: str, t_max_diff_s: float,
             rpe_delta_m: float, association: str = "nearest", alignment: str = "none",
             engine_name: str = "arrays") -> EstimateEvaluation:
    """APE (translation, rotation), RPE (per frame, per ``rpe_delta_m`` metres) and the KITTI drift metric
    of one estimate.

    Poses are associated by ``association`` (see :func:`associate`), then aligned by ``alignment``:
    ``none``, ``origin``, ``se3`` or ``sim3`` (evo's), or ``4dof`` (yaw + translation, ours). For a
    position-only estimate only the APE translation is computed: its rotations mean nothing.
    ``engine_name``: ``arrays`` computes evo's metrics on whole arrays (:mod:`.engine`), ``evo`` runs evo's own
    per-pose loops; both give the same numbers and result files.
    """
    if engine_name not in ENGINES:
        raise ValueError(f"evaluation engine {engine_name!r}: expected one of {', '.join(ENGINES)}")
    arrays = engine_name == "arrays"
    ev = EstimateEvaluation(name=name, poses=len(estimate), matched_poses=0)
    ev.association, ev.alignment = association, alignment
    try:
        ref_a, est_a = associate(reference, estimate, association, t_max_diff_s)
    except sync.SyncException as exc:
        ev.note = f"no poses associated ({association}, max {t_max_diff_s} s: {exc})"
        return ev
    ev.matched_poses = int(ref_a.num_poses)
    if ev.matched_poses < 2:
        ev.note = "fewer than 2 associated poses"
        return ev
    if alignment == "4dof":
        yaw, t = yaw_translation_fit(est_a.positions_xyz, ref_a.positions_xyz)
        moved = apply_4dof(PoseSeries(t_s=est_a.timestamps, p_w_m=est_a.positions_xyz,
                                      q_wb_xyzw=wxyz_to_xyzw(est_a.orientations_quat_wxyz),
                                      has_orientation=estimate.has_orientation), yaw, t)
        est_a = to_evo(moved, name)
        ev.alignment_params = {"yaw_deg": float(np.degrees(yaw)), "translation_m": t.tolist()}
    elif alignment in ("se3", "sim3", "origin"):
        est_a, ev.alignment_params = _align(est_a, ref_a, alignment, arrays)
    calc = _Arrays(ref_a, est_a) if arrays else _EvoLoops(ref_a, est_a)
    rels = [("translation_m", metrics.PoseRelation.translation_part)]
    if estimate.has_orientation:
        rels.append(("rotation_deg", metrics.PoseRelation.rotation_angle_deg))

    ev.metrics[keys.APE] = {}
    for key, rel in rels:
        res = calc.ape(rel)
        ev.metrics["ape"][key] = _stats(res)
        ev.results[f"ape_{key.split('_')[0]}"] = res
        if key == "translation_m":
            ev.ape_t_s = np.array(est_a.timestamps)
            ev.ape_err_m = np.array(res.np_arrays["error_array"])
            ev.ref_p_m = np.array(ref_a.positions_xyz)
    if estimate.has_orientation:
        d = kitti_drift(*calc.se3())
        ev.drift = None if d is None else d.as_dict()
    if not estimate.has_orientation:
        ev.note = "position only: no rotation or relative (RPE) metrics"
        return ev
    for label, delta, unit in ((keys.RPE_FRAME, 1.0, metrics.Unit.frames),
                               (keys.rpe_distance_group(rpe_delta_m), rpe_delta_m, metrics.Unit.meters)):
        ev.metrics[label] = {}
        for key, rel in rels:
            try:
                res = calc.rpe(rel, delta, unit)
            except (metrics.MetricsException, FilterException) as exc:   # e.g. a drive shorter than delta
                log.warning("%s: %s %s not computed: %s", name, label, key, exc)
                ev.metrics[label][key] = None
                continue
            ev.metrics[label][key] = _stats(res)
            ev.results[f"{label}_{key.split('_')[0]}"] = res
    return ev


def ratio(a: EstimateEvaluation | None, b: EstimateEvaluation | None) -> float | None:
    """APE translation RMSE of ``a`` over that of ``b`` (None when either is missing)."""
    try:
        return float(a.metrics["ape"]["translation_m"]["rmse"] / b.metrics["ape"]["translation_m"]["rmse"])
    except (AttributeError, KeyError, TypeError, ZeroDivisionError):
        return None
