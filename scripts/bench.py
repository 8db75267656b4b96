#!/usr/bin/env python3
"""The speed figures of issue 13, each as a ratio to a reference measured in the same run (this shared
machine's speed drifts by tens of per cent; a ratio taken in one run does not).

    python scripts/bench.py [--runs 3] [--hour] [--sweep] [--all-drives] [--samples 200000]

Prints, on this machine:
  1. the whole `fusion-eval -q run` on the default dataset (plots on, numba cache warm), against one
     `evo_ape tum groundtruth.tum fused.tum` call on the files it wrote: pairs timed in alternation, the
     median of the ratios (target <= 3);
  2. the replay of kitti-00 (a lidar update at every IMU sample, a GNSS fix every 10; with --all-drives also the
     four SiMpLE drives and the plain raw drives, IMU + GNSS): microseconds per IMU sample in the compiled event
     loop (`filter.replay=auto`, target <= 5 us) against the same replay stepped from Python
     (`filter.replay=python`, the previous path, kept as the tests' oracle);
  3. propagation (mechanization and covariance) per IMU sample, first order (target <= 1.0 us) and Van
     Loan, against the dense ``Phi P Phi^T + Q`` of the same step (the structured kernels' oracle);
  4. `fusion-eval --help` (target <= 0.3 s) against a bare `python -c pass`, and which of matplotlib,
     evo's plotting, dask and pandas `--help` and `check` import (none is the goal);
  5. with --hour: `fusion-eval run` on a simulated drive of 1 h at 200 Hz (csv layout; the simulation not
     counted), wall time (--runs times, each followed by `evo_ape` on its files) and the peak resident memory of
     the main process and of its largest worker, polled from /proc (targets < 10 s, < 1 GiB);
  6. with --sweep: the shipped noise-only sweep `noise64` (65 runs on kitti-00, --jobs 2) in batches against the
     same sweep run by run (`--no-batch`): filter-samples per second over the whole sweep (target >= 1 M/s).
"""

from __future__ import annotations

import argparse
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
try:                          # the installed package where there is one (a plain install measures itself)
    import fusion_eval  # noqa: E402,F401
except ImportError:
    sys.path.insert(0, str(ROOT))

from fusion_eval import session  # noqa: E402
from fusion_eval.config import Settings, load_config  # noqa: E402
from fusion_eval.filters import discretize  # noqa: E402
from fusion_eval.filters.formulations.base import canonical_prior_std, gap_of  # noqa: E402
from fusion_eval.filters.formulations.eskf import ErrorStateKF  # noqa: E402
from fusion_eval.filters.formulations.imu_model import imu_inputs  # noqa: E402
from fusion_eval.filters.state import NominalState  # noqa: E402
from fusion_eval.prepare import prepare, settings_for  # noqa: E402
from fusion_eval.replay import replay  # noqa: E402

BIN = Path(sys.executable).parent


def exe(name: str) -> list[str]:
    p = BIN / name
    if p.exists():
        return [str(p)]
    if name == "fusion-eval":
        return [sys.executable, "-m", "fusion_eval"]
    found = shutil.which(name)
    if found is None:
        raise SystemExit(f"bench: {name} not found beside {sys.executable} nor on PATH")
    return [found]


def timed(cmd: list[str], **kw) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, **kw)
    return time.perf_counter() - t0


def pairs(a: list[str], b: list[str], runs: int, before_a=None) -> tuple[float, float, list[float]]:
    """Median times of ``a`` and ``b`` timed in alternation, and each pair's ratio a/b."""
    ta, tb, ratios = [], [], []
    for _ in range(runs):
        if before_a is not None:
            before_a()
        x = timed(a)
        y = timed(b)
        ta.append(x)
        tb.append(y)
        ratios.append(x / y)
    return statistics.median(ta), statistics.median(tb), ratios


def fmt_ratios(r: list[float]) -> str:
    return f"median {statistics.median(r):.2f}x (min {min(r):.2f}, max {max(r):.2f}, {len(r)} pairs)"


# ---- 1. the whole run against evo_ape ---------------------------------------------------------------
def run_vs_evo(runs: int, tmp: Path, all_drives: bool = False) -> None:
    """The whole run against evo_ape on its files, from a folder outside the checkout (``tmp``); with ``all_drives``
    on every drive of :data:`DRIVES` too (the plain raw drives with IMU + GNSS)."""
    drives = [("default", None, ())] + (DRIVES if all_drives else [])
    for name, path, extra in drives:
        if path is not None and not Path(path).exists():
            print(f"1. fusion-eval run on {name}: skipped, {path} is absent")
            continue
        out = tmp / "run"
        run = (exe("fusion-eval") + ["-q", "run", *([str(path)] if path is not None else []), "--out", str(out),
                                     "--overwrite"] + [a for s in extra for a in ("--set", s)])
        subprocess.run(run, check=True, cwd=tmp, stdout=subprocess.DEVNULL)       # fills numba's cache
        evo = exe("evo_ape") + ["tum", str(out / "groundtruth.tum"), str(out / "fused.tum")]
        ta, tb, r = pairs(run, evo, runs)
        print(f"1. fusion-eval run ({name}, plots) {ta:7.2f} s   evo_ape on its files {tb:5.2f} s   "
              f"ratio {fmt_ratios(r)}   target <= 3x")


# ---- 2. the replay, compiled against Python ---------------------------------------------------------
SHARED = ROOT.parent / "shared" / "data"
# every drive with lidar odometry, and the plain raw drives (IMU + GNSS: no lidar to fuse)
DRIVES = [("kitti-00", ROOT / "data" / "kitti-00", ())] + \
    [(f"simple-{q}", ROOT / "configs" / "datasets" / f"simple-{q}.yaml", ()) for q in ("00", "05", "06", "07")] + \
    [(d.name[:21].replace("_drive_", "/"), d, ("filter.lidar_update=none",))
     for d in sorted(SHARED.glob("kitti-raw/*/*_sync"))]


def per_sample(path: Path, mode: str, *sets: str, repeats: int = 5) -> tuple[float, int]:
    """Microseconds per IMU sample of one replay (the best of ``repeats``) and the number of samples."""
    ds = session.dataset(path)
    c = session.resolve(session.request(sets=(f"filter.replay={mode}", *sets)), ds)
    prep = prepare(ds, c)                  # per configuration: prepare resolves its 'auto' values
    s = settings_for(c, prep)
    out = replay(prep, s)                  # warm-up: compiles or loads the cache
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = replay(prep, s, imu_only=out.imu_only)
        best = min(best, time.perf_counter() - t0)
    return best / out.n_imu_samples * 1e6, out.n_imu_samples


def replay_figures(all_drives: bool = False) -> None:
    for label, sets in (("default (Van Loan, adaptive lidar noise)", ()),
                        ("first-order propagation", ("filter.discretization=first_order",))):
        drives = DRIVES if all_drives else DRIVES[:1]
        for name, path, extra in drives:
            if not Path(path).exists():
                print(f"2. replay of {name}: skipped, {path} is absent")
                continue
            (c, n), (p, _) = per_sample(path, "auto", *sets, *extra), per_sample(path, "python", *sets, *extra)
            print(f"2. replay of {name:12s} ({n:5d} samples), {label:40s} compiled {c:6.1f} us/sample   "
                  f"Python loop {p:6.1f} us/sample   ratio {c / p:.3f}   target <= 5 us")


# ---- 3. propagation against the dense product -------------------------------------------------------
def propagation(n_samples: int) -> None:
    from numba import njit

    @njit(cache=False)
    def dense_loop(P, n, Ft_list, Qc, dt, method):
        for k in range(Ft_list.shape[0]):
            Phi, Qd = discretize.transition(Ft_list[k], Qc, dt, method)
            discretize.propagate_dense(P, n, Phi, Qd)

    rng = np.random.default_rng(0)
    for disc, n_s in (("first_order", n_samples), ("van_loan", max(n_samples // 10, 2000))):
        t = np.arange(n_s) * 0.01
        f = np.tile([0.0, 0.0, 9.81], (n_s, 1)) + rng.normal(size=(n_s, 3)) * 0.1
        w = rng.normal(size=(n_s, 3)) * 0.01
        s = Settings(load_config(None, ("imu.accel_noise_mps2_sqrthz=0.3", "imu.gyro_noise_dps_sqrthz=0.1",
                                        f"filter.discretization={disc}")))
        prm = ErrorStateKF.run_params(s, 9.81)
        x0 = NominalState(np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3))
        for clone in (False, True):
            kf = ErrorStateKF(x0, np.diag(canonical_prior_std(s) ** 2), prm, t, imu_inputs(f, w), 0, gap_of(s, t))
            if clone:
                kf.clone_pose()
            kf.predict_to(t[100])
            t0 = time.perf_counter()
            kf.predict_to(t[-1])
            us = (time.perf_counter() - t0) / (n_s - 101) * 1e6
            # the reference: the same transition applied by dense products (no mechanization)
            from fusion_eval.filters.formulations.eskf import continuous_model
            Ft, Qc = continuous_model(np.eye(3), f[0], w[0], prm, 1.0)
            m = min(n_s, 20000)
            Fts = np.repeat(Ft[None], m, axis=0)
            P = kf.P.copy()
            dense_loop(P, kf.n, Fts[:10], Qc, 0.01, discretize.METHODS[disc])
            t0 = time.perf_counter()
            dense_loop(P, kf.n, Fts, Qc, 0.01, discretize.METHODS[disc])
            ref = (time.perf_counter() - t0) / m * 1e6
            target = "   target <= 1.0 us" if disc == "first_order" and not clone else ""
            print(f"3. propagation, {disc:11s} {'21 states (clone)' if clone else '15 states':18s} {us:6.2f} us/sample   "
                  f"dense Phi P Phi^T + Q {ref:6.2f} us   ratio {us / ref:.3f}{target}")


# ---- 4. start-up ------------------------------------------------------------------------------------
HEAVY = ("matplotlib", "evo.tools.plot", "dask", "pandas")


def startup(runs: int, tmp: Path) -> None:
    ta, tb, r = pairs(exe("fusion-eval") + ["--help"], [sys.executable, "-c", "pass"], max(runs, 5))
    print(f"4. fusion-eval --help {ta:5.2f} s   python -c pass {tb:5.2f} s   ratio {fmt_ratios(r)}   target <= 0.3 s")
    probe = ("import sys, runpy; sys.argv = ['fusion-eval'] + sys.argv[1:]\n"
             "try:\n    runpy.run_module('fusion_eval', run_name='__main__')\nexcept SystemExit:\n    pass\n"
             f"print('LOADED', ','.join(m for m in {HEAVY!r} if m in sys.modules))")
    run_dir = tmp / "run"
    for args in (["--help"], ["check", str(run_dir / "metrics.json"), "--baseline", str(run_dir / "metrics.json")]):
        out = subprocess.run([sys.executable, "-c", probe, *args], capture_output=True, text=True, cwd=ROOT)
        line = next((x for x in out.stdout.splitlines() if x.startswith("LOADED")), "LOADED ?")
        loaded = line[len("LOADED"):].strip()
        print(f"   fusion-eval {args[0]:6s} imports of {', '.join(HEAVY)}: {loaded or 'none'}")


# ---- 5. one hour at 200 Hz --------------------------------------------------------------------------
def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (Linux ``/proc``; the pool's workers are children of the run)."""
    out = [pid]
    try:
        kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return out
    for k in kids:
        out += _tree(int(k))
    return out


def peak_rss(cmd: list[str], every_s: float = 0.05) -> tuple[float, dict[int, int]]:
    """Run ``cmd``; its wall time and the peak resident memory of each of its processes (bytes, by pid), polled
    from ``/proc`` every ``every_s`` (a peak shorter than that can be missed; ``getrusage`` of the children cannot
    tell one process from another, nor this run from the simulation before it)."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    peak: dict[int, int] = {}
    page = resource.getpagesize()
    while p.poll() is None:
        for pid in _tree(p.pid):
            try:
                rss = int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * page
            except (OSError, IndexError, ValueError):
                continue
            peak[pid] = max(peak.get(pid, 0), rss)
        time.sleep(every_s)
    if p.returncode:
        raise SystemExit(f"bench: {' '.join(cmd)} failed ({p.returncode})")
    return time.perf_counter() - t0, {pid: peak[pid] for pid in sorted(peak, key=lambda q: q != p.pid)}


def hour(tmp: Path, runs: int) -> None:
    sim = tmp / "hour"
    subprocess.run(exe("fusion-eval") + ["-q", "simulate", str(sim), "--duration", "3600", "--set", "imu.rate_hz=200",
                                         "--set", "output.layout=csv"], check=True, stdout=subprocess.DEVNULL)
    out = tmp / "hour-run"
    t_runs, t_evos, mains, workers = [], [], [], []
    for _ in range(runs):                  # in alternation: the run, then evo_ape on the files it wrote
        shutil.rmtree(out, ignore_errors=True)
        t_run, peaks = peak_rss(exe("fusion-eval") + ["-q", "run", str(sim), "--out", str(out)])
        t_runs.append(t_run)
        t_evos.append(timed(exe("evo_ape") + ["tum", str(out / "groundtruth.tum"), str(out / "fused.tum")]))
        rss = list(peaks.values())
        mains.append(rss[0])
        workers.append(max(rss[1:], default=0))
    ratios = [a / b for a, b in zip(t_runs, t_evos)]
    gib = 2.0 ** 30
    print(f"5. fusion-eval run, 1 h at 200 Hz {statistics.median(t_runs):7.1f} s ({min(t_runs):.1f}-{max(t_runs):.1f})   "
          f"evo_ape on its files {statistics.median(t_evos):5.1f} s   ratio {statistics.median(ratios):.2f}x   "
          f"peak RSS main process {max(mains) / gib:.2f} GiB, largest worker {max(workers) / gib:.2f} GiB   "
          f"targets < 10 s, < 1 GiB")


# ---- 6. a noise-only sweep ---------------------------------------------------------------------------
def sweep(tmp: Path) -> None:
    n_runs, n_samples = 65, 4409          # noise64 and the default; kitti-00's IMU samples from the start
    cmd = exe("fusion-eval") + ["-q", "sweep", "--grid", "noise64", "--jobs", "2"]
    tb = timed(cmd + ["--out", str(tmp / "sw-batch")], cwd=ROOT)
    tn = timed(cmd + ["--out", str(tmp / "sw-alone"), "--no-batch"], cwd=ROOT)
    print(f"6. sweep noise64 (65 runs, --jobs 2): batched {tb:6.1f} s = {n_runs * n_samples / tb:9,.0f} filter-samples/s"
          f"   run by run {tn:6.1f} s = {n_runs * n_samples / tn:9,.0f} /s   ratio {tb / tn:.2f}   target >= 1,000,000 /s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3, help="alternated pairs of the whole-run and start-up figures")
    ap.add_argument("--samples", type=int, default=200_000, help="IMU samples of the propagation figure")
    ap.add_argument("--hour", action="store_true", help="also the 1 h, 200 Hz simulated drive (a few minutes)")
    ap.add_argument("--sweep", action="store_true", help="also the 65-run noise sweep, batched and run by run (a minute)")
    ap.add_argument("--all-drives", action="store_true",
                    help="the whole run and the replay on every drive: kitti-00, the four SiMpLE drives, the plain raw "
                         "drives of ../shared")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        run_vs_evo(a.runs, tmp, a.all_drives)
        replay_figures(a.all_drives)
        propagation(a.samples)
        startup(a.runs, tmp)
        if a.hour:
            hour(tmp, a.runs)
        if a.sweep:
            sweep(tmp)


if __name__ == "__main__":
    main()
