"""Command-line interface. The only module that prints or configures logging; every
:class:`~fusion_eval.errors.FusionEvalError` becomes a one-line message and its exit code."""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

import click

from . import __version__
from .errors import FusionEvalError

log = logging.getLogger("fusion_eval")

DEFAULT_DATASET = Path("data/kitti-00")


def _repo_relative(p: Path) -> Path:
    """A default path relative to the working directory, else to the source checkout (editable installs)."""
    if p.exists():
        return p
    alt = Path(__file__).resolve().parent.parent / p
    return alt if alt.exists() else p


class _Handler(logging.Handler):
    def emit(self, record):
        click.echo(f"{record.levelname.lower()}: {record.getMessage()}" if record.levelno >= logging.WARNING
                   else record.getMessage(), err=True)


def _setup_logging(verbose: int, quiet: int) -> None:
    level = logging.INFO - 10 * verbose + 10 * quiet
    root = logging.getLogger()
    root.handlers[:] = [_Handler()]
    root.setLevel(logging.WARNING)
    log.setLevel(max(logging.DEBUG, level))
    for noisy in ("numba", "matplotlib", "evo", "PIL"):
        logging.getLogger(noisy).setLevel(logging.WARNING if verbose < 2 else logging.INFO)


class Group(click.Group):
    """Maps known errors to a one-line message and their exit code."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except FusionEvalError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(exc.exit_code)
        except KeyboardInterrupt:
            click.echo("\ninterrupted: no output directory was written", err=True)
            sys.exit(130)
        except SystemError as exc:
            # Ctrl-C inside a compiled (numba) kernel surfaces as a SystemError around the KeyboardInterrupt
            if isinstance(exc.__cause__ or exc.__context__, KeyboardInterrupt):
                click.echo("\ninterrupted: no output directory was written", err=True)
                sys.exit(130)
            raise


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="fusion-eval")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
@click.option("-q", "--quiet", count=True, help="Less log output (-q: warnings only, no progress bar).")
@click.pass_context
def main(ctx, verbose, quiet):
    """Fuse IMU, GNSS and lidar odometry with Kalman filters and evaluate them with evo."""
    _setup_logging(verbose, quiet)
    ctx.obj = {"quiet": quiet > 0}


@main.command()
@click.argument("dataset", required=False, type=click.Path(path_type=Path))
@click.option("-c", "--config", "config_path", type=click.Path(path_type=Path),
              help="YAML configuration (default: the built-in defaults, spelled out in configs/default.yaml, "
                   "with the dataset manifest's suggested settings).")
@click.option("-s", "--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a configuration key, e.g. --set imu.gyro_noise_dps_sqrthz=0.05 (repeatable).")
@click.option("-o", "--out", "out_dir", type=click.Path(path_type=Path),
              help="Output directory (default: results/<dataset>-<config>-<time>). Must not exist or be empty.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output directory (only once the new run succeeded).")
@click.option("--no-plots", is_flag=True, help="Skip the PNG plots.")
@click.pass_context
def run(ctx, dataset, config_path, sets, out_dir, overwrite, no_plots):
    """Replay DATASET through the filter and write trajectories, metrics and a report.

    DATASET is a folder with a dataset.yaml manifest, a manifest file, or a KITTI raw drive folder
    (default: data/kitti-00, the embedded KITTI drive 2011_10_03_drive_0027).
    """
    from .pipeline import run as run_pipeline

    dataset = dataset if dataset is not None else _repo_relative(DEFAULT_DATASET)
    sets = tuple(sets) + (("output.plots=false",) if no_plots else ())
    config_name = config_path.stem if config_path else "default"
    if out_dir is None:
        ds_name = dataset.resolve().parent.name if dataset.is_file() else dataset.resolve().name
        out_dir = Path("results") / f"{ds_name}-{config_name}-{time.strftime('%Y%m%d-%H%M%S')}"

    quiet = ctx.obj["quiet"]
    t0 = time.perf_counter()
    progress = None if quiet else _Progress("filtering")
    try:
        summary = run_pipeline(dataset, config_path, sets, out_dir, overwrite=overwrite, progress=progress)
    finally:
        if progress is not None:
            progress.close()
    wall = time.perf_counter() - t0
    log.debug("timings: %s", {k: round(v, 3) for k, v in summary.timings_s.items()})
    if not quiet:
        click.echo(_summary_table(summary.metrics))
        click.echo(f"wrote {summary.out_dir}/ ({wall:.1f} s)")


@main.command()
@click.argument("dataset", required=False, type=click.Path(path_type=Path))
@click.option("-V", "--variants", required=True, metavar="A,B,...",
              help="Comma-separated variant names (configs/variants/<name>.yaml) or YAML paths.")
@click.option("--variant-dir", type=click.Path(path_type=Path), default=None,
              help="Folder of variant files (default: configs/variants).")
@click.option("-c", "--config", "config_path", type=click.Path(path_type=Path), help="Base configuration for every variant.")
@click.option("-s", "--set", "sets", multiple=True, metavar="KEY=VALUE", help="Override a key in every variant (repeatable).")
@click.option("-o", "--out", "out_dir", type=click.Path(path_type=Path), help="Output directory (default: results/compare-<time>).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output directory once the comparison succeeded.")
@click.option("--no-plots", is_flag=True, help="Skip the PNG plots.")
@click.pass_context
def compare(ctx, dataset, variants, variant_dir, config_path, sets, out_dir, overwrite, no_plots):
    """Run several filter variants on DATASET and write one comparison table and overlaid plots."""
    from .compare import VARIANT_DIR, compare as run_compare

    dataset = dataset if dataset is not None else _repo_relative(DEFAULT_DATASET)
    variant_dir = variant_dir if variant_dir is not None else _repo_relative(VARIANT_DIR)
    names = [v.strip() for v in variants.split(",") if v.strip()]
    out_dir = out_dir or Path("results") / f"compare-{time.strftime('%Y%m%d-%H%M%S')}"
    progress = None if ctx.obj["quiet"] else _Progress("variants")
    t0 = time.perf_counter()
    try:
        res = run_compare(dataset, names, variant_dir, config_path, tuple(sets), out_dir, overwrite=overwrite,
                          make_plots=not no_plots, progress=progress)
    finally:
        if progress is not None:
            progress.close()
    if not ctx.obj["quiet"]:
        click.echo(f"{'variant':<26} {'estimate':<9} {'APE trans RMSE [m]':>19} {'APE rot RMSE [deg]':>19}")
        for r in res["rows"]:
            rot = r.get("ape_rot_rmse_deg")
            click.echo(f"{r['variant']:<26} {r['estimate']:<9} {r['ape_trans_rmse_m']:>19.3f} "
                       f"{'n/a' if rot is None else f'{rot:.3f}':>19}")
        click.echo(f"wrote {out_dir}/ ({time.perf_counter() - t0:.1f} s)")


@main.command()
@click.argument("out_dir", type=click.Path(path_type=Path))
@click.option("-p", "--profile", default="urban", show_default=True,
              help="Motion profile: urban, figure8, highway, or a waypoint YAML file.")
@click.option("-d", "--duration", "duration_s", type=float, default=300.0, show_default=True, help="Seconds to simulate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every random draw (same seed, same bytes).")
@click.option("-g", "--grade", default="automotive", show_default=True,
              help="Sensor grade preset: consumer, automotive, tactical, oxts-rt3003, ideal.")
@click.option("-s", "--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a simulator setting, e.g. --set imu.rate_hz=200 (repeatable; see README).")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUT_DIR once the new dataset is complete.")
def simulate(out_dir, profile, duration_s, seed, grade, sets, overwrite):
    """Write a synthetic KITTI-style drive with known truth to OUT_DIR."""
    from .simulate.dataset import simulate as run_sim

    t0 = time.perf_counter()
    s = run_sim(out_dir, profile, duration_s, seed, grade, tuple(sets), overwrite=overwrite)
    log.info("wrote %s/ (%s: %d IMU samples, %.0f m, %d lidar frames, %d GNSS fixes) in %.1f s", out_dir, s["name"],
             s["samples"], s["distance_m"], s["lidar_frames"], s["gnss_fixes"], time.perf_counter() - t0)


class _Progress:
    """A progress bar on stderr that appears only once the work it measures has started."""

    def __init__(self, label: str):
        self.label, self.bar, self.done = label, None, 0

    def __call__(self, frac: float) -> None:
        if self.bar is None:
            self.bar = click.progressbar(length=1000, label=self.label, file=sys.stderr, show_eta=True)
            self.bar.__enter__()
        n = int(frac * 1000)
        self.bar.update(n - self.done)
        self.done = n

    def close(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


def _summary_table(metrics: dict) -> str:
    def cell(d, nd):
        return f"{d['rmse']:.{nd}f}" if d else "n/a"

    lines = [f"{'estimate':<10} {'matched':>8} {'APE trans RMSE [m]':>19} {'APE rot RMSE [deg]':>19} {'RPE trans 1 frame [m]':>22}"]
    for name, m in metrics["estimates"].items():
        ape = m.get("ape", {})
        rpe = (m.get("rpe_1frame") or {}).get("translation_m")
        lines.append(f"{name:<10} {m['matched_poses']:>8} {cell(ape.get('translation_m'), 3):>19} "
                     f"{cell(ape.get('rotation_deg'), 3):>19} {cell(rpe, 4):>22}")
    for k, v in metrics["ratios"].items():
        if v is not None:
            lines.append(f"{k.replace('_', ' ')} (APE RMSE): {v:.3f}")
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    main()
