"""``fusion-eval evaluate``: the full report for existing trajectory files (any localization system's output),
or for trajectory topics of a ROS 1 / ROS 2 bag.

Files are TUM, KITTI poses or EuRoC CSV, told apart by their content (``--format`` forces one) and read by
evo's readers (:mod:`fusion_eval.datasets.trajectory_file`). KITTI files take their stamps from a times file
(``--ref-times``, ``--times``); without one, poses are matched by index (frame i gets the stamp i seconds).
"""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..datasets.trajectory_file import BY_INDEX, TrajectoryFile, as_series, read_bag_trajectories, read_trajectory
from ..errors import ConfigError, DataRangeError
from ..evaluation import keys
from ..evaluation.estimates import evaluate_series, validate_options
from ..evaluation.trajectory import aligned_positions
from ..outputs import StagedDir, repeated_path
from ..report.markdown import drift_section, drift_table, fmt_stat, segments_section
from .. import provenance
from ..provenance import header_line
from ..report import files, html
from ..tables import latex, latex_document, markdown

log = logging.getLogger(__name__)


def read_inputs(inputs: list, bag: Path | None, ref_topic: str | None, fmt: str, ref_times: Path | None,
                times: Path | None, t_offset_s: float = 0.0) -> tuple:
    """The reference and the estimates (``TrajectoryFile``) of ``evaluate``'s arguments: files, or bag topics."""
    if bag is not None:
        if not ref_topic:
            raise ConfigError("--bag needs --ref REF_TOPIC (the reference topic) and one or more estimate topics")
        if ref_times or times or fmt != "auto":
            raise ConfigError("--ref-times, --times and --format apply to trajectory files, not to bag topics")
        if ref_topic in inputs and t_offset_s == 0.0:
            raise ConfigError(f"--bag {bag}: topic {ref_topic} given as an estimate and as the reference (--ref)")
        twice = next((t for i, t in enumerate(inputs) if t in inputs[:i]), None)
        if twice is not None:            # (as one file given twice: it would be evaluated twice, as two estimates)
            raise ConfigError(f"--bag {bag}: topic {twice} given twice as an estimate")
        tfs = read_bag_trajectories(bag, [ref_topic, *inputs])
        return tfs[0], tfs[1:]
    if ref_topic:
        raise ConfigError("--ref names a topic: give the bag with --bag")
    if len(inputs) < 2:
        raise ConfigError("give a reference file and at least one estimate file (or --bag FILE --ref TOPIC TOPIC...)")
    twice = repeated_path(inputs[1:])    # one file twice would be evaluated twice, as two estimates
    if twice:
        raise ConfigError(f"{twice[1]}: given twice as an estimate (as {twice[0]} before)")
    twice = next(((inputs[0], p) for p in inputs[1:] if repeated_path([inputs[0], p])), None)
    same_times = (ref_times is None) == (times is None) and (times is None or repeated_path([ref_times, times]))
    if twice and same_times and t_offset_s == 0.0:
        # the reference against itself: an APE of 0.000 with exit 0 says nothing (with other times or an offset it
        # is a test of their effect, and is run)
        raise ConfigError(f"{twice[1]}: given as an estimate and as the reference ({twice[0]}), with the same stamps")
    ref = _dataset_reference(inputs[0], ref_times) or read_trajectory(inputs[0], ref_times, fmt)
    ests = [read_trajectory(p, times, fmt) for p in inputs[1:]]
    for f in ests:
        # paired by frame index, one pose missing mid-file would shift every later pair, silently
        if ref.stamps == BY_INDEX and f.stamps == BY_INDEX and f.traj.num_poses != ref.traj.num_poses:
            raise DataRangeError(f"{f.source} has {f.traj.num_poses} poses and the reference {ref.source} "
                                 f"{ref.traj.num_poses}: KITTI pose files without times are paired by frame index, so "
                                 "they must have one pose per frame each (give both times files: --ref-times, --times)")
    return ref, ests


def _dataset_reference(path, ref_times) -> TrajectoryFile | None:
    """A dataset (a folder: a manifest's, a KITTI raw drive, an EuRoC folder; or a manifest ``.yaml``) as the
    reference: its ground truth as a run scores against it (``prepare.ground_truth``), or None for a trajectory file.
    (A user with a run's estimate and the drive it came from had to run first to get ``groundtruth.tum``; an
    own-data review.)"""
    p = Path(path)
    if not (p.is_dir() or p.suffix in (".yaml", ".yml")):
        return None
    if ref_times is not None:
        raise ConfigError(f"--ref-times applies to a KITTI pose file; {p} is a dataset, whose ground truth has its stamps")
    from ..datasets.manifest import load_dataset
    from ..evaluation.trajectory import to_evo
    from ..prepare import ground_truth

    ds = load_dataset(p)
    if ds.groundtruth is None:
        raise ConfigError(f"{p}: dataset {ds.name!r} has no groundtruth stream to evaluate against")
    gt = ground_truth(ds)
    return TrajectoryFile(traj=to_evo(gt, "groundtruth"), format="dataset", stamps="the dataset's stamps",
                          source=f"{ds.name} ground truth ({gt.source})")


def run_evaluate(inputs: list, out_dir: Path, ref_times: Path | None = None, times: Path | None = None,
                 association: str = "nearest", alignment: str = "none", t_max_diff_s: float = 0.01,
                 rpe_delta_m: float = 100.0, segment_m: float = 100.0, segment_s: float | None = None,
                 overwrite: bool = False, make_plots: bool = True, engine: str = "arrays", *, bag: Path | None = None,
                 ref_topic: str | None = None, fmt: str = "auto", relations: tuple[str, ...] = keys.DEFAULT_RELATIONS,
                 up_axis: str = "auto", n_to_align: int = -1, t_offset_s: float = 0.0,
                 t_range_s: tuple[float | None, float | None] = (None, None)) -> dict:
    validate_options(association, alignment, t_max_diff_s, rpe_delta_m, segment_m, segment_s, engine, relations,
                     up_axis, n_to_align)
    staged = StagedDir(out_dir, overwrite=overwrite, inputs=(*(inputs if bag is None else ()), bag, ref_times, times))
    staged.check()
    # the output folder (its staging) is made before the work: an --out that cannot be created was said only after it
    with staged as out:
        ref_f, est_fs = read_inputs(list(inputs), bag, ref_topic, fmt, ref_times, times, t_offset_s)
        if ref_f.format == "dataset" and up_axis == "auto":
            # a dataset's ground truth is in a run's world frame, whose up is z: the run's own figures (a vertical
            # flight's 'auto' took y, and a 4dof alignment then tilted the world: 0.847 m for the run's 0.985; a
            # non-car review)
            up_axis = "z"
        for why in ref_f.flags:               # the estimates' are said with their other notes, below
            log.warning("the reference %s: %s", Path(ref_f.source).name, why)
        if segment_s is not None and ref_f.stamps == BY_INDEX:
            # the frame index would be read as seconds: 60 frames of a 10 Hz drive labelled "60 s"
            raise ConfigError(f"--segment-s needs stamps in seconds, and the reference {ref_f.source} has none (KITTI poses "
                              "without a times file are stamped by frame index): give --ref-times and --times, or "
                              "--segment-m")
        ref_traj = _time_range(ref_f, t_range_s)
        series, about, covs = {}, {}, {}
        names = [Path(f.source).stem if f.format != "bag" else f.traj.meta["name"].strip("/").replace("/", "_") for f in est_fs]
        # files of one name in different folders (run1/fused.tum, run2/fused.tum) are told apart by their folder
        names = [f"{Path(f.source).parent.name}-{n}" if f.format != "bag" and names.count(n) > 1 and Path(f.source).parent.name
                 else n for f, n in zip(est_fs, names)]
        for f, name in zip(est_fs, names):
            while name in series or name == "groundtruth":
                name += "_"
            series[name] = f.traj
            about[name] = {"file": f.source, "format": f.format, "stamps": f.stamps,
                           **({"repeated_stamps": f.repeated_stamps} if f.repeated_stamps else {}),
                           **({"reading": f.note} if f.note else {})}
            if f.cov is not None:
                covs[name] = (f.cov_t_s, f.cov)
        turns = {name: _orientation_placeholder(f, ref_f) for name, f in zip(series, est_fs)}
        # the other way round: a reference of placeholders (an RTK or GNSS truth written as TUM) made every estimate's
        # rotation, RPE and drift figures about the placeholder, with no word (a corrupted-input review)
        ref_turns = {name: _orientation_placeholder(ref_f, f, reference=True) for name, f in zip(series, est_fs)
                     if turns[name] is None}
        fixed = frozenset(name for name, turn in {**turns, **ref_turns}.items() if turn is not None)
        try:
            m, evals = evaluate_series(ref_traj, series, association, alignment, t_max_diff_s, rpe_delta_m, segment_m,
                                       segment_s, about, ref_stamps=ref_f.stamps, engine=engine, relations=relations,
                                       up_axis=up_axis, n_to_align=n_to_align, t_offset_s=t_offset_s, covariances=covs,
                                       position_only=fixed,
                                       ref_name=ref_topic if bag is not None else Path(ref_f.source).name)
        except DataRangeError:
            # an alignment that failed on the 2 poses a stamp unit mistake matched: the unit is the news, not the
            # alignment ('choose another --alignment' for a times file in ms)
            for f in est_fs:
                if _unit_power(ref_f, f):
                    raise DataRangeError(f"{_span(f)} against the reference {_span(ref_f)}: {_unit_hint(ref_f, f).rstrip()} "
                                         f"(its stamps scaled by 1e{-3 * _unit_power(ref_f, f):+d} would cover the "
                                         "reference's; give them in seconds)") from None
            raise
        _refuse_unmatched(ref_f, est_fs, evals, association, t_max_diff_s, t_range_s, t_offset_s)
        for name in fixed:                   # why, in the report too (it was on stderr only)
            m["estimates"][name]["note"] = (
                f"position only (one and the same orientation on every pose, while the reference turns by up to "
                f"{turns[name]:.0f} deg: placeholders): no rotation, relative (RPE) or KITTI drift metric"
                if turns[name] is not None else
                f"position only (the reference has one and the same orientation on every pose, while this estimate turns "
                f"by up to {ref_turns[name]:.0f} deg: placeholders): no rotation, relative (RPE) or KITTI drift metric")
        for name, f in zip(series, est_fs):
            ape = m["estimates"][name].get("ape") or {}
            rot, trans = ((ape.get(k) or {}).get("rmse") for k in ("rotation_deg", "translation_m"))
            for why in [*f.flags, *convention_hints(f, ref_f, alignment, rot, trans, t_offset_s),
                        *span_and_clock_hints(f, ref_f, evals[name], alignment, t_range_s, t_offset_s)]:
                log.warning("%s: %s", name, why)
                e = m["estimates"][name]
                e["note"] = f"{e['note']}; {why}" if e.get("note") else why
        if alignment == "none":              # bag topics in other frames, compared as they are (317 m with exit 0 once)
            edges = None
            for name, f in zip(series, est_fs):
                a, b = (x.strip("/") if x else None for x in (f.frame_id, ref_f.frame_id))
                if a and b and a != b:
                    from ..datasets import rosbag

                    edges = rosbag.static_edges(bag) if edges is None else edges
                    T = rosbag.transform_between(edges, b, a)
                    if T is not None and np.allclose(T, np.eye(4), atol=1e-9):
                        continue              # two names of one frame (map -> world as an identity /tf_static edge)
                    why = (f"its poses are in frame '{a}', the reference's in '{b}': without an alignment (--alignment se3, "
                           "or origin) their positions are compared across two frames")
                    log.warning("%s: %s", name, why)
                    e = m["estimates"][name]
                    e["note"] = f"{e['note']}; {why}" if e.get("note") else why
        if t_range_s != (None, None):
            m["evaluation"]["time_range_s"] = list(t_range_s)
        metrics = {"reference": ref_f.source, "reference_format": ref_f.format, "reference_stamps": ref_f.stamps,
                   **({"reference_repeated_stamps": ref_f.repeated_stamps} if ref_f.repeated_stamps else {}), **m}
        named = [("bag", bag)] if bag is not None else \
            [("reference", inputs[0]), *[("estimate", p) for p in inputs[1:]]] + \
            [(role, p) for role, p in (("reference times", ref_times), ("estimate times", times)) if p is not None]
        made = provenance.files(named)
        # the returned metrics stay the figures; the file also says what made them (as run's metrics.json)
        out.write_text("metrics.json", files.metrics_json({**metrics, "provenance": provenance.block(made)}))
        for ev in evals.values():          # evo's result files, one per metric and pose relation (evo_res reads them)
            files.write_evo_zips(ev, out.path("."))
        written = []
        if make_plots:
            from ..evaluation.alignment import detect_up_axis
            from ..report import plots

            ref = as_series(ref_f)
            up = up_axis if up_axis != "auto" else detect_up_axis(ref.p_w_m)[0] if len(ref) >= 3 else "z"
            plots.plot_generic_trajectories(out.path("trajectories.png"), ref,
                                            {k: _aligned(as_series(f), evals[k]) for k, f in zip(series, est_fs)},
                                            up_axis=up, alignment=alignment)
            plots.plot_ape_over_time(out.path("ape_over_time.png"), evals, float(ref.t_s[0]),
                                     "frame since start" if ref_f.stamps == BY_INDEX else "time since start [s]")
            written = ["trajectories.png", "ape_over_time.png"]
            if any(ev.drift for ev in evals.values()):
                plots.plot_drift(out.path("kitti_drift.png"), evals)
                written.append("kitti_drift.png")
            if metrics["segments"]:
                plots.plot_segment_map(out.path("segments_map.png"), evals, metrics["segments"], up_axis=up)
                written.append("segments_map.png")
        md = _report(metrics, written)
        out.write_text("report.md", md)
        out.write_text("metrics.tex", _latex(metrics))
        out.write_text("report.html", html.page(md, out.path("."), inputs=made))
    return metrics


PLACEHOLDER_TURN_DEG = 5.0      # the reference turning more than this while an estimate never does: placeholders


def _orientation_placeholder(f, ref_f, reference: bool = False) -> float | None:
    """Whether ``f``'s orientations are placeholders: one and the same quaternion on every pose while the reference
    turns (a GNSS or position-only track written as TUM, e.g. a run's own ``gnss.tum``). Its rotation, RPE and KITTI
    drift would be numbers about the placeholder (a 100 deg rotation error, 78 % drift: the relative translations
    taken in the wrong frame), so it is scored as a run scores GNSS, by APE translation only, and a warning says so.
    Returns the reference's largest turn (deg) for such an estimate, else None."""
    q, qr = f.traj.orientations_quat_wxyz, ref_f.traj.orientations_quat_wxyz
    if len(q) < 2 or len(qr) < 2 or not np.all(q == q[0]):
        return None
    cos_half = np.clip(np.abs(qr @ qr[0]) / (np.linalg.norm(qr, axis=1) * np.linalg.norm(qr[0])), 0.0, 1.0)
    turn_deg = float(np.degrees(2 * np.arccos(cos_half.min())))
    if turn_deg <= PLACEHOLDER_TURN_DEG:
        return None
    if reference:        # ``f`` is the reference, ``ref_f`` the estimate that turns
        log.warning("the reference %s has the same orientation on every pose while %s turns by up to %.0f deg: "
                    "placeholders; %s evaluated as position only (APE translation; no rotation, RPE or KITTI drift "
                    "metric)", f.source, ref_f.source, turn_deg, ref_f.source)
        return turn_deg
    log.warning("%s: every pose has the same orientation while the reference turns by up to %.0f deg: evaluated as "
                "position only (APE translation; no rotation, RPE or KITTI drift metric)", f.source, turn_deg)
    return turn_deg


def _body_turns(q_wxyz: np.ndarray, step: int) -> np.ndarray:
    """Rotation vectors of the orientation's increments over ``step`` poses, in the body frame (rad)."""
    from ..so3 import log_so3, quat_xyzw_to_matrix, wxyz_to_xyzw

    R = quat_xyzw_to_matrix(wxyz_to_xyzw(np.asarray(q_wxyz, float))).reshape(-1, 3, 3)
    return log_so3(np.einsum("nji,njk->nik", R[:-step:step], R[step::step]))


def _misfit(a: np.ndarray, b: np.ndarray) -> float:
    """How far body-frame turns ``b`` are from ``a`` under the best constant rotation (a mount): the residual's RMS
    over ``a``'s (Kabsch's fit)."""
    from ..so3 import nearest_rotation

    R = nearest_rotation(a.T @ b)            # a ~ R b
    return float(np.sqrt(np.mean(np.sum((a - b @ R.T) ** 2, axis=1)) / max(np.mean(np.sum(a ** 2, axis=1)), 1e-300)))


def _direct_reading(q_ref_wxyz: np.ndarray, q_wxyz: np.ndarray, readings: dict):
    """``(reading, rms_deg)`` of the reading of the quaternions (``readings``: name -> (n, 4) wxyz) that matches the
    reference's orientations as they are, with no rotation fitted, to under :data:`DIRECT_MATCH_DEG` RMS; or None."""
    qr = np.asarray(q_ref_wxyz, float)
    qr = qr / np.linalg.norm(qr, axis=1, keepdims=True)
    best = None
    for name, v in readings.items():
        v = np.asarray(v, float) / np.linalg.norm(v, axis=1, keepdims=True)
        ang = 2.0 * np.degrees(np.arccos(np.clip(np.abs(np.sum(qr * v, axis=1)), 0.0, 1.0)))
        rms = float(np.sqrt(np.mean(ang ** 2)))
        if rms < DIRECT_MATCH_DEG and (best is None or rms < best[1]):
            best = (name, rms)
    return best


DIRECT_MATCH_DEG = 5.0


def _spread(q_ref_wxyz: np.ndarray, q_wxyz: np.ndarray, two_sided: bool = True, iterations: int = 8) -> float:
    """How far the orientations ``q`` are from the reference's under one constant rotation on the world side and one on
    the body side (``R_ref ~ A R B``: another world frame and a mount, fitted alternately), or with ``two_sided``
    False under one of the two alone (the better): the RMS angle (rad) left."""
    from ..so3 import log_so3, nearest_rotation as proj, quat_xyzw_to_matrix, wxyz_to_xyzw

    Rr, R = (quat_xyzw_to_matrix(wxyz_to_xyzw(np.asarray(x, float))).reshape(-1, 3, 3) for x in (q_ref_wxyz, q_wxyz))

    def left(A, B):                     # RMS angle of Rr^T A R B
        E = np.einsum("nji,jk,nkl->nil", Rr, A, R @ B, optimize=True)
        return float(np.sqrt(np.mean(np.sum(log_so3(E) ** 2, axis=1))))

    if not two_sided:
        world = proj(np.einsum("nij,nkj->ik", Rr, R))                    # Rr ~ A R
        body = proj(np.einsum("nji,njk->ik", R, Rr))                     # Rr ~ R B
        return min(left(world, np.eye(3)), left(np.eye(3), body))
    # B from the turns since the first pose, which the model conjugates by B (Rr_0^T Rr_i = B^T R_0^T R_i B, so their
    # rotation vectors are B^T times each other's): alternating from the identity crawled along a planar track's
    # trade-off of the two yaws (9.5 deg left after 8 rounds where 2.4 is the answer)
    vr = log_so3(np.einsum("ji,njk->nik", Rr[0], Rr))
    v = log_so3(np.einsum("ji,njk->nik", R[0], R))
    B = proj(np.einsum("ni,nj->ij", v, vr))                              # v_ref ~ B^T v: B = argmax tr(B^T ...)
    A = np.eye(3)
    for _ in range(iterations):
        A = proj(np.einsum("nij,nkj->ik", Rr, R @ B))                    # sum Rr (R B)^T
        B = proj(np.einsum("nji,jk,nkl->il", R, A.T, Rr, optimize=True))  # sum R^T A^T Rr
    return left(A, B)


# unaligned, an APE this many times (and this many metres more than) the residual of one rigid motion is of two world
# frames, not of the estimate (a run's lidar: 7.2 m against a 2.9 m fit; its dead reckoning 13 km against 6 km)
OTHER_WORLD_RATIO, OTHER_WORLD_MIN_M, OTHER_WORLD_TURN_DEG = 10.0, 1.0, 10.0


def _other_world(p_ref: np.ndarray, p: np.ndarray, trans_rmse_m: float) -> str:
    """Why an unaligned estimate's APE is of its world frame, or '': one rotation and translation (Kabsch) fit its
    positions to the reference's to under 1/:data:`OTHER_WORLD_RATIO` of that APE: a KITTI cam0 ground truth against an
    ENU GPS track scored 382.9 m as they are and 1.19 m aligned, with no word (an own-data review; bag topics of
    other frames were said already)."""
    if len(p) < 10 or not trans_rmse_m > OTHER_WORLD_MIN_M:
        return ""
    R, fit = _rigid_fit(p_ref, p)
    if trans_rmse_m < OTHER_WORLD_RATIO * fit or trans_rmse_m - fit < OTHER_WORLD_MIN_M:
        return ""
    turn = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))
    # and a frame's turn, or an error that is one constant offset: an odometry's first 47 s, whose error is its small
    # heading drift about the start, fit as well (1.2 m unaligned) and is no other frame (a test)
    e = p - p_ref
    if turn < OTHER_WORLD_TURN_DEG and float(np.linalg.norm(e.mean(axis=0))) < 0.9 * np.sqrt(np.mean(np.sum(e ** 2, axis=1))):
        return ""
    return (f"its positions fit the reference's to {fit:.3g} m RMS under one rotation ({turn:.0f} deg) and translation, "
            f"against {trans_rmse_m:.3g} m as they are: the two are in different world frames (a camera's map frame "
            "against ENU, another origin), which --alignment se3 (or origin, for the origin alone) compares")


def _rigid_fit(p_ref: np.ndarray, p: np.ndarray, mirror: bool = False) -> tuple[np.ndarray, float]:
    """The rotation ``R`` (with ``mirror``, the reflection) and translation that best fit the positions ``p`` to the
    reference's, ``p_ref ~ p R + c`` (Kabsch), and the RMS residual (m)."""
    a, b = p - p.mean(axis=0), p_ref - p_ref.mean(axis=0)
    U, _, Vt = np.linalg.svd(a.T @ b)
    R = U @ np.diag([1.0, 1.0, (-1.0 if mirror else 1.0) * np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return R, float(np.sqrt(np.mean(np.sum((a @ R - b) ** 2, axis=1))))


def _mirrored(p_ref: np.ndarray, p: np.ndarray) -> str:
    """Why the positions ``p`` are the reference's mirrored (a left-handed frame: one axis flipped), or '': the best
    reflection fits them to a third of the best rotation's residual, which is itself beyond 10 % of the track's
    size."""
    size = _size(p_ref)
    if len(p) < 10 or size <= 0:
        return ""
    # (a flat track is its own mirror image: both fit alike, and nothing is said)
    fit = {sign: _rigid_fit(p_ref, p, mirror=sign < 0)[1] for sign in (1.0, -1.0)}
    if fit[1.0] > 0.1 * size and fit[-1.0] < fit[1.0] / 3:
        return (f"its positions match the reference's mirrored ({fit[-1.0]:.3g} m RMS, against {fit[1.0]:.3g} m under "
                "any rotation): a left-handed frame, one axis flipped (y for -y, NED read as ENU with a sign lost), so "
                "no alignment makes its figures meaningful")
    return ""


def convention_hints(f, ref_f, alignment: str, rot_rmse_deg: float | None = None,
                     trans_rmse_m: float | None = None, t_offset_s: float = 0.0) -> list[str]:
    """Mistakes of convention that read as plausible numbers: positions 1000^k times the reference's (mm for m:
    1758 m of APE on a desk-sized track once, with se3 alignment), and quaternions written w x y z where the format
    wants x y z w (a 149 deg rotation error beside a translation error of millimetres). Each is a sentence for a
    warning and the report; the figures are left as they are."""
    from evo.core import sync

    from ..evaluation.trajectory import associate_nearest

    out = []
    # pairs as the evaluation makes them (nearest stamp, 20 ms, --t-offset applied: without it, no pairs and no word on
    # a file whose stamps needed the offset; a review of the shared data's README: 377 m beside no hint)
    try:
        ref_a, est_a = associate_nearest(ref_f.traj, f.traj, 0.02, t_offset_s)
    except sync.SyncException:
        return out
    if est_a.num_poses < 3:
        return out
    if alignment not in ("sim3", "scale"):
        le, lr = (float(np.sum(np.linalg.norm(np.diff(x.positions_xyz, axis=0), axis=1))) for x in (est_a, ref_a))
        if le > 0 and lr > 0:
            k = np.log10(le / lr) / 3
            if round(k) != 0 and abs(k - round(k)) < 0.1:
                out.append(f"its path is {le / lr:.4g} times the reference's over the same stamps: positions in another "
                           f"unit ({'mm' if round(k) == 1 else 'km' if round(k) == -1 else f'1e{3 * round(k):+d}'} for m?)")
    mirrored = _mirrored(ref_a.positions_xyz, est_a.positions_xyz)
    if mirrored:
        out.append(mirrored)
        return out            # its orientations are of a left-handed frame: no reading of them fits
    if alignment == "none" and trans_rmse_m is not None:
        other = _other_world(ref_a.positions_xyz, est_a.positions_xyz, trans_rmse_m)
        if other:
            out.append(other)
    q = np.asarray(est_a.orientations_quat_wxyz, float)
    step = max(1, int(round(0.5 / max(float(np.median(np.diff(est_a.timestamps))), 1e-9))))   # turns over ~0.5 s
    if not np.all(q == q[0]) and q.shape[0] > 4 * step:
        a = _body_turns(np.asarray(ref_a.orientations_quat_wxyz, float), step)
        turning = np.linalg.norm(a, axis=1) > np.radians(1.0)
        if turning.sum() >= 10:
            # a file's w x y z read as x y z w: evo's (w, x, y, z) is the file's (z, w, x, y); an inverse rotation
            # (world in body, or a JPL quaternion) is the conjugate. Each reading is tried, and the best one named: a
            # conjugate once got the order's hint, which raised its rotation error from 85 to 149 deg (a review)
            as_read = _misfit(a[turning], _body_turns(q, step)[turning])
            conj = q * np.array([1.0, -1.0, -1.0, -1.0])
            # (EuRoC's csv wants w x y z: a file written x y z w is the other way round, evo's (w, x, y, z) being
            # the file's (x, y, z, w); a headerless one was read so with no word, an own-data review)
            order = ("read in the other order: written x y z w where the format wants w x y z", q[:, [3, 0, 1, 2]]) \
                if f.format == "euroc" else \
                ("read in the other order: written w x y z where the format wants x y z w", q[:, [1, 2, 3, 0]])
            readings = {order[0]: order[1],
                        "inverted (their conjugates): the world's orientation in the body frame, or JPL quaternions, "
                        "where the format wants the body's in the world": conj}
            fits = {k: _misfit(a[turning], _body_turns(v, step)[turning]) for k, v in readings.items()}
            # the order and the conjugate give the same body turns, and the same orientations under one constant
            # rotation of the world and one of the body (as does a conjugate in the other order against the file as
            # read): where the reference leaves one side fixed, a one-sided fit tells them apart, else both are named
            ref_q = np.asarray(ref_a.orientations_quat_wxyz, float)
            cands = [k for k, v in fits.items() if v < 0.25 * as_read] if as_read > 0.5 else []
            if cands:
                one = {k: _spread(ref_q, readings[k], two_sided=False) for k in cands}
                best = min(one, key=one.get)
                others = [v for k, v in one.items() if k != best]
                ties = [best] if not others or one[best] < 0.5 * min(others) else cands
                what, question = best.split(": ", 1)
                if len(ties) > 1:
                    what = " or ".join(k.split(": ", 1)[0] for k in ties) + " (their turns cannot tell which)"
                    question = " or ".join(k.split(": ", 1)[1] for k in ties)
                out.append(f"its body-frame turns match the reference's to {as_read:.0%} of their size under any "
                           f"mount rotation, to {fits[best]:.0%} with its quaternions {what}: {question}?")
            elif (alignment == "none" and rot_rmse_deg is not None and rot_rmse_deg > BODY_OFFSET_DEG
                  and trans_rmse_m is not None and trans_rmse_m < FOLLOWS_FRACTION * _size(ref_a.positions_xyz)
                  and (direct := _direct_reading(ref_q, q, readings))):
                # the world frame is the reference's (no alignment): a reading that matches its orientations as they
                # are names itself, where a planar track's turns fit every reading under a mount (a headerless
                # x y z w file read as EuRoC's w-first: 139 deg beside no translation error, no word; an own-data review)
                what, question = direct[0].split(": ", 1)
                out.append(f"its rotation error is {rot_rmse_deg:.0f} deg beside positions that follow the reference's, "
                           f"and {direct[1]:.2f} deg RMS with its quaternions {what}: {question}?")
            elif (alignment in ("se3", "sim3") and rot_rmse_deg is not None and rot_rmse_deg > BODY_OFFSET_DEG
                  and trans_rmse_m is not None and trans_rmse_m < FOLLOWS_FRACTION * _size(ref_a.positions_xyz)
                  and (spread0 := _spread(ref_q, q)) < np.radians(5.0)):      # (only where it is read: 1 s at 100k poses)
                # as read, the reference's orientations up to one constant rotation of the world and one of the body,
                # yet a large rotation error once the world is aligned: another frame's poses (a camera's optical
                # frame gave 89.5 deg beside 0.146 m, no word; a review)
                out.append(f"its orientations match the reference's under one constant rotation of the world and one "
                           f"of the body to {np.degrees(spread0):.1f} deg RMS, and its rotation error is "
                           f"{rot_rmse_deg:.0f} deg: a constant offset of the body, the poses of another frame than the "
                           "reference's (a camera's, whose optical z axis looks forward; a mounted sensor), or a "
                           "quaternion convention that amounts to one (conjugates written w x y z)")
    return out


BODY_OFFSET_DEG = 20.0      # a rotation error this large and constant is another frame, not a mounting tolerance
# and only for an estimate whose positions follow the reference's (its APE under this fraction of the track's size):
# a run's dead reckoning, 13 km off, was turned by the se3 fit and got the hint on 16 of 48 run outputs (a review)
FOLLOWS_FRACTION = 0.1


def _size(p: np.ndarray) -> float:
    """The RMS distance of positions from their centroid (m)."""
    p = np.asarray(p, float)
    return float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1)))) if p.size else 0.0


def _in_range(stamps, t_range_s=(None, None), shift_s: float = 0.0) -> np.ndarray:
    """``stamps`` (+ ``shift_s``: an estimate's --t-offset) inside the --t-start / --t-end range, on the reference's
    clock (None: open)."""
    t = np.asarray(stamps, float) + shift_s
    lo = -np.inf if t_range_s[0] is None else t_range_s[0]
    hi = np.inf if t_range_s[1] is None else t_range_s[1]
    return t[(t >= lo) & (t <= hi)]


def span_and_clock_hints(f, ref_f, ev, alignment: str, t_range_s=(None, None), t_offset_s: float = 0.0) -> list[str]:
    """What a run checks and evaluate did not (a corrupted-input review): an estimate whose matched poses span less
    than :data:`fusion_eval.evaluation.span.MIN_COVERED` of the reference's time or of its own (10 % of kitti-00's
    lidar, or of its ground truth, scored 3.18 m against 7.14 m, with no word: the 'half matched' rule counts poses of
    the shorter file), and an estimate whose speed matches the reference's best at another time than stamped (one 1 s late: KITTI drift 9.14 %
    for 0.53 %; :func:`fusion_eval.datasets.plausible.speed_clock_shift`). Sentences for a warning and the report."""
    from ..datasets.plausible import held_speed_shift
    from ..datasets.trajectory_file import BY_INDEX
    from ..evaluation.span import MIN_COVERED

    out = []
    t_ref = _in_range(ref_f.traj.timestamps, t_range_s)
    t_own = _in_range(f.traj.timestamps, t_range_s, t_offset_s)       # as matched: --t-offset applied
    t_est = ev.ape_t_s
    if t_est is not None and t_est.size > 1 and t_ref.size > 1:
        covered = float(t_est[-1] - t_est[0])
        own = float(t_own[-1] - t_own[0]) if t_own.size > 1 else 0.0
        whose, full = max((("the reference's", float(t_ref[-1] - t_ref[0])), ("its own", own)),
                          key=lambda w: w[1])
        if full > 0 and covered < MIN_COVERED * full:
            unit = "frames" if ref_f.stamps == BY_INDEX else "s"
            out.append(f"its matched poses span {covered:.1f} {unit} of {whose} {full:.1f} {unit}: every figure is over "
                       "that part only (a file cut short? --t-start / --t-end evaluate the same stretch of every file)")
    if ref_f.stamps != BY_INDEX and f.stamps != BY_INDEX:
        found = held_speed_shift(np.asarray(f.traj.timestamps, float) + t_offset_s, f.traj.positions_xyz,
                                 ref_f.traj.timestamps, ref_f.traj.positions_xyz)
        if found is not None:
            s, c_best, c_zero = found
            # s > 0: stamped late (its pose stamped t is the reference's at t - s); --t-offset is added to its stamps
            out.append(f"its speed matches the reference's best {abs(s):.2f} s {'earlier' if s > 0 else 'later'} than "
                       f"stamped (correlation {c_best:.4f} there, {c_zero:.4f} as stamped): a clock offset between the "
                       f"files, which every figure carries (--t-offset {t_offset_s - s:+.2f} matches them so)")
    return out


def _aligned(series, ev):
    """The estimate as its evaluation aligned it, for the trajectory plot: an unaligned SLAM estimate drawn beside the
    reference looked wrong where its aligned error is millimetres."""
    return replace(series, p_w_m=aligned_positions(series.p_w_m, ev.alignment_params))


def _span(f) -> str:
    t = f.traj.timestamps
    return f"{f.source} ({len(t)} poses, {t[0]:.3f} to {t[-1]:.3f} s)" if len(t) else f"{f.source} (no poses)"


def _refuse_unmatched(ref_f, est_fs, evals: dict, association: str, t_max_diff_s: float,
                      t_range_s=(None, None), t_offset_s: float = 0.0) -> None:
    """Fewer than 2 matched poses is no evaluation: exit 2 naming both files and their time spans (a report of
    'n/a' with exit 0 would pass a CI gate that looks at the exit code). Poses are counted inside the --t-start /
    --t-end range (the whole files were: every range under half a file warned of unmatched poses, a review)."""
    for f, ev in zip(est_fs, evals.values()):
        n = min(_in_range(f.traj.timestamps, t_range_s, t_offset_s).size, _in_range(ref_f.traj.timestamps, t_range_s).size)
        k = _unit_power(ref_f, f)
        if k and ev.matched_poses < 0.1 * n:
            # a times file in milliseconds against one in seconds matched 2 of 4,541 poses, and 200 m of "APE" was
            # reported with exit 0: where the estimate's stamps barely overlap the reference's as they are and
            # cover them once scaled by 1000^-k, a handful of matches is that accident
            raise DataRangeError(f"{ev.matched_poses} of {n} poses of {_span(f)} match the reference {_span(ref_f)}: "
                                 f"{_unit_hint(ref_f, f).rstrip()} (its stamps scaled by 1e{-3 * k:+d} would cover the "
                                 "reference's; give them in seconds)")
        if 2 <= ev.matched_poses < 0.5 * n:
            rates = "--t-max-diff or --association interpolate" if association != "interpolate" else "--t-max-diff"
            log.warning("%s: only %d of its %d poses match the reference (%s, within --t-max-diff %g s): the metrics "
                        "cover those (a time offset? --t-offset; stamps of other rates? %s)", ev.name, ev.matched_poses,
                        n, association, t_max_diff_s, rates)
        if ev.matched_poses < 2:
            raise DataRangeError(f"{ev.matched_poses} poses of {_span(f)} match the reference {_span(ref_f)} "
                                 f"({association}, within --t-max-diff {t_max_diff_s} s); at least 2 are needed "
                                 f"({_unit_hint(ref_f, f)}a time offset between the files? {_offset_hint(ref_f, f)}; "
                                 "KITTI files without times? --times)")


def _offset_hint(ref_f, f) -> str:
    """``--t-offset`` with the shift that puts the estimate's first stamp on the reference's, where the two spans
    do not meet and last alike (a clock offset, not a unit), else the bare option."""
    ta, tb = (np.asarray(x.traj.timestamps, float) for x in (ref_f, f))
    if ta.size >= 2 and tb.size >= 2 and _overlap(ta[0], ta[-1], tb[0], tb[-1]) == 0.0 \
            and 0.1 <= (tb[-1] - tb[0]) / max(ta[-1] - ta[0], 1e-300) <= 10:
        return f"--t-offset {ta[0] - tb[0]:.10g} puts its first stamp on the reference's"
    return "--t-offset"


def _overlap(a0: float, a1: float, b0: float, b1: float) -> float:
    """The fraction of ``[b0, b1]`` that ``[a0, a1]`` covers."""
    return max(0.0, min(a1, b1) - max(a0, b0)) / (b1 - b0) if b1 > b0 else 0.0


def _unit_power(ref_f, f) -> int:
    """``k`` where the estimate's stamps look ``1000^k`` times the reference's unit: they overlap the reference's
    time range by under 10 % as they are, and by over half once scaled by ``1000^-k``; 0 otherwise (an estimate
    that only starts late, in the same unit, overlaps as it is)."""
    ta, tb = (np.asarray(x.traj.timestamps, float) for x in (ref_f, f))
    if ta.size < 2 or tb.size < 2 or _overlap(ta[0], ta[-1], tb[0], tb[-1]) >= 0.1:
        return 0
    span_a = ta[-1] - ta[0]
    for k in (1, -1, 2, -2, 3, -3):
        s = 1000.0 ** -k
        # scaled, its span must also last about as long as the reference's: any span shrunk 1000x fits inside, and a
        # clock offset of 1000 s (or the ROS epoch against 0) was put down to milliseconds (a review)
        if _overlap(ta[0], ta[-1], tb[0] * s, tb[-1] * s) > 0.5 and 0.1 <= (tb[-1] - tb[0]) * s / max(span_a, 1e-300) <= 10:
            return k
    return 0


def _unit_hint(ref_f, f) -> str:
    """Where the two files' first stamps, or their spans, differ by a power of 1000 (seconds against milli-, micro-
    or nanoseconds), say so: a EuRoC file of microseconds is read as nanoseconds, a TUM file of nanoseconds as
    seconds, a KITTI times file of milliseconds (stamps from 0: the span tells) as seconds."""
    ta, tb = (np.asarray(x.traj.timestamps, float) for x in (ref_f, f))
    if not (ta.size and tb.size):
        return ""
    for what, a, b in (("stamps are", ta[0], tb[0]), ("time span is", ta[-1] - ta[0], tb[-1] - tb[0])):
        if a > 0 and b > 0:
            k = np.log10(b / a) / 3
            if abs(k) >= 0.8 and abs(k - round(k)) < 0.2:
                return f"the estimate's {what} 1e{3 * round(k):+d} times the reference's: in another unit? "
    return ""


def _rotation(group: dict, nd: int = 3) -> str:
    """A group's rotation RMSE in degrees, or in radians where only ``-r angle_rad`` was asked for (it read 'n/a'
    as if no rotation had been evaluated)."""
    if group.get("rotation_deg") is not None or group.get("rotation_rad") is None:
        return fmt_stat(group.get("rotation_deg"), nd=nd)
    return f"{fmt_stat(group.get('rotation_rad'), nd=nd + 2)} rad"


def _summary_table(m: dict) -> tuple[list[str], list[list], str]:
    """evo's APE and RPE per estimate (per frame, and per ``--rpe-delta-m``: it was computed but shown only in
    metrics.json): header, rows, alignment (report.md and metrics.tex)."""
    delta = m["evaluation"]["rpe_delta_m"]
    group = keys.rpe_distance_group(delta)
    rows = []
    for k, d in m["estimates"].items():
        ape = d.get("ape") or {}
        rpe = d.get("rpe_1frame") or {}
        rpe_d = d.get(group) or {}
        rows.append([k, d["stamps"], f"{d['matched_poses']}/{d['poses']}", fmt_stat(ape.get("translation_m")),
                     f"{fmt_stat(ape.get('translation_m'), 'mean')} / {fmt_stat(ape.get('translation_m'), 'max')}",
                     _rotation(ape), fmt_stat(rpe.get("translation_m"), nd=4), _rotation(rpe, nd=4),
                     fmt_stat(rpe_d.get("translation_m"), nd=3), _rotation(rpe_d)])
    return (["estimate", "stamps", "matched poses", "APE trans RMSE [m]", "APE trans mean / max [m]",
             "APE rot RMSE [deg]", "RPE trans 1 frame RMSE [m]", "RPE rot 1 frame RMSE [deg]",
             f"RPE trans {delta:g} m RMSE [m]", f"RPE rot {delta:g} m RMSE [deg]"], rows, "llrrrrrrrr")


def _latex(m: dict) -> str:
    e, ref = m["evaluation"], Path(m["reference"]).name
    label = "tab:evaluate-" + "".join(c if c.isalnum() else "-" for c in Path(m["reference"]).stem)
    tabs = [latex(*_summary_table(m), caption=f"APE and RPE against {ref} (evo; association "
                  f"{e['association']}, alignment {e['alignment']}).", label=label)]
    d = drift_table(m)            # the KITTI drift table, as a run's metrics.tex has it
    if d is not None:
        tabs.append(latex(*d, decimals=[0, 3, 4, 0], caption=f"KITTI drift metric against {ref}.", label=f"{label}-drift"))
    return latex_document(tabs, f"fusion-eval evaluate: {ref}")


def _alignment(a: dict) -> str:
    """The fitted alignment in words: its rotation as an angle about an axis, the translation, the scale (the full
    numbers are in metrics.json)."""
    import numpy as np

    from ..so3 import log_so3

    out = []
    if a.get("rotation") is not None:
        rv = log_so3(np.asarray(a["rotation"], float))
        ang = float(np.linalg.norm(rv))
        axis = ", ".join(f"{v:+.3f}" for v in (rv / ang if ang > 0 else rv))
        out.append(f"rotation {np.degrees(ang):.3f} deg about ({axis})")
    if a.get("translation_m") is not None:
        out.append("translation (" + ", ".join(f"{v:.3f}" for v in a["translation_m"]) + ") m")
    if a.get("scale") is not None:
        out.append(f"scale {a['scale']:.6f}")
    if a.get("yaw_deg") is not None:           # the 4-DoF fit: a yaw about the gravity axis (was a JSON dump)
        det = a.get("up_axis_detection") or {}
        how = (f", detected: the positions' least-varying direction is {det['angle_deg']:.1f} deg from it"
               if det.get("angle_deg") is not None else "")
        out.append(f"yaw {a['yaw_deg']:.3f} deg about {a.get('up_axis', '?')} (the up axis{how})")
    rest = {k: v for k, v in a.items() if k not in ("rotation", "translation_m", "scale", "yaw_deg", "up_axis",
                                                      "up_axis_detection")}
    if rest:
        out.append(json.dumps(rest))
    return ", ".join(out) or json.dumps(a)


def _time_range(ref_f, t_range_s):
    """The reference reduced to ``--t-start``/``--t-end`` as evo's ``--t_start``/``--t_end`` reduce it (the estimates are
    then matched to what is left): a run's common span, from its report's evo options, scored again."""
    t0, t1 = t_range_s
    if t0 is None and t1 is None:
        return ref_f.traj
    if ref_f.stamps == BY_INDEX:
        raise ConfigError(f"--t-start/--t-end need stamps in seconds, and the reference {ref_f.source} has none (KITTI "
                          "poses without a times file are stamped by frame index): give --ref-times and --times")
    import copy

    ts = ref_f.traj.timestamps
    keep = int(np.count_nonzero((ts >= (ts[0] if t0 is None else t0)) & (ts <= (ts[-1] if t1 is None else t1))))
    if keep < 2:
        raise DataRangeError(f"{ref_f.source}: {keep} of its poses in --t-start {t0} .. --t-end {t1} (its stamps run from "
                             f"{ts[0]:.6f} to {ts[-1]:.6f} s): nothing to score there")
    traj = copy.deepcopy(ref_f.traj)
    traj.reduce_to_time_range(t0, t1)
    return traj


def _report(m: dict, plots: list[str]) -> str:
    e = m["evaluation"]
    rng = e.get("time_range_s")
    L = [f"# fusion-eval evaluate: {Path(m['reference']).name}", "", header_line(), "",
         f"Reference stamps: {m['reference_stamps']}. Association: **{e['association']}**"
         + (f" (within {e['t_max_diff_s']} s)" if e["association"] == "nearest" else " (reference interpolated at the estimate's stamps)")
         + f"; alignment: **{e['alignment']}**"
         + ("" if not rng else f"; the reference's poses from {'its start' if rng[0] is None else f'{rng[0]:.6f} s'} to "
            f"{'its end' if rng[1] is None else f'{rng[1]:.6f} s'} (evo's --t_start/--t_end)") + ".", ""]
    L += markdown(*_summary_table(m))
    nees = [(k, d["nees"]) for k, d in m["estimates"].items() if d.get("nees")]
    if nees:
        L += ["", "## Consistency of the estimates' own covariances (NEES, 3 dof each)", ""]
        L += markdown(["estimate", "epochs", "position NEES mean", "in 95 % bounds", "attitude NEES mean", "in 95 % bounds"],
                      [[k, str(n["position"]["epochs"]), f"{n['position']['mean']:.2f}", f"{n['position']['fraction_in_95']:.1%}",
                        f"{n['attitude']['mean']:.2f}", f"{n['attitude']['fraction_in_95']:.1%}"] for k, n in nees],
                      align="lrrrrr")
        L += ["", "A consistent estimate has a mean NEES of 3 and 95 % of its epochs inside the bounds; above: it "
                  "claims more certainty than it has."]
    for k, d in m["estimates"].items():
        if d.get("note"):
            L.append(f"\n- {k}: {d['note']}.")
        if d.get("alignment"):
            L.append(f"\n- {k}: alignment {_alignment(d['alignment'])}.")
    L += drift_section(m) + segments_section(m)
    if plots:
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    return "\n".join(L) + "\n"
