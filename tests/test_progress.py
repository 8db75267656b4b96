"""Progress over the whole run: the stages the engine reports, how they are drawn, and -q's single line."""

from __future__ import annotations

import io
import logging
import subprocess
import sys

import pytest

from fusion_eval.progress import Counter, Display, Stages, as_stages


class _Record(Stages):
    def __init__(self):
        self.events = []

    def start(self, name, total=None):
        self.events.append(("start", name, total))

    def advance(self, n=1):
        self.events.append(("advance", n))

    def __call__(self, fraction):
        self.events.append(("fraction", fraction))


@pytest.mark.slow
def test_a_run_reports_every_stage_in_order(kitti_slice, tmp_path):
    from fusion_eval import session
    from fusion_eval.pipeline import run_to_dir

    rec = _Record()
    run_to_dir(kitti_slice, session.request(), tmp_path / "out", progress=rec)
    starts = [e[1] for e in rec.events if e[0] == "start"]
    assert starts == ["load", "prepare", "filter", "evaluate", "write"]
    fr = [e[1] for e in rec.events if e[0] == "fraction"]
    assert fr and fr[-1] == 1.0 and fr == sorted(fr)                 # the filter's fraction, monotone, to the end
    i_eval = rec.events.index(("start", "evaluate", 4))                # fused, lidar, gnss, imu_only
    i_write = next(i for i, e in enumerate(rec.events) if e[:2] == ("start", "write"))
    assert rec.events[i_eval + 1:i_write].count(("advance", 1)) == 4
    assert rec.events[i_write + 1:].count(("advance", 1)) >= 8       # files and plots written, one by one


def test_a_plain_callable_hears_only_the_filter():
    seen = []
    st = as_stages(seen.append)
    st.start("load")
    st(0.5)
    st.start("filter")
    st(0.25)
    st(1.0)
    st.start("write")
    st.advance()
    st(0.9)
    assert seen == [0.25, 1.0]
    assert isinstance(as_stages(None), Stages) and as_stages(st) is st


def test_display_off_a_terminal_writes_one_line_per_stage():
    buf = io.StringIO()
    d = Display(buf, tty=False)
    d.start("load")
    d.start("evaluate", 4)
    for _ in range(4):
        d.advance()
    d(0.5)
    d.start("write")
    d.close()
    lines = buf.getvalue().splitlines()
    assert lines[:3] == ["load ...", "evaluate (4) ...", "write ..."]
    assert len(lines) == 4 and lines[3].startswith("stage times (wall): load ") and "write" in lines[3]


def test_display_on_a_terminal_draws_bars():
    buf = io.StringIO()
    d = Display(buf, tty=True, refresh_s=0.05)
    d.start("filter")
    d(0.5)
    d(1.0)
    d.start("write")
    d.advance(3)
    d.close()
    out = buf.getvalue()
    assert "filter: ..." in out and "filter: 100%|" in out and "write: 3 done" in out   # (50 % is within mininterval)


def test_counter_says_done_failed_and_eta():
    buf = io.StringIO()
    c = Counter("sweep", buf, tty=False, every_s=0.0)
    c.update(0, 0, 4)
    c.update(2, 1, 4)
    c.update(4, 1, 4, "best 0.7")
    c.close()
    lines = buf.getvalue().splitlines()
    assert lines[0].startswith("sweep: 0/4 done, 0 failed")
    assert lines[1].startswith("sweep: 2/4 done, 1 failed") and "ETA" in lines[1]
    assert lines[2].startswith("sweep: 4/4 done, 1 failed") and "ETA" not in lines[2] and lines[2].endswith("best 0.7")


def test_a_counter_of_work_that_cannot_fail_says_no_failures():
    """simulate-track's lines: a count and an ETA, no 'failed' column (nothing there fails line by line)."""
    buf = io.StringIO()
    c = Counter("simulate-track (lines)", buf, tty=False, every_s=0.0, failures=False)
    c.update(20000, 0, 60000)
    c.update(60000, 0, 60000)
    lines = buf.getvalue().splitlines()
    assert lines[0].startswith("simulate-track (lines): 20000/60000 done (") and "ETA" in lines[0]
    assert "failed" not in buf.getvalue() and lines[1].startswith("simulate-track (lines): 60000/60000 done (")


@pytest.mark.slow
def test_quiet_prints_exactly_the_output_path(kitti_slice, tmp_path):
    out = tmp_path / "q"
    r = subprocess.run([sys.executable, "-m", "fusion_eval", "-q", "run", str(kitti_slice), "--out", str(out),
                        "--no-plots"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"{out}\n" and r.stderr == ""
    assert (out / "metrics.json").exists()


@pytest.mark.slow
def test_non_tty_run_shows_its_stages_on_stderr(kitti_slice, tmp_path):
    r = subprocess.run([sys.executable, "-m", "fusion_eval", "run", str(kitti_slice), "--out", str(tmp_path / "o"),
                        "--no-plots"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    stages = [ln for ln in r.stderr.splitlines() if ln.endswith(" ...")]
    assert stages == ["load ...", "prepare ...", "filter ...", "evaluate (4) ...", "write ..."], r.stderr
    assert "stage times (wall):" in r.stderr and r.stdout.rstrip().endswith("open report.html)")


def test_library_chatter_is_hidden_below_minus_vv():
    from fusion_eval.cli import _Handler

    quiet, loud = _Handler(verbose=0), _Handler(verbose=2)
    info = logging.LogRecord("distributed.scheduler", logging.INFO, __file__, 1, "Scheduler at tcp://x", None, None)
    warn = logging.LogRecord("distributed.worker", logging.WARNING, __file__, 1, "worker lost", None, None)
    ours = logging.LogRecord("fusion_eval.prepare", logging.INFO, __file__, 1, "gyro lag", None, None)
    assert not quiet.filter(info) and quiet.filter(warn) and quiet.filter(ours)
    assert loud.filter(info)


def test_a_compilation_says_so_once(caplog):
    """A fresh install's first run sat on 'prepare ...' for 48 s with no hint (found by a new-user review): numba's
    first compilation in a command logs one line; later ones, and a warm run, nothing."""
    import logging

    from numba import njit

    from fusion_eval import compile_notice

    compile_notice.install()
    compile_notice.install()                  # idempotent: one listener
    compile_notice._listener.told = False     # as in a fresh process
    with caplog.at_level(logging.INFO, logger="fusion_eval"):
        njit(lambda x: x + 1)(1)
        njit(lambda x: x + 2)(1)
        assert caplog.text.count("compiling the numerical kernels") == 1
        caplog.clear()
        njit(lambda x: x + 3)(1)
    assert "compiling" not in caplog.text
