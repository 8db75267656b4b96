"""PNG plots of a run (matplotlib, Agg backend, no screen needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

# A fixed title height: matplotlib otherwise measures every axis' tick labels at each draw to lift titles
# over them (none of these plots has ticks on top), which was a third of the drawing time.
matplotlib.rcParams["axes.titley"] = 1.0

from ..filters.layout import CANONICAL  # noqa: E402

BA_ID, BG_ID = (CANONICAL.start(b) for b in ("BA", "BG"))

COLORS = {"groundtruth": "black", "fused": "tab:red", "smoothed": "tab:purple", "lidar": "tab:blue", "gnss": "tab:green",
          "imu_only": "tab:orange"}
LABELS = {"groundtruth": "ground truth", "fused": "fused", "smoothed": "smoothed", "lidar": "lidar odometry",
          "gnss": "GNSS", "imu_only": "IMU dead reckoning"}
_META = {"Software": None}
_VCOLORS = plt.rcParams["axes.prop_cycle"].by_key()["color"]  # no version string in the PNG: same inputs, same bytes


def _every(n: int, at_most: int = 2500) -> slice:
    """A stride that keeps at most ``at_most`` of ``n`` points: a plot 1000 pixels wide shows no more."""
    return slice(None, None, max(1, -(-n // at_most)))


def _envelope(y: np.ndarray, at_most: int = 5000) -> np.ndarray:
    """Indices that keep a long series' look: above ``at_most`` points, the minimum and the maximum of each of
    ``at_most / 2`` consecutive bins, in order (a stride would drop the peaks a reader looks for). Shorter series
    are kept whole, so a plot of a short drive is unchanged."""
    n = len(y)
    if n <= at_most:
        return np.arange(n)
    b = -(-n // (at_most // 2))
    m = -(-n // b)
    # NaN (a gap) and the padding never win a bin: +inf for the minimum, -inf for the maximum
    y = np.asarray(y, float)
    blocks_lo = np.concatenate([np.where(np.isnan(y), np.inf, y), np.full(m * b - n, np.inf)]).reshape(m, b)
    blocks_hi = np.concatenate([np.where(np.isnan(y), -np.inf, y), np.full(m * b - n, -np.inf)]).reshape(m, b)
    base = np.arange(m) * b
    k = np.concatenate([base + np.argmin(blocks_lo, axis=1), base + np.argmax(blocks_hi, axis=1), [0, n - 1]])
    return np.unique(np.minimum(k, n - 1))


def _no_minor_labels(ax) -> None:
    """Log axes label their minor ticks, and their major ticks in mathtext (10^k); laying those labels out
    dominated the drawing time. Plain numbers, and no minor labels."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))


def _save(fig, path: Path) -> None:
    # zlib level 1 instead of 6: cheaper encoding (0.18 s of 7 plots at 6), files ~15 % larger
    fig.savefig(path, dpi=110, metadata=_META, pil_kwargs={"compress_level": 1})
    plt.close(fig)


def plot_trajectories(path: Path, series: dict) -> None:
    """Top view (East/North) of every estimate with the ground truth; axes fit the ground truth so a
    diverging dead-reckoning track does not squash the rest."""
    fig, ax = plt.subplots(figsize=(8, 7))
    gt = series["groundtruth"].p_w_m
    for name in ("groundtruth", "lidar", "imu_only", "gnss", "fused", "smoothed"):
        s = series.get(name)
        if s is None or len(s) == 0:
            continue
        p = s.p_w_m[_every(len(s), 20000)]         # a path of 20,000 points is smooth at this size
        if name == "gnss":
            ax.plot(p[:, 0], p[:, 1], ".", ms=2.5, color=COLORS[name], label=LABELS[name])
        else:
            ax.plot(p[:, 0], p[:, 1], "-", lw=1.6 if name == "groundtruth" else 1.1,
                    color=COLORS[name], label=LABELS[name], alpha=0.9)
    ax.plot(gt[0, 0], gt[0, 1], "k^", ms=8, label="start")
    lo, hi = gt[:, :2].min(axis=0), gt[:, :2].max(axis=0)  # not a state index: East, North
    pad = 0.08 * (hi - lo).max() + 5.0
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("East [m]")
    ax.set_ylabel("North [m]")
    ax.set_title("Trajectories (top view, ENU)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    _save(fig, path)


def plot_ape_over_time(path: Path, evals: dict, t0: float) -> None:
    """APE translation of each estimate over time (log scale: dead reckoning grows by orders of magnitude)."""
    fig, ax = plt.subplots(figsize=(10, 4.5))
    known = [n for n in ("imu_only", "gnss", "lidar", "fused", "smoothed") if n in evals]
    for i, name in enumerate(known + [n for n in evals if n not in known]):
        ev = evals[name]
        if ev.ape_err_m is None:
            continue
        rmse = ev.metrics["ape"]["translation_m"]["rmse"]
        style = "." if name == "gnss" else "-"
        k = _envelope(ev.ape_err_m)
        ax.plot(ev.ape_t_s[k] - t0, np.maximum(ev.ape_err_m[k], 1e-3), style, ms=2.5, lw=1.0,
                color=COLORS.get(name, _VCOLORS[i % len(_VCOLORS)]), label=f"{LABELS.get(name, name)} (RMSE {rmse:.2f} m)")
    ax.set_yscale("log")
    _no_minor_labels(ax)
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("APE translation [m]")
    ax.set_title("Absolute position error against ground truth")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="best", fontsize=8)
    _save(fig, path)


def plot_biases(path: Path, t_s: np.ndarray, ba: np.ndarray, bg: np.ndarray, sigma: np.ndarray) -> None:
    """Estimated IMU biases with their +/-3 sigma."""
    k = _every(t_s.size)
    t_s, ba, bg, sigma = t_s[k], ba[k], bg[k], sigma[k]
    t = t_s - t_s[0]
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for ax, b, sl, unit, scale, title in ((axes[0], ba, BA_ID, "m/s^2", 1.0, "accelerometer bias"),
                                          (axes[1], bg, BG_ID, "deg/s", 180 / np.pi, "gyroscope bias")):
        for i, (axis, c) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
            ax.plot(t, b[:, i] * scale, color=c, lw=1.0, label=f"{axis}")
            ax.fill_between(t, (b[:, i] - 3 * sigma[:, sl + i]) * scale, (b[:, i] + 3 * sigma[:, sl + i]) * scale,
                            color=c, alpha=0.12, lw=0)
        ax.set_ylabel(f"{title} [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8, ncol=3)
    axes[0].set_title("Estimated IMU biases (body frame), shaded: +/-3 sigma")
    axes[1].set_xlabel("time since start [s]")
    _save(fig, path)


def plot_error_sigma(path: Path, t_s: np.ndarray, err_w: np.ndarray, sigma: np.ndarray,
                     smoothed: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Fused position error per ENU axis with the filter's own +/-3 sigma (``sigma``: (N, 3) per axis): is
    the covariance honest? ``smoothed``: the smoother's error and sigma at the same stamps, drawn over it."""
    def inside(e, sg):
        return [np.mean(np.abs(e[:, i]) <= 3 * sg[:, i]) * 100 for i in range(3)]

    inside_f = inside(err_w, sigma)
    inside_s = inside(*smoothed) if smoothed is not None else None
    k = _every(t_s.size)
    t = t_s[k] - t_s[0]
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for i, (ax, axis) in enumerate(zip(axes, ("East", "North", "Up"))):
        s3 = 3 * sigma[k, i]
        ax.fill_between(t, -s3, s3, color="tab:gray", alpha=0.3, lw=0, label="+/-3 sigma (filter)")
        ax.plot(t, err_w[k, i], color=COLORS["fused"], lw=0.9, label="fused - ground truth")
        title = f"{axis}: {inside_f[i]:.1f} % of epochs inside 3 sigma"
        if smoothed is not None:
            e, sg = smoothed[0][k, i], 3 * smoothed[1][k, i]
            ax.plot(t, sg, color=COLORS["smoothed"], lw=0.6, ls="--", label="+/-3 sigma (smoothed)")
            ax.plot(t, -sg, color=COLORS["smoothed"], lw=0.6, ls="--")
            ax.plot(t, e, color=COLORS["smoothed"], lw=0.9, label="smoothed - ground truth")
            title += f" (smoothed: {inside_s[i]:.1f} %)"
        ax.set_ylabel(f"{axis} [m]")
        ax.set_title(title, fontsize=9, loc="left")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=2 if smoothed is not None else 1)
    axes[-1].set_xlabel("time since start [s]")
    fig.suptitle("Position error with its own +/-3 sigma" + (" (filter and smoother)" if smoothed is not None else ""))
    fig.subplots_adjust(left=0.08, right=0.98, top=0.9, bottom=0.08, hspace=0.35)
    _save(fig, path)


def plot_compare_ape(path: Path, runs, evs_unfiltered: dict, t0: float) -> None:
    """APE translation over time of every variant (solid) and of the unfiltered estimates (dotted)."""
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for i, r in enumerate(runs):
        rmse = r.ev.metrics["ape"]["translation_m"]["rmse"]
        k = _envelope(r.ev.ape_err_m)
        ax.plot(r.ev.ape_t_s[k] - t0, np.maximum(r.ev.ape_err_m[k], 1e-3), "-", lw=1.0, color=_VCOLORS[i % len(_VCOLORS)],
                label=f"{r.name} (RMSE {rmse:.2f} m)")
    for name in ("lidar", "gnss"):
        ev = evs_unfiltered.get(name)
        if ev is not None and ev.ape_err_m is not None:
            k = _envelope(ev.ape_err_m)
            ax.plot(ev.ape_t_s[k] - t0, np.maximum(ev.ape_err_m[k], 1e-3), ":" if name == "lidar" else ".", ms=2, lw=1.0,
                    color=COLORS[name], label=f"{LABELS[name]} (RMSE {ev.metrics['ape']['translation_m']['rmse']:.2f} m)")
    ax.set_yscale("log")
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("APE translation [m]")
    ax.set_title("Absolute position error of each variant")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="best", fontsize=7)
    _save(fig, path)


def plot_compare_biases(path: Path, runs) -> None:
    """Estimated accelerometer and gyro biases of each variant (x, y, z as solid, dashed, dotted)."""
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    styles = ("-", "--", ":")
    for i, r in enumerate(runs):
        t = r.filt.fused.t_s - r.filt.fused.t_s[0]
        for k in range(3):
            lab = r.name if k == 0 else None
            axes[0].plot(t, r.filt.accel_bias_b[:, k], styles[k], lw=0.9, color=_VCOLORS[i % len(_VCOLORS)], label=lab)
            axes[1].plot(t, np.degrees(r.filt.gyro_bias_b[:, k]) * 3600, styles[k], lw=0.9, color=_VCOLORS[i % len(_VCOLORS)])
    axes[0].set_ylabel("accel bias [m/s^2]")
    axes[1].set_ylabel("gyro bias [deg/h]")
    axes[1].set_xlabel("time since start [s]")
    axes[0].set_title("Estimated IMU biases per variant (x solid, y dashed, z dotted)")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=7)
    _save(fig, path)


def plot_compare_body_velocity(path: Path, runs, body_v: list, gt, gt_vb) -> None:
    """Lateral and vertical body-frame velocity of each variant (what the motion constraint acts on)."""
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    t0 = runs[0].filt.fused.t_s[0]
    if gt_vb is not None:
        for ax, k in zip(axes, (1, 2)):
            ax.plot(gt.t_s - t0, gt_vb[:, k], color="black", lw=1.2, label="ground truth", zorder=10)
    for i, (r, vb) in enumerate(zip(runs, body_v)):
        for ax, k in zip(axes, (1, 2)):
            ax.plot(r.filt.fused.t_s - t0, vb[:, k], lw=0.7, alpha=0.7, color=_VCOLORS[i % len(_VCOLORS)], label=r.name)
    axes[0].set_ylabel("lateral [m/s]")
    axes[1].set_ylabel("vertical [m/s]")
    axes[1].set_xlabel("time since start [s]")
    axes[0].set_title("Body-frame velocity across the direction of travel")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=7)
    _save(fig, path)


def plot_sweep(out_dir: Path, rows: list[dict], keys: list[str], metric: str, tasks, best, grid_keys=()) -> list[str]:
    """Metric against each swept parameter, a heatmap for a 2-D grid, and the best run's APE over time
    against the default's. Returns the file names written."""
    import os

    from evo.tools import file_interface

    def save(fig, name):
        tmp = out_dir / f".{name}.tmp.png"  # a .png suffix: matplotlib picks the format from it
        fig.savefig(tmp, dpi=110, metadata=_META)
        plt.close(fig)
        os.replace(tmp, out_dir / name)
        written.append(name)

    written: list[str] = []
    ok = [r for r in rows if r["status"] == "ok"]
    datasets = sorted({r["dataset"] for r in ok})
    numeric = [k for k in keys if any(isinstance(r.get(k), (int, float)) and not isinstance(r.get(k), bool) for r in ok)]
    if numeric:
        fig, axes = plt.subplots(1, len(numeric), figsize=(5 * len(numeric), 4), squeeze=False)
        for ax, k in zip(axes[0], numeric):
            for i, ds in enumerate(datasets):
                pts = sorted((r[k], r[metric]) for r in ok if r["dataset"] == ds and isinstance(r.get(k), (int, float)))
                if pts:
                    x, y = zip(*pts)
                    ax.plot(x, y, "o", ms=4, color=_VCOLORS[i % len(_VCOLORS)], label=Path(ds).name)
            # Noise settings span decades, but a swept lag or offset may be zero or negative:
            # a log axis only where every value is positive.
            values = [r[k] for r in ok if isinstance(r.get(k), (int, float))]
            if values and min(values) > 0:
                ax.set_xscale("log")
            ax.set_xlabel(k)
            ax.set_ylabel("fused APE translation RMSE [m]")
            ax.grid(alpha=0.3, which="both")
        axes[0][0].legend(fontsize=8)
        fig.suptitle("Fused APE against each swept setting")
        fig.tight_layout()
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
            fig, ax = plt.subplots(figsize=(6, 5))
            im = ax.imshow(Z, origin="lower", cmap="viridis_r", aspect="auto")
            ax.set_xticks(range(len(xs)), [f"{x:g}" for x in xs])
            ax.set_yticks(range(len(ys)), [f"{y:g}" for y in ys])
            for i in range(len(ys)):
                for j in range(len(xs)):
                    if np.isfinite(Z[i, j]):
                        ax.text(j, i, f"{Z[i, j]:.2f}", ha="center", va="center", fontsize=8, color="white")
            ax.set_xlabel(kx)
            ax.set_ylabel(ky)
            fig.colorbar(im, label="fused APE RMSE [m] (mean over datasets and variants)")
            ax.set_title("2-D grid")
            fig.tight_layout()
            save(fig, "sweep_heatmap.png")
    if best is not None:
        fig, ax = plt.subplots(figsize=(10, 4))
        for name, style in ((best["setting"], "-"), ("default", ":")):
            t = next((t for t in tasks if t.variant == best["variant"] and t.setting == name), None)
            z = None if t is None else out_dir / "runs" / t.id / "ape_translation_fused.zip"
            if z is None or not z.exists():
                continue
            res = file_interface.load_res_file(z)
            ts = res.np_arrays["timestamps"]
            k = _envelope(res.np_arrays["error_array"])
            ax.plot(ts[k] - ts[0], res.np_arrays["error_array"][k], style, lw=1.0,
                    label=f"{name} ({Path(t.dataset).name}, RMSE {res.stats['rmse']:.3f} m)")
        ax.set_xlabel("time since start [s]")
        ax.set_ylabel("APE translation [m]")
        ax.set_title("Best setting against the default")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        save(fig, "sweep_best_vs_default.png")
    return written


def plot_drift(path: Path, evals: dict) -> None:
    """KITTI drift metric against segment length: translational (%) and rotational (deg/100 m) error."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name, ev in evals.items():
        if not ev.drift:
            continue
        Ls = sorted(int(k) for k in ev.drift["per_length"])
        t = [ev.drift["per_length"][str(L)]["t_err_pct"] for L in Ls]
        r = [ev.drift["per_length"][str(L)]["r_err_deg_per_m"] * 100 for L in Ls]
        c = COLORS.get(name)
        lab = LABELS.get(name, name)
        axes[0].plot(Ls, t, "o-", color=c, label=f"{lab} ({ev.drift['t_err_pct']:.2f} %)")
        axes[1].plot(Ls, r, "o-", color=c, label=f"{lab} ({ev.drift['r_err_deg_per_100m']:.3f} deg/100 m)")
    axes[0].set_ylabel("translational error [%]")
    axes[1].set_ylabel("rotational error [deg/100 m]")
    for ax in axes:
        ax.set_xlabel("segment length [m]")
        ax.set_yscale("log")
        _no_minor_labels(ax)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle("KITTI drift metric against segment length")
    fig.subplots_adjust(left=0.08, right=0.98, top=0.88, bottom=0.13, wspace=0.3)
    _save(fig, path)


def plot_consistency(path: Path, cons: dict, t0: float) -> None:
    """NEES (position, attitude) and NIS per observation type over time, with the 95 % chi-square bounds."""
    items = [("NEES " + k, d) for k, d in cons.get("nees", {}).items()]
    items += [("NEES smoothed " + k, d) for k, d in cons.get("nees_smoothed", {}).items()]
    items += [("NIS " + k, d) for k, d in cons.get("nis", {}).items()]
    fig, axes = plt.subplots(len(items), 1, figsize=(10, 2.2 * len(items)), sharex=True, squeeze=False)
    for ax, (label, d) in zip(axes[:, 0], items):
        lo, hi = d["bounds_95"]
        # NEES is a continuous series (a line); NIS values are separate innovations (pixel markers, cheap to draw)
        style = "-" if label.startswith("NEES") else ","
        v = np.asarray(d["values"])
        k = _envelope(v)
        ax.plot(np.asarray(d["t_s"])[k] - t0, np.maximum(v[k], 1e-4), style, lw=0.7, color="tab:blue")
        ax.axhline(lo, color="tab:red", lw=0.8, ls="--")
        ax.axhline(hi, color="tab:red", lw=0.8, ls="--")
        ax.axhline(d["dof"], color="black", lw=0.6)
        ax.set_yscale("log")
        _no_minor_labels(ax)
        ax.set_ylabel(label, fontsize=8)
        ax.set_title(f"{label}: mean {d['mean']:.2f} (dof {d['dof']}), {d['fraction_in_95'] * 100:.1f} % inside the 95 % bounds",
                     fontsize=8, loc="left")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time since start [s]")
    fig.subplots_adjust(left=0.08, right=0.98, top=0.96, bottom=0.07, hspace=0.45)
    _save(fig, path)


def plot_segment_map(path: Path, evals: dict, seg: dict) -> None:
    """Top view colored by the primary estimate's error, and by its error minus the secondary's (for a
    run: fused minus lidar, where fusion helps or hurts)."""
    a, b = seg.get("primary", "fused"), seg.get("secondary")
    f = evals[a]
    lid = evals.get(b) if b else None
    panels = 2 if lid is not None and lid.ape_err_m is not None else 1
    fig, axes = plt.subplots(1, panels, figsize=(7 * panels, 6), squeeze=False)
    p = f.ref_p_m
    k = _every(len(p))
    sc = axes[0, 0].scatter(p[k, 0], p[k, 1], c=f.ape_err_m[k], s=3, cmap="viridis")
    fig.colorbar(sc, ax=axes[0, 0], label=f"{a} APE [m]")
    axes[0, 0].set_title(f"{a} error along the route")
    if panels == 2:
        diff = f.ape_err_m - np.interp(f.ape_t_s, lid.ape_t_s, lid.ape_err_m)
        lim = float(np.percentile(np.abs(diff), 98)) or 1.0
        sc = axes[0, 1].scatter(p[k, 0], p[k, 1], c=diff[k], s=3, cmap="coolwarm", vmin=-lim, vmax=lim)
        fig.colorbar(sc, ax=axes[0, 1], label=f"{a} APE - {b} APE [m] (blue: {a} better)")
        axes[0, 1].set_title(f"Where {a} is better (blue) or worse (red) than {b}")
    d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    for i in seg.get("worst", [])[:5]:  # not a state index
        s = next(x for x in seg["segments"] if x["index"] == i)
        if seg["by"] == "distance":
            k = int(np.searchsorted(d, 0.5 * (s["start_m"] + s["end_m"])))
        else:
            k = int(np.searchsorted(f.ape_t_s - f.ape_t_s[0], 0.5 * (s["start_s"] + s["end_s"])))
        k = min(k, len(p) - 1)
        axes[0, 0].annotate(f"#{i}", p[k, :2], fontsize=8, color="red")
    for ax in axes[0]:
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("East [m]")
        ax.set_ylabel("North [m]")
        ax.grid(alpha=0.3)
    fig.subplots_adjust(left=0.06, right=0.97, top=0.93, bottom=0.08, wspace=0.25)
    _save(fig, path)


def plot_generic_trajectories(path: Path, ref, estimates: dict, up_axis: str = "z") -> None:
    """Top view: the plane across the reference's gravity axis (x-y for ENU, x-z for KITTI's cam0 poses)."""
    i0, i1 = {"z": (0, 1), "y": (0, 2), "x": (1, 2)}[up_axis]
    fig, ax = plt.subplots(figsize=(8, 7))
    ax.plot(ref.p_w_m[:, i0], ref.p_w_m[:, i1], "-", color="black", lw=1.6, label="reference")
    for i, (name, s) in enumerate(estimates.items()):
        ax.plot(s.p_w_m[:, i0], s.p_w_m[:, i1], "-", lw=1.0, color=_VCOLORS[i % len(_VCOLORS)], label=name)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel(f"{'xyz'[i0]} [m]")
    ax.set_ylabel(f"{'xyz'[i1]} [m]")
    ax.set_title(f"Trajectories ({'xyz'[i0]}-{'xyz'[i1]} plane of the files' frame, as read; not aligned)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)


def plot_trials(path: Path, sec: dict) -> None:
    """Monte-Carlo trials: each trial's APE translation RMSE per estimate and its fused/sensor ratios, with the
    mean and the 95 % confidence interval of the mean."""
    rows = [r for r in sec["per_trial"] if "failed" not in r]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    panels = [(axes[0], [(n, f"{n}.ape.translation_m.rmse") for n in ("fused", "lidar", "gnss")], "APE translation RMSE [m]"),
              (axes[1], [(n, f"ratios.fused_over_{n}") for n in ("lidar", "gnss")], "fused APE RMSE / sensor alone")]
    for ax, items, ylabel in panels:
        shown = 0
        for x, (name, key) in enumerate(items):
            v = np.array([r[key] for r in rows if r.get(key) is not None], float)
            if v.size == 0:
                continue
            st = sec["stats"].get(key, {})
            jitter = (np.arange(v.size) - (v.size - 1) / 2) * (0.3 / max(v.size, 1))
            c = COLORS.get(name, "tab:gray") if not key.startswith("ratios") else COLORS.get(name)
            ax.plot(x + jitter, v, "o", color=c, alpha=0.6, ms=4)
            lo, hi = st.get("ci95_mean", [np.nan, np.nan])
            ax.errorbar([x + 0.3], [st["mean"]], yerr=[[st["mean"] - lo], [hi - st["mean"]]] if np.isfinite(lo) else None,
                        fmt="s", color="black", capsize=4, ms=5)
            shown += 1
        ax.set_xticks(range(len(items)))
        ax.set_xticklabels([LABELS.get(n, n) if not k.startswith("ratios") else f"fused / {n}" for n, k in items])
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, axis="y")
        if items[0][1].startswith("ratios"):
            ax.axhline(1.0, color="gray", lw=0.8, ls="--")
    fig.suptitle(f"{sec['n']} Monte-Carlo trials (dots), mean with its 95 % confidence interval (squares)")
    fig.subplots_adjust(left=0.08, right=0.98, top=0.88, bottom=0.1, wspace=0.25)
    _save(fig, path)
