"""A trajectory file of any localization system, read as evo reads it: TUM (8 values per line), KITTI poses
(12 values per line, stamps from a times file or the frame index), or a EuRoC CSV (``#timestamp [ns],p_x,p_y,
p_z,q_w,q_x,q_y,q_z,...``, as ``state_groundtruth_estimate0/data.csv``); or a topic of a ROS 1 / ROS 2 bag.

The format is told apart by the file's content (a EuRoC CSV by its comma-separated rows of >= 8 values with a
nanosecond stamp, TUM and KITTI by their column counts), or forced. Every file is first checked here, so that a
wrong one gets a message naming the line and what was expected (evo's readers say only "must have 8 entries per
row"); the poses are then read by evo's own ``file_interface`` readers, so that the numbers are evo's: a KITTI
file's 3x4 matrices are kept as they are, not projected onto rotations.

Covariances, for the NEES: a bag topic of ``PoseWithCovarianceStamped`` or ``nav_msgs/Odometry`` carries its own;
a file gets them from a sidecar ``<file>.cov`` beside it: ``#`` comments, then one row per pose of ``t`` and the 36
entries of the 6x6 pose covariance, row-major, in ROS's order and frames (x, y, z in the parent frame, m^2; then the
rotation about the parent's x, y, z axes, rad^2) -- the ``pose.covariance`` of a ``PoseWithCovarianceStamped``.

Stamps as evo takes them: equal consecutive stamps are accepted (evo accepts them; its nearest-stamp association
picks one of the equal poses), and counted; decreasing stamps are refused, naming the line (evo would fall back
to a linear search and match them silently).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataFormatError, place
from ..types import check_times, check_unit_quaternions
from . import kitti_poses, plausible
from .plausible import check_stamps_in_seconds, check_track
from ._text import parse_numeric_rows, read_text

log = logging.getLogger(__name__)

BY_INDEX = "frame index (no times file)"
FORMATS = ("auto", "tum", "kitti", "euroc")
_EUROC_COLS = tuple(range(8, 40))       # t, p(3), q(4) and whatever follows (velocity, biases)


@dataclass
class TrajectoryFile:
    """One trajectory as read: evo's trajectory object and how its stamps and format were obtained."""

    traj: object                  # evo.core.trajectory.PoseTrajectory3D
    format: str                   # tum | kitti | euroc | bag
    stamps: str                   # how the stamps were obtained (BY_INDEX for KITTI without times)
    repeated_stamps: int = 0      # consecutive equal stamps (accepted, as evo accepts them)
    source: str = ""
    frame_id: str | None = None   # a bag topic's header frame
    cov_t_s: np.ndarray | None = None     # stamps of the pose covariances (bag topic or sidecar .cov file)
    cov: np.ndarray | None = None         # (N, 6, 6) ROS order: position (parent frame, m^2), rotation (parent axes, rad^2)
    note: str | None = None
    flags: list = field(default_factory=list)   # what makes its figures suspect (a jump, rounded stamps): said by evaluate


def read_covariances(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A ``.cov`` sidecar: rows of ``t`` and 36 covariance entries (see the module docstring)."""
    rows, lines = parse_numeric_rows(path, read_text(path, "pose covariances: t and 36 values per row"), 37,
                                     "pose covariance file (t, then the 6x6 covariance row-major)")
    cov = rows[:, 1:].reshape(-1, 6, 6)
    bad = np.flatnonzero(np.abs(cov - np.swapaxes(cov, 1, 2)).max(axis=(1, 2)) > 1e-9 * np.abs(cov).max(axis=(1, 2)))
    if bad.size:
        raise DataFormatError(path, int(lines[bad[0]]), "a covariance must be symmetric")
    return rows[:, 0], cov


def detect_format(path: Path, text: str | None = None) -> str:
    """``tum``, ``kitti`` or ``euroc`` from the first data line (comment lines skipped) of ``path`` (or of its
    ``text``, when already read)."""
    lines = (read_text(path, "a TUM, KITTI or EuRoC trajectory") if text is None else text).splitlines()
    at = next((i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")), None)
    first = "" if at is None else lines[at]
    if "," in first:
        fields = first.split(",")
        header = any(ln.lstrip().startswith("#timestamp") for ln in lines[:at])
        # a EuRoC stamp is an integer count of nanoseconds (~1e18 for POSIX time); anything else read as one would
        # divide seconds by 1e9 and take x, y, z, w as w, x, y, z: plausible-looking and wrong
        ns = fields[0].strip().isdigit() and len(fields[0].strip()) >= 13
        if len(fields) >= 8 and (header or ns):
            return "euroc"
        raise DataFormatError(path, at + 1, f"a comma-separated trajectory must be a EuRoC CSV ('#timestamp [ns]' header or "
                                            f"integer nanosecond stamps, then p_x, p_y, p_z, q_w, q_x, q_y, q_z, ...: 8 or more "
                                            f"values), got {len(fields)} values starting {fields[0].strip()!r} (a TUM file is "
                                            "space-separated; --format forces one)")
    if at is None:
        raise DataFormatError(path, None, "no poses (an empty file, or only comments): expected a TUM, KITTI or EuRoC "
                                          "trajectory")
    n = len(first.split())
    if n == 8:
        return "tum"
    if n == 12:
        return "kitti"
    raise DataFormatError(path, at + 1, "expected a TUM (8 values per line: t x y z qx qy qz qw), KITTI (12 values: a 3x4 "
                                        f"pose matrix) or EuRoC CSV trajectory (comma-separated), got {n} values")


def _stamps_checked(path: Path, t: np.ndarray, lines: np.ndarray, seconds: bool = True) -> int:
    """Refuse decreasing stamps (naming the line) and, for stamps in ``seconds``, ones no clock in seconds gives;
    return how many repeat the previous one (accepted, as by evo)."""
    check_times(np.asarray(t, float), str(path), lines, "trajectory", allow_equal=True)
    if seconds:
        # evo would read them and match no pose within t_max_diff (0.01 of a nanosecond): "0 poses match" named no unit
        check_stamps_in_seconds("trajectory", path, lines, t, how="TUM and KITTI times files are in seconds; a EuRoC "
                                                                 "CSV file's ns stamps are read as such")
    return int(np.count_nonzero(np.diff(t) == 0))


def _poses_checked(path: Path, lines: np.ndarray, t_s: np.ndarray, p_m: np.ndarray, q: np.ndarray) -> None:
    """Refuse, naming the line, what evo would take silently: a quaternion of norm far from 1 (all zeros; it would
    normalise a scaled one) and a pose beyond the plausibility bounds a run applies (a jump faster than 10 km/s)."""
    check_unit_quaternions(path, lines, q)
    check_track("trajectory", path, lines, t_s, p_m)


def read_trajectory(path: Path, times: Path | None = None, fmt: str = "auto") -> TrajectoryFile:
    """Check and read a TUM, KITTI or EuRoC trajectory file with evo's readers.

    ``times``: a KITTI file's times file (one stamp per pose, seconds); without one, frame ``i`` gets the stamp
    ``i`` s (:data:`BY_INDEX`). ``fmt``: one of :data:`FORMATS`.
    """
    from evo.core.trajectory import PoseTrajectory3D
    from evo.tools import file_interface

    path = Path(path)
    if fmt not in FORMATS:
        raise DataFormatError(path, None, f"unknown trajectory format {fmt!r} (known: {', '.join(FORMATS)})")
    text = read_text(path, "a TUM, KITTI or EuRoC trajectory" if fmt == "auto" else f"a {fmt} trajectory")
    if fmt == "auto":
        fmt = detect_format(path, text)
    if fmt != "kitti" and times is not None:
        raise DataFormatError(times, None, f"a times file applies to KITTI pose files only ({path.name} is {fmt}: "
                                           "its rows carry their stamps)")
    if fmt == "tum":
        rows, lines = parse_numeric_rows(path, text, 8, "TUM trajectory file (timestamp tx ty tz qx qy qz qw)")
        repeated = _stamps_checked(path, rows[:, 0], lines)
        _poses_checked(path, lines, rows[:, 0], rows[:, 1:4], rows[:, 4:8])
        try:
            traj = file_interface.read_tum_trajectory_file(str(path))
        except file_interface.FileInterfaceException:
            # evo splits on single spaces only (tabs, double or trailing blanks break it); the values parsed here
            # are the same floats its reader would take
            traj = PoseTrajectory3D(rows[:, 1:4], rows[:, [7, 4, 5, 6]], rows[:, 0])
        how = "TUM stamps"
    elif fmt == "euroc":
        rows, lines = parse_numeric_rows(path, text, _EUROC_COLS, "EuRoC CSV trajectory (#timestamp [ns],p_x,p_y,p_z,"
                                         "q_w,q_x,q_y,q_z,...)", delimiter=",")
        repeated = _stamps_checked(path, rows[:, 0], lines, seconds=False)
        _poses_checked(path, lines, rows[:, 0] * 1e-9, rows[:, 1:4], rows[:, 4:8])
        try:
            traj = file_interface.read_euroc_csv_trajectory(str(path))
        except file_interface.FileInterfaceException:
            # evo refuses a blank line (one at the end, a CRLF file's last one) or blanks around the commas; these
            # are the floats its reader would take, and its ns -> s division
            traj = PoseTrajectory3D(rows[:, 1:4], rows[:, 4:8], np.divide(rows[:, 0], 1e9))
        how = "EuRoC stamps (ns)"
    else:
        T, klines = kitti_poses.read_kitti_poses(path)           # the line-accurate checks (12 finite values, a rotation)
        try:
            poses = file_interface.read_kitti_poses_file(str(path))
        except file_interface.FileInterfaceException:
            # as for TUM: evo refuses tabs, double or trailing blanks; these are the same floats its reader takes
            from evo.core.trajectory import PosePath3D

            poses = PosePath3D(poses_se3=list(T))
        if times is not None:
            t, tlines = kitti_poses.read_times(times)
            if t.size != poses.num_poses:
                raise DataFormatError(times, None, f"expected {poses.num_poses} times (one per pose of {path.name}), got {t.size}")
            repeated = _stamps_checked(Path(times), t, tlines)
            how = f"times from {Path(times).name}"
        else:
            t, how, repeated = np.arange(poses.num_poses, dtype=float), BY_INDEX, 0
        traj = PoseTrajectory3D(poses_se3=poses.poses_se3, timestamps=t)
        check_track("trajectory", path, klines, t, traj.positions_xyz)
    traj.meta["name"] = path.stem
    if repeated:
        log.warning("%s: %d repeated stamps (accepted, as evo accepts them)", path, repeated)
    out = TrajectoryFile(traj=traj, format=fmt, stamps=how, repeated_stamps=repeated, source=str(path),
                         flags=suspect(path, traj, lines if fmt != "kitti" else klines, repeated, how != BY_INDEX))
    # est.tum.cov (the README's <file>.cov) or est.cov, in that order
    sidecar = next((c for c in (path.with_name(path.name + ".cov"), path.with_suffix(".cov")) if c.exists()), None)
    if sidecar is not None:
        out.cov_t_s, out.cov = read_covariances(sidecar)
        log.info("%s: pose covariances from %s", path.name, sidecar.name)
    return out


def read_bag_trajectories(bag: Path, topics: list[str]) -> list[TrajectoryFile]:
    """The trajectories of ``topics`` in a ROS 1 or ROS 2 bag, read by evo's ``read_bag_trajectory`` (PoseStamped,
    PoseWithCovarianceStamped, Odometry, TransformStamped, PointStamped topics, or ``/tf:parent.child`` TF ids),
    with the header stamps."""
    from evo.tools import file_interface

    from .rosbag import resolve

    bag = Path(bag)
    kind, target = resolve(bag)
    if kind == "rosbag1":       # evo reads with rosbags' own readers (not AnyReader)
        from rosbags.rosbag1 import Reader
    else:
        from rosbags.rosbag2 import Reader
    out = []
    try:
        reader = Reader(target)
        reader.open()
    except Exception as exc:          # noqa: BLE001 - rosbags raises its own types for a broken bag
        raise DataFormatError(bag, None, f"cannot open the {kind} bag: {exc}") from None
    try:
        known = file_interface.get_supported_topics(reader)
        for topic in topics:
            note = None
            try:
                if _is_tf_id(topic) and not _evo_reads_tf():
                    traj, note = _tf_trajectory(bag, topic), "TF read by fusion-eval (evo's TF reading needs ROS's tf2_py)"
                else:
                    traj = file_interface.read_bag_trajectory(reader, topic, cache_tf_tree=True)
            except DataFormatError:
                raise
            except Exception as exc:      # noqa: BLE001 - evo's FileInterfaceException, or a TF lookup error
                raise DataFormatError(bag, None, f"topic {topic!r}: {exc} (trajectory topics in the bag: "
                                                 f"{', '.join(known) or 'none'}; TF frames as /tf:parent.child)") from None
            t = np.asarray(traj.timestamps)
            if t.size >= 3 and np.all(t == t[0]):
                # 'dropped 4408 messages whose stamp repeats' and then '0 poses match (0.000 to 0.000 s)' said it
                # twice without saying it (a bag review)
                raise DataFormatError(bag, None, f"topic '{topic}': all {t.size} messages carry one header stamp "
                                                 f"({float(t[0]):.9g} s): a publisher that never sets it; evaluate "
                                                 "reads header stamps (run's manifests can take the record times: "
                                                 "stamps: record)")
            lines = np.arange(1, t.size + 1)           # the 'line' of a bag topic is the message's number in it
            if t.size > 1 and np.any(np.diff(t) < 0) and np.all(np.isfinite(t)):
                # recorded out of their header stamps' order (several publishers, a bag's write buffers): sorted by
                # stamp, as run's bag reader does; they were refused as 'decreasing' (a bag review)
                order = np.argsort(t, kind="stable")
                traj.reduce_to_ids(order)
                t, lines = np.asarray(traj.timestamps), lines[order]
                log.info("%s: topic %s: messages are not in stamp order; sorted by stamp", bag, topic)
            repeated = _stamps_checked(f"{bag} (topic {topic})", t, lines)
            traj.meta["name"] = topic
            f = TrajectoryFile(traj=traj, format="bag", stamps="header stamps", repeated_stamps=repeated,
                               source=f"{bag}:{topic}", frame_id=traj.meta.get("frame_id"), note=note)
            conn = reader.topics.get(topic)
            if conn is not None and conn.msgtype in _COV_TYPES:
                from . import rosbag

                t_c, cov = rosbag.read_pose_covariances(bag, topic)
                if np.any(cov != 0):                  # an Odometry without covariance holds zeros
                    f.cov_t_s, f.cov = t_c, cov
            out.append(f)
    finally:
        reader.close()
    return out


_COV_TYPES = ("geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry")


@dataclass
class _Track:
    """The positions of a trajectory as :func:`fusion_eval.datasets.plausible.speed_glitches` reads a stream."""

    p_w_m: np.ndarray
    t_s: np.ndarray
    lines: np.ndarray | None
    source: str
    filled: None = None

    def __len__(self) -> int:
        return len(self.t_s)


INDEX_STEP_FACTOR, INDEX_STEP_MIN_M = 50.0, 10.0     # a pose file stamped by index: a glitch's step, at least
REPEATED_MAX = 0.5      # of a file's stamps repeating the previous one: rounded, not a sensor's own repeats


def suspect(path, traj, lines, repeated: int, timed: bool = True) -> list[str]:
    """What a trajectory holds that no bound refuses but that makes its figures suspect, one sentence each: a step
    faster than any platform (300 m/s; a pose 200 m off in a TUM file moved APE 3.17 -> 5.27 m and gave an RPE of
    200 m with no word, where run warns of the same in its streams: a corrupted-input review), and stamps mostly
    repeating (written with too few digits: 2,793 of 2,893 at whole seconds were 'matched' arbitrarily). ``timed``:
    the stamps are times (not a KITTI file's frame index)."""
    out = []
    n = len(traj.timestamps)
    if timed:
        s = _Track(p_w_m=traj.positions_xyz, t_s=np.asarray(traj.timestamps, float), lines=lines, source=str(path))
        out += [w.replace("trajectory: ", "", 1) for w in
                plausible.speed_glitches({"trajectory": s}, None, plausible.MAX_ANY_SPEED_MPS)]
    elif n > 2:
        # stamped by frame index: no speed to bound; a step far beyond the file's own median step is the glitch (a
        # KITTI pose 200 m off moved RPE over 100 m from 1.07 to 45.9 m with no word)
        step = np.linalg.norm(np.diff(traj.positions_xyz, axis=0), axis=1)
        moving = step[step > 0]
        limit = max(INDEX_STEP_FACTOR * float(np.median(moving)), INDEX_STEP_MIN_M) if moving.size else np.inf
        bad = np.flatnonzero(step > limit)
        if bad.size:
            at = place(str(path), None if lines is None else int(lines[bad[0] + 1]))
            out.append(f"{bad.size} step(s) over {limit:.3g} m from one pose to the next ({INDEX_STEP_FACTOR:g}x its "
                       f"median step), the first {step[bad[0]]:.3g} m at {at}: a glitch in the data, whose figures are "
                       "suspect")
    if n > 10 and repeated > REPEATED_MAX * n:
        out.append(f"{repeated} of its {n} stamps repeat the previous one: stamps written with too few digits (rounded "
                   "to whole seconds?), which the association matches arbitrarily; write them with their fraction")
    return out


def _is_tf_id(topic: str) -> bool:
    from evo.tools import tf_id

    return bool(tf_id.check_id(topic))


def _evo_reads_tf() -> bool:
    try:
        import tf2_py  # noqa: F401 - evo's TF cache is built on ROS's tf2
    except ImportError:
        return False
    return True


def _tf_trajectory(bag: Path, identifier: str):
    """A ``/tf:parent.child`` trajectory without ROS's tf2: the transforms of the direct edge parent -> child on the
    TF topic, or of an edge parent -> x followed by a static edge x -> child from ``/tf_static``."""
    from evo.core.trajectory import PoseTrajectory3D
    from evo.tools import tf_id

    from ..so3 import make_T, xyzw_to_wxyz
    from . import rosbag

    tf_topic, parent, child = tf_id.split_id(identifier)[:3]
    try:
        poses = rosbag.read_poses(bag, tf_topic, child_frame=child, parent_frame=parent)
        T = None
    except DataFormatError:
        statics = rosbag.static_edges(bag)
        via = next(((a, Tab) for (a, b), Tab in statics.items() if b == child.strip("/")), None)
        if via is None:
            raise
        try:
            poses = rosbag.read_poses(bag, tf_topic, child_frame=via[0], parent_frame=parent)
        except DataFormatError as exc:    # name the frames asked for, not the intermediate one tried last
            present = str(exc).partition("(frames present: ")[2].removesuffix(")")
            raise DataFormatError(bag, None, f"no TF edge {parent} -> {child}: not on '{tf_topic}' directly, nor as "
                                             f"{parent} -> {via[0]} followed by the /tf_static edge {via[0]} -> "
                                             f"{child} ('{tf_topic}' holds: {present})") from None
        T = make_T(poses.R_wb(), poses.p_w_m) @ via[1][None]
    if T is None:
        return PoseTrajectory3D(np.array(poses.p_w_m), xyzw_to_wxyz(poses.q_wb_xyzw), np.array(poses.t_s))
    return PoseTrajectory3D(poses_se3=list(T), timestamps=np.array(poses.t_s))


def as_series(tf: TrajectoryFile, has_orientation: bool = True):
    """The trajectory as a :class:`~fusion_eval.types.PoseSeries` (for plots and the per-segment breakdown)."""
    from ..so3 import wxyz_to_xyzw
    from ..types import PoseSeries

    tr = tf.traj
    return PoseSeries(t_s=np.array(tr.timestamps), p_w_m=np.array(tr.positions_xyz),
                      q_wb_xyzw=wxyz_to_xyzw(np.array(tr.orientations_quat_wxyz)), source=tf.source,
                      has_orientation=has_orientation, repeated_stamps=True)
