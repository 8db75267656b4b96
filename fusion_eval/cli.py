"""Command-line interface. The only module that prints or configures logging; every
:class:`~fusion_eval.errors.FusionEvalError` becomes a one-line message and its exit code."""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import sys
import time
from pathlib import Path

import click

# One BLAS thread per process (unless the user chose otherwise), set before numpy loads: the products here are small
# (at most a few 100k x 10), where OpenBLAS's threads spin more than they share, and sweeps, tune and the trials run
# one process per core already. kitti-00's run took 0.87x the wall time and CPU with it (alternated, 7 pairs,
# 2026-12-05); the hand-eye fit's 0.25 s of CPU went to 0.09 s. The Python API leaves the host's setting alone.
for _blas in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_blas, "1")

from . import __version__, interrupts
from .errors import FusionEvalError, one_line

log = logging.getLogger("fusion_eval")


# libraries whose INFO lines are theirs, not the user's: shown from -vv on. A filter on the handler, not logger
# levels, because distributed sets its loggers' levels itself when it is imported (after this setup)
_CHATTY = ("distributed", "dask", "numba", "matplotlib", "evo", "PIL", "optuna", "bokeh", "tornado")


class _Handler(logging.Handler):
    def __init__(self, verbose: int = 0):
        super().__init__()
        self.verbose = verbose

    def filter(self, record):
        if self.verbose < 2 and record.levelno < logging.WARNING and record.name.split(".")[0] in _CHATTY:
            return False
        return super().filter(record)

    def emit(self, record):
        msg = (f"{record.levelname.lower()}: {record.getMessage()}" if record.levelno >= logging.WARNING
               else record.getMessage())
        if "tqdm" in sys.modules:       # a progress bar may be drawn: tqdm moves it below the message
            sys.modules["tqdm"].tqdm.write(msg, file=sys.stderr)
        else:
            click.echo(msg, err=True)


CONSOLE: tuple[int, int] | None = None     # (verbose, quiet) of this process's command line, once set up


def _setup_logging(verbose: int, quiet: int) -> None:
    # -q: no log below errors (README), warnings included: a script reads the one line on stdout and the exit code
    global CONSOLE
    CONSOLE = (verbose, quiet)
    level = logging.ERROR if quiet else logging.INFO - 10 * verbose
    root = logging.getLogger()
    root.handlers[:] = [_Handler(verbose)]
    root.setLevel(logging.ERROR if quiet else logging.WARNING)
    log.setLevel(max(logging.DEBUG, level))
    for noisy in _CHATTY:
        logging.getLogger(noisy).setLevel(logging.ERROR if quiet else logging.WARNING if verbose < 2 else logging.INFO)


def worker_logging(console: tuple[int, int]) -> None:
    """A spawned worker's logging as its command's (``console``: :data:`CONSOLE`): it starts with none, and printed
    warnings under -q, without their 'warning:' (a tune review). A forked worker inherits the parent's."""
    _setup_logging(*console)


def _given(ctx, *names: str) -> list[str]:
    """Which of the options ``names`` (parameter names) the user gave, rather than left at their defaults."""
    from click.core import ParameterSource

    return [n for n in names if ctx.get_parameter_source(n) in (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT)]


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _refuse_ignored(ctx, names: tuple[str, ...], why: str) -> None:
    """A usage error naming the options of ``names`` that were given though they do not apply (``why``): an option
    silently ignored makes a user believe a result was computed their way."""
    given = _given(ctx, *names)
    if given:
        raise click.UsageError(f"{', '.join(_flag(n) for n in given)} {'does' if len(given) == 1 else 'do'} not apply "
                               f"{why}")


def _usage_error(exc: click.UsageError) -> None:
    """click's own usage errors (an option's value out of range, an unknown option or command) as one line, like
    every other error of the tool, instead of click's usage block: the command, what is wrong, where help is."""
    if isinstance(exc, getattr(click.exceptions, "NoArgsIsHelpError", ())):   # `fusion-eval` alone: click's help
        exc.show()
        sys.exit(exc.exit_code)
    where = exc.ctx.command_path if exc.ctx is not None else "fusion-eval"
    msg = " ".join(exc.format_message().split())
    click.echo(f"error: {where}: {msg} (see {where} --help)", err=True)
    sys.exit(exc.exit_code)


class Group(click.Group):
    """Maps known errors to a one-line message and their exit code."""

    def parse_args(self, ctx, args):
        try:
            return super().parse_args(ctx, args)
        except click.UsageError as exc:          # the group's own options
            _usage_error(exc)

    def invoke(self, ctx):
        # SIGINT and SIGTERM raise KeyboardInterrupt / Terminated (the same clean-up runs), deferred while numba
        # calls into llvmlite (see interrupts.py); the caller's handlers are restored after
        try:
            with interrupts.handled():
                return super().invoke(ctx)
        except KeyboardInterrupt as exc:
            _interrupted(exc)
        except Exception as exc:
            # a signal raised inside numba (its compiler, or a compiled kernel's callback) may come out as another
            # error (a SystemError around the KeyboardInterrupt, a typing error): it is still the interruption
            signum = interrupts.received()
            if signum is not None:
                _interrupted(interrupts.as_exception(signum))
            if isinstance(exc, OSError) and exc.errno == errno.EIO and not exc.filename:
                # a write to a terminal that has gone (EIO, no file named), often before its SIGHUP is taken: the
                # hang-up it is (it exited 1, its one line raising the same error; a clean-clone CI run)
                _interrupted(interrupts.HungUp())
            if isinstance(exc, FusionEvalError):
                # one line, whatever a library's message embedded (a YAML parser's report spans several)
                click.echo("error: " + one_line(str(exc)), err=True)
                sys.exit(exc.exit_code)
            if isinstance(exc, click.UsageError):   # a command's options, an unknown command
                _usage_error(exc)
            from concurrent.futures.process import BrokenProcessPool

            if isinstance(exc, BrokenProcessPool):
                # a worker killed (the OOM killer, a kill -9) ended a tune in a traceback (a tune review)
                click.echo("error: a worker process of this command died (killed by a signal, or by the system's "
                           "out-of-memory killer): a run or a comparison wrote nothing; a sweep or a tune keeps what "
                           "it finished, and the same command goes on from there", err=True)
                sys.exit(1)
            if isinstance(exc, MemoryError):
                # an hour at 400 Hz simulated under a memory limit was a 46-line traceback (a simulate review); the
                # output folder is written atomically, so nothing half-written is left
                click.echo("error: out of memory: this command needs more memory than the system gave it (a shorter "
                           "drive, a lower IMU rate, or --jobs 1 needs less); nothing half-written is left: a run or a comparison wrote "
                           "nothing, a sweep or a tune keeps what it finished", err=True)
                sys.exit(1)
            if isinstance(exc, RuntimeError) and str(exc).startswith("Symlink loop from "):
                # pathlib's resolve() on a loop of links (up to Python 3.12) where no check saw it first
                # (outputs.refuse_link_loop sees the dataset and --out of every command)
                click.echo(f"error: {str(exc)[len('Symlink loop from '):].strip(chr(39))}: a loop of symbolic links "
                           "(the link leads, through others, back to itself)", err=True)
                sys.exit(2)
            if isinstance(exc, OSError) and not isinstance(exc, BrokenPipeError):
                # the system refused a read or write no check foresaw (stdout on a full device): one line, not a
                # traceback; the output folder was written atomically or not at all
                where = _as_given(str(exc.filename)) if exc.filename else ""
                click.echo("error: " + one_line(f"{where + ': ' if where else ''}{exc.strerror or exc}"), err=True)
                sys.exit(2)
            raise


def _as_given(path: str) -> str:
    """A path inside a staging folder (``OUT/../.NAME.partial-PID/x``) as the user named it (``NAME/x``): a full disk
    named the hidden staging path, not --out (a corrupted-input review)."""
    import re

    def inside_mount(m):          # staged inside a mount point; --out out/out stages beside, in out/ (a diff review)
        return m.group(0)[:m.end(2) - m.start(0)] if os.path.ismount(path[:m.end(2)]) else m.group(0)
    path = re.sub(r"(^|/)([^/]+)/\.\2\.partial-\d+(?=/|$)", inside_mount, path)
    return re.sub(r"(^|/)\.([^/]+)\.partial-\d+(?=/|$)", r"\1\2", path)


_PROCESS_ENTRY = False        # set by entry(): the command is the whole process, not a call inside another program


def entry() -> None:
    """The console script and ``python -m fusion_eval``: :func:`main` as the process itself."""
    global _PROCESS_ENTRY
    _PROCESS_ENTRY = True
    if os.environ.get("MPLBACKEND", "agg").lower() != "agg":
        # the plots are drawn on Agg canvases of their own; a backend named here that is not installed (a notebook's
        # module://matplotlib_inline...) failed every worker at matplotlib's import, reported as a killed process,
        # and compare, evaluate and a sweep's summary with a traceback (a failure-injection review)
        os.environ["MPLBACKEND"] = "Agg"
    if os.name != "posix":
        # fork-started workers, POSIX signal masks and non-blocking pipes: on Windows every command failed with a
        # traceback of its own (a portability review); one line instead
        sys.exit("error: fusion-eval runs on Linux and macOS (POSIX); on Windows, run it under WSL")
    # a path that is not UTF-8 (a byte the file system allows) is echoed back as the bytes it was given, not as a
    # UnicodeEncodeError after the command's work is done
    if sys.stdout is not None and hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(errors="surrogateescape")
    try:
        main()
    except SystemExit:
        _keep_status()
        raise


def _keep_status() -> None:
    """The command is over and its exit status decided: a Ctrl-C or a hang-up during the interpreter's exit (the
    pools' threads joined, numba's caches closed) killed the process by the signal after "wrote ..." was printed, a
    failure to a script whose command had finished (an interruption review: sweep, track, tune, simulate): they are
    ignored from here. SIGTERM keeps its default action, as after an interruption: it must still end an exit that
    hangs (a Python handler would not do: the interpreter gives the default back as it finalizes)."""
    interrupts.ignore_terminal_signals()


def _interrupted(exc: BaseException) -> None:
    # The command is over: a second Ctrl-C (an impatient user, a terminal's repeat) must not change how it ends.
    # Python gives a handled signal back its default action when the interpreter finalizes, so a SIGINT arriving
    # during the exit (the pool's threads joined, numba's caches closed: a few hundred ms) killed the process by the
    # signal (status -2) after "interrupted" was printed, instead of exiting 130. So the process ignores SIGINT from
    # here on (SIGTERM keeps its default: it must still end an exit that hangs); a program that called main() itself
    # keeps its own handler.
    if _PROCESS_ENTRY:
        interrupts.ignore_terminal_signals()
        # and the libraries' exit hooks cut short by the signal keep their tracebacks to themselves (Dask's cluster
        # interrupted as it started printed "Exception ignored in atexit callback ... Status.init", its comms
        # "CommClosedError" under the one line: a failure-injection review)
        sys.unraisablehook = lambda _unraisable: None
        logging.getLogger("distributed").setLevel(logging.CRITICAL + 1)
    what = ("hung up (SIGHUP)" if isinstance(exc, interrupts.HungUp) else
            "terminated (SIGTERM)" if isinstance(exc, interrupts.Terminated) else "interrupted")
    done = interrupts.written()
    old = interrupts.left_as_they_were()
    said = (exc.args[0] if exc.args else f"after {' and '.join(done)} {'was' if len(done) == 1 else 'were'} written whole"
            if done else "no output directory was written" + (
                f"; {' and '.join(old)} {'is' if len(old) == 1 else 'are'} as before" if old else ""))
    try:
        click.echo(f"\n{what}: {said}", err=True)
    except OSError:
        # a hung-up terminal takes no more output (EIO): the status still says what ended the command (it exited 1
        # with a traceback there; a diff review with a pseudo-terminal closed)
        pass
    sys.exit(129 if isinstance(exc, interrupts.HungUp) else 143 if isinstance(exc, interrupts.Terminated) else 130)


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="fusion-eval")
@click.option("-v", "--verbose", count=True, help="More log output: -v debug lines (stage timings), -vv also the "
                                                  "libraries' own logs (Dask, numba, evo, Optuna).")
@click.option("-q", "--quiet", count=True, help="Quiet: no progress, no tables, no log below errors; the command prints "
                                                "one line, its output path, on stdout (for scripts).")
@click.pass_context
def main(ctx, verbose, quiet):
    """Fuse IMU, GNSS and lidar odometry with Kalman filters and evaluate them with evo."""
    if verbose and quiet:
        raise click.UsageError("-q and -v ask for opposite things: give one of them")
    _setup_logging(verbose, quiet)
    ctx.obj = {"quiet": quiet > 0}


def _refuse_used_out(out_dir, overwrite: bool, inputs=()) -> None:
    """The output directory's own checks, before the command imports its numerics (0.7 s): a second run into the
    same --out is refused at once, not after the imports. The command checks again, with its inputs, as it starts."""
    if out_dir is not None:
        from .outputs import StagedDir

        StagedDir(out_dir, overwrite, inputs=inputs).check()



@main.command()
@click.argument("dataset", required=False, type=click.Path(path_type=Path))
@click.option("-c", "--config", "config_path", type=click.Path(path_type=Path),
              help="YAML configuration (default: the built-in defaults, spelled out in configs/default.yaml, "
                   "with the dataset manifest's suggested settings).")
@click.option("-s", "--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a configuration key, e.g. --set imu.gyro_noise_dps_sqrthz=0.05 (repeatable).")
@click.option("-o", "--out", "out_dir", type=click.Path(path_type=Path),
              help="Output directory (default: results/<dataset>-<config>[-set]-<time>[-2, -3...: another run started "
                   "in the same second]). Must not exist or be empty.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output directory (only once the new run succeeded).")
@click.option("--no-plots", is_flag=True, help="Skip the PNG plots.")
@click.option("--trials", type=click.IntRange(min=1), default=1, show_default=True,
              help="Monte-Carlo trials over the seeds of every random element (GNSS degradation, odometer noise, ...); "
                   "metrics.json gets each metric's mean, std, min, max and 95 % intervals.")
@click.pass_context
def run(ctx, dataset, config_path, sets, out_dir, overwrite, no_plots, trials):
    """Replay DATASET through the filter and write trajectories, metrics and a report.

    DATASET is a folder with a dataset.yaml manifest, a manifest file, or a KITTI raw drive folder
    (default: data/kitti-00, the embedded KITTI drive 2011_10_03_drive_0027; the shipped copy when the
    working directory has none).
    """
    _refuse_used_out(out_dir, overwrite, (dataset, config_path))
    from .commands.run import run as run_command, summary_table

    sets = tuple(sets) + (("output.plots=false",) if no_plots else ())
    quiet = ctx.obj["quiet"]
    t0 = time.perf_counter()
    with _display(quiet) as progress:
        res = run_command(dataset, config_path, sets, out_dir, overwrite=overwrite, progress=progress, trials=trials)
    wall = time.perf_counter() - t0
    log.debug("timings: %s", {k: round(v, 3) for k, v in res.timings_s.items()})
    if quiet:
        click.echo(res.out_dir)
        return
    click.echo(summary_table(res.metrics))
    click.echo(f"wrote {res.out_dir}/ ({wall:.1f} s; open report.html)")


@main.command()
@click.argument("dataset", required=False, type=click.Path(path_type=Path))
@click.option("-V", "--variants", required=True, metavar="A,B,...",
              help="Comma-separated variant names (configs/variants/<name>.yaml) or YAML paths.")
@click.option("--variant-dir", type=click.Path(path_type=Path), default=None,
              help="Folder of variant files (default: configs/variants, else the shipped variants).")
@click.option("-c", "--config", "config_path", type=click.Path(path_type=Path), help="Base configuration for every variant.")
@click.option("-s", "--set", "sets", multiple=True, metavar="KEY=VALUE", help="Override a key in every variant (repeatable).")
@click.option("-o", "--out", "out_dir", type=click.Path(path_type=Path), help="Output directory (default: results/compare-<time>[-2...]).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output directory once the comparison succeeded.")
@click.option("--no-plots", is_flag=True, help="Skip the PNG plots.")
@click.option("--trials", type=click.IntRange(min=1), default=1, show_default=True,
              help="Monte-Carlo trials over the seeds of every random element: the table gives means (APE +/- std).")
@click.pass_context
def compare(ctx, dataset, variants, variant_dir, config_path, sets, out_dir, overwrite, no_plots, trials):
    """Run several filter variants on DATASET and write one comparison table and overlaid plots."""
    _refuse_used_out(out_dir, overwrite, (dataset, config_path, variant_dir))
    from .commands.compare import compare as run_compare

    names = [v.strip() for v in variants.split(",") if v.strip()]
    t0 = time.perf_counter()
    with _display(ctx.obj["quiet"]) as progress:
        res = run_compare(dataset, names, variant_dir, config_path, tuple(sets), out_dir, overwrite=overwrite,
                          make_plots=not no_plots, progress=progress, trials=trials)
    if ctx.obj["quiet"]:
        click.echo(res["out_dir"])
    elif res.get("ground_truth") is False:
        click.echo("no ground truth: the variants by their innovations (compare.md)")
        click.echo(f"{'variant':<26} {'fused streams':<22} {'rank':>4} {'NLL per update':>15} {'NIS calibration':>16}")
        for r in res["rows"]:
            click.echo(f"{r['variant']:<26} {r['streams']:<22} {r.get('rank_nll', 'n/a'):>4} "
                       f"{r['nll_per_update']:>15.6f} {r['nis_calibration']:>16.4f}")
        for n in res.get("notes") or ():
            click.echo(n)
        click.echo(f"wrote {res['out_dir']}/ ({time.perf_counter() - t0:.1f} s)")
    else:
        # over trials, the translation's std beside its mean (after the rotation column it read as the rotation's)
        n_trials = max((r.get("trials") or 1 for r in res["rows"]), default=1)
        trans = "APE trans RMSE [m]" if n_trials == 1 else f"APE trans RMSE [m], mean +/- std of {n_trials} trials"
        w = len(trans)
        click.echo(f"{'variant':<26} {'estimate':<9} {trans:>{w}} {'APE rot RMSE [deg]':>19}")
        for r in res["rows"]:
            rot = r.get("ape_rot_rmse_deg")
            sd = r.get("ape_trans_rmse_m_std")
            tr = r.get("ape_trans_rmse_m")
            t = ("n/a" if tr is None else f"{tr:.3f}") + ("" if sd is None else f" +/- {sd:.3f}")
            click.echo(f"{r['variant']:<26} {r['estimate']:<9} {t:>{w}} {'n/a' if rot is None else f'{rot:.3f}':>19}")
        note = (res.get("trials") or {}).get("ranking_note")
        if note:
            click.echo(note.replace("**", ""))
        click.echo(f"wrote {res['out_dir']}/ ({time.perf_counter() - t0:.1f} s)")


@main.command()
@click.argument("datasets", nargs=-1, type=click.Path(path_type=Path))
@click.option("-g", "--grid", "sweep_file", required=True, metavar="SWEEP",
              help="Sweep file (datasets, variants and the settings to sweep: grid, settings, random), or the name of "
                   "a shipped sweep (noise5, noise64, grid2d).")
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(path_type=Path),
              help="Sweep directory; running again into it skips the runs already recorded there.")
@click.option("-j", "--jobs", type=int, default=None, help="Parallel runs (default: all cores).")
@click.option("--variant-dir", type=click.Path(path_type=Path), default=None,
              help="Folder of variant files (default: configs/variants, else the sweep's project's, else the shipped ones).")
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Run on an existing Dask cluster, e.g. tcp://host:8786.")
@click.option("--dask", "dask_mode", type=click.Choice(["local"]), default=None, help="Start a Dask LocalCluster with --jobs workers.")
@click.option("--retry-failed", is_flag=True, help="Run again the runs recorded as failed.")
@click.option("--summarize-only", is_flag=True, help="Only rebuild sweep.csv, sweep.md, plots and best.yaml from the records.")
@click.option("--no-plots", is_flag=True, help="Skip the summary plots.")
@click.option("--trials", type=click.IntRange(min=1), default=None,
              help="Monte-Carlo trials of every setting (default: the sweep file's 'trials', else 1): the summary ranks "
                   "by the mean over the trials.")
@click.option("--batch/--no-batch", default=True, show_default=True,
              help="Runs that differ only in the filter's noise settings share one loading and preparation of the "
                   "data and one evaluation of the unfiltered estimates (the same results); --no-batch runs each alone.")
@click.option("--objective", default=None, metavar="OBJ",
              help="What the summary ranks by, lower is better (default: the sweep file's 'objective', else "
                   "fused.ape.rmse): a metric key as check names them (fused.rpe_100m.rmse, fused.kitti_drift.t_err_pct, "
                   "smoothed.ape.rmse, ...), nll or nis (no ground truth), or a weighted sum as tune takes it. With "
                   "--summarize-only it ranks the recorded runs again.")
@click.pass_context
def sweep(ctx, datasets, sweep_file, out_dir, jobs, variant_dir, scheduler, dask_mode, retry_failed, summarize_only,
          no_plots, trials, batch, objective):
    """Run DATASET(s) over the settings of a sweep file, in parallel or on Dask, and rank the results."""
    _say_compiling(ctx.obj["quiet"])
    from .commands.sweep import run_sweep

    if summarize_only:
        _refuse_ignored(ctx, ("jobs", "scheduler", "dask_mode", "retry_failed", "trials", "batch"),
                        "with --summarize-only, which runs nothing (it rebuilds the summary from the records)")
    t0 = time.perf_counter()
    bars: list = []

    def progress_for(total: int):
        if ctx.obj["quiet"]:
            return None
        from .progress import Counter

        bars.append(Counter("sweep"))
        bar = bars[-1]
        return lambda ok, failed, remaining, skipped: bar.update(
            ok + failed, failed, ok + failed + remaining, f"{skipped} already recorded" if skipped else "")

    try:
        res = run_sweep(sweep_file, [str(d) for d in datasets], out_dir, jobs, variant_dir, scheduler, dask_mode == "local",
                        retry_failed, summarize_only, not no_plots, progress_for, trials, batch, objective)
    finally:
        for bar in bars:
            bar.close()
    rows = res["summary"]["rows"]
    if not summarize_only and rows and not any(r["status"] == "ok" for r in rows):
        # a sweep with nothing to rank has failed, whatever its records say: exit 0 and "wrote best.yaml" hid it
        first = next((r for r in rows if r.get("error")), rows[0])
        raise FusionEvalError(f"no run of the sweep finished ({len(rows)} failed or diverged; every error is in "
                              f"{out_dir}/sweep.md); the first, {first['id']}: {first.get('error') or first['status']}")
    if ctx.obj["quiet"]:
        click.echo(out_dir)
    else:
        best, counts = res["summary"]["best"], res["counts"]
        if summarize_only:
            st = [r["status"] for r in res["summary"]["rows"]]
            click.echo(f"summary of {st.count('ok')} finished, {st.count('failed')} failed and {st.count('pending')} "
                       f"pending runs ({time.perf_counter() - t0:.1f} s)")
        else:
            n_rows = len(res["summary"]["rows"])
            shared = n_rows - (counts["run"] + counts["failed"] + counts["skipped"])
            # "5 runs done" beside sweep.md's "6 runs: 6 finished" read as a lost run (a student's review)
            click.echo(f"{counts['run']} runs done, {counts['failed']} failed, {counts['skipped']} already recorded "
                       f"({time.perf_counter() - t0:.1f} s)"
                       + (f"; {n_rows} settings in sweep.md, {shared} of them the same configuration as another, "
                          "which share its run" if shared > 0 else ""))
        if best:
            what = ("fused APE RMSE" if "mean_fused_ape_trans_rmse_m" in best else best["objective"])
            click.echo(f"best: variant {best['variant']}, setting {best['setting']}: mean {what} "
                       f"{best['mean_objective']:.4g}" + (" m" if "mean_fused_ape_trans_rmse_m" in best else ""))
            if best.get("note"):
                click.echo(best["note"])
        click.echo(f"wrote {out_dir}/sweep.csv, sweep.md, report.html" + (", best.yaml" if best else ""))
    failed = res["summary"]["failed_runs"]        # runs, trials included (a setting of trials folds them)
    if failed and not summarize_only:
        # everything is written, but a CI script must see it: exit 0 with the failure only in a warning (hidden by -q)
        # read as a clean sweep (a review)
        click.echo(f"error: {len(failed)} of {res['summary']['runs']} runs of the sweep failed (each in {out_dir}/sweep.md; "
                   f"--retry-failed runs them again); the first, {failed[0]['id']}: {failed[0]['error']}", err=True)
        ctx.exit(1)


@main.command()
@click.argument("inputs", nargs=-1, required=True)
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(path_type=Path), help="Output directory.")
@click.option("--format", "fmt", type=click.Choice(["auto", "tum", "kitti", "euroc"]), default="auto", show_default=True,
              help="Trajectory file format (auto: told apart by the content).")
@click.option("--bag", type=click.Path(path_type=Path), help="A ROS 1 .bag or ROS 2 bag: INPUTS are estimate topics.")
@click.option("--ref", "ref_topic", help="The reference topic of --bag (or a TF id /tf:parent.child).")
@click.option("--ref-times", type=click.Path(path_type=Path), help="Times file of a KITTI reference (one per pose).")
@click.option("--times", type=click.Path(path_type=Path), help="Times file of KITTI estimates (one per pose).")
@click.option("--association", type=click.Choice(["nearest", "interpolate"]), default="nearest", show_default=True,
              help="evo's --sync_method: nearest_time, or interpolation (guarded by --t-max-diff).")
@click.option("--alignment", type=click.Choice(["none", "origin", "se3", "sim3", "scale", "4dof"]), default="none",
              show_default=True, help="evo's --align_origin, -a, -as, -s; or 4dof (about the gravity axis).")
@click.option("-a", "--align", "evo_align", is_flag=True,
              help="evo's -a: --alignment se3 (with -s: sim3), for evo users' command lines.")
@click.option("-s", "--correct-scale", "evo_scale", is_flag=True, help="evo's -s: --alignment scale (with -a: sim3).")
@click.option("--up-axis", type=click.Choice(["auto", "x", "y", "z"]), default="auto", show_default=True,
              help="Gravity axis of the reference frame for --alignment 4dof (auto: detected).")
@click.option("--n-to-align", type=int, default=-1, show_default=True, help="Poses used by the alignment fit (-1: all).")
@click.option("-r", "--pose-relation", "relations", multiple=True,
              type=click.Choice(["trans_part", "angle_deg", "angle_rad", "rot_part", "full", "point_distance"]),
              help="evo's pose relations to report (repeatable; default trans_part and angle_deg).")
@click.option("--t-max-diff", type=float, default=0.01, show_default=True, help="Max stamp difference, s.")
@click.option("--t-offset", type=float, default=0.0, show_default=True, help="Added to the estimates' stamps for matching, s.")
@click.option("--t-start", type=float, default=None,
              help="evo's --t_start: the reference's poses before this stamp are left out, s (with --t-end: a run's "
                   "common span, as its report prints it).")
@click.option("--t-end", type=float, default=None, help="evo's --t_end: the reference's poses after this stamp are left out, s.")
@click.option("--rpe-delta-m", type=float, default=100.0, show_default=True, help="RPE segment length, m.")
@click.option("--segment-m", type=float, default=100.0, show_default=True, help="Per-segment window along the route, m.")
@click.option("--segment-s", type=float, default=None, help="Per-segment window in time instead, s.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output directory.")
@click.option("--no-plots", is_flag=True, help="Skip the PNG plots.")
@click.option("--engine", type=click.Choice(["arrays", "evo"]), default="arrays", show_default=True,
              help="evo's metrics on whole arrays, or evo's own per-pose loops (same numbers, ~10x slower).")
@click.pass_context
def evaluate(ctx, inputs, out_dir, fmt, bag, ref_topic, ref_times, times, association, alignment, evo_align, evo_scale,
             up_axis, n_to_align, relations, t_max_diff, t_offset, t_start, t_end, rpe_delta_m, segment_m, segment_s,
             overwrite, no_plots, engine):
    """Evaluate trajectories against a reference: REFERENCE ESTIMATE... (TUM, KITTI poses with or without times,
    EuRoC CSV; the REFERENCE may be a dataset folder or manifest: its ground truth), or --bag FILE --ref REF_TOPIC
    EST_TOPIC...: evo's APE/RPE, the KITTI drift metric and the per-segment breakdown."""
    _say_compiling(ctx.obj["quiet"])
    from .commands.evaluate import run_evaluate
    from .evaluation.keys import DEFAULT_RELATIONS

    if _given(ctx, "segment_m") and segment_s is not None:
        raise click.UsageError("--segment-m and --segment-s: give one (the per-segment window along the route in m, "
                               "or in time in s)")
    if evo_align or evo_scale:         # evo's flags (-a, -s, -as): an evo_ape command line works as it is
        evo = {(True, False): "se3", (False, True): "scale", (True, True): "sim3"}[(evo_align, evo_scale)]
        if _given(ctx, "alignment") and alignment != evo:
            raise click.UsageError(f"--alignment {alignment} and {'-as' if evo == 'sim3' else '-a' if evo == 'se3' else '-s'}"
                                   f" (evo's for --alignment {evo}): give one")
        alignment = evo
    if alignment != "4dof":
        _refuse_ignored(ctx, ("up_axis",), f"with --alignment {alignment} (the gravity axis of --alignment 4dof)")
    if alignment == "none":
        _refuse_ignored(ctx, ("n_to_align",), "without an --alignment")
    if not abs(t_offset) < float("inf"):            # nan or inf: every stamp would be, and nothing would match
        raise click.UsageError(f"--t-offset must be a finite number of seconds, got {t_offset}")
    for name, v in (("--t-start", t_start), ("--t-end", t_end)):
        if v is not None and not abs(v) < float("inf"):
            raise click.UsageError(f"{name} must be a finite stamp in seconds, got {v}")
    if t_start is not None and t_end is not None and t_start >= t_end:
        raise click.UsageError(f"--t-start {t_start} is not before --t-end {t_end}")

    m = run_evaluate(list(inputs), out_dir, ref_times, times, association, alignment, t_max_diff, rpe_delta_m,
                     segment_m, segment_s, overwrite, not no_plots, engine, bag=bag, ref_topic=ref_topic, fmt=fmt,
                     relations=tuple(relations) or DEFAULT_RELATIONS, up_axis=up_axis, n_to_align=n_to_align,
                     t_offset_s=t_offset, t_range_s=(t_start, t_end))
    if ctx.obj["quiet"]:
        click.echo(out_dir)
    else:
        from .evaluation.keys import rpe_distance_group

        delta = m["evaluation"]["rpe_delta_m"]
        rpe_head = f"RPE {delta:g} m [m]"
        click.echo(f"{'estimate':<28} {'matched':>8} {'APE trans RMSE [m]':>19} {rpe_head:>15} {'KITTI t_err [%]':>16} "
                   f"{'r_err [deg/100m]':>17}")
        for k, d in m["estimates"].items():
            ape = (d.get("ape") or {}).get("translation_m")
            rpe = (d.get(rpe_distance_group(delta)) or {}).get("translation_m")
            dr = d.get("kitti_drift")
            cells = [_num_or_na(ape and ape["rmse"], 3), _num_or_na(rpe and rpe["rmse"], 3),
                     _num_or_na(dr and dr["t_err_pct"], 3), _num_or_na(dr and dr["r_err_deg_per_100m"], 4)]
            click.echo(f"{k:<28} {d['matched_poses']:>8} {cells[0]:>19} {cells[1]:>15} {cells[2]:>16} {cells[3]:>17}")
        click.echo(f"wrote {out_dir}/")


@main.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(path_type=Path), help="Output directory.")
@click.option("--sensors", type=click.Choice(["both", "lidar", "radar"]), default="both", show_default=True)
@click.option("--noise-ax", type=float, default=9.0, show_default=True, help="Acceleration noise variance sigma_ax^2, m^2/s^4.")
@click.option("--noise-ay", type=float, default=9.0, show_default=True, help="Acceleration noise variance sigma_ay^2, m^2/s^4.")
@click.option("--lidar-var", nargs=2, type=float, default=(0.0225, 0.0225), show_default=True, help="Lidar R diagonal, m^2.")
@click.option("--radar-var", nargs=3, type=float, default=(0.09, 0.0009, 0.09), show_default=True,
              help="Radar R diagonal: rho [m^2], phi [rad^2], rho_dot [m^2/s^2].")
@click.option("--max-gap", "max_gap_s", type=float, default=5.0, show_default=True,
              help="Restart the tracker after a gap of over this many seconds between measurements.")
@click.option("--smooth", is_flag=True, help="Also an RTS smoother over the filter (reported beside it).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output directory.")
@click.option("--no-plots", is_flag=True, help="Skip the plots.")
@click.pass_context
def track(ctx, input_path, out_dir, sensors, noise_ax, noise_ay, lidar_var, radar_var, max_gap_s, smooth, overwrite,
          no_plots):
    """Track a 2-D target from lidar (KF) and radar (EKF) measurements; RMSE against the file's ground truth."""
    _say_compiling(ctx.obj["quiet"])
    from .commands.track import track as run_track

    if sensors != "both":
        _refuse_ignored(ctx, ("radar_var",) if sensors == "lidar" else ("lidar_var",), f"with --sensors {sensors}")
    metrics = run_track(input_path, out_dir, sensors, noise_ax, noise_ay, lidar_var, radar_var, overwrite, not no_plots,
                        smooth, max_gap_s)
    if ctx.obj["quiet"]:
        click.echo(out_dir)
    else:
        def four(r):               # a one-line input has no RMSE (null in metrics.json)
            return ", ".join("n/a" if r[k] is None else f"{r[k]:.4f}" for k in ("px", "py", "vx", "vy"))

        click.echo(f"RMSE [px, py, vx, vy] = [{four(metrics['rmse'])}] ({metrics['estimates']} estimates, sensors: {sensors})")
        if "smoothed" in metrics:
            click.echo(f"smoothed (RTS): RMSE [px, py, vx, vy] = [{four(metrics['smoothed']['rmse'])}]")
        for k, d in metrics["nis"].items():
            click.echo(f"NIS {k}: mean {d['mean']:.4g} (dof {d['dof']}), {d['fraction_above_95'] * 100:.1f} % above the 95 % line")
        for what, d in (("NEES", metrics.get("nees")), ("NEES smoothed", metrics.get("smoothed", {}).get("nees"))):
            if d:
                click.echo(f"{what}: mean {d['mean']:.4g} (dof {d['dof']}), {d['fraction_above_95'] * 100:.1f} % above the 95 % line")
        click.echo(f"wrote {out_dir}/")


@main.command("simulate-track")
@click.argument("out_file", type=click.Path(path_type=Path))
@click.option("--duration", "duration_s", type=float, default=25.0, show_default=True, help="Seconds.")
@click.option("--interval", "interval_s", type=float, default=0.05, show_default=True, help="Seconds between measurements (lidar and radar alternate).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--start", nargs=2, type=float, default=(0.6, 0.6), show_default=True, help="Start position x y, m.")
@click.option("--heading", "heading_deg", type=float, default=0.0, show_default=True, help="Initial heading, deg.")
@click.option("--speed", "speed_mps", type=float, default=5.0, show_default=True, help="Mean speed, m/s.")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUT_FILE.")
@click.pass_context
def simulate_track_cmd(ctx, out_file, duration_s, interval_s, seed, start, heading_deg, speed_mps, overwrite):
    """Write a lidar/radar measurement file with known truth (the format `fusion-eval track` reads)."""
    from .commands.track import simulate_track
    from .progress import Counter
    from .tracking.simulate import CHUNK

    # a counter where it takes long enough to wonder (more than one chunk of lines; 10 million: minutes)
    many = not ctx.obj["quiet"] and interval_s > 0 and duration_s / interval_s > CHUNK
    bar = Counter("simulate-track (lines)", failures=False) if many else None
    try:
        n = simulate_track(out_file, duration_s, interval_s, seed, start, heading_deg, speed_mps, overwrite,
                           progress=None if bar is None else lambda done, total: bar.update(done, 0, total))
    finally:
        if bar is not None:
            bar.close()
    if ctx.obj["quiet"]:
        click.echo(str(out_file))
    log.info("wrote %s (%d measurements)", out_file, n)


@main.command()
@click.argument("metrics_path", metavar="METRICS", type=click.Path(path_type=Path))
@click.option("-b", "--baseline", required=True, type=click.Path(path_type=Path), help="Baseline metrics.json or sweep.csv.")
@click.option("--rtol", multiple=True, metavar="[PATTERN=]R",
              help="Relative tolerance of a metric's increase (default 0.05); PATTERN=R sets it for the metrics the glob "
                   "matches (repeatable; the last match wins).")
@click.option("--atol", multiple=True, metavar="[PATTERN=]A",
              help="Absolute tolerance of a metric's increase, in the metric's unit (default 0); PATTERN=A as for --rtol, "
                   "e.g. --atol 0.01 --atol '*rotation*=0.05'.")
@click.option("-m", "--metric", "patterns", multiple=True, metavar="PATTERN",
              help="Metric paths to compare (glob, repeatable; default: RMSE of APE/RPE and the ratios, or innovations.* "
                   "for a run on a drive without ground truth).")
@click.option("--require", "rules", multiple=True, metavar="EXPR",
              help="A rule that must hold, e.g. 'fused.ape.rmse < lidar.ape.rmse' (repeatable).")
@click.option("--junit", "junit_path", type=click.Path(path_type=Path), help="Also write JUnit XML here.")
@click.option("--summary", "summary_path", type=click.Path(path_type=Path),
              help="Markdown summary (default: check.md next to METRICS).")
@click.option("--update-baseline", is_flag=True, help="Replace the baseline with METRICS and exit 0.")
@click.option("--trial-stat", type=click.Choice(["mean", "median", "max", "min", "std", "p97.5", "none"]), default="mean",
              show_default=True, help="For a metrics.json of a run with --trials: compare this statistic of each metric "
                                      "over the trials ('none': trial 0's own values).")
@click.pass_context
def check(ctx, metrics_path, baseline, rtol, atol, patterns, rules, junit_path, summary_path, update_baseline, trial_stat):
    """Compare METRICS with a baseline; exit 0 if within tolerance and every rule holds, 1 on a regression,
    2 on a usage or data error."""
    from .commands.check import check as run_check, update_baseline as write_baseline

    if update_baseline:
        write_baseline(metrics_path, baseline)
        click.echo(f"baseline {baseline} updated from {metrics_path}")
        return
    res = run_check(metrics_path, baseline, rtol, atol, tuple(patterns), tuple(rules), junit_path, summary_path,
                    None if trial_stat == "none" else trial_stat, trial_stat_given=bool(_given(ctx, "trial_stat")))
    if ctx.obj["quiet"]:            # one line for scripts: the verdict (the exit code says it too)
        click.echo("check: PASS" if res.ok else "check: FAIL (regression, missing or invalid metric, or failed rule)")
        sys.exit(0 if res.ok else 1)
    w = max(len(r.metric) for r in res.rows)
    if res.values:
        click.echo(f"values: {res.values}")
    click.echo(f"{'metric':<{w}}  {'baseline':>12}  {'current':>12}  {'change':>10}  verdict")
    for r in res.rows:
        b = "" if r.baseline is None else f"{r.baseline:.6g}"
        c = r.raw if r.current is None else f"{r.current:.6g}"
        click.echo(f"{r.metric:<{w}}  {b:>12}  {c:>12}  {r.change:>10}  {r.verdict}")
    for rule, holds, txt in res.rules:
        click.echo(f"rule {txt}: {'holds' if holds else 'FAILS'}")
    click.echo("check: PASS" if res.ok else "check: FAIL (regression, missing or invalid metric, or failed rule)")
    if not res.ok:
        sys.exit(1)


@main.command()
@click.argument("out_dir", type=click.Path(path_type=Path))
@click.option("-p", "--profile", default="urban", show_default=True,
              help="Motion profile: urban, figure8, highway, or a waypoint YAML file.")
@click.option("-d", "--duration", "duration_s", type=float, default=300.0, show_default=True, help="Seconds to simulate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every random draw (same seed, same bytes).")
@click.option("--grade", default="automotive", show_default=True,
              help="Sensor grade preset: consumer, automotive, tactical, oxts-rt3003, ideal.")
@click.option("-s", "--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a simulator setting, e.g. --set imu.rate_hz=200 (repeatable; see README).")
@click.option("--overwrite", is_flag=True, help="Replace an existing OUT_DIR once the new dataset is complete.")
@click.pass_context
def simulate(ctx, out_dir, profile, duration_s, seed, grade, sets, overwrite):
    """Write a synthetic KITTI-style drive with known truth to OUT_DIR."""
    _say_compiling(ctx.obj["quiet"])
    from .commands.simulate import simulate as run_sim

    t0 = time.perf_counter()
    s = run_sim(out_dir, profile, duration_s, seed, grade, tuple(sets), overwrite=overwrite)
    log.info("wrote %s/ (%s: %d IMU samples, %.0f m, %d lidar frames, %d GNSS fixes) in %.1f s", out_dir, s["name"],
             s["samples"], s["distance_m"], s["lidar_frames"], s["gnss_fixes"], time.perf_counter() - t0)
    if ctx.obj["quiet"]:
        click.echo(out_dir)


def _num_or_na(x, nd: int) -> str:
    return "n/a" if x is None or x is False else f"{x:.{nd}f}"


@main.command()
@click.argument("datasets", nargs=-1, type=click.Path(path_type=Path))
@click.option("--space", default="noise", show_default=True, metavar="SPACE",
              help="Search space: a YAML file of config keys with ranges, or a shipped space's name (noise, imu-gnss, model).")
@click.option("--objective", "objectives", multiple=True, metavar="OBJ",
              help="nll or nis (no ground truth needed), a metric key (fused.ape.rmse, fused.rpe_100m.rmse, ...) or a "
                   "weighted sum (0.5*fused.ape.rmse+0.5*fused.rpe_100m.rmse); twice for a multi-objective study.")
@click.option("--trials", "n_trials", type=click.IntRange(min=1), default=100, show_default=True,
              help="Trials in the study (a resumed study goes on up to this many).")
@click.option("--test", "test", multiple=True, type=click.Path(path_type=Path),
              help="A held-out drive (repeatable): scored with the default and the tuned config, never trained on.")
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(path_type=Path),
              help="Study directory; the same command resumes the study stored there.")
@click.option("--sampler", type=click.Choice(["tpe", "cmaes"]), default="tpe", show_default=True)
@click.option("--seed", type=click.IntRange(0, 2 ** 32 - 1), default=0, show_default=True, help="Seed of the sampler.")
@click.option("--seeds", type=click.IntRange(min=1), default=1, show_default=True,
              help="Monte-Carlo seeds per drive (GNSS degradation and other random elements); the objective is their mean.")
@click.option("-c", "--config", "config_path", type=click.Path(path_type=Path), help="Base configuration of every trial.")
@click.option("-s", "--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a key in every trial and in the default it is compared with (repeatable).")
@click.option("-j", "--jobs", type=int, default=None, help="Trials scored at once (default: the cores, at most 4).")
@click.option("--batch", type=click.IntRange(min=1), default=4, show_default=True,
              help="Trials asked per generation: a seeded study depends on it, not on -j or the machine (give -j at "
                   "most this).")
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Score trials on an existing Dask cluster.")
@click.option("--dask", "dask_mode", type=click.Choice(["local"]), default=None, help="Start a Dask LocalCluster.")
@click.option("--no-prune", is_flag=True, help="Score every trial on every drive and seed.")
@click.option("--no-plots", is_flag=True, help="Skip the plots.")
@click.pass_context
def tune(ctx, datasets, space, objectives, n_trials, test, out_dir, sampler, seed, seeds, config_path, sets, jobs, batch,
         scheduler, dask_mode, no_prune, no_plots):
    """Tune the filter's noise settings on DATASET(s) (default: the embedded kitti-00) with Optuna."""
    _say_compiling(ctx.obj["quiet"])
    from .commands.tune import run_tune

    from .progress import Counter

    bar = None if ctx.obj["quiet"] else Counter("tune")

    def progress(done, total, best, failed=0):
        if bar is not None:
            bar.update(done, failed, total, "" if best is None else f"best {best:.4g}")

    try:
        res = run_tune(list(datasets), list(test), space, list(objectives), n_trials, out_dir, sampler=sampler,
                       seed=seed, seeds=seeds, config_path=config_path, sets=sets, jobs=jobs, scheduler=scheduler,
                       dask_local=dask_mode == "local", prune=not no_prune, plots=not no_plots, progress=progress,
                       batch=batch)
    finally:
        if bar is not None:
            bar.close()
    if ctx.obj["quiet"]:
        click.echo(out_dir)
    else:
        click.echo((res["setup"].out_dir / "tune.md").read_text(encoding="utf-8"))
        click.echo(f"wrote {res['setup'].out_dir}/ ({res['runtime_s']:.1f} s)")


def _say_compiling(quiet: bool) -> None:
    """A fresh install's first run says why it takes a minute (:mod:`fusion_eval.compile_notice`); -q says nothing."""
    if not quiet:
        from . import compile_notice

        compile_notice.install()


@contextlib.contextmanager
def _display(quiet: bool):
    """The stages of a run drawn on stderr (:class:`fusion_eval.progress.Display`), or nothing with -q."""
    if quiet:
        yield None
        return
    from .progress import Display

    _say_compiling(quiet)
    d = Display()
    try:
        yield d
    except BaseException:
        d.close(summary=False)          # the error line is what follows, not the times of the stages that ran
        raise
    d.close()


if __name__ == "__main__":  # pragma: no cover
    main()
