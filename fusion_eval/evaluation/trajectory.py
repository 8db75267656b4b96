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
from evo.core.geometry import GeometryException
from evo.core.result import Result
from evo.core.trajectory import PoseTrajectory3D
from evo.main_ape import ape as evo_ape
from evo.main_rpe import rpe as evo_rpe

from ..errors import DataRangeError
from ..so3 import wxyz_to_xyzw, xyzw_to_wxyz
from ..types import PoseSeries
from . import engine, keys
from .alignment import detect_up_axis, fit_4dof
from .drift import kitti_drift

log = logging.getLogger(__name__)

STATS = keys.STATS


def to_evo(poses: PoseSeries, name: str) -> PoseTrajectory3D:
    """A (new, independent) evo trajectory of a pose series: the only place quaternions go to w-first order."""
    traj = PoseTrajectory3D(positions_xyz=np.array(poses.p_w_m), orientations_quat_wxyz=xyzw_to_wxyz(poses.q_wb_xyzw),
                            timestamps=np.array(poses.t_s))
    traj.meta["name"] = name
    return traj


def from_evo(traj: PoseTrajectory3D, repeated_stamps: bool = False) -> PoseSeries:
    """A pose series of an evo trajectory (quaternions back to the package's (x, y, z, w) order)."""
    return PoseSeries(t_s=np.array(traj.timestamps), p_w_m=np.array(traj.positions_xyz),
                      q_wb_xyzw=wxyz_to_xyzw(np.array(traj.orientations_quat_wxyz)), source=traj.meta.get("name", "<evo>"),
                      repeated_stamps=repeated_stamps)


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
    ape_hv_m: np.ndarray | None = None                # (n, 2): horizontal and vertical parts of each APE translation
                                                      # error (the reference's up axis), for the per-segment table
    nees: dict | None = None                          # position / attitude NEES of an estimate with covariances
    matchable: int = 0                                # pairs evo could make at most (trajectory._matchable)
    ref_interval_s: float = 0.0                       # the reference's median stamp interval (s)
    said: list = field(default_factory=list)          # the warnings its evaluation gave (:func:`evaluate`)


def _stats(res: Result) -> dict:
    return {k: float(res.stats[k]) for k in STATS}


def as_evo(x, name: str) -> PoseTrajectory3D:
    """An evo trajectory of a pose series, or an evo trajectory (read by evo's readers) as it is."""
    return to_evo(x, name) if isinstance(x, PoseSeries) else x


def associate(reference, estimate, method: str, t_max_diff_s: float, t_offset_s: float = 0.0):
    """Pairs of evo trajectories, as ``evo_ape --sync_method`` makes them: ``nearest`` stamp within
    ``t_max_diff_s`` (``nearest_time``), or ``interpolate``: the stamps matched the same way, then the trajectory
    with more poses interpolated (linear position, SLERP) at the matched stamps of the other
    (``evo.core.sync.associate_trajectories`` with ``SyncMethod.interpolation``): a gap in either is never
    bridged. ``t_offset_s`` is added to the estimate's stamps for the matching only (evo's ``--t_offset``)."""
    ref = as_evo(reference, "groundtruth")
    est = as_evo(estimate, getattr(estimate, "source", None) or est_name(estimate))
    if method == "interpolate":
        from evo.core.sync_method import SyncMethod

        return sync.associate_trajectories(ref, est, sync_method=SyncMethod.interpolation, max_diff=t_max_diff_s,
                                           offset_2=t_offset_s)
    return associate_nearest(ref, est, t_max_diff_s, t_offset_s)


def _stamps(x) -> np.ndarray:
    return np.asarray(x.t_s if isinstance(x, PoseSeries) else x.timestamps, float)


def _matchable(reference, estimate, t_max_diff_s: float, t_offset_s: float = 0.0) -> tuple[int, float]:
    """How many pairs evo's association could make at most (each pose of the sparser side once), with a tolerance
    of half the other side's interval: the fewer of the estimate's stamps near one of the reference's and the
    reference's near one of the estimate's (a stamp in the other's gap counts for neither: fixes in a truth's gaps
    were counted, and the suggested settings then changed nothing; a review); and the reference's median interval.
    A receiver whose fixes fall between a 10 Hz truth's stamps had 101 of its 469 matched (an own-data review)."""
    tr, te = _stamps(reference), _stamps(estimate) + t_offset_s
    if tr.size < 2 or te.size < 2:
        return 0, 0.0
    dr, de = float(np.median(np.diff(tr))), float(np.median(np.diff(te)))
    n_est = engine.matching_time_indices(te, tr, max(t_max_diff_s, 0.6 * dr))[0].size
    n_ref = engine.matching_time_indices(tr, te, max(t_max_diff_s, 0.6 * de))[0].size
    return min(n_est, n_ref), dr


def est_name(x) -> str:
    return x.meta.get("name", "estimate") if hasattr(x, "meta") else "estimate"


def associate_nearest(traj_1, traj_2, max_diff: float, offset_2: float = 0.0):
    """``evo.core.sync.associate_trajectories`` (nearest stamp, no offset) with the stamps matched on whole
    arrays (:func:`engine.matching_time_indices`) and the matched poses taken without deep copies: the same
    pair of trajectories (``tests/test_engine_parity.py``)."""
    second_longer = traj_2.num_poses > traj_1.num_poses
    short, long_ = (traj_1, traj_2) if second_longer else (traj_2, traj_1)
    i_short, i_long = engine.matching_time_indices(short.timestamps, long_.timestamps, max_diff,
                                                   offset_2 if second_longer else -offset_2)
    if i_short.size == 0:
        raise sync.SyncException(
            f"found no matching timestamps between {traj_1.name or 'first trajectory'} and "
            f"{traj_2.name or 'second trajectory'} with max. time diff {max_diff} (s) and time offset {offset_2} (s)")
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
    """The same results from :mod:`.engine` (whole arrays; the pairs of each delta selected once, by evo). The
    error poses of a delta serve every relation in ``relations`` (made once, on the first relation's call), and
    the arrays of stamps and distances, the same poses for every relation, are computed once per metric."""

    def __init__(self, ref_a, est_a, rpe_trajectories: bool = True, relations=()):
        self.ref_a, self.est_a = ref_a, est_a
        self.ref_T, self.est_T = engine.traj_se3(ref_a), engine.traj_se3(est_a)
        self._pairs: dict = {}
        self._rpe: dict = {}
        self._time: dict = {}
        self.rpe_trajectories = rpe_trajectories
        self.relations = tuple(dict.fromkeys(relations))

    def se3(self):
        return self.ref_T, self.est_T

    def _time_arrays(self, key, ids, make):
        """``make(kept time arrays or None)``, keeping the new result's time arrays for the next relation of the
        same poses (``ids``; the point-distance ratio drops pairs of zero reference distance, so its ids may
        differ from the others')."""
        kept = self._time.get(key)
        same = kept is not None and (ids is None or np.array_equal(kept[0], ids))
        res = make(kept[1] if same else None)
        if not same and engine.TIME_ARRAYS[0] in res.np_arrays:
            self._time[key] = (ids, {k: res.np_arrays[k] for k in engine.TIME_ARRAYS})
        return res

    def ape(self, rel):
        err = engine.ape_error(self.ref_T, self.est_T, rel)
        return self._time_arrays("ape", None, lambda ta: engine.ape_result(self.ref_a, self.est_a, rel, err,
                                                                           time_arrays=ta))

    def rpe(self, rel, delta, unit):
        metrics.RPE(rel, delta, unit)                  # evo's argument checks, before any work
        key = (delta, unit)
        if key not in self._pairs:
            self._pairs[key] = engine.rpe_pairs(self.ref_T, self.est_T, delta, unit)
        if (key, rel) not in self._rpe:
            rels = [rel] + [r for r in self.relations if r != rel and (key, r) not in self._rpe]
            for r, out in zip(rels, engine.rpe_errors(self.ref_T, self.est_T, rels, self._pairs[key])):
                self._rpe[(key, r)] = out
        err, ids = self._rpe.pop((key, rel))
        return self._time_arrays(key, ids, lambda ta: engine.rpe_result(
            self.ref_a, self.est_a, rel, err, ids, delta, unit, trajectories=self.rpe_trajectories, time_arrays=ta))


def _align(est_a, ref_a, alignment: str, arrays: bool, n_to_align: int = -1):
    """The estimate moved by evo's ``origin``/``se3``/``sim3``/``scale`` alignment (``--align_origin``, ``-a``,
    ``-as``, ``-s``), Umeyama's fit on the first ``n_to_align`` poses (-1: all), the alignment's parameters, and the
    rotation and scale it applied ``(R, s)`` (what carries a covariance along)."""
    with_scale, only_scale = alignment in ("sim3", "scale"), alignment == "scale"
    if not arrays:
        est_a = copy.deepcopy(est_a)
        if alignment == "origin":
            T = np.asarray(est_a.align_origin(ref_a))
            return est_a, {"T": T.tolist()}, (T[:3, :3], 1.0)
        r, t, s = est_a.align(ref_a, correct_scale=with_scale, correct_only_scale=only_scale, n=n_to_align)
    else:
        est_T, ref_T = engine.traj_se3(est_a), engine.traj_se3(ref_a)
        if alignment == "origin":
            moved, T = engine.align_origin(est_T, ref_T)
            return engine.with_poses(est_a, moved), {"T": T.tolist()}, (T[:3, :3], 1.0)
        moved, (r, t, s) = engine.align_se3(est_T, est_a.positions_xyz, ref_a.positions_xyz, with_scale,
                                            only_scale=only_scale, n=n_to_align)
        est_a = engine.with_poses(est_a, moved)
    if only_scale:
        return est_a, {"scale": float(s)}, (np.eye(3), float(s))
    return (est_a, {"rotation": np.asarray(r).tolist(), "translation_m": np.asarray(t).tolist(), "scale": float(s)},
            (np.asarray(r), float(s)))


_EVO_ALIGNED = {"se3": "\n(with SE(3) Umeyama alignment)", "sim3": "\n(with Sim(3) Umeyama alignment)",
                "scale": "\n(scale corrected)", "origin": "\n(with origin alignment)", "none": "\n(not aligned)",
                "4dof": "\n(with 4-DoF alignment: a rotation about the up axis and a translation)"}


def _evo_labelled(alignment: str, n_to_align: int, params: dict | None):
    """A function that gives a result evo's title for the alignment applied before it (``evo_ape -a``: "(with SE(3)
    Umeyama alignment)", ...) and evo's ``alignment_transformation_sim3`` array: the metric was computed on poses
    aligned beforehand, so every result file said "(not aligned)" and lacked the array (a review)."""
    suffix = _EVO_ALIGNED.get(alignment, "")
    if alignment in ("se3", "sim3", "scale") and n_to_align != -1:
        suffix = suffix + f" (aligned poses: {n_to_align})"
    sim3 = _sim3_of(params) if alignment in ("se3", "sim3", "scale", "origin") else None

    def label(res):
        # the alignment's line replaced, the metric's kept: RPE's "for delta = 100.0 (m) using consecutive pairs"
        # went with it, and evo_res tabled the 1-frame and 100 m results under one title with no word (a review)
        kept = [ln for ln in res.info["title"].split("\n") if not ln.startswith("(")]
        res.info["title"] = "\n".join(kept) + suffix
        if sim3 is not None:
            res.add_np_array("alignment_transformation_sim3", sim3)
        return res
    return label


def _sim3_of(params: dict | None) -> np.ndarray | None:
    """The 4x4 ``[s R, t]`` of an alignment as :func:`_align` and :func:`_align_4dof` record it
    (``alignment_params``), or evo's ``--align_origin`` transform ``T``; None without one."""
    if not params or not ({"T", "rotation", "scale"} & params.keys()):
        return None
    if "T" in params:
        return np.asarray(params["T"], float)
    S = np.eye(4)
    S[:3, :3] = float(params.get("scale", 1.0)) * np.asarray(params.get("rotation", np.eye(3)), float)
    S[:3, 3] = params.get("translation_m", np.zeros(3))
    return S


def aligned_positions(p_m: np.ndarray, params: dict | None) -> np.ndarray:
    """Positions moved by an alignment as :func:`_align` and :func:`_align_4dof` record it (``alignment_params``):
    ``p' = s R p + t``, or evo's ``--align_origin`` transform ``T``; unchanged without one."""
    S = _sim3_of(params)
    return p_m if S is None else p_m @ S[:3, :3].T + S[:3, 3]


def _align_4dof(est_a, ref_a, up_axis: str, n_to_align: int = -1):
    """The estimate rotated about the reference's gravity axis and translated (least squares on the positions)."""
    p_e, p_r = est_a.positions_xyz, ref_a.positions_xyz
    if n_to_align != -1:
        p_e, p_r = p_e[:n_to_align], p_r[:n_to_align]
    params: dict = {}
    if up_axis == "auto":
        up_axis, det = detect_up_axis(ref_a.positions_xyz)
        params["up_axis_detection"] = det
        if det["angle_deg"] > MAX_UP_TILT_DEG and det["flatness"] <= FLAT_ENOUGH:
            log.warning("the 4-DoF alignment turns about %s, the coordinate axis nearest the reference's ground plane's "
                        "normal, which is %.1f deg from it: a tilted frame (ECEF-like?) has no coordinate axis along "
                        "gravity and a yaw about another is not the 4-DoF fit; give --up-axis, or use --alignment se3",
                        up_axis, det["angle_deg"])
    R, t, yaw = fit_4dof(p_e, p_r, up_axis)
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = R, t
    params.update({"up_axis": up_axis, "yaw_deg": float(np.degrees(yaw)), "rotation": R.tolist(), "translation_m": t.tolist()})
    return engine.with_poses(est_a, A @ engine.traj_se3(est_a)), params, (R, 1.0)


# a reference whose smallest principal spread is above this share of the middle one has no clear ground plane (a
# flight): its errors are not split into horizontal and vertical parts along a guessed axis
FLAT_ENOUGH = 0.5
# nor one whose ground plane's normal lies further than this from the nearest coordinate axis: a frame tilted against
# gravity (ECEF-like, or a camera's), where 'up' along an axis mixes horizontal into vertical (a reference rotated by
# 20/-30/70 deg split one segment's 0.59 / 1.07 m into 0.29 / 1.19, with no word: a metamorphic review). A road's
# grade stays inside it (the plane of a clip that climbs 20 % throughout: 11.3 deg; 36 % would be 20), and ECEF is
# tilted by 40-55 deg at mid-latitudes (Karlsruhe's local up is 41 deg off ECEF's z)
MAX_UP_TILT_DEG = 20.0


def horizontal_vertical(dp_m: np.ndarray, up_axis: str, p_ref_m: np.ndarray) -> np.ndarray | None:
    """The horizontal and vertical parts of position errors ``dp_m`` (estimate - reference, (n, 3), in the
    reference's frame): ``(n, 2)`` of the norm across ``up_axis`` and the absolute value along it, whose root sum of
    squares is the APE translation error (evo's ``trans_part``). ``up_axis`` 'auto': the reference's least-varying
    axis (:func:`fusion_eval.evaluation.alignment.detect_up_axis`); None where it has no clear ground plane, or one
    tilted against every coordinate axis (:data:`MAX_UP_TILT_DEG`)."""
    if up_axis == "auto":
        if len(p_ref_m) < 3:
            return None
        up_axis, det = detect_up_axis(p_ref_m)
        if det["flatness"] > FLAT_ENOUGH or det["angle_deg"] > MAX_UP_TILT_DEG:
            return None
    k = "xyz".index(up_axis)
    across = np.delete(dp_m, k, axis=1)
    return np.column_stack([np.hypot(across[:, 0], across[:, 1]), np.abs(dp_m[:, k])])


def _keeping_said(fn):
    """``fn``, an evaluation, with the warnings it gave (still said) kept in the result's ``said``: in a pool's worker
    they print there, and a Monte-Carlo run's summary of its trials' warnings must know them as the run's (trial 0's
    evaluation warnings were said again as the later trials' own; a review of the diff)."""
    import functools

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        from ..log_context import collected

        with collected() as said:
            ev = fn(*args, **kwargs)
        ev.said = list(said)
        return ev
    return wrapped


@_keeping_said
def evaluate(reference, estimate, name: str, t_max_diff_s: float,
             rpe_delta_m: float, association: str = "nearest", alignment: str = "none",
             engine_name: str = "arrays", *, relations: tuple[str, ...] = keys.DEFAULT_RELATIONS, up_axis: str = "auto",
             n_to_align: int = -1, t_offset_s: float = 0.0, has_orientation: bool | None = None,
             cov: tuple[np.ndarray, np.ndarray] | None = None, rpe_trajectories: bool = True,
             ref_name: str = "groundtruth") -> EstimateEvaluation:
    """APE and RPE (per frame, per ``rpe_delta_m`` metres) under each pose relation, and the KITTI drift metric
    of one estimate. ``reference`` and ``estimate``: pose series, or evo trajectories as evo's readers give them.

    Poses are associated by ``association`` (see :func:`associate`), then aligned by ``alignment``:
    ``none``, ``origin``, ``se3``, ``sim3`` or ``scale`` (evo's ``--align_origin``, ``-a``, ``-as``, ``-s``; the
    Umeyama fit on the first ``n_to_align`` poses), or ``4dof`` (a rotation about ``up_axis`` and a translation,
    ours). ``relations``: evo's pose relations (:data:`keys.RELATION_KEYS`); the translation is always computed.
    For a position-only estimate only the translation relations are computed: its rotations mean nothing.
    ``engine_name``: ``arrays`` computes evo's metrics on whole arrays (:mod:`.engine`), ``evo`` runs evo's own
    per-pose loops; both give the same numbers and result files. ``cov``: the estimate's pose covariances
    ``(t_s, (N, 6, 6))`` in ROS's order and frames: the NEES of position and attitude (:func:`pose_nees_of`).
    ``rpe_trajectories``: False leaves the reduced trajectories out of the arrays engine's RPE results (see
    :func:`engine.rpe_result`; evo's loops always make them). ``ref_name``: the reference's name in the result
    files (``name`` is the estimate's).
    """
    if engine_name not in ENGINES:
        raise ValueError(f"evaluation engine {engine_name!r}: expected one of {', '.join(ENGINES)}")
    arrays = engine_name == "arrays"
    if has_orientation is None:
        has_orientation = getattr(estimate, "has_orientation", True)
    n_est = len(estimate) if isinstance(estimate, PoseSeries) else estimate.num_poses
    ev = EstimateEvaluation(name=name, poses=n_est, matched_poses=0)
    ev.association, ev.alignment = association, alignment
    # (before the association: an estimate none of whose poses match is counted too)
    ev.matchable, ev.ref_interval_s = _matchable(reference, estimate, t_max_diff_s, t_offset_s)
    try:
        ref_a, est_a = associate(reference, estimate, association, t_max_diff_s, t_offset_s)
    except sync.SyncException as exc:
        ev.note = f"no poses associated ({association}, max {t_max_diff_s} s: {exc})"
        return ev
    ev.matched_poses = int(ref_a.num_poses)
    if ev.matched_poses < 2:
        ev.note = "fewer than 2 associated poses"
        return ev
    applied = (np.eye(3), 1.0)             # the rotation and scale the alignment applied (none: identity)
    if alignment == "4dof":
        est_a, ev.alignment_params, applied = _align_4dof(est_a, ref_a, up_axis, n_to_align)
    elif alignment == "origin" and not has_orientation:
        # evo's --align_origin moves the first pose onto the reference's, rotation included: a GNSS track's placeholder
        # orientation turned kitti-00's by 61 deg (APE 298 m for 2.45); its first position is all it has
        T = np.eye(4)
        T[:3, 3] = np.asarray(ref_a.positions_xyz[0]) - np.asarray(est_a.positions_xyz[0])
        if arrays:
            est_a = engine.with_poses(est_a, T @ engine.traj_se3(est_a))
        else:
            est_a = copy.deepcopy(est_a)
            est_a.transform(T)
        ev.alignment_params = {"T": T.tolist(), "note": "position only: aligned at its first position (no rotation)"}
    elif alignment in ("se3", "sim3", "scale", "origin"):
        try:
            est_a, ev.alignment_params, applied = _align(est_a, ref_a, alignment, arrays, n_to_align)
        except GeometryException as exc:
            # Umeyama's fit needs positions that span more than a line: 2 matched poses, or an estimate that
            # stood still (a tracker that lost track), was a traceback
            n = ev.matched_poses if n_to_align == -1 else min(n_to_align, ev.matched_poses)
            raise DataRangeError(f"{name}: the {alignment} alignment is not possible on its {n} matched positions "
                                 f"(evo: {exc}): it needs at least 3 that do not lie on one line (or one point); "
                                 "choose another --alignment") from None
    if cov is not None:
        ev.nees = pose_nees_of(ref_a, est_a, cov, applied, t_max_diff_s)
    labelled = _evo_labelled(alignment, n_to_align, ev.alignment_params)
    wanted = ["trans_part", *[r for r in relations if r != "trans_part"]]
    rels = [(keys.RELATION_KEYS[r], keys.EVO_RELATIONS[r]) for r in wanted
            if has_orientation or r in keys.POSITION_RELATIONS]
    calc = _Arrays(ref_a, est_a, rpe_trajectories, [rel for _, rel in rels]) if arrays else _EvoLoops(ref_a, est_a)

    ev.metrics[keys.APE] = {}
    for key, rel in rels:
        res = labelled(calc.ape(rel))
        ev.metrics["ape"][key] = _stats(res)
        ev.results[f"ape_{keys.RESULT_NAMES[key]}"] = res
        if key == "translation_m":
            # on the reference's clock, as matched: the estimate keeps its own stamps through the association
            # (evo's), and --t-offset once left the segment table and the APE plot 100 s off (a metamorphic review)
            ev.ape_t_s = np.array(est_a.timestamps) + t_offset_s
            ev.ape_err_m = np.array(res.np_arrays["error_array"])
            ev.ref_p_m = np.array(ref_a.positions_xyz)
            ev.ape_hv_m = horizontal_vertical(np.asarray(est_a.positions_xyz) - ev.ref_p_m, up_axis, ev.ref_p_m)
    if has_orientation:
        d = kitti_drift(*calc.se3())
        ev.drift = None if d is None else d.as_dict()
    if not has_orientation:
        ev.note = "position only: no rotation or relative (RPE) metrics" + (
            "; aligned at its first position, not its (placeholder) orientation" if alignment == "origin" else "")
        return _named(ev, ref_name)
    for label, delta, unit in ((keys.RPE_FRAME, 1.0, metrics.Unit.frames),
                               (keys.rpe_distance_group(rpe_delta_m), rpe_delta_m, metrics.Unit.meters)):
        ev.metrics[label] = {}
        failed = []
        for key, rel in rels:
            try:
                res = labelled(calc.rpe(rel, delta, unit))
            except (metrics.MetricsException, FilterException) as exc:   # e.g. a drive shorter than delta
                failed.append((key, exc))
                ev.metrics[label][key] = None
                continue
            ev.metrics[label][key] = _stats(res)
            ev.results[f"{label}_{keys.RESULT_NAMES[key]}"] = res
        if failed:
            # one line per estimate, and the setting to change: evo's own words ('try lower values') came once per
            # pose relation, naming no setting (a room-sized route gave 14 such lines in a compare; a non-car review)
            what = ", ".join(k for k, _ in failed)
            if unit == metrics.Unit.meters and "empty index list" in str(failed[0][1]):
                log.warning("%s: %s (%s) not computed: no two poses %g m apart along its path (a route shorter than "
                            "that); give a shorter evaluation.rpe_delta_m (evaluate: --rpe-delta-m)", name, label, what,
                            delta)
            else:
                log.warning("%s: %s (%s) not computed: %s", name, label, what, failed[0][1])
    return _named(ev, ref_name)


def _named(ev: EstimateEvaluation, ref: str) -> EstimateEvaluation:
    """Each evo result named by its estimate and reference, as ``evo_ape`` names them by their files: evo's
    defaults ('estimate', 'reference') made every result file of a run alike, and ``evo_res *.zip`` refuses
    results whose ``est_name`` repeats. Names, not paths: a run's files are the same bytes in any checkout."""
    for res in ev.results.values():
        old = (res.info.get("ref_name"), res.info.get("est_name"))
        res.info["ref_name"], res.info["est_name"] = ref, ev.name
        res.trajectories = {ref if k == old[0] else ev.name if k == old[1] else k: v for k, v in res.trajectories.items()}
    return ev


def pose_nees_of(ref_a, est_a, cov: tuple[np.ndarray, np.ndarray], applied: tuple[np.ndarray, float],
                 t_max_diff_s: float) -> dict | None:
    """Position and attitude NEES (3 dof each) of the associated, aligned estimate against the reference.

    ``cov``: ``(t_s, (N, 6, 6))`` in ROS's order: position in the parent frame (m^2), then rotation about the parent's
    axes (rad^2), as ``PoseWithCovarianceStamped`` holds it. Each estimated pose takes the covariance of the nearest
    stamp within ``t_max_diff_s``; an alignment's rotation ``R`` and scale ``s`` carry it along (``s^2 R P R^T``
    for the position, ``R P R^T`` for the rotation), and the rotation block is expressed in the body frame for the
    error ``R_ref = R_est Exp(e)`` (:func:`fusion_eval.evaluation.consistency.pose_nees`).
    """
    from .consistency import pose_nees, summary

    t_c, C = cov
    i_est, i_cov = engine.matching_time_indices(np.asarray(est_a.timestamps), np.asarray(t_c), t_max_diff_s)
    if i_est.size == 0:
        log.warning("%s: no covariance stamp within %g s of an associated pose: no NEES", est_name(est_a), t_max_diff_s)
        return None
    R_A, s = applied
    T_e, T_r = engine.traj_se3(est_a)[i_est], engine.traj_se3(ref_a)[i_est]
    P = np.array(C[i_cov], float)
    R_e = T_e[:, :3, :3]
    P_pos = s * s * np.einsum("ij,njk,lk->nil", R_A, P[:, :3, :3], R_A)
    P_rot_w = np.einsum("ij,njk,lk->nil", R_A, P[:, 3:, 3:], R_A)
    P_rot_b = np.einsum("nji,njk,nkl->nil", R_e, P_rot_w, R_e)
    P6 = np.zeros((len(P), 6, 6))
    P6[:, :3, :3], P6[:, 3:, 3:] = P_pos, P_rot_b
    ok = (np.linalg.eigvalsh(P_pos).min(axis=1) > 0) & (np.linalg.eigvalsh(P_rot_b).min(axis=1) > 0)
    skipped = int(np.count_nonzero(~ok))
    if skipped:
        log.warning("%s: %d of %d covariances are not positive definite: left out of the NEES", est_name(est_a), skipped, ok.size)
    if not ok.any():
        return None
    n_p, n_a = pose_nees(T_e[ok, :3, 3], R_e[ok], T_r[ok, :3, 3], T_r[ok, :3, :3], P6[ok])
    return {"position": summary(n_p, 3), "attitude": summary(n_a, 3), "poses_without_covariance": int(est_a.num_poses - i_est.size),
            "covariances_not_positive_definite": skipped}


# an APE RMSE below this is an estimate scored where it equals its reference (an anchored start, a ground truth of two
# poses): no ratio is taken over it ('fused over lidar 2699170384210' on a 2-row ground truth: a corrupted-input review)
MIN_RATIO_DENOMINATOR_M = 1e-6


def ratio(a: EstimateEvaluation | None, b: EstimateEvaluation | None) -> float | None:
    """APE translation RMSE of ``a`` over that of ``b`` (None when either is missing, or ``b``'s is below
    :data:`MIN_RATIO_DENOMINATOR_M`)."""
    try:
        den = b.metrics["ape"]["translation_m"]["rmse"]
        return None if not den >= MIN_RATIO_DENOMINATOR_M else float(a.metrics["ape"]["translation_m"]["rmse"] / den)
    except (AttributeError, KeyError, TypeError, ZeroDivisionError):
        return None
