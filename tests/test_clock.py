"""The lidar frame clock recovered from the stamps of the IMU packets the frames were matched to."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import KITTI00, ROOT, shared_path
from fusion_eval.datasets import clock
from fusion_eval.datasets.kitti_oxts import read_oxts
from fusion_eval.errors import ConfigError


def test_quantised_stamps_with_a_drifting_period_and_glitches_are_recovered():
    rng = np.random.default_rng(0)
    n = 3000
    period = 0.1037 * (1 + 2e-3 * np.sin(np.arange(n) / 700))      # a slowly drifting scan period
    t_true = 100.0 + np.concatenate(([0.0], np.cumsum(period[:-1])))
    stamps = np.round(t_true / 0.01) * 0.01                          # nearest packet of a 100 Hz grid
    valid = np.ones(n, bool)
    valid[:14] = False                                               # filled packets at the start: ramps
    stamps[:14] = stamps[14] - 0.095 * np.arange(14, 0, -1)
    glitch = rng.choice(np.arange(100, n - 100), 5, replace=False)
    stamps[glitch] -= 0.024                                          # a packet stamped early
    t, info = clock.smooth_frame_times(stamps, valid, 5.0)
    err = t - t_true
    assert (stamps - t_true)[valid].std() > 2.5e-3
    assert np.sqrt(np.mean(err ** 2)) < 0.6e-3 and np.abs(err).max() < 2.5e-3, (np.sqrt(np.mean(err ** 2)), np.abs(err).max())
    assert info["glitches"] == 5
    assert 2.5 < info["residual_std_ms"] < 3.3                      # uniform +/- 5 ms: 2.9 ms


def test_kitti_00_oxts_stamps_smoothed_reproduce_its_times_file():
    # frame i of KITTI odometry seq 00 is raw packet i; its own times.txt is the independent reference
    raw = read_oxts(KITTI00 / "oxts")
    times = np.loadtxt(KITTI00 / "lidar" / "times.txt")
    n = min(times.size, raw.t_s.size)
    t, info = clock.smooth_frame_times(raw.t_s[:n], ~raw.filled[:n], 5.0)
    ok = ~raw.filled[:n]
    ref = times[:n] + np.median(raw.t_s[:n][ok] - times[:n][ok])
    raw_err = (raw.t_s[:n] - ref)[ok]
    err = (t - ref)[ok]
    err -= np.median(err)
    assert np.sqrt(np.mean(err ** 2)) < 0.5 * np.sqrt(np.mean((raw_err - np.median(raw_err)) ** 2))
    assert np.sqrt(np.mean(err ** 2)) < 1.5e-3, np.sqrt(np.mean(err ** 2))


def test_smoothing_is_a_manifest_choice_with_a_checked_value(tmp_path):
    from fusion_eval.datasets.manifest import load_dataset

    body = (ROOT / "configs" / "datasets" / "simple-06.yaml").read_text()
    shared_path("kitti-odometry-simple", "06")
    m = tmp_path / "m.yaml"
    m.write_text(body.replace("smooth_s: 5.0", "smooth_s: -1").replace("../../../shared", str(ROOT.parent / "shared")))
    with pytest.raises(ConfigError, match="smooth_s"):
        load_dataset(m)
    ds = load_dataset(ROOT / "configs" / "datasets" / "simple-06.yaml")
    c = ds.description["lidar_clock"]
    assert 2.0 < c["residual_std_ms"] < 4.0 and c["window_frames"] > 50
