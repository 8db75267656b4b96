"""Rankings from one run of each entry say when their lead is inside what one seed moves (a student's review: noise
settings 0.754-0.758 m apart ranked and 'best.yaml' written, with a seed spread of 0.08 m on the drive)."""

from __future__ import annotations

import math

from fusion_eval import trials


def test_a_small_lead_from_one_run_each_is_said_with_the_way_to_rank_over_seeds():
    note = trials.one_draw_note(0.754, 0.758, 1, "The best leads the next by")
    assert note.startswith("The best leads the next by 0.53 % from one run each") and "`--trials 5`" in note
    assert "the runs' random elements" in note
    assert "`--seeds 3`" in trials.one_draw_note(0.728, 0.757, 1, "x", "--seeds 3")
    named = trials.one_draw_note(0.754, 0.758, 1, "x", streams=["degraded GNSS"])
    assert "with the same seeds of the degraded GNSS these runs fuse" in named and "one seed does not rank them" in named
    # nothing fused is drawn from a seed (IMU + lidar): no advice to run trials that would all be equal (a student's
    # review of a comparison without GNSS)
    assert trials.one_draw_note(0.754, 0.758, 1, "x", streams=[]) is None


def test_entries_drawn_with_other_seeds_or_equal_are_said_so():
    """Paired runs (the same seeds) differ by 0.1-2 % from seed to seed, unpaired ones by a whole seed's spread (11 %
    of kitti-00's fused APE): a variant 19 % ahead of itself under another seed got no word, and two equal figures
    'led by 0 %' (a statistics review)."""
    unpaired = trials.one_draw_note(0.631, 0.753, 1, "The best leads the next by", paired=False)
    assert unpaired.startswith("The best leads the next by 19 % from one run each, drawn with different seeds")
    assert "an unpaired comparison" in unpaired and "Give both the same seeds" in unpaired
    assert trials.one_draw_note(0.631, 0.753, 1, "x") is None                       # paired: a 19 % lead is one
    assert trials.one_draw_note(0.50, 0.70, 1, "x", paired=False) is None           # 40 %: beyond what seeds do
    same = trials.one_draw_note(0.753, 0.753, 1, "x")
    assert same.startswith("The first two figures are equal (0.753): this ranking does not order them")


def test_effective_seeds_follow_gnss_seed_where_null():
    from fusion_eval.config import load_config

    a = trials.effective_seeds(load_config(None, ("gnss.seed=3",)))
    b = trials.effective_seeds(load_config(None, ("gnss.seed=3", "gnss_velocity.seed=3")))
    assert a["gnss_velocity.seed"] == 3 and a == b
    assert trials.effective_seeds(load_config(None, ())) != a


def test_seeded_streams_are_the_fused_streams_drawn_with_a_seed():
    deg = {"degraded": True}
    assert trials.seeded_streams({"nis": {"gnss": {}, "lidar": {}}, "gnss_degradation": deg}) == ["degraded GNSS"]
    # degraded but not fused: only the unfiltered GNSS estimate varies with the seed
    assert trials.seeded_streams({"nis": {"lidar": {}}, "gnss_degradation": deg}) == []
    assert trials.seeded_streams({"nis": {"gnss": {}}, "gnss_degradation": {"degraded": False}}) == []
    assert trials.seeded_streams({"nis": {"gnss_velocity": {}, "odometer": {}},
                                  "preprocessing": {"gnss_velocity": deg, "odometer_added_noise_std_mps": 0.05}}) == [
        "degraded gnss_velocity", "odometer noise"]


def test_no_note_on_means_over_trials_a_clear_lead_or_no_figures():
    assert trials.one_draw_note(0.754, 0.758, 5, "x") is None          # ranked on means over seeds
    assert trials.one_draw_note(0.70, 0.80, 1, "x") is None            # a 14 % lead
    assert trials.one_draw_note(math.nan, 0.8, 1, "x") is None
    assert trials.one_draw_note(0.8, 0.7, 1, "x") is None              # not a lead


def test_the_sweep_summary_and_the_compare_report_carry_it(kitti_slice, tmp_path):
    from click.testing import CliRunner

    from fusion_eval.cli import main

    (tmp_path / "grid.yaml").write_text("settings:\n  a: {gnss.noise_std_m: [1.0, 1.0, 2.0]}\n"
                                        "  b: {gnss.noise_std_m: [1.01, 1.01, 2.0]}\n")
    r = CliRunner().invoke(main, ["sweep", str(kitti_slice), "--grid", str(tmp_path / "grid.yaml"), "--out",
                                  str(tmp_path / "sw"), "--no-plots", "--jobs", "1"])
    assert r.exit_code == 0, r.output
    assert "from one run each" in r.output
    # setting a is the default's configuration: they share one run, and the console says so beside sweep.md's count
    assert "2 runs done" in r.output and "3 settings in sweep.md, 1 of them the same configuration as another" in r.output
    md = (tmp_path / "sw" / "sweep.md").read_text()
    assert "The best leads the next by" in md
    # the next is the setting that ran something else, not the default's run under another name (it 'led by 0 %')
    import re

    lead = float(re.search(r"The best leads the next by ([0-9.]+) %", md).group(1))
    assert lead > 0.0, md
    # each setting's consistency and the lidar noise's adaptation are columns (a student's review: the adaptation
    # undid a swept noise, and an overconfident setting ranked first, with no word)
    assert "NEES pos (3 dof)" in md and "lidar noise x pos / att" in md and "lidar.noise_adapt: none" in md
    head = (tmp_path / "sw" / "sweep.csv").read_text().splitlines()[0].split(",")
    assert {"nees_pos_mean", "nees_pos_in95_frac", "nis_lidar_mean", "lidar_noise_pos_x", "lidar_noise_att_x"} <= set(head)


def test_an_overconfident_best_gets_a_caveat():
    from fusion_eval.commands.sweep_summary import _overconfident_best

    rows = [{"dataset": "d", "variant": "eskf", "setting": "default", "nees_pos_mean": 7.0},
            {"dataset": "d", "variant": "eskf", "setting": "gnss-trusted", "nees_pos_mean": 14.4},
            {"dataset": "d", "variant": "eskf", "setting": "lidar-tight", "nees_pos_mean": 7.2},
            {"dataset": "e", "variant": "eskf", "setting": "gnss-trusted", "nees_pos_mean": 3.1}]
    c = _overconfident_best(rows, "eskf", "gnss-trusted")
    assert c.startswith("Caveat: the best setting's filter is overconfident") and "14.4 (the default 7.0)" in c
    assert "`e`" not in c                                       # consistent there
    assert _overconfident_best(rows, "eskf", "lidar-tight") is None     # as (in)consistent as the default
    assert _overconfident_best(rows[:1], "eskf", "default") is None


def test_the_compare_report_carries_it():
    from fusion_eval.commands.compare import _markdown

    rows = [{"variant": v, "estimate": e, "ape_trans_rmse_m": a} for v, e, a in
            (("eskf", "fused", 0.757), ("iekf", "fused", 0.759), ("eskf", "lidar", 7.18))]
    text = _markdown("kitti-00", rows, None, False)
    assert "The best variant's fused APE leads the next by 0.26 % from one run each" in text
    assert "leads the next" not in _markdown("kitti-00", rows, None, False, n_trials=5)
    assert "leads the next" not in _markdown("kitti-00", rows, None, False, seeded=[])
    # a variant drawn with another seed: unpaired, and its lead inside what a seed moves is said as such
    rows[0]["ape_trans_rmse_m"] = 0.631
    seeds = {"eskf": {"gnss.seed": 3}, "iekf": {"gnss.seed": 0}}
    text = _markdown("kitti-00", rows, None, False, seeds=seeds)
    assert "leads the next by 20 % from one run each, drawn with different seeds" in text, text
    assert "leads the next" not in _markdown("kitti-00", rows, None, False, seeds={"eskf": {}, "iekf": {}})


def test_compare_gives_numbas_compilation_apart_from_the_filter_time():
    """compare's 'filter time' of a variant first compiled in the same command was 18 s against 0.6 s warm, read as
    the formulation's speed (a student's review): the compilation is timed apart and said."""
    from numba import njit

    from fusion_eval import compile_notice
    from fusion_eval.commands.compare import _markdown

    compile_notice.install()
    before = compile_notice.compile_seconds()

    @njit(cache=False)
    def fresh(x):
        return x * 2.0 + 1.0

    assert fresh(1.0) == 3.0
    assert compile_notice.compile_seconds() > before
    rows = [{"variant": "eskf", "estimate": "fused", "ape_trans_rmse_m": 0.757, "runtime_s": 0.56},
            {"variant": "invariant", "estimate": "fused", "ape_trans_rmse_m": 0.761, "runtime_s": 1.97, "compile_s": 15.0}]
    text = _markdown("kitti-00", rows, None, False)
    assert "1.97 (+15.0 compiling)" in text and "without numba's compilation" in text
    assert "compiling" not in _markdown("kitti-00", rows[:1], None, False)


def test_metrics_json_is_strict_json_with_null_for_figures_not_computed(tmp_path):
    """An iterated update's run wrote a bare NaN for the innovations' likelihood it does not compute: no JSON for jq or
    JSON.parse (a corrupted-input review). Such figures are null; a tune on them names why."""
    import json

    import pytest

    from fusion_eval.errors import ConfigError
    from fusion_eval.report.files import metrics_json
    from fusion_eval.tuning.objectives import parse

    text = metrics_json({"innovations": {"nll_per_update": float("nan"), "nis_calibration": float("inf"), "updates": 3},
                         "nis": {"lidar": {"nll_mean": float("nan"), "mean": 6.1}}, "list": [1.0, float("-inf")]})
    assert "NaN" not in text and "Infinity" not in text
    body = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    assert body["innovations"]["nll_per_update"] is None and body["nis"]["lidar"]["mean"] == 6.1
    assert body["list"] == [1.0, None]
    with pytest.raises(ConfigError, match=r"ln det S .*filter.iterations > 1, or the odometer \+ gyro model"):
        parse("nll").check({"innovations.nis_calibration": 1.0, "fused.ape.rmse": 0.7}, "kitti-00")


def test_gnss_degradation_keys_on_a_receivers_stream_are_said_to_do_nothing(tmp_path):
    """gnss.rate_hz and gnss.noise_std_m do nothing to a stream the manifest does not mark for degradation (every
    simulated drive's, a CSV or bag receiver's): a sweep over them gave identical rows and a 'best' with no word (a
    corrupted-input review). It is a data warning now; the defaults raise none."""
    import fusion_eval as fe
    from fusion_eval.simulate.dataset import simulate

    simulate(tmp_path / "s", "urban", 30.0, 0, "automotive", (), jobs=1)
    ds = fe.load_dataset(tmp_path / "s")
    w = fe.run(ds, overrides={"gnss.rate_hz": 0.1, "gnss.noise_std_m": [10.0, 10.0, 20.0]}).metrics
    (msg,) = [x for x in w["preprocessing"]["data_warnings"] if "marked for degradation" in x]
    assert msg.startswith("gnss.rate_hz=0.1 and gnss.noise_std_m=[10.0, 10.0, 20.0] apply only to a GNSS stream")
    plain = fe.run(ds).metrics["preprocessing"].get("data_warnings", [])
    assert not [x for x in plain if "marked for degradation" in x]


def test_a_reference_or_truth_of_placeholder_orientations_is_said(slice_run, tmp_path):
    """A run's own gnss.tum as evaluate's reference gave a 100 deg rotation APE and 75 % drift about its identity
    placeholders, and a truth with identity quaternions a 114 deg fused rotation APE in a run, both with no word (a
    corrupted-input review)."""
    import json
    from dataclasses import replace

    import numpy as np
    from click.testing import CliRunner

    from fusion_eval.cli import main
    from fusion_eval.datasets.plausible import truth_orientation_placeholder

    r = CliRunner().invoke(main, ["evaluate", str(slice_run / "gnss.tum"), str(slice_run / "fused.tum"), "--out",
                                  str(tmp_path / "e"), "--no-plots"])
    assert r.exit_code == 0, r.output
    assert "has the same orientation on every pose" in r.stderr and "evaluated as position only" in r.stderr
    m = json.loads((tmp_path / "e" / "metrics.json").read_text())["estimates"]["fused"]
    assert m["note"].startswith("position only (the reference has one and the same orientation")
    assert "rotation_deg" not in m["ape"]

    import fusion_eval as fe

    gt = fe.load_dataset(None).groundtruth
    flat = replace(gt, q_wb_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (len(gt), 1)))
    assert "one and the same orientation on every pose" in truth_orientation_placeholder(flat)
    assert truth_orientation_placeholder(gt) is None
