"""PNG plots of a run (matplotlib, Agg backend, no screen needed)."""

from __future__ import annotations

import itertools
import textwrap
import warnings
from pathlib import Path

import matplotlib
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
import numpy as np

# A fixed title height: matplotlib otherwise measures every axis' tick labels at each draw to lift titles
# over them (none of these plots has ticks on top), which was a third of the drawing time.
_RC = {"axes.titley": 1.0}
_FIGURE_KW = ("figsize", "dpi", "layout", "constrained_layout", "tight_layout")


def subplots(*args, **kw):
    """``plt.subplots`` without pyplot: a ``Figure`` of its own on an Agg canvas of its own, so
    that drawing the plots neither switches the host's backend nor keeps figures in pyplot's registry, and the fixed
    title height applies to these axes only (as an API call, ``res.write()`` once set the host's backend to Agg and
    its ``axes.titley``: a notebook's inline figures stopped showing; a review)."""
    fig_kw = {k: kw.pop(k) for k in _FIGURE_KW if k in kw}
    with matplotlib.rc_context(_RC):
        fig = Figure(**fig_kw)
        FigureCanvasAgg(fig)            # its own Agg canvas (measured text for label placement), not the host's
        return fig, fig.subplots(*args, **kw)

from ..evaluation.keys import RANK_COLUMN, is_number  # noqa: E402
from ..resources import dataset_label  # noqa: E402
from ..filters.layout import CANONICAL  # noqa: E402
from . import thin  # noqa: E402

BA_ID, BG_ID = (CANONICAL.start(b) for b in ("BA", "BG"))

COLORS = {"groundtruth": "black", "fused": "tab:red", "smoothed": "tab:purple", "lidar": "tab:blue", "gnss": "tab:green",
          "imu_only": "tab:orange"}
LABELS = {"groundtruth": "ground truth", "fused": "fused", "smoothed": "smoothed", "lidar": "lidar odometry",
          "gnss": "GNSS", "imu_only": "IMU dead reckoning"}
_META = {"Software": None}                                    # no version string in the PNG: same inputs, same bytes
# estimates of other names (a user's own files in evaluate, compare's variants after the first): colours no named
# estimate has, so that red, blue, green, orange and purple mean fused, lidar, GNSS, dead reckoning and smoothed in
# every plot (a student's review: evaluate drew fused blue and lidar orange in one plot, red and blue in the next)
OTHER_COLORS = ["tab:cyan", "tab:brown", "tab:pink", "tab:olive", "navy", "darkgoldenrod", "teal", "magenta", "tab:gray"]


def estimate_colors(names) -> dict:
    """One colour per estimate name, the same in every plot of a report: :data:`COLORS` for the named estimates,
    :data:`OTHER_COLORS` in order for the rest."""
    others = itertools.cycle(OTHER_COLORS)
    return {n: COLORS[n] if n in COLORS else next(others) for n in names}


def _legend_outside(fig, ax, right: float = 0.78, **kw) -> None:
    """The legend right of the axes, where it hides no data (inside, 'best' still covered the errors below 0.5 m over
    the drive's last 160 s: a student's review)."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, **kw)
    fig.subplots_adjust(left=0.07, right=right)



def _no_minor_labels(ax) -> None:
    """Log axes label their ticks in mathtext (10^k) by default, and label minor ticks; laying those labels out
    dominated the drawing time. Plain numbers; minor ticks at 1, 2 and 5 of each decade (matplotlib's eight per
    decade were 150 tick objects on the consistency plot, a quarter of its drawing), labelled only where the axis
    spans so few decades that its major ticks alone would leave it unreadable (an APE of 1-8 m showed only '1')."""
    from matplotlib.ticker import FuncFormatter

    def minor(v, _pos):
        lo, hi = sorted(ax.yaxis.get_view_interval())
        if lo <= 0 or v <= 0:
            return ""
        decades = np.log10(hi / lo)
        digit = round(v / 10 ** np.floor(np.log10(v) + 1e-9))
        return f"{v:g}" if decades < 1.2 or (decades < 3 and digit in (2, 5)) else ""

    ax.yaxis.set_minor_locator(_LogMinor())
    ax.yaxis.set_minor_formatter(FuncFormatter(minor))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))


class _LogMinor(matplotlib.ticker.LogLocator):
    """Minor ticks of a log axis: 1, 2 and 5 of each decade, and every digit within an axis of under 1.5 decades
    (0.6 to 0.9 has no 1, 2 or 5 to show)."""

    def __init__(self):
        super().__init__(subs=(1.0, 2.0, 5.0))

    def tick_values(self, vmin, vmax):
        lo, hi = sorted((vmin, vmax))
        self.set_params(subs=np.arange(1.0, 10.0) if lo > 0 and hi / lo < 10 ** 1.5 else (1.0, 2.0, 5.0))
        return super().tick_values(vmin, vmax)


def _save(fig, path: Path) -> None:
    # zlib level 1 instead of 6: cheaper encoding (0.18 s of 7 plots at 6), files ~15 % larger
    fig.savefig(path, dpi=110, metadata=_META, pil_kwargs={"compress_level": 1})
    fig.clear()


HEIGHT_POINTS = 2000      # not a state index: the height panel's points per estimate (the envelope's)


def plot_trajectories(path: Path, paths: dict, extent: tuple, start_frame: bool = False) -> None:
    """Top view (East/North) of every estimate with the ground truth (``paths``, ``extent``:
    :func:`fusion_eval.report.thin.paths`); axes fit the ground truth so a diverging dead-reckoning track does
    not squash the rest."""
    fig, (ax, axh) = subplots(2, 1, figsize=(8, 8.4), gridspec_kw={"height_ratios": [3.4, 1]})
    t0 = min((p[0, 3] for p in paths.values() if p.shape[1] > 3 and len(p)), default=0.0)
    for name in ("groundtruth", "lidar", "imu_only", "gnss", "fused", "smoothed"):
        p = paths.get(name)
        if p is None:
            continue
        if name == "gnss":
            ax.plot(p[:, 0], p[:, 1], ".", ms=2.5, color=COLORS[name], label=LABELS[name])
        else:
            ax.plot(p[:, 0], p[:, 1], "-", lw=1.6 if name == "groundtruth" else 1.1,
                    color=COLORS[name], label=LABELS[name], alpha=0.9)
        if p.shape[1] > 3:          # the height over time: a top view hid a flight's 60 m climb (a non-car review)
            k = thin.envelope(p[:, 2], HEIGHT_POINTS)       # a 900-pixel panel: its peaks kept, not 20,000 points
            axh.plot(p[k, 3] - t0, p[k, 2], "." if name == "gnss" else "-", ms=2.0,
                     lw=1.6 if name == "groundtruth" else 1.0, color=COLORS[name], alpha=0.9)
    lo, hi, start = extent
    ax.plot(start[0], start[1], "k^", ms=8, label="start")
    pad = 0.08 * (hi[:2] - lo[:2]).max() + 5.0          # not a state index: East and North
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal", adjustable="box")
    # without GNSS or truth the world is the start's levelled frame: x the body's forward axis at the start
    ax.set_xlabel(_plane_labels(start_frame)[0])
    ax.set_ylabel(_plane_labels(start_frame)[1])
    ax.set_title("Trajectories (top view, the start's levelled frame)" if start_frame else "Trajectories (top view, ENU)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    # the height axis fits every estimate but dead reckoning (its kilometres would flatten the rest)
    ups = [p[:, 2] for n, p in paths.items() if n != "imu_only" and p.shape[1] > 3 and len(p)]
    if ups:
        zlo, zhi = min(float(np.nanmin(u)) for u in ups), max(float(np.nanmax(u)) for u in ups)
        hpad = 0.08 * (zhi - zlo) + 0.5
        axh.set_ylim(zlo - hpad, zhi + hpad)
    axh.set_xlabel("time since start [s]")
    axh.set_ylabel("Up [m]")
    axh.set_title("Height", fontsize=9, loc="left")
    axh.grid(alpha=0.3)
    fig.subplots_adjust(left=0.12, right=0.97, top=0.95, bottom=0.06, hspace=0.22)
    _save(fig, path)


def _metres(x: float) -> str:
    """An RMSE for a legend, as the report's tables print it: three decimals (0.760 m, where '0.76' read as another
    figure than the table's 0.760: a student's review), whole metres from 1000 m (dead reckoning's 13258 m)."""
    return f"{x:.0f} m" if abs(x) >= 1000 else f"{x:.3f} m"


def _log_floor(errs) -> float:
    """The floor of a log-scale error plot: for each estimate half its smallest positive error (an anchored start is
    exactly 0), but no more than three decades below its largest; the lowest over the estimates. Not a fixed
    millimetre, which flattened a sub-millimetre estimate onto the axis, nor an anchored start's first micrometres,
    which gave 3-12 of the axis' decades to the drive's first second (a plot review: a simulated drive's axis reached
    1e-9 m, its errors lived between 0.1 and 10 m). The minimum and maximum are the thinned curves' too
    (:func:`fusion_eval.report.thin.envelope`), so the floor is the same drawn from either."""
    floors = [max(0.5 * float(np.min(e[e > 0])), 1e-3 * float(np.max(e))) for e in errs
              if e is not None and np.any(e > 0)]
    return max(min(floors), 1e-9) if floors else 1e-3


OFF_SCALE = 30.0       # dead reckoning beyond this factor of the other estimates' largest error leaves the plot's scale
CEILING = 10.0         # ... which then ends at this factor of theirs


def _ceiling(others_max: float, outlier_max: float) -> float | None:
    """The top of a log-scale error axis that IMU dead reckoning would otherwise stretch over decades of nothing, or
    None: it grows to 1e4 m on kitti-00 where the other estimates live between 0.1 and 10 m, which it squeezed into
    two of the axis' seven decades (a plot review)."""
    if not (np.isfinite(others_max) and others_max > 0 and outlier_max > OFF_SCALE * others_max):
        return None
    return CEILING * others_max


def _gapped(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``t, y`` with a NaN in each gap of more than five median steps, so that the line breaks there instead of
    drawing a straight segment across a stretch with no matched pose."""
    if t.size < 3:
        return t, y
    dt = np.diff(t)
    cut = np.flatnonzero(dt > 5.0 * np.median(dt)) + 1
    if cut.size == 0:
        return t, y
    return np.insert(t.astype(float), cut, np.nan), np.insert(y.astype(float), cut, np.nan)


def plot_ape_over_time(path: Path, evals: dict, t0: float, x_label: str = "time since start [s]", spans=()) -> None:
    """APE translation of each estimate over time (log scale: dead reckoning grows by orders of magnitude);
    ``x_label``: what the stamps count (frames, for KITTI poses without a times file); ``spans``: ``(start, end,
    label)`` on the plot's time axis, shaded (the GNSS outages, the IMU's gaps: where on the route the error grows and
    why, which a reader had to find in the report's text)."""
    fig, ax = subplots(figsize=(12, 4.5))
    _shade(ax, spans)
    known = [n for n in ("imu_only", "gnss", "lidar", "fused", "smoothed") if n in evals]
    floor = _log_floor([ev.ape_err_m for ev in evals.values()])
    colors = estimate_colors(list(evals))
    drawn = {n: ev for n, ev in evals.items() if ev.ape_err_m is not None and ev.ape_err_m.size}
    top = _ceiling(max((float(np.max(ev.ape_err_m)) for n, ev in drawn.items() if n != "imu_only"), default=np.nan),
                   float(np.max(drawn["imu_only"].ape_err_m)) if "imu_only" in drawn else np.nan)
    for name in known + [n for n in evals if n not in known]:
        ev = evals[name]
        if name not in drawn:
            continue
        rmse = ev.metrics["ape"]["translation_m"]["rmse"]
        style = "." if name == "gnss" else "-"
        k = thin.envelope(ev.ape_err_m)
        label = f"{LABELS.get(name, name)} (RMSE {_metres(rmse)})"
        if name == "imu_only" and top is not None:
            t_out = ev.ape_t_s[np.argmax(ev.ape_err_m > top)] - t0
            label = f"{label}\n  off the scale from {t_out:.0f} s"
        ax.plot(*_gapped(ev.ape_t_s[k] - t0, np.maximum(ev.ape_err_m[k], floor)), style, ms=2.5, lw=1.0,
                color=colors[name], label=label)
    ax.set_yscale("log")
    if top is not None:
        ax.set_ylim(top=top)
    _no_minor_labels(ax)
    ax.set_xlabel(x_label)
    ax.set_ylabel("APE translation [m]")
    ax.set_title("Absolute position error against ground truth")
    ax.grid(alpha=0.3, which="both")
    _legend_outside(fig, ax, fontsize=8)
    _save(fig, path)


MG_MPS2 = 9.80665e-3                  # 1 mg (thousandth of standard gravity) in m/s^2
DEG_H_RPS = np.pi / 180 / 3600        # 1 deg/h in rad/s


def _bias_limits(b: np.ndarray, s3: np.ndarray, extra: list[np.ndarray]) -> tuple[float, float]:
    """y-limits that show the estimate (and the truth) whole and the +/-3 sigma where it is informative: the
    first sigma, the prior's, is often ten times the bias and would squash the estimate into a line."""
    core = np.concatenate([b, *extra])
    core = core[np.isfinite(core)]
    if core.size == 0:
        return -1.0, 1.0
    lo, hi = float(core.min()), float(core.max())
    band = s3[np.isfinite(s3)]
    if band.size:
        half = float(np.percentile(band, 50))      # the sigma of the settled filter, not of its prior
        lo, hi = min(lo, float(np.median(b)) - half), max(hi, float(np.median(b)) + half)
    pad = 0.08 * (hi - lo) if hi > lo else max(abs(hi), 1e-6)
    return lo - pad, hi + pad


def biases_figure(t_s: np.ndarray, ba: np.ndarray, bg: np.ndarray, sigma: np.ndarray, truth=None):
    """The figure of :func:`plot_biases`: a 2 x 3 grid, accelerometer x/y/z [mg] over gyro x/y/z [deg/h], each
    axis with its own +/-3 sigma band and limits; ``truth`` (``t_s``, ``accel_b_mps2``, ``gyro_b_rps`` on the
    filter's clock, :class:`fusion_eval.datasets.truth.TruthBiases`) overlaid where given."""
    t_s, ba, bg, sigma, truth = thin.biases(t_s, ba, bg, sigma, truth)       # as given when thinned already
    t0 = float(t_s[0])
    t = t_s - t0
    tt = None if truth is None else truth.t_s - t0
    fig, axes = subplots(2, 3, figsize=(13, 6.5), sharex=True)
    rows = ((ba, BA_ID, MG_MPS2, "mg", "accelerometer", None if truth is None else truth.accel_b_mps2),
            (bg, BG_ID, DEG_H_RPS, "deg/h", "gyro", None if truth is None else truth.gyro_b_rps))
    for r, (b_all, sl, unit_si, unit, what, tb) in enumerate(rows):
        # one panel per axis, all in the fused estimate's colour (red, green, blue per axis read as the fused, GNSS
        # and lidar estimates of the other plots: a plot review)
        for i, (axis, c) in enumerate(zip("xyz", (COLORS["fused"],) * 3)):
            ax = axes[r, i]
            b, s3 = b_all[:, i] / unit_si, 3 * sigma[:, sl + i] / unit_si
            ax.fill_between(t, b - s3, b + s3, color=c, alpha=0.12, lw=0)
            ax.plot(t, b + s3, color=c, lw=0.5, ls="--", label="estimate +/- 3 sigma")
            ax.plot(t, b - s3, color=c, lw=0.5, ls="--")
            ax.plot(t, b, color=c, lw=1.2, label="estimate")
            extra = []
            title = f"{what} {axis}: final {b[-1]:.3g} +/- {s3[-1]:.2g} {unit} (3 sigma)"
            if tb is not None and tb.shape[0]:
                bt = tb[:, i] / unit_si
                ax.plot(tt, bt, color="black", lw=1.0, ls=(0, (4, 2)), label="true bias (simulator)")
                extra.append(bt)
                title += f", true {bt[-1]:.3g}"
            ax.set_ylim(*_bias_limits(b, s3, extra))
            ax.set_title(title, fontsize=8, loc="left")
            ax.set_ylabel(f"{what} bias {axis} [{unit}]", fontsize=9)
            ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time since start [s]")
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle("Estimated IMU biases (body frame) with their +/-3 sigma (dashed; the first seconds' prior runs off "
                 f"the scale)\n1 mg = {MG_MPS2:g} m/s^2; 1 deg/h = {DEG_H_RPS:.3g} rad/s", fontsize=10)
    fig.subplots_adjust(left=0.06, right=0.99, top=0.89, bottom=0.13, hspace=0.3, wspace=0.28)
    return fig


def plot_biases(path: Path, t_s: np.ndarray, ba: np.ndarray, bg: np.ndarray, sigma: np.ndarray, truth=None) -> None:
    """Estimated IMU biases with their +/-3 sigma, one panel per axis, and the true biases where known
    (``truth``: a simulated drive's, :func:`fusion_eval.datasets.truth.truth_imu_biases`)."""
    _save(biases_figure(t_s, ba, bg, sigma, truth), path)


def _shade(ax, spans, legend: bool = True) -> None:
    """The route's spans (``(start, end, label)``, :func:`fusion_eval.report.spans_of`) on a time axis: the GNSS
    outages gold, the IMU's holes cyan, each label once in the legend."""
    shaded: set = set()
    for a, b, label in spans:
        # (orange is dead reckoning's, purple the smoother's; the holes cyan: grey vanished in the grey 3-sigma band, a review)
        color = "gold" if label.startswith("GNSS") else "tab:cyan"
        ax.axvspan(a, b, color=color, alpha=0.18, lw=0, label=None if (label in shaded or not legend) else label)
        shaded.add(label)


def error_sigma_panels(axes, d: dict, names, unit: str, scale: float = 1.0, titles=None, spans=()) -> None:
    """One axis per column of ``d["err"]`` (N, 3) (``d``: :func:`fusion_eval.report.thin.error_sigma`): the
    filter's +/-3 sigma as a grey band, the error over it, the smoother's error and sigma where given, and the
    share of epochs inside 3 sigma in the title. ``scale``: SI to the unit shown; ``names`` label the y axes,
    ``titles`` (default: the names) open the titles."""
    t_s, err, sigma, smoothed = d["t_s"], d["err"], d["sigma"], d["smoothed"]
    inside_f, inside_s = d["inside"]
    t = t_s - t_s[0]
    for i, (ax, name, what) in enumerate(zip(axes, names, titles or names)):
        _shade(ax, spans, legend=i == 0)
        s3 = 3 * sigma[:, i] * scale
        ax.fill_between(t, -s3, s3, color="tab:gray", alpha=0.3, lw=0, label="+/-3 sigma (filter)")
        ax.plot(t, err[:, i] * scale, color=COLORS["fused"], lw=0.9, label="fused - ground truth")
        # 99.7 % is what a consistent filter's Gaussian error gives: without it '95 % inside' read as fine (a review)
        title = (f"{what}: {inside_f[i]:.1f} % of epochs inside 3 sigma (99.7 % if consistent)" if np.isfinite(inside_f[i])
                 else f"{what}: the filter has no sigma for this state")
        if smoothed is not None:
            e, sg = smoothed[0][:, i] * scale, 3 * smoothed[1][:, i] * scale
            ax.plot(t, sg, color=COLORS["smoothed"], lw=0.6, ls="--", label="+/-3 sigma (smoothed)")
            ax.plot(t, -sg, color=COLORS["smoothed"], lw=0.6, ls="--")
            ax.plot(t, e, color=COLORS["smoothed"], lw=0.9, label="smoothed - ground truth")
            title += f" (smoothed: {inside_s[i]:.1f} %)"
        # limits from the errors and the band's common width: a sigma spike at a gap in the data (or the prior's
        # first seconds) would otherwise flatten the errors into a line
        shown = np.abs(err[:, i] * scale) if smoothed is None else np.abs(np.r_[err[:, i], smoothed[0][:, i]] * scale)
        lim = max(float(np.nanmax(shown, initial=0.0)), float(np.nanpercentile(s3, 98)) if np.isfinite(s3).any() else 0.0)
        if lim > 0:
            ax.set_ylim(-1.08 * lim, 1.08 * lim)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.set_title(title, fontsize=9, loc="left")
        ax.grid(alpha=0.3)


def plot_error_sigma(path: Path, d: dict, spans=()) -> None:
    """Fused position error per ENU axis with the filter's own +/-3 sigma per axis (``d``:
    :func:`fusion_eval.report.thin.error_sigma`): is the covariance honest? The smoother's error and sigma at
    the same stamps, where given, drawn over it; ``spans`` (on this plot's time axis) shaded."""
    smoothed = d["smoothed"]
    fig, axes = subplots(3, 1, figsize=(10, 7), sharex=True)
    error_sigma_panels(axes, d, ("East", "North", "Up"), "m", spans=spans)
    axes[0].legend(loc="upper right", fontsize=8, ncol=2 if smoothed is not None else 1)
    axes[-1].set_xlabel("time since start [s]")
    fig.suptitle("Position error with its own +/-3 sigma" + (" (filter and smoother)" if smoothed is not None else ""))
    fig.subplots_adjust(left=0.08, right=0.98, top=0.9, bottom=0.08, hspace=0.35)
    _save(fig, path)


ATT_NAMES = ("roll", "pitch", "yaw")
ATT_TITLES = ("roll error (about body x)", "pitch error (about body y)", "yaw error (about body z)")
VEL_NAMES = ("East", "North", "Up")
VEL_TITLES = ("East velocity error", "North velocity error", "Up velocity error")


def att_vel_error_figure(av: dict, spans=()):
    """The figure of :func:`plot_att_vel_error_sigma` (``av``: :func:`fusion_eval.report.thin.att_vel`):
    attitude error (left column, deg) and velocity error (right column, m/s; absent when the estimate has no
    velocity) with the filter's +/-3 sigma."""
    has_vel = av.get("vel") is not None
    fig, axes = subplots(3, 2 if has_vel else 1, figsize=(14 if has_vel else 9, 7.5), sharex=True, squeeze=False)
    error_sigma_panels(axes[:, 0], av["att"], ATT_NAMES, "deg", scale=180 / np.pi, titles=ATT_TITLES, spans=spans)
    title = ("Attitude error Log(R_gt^T R_fused), body frame (x, y, z = roll, pitch, yaw for a forward-left-up IMU), "
             "with the filter's +/-3 sigma")
    if has_vel:
        error_sigma_panels(axes[:, 1], av["vel"], VEL_NAMES, "m/s", titles=VEL_TITLES, spans=spans)
        title += f"\nvelocity error: fused minus true ENU velocity; true velocity: {av['vel_truth']}"
    for ax in axes[-1]:
        ax.set_xlabel("time since start [s]")
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=2 if av["att"]["smoothed"] is not None else 1)
    fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0.07, right=0.99, top=0.89, bottom=0.07, hspace=0.35, wspace=0.18)
    return fig


def plot_att_vel_error_sigma(path: Path, av: dict, spans=()) -> None:
    """Fused attitude and velocity errors against the ground truth with the filter's own +/-3 sigma (``av``:
    :func:`fusion_eval.report.thin.att_vel` of :func:`fusion_eval.evaluation.run_metrics.fused_att_vel_error`):
    the position plot's question for the other two blocks of the state; ``spans`` shaded."""
    _save(att_vel_error_figure(av, spans), path)


# the unfiltered estimates beside variants: in their colours of a run's plots, which no variant has
_UNFILTERED = {"lidar": (COLORS["lidar"], ":"), "gnss": (COLORS["gnss"], ".")}   # as in a run's plots
# the first variant in the run plots' fused red, the rest in colours no estimate of a run's plots has (blue was the
# first variant here and the lidar there, orange a variant here and dead reckoning there: a plot review; purple, the
# smoothed estimate's, the sixth variant: a student's review)
_VARIANT_COLORS = ["tab:red", *OTHER_COLORS]


SYMLOG_LIN_M = 0.01     # compare's difference panel: linear within +/- this, logarithmic beyond


def plot_compare_ape(path: Path, runs, evs_unfiltered: dict, t0: float) -> None:
    """APE translation over time of every variant (solid; a variant's smoothed estimate dashed, in its colour)
    and of the unfiltered estimates (lidar dotted, GNSS dots, in their own colours); with two variants or more, a
    second panel of each later variant's APE minus the first's, linear within +/- :data:`SYMLOG_LIN_M` and
    logarithmic beyond: variants within centimetres of each other were one band on the log axis, the thinner hidden
    under the others (a plot review)."""
    diffs = len(runs) > 1 and runs[0].ev.ape_err_m is not None and len(runs[0].ev.ape_err_m) > 1
    if diffs:
        fig, (ax, axd) = subplots(2, 1, figsize=(12, 7.5), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    else:
        fig, ax = subplots(figsize=(12, 4.5))
    floor = _log_floor([r.ev.ape_err_m for r in runs] + [r.ev_smoothed.ape_err_m for r in runs if r.ev_smoothed is not None]
                       + [ev.ape_err_m for ev in evs_unfiltered.values()])
    for i, r in enumerate(runs):
        color = _VARIANT_COLORS[i % len(_VARIANT_COLORS)]
        for ev, style, label in ((r.ev, "-", r.name), (r.ev_smoothed, "--", f"{r.name} smoothed")):
            if ev is None or ev.ape_err_m is None:
                continue
            k = thin.envelope(ev.ape_err_m)
            # each later variant thinner: variants with the same errors (eskf, invariant, iekf with GNSS) hid the first
            # under the last; drawn so, each shows as a rim of the one over it
            ax.plot(*_gapped(ev.ape_t_s[k] - t0, np.maximum(ev.ape_err_m[k], floor)), style,
                    lw=max(0.5, 2.2 - 1.7 * i / max(1, len(runs) - 1)), color=color,
                    label=f"{label} (RMSE {_metres(ev.metrics['ape']['translation_m']['rmse'])})")
    for name in ("lidar", "gnss"):
        ev = evs_unfiltered.get(name)
        if ev is not None and ev.ape_err_m is not None:
            k = thin.envelope(ev.ape_err_m)
            color, style = _UNFILTERED[name]
            ax.plot(*_gapped(ev.ape_t_s[k] - t0, np.maximum(ev.ape_err_m[k], floor)), style, ms=2, lw=1.0, color=color,
                    label=f"{LABELS[name]} (RMSE {_metres(ev.metrics['ape']['translation_m']['rmse'])})")
    ax.set_yscale("log")
    _no_minor_labels(ax)
    ax.set_ylabel("APE translation [m]")
    ax.set_title("Absolute position error of each variant (later variants drawn thinner, over the earlier)")
    ax.grid(alpha=0.3, which="both")
    _legend_outside(fig, ax, fontsize=7)
    if diffs:
        base = runs[0].ev
        axd.axhline(0.0, color=_VARIANT_COLORS[0], lw=1.2)
        for i, r in enumerate(runs):
            for ev, style in ((r.ev, "-"), (r.ev_smoothed, "--")):
                if (i == 0 and style == "-") or ev is None or ev.ape_err_m is None or len(ev.ape_err_m) < 2:
                    continue
                d = np.interp(base.ape_t_s, ev.ape_t_s, ev.ape_err_m, left=np.nan, right=np.nan) - base.ape_err_m
                k = thin.envelope(d)
                axd.plot(*_gapped(base.ape_t_s[k] - t0, d[k]), style, lw=1.0,
                         color=_VARIANT_COLORS[i % len(_VARIANT_COLORS)])
        # linear within +/-1 cm, logarithmic beyond: filters centimetres apart and a smoother decimetres apart on one
        # axis (linear, the smoother's 0.9 m flattened the filters into the zero line)
        axd.set_yscale("symlog", linthresh=SYMLOG_LIN_M, linscale=0.5)
        axd.set_ylabel(f"APE - {runs[0].name}'s APE [m]")
        axd.set_title(f"Each variant against {runs[0].name} (below zero: better than it; linear within +/-"
                      f"{SYMLOG_LIN_M * 100:g} cm, logarithmic beyond)", fontsize=9, loc="left")
        axd.grid(alpha=0.3)
        axd.set_xlabel("time since start [s]")
        fig.subplots_adjust(hspace=0.25)
    else:
        ax.set_xlabel("time since start [s]")
    _save(fig, path)


def plot_compare_biases(path: Path, runs) -> None:
    """Estimated accelerometer and gyro biases of each variant, one panel per sensor and axis: 15-18 lines in two
    panels, the axes told apart by line style with no key for it, could not be read (a plot review)."""
    fig, axes = subplots(2, 3, figsize=(14, 6), sharex=True)
    for i, r in enumerate(runs):
        t = r.filt.fused.t_s - r.filt.fused.t_s[0]
        c = _VARIANT_COLORS[i % len(_VARIANT_COLORS)]
        lw = max(0.6, 1.6 - 1.0 * i / max(1, len(runs) - 1))      # later variants thinner, over the earlier
        for k in range(3):
            axes[0, k].plot(t, r.filt.accel_bias_b[:, k] / MG_MPS2, "-", lw=lw, color=c, label=r.name if k == 0 else None)
            axes[1, k].plot(t, r.filt.gyro_bias_b[:, k] / DEG_H_RPS, "-", lw=lw, color=c)
    for k, axis in enumerate("xyz"):
        axes[0, k].set_title(f"accelerometer, {axis} (body)", fontsize=9)
        axes[1, k].set_title(f"gyro, {axis} (body)", fontsize=9)
        axes[1, k].set_xlabel("time since start [s]")
    axes[0, 0].set_ylabel("accel bias [mg]")     # the unit of a run's biases.png (m/s^2 here: a student's review)
    axes[1, 0].set_ylabel("gyro bias [deg/h]")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    fig.suptitle("Estimated IMU biases per variant", fontsize=11)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper right", fontsize=7, ncol=min(len(labels), 6), frameon=False)
    fig.subplots_adjust(left=0.06, right=0.99, top=0.86, bottom=0.09, wspace=0.25, hspace=0.35)
    _save(fig, path)


def plot_compare_body_velocity(path: Path, runs, body_v: list, gt, gt_vb) -> None:
    """Lateral and vertical body-frame velocity of each variant (what the motion constraint acts on)."""
    fig, axes = subplots(2, 1, figsize=(10, 6), sharex=True)
    t0 = runs[0].filt.fused.t_s[0]
    if gt_vb is not None:
        # thin and dashed over the variants: drawn thick on top, it hid the variant that followed it best (a review)
        for ax, k in zip(axes, (1, 2)):
            ax.plot(gt.t_s - t0, gt_vb[:, k], "--", color="black", lw=0.8, label="ground truth", zorder=10)
    for i, (r, vb) in enumerate(zip(runs, body_v)):
        label = r.name
        if gt_vb is not None:       # how far each follows the truth, in the legend (the lines overlap)
            rms = [float(np.sqrt(np.nanmean((vb[:, k] - np.interp(r.filt.fused.t_s, gt.t_s, gt_vb[:, k],
                                                                   left=np.nan, right=np.nan)) ** 2))) for k in (1, 2)]
            label += f" (RMS from the truth: lateral {rms[0]:.3f}, vertical {rms[1]:.3f} m/s)"
        for ax, k in zip(axes, (1, 2)):
            ax.plot(r.filt.fused.t_s - t0, vb[:, k], lw=0.9, alpha=0.8, color=_VARIANT_COLORS[i % len(_VARIANT_COLORS)],
                    label=label)
    axes[0].set_ylabel("lateral [m/s]")
    axes[1].set_ylabel("vertical [m/s]")
    axes[1].set_xlabel("time since start [s]")
    axes[0].set_title("Body-frame velocity across the direction of travel")
    for ax in axes:
        ax.grid(alpha=0.3)
    # below the axes, one row: inside, the legend covered the data and hid a variant behind the truth (a review)
    handles, labels = axes[0].get_legend_handles_labels()
    ncol = 2 if gt_vb is not None else min(len(labels), 6)
    rows = -(-len(labels) // ncol)
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=7 if gt_vb is not None else 8, frameon=False)
    fig.subplots_adjust(bottom=0.08 + 0.035 * rows, top=0.93, hspace=0.12)
    _save(fig, path)


def _value_axis(ax, values, axis: str = "x", at_values: bool = True) -> None:
    """A readable axis for swept values: logarithmic where they are all positive and span a decade or more (noise
    densities; a swept lag or offset may be zero or negative), ticks at the values themselves (``at_values``)
    when few enough to stand apart (else matplotlib's, fewer), plain numbers of 3 digits, no minor labels,
    slanted labels."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, MaxNLocator, NullFormatter

    vals = sorted({float(v) for v in values if is_number(v)})
    if not vals:
        return
    log = vals[0] > 0 and vals[-1] / vals[0] >= 10
    a = ax.xaxis if axis == "x" else ax.yaxis
    (ax.set_xscale if axis == "x" else ax.set_yscale)("log" if log else "linear")
    u = np.log10(vals) if log else np.asarray(vals)
    span = float(u[-1] - u[0]) or 1.0
    keep = [0]
    for i in range(1, len(vals)):
        if u[i] - u[keep[-1]] >= 0.08 * span:           # closer labels would overlap
            keep.append(i)
    if at_values and len(keep) <= 8:
        a.set_major_locator(FixedLocator([vals[i] for i in keep]))
    else:
        a.set_major_locator(LogLocator(numticks=6) if log else MaxNLocator(6))
    def label(v, _pos):
        # three significant digits, or as many more as the ticks need to read apart (0.797, 0.798, 0.798, 0.799 on a
        # 0.004-wide axis; a review)
        locs = [x for x in a.get_majorticklocs() if np.isfinite(x)]
        n = 3
        while n < 8 and len({f"{x:.{n}g}" for x in locs}) < len(set(locs)):
            n += 1
        return f"{v:.{n}g}"
    a.set_major_formatter(FuncFormatter(label))
    a.set_minor_formatter(NullFormatter())
    if axis == "x":
        ax.margins(x=0.1)
        for lab in ax.get_xticklabels():
            lab.set_rotation(30)
            lab.set_horizontalalignment("right")


def _setting_label(name: str) -> str:
    """A grid setting's name is ``key=value,key=value``: its values alone (the keys go in the axis label)."""
    return " / ".join(kv.split("=", 1)[1] for kv in name.split(",")) if "=" in name else name


def _grid_keys_of(names) -> list[str]:
    """The keys of the grid settings among ``names`` (``key=value,...``), in their order."""
    first = next((nm for nm in names if "=" in nm), None)
    return [] if first is None else [kv.split("=", 1)[0] for kv in first.split(",")]


OVERVIEW_MAX_SETTINGS = 40     # not a state index: beyond, the names of every setting would not fit one panel (a big grid: the heatmap)


def sweep_params_figure(rows: list[dict], keys: list[str], metric: str, defaults: dict | None = None,
                        metric_label: str | None = None):
    """The figure of ``sweep_params.png`` (None when no swept key is numeric): a first panel with every setting
    ranked by ``metric`` (up to :data:`OVERVIEW_MAX_SETTINGS`), then, for each numeric swept key, ``metric``
    against the key's value over the settings that set it, and the default configuration as a star at its own
    value of the key (``defaults[(dataset, variant)][key]``, :func:`fusion_eval.commands.sweep_summary.default_values`)
    and as a dotted line at its metric. Artists carry ``gid`` "settings" and "default" (one marker per run).
    ``metric_label``: how the axes name ``metric`` (default: the fused APE translation RMSE's label)."""
    from matplotlib.lines import Line2D

    label = metric_label or "fused APE translation RMSE [m]"
    short = "APE RMSE" if metric_label is None else "figure"

    defaults = defaults or {}
    ok = [r for r in rows if r["status"] == "ok" and is_number(r.get(metric))]
    numeric = [k for k in keys if any(is_number(r.get(k)) and r["setting"] != "default" for r in ok)]
    if not numeric:
        return None
    series = sorted({(r["dataset"], r["variant"]) for r in ok})
    several_variants = len({v for _, v in series}) > 1
    names = sorted({r["setting"] for r in ok})
    overview = len(names) <= OVERVIEW_MAX_SETTINGS
    # keys that the same settings set are one panel: lidar-tight and lidar-loose set the position and the rotation
    # noise together, and two panels showed the same points twice (a student's review)
    # (only keys whose values determine each other, setting by setting: a grid sets every key in every setting, and
    # its keys vary independently: one panel for grid2d's two keys hid the second, a review)
    values = {k: {r["setting"]: r[k] for r in ok if r["setting"] != "default" and is_number(r.get(k))} for k in numeric}

    def set_together(a: str, b: str) -> bool:
        va, vb = values[a], values[b]
        pairs = {(va[s], vb[s]) for s in va} if va.keys() == vb.keys() else set()
        return bool(pairs) and len(pairs) == len({x for x, _ in pairs}) == len({y for _, y in pairs})

    groups: list[list[str]] = []
    for k in numeric:
        g = next((g for g in groups if set_together(g[0], k)), None)
        g.append(k) if g is not None else groups.append([k])
    std_col = f"{metric}_std"
    n = len(groups) + overview
    ncols = min(3, n)
    nrows = -(-n // ncols)
    height = max(4.3 * nrows, (0.24 * len(names) + 1.8) if overview else 0.0) + 0.7
    fig, axes = subplots(nrows, ncols, figsize=(5.4 * ncols, height), squeeze=False)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.set_visible(False)

    def label_of(ds, v):
        return dataset_label(ds) + (f" / {v}" if several_variants else "")

    def default_row(ds, v):
        return next((r for r in ok if r["dataset"] == ds and r["variant"] == v and r["setting"] == "default"), None)

    if overview:
        ax = flat.pop(0)
        mean = {nm: np.mean([r[metric] for r in ok if r["setting"] == nm]) for nm in names}
        order = sorted(names, key=lambda nm: (-mean[nm], nm))        # the best at the top
        ypos = {nm: i for i, nm in enumerate(order)}
        for j, (ds, v) in enumerate(series):
            c = _VARIANT_COLORS[j % len(_VARIANT_COLORS)]
            sub = [r for r in ok if r["dataset"] == ds and r["variant"] == v]
            off = (j - (len(series) - 1) / 2) * 0.12
            st = [r for r in sub if r["setting"] != "default"]
            ax.plot([r[metric] for r in st], [ypos[r["setting"]] + off for r in st], "o", ms=5, color=c, gid="settings")
            d = default_row(ds, v)
            if d is not None:
                ax.plot([d[metric]], [ypos["default"] + off], "*", ms=13, mfc=c, mec="black", mew=0.8, gid="default")
                ax.axvline(d[metric], color=c, ls=":", lw=1.0)
        ax.set_yticks(range(len(order)), [_setting_label(nm) for nm in order], fontsize=8)
        for lab in ax.get_yticklabels():
            if lab.get_text() == "default":
                lab.set_fontweight("bold")
        _value_axis(ax, [r[metric] for r in ok], axis="x", at_values=False)
        ax.set_xlabel(label)
        gk = _grid_keys_of(names)
        if gk:
            ax.set_ylabel("grid settings: " + " / ".join(gk), fontsize=8)
        ax.set_title("Every setting, best at the top", fontsize=9)
        ax.grid(alpha=0.3, which="major")
    for ax, g in zip(flat, groups):
        k, *together = g
        xs, notes = [], []
        for j, (ds, v) in enumerate(series):
            c = _VARIANT_COLORS[j % len(_VARIANT_COLORS)]
            mine = [r for r in ok if r["dataset"] == ds and r["variant"] == v and r["setting"] != "default"
                    and is_number(r.get(k))]
            pts = sorted((r[k], r[metric], r["setting"]) for r in mine)
            # a curve joins only settings that change nothing but this panel's keys (one that also switched the
            # lidar noise's adaptation off was joined to the default, which has it on: a student's review)
            alone = {r["setting"] for r in mine if all(r.get(o) in ("", None) for o in keys if o not in g)}
            d = default_row(ds, v)
            dx = defaults.get((ds, v), {}).get(k)
            both = [p for p in pts if p[2] in alone] + ([(dx, d[metric], "default")] if d is not None and is_number(dx) else [])
            both.sort()
            if len(both) > 1 and len({p[0] for p in both}) == len(both):     # one run per value: a curve
                ax.plot([p[0] for p in both], [p[1] for p in both], "-", lw=0.8, color=c, alpha=0.6)
            if pts:
                err = {r["setting"]: r.get(std_col) for r in mine}
                if any(is_number(e) and e > 0 for e in err.values()):     # means over trials: their std as a bar
                    ax.errorbar([p[0] for p in pts], [p[1] for p in pts],
                                yerr=[err[p[2]] if is_number(err[p[2]]) else 0.0 for p in pts], fmt="none", ecolor=c,
                                elinewidth=0.8, capsize=3, alpha=0.7)
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", ms=5, color=c, gid="settings")
            if len(series) == 1 and len(groups) == 2:
                _interaction(ax, mine, k, next(o for o in groups if o is not g)[0], metric)
            if d is not None:
                ax.axhline(d[metric], color=c, ls=":", lw=1.0)
                if is_number(dx):
                    ax.plot([dx], [d[metric]], "*", ms=13, mfc=c, mec="black", mew=0.8, gid="default")
                    if not any(nm == "default" for _, _, nm in notes):
                        notes.append((dx, d[metric], "default"))
            if len(pts) <= 12 and not (len(series) == 1 and len(groups) == 2):   # (a grid's lines say their values)
                # each name once (two variants' points labelled it twice, overlapping)
                said = {nm for _, _, nm in notes}
                notes += [(x, y, nm) for x, y, nm in pts if "=" not in nm and not nm.startswith("random-") and nm not in said]
            xs += [p[0] for p in pts + both]
        _value_axis(ax, xs)
        ax.autoscale_view()
        for x, y, nm in notes:       # a grid's or a sample's name is its x: only named settings are labelled
            right = ax.transAxes.inverted().transform(ax.transData.transform((x, y)))[0] > 0.7
            ax.annotate(nm, (x, y), xytext=(-5 if right else 5, 4), textcoords="offset points", fontsize=7,
                        color="dimgray", ha="right" if right else "left")
        ax.set_xlabel(k + (f"\n(set together with {', '.join(together)})" if together else ""), fontsize=9)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3, which="major")
    handles = [Line2D([], [], ls="", marker="o", color="gray", label="a setting of the sweep"),
               Line2D([], [], ls="", marker="*", ms=12, mfc="gray", mec="black", label="the default configuration"),
               Line2D([], [], ls=":", color="gray", label=f"the default's {short}")]
    if len(series) > 1:
        handles += [Line2D([], [], ls="", marker="s", color=_VARIANT_COLORS[j % len(_VARIANT_COLORS)], label=label_of(*sv))
                    for j, sv in enumerate(series)]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 4), fontsize=8, frameon=False)
    fig.suptitle(("Fused APE" if metric_label is None else metric_label) + " against the sweep's settings"
                 + ("" if len(series) > 1 else f" ({label_of(*series[0])})"))
    fig.tight_layout(rect=(0, 0.55 / height * (1 + (len(handles) > 4)), 1, 1 - 0.35 / height))
    return fig


_INTERACTION_MARKERS = "os^Dv<>p"


def _interaction(ax, mine: list[dict], k: str, other: str, metric: str) -> None:
    """On a 2-D grid's panel of ``k``: the settings of each value of the ``other`` key joined by a thin line of its
    own shade and marker, labelled: three dots per value said nothing of which value of the other key each was, so
    an interaction did not show (a plot review)."""
    by = {}
    for r in mine:
        if is_number(r.get(other)):
            by.setdefault(r[other], []).append((r[k], r[metric]))
    if len(by) < 2 or len(by) > len(_INTERACTION_MARKERS):
        return
    shades = np.linspace(0.15, 0.65, len(by))
    for (val, pts), m, g in zip(sorted(by.items()), _INTERACTION_MARKERS, shades):
        pts.sort()
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "-", marker=m, ms=4, lw=0.8, color=str(g), mfc="none",
                gid="interaction", label=f"{other} = {val:g}")
    ax.legend(fontsize=7, loc="best", title=None)


def plot_sweep(out_dir: Path, rows: list[dict], keys: list[str], metric: str, tasks, best, grid_keys=(),
               defaults: dict | None = None, metric_label: str | None = None) -> list[str]:
    """Metric against each swept parameter (:func:`sweep_params_figure`; ``defaults``: the default run's value of
    each swept key per (dataset, variant)), a heatmap for a 2-D grid, and the best run's APE over time against
    the default's. ``metric_label``: the name of a ranked ``metric`` other than the fused APE RMSE. Returns the
    file names written."""
    import os

    from evo.tools import file_interface

    def save(fig, name):
        tmp = out_dir / f".{name}.tmp.png"  # a .png suffix: matplotlib picks the format from it
        fig.savefig(tmp, dpi=110, metadata=_META)
        fig.clear()
        os.replace(tmp, out_dir / name)
        written.append(name)

    written: list[str] = []
    ok = [r for r in rows if r["status"] == "ok"]
    fig = sweep_params_figure(rows, keys, metric, defaults, metric_label)
    numeric = [k for k in keys if any(is_number(r.get(k)) for r in ok)]
    if fig is not None:
        save(fig, "sweep_params.png")
    if len(grid_keys) == 2 and all(k in numeric for k in grid_keys):
        kx, ky = grid_keys
        xs = sorted({r[kx] for r in ok if isinstance(r.get(kx), (int, float))})
        ys = sorted({r[ky] for r in ok if isinstance(r.get(ky), (int, float))})
        if len(xs) > 1 and len(ys) > 1 and len(xs) * len(ys) <= 400:
            cells: dict = {}
            for r in ok:
                if r.get(kx) in xs and r.get(ky) in ys and r["setting"] != "default":
                    cells.setdefault((ys.index(r[ky]), xs.index(r[kx])), []).append(r[metric])
            Z = np.full((len(ys), len(xs)), np.nan)
            for (i, j), vals in cells.items():
                Z[i, j] = float(np.mean(vals))
            fig, ax = subplots(figsize=(6, 5))
            # viridis as the segment map's: yellow the largest error there and here (this was reversed, yellow the
            # best, and one report read both ways; a plot review)
            im = ax.imshow(Z, origin="lower", cmap="viridis", aspect="auto")
            ax.set_xticks(range(len(xs)), [f"{x:g}" for x in xs])
            ax.set_yticks(range(len(ys)), [f"{y:g}" for y in ys])
            for i in range(len(ys)):
                for j in range(len(xs)):
                    if np.isfinite(Z[i, j]):
                        # dark text on the bright (worst, yellow) cells, white on the dark ones
                        r, g, b, _ = im.cmap(im.norm(Z[i, j]))
                        ax.text(j, i, f"{Z[i, j]:.3f}", ha="center", va="center", fontsize=8,
                                color="black" if 0.299 * r + 0.587 * g + 0.114 * b > 0.5 else "white")
            ax.set_xlabel(kx)
            ax.set_ylabel(ky)
            fig.colorbar(im, label=f"{metric_label or 'fused APE RMSE [m]'} (mean over datasets and variants)")
            if np.isfinite(Z).any():          # the best cell outlined (three cells read 0.77 at two decimals)
                bi, bj = np.unravel_index(int(np.nanargmin(Z)), Z.shape)
                ax.add_patch(Rectangle((bj - 0.5, bi - 0.5), 1, 1, fill=False, ec="red", lw=2))
            d = [r[metric] for r in ok if r["setting"] == "default" and is_number(r.get(metric))]
            ax.set_title(f"{metric_label or 'Fused APE RMSE [m]'} over the 2-D grid (best outlined)"
                         + (f"\nthe default configuration, off the grid: {np.mean(d):.3f}" if d else ""), fontsize=9)
            fig.tight_layout()
            save(fig, "sweep_heatmap.png")
    if best is not None:
        # the best against the default; where the default is the best, against the runner-up (two identical curves,
        # both labelled 'default', said nothing: a plot review)
        other = "default"
        if best["setting"] == "default":
            rest = sorted((r for r in ok if r["setting"] != "default" and r["variant"] == best["variant"]
                           and is_number(r.get(metric))), key=lambda r: r[metric])
            other = rest[0]["setting"] if rest else None
        fig, ax = subplots(figsize=(10, 4))
        # fixed colours (the default cycle's blue and orange are the lidar's and dead reckoning's elsewhere)
        for name, style, color in ((best["setting"], "-", COLORS["fused"]), (other, ":", "black")):
            if name is None:
                continue
            # the best setting's own dataset, trial 0 (the curve of one run)
            t = next((t for t in tasks if t.variant == best["variant"] and t.setting == name and t.trial == 0
                      and t.dataset == best.get("dataset", t.dataset)), None)
            z = None if t is None else out_dir / "runs" / t.id / "ape_translation_fused.zip"
            if z is None or not z.exists():
                continue
            res = file_interface.load_res_file(z)
            ts = res.np_arrays["timestamps"]
            k = thin.envelope(res.np_arrays["error_array"])
            row = next((r for r in ok if (r["dataset"], r["variant"], r["setting"]) == (t.dataset, t.variant, name)), {})
            # with Monte-Carlo trials the table ranks by their mean: the legend gives it beside this trial's figure
            # (it showed trial 0's RMSE alone, which contradicted sweep.md)
            rmse = (f"trial 0 RMSE {res.stats['rmse']:.3f} m, mean of {row['trials']} trials {row[RANK_COLUMN]:.3f} m"
                    if is_number(row.get("trials")) and row["trials"] > 1 and is_number(row.get(RANK_COLUMN))
                    else f"RMSE {res.stats['rmse']:.3f} m")
            ax.plot(ts[k] - ts[0], res.np_arrays["error_array"][k], style, lw=1.0, color=color,
                    label=f"{name} ({Path(t.dataset).name}, {rmse})")
        if not ax.lines:           # no run has an APE (drives without ground truth): no plot
            return written
        ax.set_xlabel("time since start [s]")
        ax.set_ylabel("APE translation [m]")
        ax.set_title(("Best setting against the default" if other == "default" else
                      f"Best setting (the default) against the runner-up ({other})" if other else "Best setting")
                     + (f" (ranked by {metric_label})" if metric_label else ""))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        save(fig, "sweep_best_vs_default.png")
    return written


def plot_drift(path: Path, evals: dict) -> None:
    """KITTI drift metric against segment length: translational (%) and rotational (deg/100 m) error."""
    fig, axes = subplots(1, 2, figsize=(11, 4))
    colors = estimate_colors(list(evals))
    curves = {}
    for name, ev in evals.items():
        if not ev.drift:
            continue
        Ls = sorted(int(k) for k in ev.drift["per_length"])
        curves[name] = (Ls, [ev.drift["per_length"][str(L)]["t_err_pct"] for L in Ls],
                        [ev.drift["per_length"][str(L)]["r_err_deg_per_m"] * 100 for L in Ls])
    tops = []
    for q in (1, 2):          # per panel: dead reckoning's 900 % hid the fused against the lidar, 0.49 against 0.46 %
        others = [v for n, c in curves.items() if n != "imu_only" for v in c[q] if np.isfinite(v)]
        dr = [v for v in curves.get("imu_only", ((), (), ()))[q] if np.isfinite(v)]
        tops.append(_ceiling(max(others, default=np.nan), max(dr, default=np.nan)))
    for name, (Ls, t, r) in curves.items():
        ev = evals[name]
        c = colors[name]
        lab = LABELS.get(name, name)
        off = " (off the scale)" if name == "imu_only" else ""
        axes[0].plot(Ls, t, "o-", color=c, label=f"{lab} ({ev.drift['t_err_pct']:.2f} %){off if tops[0] else ''}")
        axes[1].plot(Ls, r, "o-", color=c,
                     label=f"{lab} ({ev.drift['r_err_deg_per_100m']:.3f} deg/100 m){off if tops[1] else ''}")
    axes[0].set_ylabel("translational error [%]")
    axes[1].set_ylabel("rotational error [deg/100 m]")
    for ax in axes:
        ax.set_xlabel("segment length [m]")
        if any(np.any(np.asarray(ln.get_ydata()) > 0) for ln in ax.get_lines()):
            with warnings.catch_warnings():     # one segment length: equal limits, which matplotlib widens itself
                warnings.filterwarnings("ignore", "Attempting to set identical low and high ylims")
                ax.set_yscale("log")   # (an estimate equal to its reference has no error to put on a log axis)
            _no_minor_labels(ax)
            top = tops[0] if ax is axes[0] else tops[1]
            if top is not None:
                ax.set_ylim(top=top)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle("KITTI drift metric against segment length")
    fig.subplots_adjust(left=0.08, right=0.98, top=0.88, bottom=0.13, wspace=0.3)
    _save(fig, path)


def consistency_figure(cons: dict, t0: float):
    """The figure of :func:`plot_consistency`, one axis per NEES / NIS series, and a legend for its lines."""
    items = [("NEES " + k, d) for k, d in cons.get("nees", {}).items()]
    items += [("NEES smoothed " + k, d) for k, d in cons.get("nees_smoothed", {}).items()]
    items += [("NIS " + k, d) for k, d in cons.get("nis", {}).items()]
    height = 2.2 * len(items) + 0.5
    fig, axes = subplots(len(items), 1, figsize=(10, height), sharex=True, squeeze=False)
    # (without ground truth there is no NEES: the legend names the dots alone)
    what = "NEES (line) / NIS (dots)" if any(i[0].startswith("NEES") for i in items) else "NIS (dots)"
    for ax, (label, d) in zip(axes[:, 0], items):
        lo, hi = d["bounds_95"]
        v = np.asarray(d["values"])
        t = np.asarray(d["t_s"]) - t0
        # the axis' floor: a tenth of the lower bound, or lower where over 5 % of the values are (the constraint's NIS
        # far below its dof is a finding); the first epoch's 1e-4 squeezed the bounds into a third of the axis (a plot
        # review). Values below it sit on it
        pos = v[np.isfinite(v) & (v > 0)]
        floor = min(0.1 * lo, float(np.percentile(pos, 5))) if pos.size else 0.1 * lo
        floor = max(floor, 1e-6)
        k = thin.envelope(v)
        if label.startswith("NEES"):       # a continuous series: a line
            ax.plot(t[k], np.maximum(v[k], floor), "-", lw=0.7, color="tab:blue", label=what)
        else:
            # separate innovations: dots sized by their number (1 Hz GNSS in pixels was invisible; a plot review),
            # and their mean over 10 s windows, where a stretch of over- or under-confidence shows
            ms = 3.0 if v.size < 600 else 1.5 if v.size < 3000 else None
            ax.plot(t[k], np.maximum(v[k], floor), "." if ms else ",", color="tab:blue", label=what,
                    **({"ms": ms} if ms else {}))
            _window_mean(ax, t, v, floor)
        ax.set_ylim(bottom=floor / 1.3)
        ax.axhline(lo, color="tab:red", lw=0.8, ls="--", label="95 % chi-square bounds of one epoch")
        ax.axhline(hi, color="tab:red", lw=0.8, ls="--")
        ax.axhline(d["dof"], color="black", lw=0.6, label="dof: the mean of a consistent filter")
        ax.set_yscale("log")
        _no_minor_labels(ax)
        ax.set_ylabel(label, fontsize=8)
        ax.set_title(f"{label}: mean {d['mean']:.2f} (dof {d['dof']}), {d['fraction_in_95'] * 100:.1f} % inside the 95 % bounds",
                     fontsize=8, loc="left")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time since start [s]")
    # one legend for every axis (the same lines in each), above the first, off the data
    seen = {}
    for ax in axes[:, 0]:
        for h, lb in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lb, h)
    fig.legend(list(seen.values()), list(seen), loc="upper center", ncol=4, fontsize=8, frameon=False)
    fig.subplots_adjust(left=0.08, right=0.98, top=1 - 0.45 / height, bottom=0.5 / height, hspace=0.45)
    return fig


NIS_WINDOW_S = 10.0     # the NIS plot's running mean: over this many seconds of innovations


def _window_means(t: np.ndarray, v: np.ndarray) -> tuple[float, np.ndarray]:
    """The mean of ``v`` over consecutive :data:`NIS_WINDOW_S` windows from ``t[0]`` (finite ``t``, ``v``), NaN for a
    window with fewer than 3 values, and where the first window starts."""
    w = np.floor((t - t[0]) / NIS_WINDOW_S).astype(int)
    n = np.bincount(w)
    return float(t[0]), np.where(n >= 3, np.bincount(w, weights=v) / np.maximum(n, 1), np.nan)


def _plane_labels(start_frame: bool) -> tuple[str, str]:
    """The top view's axis labels: East and North, or the start's levelled frame (no GNSS and no truth: x forward
    at the start)."""
    return ("x, forward at the start [m]", "y, left at the start [m]") if start_frame else ("East [m]", "North [m]")


def _window_mean(ax, t: np.ndarray, v: np.ndarray, floor: float) -> None:
    """The mean of the innovations' NIS over consecutive :data:`NIS_WINDOW_S` windows (with at least 3 in each), as
    a step line: a consistent filter's stays near the dof."""
    ok = np.isfinite(v) & np.isfinite(t)
    if ok.sum() < 6 or t[ok][-1] - t[ok][0] < 2 * NIS_WINDOW_S:
        return
    t_first, mean = _window_means(t[ok], v[ok])
    edges = t_first + NIS_WINDOW_S * np.arange(mean.size + 1)
    y = np.maximum(mean, floor)
    ax.stairs(y, edges, baseline=None, color="tab:orange", lw=1.2, label=f"NIS mean over {NIS_WINDOW_S:g} s")


def plot_innovation_map(path: Path, route: np.ndarray, nis: dict, start_frame: bool = False) -> None:
    """Where on the route the filter disagreed with its sensors, for a drive without ground truth (whose segment map
    has no error to colour): the fused route's top view (``route``: E, N, U, t rows, :func:`thin.paths`) coloured
    by each measured stream's mean NIS over its dof in :data:`NIS_WINDOW_S` windows, one panel per stream, on a log
    scale centred on 1 (red: the stream disagrees beyond its stated noise; blue: it agrees better than stated)."""
    from matplotlib.colors import LogNorm

    names = list(nis)
    fig, axes = subplots(1, len(names), figsize=(6.2 * len(names), 5.6), squeeze=False)
    t_route = route[:, 3]
    for ax, k in zip(axes[0], names):
        d = nis[k]
        t, v = np.asarray(d["t_s"], float), np.asarray(d["values"], float) / d["dof"]
        ok = np.isfinite(t) & np.isfinite(v)
        t, v = t[ok], v[ok]
        ax.plot(route[:, 0], route[:, 1], "-", color="0.85", lw=3.0, zorder=1)
        if t.size >= 3:
            t_first, mean = _window_means(t, v)
            # each route point takes its window's mean (windows with fewer than 3 updates left grey)
            c = mean[np.clip(np.floor((t_route - t_first) / NIS_WINDOW_S).astype(int), 0, mean.size - 1)]
            inside = np.isfinite(c) & (t_route >= t[0]) & (t_route <= t[-1])
            sc = ax.scatter(route[inside, 0], route[inside, 1], c=np.clip(c[inside], 0.1, 10.0), s=4, cmap="coolwarm",
                            norm=LogNorm(0.1, 10.0), zorder=2)
            fig.colorbar(sc, ax=ax, shrink=0.8, label=f"mean NIS / dof over {NIS_WINDOW_S:g} s")
        ax.plot(route[0, 0], route[0, 1], "k^", ms=8, zorder=3)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(_plane_labels(start_frame)[0])
        ax.set_ylabel(_plane_labels(start_frame)[1])
        ax.set_title(f"{k}: mean NIS / dof {np.mean(v):.2f} over {v.size} updates", fontsize=9)
        ax.grid(alpha=0.3)
    fig.suptitle("Where the sensors disagree with the filter (no ground truth: the innovations alone)", fontsize=10)
    fig.tight_layout()
    _save(fig, path)


def plot_consistency(path: Path, cons: dict, t0: float) -> None:
    """NEES (position, attitude) and NIS per observation type over time, with the 95 % chi-square bounds."""
    _save(consistency_figure(cons, t0), path)


_PLANE = {"z": ((0, 1), ("East [m]", "North [m]")), "y": ((0, 2), ("x [m]", "z [m]")),   # not a state index
          "x": ((1, 2), ("y [m]", "z [m]"))}                                                   # not a state index


def segment_map_figure(evals: dict, seg: dict, up_axis: str = "z"):
    """The figure of :func:`plot_segment_map`, with the worst segments labelled and a caption saying what the
    labels are. ``up_axis``: the reference frame's vertical axis; the map is the plane across it (ENU: East-North;
    KITTI camera poses, y down: x-z)."""
    (i0, i1), (xlabel, ylabel) = _PLANE[up_axis]
    a, b = seg.get("primary", "fused"), seg.get("secondary")
    f = evals[a]
    lid = evals.get(b) if b else None
    panels = 2 if lid is not None and lid.ape_err_m is not None else 1
    fig, axes = subplots(1, panels, figsize=(7 * panels, 6.6), squeeze=False)
    p = f.ref_p_m
    k = thin.every(len(p))
    sc = axes[0, 0].scatter(p[k, i0], p[k, i1], c=f.ape_err_m[k], s=3, cmap="viridis")
    fig.colorbar(sc, ax=axes[0, 0], label=f"{a} APE [m]")
    # long estimate names (a file's stem) wrapped: a one-line title ran into the next panel's colour bar
    axes[0, 0].set_title(textwrap.fill(f"{a} error along the route", 55), fontsize=10)
    if panels == 2:
        diff = f.ape_err_m - np.interp(f.ape_t_s, lid.ape_t_s, lid.ape_err_m)
        # only where the other estimate has a pose near: across a GNSS outage the line between the fixes on either
        # side is no error of it (a thin black line there: gray is the colour map's middle)
        far = _far_from(f.ape_t_s, lid.ape_t_s)
        diff[far] = np.nan
        if np.any(far[k]):
            axes[0, 1].scatter(p[k, i0][far[k]], p[k, i1][far[k]], c="black", s=0.5, label=f"no {b} pose here")
            axes[0, 1].legend(loc="best", fontsize=8, markerscale=6)
        lim = float(np.nanpercentile(np.abs(diff), 98)) if np.any(~far) else 1.0
        lim = lim or 1.0
        sc = axes[0, 1].scatter(p[k, i0][~far[k]], p[k, i1][~far[k]], c=diff[k][~far[k]], s=3, cmap="coolwarm",
                                vmin=-lim, vmax=lim)
        fig.colorbar(sc, ax=axes[0, 1], label=f"{a} APE - {b} APE [m] (blue: {a} better)")
        axes[0, 1].set_title(textwrap.fill(f"Where {a} is better (blue) or worse (red) than {b}", 55), fontsize=10)
    d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    worst = seg.get("worst", [])[:5]  # not a state index
    xy = p[:, [i0, i1]]        # the map's two coordinates of the route
    marks = []
    for i in worst:
        s = next(x for x in seg["segments"] if x["index"] == i)
        if seg["by"] == "distance":
            k = int(np.searchsorted(d, 0.5 * (s["start_m"] + s["end_m"])))
        else:
            k = int(np.searchsorted(f.ape_t_s - f.ape_t_s[0], 0.5 * (s["start_s"] + s["end_s"])))
        k = min(k, len(p) - 1)
        axes[0, 0].plot(*xy[k], "o", ms=5, mfc="none", mec="red", mew=1.2)
        rmse = s["rmse_m"].get(a)
        marks.append((f"#{i}" + (f" ({rmse:.2f} m)" if rmse is not None else ""), xy[k]))
    for ax in axes[0]:
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    if worst:
        unit = "s" if seg["by"] == "time" else "m"
        what = "of time" if seg["by"] == "time" else "along the reference (ground-truth) route"
        caption = (f"Red circles, #k (RMSE): segment k, the k-th window of {seg['length']:g} {unit} {what} "
                   f"(counted from 0); the {len(worst)} segments with the largest {a} APE translation RMSE, marked at "
                   "their middle.")
        fig.text(0.06, 0.015, textwrap.fill(caption, 95 * panels), fontsize=8, color="dimgray")
    fig.subplots_adjust(left=0.1 if panels == 1 else 0.06, right=0.97, top=0.94, bottom=0.14, wspace=0.25)
    _place_labels(fig, axes[0, 0], marks)
    return fig


def _far_from(t_s: np.ndarray, other_t_s: np.ndarray) -> np.ndarray:
    """Where ``t_s`` lies more than twice the other series' median interval (at least 0.5 s) from its nearest stamp."""
    if len(other_t_s) < 2:
        return np.ones(len(t_s), bool)
    gap = max(2.0 * float(np.median(np.diff(other_t_s))), 0.5)
    j = np.clip(np.searchsorted(other_t_s, t_s), 1, len(other_t_s) - 1)
    return np.minimum(np.abs(t_s - other_t_s[j - 1]), np.abs(other_t_s[j] - t_s)) > gap


def _place_labels(fig, ax, marks) -> None:
    """Each ``(text, xy)`` written beside its point where it overlaps no label placed before and stays inside the
    axes: right of the point, then left, stepped up and down (two worst segments of a route that passes a place
    twice stood on each other, and a label at the map's edge ran under the colour bar)."""
    renderer = fig.canvas.get_renderer()
    ax.get_xlim(), ax.get_ylim()        # the pending autoscaling done (the data limits are settled at a draw)
    ax.apply_aspect()                   # the equal-aspect box as it will be drawn
    box_ax = ax.get_window_extent(renderer)
    taken = []
    steps = [(dx, dy) for dy in (4, -9, 17, -22, 30, -35) for dx in (5, -5)]
    for text, xy in marks:
        for n, (dx, dy) in enumerate(steps):
            t = ax.annotate(text, xy, xytext=(dx, dy), textcoords="offset points", fontsize=8, color="red",
                            ha="left" if dx > 0 else "right", va="bottom", annotation_clip=False)
            b = t.get_window_extent(renderer)
            inside = box_ax.x0 <= b.x0 and b.x1 <= box_ax.x1 and box_ax.y0 <= b.y0 and b.y1 <= box_ax.y1
            if n == len(steps) - 1 or (inside and not any(b.overlaps(o) for o in taken)):
                taken.append(b)
                break
            t.remove()


def plot_segment_map(path: Path, evals: dict, seg: dict, up_axis: str = "z") -> None:
    """Top view colored by the primary estimate's error, and by its error minus the secondary's (for a
    run: fused minus lidar, where fusion helps or hurts), with the worst segments labelled."""
    _save(segment_map_figure(evals, seg, up_axis), path)


def plot_generic_trajectories(path: Path, ref, estimates: dict, up_axis: str = "z", alignment: str = "none") -> None:
    """Top view: the plane across the reference's gravity axis (x-y for ENU, x-z for KITTI's cam0 poses);
    ``estimates`` as the evaluation aligned them (``alignment``, for the title)."""
    i0, i1 = {"z": (0, 1), "y": (0, 2), "x": (1, 2)}[up_axis]
    fig, ax = subplots(figsize=(8, 7))
    ax.plot(ref.p_w_m[:, i0], ref.p_w_m[:, i1], "-", color="black", lw=1.6, label="reference")
    colors = estimate_colors(list(estimates))
    for name, s in estimates.items():
        ax.plot(s.p_w_m[:, i0], s.p_w_m[:, i1], "-", lw=1.0, color=colors[name], label=LABELS.get(name, name))
    ax.set_aspect("equal", adjustable="box")
    # whole coordinates: georeferenced (UTM) files put an offset '+5.429e6' over the title, and a reader must add it
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_xlabel(f"{'xyz'[i0]} [m]")
    ax.set_ylabel(f"{'xyz'[i1]} [m]")
    how = "as read; not aligned" if alignment == "none" else f"estimates aligned as evaluated: {alignment}"
    ax.set_title(f"Trajectories ({'xyz'[i0]}-{'xyz'[i1]} plane of the files' frame, {how})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)


TRIAL_METRICS = (("fused.ape.translation_m.rmse", "fused", "fused APE translation RMSE [m]"),
                 ("smoothed.ape.translation_m.rmse", "smoothed", "smoothed APE translation RMSE [m]"),
                 ("lidar.ape.translation_m.rmse", "lidar", "lidar odometry APE translation RMSE [m]"),
                 ("gnss.ape.translation_m.rmse", "gnss", "GNSS APE translation RMSE [m]"),
                 ("fused.ape.rotation_deg.rmse", "fused", "fused APE rotation RMSE [deg]"),
                 ("ratios.fused_over_lidar", "lidar", "fused / lidar APE RMSE"),
                 ("ratios.fused_over_gnss", "gnss", "fused / GNSS APE RMSE"))


def trials_figure(sec: dict):
    """The figure of :func:`plot_trials`: one panel per metric, each on its own scale (the sensors' errors are
    ten times the fused one: on a shared axis the fused spread was a flat row of dots)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    rows = [r for r in sec["per_trial"] if "failed" not in r]
    shown, same = [], []
    for key, name, label in TRIAL_METRICS:
        v = np.array([r[key] for r in rows if r.get(key) is not None], float)
        v = v[np.isfinite(v)]
        if v.size > 1 and np.ptp(v) <= 1e-12 * max(1.0, float(np.max(np.abs(v)))):
            same.append(f"{label} {v[0]:.3g}")     # a sensor no seed touches (the lidar): a panel of one value, said
        elif v.size:
            shown.append((key, name, label, v))
    nrows = -(-max(len(shown), 1) // 4)
    ncols = -(-max(len(shown), 1) // nrows)       # at most 4 a row, the rows as full as they can be
    fig, axes = subplots(nrows, ncols, figsize=(3.6 * ncols, 3.6 * nrows + 1.2), squeeze=False)
    for ax, (key, name, label, v) in zip(axes.ravel(), shown):
        c = COLORS.get(name, "tab:gray")
        st = sec["stats"].get(key, {})
        mean, std = st.get("mean", float(np.mean(v))), st.get("std", float(np.std(v)))
        ax.axhspan(mean - std, mean + std, color=c, alpha=0.15, lw=0)
        ax.boxplot([v], positions=[0], widths=0.5, whis=(0, 100), showfliers=False,
                   medianprops={"color": "black"}, boxprops={"color": c}, whiskerprops={"color": c},
                   capprops={"color": c})
        # the trials spread over the box's width in trial order: equal values stay apart, the same bytes each time
        jitter = (np.arange(v.size) - (v.size - 1) / 2) * (0.4 / max(v.size, 1))
        ax.plot(jitter, v, "o", color=c, alpha=0.7, ms=4)
        lo, hi = st.get("ci95_mean", [np.nan, np.nan])
        ax.errorbar([0.5], [mean], yerr=[[mean - lo], [hi - mean]] if np.isfinite(lo) else None, fmt="s",
                    color="black", capsize=4, ms=5)
        if key.startswith("ratios") and v.max() > 0.8:
            ax.axhline(1.0, color="gray", lw=0.8, ls="--")      # above 1: fusion worse than the sensor alone
        ax.set_xlim(-0.6, 0.9)
        ax.set_xticks([])
        # min and max in words: 'a .. b' is the 95 % interval of the mean on the console (a plot review)
        ax.set_title(f"{label}\n{mean:.3g} +/- {std:.2g} (std), min {v.min():.3g}, max {v.max():.3g}", fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    for ax in axes.ravel()[len(shown):]:
        ax.set_visible(False)
    handles = [Line2D([], [], ls="", marker="o", color="gray", alpha=0.7, label="one trial"),
               Patch(facecolor="white", edgecolor="gray", label="box: quartiles and median, whiskers: min .. max"),
               Patch(facecolor="gray", alpha=0.3, label="mean +/- 1 std"),
               Line2D([], [], ls="-", marker="s", color="black", label="mean with the 95 % CI of the mean")]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"{sec['n']} Monte-Carlo trials: the spread of each metric"
                 + (f"\n(the same in every trial, not drawn: {'; '.join(same)})" if same else ""),
                 fontsize=11 if same else None)
    h = 3.6 * nrows + 1.2
    fig.subplots_adjust(left=0.07, right=0.98, top=1 - 1.0 / h, bottom=0.45 / h, wspace=0.35, hspace=0.5)
    return fig


def plot_trials(path: Path, sec: dict) -> None:
    """Monte-Carlo trials: the spread of each trial's APE RMSE per estimate and of its fused/sensor ratios (box,
    mean +/- std band, each trial), with the mean and the 95 % confidence interval of the mean."""
    _save(trials_figure(sec), path)
