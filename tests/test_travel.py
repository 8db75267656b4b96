"""The direction of travel in the IMU frame (``filter.nhc_travel_pitch_mrad: auto``), from poses alone."""

from __future__ import annotations

import re

import numpy as np
import pytest

from fusion_eval.calibration.travel import MIN_STRETCHES, estimate_travel_pitch, vehicle_axes
from fusion_eval.filters.observations.base import BODY_VELOCITY_ROW
from fusion_eval.so3 import exp_so3, matrix_to_quat_xyzw
from fusion_eval.types import PoseSeries


def _drive(pitch_mrad: float, seconds: float, rng, turn_every_s: float = 30.0) -> PoseSeries:
    """A car at 10 m/s on a hilly road, its IMU pitched ``pitch_mrad`` nose-down against the direction of travel,
    turning for 5 s every ``turn_every_s``; the poses carry 1 cm and 0.01 deg of noise."""
    dt = 0.1
    t = np.arange(0.0, seconds, dt)
    yaw = np.cumsum(np.where((t % turn_every_s) > turn_every_s - 5.0, 0.3, 0.0)) * dt
    grade = 0.03 * np.sin(2 * np.pi * t / 60.0)                     # the road's slope: climbing and descending
    d = np.stack([np.cos(yaw) * np.cos(grade), np.sin(yaw) * np.cos(grade), np.sin(grade)], axis=1) * 10.0 * dt
    p = np.cumsum(d, axis=0) + rng.normal(size=(t.size, 3)) * 0.01
    # body frame: along the travel direction, then pitched nose-down by the mount (a positive pitch of travel)
    R = np.stack([exp_so3(np.array([0.0, 0.0, y])) @ exp_so3(np.array([0.0, -g + pitch_mrad * 1e-3, 0.0]))
                  @ exp_so3(rng.normal(size=3) * np.radians(0.01)) for y, g in zip(yaw, grade)])
    return PoseSeries(t_s=t, p_w_m=p, q_wb_xyzw=matrix_to_quat_xyzw(R))


@pytest.mark.parametrize("pitch_mrad", [0.0, 12.0, -25.0])
def test_travel_pitch_is_recovered_on_a_hilly_drive_with_turns(pitch_mrad):
    est = estimate_travel_pitch(_drive(pitch_mrad, 300.0, np.random.default_rng(3)))
    assert est is not None and est.seconds > 100
    assert abs(est.pitch_mrad - pitch_mrad) < 0.5, est
    assert 0 < est.std_mrad < 0.5


def test_too_little_straight_driving_gives_no_estimate():
    # turning 5 s in every 6: under MIN_STRETCHES seconds of straight driving in the whole drive
    assert estimate_travel_pitch(_drive(10.0, 120.0, np.random.default_rng(1), turn_every_s=6.0)) is None
    assert estimate_travel_pitch(_drive(10.0, MIN_STRETCHES - 5.0, np.random.default_rng(1))) is None


def test_vehicle_axes_are_a_rotation_whose_x_axis_points_along_travel():
    A = vehicle_axes(0.012, -0.004)
    assert np.allclose(A @ A.T, np.eye(3)) and np.isclose(np.linalg.det(A), 1.0)
    assert np.allclose(A[0], [np.cos(0.012) * np.cos(-0.004), np.cos(0.012) * np.sin(-0.004), np.sin(0.012)])
    assert abs(A[1, 2]) < 1e-15                                     # the lateral axis stays in the IMU's x-y plane


# ---- on the real KITTI drive ----------------------------------------------------------------------------------

def _prepared(path, *sets):
    from fusion_eval import load_dataset, session
    from fusion_eval.prepare import prepare

    ds = load_dataset(path)
    cfg = session.resolve(session.request(sets=sets), ds)
    return prepare(ds, cfg), cfg


def test_kitti_travel_pitch_from_the_lidar_and_from_a_smoothed_imu_gnss_pass_match_the_ground_truths_own(kitti_slice):
    """The OXTS unit points 8-9 mrad below the direction of travel on this drive (the GPS/INS solution's own
    body-frame velocity says so); both blind estimates find it, neither reads the ground truth."""
    from fusion_eval.calibration.travel import pitch_from_smoothed_pass

    prep, cfg = _prepared(kitti_slice, "filter.nhc=true")
    truth = estimate_travel_pitch(prep.groundtruth)
    lid = prep.applied["nhc_travel"]
    assert "lidar" in lid["method"] and abs(lid["pitch_mrad"] - truth.pitch_mrad) < 2.5, (lid, truth)   # 7.4 vs 8.7
    assert prep.resolved["filter"]["nhc_travel_pitch_mrad"] == lid["pitch_mrad"]
    sm, why_not = pitch_from_smoothed_pass(prep, cfg)
    assert why_not == "" and "smoothed" in sm.method and abs(sm.pitch_mrad - truth.pitch_mrad) < 1.5, (sm, truth)      # 8.3 vs 8.7


def test_without_lidar_and_gnss_the_vertical_row_is_left_out_and_said():
    from conftest import shared_path
    from fusion_eval.filters.observations.nhc import OBSERVATION as NHC
    from fusion_eval.prepare import settings_for
    from fusion_eval.report.markdown import _estimates

    raw = shared_path("kitti-raw", "2011_09_30", "2011_09_30_drive_0027_sync")       # IMU + GNSS, no lidar
    prep, cfg = _prepared(raw, "filter.nhc=true", "filter.use_gnss=false", "filter.lidar_update=none")
    a = prep.applied["nhc_travel"]
    assert a["pitch_mrad"] is None and a["method"] == "no lidar stream; no GNSS fused"
    assert any("not estimated (no lidar stream; no GNSS fused); its vertical row is left out" in x for x in _estimates(prep.applied))
    b = NHC.bind(prep, settings_for(cfg, prep))
    assert b.dof == 1 and b.kernel.data[:, NHC_USED].tolist() == [[0.0, 1.0, 0.0]] * b.t_s.size


def test_a_given_pitch_is_used_as_it_is_and_nothing_is_estimated(kitti_slice):
    from fusion_eval.filters.observations.nhc import OBSERVATION as NHC
    from fusion_eval.prepare import settings_for

    prep, cfg = _prepared(kitti_slice, "filter.nhc=true", "filter.nhc_travel_pitch_mrad=12.5")
    assert "nhc_travel" not in prep.applied
    b = NHC.bind(prep, settings_for(cfg, prep))
    axes = b.kernel.data[0, NHC_AXES].reshape(3, 3)
    assert b.dof == 2 and np.allclose(axes, vehicle_axes(12.5e-3, 0.0))


@pytest.mark.slow
def test_on_kitti_the_constraint_along_the_estimated_travel_direction_beats_the_one_along_the_imus_axes():
    """SiMpLE 06, IMU + lidar without GNSS (configs/lidar-imu.yaml): the vertical row along the IMU's own z axis
    (the 13 mrad mount ignored) costs six times the error of the row along the estimated direction of travel
    (measured 1.344 and 0.214 m; the lidar alone 0.414)."""
    import fusion_eval as fe
    from conftest import ROOT, shared_path

    shared_path("kitti-odometry-simple", "06")
    ds = fe.load_dataset(ROOT / "configs" / "datasets" / "simple-06.yaml")
    base = {"filter.use_gnss": False, "imu.accel_noise_mps2_sqrthz": 0.3, "imu.gyro_noise_dps_sqrthz": 0.1}
    ape = {p: fe.run(ds, overrides={**base, "filter.nhc_travel_pitch_mrad": p}).metrics["estimates"]["fused"]
           ["ape"]["translation_m"]["rmse"] for p in ("auto", 0.0)}
    assert ape["auto"] < 0.3 * ape[0.0], ape


NHC_USED = BODY_VELOCITY_ROW.sl("used")
NHC_AXES = BODY_VELOCITY_ROW.sl("axes")


def test_the_estimated_direction_of_travel_makes_the_vertical_row_zero_for_a_car_driving_straight():
    """The estimator's sign and the constraint's axes agree: a car moving along its direction of travel violates
    neither row of the constraint built from the estimate (a sign slip would leave 2 x 12 mrad x 10 m/s)."""
    from fusion_eval.filters.observations.base import kernel_model
    from fusion_eval.filters.observations.nhc import nhc_kernel
    from fusion_eval.filters.state import NominalState

    est = estimate_travel_pitch(_drive(12.0, 300.0, np.random.default_rng(5)))
    axes = vehicle_axes(est.pitch_mrad * 1e-3, 0.0)
    R = exp_so3(np.array([0.0, -0.03, 0.7]))
    d = _drive(12.0, 300.0, np.random.default_rng(5))
    v_b = d.R_wb()[0].T @ (d.p_w_m[10] - d.p_w_m[0]) / 1.0          # the drive's body-frame velocity, over 1 s
    x = NominalState(np.zeros(3), R @ v_b, R, np.zeros(3), np.zeros(3))
    row = BODY_VELOCITY_ROW.pack(v=np.zeros(3), std=np.full(3, 0.1), used=[0.0, 1.0, 1.0], axes=axes.ravel())
    _, r, _ = kernel_model(nhc_kernel, x, row=row)
    assert np.abs(r).max() < 0.05, r                  # the poses' 1 cm noise over 1 s; 0.24 m/s with the sign flipped


@pytest.mark.parametrize("platform,sets,expected", [
    ("car", (), True),
    ("wheeled", (), True),
    (None, (), False),
    ("aerial", (), False),
    ("car", ("filter.nhc=false",), False),
    ("aerial", ("filter.nhc=true",), True),
    ("car", ("filter.process_model=odometer_gyro",), False),       # no velocity state: left out, not refused
    ("car", ("smoother.method=batch",), False),                    # no factor for it in the graph
])
def test_nhc_auto_follows_the_platform_where_the_configuration_can_take_it(kitti_slice, platform, sets, expected):
    from fusion_eval import load_dataset, session

    ds = load_dataset(kitti_slice)
    ds.description["platform"] = platform
    cfg = session.resolve(session.request(sets=sets), ds)
    assert cfg["filter"]["nhc"] is expected


def test_an_unknown_platform_is_refused_naming_the_manifest(kitti_slice, tmp_path):
    import shutil

    from fusion_eval import load_dataset
    from fusion_eval.errors import ConfigError

    d = tmp_path / "ds"
    shutil.copytree(kitti_slice, d)
    m = d / "dataset.yaml"
    m.write_text(m.read_text().replace("platform: car", "platform: boat"))
    line = next(i for i, ln in enumerate(m.read_text().splitlines(), 1) if ln.startswith("platform: boat"))
    with pytest.raises(ConfigError, match=rf"dataset.yaml:{line}: 'platform' must be one of car, wheeled, aerial, handheld, "
                                          r"legged, other, got 'boat'"):
        load_dataset(d)


def test_an_uncertain_estimate_is_not_used_and_the_report_says_why():
    from fusion_eval.calibration.travel import MAX_STD_MRAD, TravelEstimate, uncertain

    assert uncertain(TravelEstimate(12.0, 0.8, 500, 60.0)) == ""
    why = uncertain(TravelEstimate(40.0, 9.0, 30, 22.0))
    assert why == f"an estimate of 40.0 +/- 9.0 mrad, over {MAX_STD_MRAD:g} mrad of uncertainty"
    assert uncertain(TravelEstimate(12.0, float("nan"), 25, 21.0))           # one block: no spread to judge it by


def test_a_lidar_estimate_too_uncertain_falls_back_on_the_smoothed_pass(kitti_slice, monkeypatch):
    from fusion_eval.calibration import travel

    monkeypatch.setattr(travel, "MAX_STD_MRAD", 0.5)      # the slice's lidar estimate has 1.1 mrad, the pass's 1.2
    prep, _ = _prepared(kitti_slice, "filter.nhc=true")
    a = prep.applied["nhc_travel"]
    assert a["pitch_mrad"] is None and re.fullmatch(
        r"an estimate of 7\.4 \+/- 1\.1 mrad, over 0\.5 mrad of uncertainty from the lidar; an estimate of \d+\.\d "
        r"\+/- \d+\.\d mrad, over 0\.5 mrad of uncertainty from the smoothed IMU \+ GNSS pass", a["method"]), a


@pytest.mark.parametrize("sets,lines", [
    ((), ["- Non-holonomic constraint: on (the dataset's platform is a car).",
          "- Lidar increments in the body frame (lidar.relative_frame: auto, GNSS fused)."]),
    (("filter.use_gnss=false",), ["- Lidar increments in the heading frame (lidar.relative_frame: auto, no GNSS fused)."]),
    (("filter.nhc=false",), ["- Non-holonomic constraint: off on this car (filter.nhc=false, or a process model or smoother "
                             "without it; see README, 'The non-holonomic constraint')."]),
    (("filter.nhc_travel_pitch_mrad=null",), ["- Non-holonomic constraint: on (the dataset's platform is a car), lateral "
                                              "row only."]),
])
def test_the_report_says_what_auto_chose_for_the_constraint_and_the_lidar_frame(kitti_slice, sets, lines):
    from fusion_eval.report.markdown import _estimates

    prep, _ = _prepared(kitti_slice, *sets)
    said = _estimates(prep.applied)
    for line in lines:
        assert line in said, said


@pytest.mark.parametrize("sets,message", [
    (("filter.nhc=maybe",), "filter.nhc must be true, false or 'auto', got 'maybe'"),
    (("filter.nhc_travel_pitch_mrad=abc",), "filter.nhc_travel_pitch_mrad must be a number, 'auto' or null, got 'abc'"),
])
def test_a_bad_value_is_refused_naming_every_value_the_key_takes(sets, message):
    from fusion_eval.config import load_config
    from fusion_eval.errors import ConfigError

    with pytest.raises(ConfigError, match=re.escape(message)):
        load_config(None, sets)


@pytest.mark.parametrize("yaw_mrad", [1570.8, -1570.8, 400.0])
def test_travel_pitch_in_a_yawed_imu_is_recovered_with_the_mounts_yaw_either_sign(yaw_mrad):
    """An IMU yawed against the car: the increments are taken in the vehicle's axes; a yaw given 180 deg off (its
    sign is not seen in the IMU's data) gives the pitch negated, and the constraint's vertical row the same."""
    base = _drive(12.0, 300.0, np.random.default_rng(4))
    Rz = exp_so3(np.array([0.0, 0.0, yaw_mrad * 1e-3]))        # the IMU's axes: the vehicle's turned by -yaw
    R = base.R_wb() @ Rz.T
    poses = PoseSeries(t_s=base.t_s, p_w_m=base.p_w_m, q_wb_xyzw=matrix_to_quat_xyzw(R))
    assert estimate_travel_pitch(poses, yaw_mrad * 1e-3).pitch_mrad == pytest.approx(12.0, abs=0.5)
    flipped = estimate_travel_pitch(poses, yaw_mrad * 1e-3 + np.pi)
    assert flipped.pitch_mrad == pytest.approx(-12.0, abs=0.5)
    np.testing.assert_allclose(vehicle_axes(flipped.pitch_mrad * 1e-3, yaw_mrad * 1e-3 + np.pi)[2],
                               vehicle_axes(12e-3, yaw_mrad * 1e-3)[2], atol=1e-3)
    if abs(yaw_mrad) > 1000:          # along the IMU's own x axis there is no straight driving at all
        assert estimate_travel_pitch(poses) is None


def test_a_constraint_rate_the_imu_cannot_give_is_said(kitti_slice, caplog):
    """The constraint fires at IMU samples: 7, 10, 25 and 100 Hz on a 10 Hz IMU were all 10 Hz, with no word (a
    configuration audit); a rate it can give says nothing."""
    from fusion_eval import load_dataset, session
    from fusion_eval.filters.observations.nhc import OBSERVATION
    from fusion_eval.prepare import prepare, settings_for

    ds = load_dataset(kitti_slice)
    for rate, said in ((25.0, "at every sample of this 10 Hz stream: 10 Hz"), (3.0, "every 3rd sample"), (5.0, None)):
        cfg = session.resolve(session.request(sets=(f"filter.nhc_rate_hz={rate}",)), ds)
        prep = prepare(ds, cfg)
        caplog.clear()
        with caplog.at_level("WARNING"):
            OBSERVATION.bind(prep, settings_for(cfg, prep))
        assert (said in caplog.text) if said else "nhc_rate_hz" not in caplog.text, caplog.text
