"""One simulated drive through every layout the simulator writes (KITTI raw, OXTS CSV, EuRoC, generic CSV, ROS 1 and
ROS 2 bags) gives the same data and the same fused metrics (to 1e-9); the readers behind them (EuRoC folders without a
manifest, generic CSV streams, frames with ``T_imu_<frame>``) and their one-line errors."""

from __future__ import annotations

import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

import fusion_eval as fe
from fusion_eval.datasets.manifest import load_dataset
from fusion_eval.errors import ConfigError, DataFormatError
from fusion_eval.simulate.dataset import simulate
from fusion_eval.so3 import quat_xyzw_to_matrix

DURATION_S = 40.0
LAYOUTS = ("csv", "euroc", "csv_log", "rosbag1", "rosbag2")


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    root = tmp_path_factory.mktemp("layouts")
    out = {}
    for layout in ("kitti", *LAYOUTS):
        simulate(root / layout, "urban", DURATION_S, seed=3, grade="automotive", sets=(f"output.layout={layout}",))
        out[layout] = root / layout
    return out


@pytest.fixture(scope="module")
def reference_metrics(drives):
    return fe.run(drives["kitti"]).metrics


def _stats(m: dict):
    for est, d in m["estimates"].items():
        for group, rels in d.items():
            if not isinstance(rels, dict) or group not in ("ape", "rpe_1frame") and not group.startswith("rpe_"):
                continue
            for rel, st in rels.items():
                for k, v in (st or {}).items():
                    yield (est, group, rel, k), v


@pytest.mark.slow
@pytest.mark.parametrize("layout", LAYOUTS)
def test_same_drive_same_data_and_metrics_through_every_layout(drives, reference_metrics, layout):
    a, b = load_dataset(drives["kitti"]), load_dataset(drives[layout])
    for name in ("imu", "groundtruth", "gnss", "lidar", "odometer"):
        sa, sb = getattr(a, name), getattr(b, name)
        assert np.array_equal(sa.t_s, sb.t_s), (layout, name)          # every stamp carried exactly
        for f in ("f_b_mps2", "w_b_rps", "p_w_m", "std_w_m", "v_mps"):
            if getattr(sa, f, None) is not None:
                assert np.abs(getattr(sa, f) - getattr(sb, f)).max() <= 1e-12, (layout, name, f)
    m = fe.run(drives[layout]).metrics
    ref = dict(_stats(reference_metrics))
    got = dict(_stats(m))
    assert ref.keys() == got.keys() and len(ref) > 40
    for k, v in ref.items():
        assert got[k] == pytest.approx(v, abs=1e-9), (layout, k)


@pytest.mark.slow
def test_map_matching_lidar_through_a_bag_and_euroc(tmp_path):
    ms = {}
    for layout in ("kitti", "euroc", "rosbag2"):
        simulate(tmp_path / layout, "urban", 20.0, seed=5, grade="automotive",
                 sets=(f"output.layout={layout}", "lidar.mode=map_matching", "lidar.rate_hz=5"))
        ms[layout] = dict(_stats(fe.run(tmp_path / layout).metrics))
    for layout in ("euroc", "rosbag2"):
        for k, v in ms["kitti"].items():
            assert ms[layout][k] == pytest.approx(v, abs=1e-9), (layout, k)


@pytest.mark.slow
def test_the_lidar_extrinsic_from_tf_static(drives, tmp_path):
    """The bag's /tf_static holds the IMU -> cam0 extrinsic; read from there it is the rigid version of the
    calibration files' chain (whose 6-digit rotation is orthonormal only to ~1e-6)."""
    man = yaml.safe_load((drives["rosbag1"] / "dataset.yaml").read_text())
    lidar = dict(man["streams"]["lidar"])
    lidar.pop("T_cam0_imu")
    lidar["T_imu_cam0"] = {"tf_static": ["imu_link", "cam0"], "bag": str(drives["rosbag1"] / "drive.bag")}
    man["streams"]["lidar"] = {**lidar, "path": str(drives["rosbag1"] / "drive.bag")}
    for k in ("imu", "groundtruth"):
        man["streams"][k]["path"] = str(drives["rosbag1"] / "drive.bag")
    man["streams"] = {k: man["streams"][k] for k in ("imu", "groundtruth", "lidar")}
    (tmp_path / "dataset.yaml").write_text(yaml.safe_dump(man))
    a, b = load_dataset(drives["rosbag1"]), load_dataset(tmp_path / "dataset.yaml")
    d = np.abs(a.lidar.p_w_m - b.lidar.p_w_m).max()
    assert 1e-9 < d < 1e-5
    lidar["T_imu_cam0"] = {"tf_static": ["imu_link", "nope"], "bag": str(drives["rosbag1"] / "drive.bag")}
    man["streams"]["lidar"] = {**lidar, "path": str(drives["rosbag1"] / "drive.bag")}
    (tmp_path / "dataset.yaml").write_text(yaml.safe_dump(man))
    with pytest.raises(ConfigError, match="no /tf_static transform imu_link -> nope"):
        load_dataset(tmp_path / "dataset.yaml")
    # a bag that is not there: the manifest's line of the key, not only the missing file
    lidar["T_imu_cam0"] = {"tf_static": ["imu_link", "cam0"], "bag": str(tmp_path / "missing.bag")}
    man["streams"]["lidar"] = {**lidar, "path": str(drives["rosbag1"] / "drive.bag")}
    (tmp_path / "dataset.yaml").write_text(yaml.safe_dump(man))
    with pytest.raises(ConfigError, match=r"dataset\.yaml:\d+: T_imu_cam0: .*missing\.bag: no such file"):
        load_dataset(tmp_path / "dataset.yaml")
    # keys the bag streams do not read were ignored: an 'invert: true' (the transform taken as written), an IMU's
    # std_m, a GNSS child_frame (found by a review with its own bags)
    lidar["T_imu_cam0"] = {"tf_static": ["cam0", "imu_link"], "bag": str(drives["rosbag1"] / "drive.bag"), "invert": True}
    man["streams"]["lidar"] = {**lidar, "path": str(drives["rosbag1"] / "drive.bag")}
    (tmp_path / "dataset.yaml").write_text(yaml.safe_dump(man))
    with pytest.raises(ConfigError, match="unknown key 'invert' in T_imu_cam0 .*swap the two frames"):
        load_dataset(tmp_path / "dataset.yaml")
    man["streams"]["lidar"]["T_imu_cam0"].pop("invert")
    man["streams"]["imu"]["std_m"] = 0.5
    (tmp_path / "dataset.yaml").write_text(yaml.safe_dump(man))
    with pytest.raises(ConfigError, match="unknown key 'std_m' in stream 'imu'"):
        load_dataset(tmp_path / "dataset.yaml")


def test_a_plain_euroc_folder_needs_no_manifest(drives, tmp_path):
    seq = tmp_path / "V1_sim"
    shutil.copytree(drives["euroc"] / "mav0", seq / "mav0")
    ds = load_dataset(seq)
    ref = load_dataset(drives["euroc"])
    assert np.array_equal(ds.imu.f_b_mps2, ref.imu.f_b_mps2) and np.array_equal(ds.groundtruth.p_w_m, ref.groundtruth.p_w_m)
    assert ds.gnss is None and ds.lidar is None and "(implicit EuRoC manifest)" in ds.description["manifest"]
    assert ds.description["config"] == {"filter": {"lidar_update": "none", "use_gnss": False}}
    m = fe.run(seq).metrics                      # runs as it is: dead reckoning, said so in the log
    assert m["estimates"]["fused"]["matched_poses"] > 100
    assert load_dataset(seq / "mav0").imu.t_s.size == ds.imu.t_s.size        # the mav0 folder itself works too


def _manifest(root, streams: dict, **top) -> object:
    body = {"name": "t", "streams": streams, **top}
    (root / "dataset.yaml").write_text(yaml.safe_dump(body, sort_keys=False))
    return root / "dataset.yaml"


def test_csv_streams_units_time_units_and_frames(drives, tmp_path):
    src = load_dataset(drives["csv_log"])
    t_ns = np.round(src.imu.t_s * 1e9).astype(np.int64)
    imu = np.column_stack([src.imu.w_b_rps * 180 / np.pi, src.imu.f_b_mps2 / 9.80665])
    (tmp_path / "imu.txt").write_text("# my logger\nstamp gx gy gz ax ay az\n" + "\n".join(
        f"{n} " + " ".join(f"{v:.17g}" for v in row) for n, row in zip(t_ns, imu)) + "\n")
    gt = src.groundtruth
    (tmp_path / "gt.csv").write_text("\n".join(",".join(f"{v:.17g}" for v in [t, *p, *q, 0.0]) for t, p, q in
                                               zip(gt.t_s, gt.p_w_m, gt.q_wb_xyzw)) + "\n")
    # the lidar stream in its own frame 'velo', given by its pose in the IMU frame
    man = yaml.safe_load((drives["csv_log"] / "dataset.yaml").read_text())
    T_c_b = np.eye(4)
    T_c_b[:3, :] = np.reshape(man["streams"]["lidar"]["T_cam0_imu"], (3, 4))
    T_imu_velo = np.linalg.inv(T_c_b)
    shutil.copy(drives["csv_log"] / "lidar.csv", tmp_path / "lidar.csv")
    p = _manifest(tmp_path, {
        "imu": {"format": "csv", "path": "imu.txt", "delimiter": " ", "time_unit": "ns", "gyro_unit": "deg/s", "accel_unit": "g",
                "columns": ["t", "wx", "wy", "wz", "ax", "ay", "az"]},
        "groundtruth": {"format": "csv", "path": "gt.csv", "columns": ["t", "x", "y", "z", "qx", "qy", "qz", "qw", "_unused"]},
        "lidar": {"format": "csv", "path": "lidar.csv", "columns": ["t", "x", "y", "z", "qx", "qy", "qz", "qw"],
                  "frame": "velo", "T_imu_velo": [float(x) for x in T_imu_velo[:3, :].ravel()]}})
    ds = load_dataset(p)
    assert np.abs(ds.imu.t_s - src.imu.t_s).max() < 1e-6 and np.allclose(ds.imu.w_b_rps, src.imu.w_b_rps, atol=1e-15)
    assert np.allclose(ds.imu.f_b_mps2, src.imu.f_b_mps2, atol=1e-14)
    assert np.array_equal(ds.groundtruth.p_w_m, gt.p_w_m)
    assert np.abs(ds.lidar.p_w_m - src.lidar.p_w_m).max() < 1e-9


@pytest.mark.parametrize("unit,per_ns", [("ms", 1_000_000), ("us", 1_000)])
@pytest.mark.parametrize("t_first", [True, False], ids=["t_first", "t_last"])
def test_csv_stamps_in_decimal_milliseconds_and_microseconds_are_read_exactly(tmp_path, unit, per_ns, t_first):
    """A 400 Hz logger in ms writes 0, 2.5, 5, 7.5: with t first such a file was refused ('the stamp must be an
    integer number of nanoseconds'), with t elsewhere its stamps were rounded to whole ms with no word (found by a
    review with its own CSV logs)."""
    from fusion_eval.datasets._text import ns_to_s

    n = 40
    ns = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 2_500_000 + 123      # epoch, 2.5 ms apart
    stamps = [f"{v // per_ns}.{v % per_ns:0{len(str(per_ns)) - 1}d}" for v in ns.tolist()]
    body = ["0,0,9.8,0,0,0"] * n
    rows = [f"{t},{b}" if t_first else f"{b},{t}" for t, b in zip(stamps, body)]
    (tmp_path / "imu.csv").write_text("\n".join(rows) + "\n")
    cols = ["ax", "ay", "az", "wx", "wy", "wz"]
    imu = {"format": "csv", "path": "imu.csv", "time_unit": unit, "columns": ["t", *cols] if t_first else [*cols, "t"]}
    ds = load_dataset(_manifest(tmp_path, {"imu": imu}))
    assert np.array_equal(ds.imu.t_s, ns_to_s(ns)), (ds.imu.t_s - ns_to_s(ns))
    assert np.allclose(ds.imu.f_b_mps2[:, 2], 9.8)
    rows[7] = rows[7].replace(stamps[7], f"{ns[7] / per_ns:.15e}")        # an exponent: read as a float
    (tmp_path / "imu.csv").write_text("\n".join(rows) + "\n")
    assert abs(load_dataset(_manifest(tmp_path, {"imu": imu})).imu.t_s[7] - ns_to_s(ns[7:8])[0]) < 1e-6
    rows[7] = rows[7].replace(f"{ns[7] / per_ns:.15e}", "soon")
    (tmp_path / "imu.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(DataFormatError, match=r"imu.csv:8: .*expected a number, got 'soon'"):
        load_dataset(_manifest(tmp_path, {"imu": imu}))
    # an inf or a stamp beyond int64's nanoseconds: named, not wrapped (a review of the diff)
    for bad, why in (("inf", "values must be finite numbers"), ("99999999999999999", "beyond any date")):
        rows[7] = ",".join(bad if i == (0 if t_first else 6) else x for i, x in enumerate(rows[7].split(",")))
        (tmp_path / "imu.csv").write_text("\n".join(rows) + "\n")
        with pytest.raises(DataFormatError, match=rf"imu.csv:8: .*{why}"):
            load_dataset(_manifest(tmp_path, {"imu": imu}))


def test_csv_stream_errors_name_the_file_line_and_expectation(tmp_path):
    (tmp_path / "imu.csv").write_text("t,ax,ay,az,wx,wy,wz\n1,0,0,9.8,0,0,0\n2,0,0,9.8,0,x,0\n")
    imu = {"format": "csv", "path": "imu.csv", "columns": ["t", "ax", "ay", "az", "wx", "wy", "wz"]}
    with pytest.raises(DataFormatError, match=r"imu.csv:3: .*expected a number, got 'x'"):
        load_dataset(_manifest(tmp_path, {"imu": imu}))
    with pytest.raises(ConfigError, match="'gyro' is not a imu column"):
        load_dataset(_manifest(tmp_path, {"imu": {**imu, "columns": ["t", "ax", "ay", "az", "gyro", "wy", "wz"]}}))
    with pytest.raises(ConfigError, match="needs the columns az"):
        load_dataset(_manifest(tmp_path, {"imu": {**imu, "columns": ["t", "ax", "ay", "_", "wx", "wy", "wz"]}}))
    with pytest.raises(ConfigError, match="time_unit must be one of"):
        load_dataset(_manifest(tmp_path, {"imu": {**imu, "time_unit": "fortnights"}}))
    with pytest.raises(ConfigError, match="unknown key 'colums'"):
        load_dataset(_manifest(tmp_path, {"imu": {"format": "csv", "path": "imu.csv", "colums": []}}))
    (tmp_path / "imu.csv").write_text("t,ax,ay,az,wx,wy,wz\n1,0,0,9.8,0,0,0\n2,0,0,9.8,0,0\n")
    with pytest.raises(DataFormatError, match=r"imu.csv:3: .*must have 7 values per row, got 6"):
        load_dataset(_manifest(tmp_path, {"imu": imu}))
    with pytest.raises(ConfigError, match=r"frame 'velo' needs T_imu_velo"):
        (tmp_path / "imu.csv").write_text("t,ax,ay,az,wx,wy,wz\n1,0,0,9.8,0,0,0\n2,0,0,9.8,0,0,0\n")
        (tmp_path / "l.csv").write_text("1,0,0,0,0,0,0,1\n2,1,0,0,0,0,0,1\n")
        load_dataset(_manifest(tmp_path, {"imu": imu, "lidar": {"format": "csv", "path": "l.csv", "frame": "velo",
                                                                "columns": ["t", "x", "y", "z", "qx", "qy", "qz", "qw"]}}))


def test_euroc_imu_with_a_broken_row(tmp_path):
    d = tmp_path / "seq" / "mav0" / "imu0"
    d.mkdir(parents=True)
    (d / "data.csv").write_text("#timestamp [ns],w_RS_S_x,w_RS_S_y,w_RS_S_z,a_RS_S_x,a_RS_S_y,a_RS_S_z\n"
                                "1403715273262142976,0.1,0.2,0.3,9.1,0.1,0.2\n1403715273267142912,0.1,0.2,0.3,9.1,0.1\n")
    with pytest.raises(DataFormatError, match=r"data.csv:3: .*must have 7 values per row, got 6"):
        load_dataset(tmp_path / "seq")


@pytest.mark.slow
def test_the_readmes_manifests(drives):
    """The README's "Your own data" manifests, copied from it, run as written on the simulated drive of their layout
    (with the default configuration: they carry no suggested settings), and fusion beats the lidar and the GNSS."""
    import re
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    blocks = re.findall(r"```yaml\n# your-own-data: (\w+)\n(.*?)```", readme, re.S)
    assert {b[0] for b in blocks} == {"euroc", "rosbag1", "csv_log"}
    for layout, body in blocks:
        path = drives[layout] / "readme.yaml"
        path.write_text(body)
        ds = load_dataset(path)
        ref = load_dataset(drives[layout])
        assert np.array_equal(ds.imu.t_s, ref.imu.t_s) and ds.gnss is not None
        if ds.lidar is not None:
            assert np.abs(ds.lidar.p_w_m - ref.lidar.p_w_m).max() < 1e-5        # the README's rounded extrinsic
        r = fe.run(path).metrics
        fused = r["estimates"]["fused"]["ape"]["translation_m"]["rmse"]
        assert fused < r["estimates"]["gnss"]["ape"]["translation_m"]["rmse"], layout
        if ds.lidar is not None:
            assert fused < r["estimates"]["lidar"]["ape"]["translation_m"]["rmse"], layout
        # the GNSS as accurate as through the simulator's own manifest (a wrong geodetic origin offsets it by metres)
        own = fe.run(drives[layout]).metrics["estimates"]["gnss"]["ape"]["translation_m"]["rmse"]
        assert r["estimates"]["gnss"]["ape"]["translation_m"]["rmse"] == pytest.approx(own, rel=1e-9), layout


@pytest.mark.slow
def test_the_readmes_bag_without_its_groundtruth_line_runs_from_the_data(drives):
    """A robot's bag has no truth: the README's rosbag1 manifest without its groundtruth line runs (the start from the
    data, the lidar anchored on it), and its fused estimate, scored afterwards against the simulator's truth, lies
    within 1.5x (and 0.3 m) of the run with the truth and under the GNSS alone."""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    body = dict(re.findall(r"```yaml\n# your-own-data: (\w+)\n(.*?)```", readme, re.S))["rosbag1"]
    blind = re.sub(r"  groundtruth: [^\n]+\n", "", body)
    assert blind != body
    (drives["rosbag1"] / "blind.yaml").write_text(blind, encoding="utf-8")
    (drives["rosbag1"] / "seen.yaml").write_text(body, encoding="utf-8")
    a = fe.run(drives["rosbag1"] / "blind.yaml")
    b = fe.run(drives["rosbag1"] / "seen.yaml")
    assert a.metrics["ground_truth"] is False and a.metrics["preprocessing"]["init_state"]["pose_from"] == "data"
    m = fe.evaluate(b.trajectories["groundtruth"], a.trajectories["fused"])
    blind_ape = next(iter(m["estimates"].values()))["ape"]["translation_m"]["rmse"]
    seen = b.metrics["estimates"]
    assert blind_ape < max(1.5 * seen["fused"]["ape"]["translation_m"]["rmse"],
                           seen["fused"]["ape"]["translation_m"]["rmse"] + 0.3), (blind_ape, seen["fused"]["ape"])
    assert blind_ape < seen["gnss"]["ape"]["translation_m"]["rmse"]


@pytest.mark.parametrize("edit,needle", [
    (lambda e: e.__setitem__("delimiter", ""), "delimiter must be a non-empty string"),       # once a ValueError traceback
    (lambda e: e.__setitem__("columns", ["t", "ax", "ax", "az", "wx", "wy", "wz"]), "csv column 'ax' is named twice"),
], ids=["empty-delimiter", "repeated-column"])
def test_a_csv_entry_that_cannot_be_read_is_named_with_its_line(drives, tmp_path, edit, needle):
    man = yaml.safe_load((drives["csv_log"] / "dataset.yaml").read_text())
    shutil.copytree(drives["csv_log"], tmp_path, dirs_exist_ok=True)      # every stream's file is there
    edit(man["streams"]["imu"])
    (tmp_path / "dataset.yaml").write_text(yaml.safe_dump(man, sort_keys=False))
    with pytest.raises(ConfigError, match=r"dataset\.yaml:\d+: " + re.escape(needle)):
        load_dataset(tmp_path)


def test_outages_apply_to_a_receivers_gnss_too(drives):
    """A receiver's fixes (not marked for degradation) get no noise and keep their rate, but gnss.outages_s is the
    user's experiment and applies: it was silently ignored, the run the same as without it."""
    m = fe.run(drives["csv_log"], overrides={"gnss.outages_s": [[0.0, 20.0]]}).metrics
    info = m["gnss_degradation"]
    assert info["degraded"] is False and info["fixes_in_outages"] >= 19 and info["outages_s"] == [[0.0, 20.0]]
    full = fe.run(drives["csv_log"]).metrics["gnss_degradation"]
    assert info["fixes_used"] == full["fixes_used"] - info["fixes_in_outages"]


def test_a_ground_truth_without_velocity_starts_the_filter_from_its_positions(drives, tmp_path):
    """A EuRoC / TUM-VI ground truth of poses only (8 columns: a motion capture's): the initial velocity comes from
    its positions differenced around the start, where the run once stopped ('needs a ground truth with velocity
    (KITTI OXTS)'), so a plain TUM-VI folder never ran by default."""
    src = drives["euroc"]
    dst = tmp_path / "eu"
    shutil.copytree(src, dst)
    gt = dst / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    lines = gt.read_text().splitlines()
    gt.write_text("\n".join(",".join(ln.split(",")[:8]) for ln in lines) + "\n")
    full, cut = fe.run(src).metrics, fe.run(dst).metrics
    assert "differenced" in cut["preprocessing"]["init_velocity"] and "init_velocity" not in full["preprocessing"]
    a, b = (m["estimates"]["fused"]["ape"]["translation_m"]["rmse"] for m in (full, cut))
    assert b == pytest.approx(a, rel=0.02), (a, b)


def _decimal_to_ns_numpy(text, per_ns):
    """The numpy-string implementation ``_text.decimal_to_ns`` had before its compiled pass: the test's oracle."""
    s = np.char.strip(np.asarray(text, dtype=str))
    neg = np.char.startswith(s, "-")
    s = np.where(neg | np.char.startswith(s, "+"), np.char.lstrip(s, "+-"), s)
    parts = np.char.partition(s, ".")
    ip, fp = parts[..., 0], parts[..., 2]
    digits = len(str(per_ns)) - 1
    bad = ~((np.char.isdigit(ip) | (ip == "")) & (np.char.isdigit(fp) | (fp == "")) & ((ip != "") | (fp != "")))
    ip = np.where(bad | (ip == ""), "0", ip)
    first = np.char.ljust(np.where(bad, "", fp), digits + 1, "0").astype(f"U{digits + 1}").astype(np.int64)
    ns = ip.astype(np.int64) * per_ns + first // 10 + (first % 10 >= 5)
    return np.where(neg, -ns, ns), bad


@pytest.mark.parametrize("per_ns", [1_000_000, 1_000])
def test_compiled_decimal_stamps_equal_the_numpy_string_reading(per_ns):
    """The compiled stamp reader gives the nanoseconds and the flags of the numpy string functions it replaced
    (1.6 s -> 20 ms for an hour at 200 Hz), on plain, signed, padded, rounded and malformed stamps."""
    from fusion_eval.datasets._text import decimal_to_ns

    rng = np.random.default_rng(3)
    whole = rng.integers(0, 1_700_000_000_000, 300)
    frac = rng.integers(0, 10 ** 9, 300)
    text = [f"{w}.{f:09d}"[: rng.integers(len(str(w)) + 1, len(str(w)) + 11)] for w, f in zip(whole, frac)]
    text += ["0", "12", "12.", ".5", "-3.25", "+7.5", " 42.125 ", "1.0000005", "1.0000004999", "0.0000000",
             "1e3", "1.2.3", "-", "+", ".", "", "abc", "12a", "1 2", "1.5\r"]
    ns, bad = decimal_to_ns(np.array(text), per_ns)
    ref_ns, ref_bad = _decimal_to_ns_numpy(np.array(text), per_ns)
    assert np.array_equal(bad, ref_bad), [t for t, a, b in zip(text, bad, ref_bad) if a != b]
    assert np.array_equal(ns[~bad], ref_ns[~ref_bad])
    # where the numpy reading was wrong, flagged for the careful path: two signs (read as -1) and other scripts'
    # digits; and beyond int64's nanoseconds, not wrapped
    assert decimal_to_ns(np.array(["--1", "+-2", "\u0661\u0662"]), per_ns)[1].all()
    assert decimal_to_ns(np.array(["99999999999999999999"]), per_ns)[1].all()
    assert decimal_to_ns(np.array([], dtype=str), per_ns)[0].size == 0


def test_a_skipped_csv_column_may_hold_text(tmp_path):
    """A ROS export's frame_id column was refused ('expected a number, got imu_link') though the manifest skips it
    with '_' (an own-data review); the columns read stay checked, through both of the readers."""
    rows = [f"{1.0 + 0.01 * i:.2f},imu_link,0,0,9.8,0,0,0.1" for i in range(40)]
    (tmp_path / "imu.csv").write_text("t,frame_id,ax,ay,az,wx,wy,wz\n" + "\n".join(rows) + "\n")
    imu = {"format": "csv", "path": "imu.csv", "columns": ["t", "_frame", "ax", "ay", "az", "wx", "wy", "wz"]}
    ds = load_dataset(_manifest(tmp_path, {"imu": imu}))
    assert np.allclose(ds.imu.f_b_mps2[:, 2], 9.8) and np.allclose(ds.imu.w_b_rps[:, 2], 0.1) and len(ds.imu.t_s) == 40
    rows.insert(10, "# a comment line: the line-by-line reader")
    rows[20] = rows[20].replace(",0.1", ",x")
    (tmp_path / "imu.csv").write_text("t,frame_id,ax,ay,az,wx,wy,wz\n" + "\n".join(rows) + "\n")
    with pytest.raises(DataFormatError, match=r"imu.csv:22: .*expected a number, got 'x'"):
        load_dataset(_manifest(tmp_path, {"imu": imu}))


def _written_pairs(manifest: Path) -> set:
    streams = yaml.safe_load(manifest.read_text(encoding="utf-8"))["streams"]
    return {(e["format"], s) for s, e in streams.items()}


def test_every_registered_format_reads_each_stream_it_declares(tmp_path):
    """The registry walked: every (format, stream) pair a format or an observation's stream declares is read here, by
    a simulator layout (whose round trips the slow test above holds to 1e-12), the shipped kitti-00 manifest, or a
    round trip below of the simulated drive's own series; a format added without any of these fails here by name."""
    from fusion_eval.datasets import formats
    from fusion_eval.datasets.tum import format_tum
    from fusion_eval.filters.observations import extra_streams

    declared = {(name, stream) for name, fmt in formats.formats().items() for stream in fmt.readers}
    declared |= {(name, spec.name) for spec in extra_streams() for name in spec.readers}
    covered = set()
    for layout in ("kitti", *LAYOUTS):
        simulate(tmp_path / layout, "urban", 2.0, seed=3, grade="automotive", sets=(f"output.layout={layout}",))
        covered |= _written_pairs(tmp_path / layout / "dataset.yaml")
    shipped = Path(__file__).resolve().parents[1] / "data" / "kitti-00" / "dataset.yaml"
    covered |= _written_pairs(shipped)
    load_dataset(shipped)                                   # (its streams read: test_readers holds their values)

    ref = load_dataset(tmp_path / "kitti")
    d = tmp_path / "kitti"
    (d / "gt.tum").write_text(format_tum(ref.groundtruth), encoding="utf-8")
    (d / "lidar.tum").write_text(format_tum(ref.lidar), encoding="utf-8")
    (d / "gnss.tum").write_text(format_tum(replace(ref.groundtruth, t_s=ref.gnss.t_s, p_w_m=ref.gnss.p_w_m,
                                                   q_wb_xyzw=np.tile([0.0, 0, 0, 1], (ref.gnss.t_s.size, 1)),
                                                   v_w_mps=None, lines=None)), encoding="utf-8")
    T = np.tile(np.eye(4), (len(ref.groundtruth), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = quat_xyzw_to_matrix(ref.groundtruth.q_wb_xyzw), ref.groundtruth.p_w_m
    np.savetxt(d / "gt_kitti.txt", T[:, :3, :].reshape(-1, 12), fmt="%.17g")
    np.savetxt(d / "gt_times.txt", ref.groundtruth.t_s, fmt="%.9f")
    ns = np.round(ref.gnss.t_s * 1e9).astype(np.int64)
    (d / "leica.csv").write_text("#timestamp [ns],p_x [m],p_y [m],p_z [m]\n" + "".join(
        f"{t},{x!r},{y!r},{z!r}\n" for t, (x, y, z) in zip(ns, ref.gnss.p_w_m.tolist())), encoding="utf-8")
    trips = {("tum", "groundtruth"): {"path": "gt.tum"}, ("tum", "lidar"): {"path": "lidar.tum", "frame": "imu"},
             ("tum", "gnss"): {"path": "gnss.tum", "std_m": 1.5},
             ("kitti_poses", "groundtruth"): {"path": "gt_kitti.txt", "times": {"file": "gt_times.txt"}, "frame": "imu"},
             ("euroc", "gnss"): {"path": "leica.csv", "std_m": 1.5}}
    imu = yaml.safe_load((d / "dataset.yaml").read_text(encoding="utf-8"))["streams"]["imu"]
    for (fmt, stream), entry in trips.items():
        (d / "trip.yaml").write_text(yaml.safe_dump({"name": "trip", "streams": {"imu": imu, stream: {"format": fmt, **entry}}}),
                                     encoding="utf-8")
        got, want = getattr(load_dataset(d / "trip.yaml"), stream), getattr(ref, stream)
        assert np.abs(got.t_s - want.t_s).max() < 1e-9 and np.abs(got.p_w_m - want.p_w_m).max() < 1e-6, (fmt, stream)
        if stream == "gnss":
            assert np.all(got.std_w_m == 1.5), fmt
        else:
            assert np.abs(quat_xyzw_to_matrix(got.q_wb_xyzw) - quat_xyzw_to_matrix(want.q_wb_xyzw)).max() < 1e-6, (fmt, stream)
    unread = sorted(declared - covered - trips.keys())
    assert not unread, f"registered (format, stream) pairs that nothing reads in the tests: {unread}"
    assert not (trips.keys() & covered), "a round trip here duplicates a layout's"
