"""ROS bag reader and writer (fusion_eval.datasets.rosbag): round trips through ROS 1 and ROS 2 bags, the fixed-offset
fast path against the rosbags typestore, stamps, errors, and the real bags of evo's test data against evo."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer as Writer2

from conftest import SHARED, shared_path, under_ci
from fusion_eval.datasets import rosbag as rb
from fusion_eval.errors import ConfigError, DataFormatError, OutputError
from fusion_eval.geo import geodetic_to_enu
from fusion_eval.so3 import make_T, quat_xyzw_to_matrix
from fusion_eval.types import ImuSeries, PoseSeries

# (version, storage) of every bag flavour the writer makes; the reader sees rosbag1, sqlite3 and MCAP storage
FLAVOURS = [("rosbag1", "sqlite3"), ("rosbag2", "sqlite3"), ("rosbag2", "mcap")]
FLAVOUR_IDS = ["ros1", "ros2-sqlite3", "ros2-mcap"]
T0 = 1.7e9      # POSIX-like stamps: float64 spacing 2.4e-7 s
EVO = "evo-test-data"
# (under CI=true, where ../shared is beside the clone, its absence is not skipped: the tests fail on the missing files)
needs_evo_data = pytest.mark.skipif(not (SHARED / EVO).exists() and not under_ci(),
                                    reason=f"needs the shared real data {SHARED / EVO}")


def _bag(tmp_path: Path, version: str, name: str = "b") -> Path:
    return tmp_path / (f"{name}.bag" if version == "rosbag1" else name)


def _write(tmp_path, flavour, streams, tf_static=(), name="b") -> Path:
    version, storage = flavour
    return rb.write_bag(_bag(tmp_path, version, name), version, streams, tf_static=tf_static, storage=storage)


def _imu(rng, n=200, t0=T0) -> ImuSeries:
    t = t0 + np.cumsum(rng.uniform(0.004, 0.006, n))
    return ImuSeries(t_s=t, f_b_mps2=rng.normal(0, 3, (n, 3)), w_b_rps=rng.normal(0, 0.5, (n, 3)))


def _poses(rng, n=60, t0=T0, velocity=True) -> PoseSeries:
    t = t0 + np.cumsum(rng.uniform(0.05, 0.15, n))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    return PoseSeries(t_s=t, p_w_m=rng.normal(0, 50, (n, 3)), q_wb_xyzw=q,
                      v_w_mps=rng.normal(0, 5, (n, 3)) if velocity else None)


def _expected_stamps(t_s) -> np.ndarray:
    """What a reader must give back for a written float stamp: the nearest whole nanosecond, as seconds correctly
    rounded (Python's exact int / int, independent of the module's conversion)."""
    return np.array([n / 1_000_000_000 for n in rb._to_ns(t_s, "test").tolist()])


def _typed_messages(path: Path, topic: str):
    """(record ns, message) of a topic decoded message by message with the reference typestore (independent of
    the module's reading routes)."""
    ros1 = path.suffix == ".bag"
    store = rb._typestore(ros1)
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for c, t, raw in reader.messages(conns):
            yield t, (store.deserialize_ros1(raw, c.msgtype) if ros1 else store.deserialize_cdr(raw, c.msgtype))


# ---------------------------------------------------------------------------------------------------------------
# round trips


@pytest.mark.parametrize("flavour", FLAVOURS, ids=FLAVOUR_IDS)
def test_imu_round_trip(tmp_path, flavour):
    imu = _imu(np.random.default_rng(1))
    bag = _write(tmp_path, flavour, [rb.BagStream("/imu/data", "imu", imu, "imu_link")])
    assert rb.topics(bag) == {"/imu/data": ("sensor_msgs/msg/Imu", len(imu))}
    back = rb.read_imu(bag, "/imu/data")
    # POSIX stamps survive bit for bit (module docstring); values are float64 in the message
    np.testing.assert_array_equal(back.t_s, imu.t_s)
    np.testing.assert_allclose(back.f_b_mps2, imu.f_b_mps2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.w_b_rps, imu.w_b_rps, rtol=0, atol=1e-12)
    # the IMU took the direct storage route
    assert rb._fixed_fields(bag, "/imu/data", rb.IMU)["method"] == "storage"


@pytest.mark.parametrize("flavour", FLAVOURS, ids=FLAVOUR_IDS)
def test_navsatfix_round_trip_drops_no_fix(tmp_path, flavour, caplog):
    rng = np.random.default_rng(2)
    n = 40
    t = T0 + np.arange(n) * 0.2
    lat, lon, alt = 48.1 + rng.normal(0, 1e-4, n), 11.5 + rng.normal(0, 1e-4, n), 520 + rng.normal(0, 2, n)
    std = rng.uniform(0.5, 3.0, (n, 3))
    status = np.zeros(n, int)
    status[[0, 7, 8]] = -1           # STATUS_NO_FIX, among them the first message
    status[20] = 2                   # GBAS fix: kept
    fixes = rb.FixSeries(t_s=t, lat_deg=lat, lon_deg=lon, alt_m=alt, std_enu_m=std, status=status)
    bag = _write(tmp_path, flavour, [rb.BagStream("/gps/fix", "navsatfix", fixes, "gps")])
    with caplog.at_level(logging.INFO, logger="fusion_eval"):
        origin = rb.first_fix(bag, "/gps/fix")
        assert origin == (lat[1], lon[1], alt[1])      # the first *valid* fix
        g = rb.read_navsatfix(bag, "/gps/fix", origin)
    # said once: the look for the first fix said it too (a user's review saw the line twice)
    assert sum("dropped 3 of 40 fixes with status STATUS_NO_FIX" in r.getMessage() for r in caplog.records) == 1
    keep = status >= 0
    assert len(g) == n - 3
    np.testing.assert_array_equal(g.t_s, t[keep])
    np.testing.assert_allclose(g.p_w_m, geodetic_to_enu(lat[keep], lon[keep], alt[keep], *origin), rtol=0, atol=1e-12)
    np.testing.assert_allclose(g.std_w_m, std[keep], rtol=1e-12)
    assert rb._fixed_fields(bag, "/gps/fix", rb.NAVSATFIX)["method"] == "storage"


def test_navsatfix_with_a_covariance_that_is_no_variance_names_the_message(tmp_path):
    """A negative or NaN variance became a NaN std, reported as 'GNSS std must be finite numbers' without the
    message (found by a new-user review)."""
    n = 6
    std = np.ones((n, 3))
    std[3, 1] = np.nan
    fixes = rb.FixSeries(t_s=T0 + np.arange(n), lat_deg=np.full(n, 48.0), lon_deg=np.full(n, 11.0), alt_m=np.full(n, 500.0),
                         std_enu_m=std, status=np.zeros(n, int))
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/fix", "navsatfix", fixes, "gps")])
    with pytest.raises(DataFormatError, match=r"topic '/fix', message 4: position_covariance's diagonal .* must be variances"):
        rb.read_navsatfix(bag, "/fix", (48.0, 11.0, 500.0))


@pytest.mark.parametrize("flavour", FLAVOURS[:2], ids=FLAVOUR_IDS[:2])
def test_navsatfix_without_covariance(tmp_path, flavour):
    n = 5
    fixes = {"t_s": T0 + np.arange(n), "lat_deg": np.full(n, 48.0), "lon_deg": np.full(n, 11.0), "alt_m": np.full(n, 500.0)}
    bag = _write(tmp_path, flavour, [rb.BagStream("/fix", "navsatfix", fixes, "gps")])
    with pytest.raises(DataFormatError, match=r"5 of 5 fixes have no usable covariance \(the first: message 1, "
                                              r"position_covariance_type 0.*must give std_m") as err:
        rb.read_navsatfix(bag, "/fix", (48.0, 11.0, 500.0))
    assert err.value.path == str(bag)
    g = rb.read_navsatfix(bag, "/fix", (48.0, 11.0, 500.0), default_std_m=[1.0, 2.0, 4.0])
    np.testing.assert_array_equal(g.std_w_m, np.tile([1.0, 2.0, 4.0], (n, 1)))
    np.testing.assert_allclose(g.p_w_m, 0.0, atol=1e-9)


def test_navsatfix_with_zero_variances_takes_std_m(tmp_path):
    """Receivers publish a known covariance type with zeros before their first accuracy estimate: one such fix of
    601 refused the whole run with 'GNSS position std must be > 0', and std_m could not override it (found by a
    review with its own bags). Such fixes take std_m like fixes of unknown type."""
    n = 6
    std = np.ones((n, 3))
    std[0] = 0.0
    fixes = rb.FixSeries(t_s=T0 + np.arange(n), lat_deg=np.full(n, 48.0), lon_deg=np.full(n, 11.0), alt_m=np.full(n, 500.0),
                         std_enu_m=std, status=np.zeros(n, int))
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/fix", "navsatfix", fixes, "gps")])
    with pytest.raises(DataFormatError, match=r"1 of 6 fixes have no usable covariance \(the first: message 1"):
        rb.read_navsatfix(bag, "/fix", (48.0, 11.0, 500.0))
    g = rb.read_navsatfix(bag, "/fix", (48.0, 11.0, 500.0), default_std_m=[2.0, 2.0, 3.0])
    np.testing.assert_array_equal(g.std_w_m[0], [2.0, 2.0, 3.0])
    np.testing.assert_allclose(g.std_w_m[1:], 1.0, rtol=1e-12)


def test_a_zero_header_stamp_names_its_message(tmp_path):
    """A driver publishing before its clock was set (header.stamp 0 on the first message) was blamed on milliseconds
    or on recordings run together (found by a review with its own bags)."""
    from dataclasses import replace

    imu = _imu(np.random.default_rng(1))
    t = imu.t_s.copy()
    t[0] = 0.0
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/imu/data", "imu", replace(imu, t_s=t), "imu_link")])
    with pytest.raises(DataFormatError, match=r"topic '/imu/data', message 1: header stamp 0 among stamps .*stamps: record"):
        rb.read_imu(bag, "/imu/data")
    # every stamp 0 (a driver that never sets it): each message but one was dropped as a repeat and the run refused
    # for "fewer than 2 usable IMU samples" (a user's review)
    unset = replace(imu)
    object.__setattr__(unset, "t_s", t * 0.0)           # (the series itself refuses repeated stamps)
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/imu/data", "imu", unset, "imu_link")], name="all")
    with pytest.raises(DataFormatError, match=r"topic '/imu/data': all \d+ messages carry one header stamp .*stamps: record"):
        rb.read_imu(bag, "/imu/data")


@pytest.mark.parametrize("flavour", FLAVOURS[:2], ids=FLAVOUR_IDS[:2])
def test_odometry_round_trip_with_velocity_and_covariance(tmp_path, flavour):
    poses = _poses(np.random.default_rng(3))
    std = np.array([0.1, 0.2, 0.3, 0.01, 0.02, 0.03])
    bag = _write(tmp_path, flavour, [rb.BagStream("/odom", "odometry", poses, "odom", "base_link", std_m=std)])
    back = rb.read_poses(bag, "/odom")
    np.testing.assert_array_equal(back.t_s, poses.t_s)
    np.testing.assert_allclose(back.p_w_m, poses.p_w_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.q_wb_xyzw, poses.q_wb_xyzw, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.v_w_mps, poses.v_w_mps, rtol=0, atol=1e-12)
    # the message carries the twist in the child frame: R_wb^T v_w
    (_, first), = [next(_typed_messages(bag, "/odom"))]
    lin = first.twist.twist.linear
    v_b = quat_xyzw_to_matrix(poses.q_wb_xyzw[:1])[0].T @ poses.v_w_mps[0]
    np.testing.assert_allclose([lin.x, lin.y, lin.z], v_b, atol=1e-12)
    assert first.child_frame_id == "base_link" and first.header.frame_id == "odom"
    t, cov = rb.read_pose_covariances(bag, "/odom")
    np.testing.assert_array_equal(t, poses.t_s)
    np.testing.assert_allclose(cov, np.broadcast_to(np.diag(std ** 2), (len(poses), 6, 6)), rtol=1e-15)
    # child and parent frames select messages
    assert len(rb.read_poses(bag, "/odom", child_frame="base_link", parent_frame="odom")) == len(poses)
    with pytest.raises(DataFormatError, match=r"no pose with child_frame='wheel'.*odom->base_link \(60\)"):
        rb.read_poses(bag, "/odom", child_frame="wheel")


@pytest.mark.parametrize("kind", ["pose", "pose_cov", "transform"])
@pytest.mark.parametrize("flavour", FLAVOURS[:2], ids=FLAVOUR_IDS[:2])
def test_pose_kinds_round_trip(tmp_path, flavour, kind):
    poses = _poses(np.random.default_rng(4), velocity=False)
    bag = _write(tmp_path, flavour, [rb.BagStream("/p", kind, poses, "map", "body", std_m=0.5)])
    back = rb.read_poses(bag, "/p")
    np.testing.assert_array_equal(back.t_s, poses.t_s)
    np.testing.assert_allclose(back.p_w_m, poses.p_w_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.q_wb_xyzw, poses.q_wb_xyzw, rtol=0, atol=1e-12)
    assert back.v_w_mps is None
    if kind == "pose_cov":
        _, cov = rb.read_pose_covariances(bag, "/p")
        np.testing.assert_allclose(cov[:, :3, :3], np.broadcast_to(0.25 * np.eye(3), (len(poses), 3, 3)))
        assert np.all(cov[:, 3:, 3:] == 0)
    else:
        with pytest.raises(DataFormatError, match="expected geometry_msgs/msg/PoseWithCovarianceStamped or nav_msgs/msg/Odometry"):
            rb.read_pose_covariances(bag, "/p")


@pytest.mark.parametrize("flavour", FLAVOURS[:2], ids=FLAVOUR_IDS[:2])
def test_tf_round_trip_picks_the_child_frame_and_static_transforms(tmp_path, flavour):
    rng = np.random.default_rng(5)
    odom_base = _poses(rng, velocity=False)
    base_cam = _poses(rng, n=45, t0=T0 + 0.01, velocity=False)
    R = quat_xyzw_to_matrix(np.array([[0.1, -0.2, 0.3, 0.9]]))
    T_base_imu = make_T(R, np.array([[0.5, -0.1, 1.2]]))[0]
    T_map_odom = make_T(np.eye(3)[None], np.array([[10.0, 20.0, 0.0]]))[0]
    bag = _write(tmp_path, flavour, [rb.BagStream("/tf", "tf", odom_base, "odom", "base_link"),
                                     rb.BagStream("/tf", "tf", base_cam, "/base_link", "camera")],
                 tf_static=[("base_link", "imu", T_base_imu), ("map", "odom", T_map_odom)])
    assert rb.topics(bag) == rb._anyreader_topics(bag) == {"/tf": ("tf2_msgs/msg/TFMessage", 105),
                                                           "/tf_static": ("tf2_msgs/msg/TFMessage", 1)}
    for child, ref in [("base_link", odom_base), ("camera", base_cam)]:
        back = rb.read_poses(bag, "/tf", child_frame=child)
        np.testing.assert_array_equal(back.t_s, ref.t_s)
        np.testing.assert_allclose(back.p_w_m, ref.p_w_m, rtol=0, atol=1e-12)
        np.testing.assert_allclose(back.q_wb_xyzw, ref.q_wb_xyzw, rtol=0, atol=1e-12)
    # a leading '/' is ignored on both sides; a wrong parent lists the edges
    assert len(rb.read_poses(bag, "/tf", child_frame="/camera", parent_frame="base_link")) == 45
    with pytest.raises(DataFormatError, match=r"base_link->camera \(45\), odom->base_link \(60\)"):
        rb.read_poses(bag, "/tf", child_frame="camera", parent_frame="odom")
    with pytest.raises(ConfigError, match=r"give child_frame, the frame whose poses to read .*transforms present: "
                                          r"base_link->camera \(45\), odom->base_link \(60\)"):
        rb.read_poses(bag, "/tf")
    np.testing.assert_allclose(rb.static_transform(bag, "base_link", "imu"), T_base_imu, atol=1e-12)
    np.testing.assert_allclose(rb.static_transform(bag, "imu", "base_link") @ T_base_imu, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(rb.static_transform(bag, "map", "odom"), T_map_odom, atol=1e-12)
    assert rb.static_transform(bag, "map", "imu") is None          # no chain of static edges joins them
    assert rb.static_transform(bag, "odom", "base_link") is None   # dynamic edges are not static


def test_a_refused_bag_value_names_its_message(tmp_path):
    """A NaN in an IMU message 5000 of an hour's bag was refused naming the topic alone (found by a review with its
    own bags): the message number is named as a CSV's line is."""
    import dataclasses

    imu = _imu(np.random.default_rng(2))
    f = imu.f_b_mps2.copy()
    f[57, 0] = np.nan              # written as it is: a series made without its checks (which would refuse it here)
    bad = object.__new__(ImuSeries)
    for fld in dataclasses.fields(ImuSeries):
        object.__setattr__(bad, fld.name, f if fld.name == "f_b_mps2" else getattr(imu, fld.name))
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/imu/data", "imu", bad, "imu_link")])
    with pytest.raises(DataFormatError, match=r"\(topic /imu/data, message 58\): IMU specific force must be finite"):
        rb.read_imu(bag, "/imu/data")


def test_a_static_transform_through_a_common_parent_is_composed():
    """A robot's TF tree holds base_link -> imu_link and base_link -> lidar, never imu_link -> lidar: the extrinsic
    was refused (found by a review with its own bags); the chain through the frames between is composed."""
    rng = np.random.default_rng(5)

    def T(n):
        q = rng.normal(size=(1, 4)) / 2 + [0, 0, 0, 1.0]
        return make_T(quat_xyzw_to_matrix(q / np.linalg.norm(q)), rng.normal(size=(1, 3)))[0]
    T_base_imu, T_base_lidar, T_lidar_cam = T(0), T(1), T(2)
    edges = {("base_link", "imu_link"): T_base_imu, ("base_link", "lidar"): T_base_lidar, ("lidar", "cam"): T_lidar_cam,
             ("map", "odom"): T(3)}
    want = np.linalg.inv(T_base_imu) @ T_base_lidar @ T_lidar_cam
    np.testing.assert_allclose(rb.transform_between(edges, "imu_link", "cam"), want, atol=1e-12)
    np.testing.assert_allclose(rb.transform_between(edges, "/cam", "imu_link") @ want, np.eye(4), atol=1e-12)
    assert rb.transform_between(edges, "imu_link", "odom") is None


def test_messages_interleaved_in_time_order(tmp_path):
    rng = np.random.default_rng(6)
    imu, poses = _imu(rng, n=100), _poses(rng, n=10)
    bag = _write(tmp_path, FLAVOURS[1], [rb.BagStream("/imu", "imu", imu, "imu"),
                                         rb.BagStream("/gt", "pose", poses, "map")])
    # storage order (sqlite rowid), not the reader's merge: time-sorted, the topics mixed
    import sqlite3
    db3, = bag.glob("*.db3")
    con = sqlite3.connect(db3)
    rows = con.execute("SELECT m.timestamp, t.name FROM messages m JOIN topics t ON m.topic_id = t.id ORDER BY m.id").fetchall()
    con.close()
    rec = [r[0] for r in rows]
    names = [r[1] for r in rows]
    assert rec == sorted(rec) and len(rec) == 110
    first_gt, last_gt = names.index("/gt"), len(names) - 1 - names[::-1].index("/gt")
    assert "/imu" in names[first_gt:last_gt] and names[0] == "/imu"
    np.testing.assert_array_equal(sorted(rec), np.sort(np.r_[rb._to_ns(imu.t_s, ""), rb._to_ns(poses.t_s, "")]))


# ---------------------------------------------------------------------------------------------------------------
# stamps


@pytest.mark.parametrize("flavour", FLAVOURS, ids=FLAVOUR_IDS)
def test_header_and_record_stamps(tmp_path, flavour):
    rng = np.random.default_rng(7)
    imu, poses = _imu(rng, n=50), _poses(rng, n=20)
    # record times later than the stamps and in another order than them: the header read must sort
    rec_imu = imu.t_s + 0.25 + rng.uniform(0, 0.02, len(imu))
    rec_pose = poses.t_s[::-1] + 1.0
    bag = _write(tmp_path, flavour, [rb.BagStream("/imu", "imu", imu, "imu", record_t_s=rec_imu),
                                     rb.BagStream("/gt", "pose", poses, "map", record_t_s=rec_pose)])
    h, r = rb.read_imu(bag, "/imu"), rb.read_imu(bag, "/imu", stamps="record")
    np.testing.assert_array_equal(h.t_s, imu.t_s)
    order = np.argsort(rec_imu)
    np.testing.assert_array_equal(r.t_s, _expected_stamps(rec_imu[order]))
    np.testing.assert_array_equal(r.f_b_mps2, imu.f_b_mps2[order])
    assert np.min(r.t_s - h.t_s) > 0.2         # the two clocks differ as written
    ph, pr = rb.read_poses(bag, "/gt"), rb.read_poses(bag, "/gt", stamps="record")
    np.testing.assert_array_equal(ph.t_s, poses.t_s)
    np.testing.assert_array_equal(ph.p_w_m, poses.p_w_m)       # sorted back by header stamp
    np.testing.assert_array_equal(pr.p_w_m, poses.p_w_m[::-1])  # in record order
    with pytest.raises(ConfigError, match="stamps must be 'header' or 'record'"):
        rb.read_imu(bag, "/imu", stamps="receive")


def test_stamps_round_to_the_nanosecond(tmp_path):
    rng = np.random.default_rng(8)
    # small stamps carry sub-nanosecond digits that a bag cannot hold
    small = ImuSeries(t_s=np.sort(rng.uniform(0, 1000, 300)) + 1e-10 * rng.uniform(size=300),
                      f_b_mps2=np.zeros((300, 3)), w_b_rps=np.zeros((300, 3)))
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/imu", "imu", small, "imu")])
    back = rb.read_imu(bag, "/imu").t_s
    np.testing.assert_array_equal(back, _expected_stamps(small.t_s))
    assert np.max(np.abs(back - small.t_s)) <= 0.5e-9 + 1e-12
    # POSIX stamps come back bit for bit
    t = T0 + np.sort(rng.uniform(0, 3600, 2000))
    posix = ImuSeries(t_s=t, f_b_mps2=np.zeros((t.size, 3)), w_b_rps=np.zeros((t.size, 3)))
    bag2 = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/imu", "imu", posix, "imu")], name="p")
    np.testing.assert_array_equal(rb.read_imu(bag2, "/imu").t_s, t)
    with pytest.raises(DataFormatError, match=r"in \[0, 2\^31\) s"):
        rb._to_ns(np.array([-1.0]), "x")


# ---------------------------------------------------------------------------------------------------------------
# the fixed-offset fast path against the typestore


@pytest.mark.parametrize("frame_id", ["", "i", "imu", "imu_lin", "imu_link", "imu_link_front_left"])
@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "cdr"])
def test_fast_imu_serializer_equals_typestore(ros1, frame_id):
    rng = np.random.default_rng(9)
    n = 4
    ns = rb._to_ns(T0 + np.arange(n) * 0.005, "t")
    f, w = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    fast = rb._imu_payloads(ns, frame_id, f, w, ros1)
    b = rb._Builder(ros1)
    assert fast == [b.serialize(b.imu(int(ns[i]), frame_id, i, f[i], w[i]), rb.IMU) for i in range(n)]


@pytest.mark.slow
@pytest.mark.parametrize("frame_id", ["", "gps", "gps_ant", "gps_ante", "navsat_link_1"])
@pytest.mark.parametrize("flavour", FLAVOURS, ids=FLAVOUR_IDS)
def test_fast_path_equals_typestore_deserialization(tmp_path, flavour, frame_id):
    """Every frame_id length shifts the CDR alignment differently; each route must give the typestore's values."""
    rng = np.random.default_rng(10)
    imu = _imu(rng, n=30)
    n = 12
    fixes = rb.FixSeries(t_s=T0 + np.arange(n) * 0.1, lat_deg=rng.uniform(-80, 80, n), lon_deg=rng.uniform(-180, 180, n),
                         alt_m=rng.normal(100, 50, n), std_enu_m=rng.uniform(0.1, 5, (n, 3)),
                         status=rng.integers(-1, 3, n))
    bag = _write(tmp_path, flavour, [rb.BagStream("/imu", "imu", imu, frame_id),
                                     rb.BagStream("/fix", "navsatfix", fixes, frame_id)])
    for topic, msgtype in [("/imu", rb.IMU), ("/fix", rb.NAVSATFIX)]:
        # the reference: the typestore's messages, their attributes read here (not by the module's _fields_of)
        ref = [_attrs(m, msgtype) for _, m in _typed_messages(bag, topic)]
        rec = np.array([t for t, _ in _typed_messages(bag, topic)])
        for method in ("auto", "raw", "deserialize"):
            got = rb._fixed_fields(bag, topic, msgtype, method=method)
            assert got["method"] == ("storage" if method == "auto" else method)
            np.testing.assert_array_equal(got["rec_ns"], rec)
            for name in rb._READ_FIELDS[msgtype]:
                np.testing.assert_array_equal(got[name], np.array([r[name] for r in ref]), err_msg=f"{method} {name}")


def _attrs(m, msgtype: str) -> dict:
    out = {"sec": m.header.stamp.sec, "nsec": m.header.stamp.nanosec}
    if msgtype == rb.IMU:
        a, w = m.linear_acceleration, m.angular_velocity
        return {**out, "f": [a.x, a.y, a.z], "w": [w.x, w.y, w.z]}
    return {**out, "status": m.status.status, "lla": [m.latitude, m.longitude, m.altitude],
            "cov": list(m.position_covariance), "cov_type": m.position_covariance_type}


def _raw_bag(path: Path, ros1: bool, msgs, compression=None) -> Path:
    """A bag written with rosbags directly: msgs = [(topic, msgtype, record ns, message)]."""
    store = rb._typestore(ros1)
    if ros1:
        w = Writer1(path)
        if compression:
            w.set_compression(compression)
    else:
        w = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP if compression == "mcap-zstd" else StoragePlugin.SQLITE3)
        if compression == "mcap-zstd":
            w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        elif compression == "message":
            w.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with w:
        conns = {}
        for topic, typ, t, msg in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=store)
            raw = store.serialize_ros1(msg, typ) if ros1 else store.serialize_cdr(msg, typ)
            w.write(conns[topic], t, raw)
    return path


def _imu_msgs(ros1: bool, frames: list[str], rng) -> tuple[list, np.ndarray, np.ndarray]:
    b = rb._Builder(ros1)
    ns = rb._to_ns(T0 + np.arange(len(frames)) * 0.005, "t")
    f, w = rng.normal(size=(len(frames), 3)), rng.normal(size=(len(frames), 3))
    return [("/imu", rb.IMU, int(ns[i]), b.imu(int(ns[i]), fr, i, f[i], w[i])) for i, fr in enumerate(frames)], f, w


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_varying_frame_id_falls_back_and_repeated_stamps_are_dropped(tmp_path, ros1, caplog):
    rng = np.random.default_rng(11)
    msgs, f, w = _imu_msgs(ros1, ["imu", "/imu", "imu", "//imu", "imu", "/imu"], rng)     # one frame, spelt three ways
    # the fifth message repeats the fourth one's header stamp
    dup = msgs[4][3]
    dup.header.stamp = msgs[3][3].header.stamp
    bag = _raw_bag(tmp_path / ("v.bag" if ros1 else "v"), ros1, msgs)
    assert rb._fixed_fields(bag, "/imu", rb.IMU)["method"] == "deserialize"
    imu = rb.read_imu(bag, "/imu")
    keep = [0, 1, 2, 3, 5]
    np.testing.assert_array_equal(imu.f_b_mps2, f[keep])
    np.testing.assert_array_equal(imu.w_b_rps, w[keep])
    assert "dropped 1 messages whose stamp repeats" in caplog.text


@pytest.mark.parametrize("compression", [Writer1.CompressionFormat.BZ2, Writer1.CompressionFormat.LZ4, "mcap-zstd", "message"],
                         ids=["ros1-bz2", "ros1-lz4", "mcap-zstd", "sqlite3-message-zstd"])
def test_compressed_bags(tmp_path, compression):
    ros1 = not isinstance(compression, str)
    rng = np.random.default_rng(12)
    msgs, f, w = _imu_msgs(ros1, ["imu"] * 3000, rng)      # a few chunks
    bag = _raw_bag(tmp_path / ("c.bag" if ros1 else "c"), ros1, msgs, compression)
    got = rb._fixed_fields(bag, "/imu", rb.IMU)
    # per-message compression is left to rosbags (the raw route); chunk compression is read directly
    assert got["method"] == ("raw" if compression == "message" else "storage")
    imu = rb.read_imu(bag, "/imu")
    np.testing.assert_array_equal(imu.f_b_mps2, f)
    np.testing.assert_array_equal(imu.w_b_rps, w)
    np.testing.assert_array_equal(imu.t_s, _expected_stamps(T0 + np.arange(3000) * 0.005))


# ---------------------------------------------------------------------------------------------------------------
# opening and errors


def test_paths_a_reader_accepts(tmp_path):
    imu = _imu(np.random.default_rng(13), n=20)
    folder = _write(tmp_path, FLAVOURS[1], [rb.BagStream("/imu", "imu", imu, "imu")])
    mcap = _write(tmp_path, FLAVOURS[2], [rb.BagStream("/imu", "imu", imu, "imu")], name="m")
    db3, = folder.glob("*.db3")
    loose = tmp_path / "loose" / "x.mcap"      # an MCAP file without its metadata.yaml
    loose.parent.mkdir()
    loose.write_bytes(next(mcap.glob("*.mcap")).read_bytes())
    for p in (folder, db3, mcap, next(mcap.glob("*.mcap")), loose):
        np.testing.assert_array_equal(rb.read_imu(p, "/imu").t_s, imu.t_s)
        assert rb.topics(p) == rb._anyreader_topics(p) == {"/imu": ("sensor_msgs/msg/Imu", 20)}
        with rb.open_reader(p) as reader:
            assert reader.message_count == 20


def test_errors_name_the_file_and_what_was_expected(tmp_path):
    rng = np.random.default_rng(14)
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/imu", "imu", _imu(rng, n=10), "imu"),
                                         rb.BagStream("/gt", "pose", _poses(rng, n=5), "map")])
    with pytest.raises(DataFormatError) as err:
        rb.read_imu(bag, "/imu0")
    assert str(err.value) == (f"{bag}: topic '/imu0' not in bag "
                              "(topics: /gt [geometry_msgs/msg/PoseStamped], /imu [sensor_msgs/msg/Imu])")
    with pytest.raises(DataFormatError, match=r"topic '/gt' is geometry_msgs/msg/PoseStamped, expected sensor_msgs/msg/NavSatFix"):
        rb.read_navsatfix(bag, "/gt", (0.0, 0.0, 0.0))
    with pytest.raises(DataFormatError, match=r"topic '/imu' is sensor_msgs/msg/Imu, expected nav_msgs/msg/Odometry or "):
        rb.read_poses(bag, "/imu")
    with pytest.raises(DataFormatError, match=r"no such file or folder; expected a ROS 1 \.bag file"):
        rb.read_imu(tmp_path / "missing.bag", "/imu")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(DataFormatError, match=r"not a bag \(suffix '\.txt'\)"):
        rb.topics(tmp_path / "notes.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFormatError, match="no metadata.yaml"):
        rb.topics(tmp_path / "empty")
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(100))
    with pytest.raises(DataFormatError, match=r"junk\.bag: cannot open as a rosbag1 bag"):
        rb.read_imu(tmp_path / "junk.bag", "/imu")
    with pytest.raises(OutputError, match="exists"):
        rb.write_bag(bag, "rosbag1", [])
    with pytest.raises(ConfigError, match="kind must be one of"):
        rb.write_bag(tmp_path / "k.bag", "rosbag1", [rb.BagStream("/x", "gnss", None, "f")])
    with pytest.raises(ConfigError, match="needs child_frame_id"):
        rb.write_bag(tmp_path / "k.bag", "rosbag1", [rb.BagStream("/tf", "tf", _poses(rng), "map")])
    assert not (tmp_path / "k.bag").exists()


def test_a_bag_that_fails_while_written_leaves_nothing(tmp_path, monkeypatch):
    """The writer fails after writing its messages (the final rename refused): neither the bag nor the temporary
    one it was written into is left."""
    def refuse(*_a, **_k):
        raise OSError("disk full")
    monkeypatch.setattr(rb.os, "replace", refuse)
    imu = _imu(np.random.default_rng(2), n=20)
    for flavour in FLAVOURS[:2]:
        with pytest.raises(OSError, match="disk full"):
            _write(tmp_path, flavour, [rb.BagStream("/imu", "imu", imu, "imu")], name="k")
    assert sorted(p.name for p in tmp_path.iterdir()) == [], list(tmp_path.iterdir())


# ---------------------------------------------------------------------------------------------------------------
# the real bags of evo's test data


@needs_evo_data
def test_ros_example_bag_equals_evo():
    from evo.tools import file_interface
    from rosbags.rosbag1 import Reader

    path = shared_path(EVO, "ROS_example.bag")
    assert rb.topics(path) == {"groundtruth": ("geometry_msgs/msg/PoseStamped", 12765),
                               "ORB-SLAM": ("geometry_msgs/msg/PoseStamped", 8362),
                               "S-PTAM": ("geometry_msgs/msg/PoseStamped", 5439)}
    gt = rb.read_poses(path, "groundtruth")
    with Reader(path) as reader:
        ref = file_interface.read_bag_trajectory(reader, "groundtruth")
    assert len(gt) == 12765 == ref.num_poses
    np.testing.assert_allclose(gt.t_s, ref.timestamps, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gt.p_w_m, ref.positions_xyz, rtol=0, atol=1e-12)
    np.testing.assert_allclose(gt.q_wb_xyzw, ref.orientations_quat_wxyz[:, [1, 2, 3, 0]], rtol=0, atol=1e-12)


@needs_evo_data
def test_tf_example_bags():
    ros1, ros2 = shared_path(EVO, "tf_example.bag"), shared_path(EVO, "tf_example")
    for path in (ros1, ros2, ros2 / "tf_example.db3"):
        assert rb.topics(path) == {"/tf": ("tf2_msgs/msg/TFMessage", 517), "/tf_static": ("tf2_msgs/msg/TFMessage", 1)}
    a = rb.read_poses(ros1, "/tf", child_frame="base_footprint")
    b = rb.read_poses(ros2, "/tf", child_frame="base_footprint", parent_frame="odom")
    # against the transforms decoded one by one with the typestore
    ref = [(tf.header.stamp.sec + tf.header.stamp.nanosec * 1e-9, tf.transform.translation, tf.transform.rotation)
           for _, m in _typed_messages(ros1, "/tf") for tf in m.transforms if tf.child_frame_id == "base_footprint"]
    assert len(a) == len(b) == len(ref) == 517
    np.testing.assert_array_equal(a.t_s, [r[0] for r in ref])
    np.testing.assert_array_equal(a.p_w_m, [(r[1].x, r[1].y, r[1].z) for r in ref])
    q = np.array([(r[2].x, r[2].y, r[2].z, r[2].w) for r in ref])
    np.testing.assert_allclose(a.q_wb_xyzw, q / np.linalg.norm(q, axis=1)[:, None], rtol=0, atol=1e-15)
    for x, y in [(a.t_s, b.t_s), (a.p_w_m, b.p_w_m), (a.q_wb_xyzw, b.q_wb_xyzw)]:
        np.testing.assert_array_equal(x, y)       # the ROS 1 and ROS 2 copies hold the same data
    np.testing.assert_array_equal(rb.static_transform(ros2, "base_footprint", "base_link"), np.eye(4))
    with pytest.raises(DataFormatError, match=r"frames present: odom->base_footprint \(517\)"):
        rb.read_poses(ros2, "/tf", child_frame="base_link")


@needs_evo_data
def test_tf_example_against_evo_tf_lookup():
    """evo reads '/tf:odom.base_footprint' through tf2's BufferCore: it needs ROS's tf2_py, chains transforms and
    resamples them at its lookup frequency; where its samples fall on a message stamp, the poses must agree."""
    pytest.importorskip("tf2_py", reason="evo's TF-ID reading needs ROS's tf2_py and chains/resamples transforms")
    from evo.tools import file_interface
    from rosbags.rosbag1 import Reader

    path = shared_path(EVO, "tf_example.bag")
    ours = rb.read_poses(path, "/tf", child_frame="base_footprint", parent_frame="odom")
    with Reader(path) as reader:
        ref = file_interface.read_bag_trajectory(reader, "/tf:odom.base_footprint")
    i = np.clip(np.searchsorted(ours.t_s, ref.timestamps), 0, len(ours) - 1)
    same = np.abs(ours.t_s[i] - ref.timestamps) < 1e-9
    assert same.any()
    np.testing.assert_allclose(ref.positions_xyz[same], ours.p_w_m[i[same]], rtol=0, atol=1e-9)


def test_a_bag_garbled_in_the_middle_is_a_one_line_error(tmp_path):
    """A ROS 1 bag whose middle is overwritten opens (its index is intact) and fails only where the reader meets the
    damage: once rosbags' ReaderError traceback out of `run`; now the bag, the topic and how far it got."""
    from fusion_eval.errors import DataFormatError

    imu = _imu(np.random.default_rng(5), n=5000)
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/imu/data", "imu", imu, "imu_link")])
    assert bag.suffix == ".bag"
    data = bytearray(bag.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 4096] = bytes(range(256)) * 16
    bag.write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match=r"damaged: reading topic '/imu/data' failed after \d+ messages"):
        rb.read_imu(bag, "/imu/data")


@pytest.mark.parametrize("flavour", FLAVOURS, ids=FLAVOUR_IDS)
def test_nan_in_first_and_last_fix_keeps_the_fast_path(tmp_path, flavour):
    """A no-fix message carries NaN coordinates (REP 145); the check of the first and last messages against the
    typestore must read NaN as equal to NaN, or a 1 h bag falls back to per-message deserialization."""
    rng = np.random.default_rng(12)
    n = 8
    lat = rng.uniform(40, 50, n)
    lat[[0, -1]] = np.nan
    fixes = rb.FixSeries(t_s=T0 + np.arange(n) * 0.1, lat_deg=lat, lon_deg=rng.uniform(0, 10, n),
                         alt_m=rng.normal(100, 5, n), std_enu_m=np.full((n, 3), 1.0),
                         status=np.where(np.isnan(lat), -1, 0))
    bag = _write(tmp_path, flavour, [rb.BagStream("/imu", "imu", _imu(rng, n=30), "imu"),
                                     rb.BagStream("/fix", "navsatfix", fixes, "gps")])
    got = rb._fixed_fields(bag, "/fix", rb.NAVSATFIX)
    assert got["method"] == "storage"
    np.testing.assert_array_equal(got["lla"][:, 0], lat)


@pytest.mark.parametrize("flavour", FLAVOURS, ids=FLAVOUR_IDS)
def test_a_bag_given_as_the_dataset_says_what_to_write(tmp_path, flavour):
    """'fusion-eval run drive.bag' read the bag as a YAML manifest ('not UTF-8 text'): now it lists the topics."""
    from fusion_eval.datasets.manifest import load_dataset

    bag = _write(tmp_path, flavour, [rb.BagStream("/imu", "imu", _imu(np.random.default_rng(3), n=30), "imu")])
    with pytest.raises(DataFormatError, match=r"a ROS bag, not a dataset: write a dataset.yaml .*its topics: /imu "
                                              r"\[sensor_msgs/msg/Imu\]"):
        load_dataset(bag)


def test_a_manifests_topic_the_bag_lacks_is_named_at_its_line(tmp_path):
    """A typo in a manifest's topic named the bag and its topics, not the manifest's line where it is fixed (a user's
    review)."""
    from fusion_eval.datasets.manifest import load_dataset

    rng = np.random.default_rng(15)
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/imu", "imu", _imu(rng, n=10), "imu"),
                                         rb.BagStream("/gt", "pose", _poses(rng, n=5), "map")])
    (tmp_path / "dataset.yaml").write_text(
        "name: typo\nstreams:\n  imu: {format: rosbag, path: " + bag.name + ",\n"
        "        topic: /imu0}\n  groundtruth: {format: rosbag, path: " + bag.name + ", topic: /gt}\n")
    with pytest.raises(ConfigError, match=r"dataset.yaml:4: topic '/imu0' not in bag \(topics: /gt .*, /imu .*\) in "):
        load_dataset(tmp_path)


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_evaluate_reads_a_topic_recorded_out_of_stamp_order_sorted(tmp_path, ros1, caplog):
    """Messages recorded out of their header stamps' order (two publishers, write buffers): run's reader sorts them,
    evaluate --bag refused them as 'decreasing' and named the place 'message, message 2' (a bag review)."""
    from fusion_eval.datasets.trajectory_file import read_bag_trajectories

    rng = np.random.default_rng(5)
    b = rb._Builder(ros1)
    poses = _poses(rng, n=40, velocity=False)
    ns = rb._to_ns(poses.t_s, "t")
    order = np.arange(40)
    order[10], order[11] = 11, 10                    # two messages swapped on record, not in their stamps
    msgs = [("/pose", rb.POSE_STAMPED, int(ns[0]) + 200_000_000 * j, b.T[rb.POSE_STAMPED](
        header=b.header(int(ns[i]), "map", j), pose=b.pose(poses.p_w_m[i], poses.q_wb_xyzw[i]))) for j, i in enumerate(order)]
    bag = _raw_bag(tmp_path / ("p.bag" if ros1 else "p"), ros1, msgs)
    with caplog.at_level(logging.INFO, logger="fusion_eval"):
        (f,) = read_bag_trajectories(bag, ["/pose"])
    np.testing.assert_array_equal(f.traj.timestamps, _expected_stamps(poses.t_s))
    np.testing.assert_allclose(f.traj.positions_xyz, poses.p_w_m)
    assert "not in stamp order; sorted by stamp" in caplog.text


def test_poses_of_another_frame_than_the_extrinsic_taken_are_said(tmp_path, caplog):
    """Odometry of velo_link (its child_frame_id) read with T_imu_base from tf_static [imu_link, base_link] made the
    fused APE 1.11 m for 0.76 with no word (a bag review); the right frame, or a type without a child frame, says
    nothing."""
    from fusion_eval.datasets import rosbag_streams
    from fusion_eval.datasets.streams import ReadContext

    rng = np.random.default_rng(6)
    bag = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/odom", "odometry", _poses(rng), "odom", child_frame_id="velo_link"),
                                         rb.BagStream("/pose", "pose", _poses(rng), "map")])
    (tmp_path / "m.yaml").write_text("streams: {}\n")
    ctx = ReadContext(root=tmp_path, manifest=tmp_path / "m.yaml", origin=None, oxts=None)

    def said(topic, frame, pair):
        caplog.clear()
        entry = {"format": "rosbag", "path": bag.name, "topic": topic, "frame": frame, f"T_imu_{frame}": {"tf_static": pair}}
        with caplog.at_level(logging.WARNING, logger="fusion_eval"):
            rosbag_streams.read_poses(entry, ctx)
        return caplog.text

    w = said("/odom", "base", ["imu_link", "base_link"])
    assert "are of frame 'velo_link' (their child_frame_id), but the extrinsic taken is base_link's" in w
    assert "tf_static: [imu_link, velo_link]" in w
    assert said("/odom", "velo", ["imu_link", "/velo_link"]) == ""
    assert said("/pose", "base", ["imu_link", "base_link"]) == ""           # PoseStamped: no child frame to check
    unset = _write(tmp_path, FLAVOURS[0], [rb.BagStream("/odom", "odometry", _poses(rng), "odom", child_frame_id="x")],
                   name="unset")
    entry = {"format": "rosbag", "path": unset.name, "topic": "/odom", "frame": "base",
             "T_imu_base": {"tf_static": ["imu_link", "base_link"]}}
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="fusion_eval"):
        rosbag_streams._check_frame(entry, ctx, {("odom", ""): 60})     # a driver that leaves child_frame_id unset
    assert caplog.text == ""


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2-sqlite3"])
@pytest.mark.parametrize("names", [("imu0", "imu1"), ("imu_link", "imu2_link")], ids=["same-length", "other-length"])
def test_two_sensors_on_one_topic_are_refused_unless_one_frame_is_chosen(tmp_path, ros1, names):
    """Two IMU drivers publishing on one topic (frame_ids imu_link and imu2_link, the second rotated) ran as one IMU,
    through misleading messages, to 1.58 m for 0.76 (a bag review): refused, naming the frames and their counts;
    the entry's frame_id reads one of them, with the messages' own numbers. Both storage routes: frame_ids of one
    length read by fixed offsets, of two lengths message by message."""
    rng = np.random.default_rng(13)
    frames = [names[i % 2] for i in range(40)]
    msgs, f, w = _imu_msgs(ros1, frames, rng)
    bag = _raw_bag(tmp_path / ("two.bag" if ros1 else "two"), ros1, msgs)
    a, b = sorted(names)
    with pytest.raises(DataFormatError, match=rf"holds messages of 2 frames \('{a}' \(20\), '{b}' \(20\)\).*"
                                              "give the stream's frame_id"):
        rb.read_imu(bag, "/imu")
    imu = rb.read_imu(bag, "/imu", frame_id=names[1])
    np.testing.assert_array_equal(imu.f_b_mps2, f[1::2])
    np.testing.assert_array_equal(imu.lines, np.arange(2, 41, 2))
    with pytest.raises(DataFormatError, match="no message of frame_id 'gps'"):
        rb.read_imu(bag, "/imu", frame_id="gps")


def test_a_ros2_bags_metadata_yaml_reads_its_folder(tmp_path):
    """path: bag/metadata.yaml was 'not a bag (suffix .yaml)' (a bag review): the bag is the file's folder."""
    rng = np.random.default_rng(8)
    bag = _write(tmp_path, FLAVOURS[1], [rb.BagStream("/imu", "imu", _imu(rng), "imu")])
    assert rb.resolve(bag / "metadata.yaml") == ("rosbag2", bag)
    np.testing.assert_array_equal(rb.read_imu(bag / "metadata.yaml", "/imu").t_s, rb.read_imu(bag, "/imu").t_s)


def test_evaluate_refuses_a_topic_whose_header_stamps_are_never_set(tmp_path):
    """All header stamps 0: 'dropped 4408 messages whose stamp repeats' then '0 poses match (0.000 to 0.000 s)' (a bag
    review); one line says what it is."""
    from fusion_eval.datasets.trajectory_file import read_bag_trajectories

    rng = np.random.default_rng(9)
    b = rb._Builder(False)
    poses = _poses(rng, n=20, velocity=False)
    msgs = [("/pose", rb.POSE_STAMPED, int(T0 * 1e9) + 10_000_000 * j, b.T[rb.POSE_STAMPED](
        header=b.header(0, "map", j), pose=b.pose(poses.p_w_m[j], poses.q_wb_xyzw[j]))) for j in range(20)]
    bag = _raw_bag(tmp_path / "z", False, msgs)
    with pytest.raises(DataFormatError, match=r"topic '/pose': all 20 messages carry one header stamp \(0 s\): a "
                                              r"publisher that never sets it"):
        read_bag_trajectories(bag, ["/pose"])


def test_zstd_chunks_without_a_zstd_module_take_the_general_route(monkeypatch):
    """An older rosbags brings zstandard, not backports.zstd: the fast path's import failed, warned of a missing
    module and took the slow route (a portability review); each known module is tried, and with none the fast path
    steps aside as for any layout it does not handle."""
    from fusion_eval.datasets import rosbag

    for name in ("compression", "compression.zstd", "backports", "backports.zstd", "zstandard"):
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(rosbag._NoFastPath, match="no zstd module"):
        rosbag._zstd_decompress(b"\x28\xb5\x2f\xfd")
