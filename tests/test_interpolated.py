"""A KITTI drive as a bag or a CSV delivers it: IMU samples a provider interpolated, found in the values where the
format cannot mark them (the same samples as KITTI's own marks, the same run, nothing found in real or simulated
measurements), and what such a drive's manifest and report say (from a kitti2bag user trial)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import fusion_eval as fe
from fusion_eval.datasets.interpolated import MAX_SHARE, interpolated_imu, linear_runs
from fusion_eval.datasets.kitti_oxts import imu_from_oxts, read_oxts
from fusion_eval.types import ImuSeries

from conftest import shared_path

RAW = shared_path("kitti-raw")


def _imu(values: np.ndarray, filled=None) -> ImuSeries:
    t = 0.01 * np.arange(values.shape[0])
    return ImuSeries(t_s=t, f_b_mps2=values[:, :3], w_b_rps=values[:, 3:], filled=filled)


def _noisy(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v = rng.normal(0.0, 0.05, (n, 6))
    v[:, 2] += 9.81
    return v


def test_a_ramp_between_two_real_samples_is_found_and_nothing_else():
    v = _noisy(200)
    a, b = 50, 60                                     # samples 51-59 filled: a straight line from 50 to 60
    for i in range(a + 1, b):
        v[i] = v[a] + (v[b] - v[a]) * (i - a) / (b - a)
    mask = linear_runs(v)
    assert np.array_equal(np.flatnonzero(mask), np.arange(a + 1, b))


def test_one_sample_alone_on_its_neighbours_line_is_left():
    v = _noisy(100)
    v[40] = 0.5 * (v[39] + v[41])                     # one collinear triple: quantised data at rest makes these
    assert not linear_runs(v).any()
    v[40] = v[39] + (v[42] - v[39]) / 3.0            # ... not two in a row
    v[41] = v[39] + (v[42] - v[39]) * 2.0 / 3.0
    assert np.array_equal(np.flatnonzero(linear_runs(v)), [40, 41])


def test_samples_with_a_channel_that_does_not_change_are_not_a_providers_ramp():
    """A noise-free simulation's clothoid (yaw rate and lateral force ramp, the rest constant), a frozen reading, a
    quantised IMU at rest with one live channel stepping one LSB a sample: real measurements, none found (a review
    found 5 % of a clothoid drive and 1.1 % of a one-live-channel hour dropped when constant channels counted)."""
    n = 3000
    v = np.tile([0.0, 0.0, 9.81, 0.0, 0.0, 0.0], (n, 1))
    w = np.clip((np.arange(n) % 1000 - 200) * 1e-3, 0.0, 0.3)          # ramps up, holds, drops back
    v[:, 5], v[:, 1] = w, 10.0 * w
    assert not linear_runs(v).any()
    v = _noisy(100)
    v[20:40] = v[20]
    assert not linear_runs(v).any()
    v = np.tile([0.1, -0.2, 9.81, 0.01, 0.02, 0.03], (50, 1))
    v[:, 5] += 1e-3 * np.r_[np.zeros(10), np.arange(10), np.full(30, 9)]
    assert not linear_runs(v).any()
    v[:, :5] += _noisy(50, seed=3)[:, :5] * 1e-2                        # ... all channels live: a ramp is a ramp
    v[10:20, :5] = v[10, :5] + (v[19, :5] - v[10, :5]) * np.arange(10)[:, None] / 9.0
    assert np.array_equal(np.flatnonzero(linear_runs(v)), np.arange(11, 19))


def test_a_run_at_the_start_takes_the_first_sample():
    """KITTI extrapolates its first packets (0-13 on kitti-00): no real sample begins that line."""
    v = _noisy(100)
    slope = np.linspace(-1.0, 1.0, 6)
    v[:10] = v[10] - slope * np.arange(10, 0, -1)[:, None] * 0.01
    mask = linear_runs(v)
    assert mask[:10].all() and not mask[10:].any()


def test_a_run_at_the_end_takes_the_last_sample():
    v = _noisy(100)
    slope = np.linspace(0.5, 2.0, 6)
    v[90:] = v[89] + slope * np.arange(1, 11)[:, None] * 0.01
    mask = linear_runs(v)
    assert mask[90:].all() and not mask[:90].any()


def test_a_stream_mostly_on_lines_is_kept_and_said():
    """An IMU upsampled by linear interpolation (every 5th sample real) is the stream's nature, not a repair."""
    real = _noisy(41)
    v = np.vstack([real[k] + (real[k + 1] - real[k]) * j / 5.0 for k in range(40) for j in range(5)] + [real[40]])
    mask, said = interpolated_imu(_imu(v))
    assert linear_runs(v).mean() > MAX_SHARE
    assert not mask.any() and "kept as measurements" in said and "upsampled" in said and "% of the stream" in said


def test_samples_the_provider_marked_are_not_counted_again():
    v = _noisy(100)
    for i in range(31, 40):
        v[i] = v[30] + (v[40] - v[30]) * (i - 30) / 10
    marked = np.zeros(100, bool)
    marked[31:40] = True
    mask, said = interpolated_imu(_imu(v, filled=marked))
    assert not mask.any() and said is None
    mask, said = interpolated_imu(_imu(v))
    assert mask.sum() == 9 and "9 samples in 1 run(s)" in said


@pytest.mark.skipif(not RAW.is_dir(), reason="needs ../shared/data/kitti-raw (the real KITTI OXTS drives)")
def test_the_real_drives_filled_packets_are_found_from_their_values_alone():
    """On every real drive: the samples found are KITTI's own filled-in packets (where not alone: 0018's packet 2162
    is a run of one) and no real packet; a drive without filled packets gets none."""
    seen = 0
    for drive in sorted(RAW.glob("*/*_sync")):
        imu = imu_from_oxts(read_oxts(drive / "oxts"))
        found = linear_runs(np.hstack([imu.f_b_mps2, imu.w_b_rps]))
        assert not (found & ~imu.filled).any(), drive.name          # no real packet taken
        idx = np.flatnonzero(imu.filled)
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if idx.size else []
        for r in runs:
            assert found[r].all() == (r.size > 1), (drive.name, r[0], r.size)
        seen += int(found.sum())
    assert seen > 100


@pytest.mark.slow
def test_a_kitti_drive_without_its_marks_runs_as_with_them(kitti_slice, tmp_path):
    """kitti-00 (its first 90 s, filled packets 0-13 and 347-361) with the IMU's marks removed, as a bag or a CSV
    delivers it: the same fused estimate to the last bit, and the report says what was found; with the marks kept
    ('keep') the drive's filled packets are integrated as measurements (the full kitti-00: 1.55 m against 0.753)."""
    ds = fe.load_dataset(kitti_slice)
    streams = {**ds.description["streams"], "gnss": {**ds.description["streams"]["gnss"], "format": "rosbag"}}
    bare = replace(ds, imu=replace(ds.imu, filled=None), description={**ds.description, "streams": streams})
    a, b = fe.run(ds), fe.run(bare)
    ape = lambda r: r.metrics["estimates"]["fused"]["ape"]["translation_m"]["rmse"]       # noqa: E731
    assert ape(b) == ape(a)
    pre = b.metrics["preprocessing"]
    assert pre["imu_filled_samples"] == int(ds.imu.filled.sum()) and pre["imu_filled_found"] == pre["imu_filled_samples"]
    assert any("lie exactly on the straight line" in w and "imu.filled_packets: drop" in w for w in pre["data_warnings"])
    kept = fe.run(bare, overrides={"imu.filled_packets": "keep"})
    assert ape(kept) > 1.1 * ape(a)
    assert any("imu.filled_packets: keep: used as measurements" in w for w in kept.metrics["preprocessing"]["data_warnings"])
    b.write(tmp_path / "out")
    line = next(x for x in (tmp_path / "out" / "report.md").read_text(encoding="utf-8").splitlines()
                if x.startswith("- Filled-in IMU packets"))
    assert f"{pre['imu_filled_found']} of them found as exact straight lines" in line
    # a bag's fixes marked for degradation are not called KITTI's OXTS solution (a kitti2bag trial)
    md = (tmp_path / "out" / "report.md").read_text(encoding="utf-8")
    assert "The GNSS stream was degraded, as the manifest marks it" in md and "KITTI's OXTS position is" not in md
    inn = b.metrics["innovations"]
    assert f"negative log-likelihood per update {inn['nll_per_update']:.4f} over {inn['updates']} updates" in md
    a.write(tmp_path / "raw")
    assert "KITTI's OXTS position is the GPS/INS solution" in (tmp_path / "raw" / "report.md").read_text(encoding="utf-8")


def test_kitti_odometry_times_beside_an_imu_read_from_a_csv_say_what_to_write(kitti_slice, tmp_path):
    """times.align_to: imu pairs frames with OXTS packets; with the IMU from a CSV (or a bag) the error said 'give
    times.file instead' to a user who had given it (a kitti2bag trial): it now says to drop align_to and use t0_s."""
    import shutil

    import yaml

    from fusion_eval.errors import ConfigError

    root = tmp_path / "k"
    shutil.copytree(kitti_slice, root)
    imu = imu_from_oxts(read_oxts(root / "oxts"))
    np.savetxt(root / "imu.csv", np.column_stack([imu.t_s, imu.f_b_mps2, imu.w_b_rps]), fmt="%.17g", delimiter=",",
               header="t,ax,ay,az,wx,wy,wz", comments="")
    m = yaml.safe_load((root / "dataset.yaml").read_text(encoding="utf-8"))
    m["streams"]["imu"] = {"format": "csv", "path": "imu.csv", "columns": ["t", "ax", "ay", "az", "wx", "wy", "wz"]}
    assert "file" in m["streams"]["lidar"]["times"] and m["streams"]["lidar"]["times"].get("align_to") == "imu"
    (root / "dataset.yaml").write_text(yaml.safe_dump(m, sort_keys=False), encoding="utf-8")
    with pytest.raises(ConfigError, match="remove align_to and put the file on the IMU's clock with t0_s"):
        fe.load_dataset(root)
    del m["streams"]["lidar"]["times"]["file"]
    (root / "dataset.yaml").write_text(yaml.safe_dump(m, sort_keys=False), encoding="utf-8")
    with pytest.raises(ConfigError, match="give times.file with t0_s"):
        fe.load_dataset(root)
