"""A trajectory file of any localization system, read as evo reads it: TUM (8 values per line), KITTI poses
(12 values per line, stamps from a times file or the frame index), or a EuRoC CSV (``#timestamp [ns],p_x,p_y,
p_z,q_w,q_x,q_y,q_z,...``, as ``state_groundtruth_estimate0/data.csv``); or a topic of a ROS 1 / ROS 2 bag.

The format is told apart by the file's content (a EuRoC CSV by its comma-separated rows of >= 8 values with a
nanosecond stamp, TUM and KITTI by their column counts), or forced. Every file is first checked here, so that a
wrong one gets a message naming the line and what was expected (evo's readers say only "must have 8 entries per
row"); the poses are then read by evo's own ``file_interface`` readers, so that the numbers are evo's: a KITTI
file's 3x4 matrices are kept as they are, not projected onto rotations.

Stamps as evo takes them: equal consecutive stamps are accepted (evo accepts them; its nearest-stamp association
picks one of the equal poses), and counted; decreasing stamps are refused, naming the line (evo would fall back
to a linear search and match them silently).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataFormatError
from . import kitti_poses
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


def detect_format(path: Path) -> str:
    """``tum``, ``kitti`` or ``euroc`` from the first data line (comment lines skipped)."""
    first = next((ln for ln in read_text(path, "a TUM, KITTI or EuRoC trajectory").splitlines()
                  if ln.strip() and not ln.lstrip().startswith("#")), "")
    if "," in first:
        n = len(first.split(","))
        if n >= 8:
            return "euroc"
        raise DataFormatError(path, None, f"a comma-separated trajectory must be a EuRoC CSV (#timestamp [ns], p_x, p_y, "
                                          f"p_z, q_w, q_x, q_y, q_z, ...: at least 8 values per row), got {n} values")
    n = len(first.split())
    if n == 8:
        return "tum"
    if n == 12:
        return "kitti"
    raise DataFormatError(path, None, "expected a TUM (8 values per line: t x y z qx qy qz qw), KITTI (12 values: a 3x4 "
                                      f"pose matrix) or EuRoC CSV trajectory (comma-separated), got {n} values")


def _stamps_checked(path: Path, t: np.ndarray, lines: np.ndarray) -> int:
    d = np.diff(t)
    bad = np.flatnonzero(d < 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise DataFormatError(path, int(lines[i]), f"timestamps must not decrease ({t[i]!r} after {t[i - 1]!r})")
    return int(np.count_nonzero(d == 0))


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
    if fmt == "auto":
        fmt = detect_format(path)
    if fmt != "kitti" and times is not None:
        raise DataFormatError(times, None, f"a times file applies to KITTI pose files only ({path.name} is {fmt}: "
                                           "its rows carry their stamps)")
    text = read_text(path, f"a {fmt} trajectory")
    if fmt == "tum":
        rows, lines = parse_numeric_rows(path, text, 8, "TUM trajectory file (timestamp tx ty tz qx qy qz qw)")
        repeated = _stamps_checked(path, rows[:, 0], lines)
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
        repeated = _stamps_checked(path, rows[:, 0], lines)
        traj = file_interface.read_euroc_csv_trajectory(str(path))
        how = "EuRoC stamps (ns)"
    else:
        kitti_poses.read_kitti_poses(path)                  # the line-accurate checks (12 finite values, a rotation)
        poses = file_interface.read_kitti_poses_file(str(path))
        if times is not None:
            t, tlines = kitti_poses.read_times(times)
            if t.size != poses.num_poses:
                raise DataFormatError(times, None, f"expected {poses.num_poses} times (one per pose of {path.name}), got {t.size}")
            repeated = _stamps_checked(Path(times), t, tlines)
            how = f"times from {Path(times).name}"
        else:
            t, how, repeated = np.arange(poses.num_poses, dtype=float), BY_INDEX, 0
        traj = PoseTrajectory3D(poses_se3=poses.poses_se3, timestamps=t)
    traj.meta["name"] = path.stem
    if repeated:
        log.warning("%s: %d repeated stamps (accepted, as evo accepts them)", path, repeated)
    return TrajectoryFile(traj=traj, format=fmt, stamps=how, repeated_stamps=repeated, source=str(path))


def bag_kind(path: Path) -> str:
    """``rosbag1`` for a ``.bag`` file, ``rosbag2`` for a ROS 2 bag folder (``metadata.yaml``), a ``.db3`` or an
    ``.mcap`` file."""
    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, None, "bag not found (expected a ROS 1 .bag file or a ROS 2 bag folder)")
    if path.is_file() and path.suffix == ".bag":
        return "rosbag1"
    if (path.is_dir() and (path / "metadata.yaml").exists()) or path.suffix in (".db3", ".mcap"):
        return "rosbag2"
    raise DataFormatError(path, None, "expected a ROS 1 .bag file, or a ROS 2 bag (a folder with metadata.yaml, "
                                      "a .db3 or an .mcap file)")


def read_bag_trajectories(bag: Path, topics: list[str]) -> list[TrajectoryFile]:
    """The trajectories of ``topics`` in a ROS 1 or ROS 2 bag, read by evo's ``read_bag_trajectory`` (PoseStamped,
    PoseWithCovarianceStamped, Odometry, TransformStamped, PointStamped topics, or ``/tf:parent.child`` TF ids),
    with the header stamps."""
    from evo.tools import file_interface

    bag = Path(bag)
    kind = bag_kind(bag)
    if kind == "rosbag1":
        from rosbags.rosbag1 import Reader
    else:
        from rosbags.rosbag2 import Reader
    target = bag if kind == "rosbag1" or bag.is_dir() else bag.parent
    out = []
    try:
        reader = Reader(target)
        reader.open()
    except Exception as exc:          # noqa: BLE001 - rosbags raises its own types for a broken bag
        raise DataFormatError(bag, None, f"cannot open the {kind} bag: {exc}") from None
    try:
        known = file_interface.get_supported_topics(reader)
        for topic in topics:
            try:
                traj = file_interface.read_bag_trajectory(reader, topic, cache_tf_tree=True)
            except Exception as exc:      # noqa: BLE001 - evo's FileInterfaceException, or a TF lookup error
                raise DataFormatError(bag, None, f"topic {topic!r}: {exc} (trajectory topics in the bag: "
                                                 f"{', '.join(known) or 'none'}; TF frames as /tf:parent.child)") from None
            t = np.asarray(traj.timestamps)
            d = np.diff(t)
            if np.any(d < 0):
                i = int(np.flatnonzero(d < 0)[0]) + 1
                raise DataFormatError(bag, None, f"topic {topic!r}: header stamps must not decrease (message {i + 1}: "
                                                 f"{t[i]!r} after {t[i - 1]!r})")
            traj.meta["name"] = topic
            out.append(TrajectoryFile(traj=traj, format="bag", stamps="header stamps", repeated_stamps=int(np.sum(d == 0)),
                                      source=f"{bag}:{topic}", frame_id=traj.meta.get("frame_id")))
    finally:
        reader.close()
    return out


def as_series(tf: TrajectoryFile, has_orientation: bool = True):
    """The trajectory as a :class:`~fusion_eval.types.PoseSeries` (for plots and the per-segment breakdown)."""
    from ..so3 import wxyz_to_xyzw
    from ..types import PoseSeries

    tr = tf.traj
    return PoseSeries(t_s=np.array(tr.timestamps), p_w_m=np.array(tr.positions_xyz),
                      q_wb_xyzw=wxyz_to_xyzw(np.array(tr.orientations_quat_wxyz)), source=tf.source,
                      has_orientation=has_orientation, repeated_stamps=True)
