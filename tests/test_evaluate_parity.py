"""``fusion-eval evaluate`` reproduces evo on every file of evo's own test data, with every alignment evo offers
(none, ``--align_origin``, ``-a``, ``-as``, ``-s``), every APE pose relation (``-r``) and both sync methods,
to 1e-6: the reference is evo's own pipeline (its file readers, ``sync_with``, ``main_ape.ape``), as ``evo_ape``
runs it; two figures come from evo's command line itself (``evo_ape euroc V102 -a`` 0.091727 m, ``evo_ape bag
ROS_example.bag groundtruth ORB-SLAM -as`` 5.404707 m).

The whole matrix is ``slow``; one alignment per file runs in the quick suite.
"""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from evo.core.sync_method import SyncMethod
from evo.main_ape import ape as evo_ape
from evo.tools import file_interface
from fusion_eval.commands.evaluate import read_inputs, run_evaluate
from fusion_eval.evaluation import keys
from fusion_eval.evaluation.estimates import evaluate_series
from fusion_eval.errors import DataFormatError

TOL = 1e-6
ALL_RELATIONS = tuple(keys.RELATION_KEYS)
# alignment -> evo_ape's flags (align, correct_scale, align_origin)
EVO_ALIGN = {"none": (False, False, False), "origin": (False, False, True), "se3": (True, False, False),
             "sim3": (True, True, False), "scale": (False, True, False)}
# (id, evo sub-command, reference, estimate): files of ../shared/data/evo-test-data, or bag topics
CASES = [("kitti-orb", "kitti", "KITTI_00_gt.txt", "KITTI_00_ORB.txt"),
         ("kitti-sptam", "kitti", "KITTI_00_gt.txt", "KITTI_00_SPTAM.txt"),
         ("fr1-rgbdslam", "tum", "freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt"),
         ("fr1-drift", "tum", "freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam_drift.txt"),
         ("fr1-orb-mono", "tum", "freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-ORB_kf_mono.txt"),
         ("fr2-desk", "tum", "fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt"),
         ("fr2-desk-mono", "tum", "fr2_desk_groundtruth.txt", "fr2_desk_ORB_kf_mono.txt"),
         ("euroc-v102", "euroc", "V102_groundtruth.csv", "V102.txt"),
         ("bag1-orb", "bag", "ROS_example.bag:groundtruth", "ORB-SLAM"),
         ("bag1-sptam", "bag", "ROS_example.bag:groundtruth", "S-PTAM")]
QUICK = {"kitti-orb": "se3", "fr1-rgbdslam": "origin", "fr2-desk": "sim3", "euroc-v102": "se3", "bag1-orb": "sim3",
         "fr1-orb-mono": "scale"}


def _paths(sub, ref, est):
    if sub in ("bag", "bag2"):
        bag, ref_topic = ref.split(":", 1)
        return shared_path("evo-test-data", bag), ref_topic, est
    return None, shared_path("evo-test-data", ref), shared_path("evo-test-data", est)


def _evo_load(sub, ref, est):
    """Reference and estimate as ``evo_ape``'s ``load_trajectories`` reads them."""
    bag, r, e = _paths(sub, ref, est)
    if sub == "kitti":
        return file_interface.read_kitti_poses_file(str(r)), file_interface.read_kitti_poses_file(str(e))
    if sub == "tum":
        return file_interface.read_tum_trajectory_file(str(r)), file_interface.read_tum_trajectory_file(str(e))
    if sub == "euroc":
        return file_interface.read_euroc_csv_trajectory(str(r)), file_interface.read_tum_trajectory_file(str(e))
    if sub == "bag":
        from rosbags.rosbag1 import Reader
    else:
        from rosbags.rosbag2 import Reader
    with Reader(bag) as reader:
        return (file_interface.read_bag_trajectory(reader, r, cache_tf_tree=True),
                file_interface.read_bag_trajectory(reader, e, cache_tf_tree=True))


def _evo_ape(loaded, sync_method, alignment, relation, t_max_diff=0.01):
    ref, est = (copy.deepcopy(t) for t in loaded)
    if hasattr(ref, "timestamps") and hasattr(est, "timestamps"):
        ref, est = ref.sync_with(est, sync_method=sync_method, max_diff=t_max_diff)
    align, scale, origin = EVO_ALIGN[alignment]
    return evo_ape(ref, est, keys.EVO_RELATIONS[relation], align=align, correct_scale=scale, align_origin=origin)


def _ours(sub, ref, est, association, alignment):
    bag, r, e = _paths(sub, ref, est)
    if bag is not None:
        ref_f, ests = read_inputs([e], bag, r, "auto", None, None)
    else:
        ref_f, ests = read_inputs([r, e], None, None, "auto", None, None)
    m, _ = evaluate_series(ref_f.traj, {"est": ests[0].traj}, association, alignment, relations=ALL_RELATIONS)
    return m["estimates"]["est"]


_LOADED: dict = {}


def _check(case, association, alignment):
    cid, sub, ref, est = case
    if cid not in _LOADED:
        _LOADED[cid] = _evo_load(sub, ref, est)
    ours = _ours(sub, ref, est, association, alignment)
    sync_method = SyncMethod.interpolation if association == "interpolate" else SyncMethod.nearest_time
    for rel in ALL_RELATIONS:
        res = _evo_ape(_LOADED[cid], sync_method, alignment, rel)
        got = ours["ape"][keys.RELATION_KEYS[rel]]
        for stat in keys.STATS:
            assert got[stat] == pytest.approx(float(res.stats[stat]), rel=0, abs=TOL), (cid, association, alignment, rel, stat)
        assert ours["matched_poses"] == len(res.np_arrays["error_array"])


@pytest.mark.slow
@pytest.mark.parametrize("case", [c for c in CASES if c[0] in QUICK], ids=lambda c: c[0])
def test_one_alignment_per_file_equals_evo(case):
    _check(case, "nearest", QUICK[case[0]])


# every alignment with nearest_time; the interpolation (stamped files only) with two alignments: the alignment acts
# after the association (scripts/parity_tables.py prints the whole product)
MATRIX = [(c, "nearest", a) for c in CASES for a in EVO_ALIGN] + \
         [(c, "interpolate", a) for c in CASES if c[1] != "kitti" for a in ("none", "se3")]


@pytest.mark.slow
@pytest.mark.parametrize("case,association,alignment", MATRIX, ids=lambda x: x[0] if isinstance(x, tuple) else str(x))
def test_every_file_alignment_relation_and_sync_equals_evo(case, association, alignment):
    _check(case, association, alignment)


def _evo_cli(tmp_path, *args) -> float:
    """The APE RMSE that evo's own command line writes to its result file."""
    exe = Path(sys.executable).with_name("evo_ape")
    res = tmp_path / "res.zip"
    subprocess.run([str(exe), *map(str, args), "--save_results", str(res), "--no_warnings"], check=True,
                   capture_output=True, timeout=120)
    return float(file_interface.load_res_file(str(res)).stats["rmse"])


@pytest.mark.slow
def test_reference_figures_from_evos_command_line(tmp_path):
    D = shared_path("evo-test-data")
    m = run_evaluate([D / "V102_groundtruth.csv", D / "V102.txt"], tmp_path / "a", alignment="se3", make_plots=False)
    evo = _evo_cli(tmp_path, "euroc", D / "V102_groundtruth.csv", D / "V102.txt", "-a")
    assert evo == pytest.approx(0.091727, abs=5e-7)
    assert m["estimates"]["V102"]["ape"]["translation_m"]["rmse"] == pytest.approx(evo, abs=TOL)
    assert m["estimates"]["V102"]["repeated_stamps"] == 4 and m["reference_format"] == "euroc"
    m = run_evaluate(["ORB-SLAM"], tmp_path / "b", alignment="sim3", bag=D / "ROS_example.bag", ref_topic="groundtruth",
                     make_plots=False)
    evo = _evo_cli(tmp_path, "bag", D / "ROS_example.bag", "groundtruth", "ORB-SLAM", "-as")
    assert evo == pytest.approx(5.404707, abs=5e-7)
    assert m["estimates"]["ORB-SLAM"]["ape"]["translation_m"]["rmse"] == pytest.approx(evo, abs=TOL)


def test_interpolation_does_not_bridge_a_gap_in_the_reference(tmp_path):
    """fr2_desk's reference has a 12 s gap: evo's interpolation (and ours) only uses estimate stamps with a
    reference pose within --t-max-diff; interpolating across the gap gave 0.1142 m instead of 0.0081 m."""
    D = shared_path("evo-test-data")
    m = run_evaluate([D / "fr2_desk_groundtruth.txt", D / "fr2_desk_ORB.txt"], tmp_path / "o", association="interpolate",
                     alignment="se3", make_plots=False)
    rmse = m["estimates"]["fr2_desk_ORB"]["ape"]["translation_m"]["rmse"]
    assert rmse == pytest.approx(0.008099, abs=5e-7)


@pytest.mark.slow
def test_4dof_finds_the_gravity_axis_of_kitti_cam0_poses(tmp_path):
    """KITTI's cam0 frame has y pointing down: the 4-DoF fit rotates about y, and can only be worse than
    SE(3) (it has fewer degrees of freedom); fitting about z (the old assumption: 4.698 m) or x is worse."""
    D = shared_path("evo-test-data")
    files = [D / "KITTI_00_gt.txt", D / "KITTI_00_ORB.txt"]
    m4 = run_evaluate(files, tmp_path / "a", alignment="4dof", make_plots=False)["estimates"]["KITTI_00_ORB"]
    m6 = run_evaluate(files, tmp_path / "b", alignment="se3", make_plots=False)["estimates"]["KITTI_00_ORB"]
    mz = run_evaluate(files, tmp_path / "c", alignment="4dof", up_axis="z", make_plots=False)["estimates"]["KITTI_00_ORB"]
    mx = run_evaluate(files, tmp_path / "d", alignment="4dof", up_axis="x", make_plots=False)["estimates"]["KITTI_00_ORB"]
    assert m4["alignment"]["up_axis"] == "y" and m4["alignment"]["up_axis_detection"]["angle_deg"] < 5
    r4, r6, rz, rx = (x["ape"]["translation_m"]["rmse"] for x in (m4, m6, mz, mx))
    assert r6 <= r4 < min(rz, rx) and rz > 4.5


def test_4dof_recovers_a_rotation_about_any_axis():
    from fusion_eval.evaluation.alignment import fit_4dof
    from fusion_eval.so3 import exp_so3

    rng = np.random.default_rng(4)
    p = rng.normal(size=(300, 3)) * [40, 2, 40]        # flat in y, as a drive in cam0 coordinates
    for axis, k in (("y", 1), ("z", 2), ("x", 0)):
        w = np.zeros(3)
        w[k] = 0.8
        R, t = exp_so3(w[None])[0], np.array([3.0, -1.0, 7.0])
        R_fit, t_fit, yaw = fit_4dof(p, p @ R.T + t, axis)
        assert np.allclose(R_fit, R, atol=1e-12) and np.allclose(t_fit, t, atol=1e-10) and yaw == pytest.approx(0.8)


@pytest.mark.slow
def test_cli_reads_a_bag_and_names_a_missing_topic(tmp_path):
    from click.testing import CliRunner
    from fusion_eval.cli import main

    D = shared_path("evo-test-data")
    r = CliRunner().invoke(main, ["evaluate", "--bag", str(D / "ROS_example.bag"), "--ref", "groundtruth", "ORB-SLAM",
                                  "S-PTAM", "-r", "full", "-r", "angle_rad", "--alignment", "se3", "-o", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    out = (tmp_path / "o" / "report.md").read_text()
    assert "ORB-SLAM" in out and "S-PTAM" in out
    r = CliRunner().invoke(main, ["evaluate", "--bag", str(D / "ROS_example.bag"), "--ref", "groundtruth", "nope",
                                  "-o", str(tmp_path / "p")])
    assert r.exit_code != 0 and "'nope'" in r.output and "ORB-SLAM" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "p").exists()


def test_a_euroc_csv_with_a_broken_row_names_the_line(tmp_path):
    from fusion_eval.datasets.trajectory_file import read_trajectory
    from fusion_eval.errors import DataFormatError

    src = shared_path("evo-test-data", "V102_groundtruth.csv").read_text().splitlines()
    src[5] = src[5].rsplit(",", 3)[0] + ",x,1,2"
    f = tmp_path / "gt.csv"
    f.write_text("\n".join(src) + "\n")
    with pytest.raises(DataFormatError, match=r"gt.csv:6: .*expected a number, got 'x'"):
        read_trajectory(f)


@pytest.mark.parametrize("edit", [lambda ln: ln + " ", lambda ln: ln.replace(" ", "\t"), lambda ln: ln.replace(" ", "  ")],
                         ids=["trailing-blank", "tabs", "double-blanks"])
def test_a_kitti_pose_file_with_other_blanks_reads_as_evo_reads_the_clean_one(tmp_path, edit):
    """evo's KITTI reader refuses a trailing blank, tabs or double blanks (a traceback before); the same floats are
    taken, so the poses equal evo's own reading of the clean file."""
    from evo.tools import file_interface

    from fusion_eval.datasets.trajectory_file import read_trajectory

    rows = shared_path("evo-test-data", "KITTI_00_ORB.txt").read_text().splitlines()[:300]
    (tmp_path / "clean.txt").write_text("\n".join(rows) + "\n")
    (tmp_path / "est.txt").write_text("\n".join(edit(ln) for ln in rows) + "\n")
    got = read_trajectory(tmp_path / "est.txt")
    want = file_interface.read_kitti_poses_file(str(tmp_path / "clean.txt"))
    assert got.traj.num_poses == want.num_poses == 300
    np.testing.assert_array_equal(np.asarray(got.traj.poses_se3), np.asarray(want.poses_se3))


@pytest.mark.parametrize("edit", [lambda t: t + "\n", lambda t: t.replace("\n", "\r\n") + "\r\n",
                                  lambda t: t.replace("\n", "\n\n", 40).replace("\n\n", "\n", 39),
                                  lambda t: t.replace(",", ", ")],
                         ids=["trailing-blank-line", "crlf-blank-line", "blank-line-inside", "blanks-after-commas"])
def test_a_euroc_csv_with_blank_lines_reads_as_evo_reads_the_clean_one(tmp_path, edit):
    """evo's EuRoC reader refuses a blank line (a traceback before, found by a new-user review); the same floats
    are taken, so the trajectory equals evo's own reading of the clean file."""
    from evo.tools import file_interface

    from fusion_eval.datasets.trajectory_file import read_trajectory

    text = "\n".join(shared_path("evo-test-data", "V102_groundtruth.csv").read_text().splitlines()[:400]) + "\n"
    (tmp_path / "clean.csv").write_text(text)
    (tmp_path / "gt.csv").write_bytes(edit(text).encode())
    got = read_trajectory(tmp_path / "gt.csv")
    want = file_interface.read_euroc_csv_trajectory(str(tmp_path / "clean.csv"))
    assert got.traj.num_poses == want.num_poses == 399
    np.testing.assert_array_equal(got.traj.timestamps, want.timestamps)
    np.testing.assert_array_equal(np.asarray(got.traj.poses_se3), np.asarray(want.poses_se3))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fr2_desk_ORB.txt", "V102_groundtruth.csv"])
def test_a_byte_order_mark_is_dropped_as_evo_drops_it(tmp_path, name):
    """A UTF-8 BOM (Windows editors write one) before a TUM or EuRoC file: refused before ('expected a number');
    now read as evo reads it, with or without a comment line first."""
    from fusion_eval.datasets.trajectory_file import read_trajectory

    src = shared_path("evo-test-data", name).read_bytes()
    plain = read_trajectory(shared_path("evo-test-data", name))
    for i, head in enumerate((b"", b"# a comment\n")):
        f = tmp_path / f"bom{i}{Path(name).suffix}"
        f.write_bytes(b"\xef\xbb\xbf" + head + src)
        got = read_trajectory(f)
        np.testing.assert_array_equal(got.traj.positions_xyz, plain.traj.positions_xyz)
        np.testing.assert_array_equal(got.traj.timestamps, plain.traj.timestamps)


def _noisy_estimate(n=2000, seed=8):
    from fusion_eval.so3 import exp_so3, matrix_to_quat_xyzw
    from fusion_eval.types import PoseSeries

    rng = np.random.default_rng(seed)
    t = 1.7e9 + np.arange(n) * 0.1
    p = np.cumsum(rng.normal(size=(n, 3)), axis=0)
    R = exp_so3(np.cumsum(rng.normal(size=(n, 3)) * 0.05, axis=0))
    std = np.array([0.3, 0.2, 0.5, 0.01, 0.02, 0.015])         # m, rad: ROS order, parent frame
    R_est = exp_so3(rng.normal(size=(n, 3)) * std[3:]) @ R
    ref = PoseSeries(t_s=t, p_w_m=p, q_wb_xyzw=matrix_to_quat_xyzw(R))
    est = PoseSeries(t_s=t, p_w_m=p + rng.normal(size=(n, 3)) * std[:3], q_wb_xyzw=matrix_to_quat_xyzw(R_est))
    return ref, est, std


@pytest.mark.slow
def test_nees_of_an_estimate_with_covariances_from_a_sidecar_and_a_bag(tmp_path):
    """An estimate whose errors follow its stated covariance has a mean NEES of ~3 (3 dof), ~95 % inside the bounds;
    one that claims 3x less sigma is flagged (~27). The same from a .cov sidecar and from PoseWithCovarianceStamped."""
    from fusion_eval.datasets import rosbag
    from fusion_eval.datasets.tum import format_tum

    ref, est, std = _noisy_estimate()
    (tmp_path / "ref.tum").write_text(format_tum(ref))
    (tmp_path / "est.tum").write_text(format_tum(est))
    C = np.diag(std ** 2).ravel()
    (tmp_path / "est.cov").write_text("# t, 6x6 pose covariance\n" + "".join(
        f"{t:.9f} " + " ".join(f"{c:.17g}" for c in C) + "\n" for t in est.t_s))
    m = run_evaluate([tmp_path / "ref.tum", tmp_path / "est.tum"], tmp_path / "o", make_plots=False)
    n = m["estimates"]["est"]["nees"]
    assert 2.8 < n["position"]["mean"] < 3.2 and 2.8 < n["attitude"]["mean"] < 3.2
    assert 0.93 < n["position"]["fraction_in_95"] < 0.97 and n["position"]["epochs"] == len(est)
    assert "Consistency of the estimates' own covariances" in (tmp_path / "o" / "report.md").read_text()
    # SE(3)-aligned: the alignment's rotation carries the covariance along (the estimate is already aligned here)
    m = run_evaluate([tmp_path / "ref.tum", tmp_path / "est.tum"], tmp_path / "a", alignment="se3", make_plots=False)
    assert 2.8 < m["estimates"]["est"]["nees"]["position"]["mean"] < 3.2
    # named as the README says, <file>.cov (est.tum.cov), it is read first: here stated 3x too small
    (tmp_path / "est.tum.cov").write_text("".join(f"{t:.9f} " + " ".join(f"{c / 9:.17g}" for c in C) + "\n"
                                                  for t in est.t_s))
    m = run_evaluate([tmp_path / "ref.tum", tmp_path / "est.tum"], tmp_path / "c", make_plots=False)
    assert 24 < m["estimates"]["est"]["nees"]["position"]["mean"] < 30
    # the same poses in a bag, the covariance on the messages, stated 3x too small
    bag = tmp_path / "run.bag"
    rosbag.write_bag(bag, "rosbag1", [rosbag.BagStream("/gt", "pose", ref, "map"),
                                      rosbag.BagStream("/est", "pose_cov", est, "map", std_m=std / 3)])
    m = run_evaluate(["/est"], tmp_path / "b", bag=bag, ref_topic="/gt", make_plots=False)
    n = m["estimates"]["est"]["nees"]
    assert 24 < n["position"]["mean"] < 30 and n["position"]["fraction_in_95"] < 0.3


@pytest.mark.parametrize("bag", ["tf_example.bag", "tf_example"])
def test_tf_trajectories_without_ros_tf2(tmp_path, bag):
    """``/tf:parent.child`` ids: evo's TF reading needs ROS's tf2_py; without it fusion-eval reads the edge
    odom -> base_footprint, and odom -> base_link through the /tf_static edge base_footprint -> base_link."""
    from fusion_eval.datasets import rosbag

    path = shared_path("evo-test-data", bag)
    m = run_evaluate(["/tf:odom.base_link"], tmp_path / "o", bag=path, ref_topic="/tf:odom.base_footprint",
                     make_plots=False)
    e = m["estimates"]["tf:odom.base_link"]
    assert e["matched_poses"] == 517
    T = rosbag.static_transform(path, "base_footprint", "base_link")
    lever = float(np.linalg.norm(T[:3, 3]))
    # a rigid offset between the two frames: the translation APE is the lever arm's length rotated with the robot
    assert e["ape"]["translation_m"]["max"] == pytest.approx(lever, abs=1e-9)
    if "reading" in e:
        assert "tf2_py" in e["reading"]
    # an edge the bag does not hold: the error names the frames asked for (it named base_footprint, the one
    # tried through the static edge)
    with pytest.raises(DataFormatError, match=r"no TF edge map -> base_link: .* map -> base_footprint followed by "
                                              r"the /tf_static edge base_footprint -> base_link .*odom->base_footprint"):
        run_evaluate(["/tf:odom.base_link"], tmp_path / "o2", bag=path, ref_topic="/tf:map.base_link", make_plots=False)


def test_tf_trajectory_through_a_static_edge(tmp_path):
    """A synthetic bag whose static edge is not the identity: /tf:odom.base_link is odom -> base_footprint composed
    with base_footprint -> base_link, so its positions differ from the footprint's by the rotated lever arm."""
    from fusion_eval.datasets import rosbag
    from fusion_eval.datasets.trajectory_file import read_bag_trajectories
    from fusion_eval.so3 import exp_so3, make_T

    ref, _, _ = _noisy_estimate(n=300)
    T_fb = make_T(exp_so3(np.array([[0.1, -0.2, 0.3]]))[0], np.array([0.5, -0.1, 0.8]))
    bag = tmp_path / "tf.bag"
    rosbag.write_bag(bag, "rosbag1", [rosbag.BagStream("/tf", "tf", ref, "odom", child_frame_id="base_footprint")],
                     tf_static=[("base_footprint", "base_link", T_fb)])
    foot, link = read_bag_trajectories(bag, ["/tf:odom.base_footprint", "/tf:odom.base_link"])
    expect = np.asarray(foot.traj.poses_se3) @ T_fb[None]
    assert np.abs(np.asarray(link.traj.poses_se3) - expect).max() < 1e-12
    assert np.abs(link.traj.positions_xyz - foot.traj.positions_xyz).max() > 0.5


@pytest.mark.parametrize("alignment", ["se3", "sim3", "scale", "origin"])
def test_the_trajectory_plot_draws_the_estimate_as_evo_aligned_it(alignment):
    """evaluate's trajectory plot moves each estimate by its evaluation's alignment parameters: the positions equal
    evo's own aligned trajectory (it drew the file as read, where a SLAM estimate's frame is arbitrary)."""
    from evo.core import sync
    from evo.tools import file_interface

    from fusion_eval.datasets.trajectory_file import as_series, read_trajectory
    from fusion_eval.evaluation.trajectory import aligned_positions, evaluate

    ref_p, est_p = shared_path("evo-test-data", "fr2_desk_groundtruth.txt"), shared_path("evo-test-data", "fr2_desk_ORB.txt")
    ref_f, est_f = read_trajectory(ref_p), read_trajectory(est_p)
    ev = evaluate(ref_f.traj, est_f.traj, "est", 0.01, 1.0, "nearest", alignment, "arrays")
    ref, est = sync.associate_trajectories(file_interface.read_tum_trajectory_file(str(ref_p)),
                                           file_interface.read_tum_trajectory_file(str(est_p)), max_diff=0.01)
    if alignment == "origin":
        est.align_origin(ref)
    else:
        est.align(ref, correct_scale=alignment in ("sim3", "scale"), correct_only_scale=alignment == "scale")
    moved = aligned_positions(as_series(est_f).p_w_m, ev.alignment_params)
    keep = np.isin(est_f.traj.timestamps, est.timestamps)
    np.testing.assert_allclose(moved[keep], est.positions_xyz, atol=1e-9)


@pytest.mark.slow
def test_bag_topics_in_other_frames_without_an_alignment_are_said(tmp_path):
    """A lidar odometry in its own odom frame against a map-frame ground truth, compared as they are, gave 317 m
    with exit 0 and no word (found by a review with its own bags); the frames are in the header of every message."""
    path = shared_path("evo-test-data", "ROS_example.bag")
    m = run_evaluate(["ORB-SLAM"], tmp_path / "o", bag=path, ref_topic="groundtruth", make_plots=False)
    assert "in frame 'ORB-SLAM', the reference's in 'groundtruth'" in m["estimates"]["ORB-SLAM"]["note"]
    m = run_evaluate(["ORB-SLAM"], tmp_path / "a", bag=path, ref_topic="groundtruth", alignment="sim3",
                     make_plots=False)
    assert "frame" not in (m["estimates"]["ORB-SLAM"].get("note") or "")


def test_two_names_of_one_frame_joined_by_an_identity_static_edge_are_not_warned(tmp_path):
    """Frames named differently but joined by an identity /tf_static edge (map -> world) are one frame: no warning
    (a review of the diff); another edge, or none, is."""
    from fusion_eval.datasets import rosbag

    ref, est, _ = _noisy_estimate(n=300)
    for T, warned in ((np.eye(4), False), (np.diag([1.0, 1.0, 1.0, 1.0]) + np.eye(4, k=3) * 5.0, True)):
        bag = tmp_path / f"b{int(warned)}.bag"
        rosbag.write_bag(bag, "rosbag1", [rosbag.BagStream("/gt", "pose", ref, "map"),
                                          rosbag.BagStream("/est", "pose", est, "world")],
                         tf_static=[("map", "world", T)])
        m = run_evaluate(["/est"], tmp_path / f"o{int(warned)}", bag=bag, ref_topic="/gt", make_plots=False)
        assert ("compared across two frames" in (m["estimates"]["est"].get("note") or "")) == warned


@pytest.mark.parametrize("flags, alignment", [(["-as"], "sim3"), (["-a"], "se3"), (["-s"], "scale"),
                                              (["-a", "--alignment", "se3"], "se3")])
def test_evo_ape_flags_give_the_same_alignment(tmp_path, flags, alignment):
    """evo's -a, -s and -as work as they do in an evo_ape command line ('No such option: -a' before; an own-data
    review): fr2/desk ORB with -as is evo's 0.006123 m; a contradicting --alignment is refused."""
    import json

    from click.testing import CliRunner
    from fusion_eval.cli import main

    files = [str(shared_path("evo-test-data", f)) for f in ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt")]
    outs = {}
    for k, extra in (("flags", flags), ("long", ["--alignment", alignment])):
        r = CliRunner().invoke(main, ["-q", "evaluate", *files, *extra, "--no-plots", "-o", str(tmp_path / k)])
        assert r.exit_code == 0, r.output
        outs[k] = json.loads((tmp_path / k / "metrics.json").read_text())
    assert outs["flags"]["evaluation"]["alignment"] == alignment
    a, b = (o["estimates"]["fr2_desk_ORB"]["ape"]["translation_m"]["rmse"] for o in (outs["flags"], outs["long"]))
    assert a == b
    if alignment == "sim3":
        assert abs(a - 0.006123) < 5e-7
    r = CliRunner().invoke(main, ["-q", "evaluate", *files, "-a", "--alignment", "origin", "-o", str(tmp_path / "x")])
    assert r.exit_code == 2 and "--alignment origin and -a (evo's for --alignment se3): give one" in r.output


@pytest.mark.parametrize("flags,n", [(("-as",), -1), (("-a",), 300), (("--alignment", "origin"), -1), ((), -1)])
def test_result_files_carry_evos_title_and_alignment_for_the_alignment_used(tmp_path, flags, n):
    """Every result file said "(not aligned)" and lacked evo's alignment_transformation_sim3 after -a or -as (the
    metric is computed on poses aligned beforehand; a review): the title, and the array, as evo_ape writes them."""
    from click.testing import CliRunner

    from fusion_eval.cli import main

    ref, est = (shared_path("evo-test-data", f) for f in ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt"))
    out = tmp_path / "o"
    extra = ("--n-to-align", str(n)) if n != -1 else ()
    r = CliRunner().invoke(main, ["evaluate", str(ref), str(est), *flags, *extra, "--out", str(out), "--no-plots"])
    assert r.exit_code == 0, r.output
    traj_ref, traj_est = (file_interface.read_tum_trajectory_file(str(p)) for p in (ref, est))
    from evo.core import sync
    from evo.core.metrics import PoseRelation

    traj_ref, traj_est = sync.associate_trajectories(traj_ref, traj_est)
    want = evo_ape(traj_ref, traj_est, PoseRelation.translation_part, align="-a" in flags or "-as" in flags,
                   correct_scale="-as" in flags, align_origin="origin" in flags, n_to_align=n)
    got = file_interface.load_res_file(str(out / "ape_translation_fr2_desk_ORB.zip"))
    assert got.info["title"] == want.info["title"]
    if "alignment_transformation_sim3" in want.np_arrays:
        np.testing.assert_allclose(got.np_arrays["alignment_transformation_sim3"],
                                   want.np_arrays["alignment_transformation_sim3"], atol=1e-9)
    else:
        assert "alignment_transformation_sim3" not in got.np_arrays
    # RPE's title keeps evo's delta line (it went with the alignment's, and evo_res tabled 1-frame and 100 m results
    # under one title with no word; a review)
    from evo.core.units import Unit
    from evo.main_rpe import rpe as evo_rpe

    rpe = file_interface.load_res_file(str(out / "rpe_1frame_translation_fr2_desk_ORB.zip"))
    want_rpe = evo_rpe(traj_ref, traj_est, PoseRelation.translation_part, delta=1, delta_unit=Unit.frames,
                       align="-a" in flags or "-as" in flags, correct_scale="-as" in flags,
                       align_origin="origin" in flags, n_to_align=n)
    assert rpe.info["title"] == want_rpe.info["title"] and "for delta = 1 (frames)" in rpe.info["title"]
