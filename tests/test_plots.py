"""The run and sweep plots: what each figure must show (built by the ``*_figure`` helpers and inspected as
matplotlib objects), the attitude / velocity error it draws, and the true biases of a simulated drive on the
filter's clock."""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest
import yaml

from fusion_eval.commands.sweep import Task
from fusion_eval.commands.sweep_summary import default_values
from fusion_eval.datasets.truth import TruthBiases, read_imu_biases, truth_imu_biases
from fusion_eval.errors import DataFormatError
from fusion_eval.evaluation.run_metrics import VEL_FROM_POSITIONS, fused_att_vel_error, fused_error
from fusion_eval.filters.layout import CANONICAL
from fusion_eval.report import filter_plots, plots, thin
from fusion_eval.so3 import exp_so3, matrix_to_quat_xyzw
from fusion_eval.types import PoseSeries

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

METRIC = "fused_ape_trans_rmse_m"


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def _circle(n: int = 400, dt_s: float = 0.1, with_velocity: bool = True) -> PoseSeries:
    """A car on a circle of 50 m at 5 m/s, heading along the path, with a slow roll and pitch: ENU poses."""
    t = 1000.0 + dt_s * np.arange(n)
    w = 0.1
    p = np.column_stack([50 * np.cos(w * (t - t[0])), 50 * np.sin(w * (t - t[0])), 0.5 * np.sin(0.3 * (t - t[0]))])
    v = np.column_stack([-5 * np.sin(w * (t - t[0])), 5 * np.cos(w * (t - t[0])), 0.15 * np.cos(0.3 * (t - t[0]))])
    from fusion_eval.so3 import euler_rpy_to_matrix

    R = euler_rpy_to_matrix(0.02 * np.sin(t), 0.01 * np.cos(t), w * (t - t[0]) + np.pi / 2)
    return PoseSeries(t_s=t, p_w_m=p, q_wb_xyzw=matrix_to_quat_xyzw(R), v_w_mps=v if with_velocity else None)


def _filter_output(poses: PoseSeries, rng: np.random.Generator) -> SimpleNamespace:
    """What the error functions read of a :class:`fusion_eval.replay.FilterOutput`."""
    sigma = np.abs(rng.normal(0.1, 0.01, (len(poses), CANONICAL.n_core)))
    return SimpleNamespace(fused=poses, sigma=sigma, smoothed=None)


# --- attitude and velocity error (evaluation/run_metrics.py)

def test_att_vel_error_is_zero_for_an_estimate_equal_to_the_truth():
    gt = _circle()
    filt = _filter_output(gt, np.random.default_rng(0))
    av = fused_att_vel_error(gt, filt)
    m = len(gt)
    assert av["t_s"].shape == (m,)
    for key in ("att_err_b_rad", "att_sigma_b_rad", "vel_err_w_mps", "vel_sigma_w_mps"):
        assert av[key].shape == (m, 3), key
    assert np.abs(av["att_err_b_rad"]).max() < 1e-7 and np.abs(av["vel_err_w_mps"]).max() < 1e-12
    # the sigma columns are the layout's attitude and velocity blocks, not the position's
    assert np.array_equal(av["att_sigma_b_rad"], filt.sigma[:, CANONICAL.sl("TH")])
    assert np.array_equal(av["vel_sigma_w_mps"], filt.sigma[:, CANONICAL.sl("V")])
    assert av["smoothed"] is None and av["vel_truth"] != VEL_FROM_POSITIONS
    assert fused_error(gt, filt)["att_vel"]["att_err_b_rad"].shape == (m, 3)     # what the run's plot job gets


def test_att_error_is_the_body_frame_rotation_of_a_known_perturbation():
    gt = _circle()
    phi_b = np.array([0.01, -0.02, 0.03])               # rad, fused = truth * Exp(phi) (right: body frame)
    R_f = gt.R_wb() @ exp_so3(phi_b)
    est = PoseSeries(t_s=gt.t_s, p_w_m=gt.p_w_m, q_wb_xyzw=matrix_to_quat_xyzw(R_f), v_w_mps=gt.v_w_mps + [0.1, 0, -0.2])
    av = fused_att_vel_error(gt, _filter_output(est, np.random.default_rng(1)))
    assert np.allclose(av["att_err_b_rad"], phi_b, atol=1e-9)
    assert np.allclose(av["vel_err_w_mps"], [0.1, 0.0, -0.2], atol=1e-12)


def test_truth_velocity_from_central_differences_when_the_truth_has_none():
    gt = _circle(with_velocity=False)
    exact = _circle().v_w_mps
    est = PoseSeries(t_s=gt.t_s, p_w_m=gt.p_w_m, q_wb_xyzw=gt.q_wb_xyzw, v_w_mps=exact)
    av = fused_att_vel_error(gt, _filter_output(est, np.random.default_rng(2)))
    assert av["vel_truth"] == VEL_FROM_POSITIONS
    # second-order differences: O(dt^2 v w^2) inside, first order at the two ends
    assert np.abs(av["vel_err_w_mps"][1:-1]).max() < 1e-3 and np.abs(av["vel_err_w_mps"]).max() < 0.05
    fig = plots.att_vel_error_figure(thin.att_vel(av))
    assert len(fig.axes) == 6 and "central differences" in fig._suptitle.get_text()


def test_att_vel_figure_without_velocity_has_the_attitude_column_only():
    gt = _circle()
    av = fused_att_vel_error(gt, _filter_output(gt, np.random.default_rng(3)))
    av = {**av, "vel_err_w_mps": None, "vel_sigma_w_mps": None}
    fig = plots.att_vel_error_figure(thin.att_vel(av))
    assert len(fig.axes) == 3 and fig.axes[0].get_ylabel() == "roll [deg]"
    assert "fused_error_att_vel_3sigma.png" in filter_plots(True)


# --- biases

def _bias_run(n: int = 600):
    t = 2000.0 + 0.1 * np.arange(n)
    ba = np.column_stack([0.01 + 0.001 * np.sin(0.05 * t), np.full(n, -0.004), np.full(n, 0.002)])
    bg = np.column_stack([np.full(n, 1e-4), np.full(n, -2e-4), np.full(n, 3e-4)])
    sigma = np.full((n, CANONICAL.n_core), 1e-3)
    sigma[:, CANONICAL.sl("BG")] = 2e-5
    sigma[:20, CANONICAL.sl("BA")] = 0.5                  # the prior: 50 times the bias
    return t, ba, bg, sigma


def test_biases_figure_has_one_panel_per_axis_and_limits_from_the_estimate():
    t, ba, bg, sigma = _bias_run()
    fig = plots.biases_figure(t, ba, bg, sigma)
    assert len(fig.axes) == 6
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels[0] == "accelerometer bias x [mg]" and labels[3] == "gyro bias x [deg/h]"
    lo, hi = fig.axes[0].get_ylim()
    b_mg = ba[:, 0] / plots.MG_MPS2
    assert lo <= b_mg.min() and hi >= b_mg.max()
    assert hi - lo < 0.2 * 3 * 0.5 / plots.MG_MPS2           # not stretched to the prior's band
    lo, hi = fig.axes[3].get_ylim()
    assert lo < 1e-4 / plots.DEG_H_RPS < hi
    assert not any(line.get_label() == "true bias (simulator)" for ax in fig.axes for line in ax.lines)


def test_biases_figure_overlays_the_true_biases():
    t, ba, bg, sigma = _bias_run()
    t_true = np.arange(t[0] - 5.0, t[-1] + 5.0 + 1e-9, 0.05)         # beyond the filter's span at both ends
    ba_true = np.column_stack([np.interp(t_true, t, ba[:, i]) + 1e-3 for i in range(3)])
    truth = TruthBiases(t_s=t_true, accel_b_mps2=ba_true, gyro_b_rps=np.tile(bg[0] * 1.1, (t_true.size, 1)))
    fig = plots.biases_figure(t, ba, bg, sigma, truth)
    for i, ax in enumerate(fig.axes):
        true = [line for line in ax.lines if line.get_label() == "true bias (simulator)"]
        assert len(true) == 1, i
        x = true[0].get_xdata()
        # the filter's span (to one truth step), on the same clock
        assert x.min() == pytest.approx(0.0, abs=0.051) and x.max() == pytest.approx(t[-1] - t[0], abs=0.051)
        want = (truth.accel_b_mps2[:, i] / plots.MG_MPS2) if i < 3 else (truth.gyro_b_rps[:, i - 3] / plots.DEG_H_RPS)
        assert true[0].get_ydata()[-1] == pytest.approx(want[-1])
    assert "true bias (simulator)" in [tx.get_text() for tx in fig.legends[0].get_texts()]


def test_truth_biases_read_from_the_manifest_entry(tmp_path):
    (tmp_path / "truth").mkdir()
    rows = "\n".join(f"{100 + 0.01 * i:.6f},0.01,0.02,0.03,0.001,0.002,0.003" for i in range(5))
    (tmp_path / "truth" / "imu_biases.csv").write_text("t_s,ba_x_mps2,ba_y_mps2,ba_z_mps2,bg_x_rps,bg_y_rps,bg_z_rps\n"
                                                        + rows + "\n")
    desc = {"manifest": str(tmp_path / "dataset.yaml"), "truth": {"imu_biases": "truth/imu_biases.csv"}}
    tb = truth_imu_biases(desc, imu_time_offset_s=0.25)
    assert tb.t_s[0] == pytest.approx(100.25) and tb.accel_b_mps2.shape == (5, 3)
    assert np.allclose(tb.gyro_b_rps[-1], [0.001, 0.002, 0.003])
    assert truth_imu_biases({"manifest": desc["manifest"], "truth": None}) is None
    (tmp_path / "bad.csv").write_text("t,bx,by,bz,gx,gy,gz\n" + rows + "\n")
    with pytest.raises(DataFormatError, match="header"):
        read_imu_biases(tmp_path / "bad.csv")


def test_simulated_truth_biases_are_on_the_imu_clock(tmp_path):
    from fusion_eval.datasets.manifest import load_dataset
    from fusion_eval.simulate.dataset import simulate

    simulate(tmp_path / "sim", "urban", 5.0, 3, "automotive")
    ds = load_dataset(tmp_path / "sim")
    tb = truth_imu_biases(ds.description, 0.0)
    # the same stamps as the IMU stream the filter runs on (the file keeps microseconds)
    assert tb is not None and tb.t_s.shape == ds.imu.t_s.shape
    assert np.abs(tb.t_s - ds.imu.t_s).max() < 1e-6


# --- consistency, segments, trials

def _series(dof: int, n: int = 200) -> dict:
    rng = np.random.default_rng(dof)
    v = rng.chisquare(dof, n)
    return {"t_s": 10.0 + np.arange(n) * 0.1, "values": v, "dof": dof, "bounds_95": [0.2, 9.3], "mean": float(v.mean()),
            "fraction_in_95": 0.95}


def test_consistency_figure_explains_bounds_and_dof():
    cons = {"nees": {"position": _series(3), "attitude": _series(3)}, "nis": {"lidar": _series(6)}}
    fig = plots.consistency_figure(cons, 10.0)
    assert len(fig.axes) == 3
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("95 %" in t and "bounds" in t for t in texts) and any(t.startswith("dof") for t in texts)
    for ax in fig.axes:                           # the legend's lines are the ones drawn in every axis
        assert {ln.get_label() for ln in ax.lines} >= set(texts)


def test_segment_map_labels_are_explained():
    n = 300
    p = np.column_stack([np.linspace(0, 299, n), np.zeros(n), np.zeros(n)])
    err = np.where((p[:, 0] >= 100) & (p[:, 0] < 200), 2.0, 0.5)
    ev = SimpleNamespace(ref_p_m=p, ape_err_m=err, ape_t_s=np.arange(n) * 0.1)
    segs = [{"index": k, "start_m": 100.0 * k, "end_m": 100.0 * k + 99, "start_s": 10.0 * k, "end_s": 10.0 * k + 9.9,
             "rmse_m": {"fused": float(np.sqrt(np.mean(err[100 * k:100 * k + 100] ** 2)))}} for k in range(3)]
    seg = {"by": "distance", "length": 100.0, "segments": segs, "worst": [1, 0], "primary": "fused", "secondary": None}
    fig = plots.segment_map_figure({"fused": ev}, seg)
    notes = [t.get_text() for t in fig.axes[0].texts]
    assert notes[0] == "#1 (2.00 m)" and len(notes) == 2
    caption = " ".join(t.get_text() for t in fig.texts)
    assert "segment k" in caption and "100 m" in caption and "largest fused APE translation RMSE" in caption


def test_segment_map_sets_fused_against_the_gnss_where_there_is_no_lidar_and_not_across_an_outage():
    """A run of IMU and GNSS had a map of its own error and nothing to set it against: the breakdown's secondary is
    the lidar, else the GNSS; across a GNSS outage the map draws no difference (the line between the fixes on either
    side is no GNSS error), but marks the span."""
    from fusion_eval.evaluation.run_metrics import segments

    n = 600
    t = 0.1 * np.arange(n)
    p = np.column_stack([np.linspace(0, 599, n), np.zeros(n), np.zeros(n)])
    t_g = np.r_[np.arange(0.0, 20.0), np.arange(40.0, 60.0)]           # 1 Hz fixes, none from 20 to 40 s

    def ev(ts, err):
        return SimpleNamespace(ape_t_s=ts, ape_err_m=err, ape_hv_m=None, ref_p_m=p[:len(ts)])
    evals = {"fused": ev(t, np.full(n, 0.5)), "gnss": ev(t_g, np.full(t_g.size, 2.0)), "imu_only": ev(t, t)}
    gt = SimpleNamespace(t_s=t, p_w_m=p)
    seg = segments(gt, evals, {"segment_m": 100.0, "segment_s": None})
    assert seg["primary"] == "fused" and seg["secondary"] == "gnss"
    evals["lidar"] = ev(t, np.full(n, 1.0))
    assert segments(gt, evals, {"segment_m": 100.0, "segment_s": None})["secondary"] == "lidar"
    fig = plots.segment_map_figure({"fused": evals["fused"], "gnss": evals["gnss"]}, seg)
    assert len(fig.axes) == 4                                              # two panels and their colour bars
    far, colored = fig.axes[1].collections
    assert far.get_label() == "no gnss pose here" and far.get_offsets().shape[0] == int(np.sum((t - 19 > 2) & (40 - t > 2)))
    assert np.allclose(colored.get_array(), -1.5)
    assert not plots._far_from(t_g + 0.5, t_g).any() and plots._far_from(np.array([30.0]), t_g).all()


def test_trials_figure_shows_the_spread_of_each_metric():
    rng = np.random.default_rng(4)
    per = [{"trial": i, "fused.ape.translation_m.rmse": 0.7 + 0.05 * rng.normal(), "gnss.ape.translation_m.rmse":
            2.4 + 0.1 * rng.normal(), "ratios.fused_over_gnss": 0.3 + 0.02 * rng.normal()} for i in range(8)]
    stats = {}
    for key in per[0]:
        if key != "trial":
            v = np.array([r[key] for r in per])
            stats[key] = {"mean": v.mean(), "std": v.std(ddof=1), "ci95_mean": [v.mean() - 0.01, v.mean() + 0.01]}
    fig = plots.trials_figure({"n": 8, "per_trial": per + [{"trial": 8, "failed": "diverged"}], "stats": stats})
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert len(shown) == 3                          # one panel, one scale, per metric present
    for ax, key in zip(shown, ("fused.ape.translation_m.rmse", "gnss.ape.translation_m.rmse", "ratios.fused_over_gnss")):
        dots = [ln for ln in ax.lines if ln.get_marker() == "o"]
        assert len(dots) == 1 and len(dots[0].get_ydata()) == 8
        band = ax.patches[0]                             # the mean +/- std band
        st = stats[key]
        assert band.get_y() == pytest.approx(st["mean"] - st["std"])
        assert band.get_y() + band.get_height() == pytest.approx(st["mean"] + st["std"])
        assert ", min " in ax.get_title() and ", max " in ax.get_title() and " .. " not in ax.get_title()
    # a metric no seed moves (the lidar's) is said in the title, not drawn as a panel of one value (a plot review)
    for r in per:
        r["lidar.ape.translation_m.rmse"] = 7.177
    stats["lidar.ape.translation_m.rmse"] = {"mean": 7.177, "std": 0.0, "ci95_mean": [7.177, 7.177]}
    fig = plots.trials_figure({"n": 8, "per_trial": per, "stats": stats})
    assert len([ax for ax in fig.axes if ax.get_visible()]) == 3
    assert "the same in every trial, not drawn: lidar odometry APE translation RMSE [m] 7.18" in fig._suptitle.get_text()


# --- sweep

def _sweep_rows(values=(0.01, 0.1, 1.0), key="imu.gyro_noise_dps_sqrthz"):
    base = {"dataset": "/d/kitti-00", "variant": "eskf", "status": "ok"}
    rows = [{**base, "setting": "default", key: "", METRIC: 0.72}]
    rows += [{**base, "setting": f"{key}={v}", key: v, METRIC: 0.7 + v} for v in values]
    rows.append({**base, "setting": "other", key: "", "gnss.std_m": [0.5, 0.5, 1.0], METRIC: 0.8})
    return rows


def _markers(ax, gid: str) -> int:
    return sum(len(ln.get_xdata()) for ln in ax.lines if ln.get_gid() == gid)


def test_sweep_panel_shows_every_setting_and_the_default():
    key = "imu.gyro_noise_dps_sqrthz"
    rows = _sweep_rows()
    fig = plots.sweep_params_figure(rows, [key, "gnss.std_m"], METRIC, {("/d/kitti-00", "eskf"): {key: 0.134}})
    overview, panel = fig.axes[0], fig.axes[1]
    assert _markers(overview, "settings") + _markers(overview, "default") == len(rows)     # every setting
    assert _markers(panel, "settings") == 3 and _markers(panel, "default") == 1             # the key's, and the default
    star = next(ln for ln in panel.lines if ln.get_gid() == "default")
    assert star.get_xdata()[0] == 0.134 and star.get_ydata()[0] == 0.72
    assert panel.get_xscale() == "log"                                   # 0.01 .. 1: two decades
    ticks = [float(x) for x in panel.get_xticks()]
    assert ticks == [0.01, 0.1, 0.134, 1.0] or ticks == [0.01, 0.1, 1.0]    # at the values, none overlapping
    assert "default" in [t.get_text() for t in overview.get_yticklabels()]
    assert "the default configuration" in [t.get_text() for t in fig.legends[0].get_texts()]


def test_sweep_panel_without_the_default_value_keeps_its_line():
    key = "lidar.time_offset_s"
    rows = _sweep_rows(values=(-0.05, 0.0, 0.05), key=key)
    fig = plots.sweep_params_figure(rows, [key], METRIC, None)
    panel = fig.axes[1]
    assert _markers(panel, "default") == 0 and panel.get_xscale() == "linear"     # zero and negative values
    assert any(ln.get_linestyle() == ":" and ln.get_ydata()[0] == 0.72 for ln in panel.lines)


def test_default_values_read_from_the_default_run(tmp_path):
    key_auto, key_set = "imu.gyro_noise_dps_sqrthz", "lidar.relative_pos_std_frac"
    tasks = [Task(i, "/d/x", "eskf", None, s, {}, None, False, str(tmp_path)) for i, s in (("a1", "default"), ("b2", "s1"))]
    (tmp_path / "runs" / "a1").mkdir(parents=True)
    cfg = {"imu": {"gyro_noise_dps_sqrthz": "auto"}, "lidar": {"relative_pos_std_frac": 0.01},
           "applied": {"imu_noise": {"gyro_noise_dps_sqrthz": 0.134}}}
    (tmp_path / "runs" / "a1" / "config.resolved.yaml").write_text(yaml.safe_dump(cfg))
    got = default_values(tasks, tmp_path, [key_auto, key_set, "gnss.std_m"])
    assert got == {("/d/x", "eskf"): {key_auto: 0.134, key_set: 0.01}}
    assert default_values(tasks, tmp_path / "elsewhere", [key_set]) == {}


@pytest.mark.slow
def test_evaluation_plots_drawn_from_their_thinned_data_are_the_same_bytes(tmp_path):
    """The run sends the metric plots only what they draw (``thin.ape_curves``, ``drift_only``, ``segment_map``,
    ``consistency``): a simulated hour's evaluations were tens of MB per plot in pickles. Same PNG bytes."""
    from fusion_eval.evaluation.trajectory import EstimateEvaluation

    rng = np.random.default_rng(8)
    n = 23_457                                          # long enough to be reduced, not a multiple of the bins
    t = 50.0 + 0.005 * np.arange(n)
    p = np.column_stack([np.cumsum(rng.normal(0, 0.01, n)), np.cumsum(rng.normal(0, 0.01, n)), np.zeros(n)])

    def ev(name, scale):
        e = np.abs(rng.normal(0, scale, n)) + np.linspace(0, 1, n)
        return EstimateEvaluation(name=name, poses=n, matched_poses=n, metrics={"ape": {"translation_m": {"rmse": 1.0}}},
                                  zips={"x.zip": b"0" * 1000}, ape_t_s=t, ape_err_m=e, ref_p_m=p,
                                  drift={"t_err_pct": 1.0, "r_err_deg_per_100m": 0.1,
                                         "per_length": {"100": {"t_err_pct": 1.0, "r_err_deg_per_m": 0.001}}})
    evals = {"fused": ev("fused", 0.1), "lidar": ev("lidar", 0.3), "imu_only": ev("imu_only", 5.0)}
    segs = [{"index": 0, "start_m": 0.0, "end_m": 1.0, "start_s": 0.0, "end_s": 10.0, "rmse_m": {"fused": 1.0}}]
    seg = {"by": "time", "length": 10.0, "segments": segs, "worst": [0], "primary": "fused", "secondary": "lidar"}
    cons = {"nees": {"position": {**_series(3), "t_s": t, "values": rng.chisquare(3, n)}},
            "nis": {"lidar": {**_series(6), "t_s": t[::20], "values": rng.chisquare(6, t[::20].size)}}}
    for name, draw, full, lean in (
            ("ape", plots.plot_ape_over_time, (evals, 50.0), (thin.ape_curves(evals), 50.0)),
            ("drift", plots.plot_drift, (evals,), (thin.drift_only(evals),)),
            ("segments", plots.plot_segment_map, (evals, seg), (thin.segment_map(evals, seg), seg)),
            ("consistency", plots.plot_consistency, (cons, 50.0), (thin.consistency(cons), 50.0))):
        draw(tmp_path / f"{name}_full.png", *full)
        draw(tmp_path / f"{name}_lean.png", *lean)
        assert (tmp_path / f"{name}_full.png").read_bytes() == (tmp_path / f"{name}_lean.png").read_bytes(), name
    assert thin.ape_curves(evals)["fused"].ape_err_m.size <= 5002 and not thin.drift_only(evals)["fused"].zips
    assert set(thin.segment_map(evals, seg)) == {"fused", "lidar"}
    assert np.array_equal(thin.envelope(thin.ape_curves(evals)["imu_only"].ape_err_m), np.arange(
        thin.ape_curves(evals)["imu_only"].ape_err_m.size))            # an envelope of an envelope keeps it


def test_compare_ape_draws_smoothed_estimates_and_keeps_unfiltered_colours_apart(monkeypatch, tmp_path):
    """The lidar odometry was drawn in the first variant's blue and the GNSS in the third's green, and a variant's
    smoothed estimate (a row of compare.md) was not drawn."""
    from matplotlib.colors import to_hex

    def ev(scale):
        t = np.arange(50.0)
        return SimpleNamespace(ape_err_m=scale * (1 + t), ape_t_s=t, metrics={"ape": {"translation_m": {"rmse": scale}}})

    runs = [SimpleNamespace(name=f"v{i}", ev=ev(i + 1.0), ev_smoothed=ev(0.5) if i == 1 else None) for i in range(4)]
    figs = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figs.append(fig))
    plots.plot_compare_ape(tmp_path / "a.png", runs, {"lidar": ev(7.0), "gnss": ev(2.0)}, 0.0)
    lines = {ln.get_label().split(" (")[0]: ln for ln in figs[0].axes[0].get_lines()}
    assert set(lines) == {"v0", "v1", "v1 smoothed", "v2", "v3", "lidar odometry", "GNSS"}
    assert lines["v1 smoothed"].get_color() == lines["v1"].get_color() and lines["v1 smoothed"].get_linestyle() == "--"
    variant = {to_hex(lines[f"v{i}"].get_color()) for i in range(4)}
    assert len(variant) == 4 and not variant & {to_hex(lines[n].get_color()) for n in ("lidar odometry", "GNSS")}
    # the second panel: each later variant (and a smoothed one) less the first, in its colour; v1 is 1 + t above v0
    diff = [ln for ln in figs[0].axes[1].get_lines() if len(ln.get_xdata()) > 2]
    assert len(diff) == 4 and figs[0].axes[1].get_yscale() == "symlog"
    by_colour = {(to_hex(ln.get_color()), ln.get_linestyle()): ln for ln in diff}
    v1 = by_colour[(to_hex(lines["v1"].get_color()), "-")]
    np.testing.assert_allclose(v1.get_ydata(), 1 + np.arange(50.0))
    one = [SimpleNamespace(name="v0", ev=ev(1.0), ev_smoothed=None)]
    plots.plot_compare_ape(tmp_path / "b.png", one, {}, 0.0)
    assert len(figs[1].axes) == 1                                  # one variant: nothing to take a difference from
    plt.close("all")


def test_a_log_axis_of_few_decades_labels_its_minor_ticks():
    """An APE of 1-8 m on a log axis showed only '1', a drift of 0.4-0.9 % no label at all (found by a review);
    many decades keep the plain major labels only (the cheap case the consistency plot needs)."""
    import matplotlib.pyplot as plt

    from fusion_eval.report.plots import _no_minor_labels

    def labels(lo, hi):
        fig, ax = plt.subplots()
        ax.plot([0, 1], [lo, hi])
        ax.set_yscale("log")
        _no_minor_labels(ax)
        fig.canvas.draw()
        out = {t.get_text() for t in ax.yaxis.get_ticklabels(minor=True) + ax.yaxis.get_ticklabels() if t.get_text()}
        plt.close(fig)
        return out

    assert {"1", "2", "5"} <= labels(1.0, 8.0)
    assert {"0.5", "0.6", "0.8"} <= labels(0.41, 0.95)
    assert not {"2", "5", "20"} & labels(1e-4, 1e3)


def test_segment_labels_do_not_overlap_and_stay_inside_the_map():
    """Two worst segments at one place had their labels on each other, and a label at the map's edge ran under the
    colour bar (found by a review)."""
    import matplotlib.pyplot as plt

    from fusion_eval.report.plots import _place_labels

    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot([0, 100], [0, 100])
    marks = [("#35 (2.36 m)", (40.0, 10.0)), ("#36 (2.16 m)", (45.0, 12.0)), ("#37 (2.10 m)", (42.0, 11.0)),
             ("#14 (2.14 m)", (99.0, 50.0))]
    _place_labels(fig, ax, marks)
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(r) for t in ax.texts]
    box = ax.get_window_extent(r)
    assert len(boxes) == 4
    assert all(box.x0 <= b.x0 and b.x1 <= box.x1 and box.y0 <= b.y0 and b.y1 <= box.y1 for b in boxes)
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
    plt.close(fig)


def test_the_ape_plot_shades_the_gnss_outages_and_the_imus_gaps(tmp_path):
    """Where on the route the error grows and why (a GNSS outage, a hole where the IMU's filled packets were dropped)
    was only in the report's text (a student's review): ape_over_time.png shades both."""
    from types import SimpleNamespace as NS

    from fusion_eval.report import route_spans

    t = np.r_[np.arange(0.0, 30.0, 0.1), np.arange(31.7, 60.0, 0.1)] + 1000.0
    res = NS(metrics={"gnss_degradation": {"outages_s": [[10.0, 20.0]]}}, cfg={"filter": {"use_gnss": True}},
             filt=NS(fused=NS(t_s=t)))
    spans = route_spans(res)
    assert spans[0] == (10.0, 20.0, "GNSS outage")
    (gap,) = spans[1:]
    assert gap[2] == "no IMU data (gap)" and gap[0] == pytest.approx(29.9) and gap[1] == pytest.approx(31.7)
    res.cfg["filter"]["use_gnss"] = False            # no GNSS fused: its outages are not the filter's
    assert [s[2] for s in route_spans(res)] == ["no IMU data (gap)"]


@pytest.mark.parametrize("n", [0, 1, 2499, 2500, 2501, 5000, 5001, 30001])
def test_thinning_keeps_the_last_point(n):
    """A stride of 13 over 30001 samples kept index 29991: the bias plot's "final" values were 0.09 s old (an
    audit: 76.4 against the filter's final 76.29 deg/h)."""
    from fusion_eval.report import thin

    idx = np.arange(n)[thin.every(n)]
    assert (idx.size == 0) == (n == 0) and idx.size <= 2500
    assert np.array_equal(idx[thin.every(idx.size)], idx)      # thinning what was thinned changes nothing
    if n:
        assert idx[0] == 0 and idx[-1] == n - 1 and np.all(np.diff(idx) > 0)
        t = np.arange(n, dtype=float)
        b = np.c_[t, -t, 2 * t]
        tt, ba, _bg, _s, _ = thin.biases(t, b, b, np.ones((n, 15)))
        assert ba[-1, 0] == n - 1 and tt[-1] == n - 1


def test_one_colour_per_estimate_name_in_every_plot(monkeypatch, tmp_path):
    """evaluate drew fused blue and lidar orange in its trajectories and red and blue in its APE plot, and compare's
    sixth variant took the smoothed estimate's purple (a student's review): named estimates keep their colour in every
    plot, other names and variants take colours no named estimate has."""
    from matplotlib.colors import to_hex

    from fusion_eval.types import PoseSeries

    c = plots.estimate_colors(["orb", "fused", "lidar", "vins"])
    assert c["fused"] == plots.COLORS["fused"] and c["lidar"] == plots.COLORS["lidar"]
    named = {to_hex(v) for v in plots.COLORS.values()}
    assert c["orb"] != c["vins"] and not {to_hex(c["orb"]), to_hex(c["vins"])} & named
    assert not {to_hex(v) for v in plots._VARIANT_COLORS[1:]} & named

    figs = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figs.append(fig))
    t = np.arange(20.0)
    p = np.column_stack([t, 0.1 * t, 0 * t])
    q = np.tile([0.0, 0.0, 0.0, 1.0], (20, 1))
    ref = PoseSeries(t, p, q, source="ref")
    ests = {"lidar": PoseSeries(t, p + 1, q, source="l"), "fused": PoseSeries(t, p + 0.1, q, source="f")}
    plots.plot_generic_trajectories(tmp_path / "t.png", ref, ests)
    evs = {n: SimpleNamespace(ape_err_m=1 + t, ape_t_s=t, metrics={"ape": {"translation_m": {"rmse": 0.76}}}) for n in ests}
    plots.plot_ape_over_time(tmp_path / "a.png", evs, 0.0)
    for fig in figs:
        col = {ln.get_label().split(" (")[0]: to_hex(ln.get_color()) for ln in fig.axes[0].get_lines()}
        assert col["fused"] == to_hex(plots.COLORS["fused"]) and col["lidar odometry"] == to_hex(plots.COLORS["lidar"])
    # legends as the tables print the figure (0.760, not 0.76), outside the axes
    labels = [tx.get_text() for tx in figs[1].axes[0].get_legend().get_texts()]
    assert "fused (RMSE 0.760 m)" in labels
    assert figs[1].axes[0].get_legend().get_bbox_to_anchor().x0 > figs[1].axes[0].get_window_extent().x1 - 1
    plt.close("all")


def test_sweep_keys_set_together_share_a_panel_and_curves_join_only_one_key_changes():
    """noise5's lidar-tight / lidar-loose set the position and the rotation noise together: two identical panels; a
    setting that also switched the adaptation off was joined to the default, which has it on; with trials the
    std had no bar (a student's review)."""
    k1, k2, other = "lidar.relative_pos_std_frac", "lidar.relative_att_std_deg", "lidar.noise_adapt"
    base = {"dataset": "/d/kitti-00", "variant": "eskf", "status": "ok"}
    rows = [{**base, "setting": "default", k1: "", k2: "", other: "", METRIC: 0.75, f"{METRIC}_std": 0.08},
            {**base, "setting": "tight", k1: 0.003, k2: 0.02, other: "", METRIC: 0.76, f"{METRIC}_std": 0.08},
            {**base, "setting": "loose", k1: 0.03, k2: 0.2, other: "", METRIC: 0.77, f"{METRIC}_std": 0.08},
            {**base, "setting": "loose-noadapt", k1: 0.05, k2: 0.3, other: "none", METRIC: 0.90, f"{METRIC}_std": 0.07}]
    fig = plots.sweep_params_figure(rows, [k1, k2, other], METRIC, {("/d/kitti-00", "eskf"): {k1: 0.01, k2: 0.05}})
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 2                                     # the overview and one panel for both keys
    panel = visible[1]
    assert f"set together with {k2}" in panel.get_xlabel()
    curve = next(ln for ln in panel.lines if ln.get_linestyle() == "-" and ln.get_gid() is None)
    assert sorted(curve.get_xdata()) == [0.003, 0.01, 0.03]      # not through loose-noadapt
    assert panel.containers and len(panel.containers[0].lines[2][0].get_segments()) == 3   # a bar per setting
    plt.close("all")


def test_a_grids_independent_keys_keep_a_panel_each():
    """Every setting of a grid sets every key: grouping keys by the settings that set them put grid2d's two keys in one
    panel and hid the second (a review). Keys are grouped only where their values determine each other."""
    k1, k2 = "imu.gyro_noise_dps_sqrthz", "lidar.relative_pos_std_frac"
    base = {"dataset": "/d/kitti-00", "variant": "eskf", "status": "ok"}
    rows = [{**base, "setting": "default", k1: "", k2: "", METRIC: 0.75}]
    rows += [{**base, "setting": f"{k1}={a},{k2}={b}", k1: a, k2: b, METRIC: 0.7 + a + b}
             for a in (0.05, 0.1, 0.2) for b in (0.005, 0.01)]
    fig = plots.sweep_params_figure(rows, [k1, k2], METRIC, None)
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 3 and [ax.get_xlabel() for ax in visible[1:]] == [k1, k2]
    plt.close("all")


def test_a_narrow_value_axis_labels_every_tick_apart():
    """A 0.004-wide axis read 0.797, 0.798, 0.798, 0.799 with three significant digits (a review): as many digits as
    the ticks need."""
    import matplotlib.pyplot as plt

    from fusion_eval.report import plots

    fig, ax = plt.subplots()
    vals = [0.7965, 0.7975, 0.7985, 0.7995, 0.8005]
    ax.plot(vals, range(5))
    plots._value_axis(ax, vals, "x", at_values=False)
    fig.canvas.draw()
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert len(set(labels)) == len(labels) and len(labels) >= 3, labels
    plt.close(fig)
    fig, ax = plt.subplots()
    ax.plot([0.01, 1.0], [1, 2])
    plots._value_axis(ax, [0.01, 0.1, 1.0], "x")
    fig.canvas.draw()
    assert [t.get_text() for t in ax.get_xticklabels()] == ["0.01", "0.1", "1"]
    plt.close(fig)


def test_dead_reckoning_far_above_the_others_is_drawn_off_the_scale(monkeypatch, tmp_path):
    """Dead reckoning's 1e4 m squeezed the fused, lidar and GNSS errors into two of the APE plot's seven decades,
    and its 900 % the fused against the lidar drift (0.49 against 0.46 %) into one line: the axis ends at ten times
    the others' largest error, and the legend says dead reckoning leaves it (a plot review). Not when it is near
    them (a short drive), nor without it."""
    from types import SimpleNamespace

    figs = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figs.append(fig))
    t = np.arange(100.0)
    drift = {"per_length": {"100": {"t_err_pct": 0.5, "r_err_deg_per_m": 0.002}}, "t_err_pct": 0.5,
             "r_err_deg_per_100m": 0.2}

    def ev(err, pct):
        return SimpleNamespace(ape_err_m=err, ape_t_s=t, metrics={"ape": {"translation_m": {"rmse": float(err.max())}}},
                               drift={**drift, "t_err_pct": pct,
                                      "per_length": {"100": {"t_err_pct": pct, "r_err_deg_per_m": 0.002}}})

    evals = {"fused": ev(0.5 + 0 * t, 0.49), "lidar": ev(1 + 0.1 * t, 0.46), "imu_only": ev(0.01 * t ** 3, 916.8)}
    plots.plot_ape_over_time(tmp_path / "a.png", evals, 0.0)
    plots.plot_drift(tmp_path / "d.png", evals)
    ax = figs[0].axes[0]
    assert ax.get_ylim()[1] == pytest.approx(10 * 10.9)
    labels = [tx.get_text() for tx in ax.get_legend().get_texts()]
    assert any(lb.startswith("IMU dead reckoning") and "off the scale from 23 s" in lb for lb in labels)
    assert figs[1].axes[0].get_ylim()[1] == pytest.approx(4.9)                  # 10 x the lidar's 0.49 %
    assert any("(off the scale)" in tx.get_text() for tx in figs[1].axes[0].get_legend().get_texts())
    assert not any("off the scale" in tx.get_text() for tx in figs[1].axes[1].get_legend().get_texts())
    near = {**evals, "imu_only": ev(2 + 0.1 * t, 3.0)}
    plots.plot_ape_over_time(tmp_path / "b.png", near, 0.0)
    assert figs[2].axes[0].get_ylim()[1] > 11.9 and not any(
        "off the scale" in tx.get_text() for tx in figs[2].axes[0].get_legend().get_texts())
    plt.close("all")


def test_consistency_plot_shows_sparse_innovations_their_window_mean_and_keeps_its_axis_on_the_bounds():
    """1 Hz GNSS NIS drawn in pixels was invisible, and a first epoch's 1e-4 squeezed the 95 % bounds into a third of
    the axis (a plot review): sparse innovations are dots, their 10 s mean a step line, and the axis ends at a tenth of
    the lower bound (or lower, where over 5 % of the values are)."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 300.0, 1.0)
    nis = rng.chisquare(3, t.size)
    nis[0] = 1e-6
    nees = rng.chisquare(3, t.size)
    nees[0] = 1e-4
    cons = {"nees": {"position": {**_series(3), "t_s": t, "values": nees}},
            "nis": {"gnss": {**_series(3), "t_s": t, "values": nis}}}
    fig = plots.consistency_figure(cons, 0.0)
    ax_nees, ax_gnss = fig.axes[:2]
    dots = [ln for ln in ax_gnss.lines if ln.get_marker() == "."]
    assert len(dots) == 1 and dots[0].get_markersize() >= 3
    lo = _series(3)["bounds_95"][0]
    assert ax_nees.get_ylim()[0] == pytest.approx(min(0.1 * lo, np.percentile(nees, 5)) / 1.3)
    steps = [p for p in ax_gnss.patches if p.get_label().startswith("NIS mean over 10 s")]
    assert len(steps) == 1
    plt.close("all")


def test_error_plots_shade_the_gnss_outages_and_imu_holes(monkeypatch):
    """An outage grew the East band to +/-5 m on the error plot with no word of it there; only the APE plot shaded
    it (a plot review). The run's spans are shaded on every error panel, each label once in the legend, on the error
    plot's own time axis (from its first stamp inside the truth)."""
    from fusion_eval import report

    gt = _circle()
    av = fused_att_vel_error(gt, _filter_output(gt, np.random.default_rng(3)))
    spans = [(1.0, 3.0, "GNSS outage"), (4.0, 4.5, "no IMU data (gap)"), (6.0, 6.5, "no IMU data (gap)")]
    fig = plots.att_vel_error_figure(thin.att_vel(av), spans)
    for ax in fig.axes:
        assert len([p for p in ax.patches if p.get_x() in (1.0, 4.0, 6.0)]) == 3
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels.count("GNSS outage") == 1 and labels.count("no IMU data (gap)") == 1
    # write_filter_outputs moves them onto the error plots' clock: 2 s later start there, 2 s earlier spans
    jobs = []
    monkeypatch.setattr(report, "draw", lambda *a: jobs.append(a))
    err = {"t_s": gt.t_s[20:], "err_w_m": np.zeros((gt.t_s.size - 20, 3)), "sigma_w_m": np.ones((gt.t_s.size - 20, 3)),
           "att_vel": {**av, "t_s": av["t_s"][20:], **{k: av[k][20:] for k in ("att_err_b_rad", "att_sigma_b_rad",
                                                                               "vel_err_w_mps", "vel_sigma_w_mps")}}}
    filt = SimpleNamespace(fused=gt, accel_bias_b=np.zeros((gt.t_s.size, 3)), gyro_bias_b=np.zeros((gt.t_s.size, 3)),
                           sigma=np.ones((gt.t_s.size, 15)))
    out = SimpleNamespace(path=lambda name: name)
    report.write_filter_outputs(out, {"groundtruth": gt}, filt, err, True, spans=spans, tums_written=("groundtruth",))
    shift = gt.t_s[0] - gt.t_s[20]
    (sig,) = [j for j in jobs if j[0] == "plot_error_sigma"]
    assert sig[-1] == [(a + shift, b + shift, lb) for a, b, lb in spans]
    plt.close("all")


def test_a_2d_grids_panels_join_the_settings_of_each_value_of_the_other_key(tmp_path):
    """Three dots per value with nothing saying which value of the other key each was: an interaction did not show
    (a plot review). Each value of the other key is a labelled line of its own."""
    kx, ky = "imu.gyro_noise_dps_sqrthz", "lidar.relative_pos_std_frac"
    base = {"dataset": "/d/kitti-00", "variant": "eskf", "status": "ok"}
    rows = [{**base, "setting": "default", kx: "", ky: "", METRIC: 0.76}]
    for x in (0.03, 0.1, 0.3):
        for y in (0.003, 0.01, 0.03):
            rows.append({**base, "setting": f"{x:g} / {y:g}", kx: x, ky: y, METRIC: 0.7 + x + 2 * x * y})
    fig = plots.sweep_params_figure(rows, [kx, ky], METRIC)
    panels = [ax for ax in fig.axes if ax.get_visible()][1:]
    for ax, other in zip(panels, (ky, kx)):
        lines = [ln for ln in ax.lines if ln.get_gid() == "interaction"]
        assert sorted(ln.get_label() for ln in lines) == sorted(f"{other} = {v:g}" for v in
                                                                 ((0.003, 0.01, 0.03) if other == ky else (0.03, 0.1, 0.3)))
        assert all(len(ln.get_xdata()) == 3 for ln in lines)
    fig.savefig(tmp_path / "s.png")
    plt.close("all")


def test_compare_biases_give_each_sensor_axis_its_panel_with_every_variant(monkeypatch, tmp_path):
    """15-18 lines in two panels, the axes told apart by a line style the legend did not key (a plot review): one
    panel per sensor and axis, each with every variant in its colour, one legend of the variants."""
    figs = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figs.append(fig))
    t = np.arange(0.0, 10.0, 0.1)

    def run(name, k):
        return SimpleNamespace(name=name, filt=SimpleNamespace(fused=SimpleNamespace(t_s=t),
                                                               accel_bias_b=np.full((t.size, 3), 0.001 * k),
                                                               gyro_bias_b=np.full((t.size, 3), 1e-5 * k)))

    plots.plot_compare_biases(tmp_path / "b.png", [run(f"v{k}", k) for k in range(5)])
    fig = figs[0]
    assert len(fig.axes) == 6 and all(len(ax.get_lines()) == 5 for ax in fig.axes)
    assert [t.get_text() for t in fig.legends[0].get_texts()] == [f"v{k}" for k in range(5)]
    assert fig.axes[0].get_title() == "accelerometer, x (body)" and fig.axes[5].get_title() == "gyro, z (body)"
    plt.close("all")


def test_compare_body_velocity_says_how_far_each_variant_is_from_the_truth(monkeypatch, tmp_path):
    """The truth drawn thick on top hid the variant that followed it best, and nothing said which did (a review):
    the truth is a thin dashed line over them, and each variant's legend gives its RMS from it."""
    figs = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figs.append(fig))
    t = np.arange(0.0, 10.0, 0.1)
    gt = SimpleNamespace(t_s=t)
    gt_vb = np.zeros((t.size, 3))
    runs = [SimpleNamespace(name=f"v{k}", filt=SimpleNamespace(fused=SimpleNamespace(t_s=t))) for k in range(2)]
    body = [np.column_stack([np.ones_like(t), np.full_like(t, 0.1 * (k + 1)), np.full_like(t, 0.02)]) for k in range(2)]
    plots.plot_compare_body_velocity(tmp_path / "v.png", runs, body, gt, gt_vb)
    labels = [x.get_text() for x in figs[0].legends[0].get_texts()]
    assert labels == ["ground truth", "v0 (RMS from the truth: lateral 0.100, vertical 0.020 m/s)",
                      "v1 (RMS from the truth: lateral 0.200, vertical 0.020 m/s)"]
    plt.close("all")


def test_the_trajectory_plot_has_the_height_over_time(monkeypatch, tmp_path):
    """A top view alone hid a flight's 60 m climb (a non-car review): a panel of the height over time, its axis fitting
    every estimate but dead reckoning."""
    from fusion_eval.report import thin

    figs = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figs.append(fig))
    t = np.arange(0.0, 60.0, 0.1)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1))
    climb = np.column_stack([np.sin(t), np.cos(t), t])                          # up 60 m over a 2 m circle
    series = {"groundtruth": PoseSeries(t, climb, q), "fused": PoseSeries(t, climb + [0.0, 0.0, 0.5], q),
              "imu_only": PoseSeries(t, climb + [0.0, 0.0, 1e4], q)}
    paths, extent = thin.paths(series)
    assert paths["fused"].shape == (t.size, 4)
    plots.plot_trajectories(tmp_path / "t.png", paths, extent)
    top, height = figs[0].axes
    assert height.get_ylabel() == "Up [m]" and len(height.get_lines()) == 3
    lo, hi = height.get_ylim()
    assert lo < 0.0 and 60.0 < hi < 100.0                                       # the climb, not dead reckoning's 1e4
    plt.close("all")
