"""Shared fixtures: paths to the embedded and shared real data, and a short slice of kitti-00."""

from __future__ import annotations

import contextlib
import os
import logging
import shutil
from pathlib import Path

import pytest

try:        # the fuzz suite's example budgets: 'ci' by default (bounded, derandomized), --hypothesis-profile=long for more
    from hypothesis import HealthCheck, settings

    _checks = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
    settings.register_profile("ci", max_examples=16, deadline=None, derandomize=True, suppress_health_check=_checks)
    settings.register_profile("long", max_examples=200, deadline=None, derandomize=False, suppress_health_check=_checks)
    settings.load_profile("ci")
except ImportError:
    pass

ROOT = Path(__file__).resolve().parent.parent
KITTI00 = ROOT / "data" / "kitti-00"
SHARED = ROOT.parent / "shared" / "data"


def pytest_sessionstart(session) -> None:
    """Under pytest-xdist, numba's cache is filled once, in the controller, before the workers start.

    In a fresh clone every process that first needs the default run's compiled kernels compiles them itself
    (about a minute each): both xdist workers, the CLI subprocesses, the Dask workers of the cluster test,
    all at once in the first minutes (four tests took 80-145 s each in CI). One default run on a 20 s slice,
    here, compiles them once into the on-disk cache that every later process loads (a few seconds when the cache
    is already warm). A failure is left to the tests themselves to report."""
    import subprocess
    import sys
    import tempfile

    if hasattr(session.config, "workerinput") or not getattr(session.config.option, "numprocesses", None):
        return
    with tempfile.TemporaryDirectory() as d:
        make_slice(Path(d) / "ds", 200)
        subprocess.run([sys.executable, "-m", "fusion_eval", "-q", "run", str(Path(d) / "ds"), "--out",
                        str(Path(d) / "out"), "--no-plots"], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL, check=False)


def wait_for(pred, timeout_s: float, step_s: float = 0.05) -> bool:
    """Poll ``pred`` until it holds (True) or ``timeout_s`` passes (False): for tests that watch another process."""
    import time

    t_end = time.time() + timeout_s
    while time.time() < t_end:
        if pred():
            return True
        time.sleep(step_s)
    return False


def under_ci() -> bool:
    """Whether the suite runs as CI runs it (CI=true), where ../shared/data sits beside the clone."""
    return os.environ.get("CI", "").lower() == "true"


def shared_path(*parts: str) -> Path:
    """A file of ../shared/data, or skip the test with the reason when it is absent. Under CI (CI=true), where the
    data sits beside the clone, its absence fails the test: a clone without ../shared skipped 48 tests and reported
    green (a mutation review)."""
    p = SHARED.joinpath(*parts)
    if not p.exists():
        if under_ci():
            pytest.fail(f"CI=true but the shared real data is not at {p}: CI runs with ../shared/data beside the clone")
        pytest.skip(f"needs the shared real data at {p} (absent on this machine)")
    return p


def make_slice(dst: Path, n_packets: int, first: int = 0) -> Path:
    """A self-contained copy of data/kitti-00 holding packets [first, first + n_packets) and their lidar poses."""
    dst.mkdir(parents=True, exist_ok=True)
    src = KITTI00
    (dst / "oxts" / "data").mkdir(parents=True)
    stamps = (src / "oxts" / "timestamps.txt").read_text().splitlines()[first:first + n_packets]
    (dst / "oxts" / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    for i in range(n_packets):
        shutil.copy(src / "oxts" / "data" / f"{first + i:010d}.txt", dst / "oxts" / "data" / f"{i:010d}.txt")
    shutil.copy(src / "calib_imu_to_velo.txt", dst)
    (dst / "lidar").mkdir()
    shutil.copy(src / "lidar" / "calib.txt", dst / "lidar")
    poses = (src / "lidar" / "00_poses_kitti.txt").read_text().splitlines()[first:first + n_packets]
    (dst / "lidar" / "poses.txt").write_text("\n".join(poses) + "\n")
    times = (src / "lidar" / "times.txt").read_text().splitlines()[first:first + n_packets]
    (dst / "lidar" / "times.txt").write_text("\n".join(times) + "\n")
    manifest = (src / "dataset.yaml").read_text().replace("lidar/00_poses_kitti.txt", "lidar/poses.txt")
    (dst / "dataset.yaml").write_text(manifest.replace("name: kitti-00", "name: kitti-00-slice"))
    return dst


@pytest.fixture(scope="session")
def kitti_slice(tmp_path_factory) -> Path:
    """The first 900 packets (about 90 s, 0.7 km) of kitti-00, including the filled packets 0-13 and 347-361."""
    return make_slice(tmp_path_factory.mktemp("slice") / "kitti-00-slice", 900)


@pytest.fixture(scope="session")
def slice_run(kitti_slice, tmp_path_factory) -> Path:
    """The output folder of `fusion-eval run` with the default configuration on the slice."""
    return cli_run(kitti_slice, tmp_path_factory.mktemp("run") / "out")


def cli_run(dataset: Path, out: Path, *extra: str) -> Path:
    """``out``, written by a `fusion-eval -q run` of ``dataset`` that must succeed (``extra``: more options)."""
    from click.testing import CliRunner

    from fusion_eval.cli import main

    res = CliRunner().invoke(main, ["-q", "run", str(dataset), "--out", str(out), *extra])
    assert res.exit_code == 0, res.output
    return out


@pytest.fixture(scope="session")
def white_sim(tmp_path_factory):
    """A 120 s urban drive whose sensors have the white noises the filters assume (no lidar scale or yaw drift), and
    the runs made on it, by formulation and smoother (shared by the slow consistency tests)."""
    import fusion_eval as fe
    from fusion_eval.simulate.dataset import simulate

    out = tmp_path_factory.mktemp("white") / "w"
    simulate(out, "urban", 120.0, 1, "automotive", ("lidar.scale_drift=0", "lidar.yaw_drift_deg_per_100m=0"), jobs=1)
    ds = fe.load_dataset(out)
    runs: dict = {}

    def run(formulation="error_state", method="rts"):
        key = (formulation, method)
        if key not in runs:
            runs[key] = fe.run(ds, overrides={"filter.formulation": formulation, "smoother.method": method})
        return runs[key]
    return run


def without_provenance(text: bytes) -> bytes:
    """A report with its provenance header (the minute and the command line, which differ between two runs of the
    same inputs) replaced by a placeholder."""
    import re

    text = re.sub(rb"fusion-eval \S+ (?:\(code \w+\) )?[^\n]* UTC: `[^\n]*`", b"<header>", text)
    text = re.sub(rb'\n *"(?:date|command)": "[^\n]*",?(?=\n)', b"", text)       # metrics.json's provenance
    # report.html's body line, as rendered (the minute of two runs differs at a minute's turn: a CI run)
    text = re.sub(rb"fusion-eval \S+ (?:\(code \w+\) )?[^\n<]* UTC: <code>[^\n]*?</code>", b"<header>", text)
    return re.sub(rb'<div class="meta">[^\n]*</div>', b"<header>", text)


def _baseline_logging() -> None:
    from fusion_eval.cli import _CHATTY          # the loggers the CLI sets, besides its own

    logging.getLogger().setLevel(logging.WARNING)
    for n in ("fusion_eval", *_CHATTY):
        logging.getLogger(n).setLevel(logging.NOTSET)


@pytest.fixture(autouse=True)
def _logging_levels_restored():
    """The CLI sets the log levels of its process (``-q``: errors only). A test, or a session fixture, that runs it
    in-process must not leave them to the next test in the same worker, whose ``caplog`` would see no warning: each
    test starts from Python's defaults (root at WARNING, the others unset) and the root's handlers are put back."""
    handlers = logging.getLogger().handlers[:]
    _baseline_logging()
    yield
    _baseline_logging()
    logging.getLogger().handlers[:] = handlers


@contextlib.contextmanager
def lock_held_elsewhere(path):
    """``path`` held as a fusion-eval lock by another process for the block; yields that process (its ``pid``)."""
    import subprocess
    import sys

    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from pathlib import Path; "
                               "from fusion_eval.locks import take; take(Path(sys.argv[1]), 0, str); "
                               "print('held', flush=True); time.sleep(60)", str(path)],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        yield holder
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
