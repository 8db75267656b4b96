"""Every estimate of a report, and every variant of a comparison, scored over the same span."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import fusion_eval as fe
from fusion_eval.cli import main
from fusion_eval.errors import DataRangeError
from fusion_eval.evaluation import span
from fusion_eval.types import PoseSeries


def _poses(t):
    t = np.asarray(t, float)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1))
    return PoseSeries(t_s=t, p_w_m=np.zeros((t.size, 3)), q_wb_xyzw=q)


def test_common_span_is_the_intersection_and_names_what_limits_it():
    gt = _poses(np.arange(0, 100, 0.1))
    sp = span.common_span(gt, {"fused": (0.0, 99.9), "lidar": (1.2, 95.0), "gnss": (0.5, 99.5)})
    # the ends rounded outwards to the microsecond
    assert (sp["start_set_by"], sp["end_set_by"]) == ("lidar", "lidar")
    assert 1.2 - 3e-6 < sp["t0_s"] < 1.2 and 95.0 < sp["t1_s"] < 95.0 + 3e-6
    cropped = span.crop(_poses(np.arange(0, 1000) * 0.1), sp)
    assert cropped.t_s[0] == pytest.approx(1.2) and cropped.t_s[-1] == pytest.approx(95.0)
    assert span.evo_options(sp).split()[::2] == ["--t_start", "--t_end"]
    with pytest.raises(DataRangeError, match="share no time span"):
        span.common_span(gt, {"a": (0.0, 10.0), "b": (20.0, 30.0)})
    # every estimate at a limit is named: run named the lidar and compare the filter for one and the same stamp
    tie = span.common_span(gt, {"fused": (1.2, 99.9), "lidar": (1.2, 95.0), "gnss": (1.2, 95.0)})
    assert (tie["start_set_by"], tie["end_set_by"]) == ("fused, lidar and gnss", "lidar and gnss")


def test_a_run_scores_every_estimate_on_the_common_span(kitti_slice):
    ds = fe.load_dataset(kitti_slice)
    common = fe.run(ds, overrides={"output.plots": False}).metrics
    own = fe.run(ds, overrides={"output.plots": False, "evaluation.span": "own"}).metrics
    sp = common["evaluation"]["span"]
    assert sp["mode"] == "common" and sp["duration_s"] > 80 and own["evaluation"]["span"] == {"mode": "own"}
    # nothing gains any pose; the span starts at the lidar's first frame, and the 1 Hz GNSS's last fix (up to a second
    # before the drive's end) no longer ends it: the GNSS's extent is taken before its rate and outages are applied
    e, o = common["estimates"], own["estimates"]
    assert all(e[k]["matched_poses"] <= o[k]["matched_poses"] for k in e)
    assert "lidar" in sp["start_set_by"] and sp["end_set_by"] != "gnss"       # not the 1 Hz GNSS alone
    assert e["fused"]["matched_poses"] == e["lidar"]["matched_poses"] == e["imu_only"]["matched_poses"]
    ratio = e["fused"]["ape"]["translation_m"]["rmse"] / e["lidar"]["ape"]["translation_m"]["rmse"]
    assert common["ratios"]["fused_over_lidar"] == pytest.approx(ratio)


def test_compare_scores_every_variant_on_one_span(kitti_slice, tmp_path):
    out = tmp_path / "cmp"
    r = CliRunner().invoke(main, ["-q", "compare", str(kitti_slice), "--variants", "eskf,lidar-relative-no-gnss,gnss-only",
                                  "--out", str(out), "--no-plots"])
    assert r.exit_code == 0, r.output
    c = json.loads((out / "compare.json").read_text())
    assert c["span"]["mode"] == "common"
    fused = [row for row in c["rows"] if row["estimate"] == "fused"]
    assert len({row["matched_poses"] for row in fused}) == 1, [row["matched_poses"] for row in fused]
    assert "Span: every estimate over the same" in (out / "compare.md").read_text()


def test_a_start_a_rounding_before_the_truth_reads_as_zero():
    """'-0.00 .. 114.85 s' on a raw drive's report (a student's review)."""
    from fusion_eval.evaluation.span import describe

    text = describe({"from_groundtruth_start_s": [-0.001, 114.85], "duration_s": 114.9, "start_set_by": "gnss",
                     "end_set_by": "gnss", "t0_s": 1.0, "t1_s": 2.0})
    assert "0.00 .. 114.85 s after" in text and "-0.00" not in text


def test_a_stream_cut_short_is_said_whichever_stream_it_is():
    """An IMU cut at 30 s of a 60 s drive, or a ground truth of 6 s, was scored over its stub with no word: the share
    was taken of the time the IMU and the ground truth shared (a corrupted-input review). It is taken of the longest
    input stream now; a drive whose streams all cover it says nothing."""
    gt = _poses(np.arange(0, 60, 0.1))
    full = span.common_span(gt, {"fused": (0.0, 59.9), "lidar": (0.0, 59.9)})
    assert span.short_span_warning(full, gt, (0.0, 59.9), {"lidar": (0.0, 59.9)}) is None
    imu_cut = span.common_span(gt, {"fused": (0.0, 30.0), "lidar": (0.0, 59.9)})
    w = span.short_span_warning(imu_cut, gt, (0.0, 30.0), {"lidar": (0.0, 59.9)})
    assert w.startswith("every estimate is scored over 30.0 s only") and "of the 59.9 s the ground truth covers" in w
    assert "IMU 30.0 s" in w and "fused sets its start" not in w
    gt_cut = _poses(np.arange(0, 6, 0.1))
    w = span.short_span_warning(span.common_span(gt_cut, {"fused": (0.0, 59.9)}), gt_cut, (0.0, 59.9), {})
    assert "of the 59.9 s the IMU covers (ground truth 5.9 s, IMU 59.9 s)" in w and "groundtruth its end" in w


def test_no_ratio_over_an_estimate_equal_to_its_reference():
    """A ground truth of two rows scored the lidar's anchored start alone: 'fused over lidar 2699170384210'."""
    from types import SimpleNamespace

    from fusion_eval.evaluation.trajectory import ratio

    def ev(rmse):
        return SimpleNamespace(metrics={"ape": {"translation_m": {"rmse": rmse}}})

    assert ratio(ev(0.7), ev(7.0)) == pytest.approx(0.1)
    assert ratio(ev(0.7), ev(2.6e-13)) is None and ratio(ev(0.7), ev(0.0)) is None and ratio(ev(0.7), None) is None
