"""Property-based fuzzing of every input kind (issue 15), with ``hypothesis``.

Each strategy corrupts one input: an OXTS packet, the packet stamps, a KITTI pose file, its times, a calibration file,
the manifest, a configuration item (``--set``), a sweep grid, a ``check`` baseline, a tracking file, a TUM trajectory
for ``evaluate``, a generic CSV stream, a EuRoC IMU file and a ROS bag (bytes flipped). For every example the command
must keep the contract: exit 0 with finite metrics, or exit 2 with one line (``error: ...``) that names the file, or
exit 3 (``error: filter diverged``); never a traceback, never a hang (each example has a time limit), never a partial
output directory.

The examples are derandomized (the same ones in every CI run) and bounded: ``--hypothesis-profile=ci`` (the
default, about 250 examples in all, 1-2 minutes) or ``--hypothesis-profile=long`` (ten times more).
"""

from __future__ import annotations

import json
import math
import shutil
import signal
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import make_slice

hypothesis = pytest.importorskip("hypothesis", reason="the fuzz suite needs hypothesis (pip install -e '.[test]')")
from hypothesis import given, strategies as st  # noqa: E402

from fusion_eval.cli import main  # noqa: E402

# the profiles ('ci', the default, and 'long') are registered in conftest.py, so that --hypothesis-profile chooses

TIME_LIMIT_S = 60
N_PACKETS = 80


@contextmanager
def time_limit(seconds: int):
    """A hang is a failure: SIGALRM interrupts the example."""
    def boom(signum, frame):
        raise TimeoutError(f"the command did not finish within {seconds} s (a hang)")
    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def contract(args: list[str], out: Path | None, names: tuple[str, ...] = ()) -> int:
    """Run the command in-process and check the contract; returns the exit code."""
    if out is not None and out.exists():
        shutil.rmtree(out)                   # an earlier example's result
    with time_limit(TIME_LIMIT_S):
        r = CliRunner().invoke(main, args)
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert "Traceback" not in r.output, r.output
    assert r.exit_code in (0, 1, 2, 3), (r.exit_code, r.output)
    if r.exit_code in (2, 3):
        err = r.stderr.strip().splitlines()
        assert err and err[-1].startswith("error: "), r.stderr
        if r.exit_code == 3:
            assert "diverged" in err[-1]
        elif names:
            assert any(n in err[-1] for n in names), (names, err[-1])
    if out is not None:
        if r.exit_code != 0:
            assert not out.exists(), "a failed command left its output directory"
        assert not list(out.parent.glob(f".{out.name}.partial*")), "a staging folder was left behind"
        if r.exit_code == 0 and (out / "metrics.json").exists():
            m = json.loads((out / "metrics.json").read_text())
            est = m.get("estimates")
            fused = est.get("fused") if isinstance(est, dict) else None
            if isinstance(fused, dict):              # run: the fused estimate was evaluated, with a finite error
                assert math.isfinite(fused["ape"]["translation_m"]["rmse"])
    return r.exit_code


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    """The slice, run once untimed: the first run in a process compiles numba's kernels (on a fresh install, with
    the other tests' processes compiling too, longer than TIME_LIMIT_S), which is not the hang the limit is for."""
    ds = make_slice(tmp_path_factory.mktemp("fuzz") / "ds", N_PACKETS)
    r = CliRunner().invoke(main, ["-q", "run", str(ds), "--out", str(ds.parent / "warm"), "--no-plots"])
    assert r.exit_code == 0, r.output
    return ds


@pytest.fixture
def fresh(pristine, tmp_path):
    """A pristine copy of the slice for each example (hypothesis runs many examples in one test call)."""
    def make() -> Path:
        d = tmp_path / "ds"
        if d.exists():
            shutil.rmtree(d)
        shutil.copytree(pristine, d)
        return d
    return make


def _run(ds: Path, tmp: Path, *extra: str, names=()) -> int:
    out = tmp / "out"
    return contract(["-q", "run", str(ds), "--out", str(out), "--no-plots", *extra], out, names)


TOKENS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64).map(repr),
    st.sampled_from(["", "abc", "1e309", "-1e309", "0x10", "1,5", "1e999999", "nan", "--", "9" * 40, "1e-320"]),
    st.integers(min_value=-10**25, max_value=10**25).map(str),
    st.text(max_size=6),
)


def _mutate_tokens(text: str, data, n_max: int = 3) -> str:
    """Replace, delete or duplicate a few whitespace-separated tokens of a text."""
    lines = text.splitlines() or [""]
    for _ in range(data.draw(st.integers(1, n_max))):
        i = data.draw(st.integers(0, len(lines) - 1))
        toks = lines[i].split()
        op = data.draw(st.sampled_from(["replace", "delete", "duplicate", "line_swap", "line_drop", "blank"]))
        if op == "replace" and toks:
            toks[data.draw(st.integers(0, len(toks) - 1))] = data.draw(TOKENS)
        elif op == "delete" and toks:
            del toks[data.draw(st.integers(0, len(toks) - 1))]
        elif op == "duplicate" and toks:
            toks.append(toks[-1])
        elif op == "line_swap" and len(lines) > 1:
            j = data.draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
            continue
        elif op == "line_drop" and len(lines) > 1:
            del lines[i]
            continue
        elif op == "blank":
            toks = []
        lines[i] = " ".join(toks)
    return "\n".join(lines) + "\n"


@pytest.mark.slow
@given(data=st.data())
def test_oxts_packets(fresh, tmp_path, data):
    ds = fresh()
    k = data.draw(st.integers(0, N_PACKETS - 1))
    p = ds / "oxts" / "data" / f"{k:010d}.txt"
    p.write_text(_mutate_tokens(p.read_text(), data))
    _run(ds, tmp_path, names=(p.name, "oxts"))


@given(data=st.data())
def test_packet_stamps(fresh, tmp_path, data):
    ds = fresh()
    p = ds / "oxts" / "timestamps.txt"
    lines = p.read_text().splitlines()
    i = data.draw(st.integers(0, len(lines) - 1))
    op = data.draw(st.sampled_from(["shift", "garbage", "drop", "swap"]))
    if op == "shift":
        date, hms = lines[i].split()
        sec = float(hms.split(":")[2]) + data.draw(st.floats(-100, 100))
        lines[i] = f"{date} {hms[:6]}{sec:012.9f}" if 0 <= sec < 60 else f"{date} {hms[:6]}99.000000000"
    elif op == "garbage":
        lines[i] = data.draw(TOKENS)
    elif op == "drop":
        del lines[i]
    else:
        j = data.draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
    p.write_text("\n".join(lines) + "\n")
    _run(ds, tmp_path, names=("timestamps.txt", "oxts", "data"))


@given(data=st.data())
def test_kitti_pose_file(fresh, tmp_path, data):
    ds = fresh()
    p = ds / "lidar" / "poses.txt"
    p.write_text(_mutate_tokens(p.read_text(), data))
    _run(ds, tmp_path, names=("poses.txt", "lidar"))


@given(data=st.data())
def test_pose_times(fresh, tmp_path, data):
    ds = fresh()
    p = ds / "lidar" / "times.txt"
    p.write_text(_mutate_tokens(p.read_text(), data, 2))
    _run(ds, tmp_path, names=("times.txt", "lidar"))


@pytest.mark.slow
@given(data=st.data())
def test_calibration(fresh, tmp_path, data):
    ds = fresh()
    p = ds / data.draw(st.sampled_from(["calib_imu_to_velo.txt", "lidar/calib.txt"]))
    p.write_text(_mutate_tokens(p.read_text(), data, 2))
    _run(ds, tmp_path, names=(p.name,))


YAML_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                        st.text(max_size=8), st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=13),
                        st.dictionaries(st.text(max_size=5), st.integers(), max_size=2))


@pytest.mark.slow
@given(data=st.data())
def test_manifest(fresh, tmp_path, data):
    ds = fresh()
    import yaml

    p = ds / "dataset.yaml"
    body = yaml.safe_load(p.read_text())
    paths = [(k,) for k in body] + [("streams", s, k) for s in body["streams"] for k in body["streams"][s]]
    path = data.draw(st.sampled_from(paths))
    node = body
    for k in path[:-1]:
        node = node[k]
    if data.draw(st.booleans()):
        del node[path[-1]]
    else:
        node[path[-1]] = data.draw(YAML_VALUES)
    p.write_text(yaml.safe_dump(body))
    _run(ds, tmp_path, names=("dataset.yaml", "manifest"))


@pytest.mark.slow
@given(data=st.data())
def test_config_set(fresh, tmp_path, data):
    ds = fresh()
    from fusion_eval.config import schema

    key = data.draw(st.sampled_from(sorted(schema())))
    value = data.draw(st.one_of(TOKENS, st.sampled_from(["[1, 2]", "[1, 2, 3]", "true", "auto", "null", "{a: 1}"])))
    _run(ds, tmp_path, "--set", f"{key}={value}", names=("--set", key))


@pytest.mark.slow
@given(data=st.data())
def test_sweep_grid(fresh, tmp_path, data):
    ds = fresh()
    grid = tmp_path / "grid.yaml"
    body = data.draw(st.sampled_from([
        "settings: {a: {imu.gyro_noise_dps_sqrthz: VALUE}}\n",
        "random: {n: VALUE, ranges: {imu.gyro_noise_dps_sqrthz: [0.001, 0.01]}}\n",
        "variants: VALUE\nsettings: {a: {imu.gyro_noise_dps_sqrthz: 0.01}}\n",
        "settings: VALUE\n",
        "plots: VALUE\nsettings: {a: {imu.gyro_noise_dps_sqrthz: 0.01}}\n",
    ])).replace("VALUE", data.draw(TOKENS).replace("\n", " ") or "''")
    grid.write_text(body)
    out = tmp_path / "sw"
    contract(["-q", "sweep", str(ds), "--grid", str(grid), "--out", str(out), "--jobs", "1"], None, ("grid.yaml", "sweep"))


@given(data=st.data())
def test_check_baseline(tmp_path, data):
    cur = {"estimates": {"fused": {"ape": {"translation_m": {"rmse": 1.0, "max": 3.0}}},
                         "lidar": {"ape": {"translation_m": {"rmse": 7.0}}}}, "ratios": {"fused_over_lidar": 0.14}}
    (tmp_path / "cur.json").write_text(json.dumps(cur))
    base = json.loads(json.dumps(cur))
    node = base["estimates"]["fused"]["ape"]["translation_m"]
    node["rmse"] = data.draw(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=4), st.none(),
                                       st.lists(st.integers(), max_size=2)))
    text = json.dumps(base)
    if data.draw(st.booleans()):
        cut = data.draw(st.integers(0, len(text)))
        text = text[:cut] + data.draw(st.text(max_size=3)) + text[cut:]
    (tmp_path / "base.json").write_text(text)
    contract(["check", str(tmp_path / "cur.json"), "--baseline", str(tmp_path / "base.json")], None, ("base.json",))


@given(data=st.data())
def test_tracking_file(tmp_path, data):
    lines = [f"L\t{1.0 + i * 0.1:.4f}\t{0.5:.4f}\t{1477010443000000 + i * 50000}\t1.0\t0.5\t5.0\t0.0" if i % 2 == 0 else
             f"R\t{1.2:.4f}\t{0.4:.4f}\t{5.0:.4f}\t{1477010443000000 + i * 50000}\t1.0\t0.5\t5.0\t0.0" for i in range(40)]
    f = tmp_path / "trk.txt"
    f.write_text(_mutate_tokens("\n".join(lines), data).replace(" ", "\t"))
    out = tmp_path / "o"
    contract(["-q", "track", str(f), "--out", str(out), "--no-plots"], out, ("trk.txt",))


@given(data=st.data())
def test_tum_trajectory_for_evaluate(tmp_path, data):
    ref = tmp_path / "ref.tum"
    ref.write_text("".join(f"{100 + i * 0.1:.3f} {i * 0.5} {np.sin(i / 9):.6f} 0 0 0 0 1\n" for i in range(60)))
    est = tmp_path / "est.tum"
    est.write_text(_mutate_tokens(ref.read_text(), data))
    out = tmp_path / "o"
    contract(["-q", "evaluate", str(ref), str(est), "--out", str(out), "--no-plots"], out, ("est.tum",))


@pytest.mark.slow
@given(data=st.data())
def test_generic_csv_stream(fresh, tmp_path, data):
    ds = fresh()
    import yaml

    from fusion_eval.datasets.kitti_oxts import imu_from_oxts, read_oxts

    imu = imu_from_oxts(read_oxts(ds / "oxts"))
    rows = [f"{t:.9f},{a[0]!r},{a[1]!r},{a[2]!r},{w[0]!r},{w[1]!r},{w[2]!r}" for t, a, w in zip(imu.t_s, imu.f_b_mps2, imu.w_b_rps)]
    text = "t,ax,ay,az,wx,wy,wz\n" + "\n".join(rows) + "\n"
    text = _mutate_tokens(text.replace(",", " "), data).replace(" ", ",")
    (ds / "imu.csv").write_text(text)
    body = yaml.safe_load((ds / "dataset.yaml").read_text())
    body["streams"]["imu"] = {"format": "csv", "path": "imu.csv", "columns": ["t", "ax", "ay", "az", "wx", "wy", "wz"]}
    (ds / "dataset.yaml").write_text(yaml.safe_dump(body))
    _run(ds, tmp_path, names=("imu.csv",))


@given(data=st.data())
def test_euroc_imu(tmp_path, data):
    seq = tmp_path / "seq" / "mav0" / "imu0"
    seq.mkdir(parents=True, exist_ok=True)
    rows = [f"{1403715273262142976 + i * 5000000},0.01,0.02,-0.01,9.79,0.1,-0.2" for i in range(50)]
    text = _mutate_tokens("\n".join(rows).replace(",", " "), data).replace(" ", ",")
    (seq / "data.csv").write_text("#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n" + text)
    from fusion_eval.datasets.manifest import load_dataset
    from fusion_eval.errors import FusionEvalError

    with time_limit(TIME_LIMIT_S):
        try:
            ds = load_dataset(tmp_path / "seq")
        except FusionEvalError as exc:
            assert "data.csv" in str(exc)
            return
    assert np.all(np.isfinite(ds.imu.f_b_mps2)) and np.all(np.diff(ds.imu.t_s) > 0)


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory) -> Path:
    from fusion_eval.datasets import rosbag
    from fusion_eval.types import ImuSeries, PoseSeries

    d = tmp_path_factory.mktemp("bag")
    rng = np.random.default_rng(0)
    n = 200
    t = 1.7e9 + np.arange(n) * 0.01
    imu = ImuSeries(t_s=t, f_b_mps2=rng.normal(size=(n, 3)), w_b_rps=rng.normal(size=(n, 3)) * 0.1)
    poses = PoseSeries(t_s=t[::10], p_w_m=rng.normal(size=(20, 3)), q_wb_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (20, 1)))
    rosbag.write_bag(d / "b.bag", "rosbag1", [rosbag.BagStream("/imu", "imu", imu, "imu"),
                                              rosbag.BagStream("/gt", "pose", poses, "map")])
    return d / "b.bag"


@given(data=st.data())
def test_bag_with_flipped_bytes(small_bag, tmp_path, data):
    from fusion_eval.datasets import rosbag
    from fusion_eval.errors import FusionEvalError

    raw = bytearray(small_bag.read_bytes())
    for _ in range(data.draw(st.integers(1, 8))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        raw = raw[:data.draw(st.integers(0, len(raw)))]
    bag = tmp_path / "b.bag"
    bag.write_bytes(bytes(raw))
    with time_limit(TIME_LIMIT_S):
        for read in (lambda: rosbag.read_imu(bag, "/imu"), lambda: rosbag.read_poses(bag, "/gt")):
            try:
                s = read()
            except FusionEvalError as exc:
                assert "b.bag" in str(exc), str(exc)
                continue
            assert np.all(np.isfinite(s.t_s))
