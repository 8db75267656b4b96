"""The worker pool: objects shared with forked workers without pickles (Pool.share)."""

from __future__ import annotations

import numpy as np
import pytest


class _NoPickle:
    """An object a job can only get by inheritance: pickling it fails."""

    def __init__(self, value):
        self.value = value

    def __reduce__(self):
        raise TypeError("pickled")


def _value_of(obj):
    return obj.value


def test_a_shared_object_reaches_forked_workers_without_a_pickle():
    """Pool.share: objects registered before the pool's first job (which forks the workers) are named by token;
    one registered later is pickled as usual; the registry forgets them when the pool ends."""
    from fusion_eval import pool

    with pool.executor(2) as ex:
        early = ex.share(_NoPickle(41))
        big = ex.share(np.arange(10))
        assert ex.submit(_value_of, early).result() == 41
        assert ex.submit(np.sum, big).result() == 45
        late = ex.share(_NoPickle(7))                    # the workers exist: it must travel as a pickle
        with pytest.raises(TypeError, match="pickled"):
            ex.submit(_value_of, late).result()
        assert ex.submit(np.sum, ex.share(np.arange(4))).result() == 6
    assert not pool._SHARED
    assert pool.Inline().share(early.obj) is early.obj


@pytest.mark.slow
def test_a_run_draws_its_plots_in_workers_that_preloaded_matplotlib(kitti_slice, tmp_path):
    """The run's plots are drawn by its workers, which import matplotlib as they start (while the main process
    prepares and filters); the main process, which only submits them, never imports it (about a second)."""
    import subprocess
    import sys

    out = tmp_path / "out"
    code = ("import sys\n"
            "from fusion_eval.cli import main\n"
            "try:\n"
            f"    main(['-q', 'run', {str(kitti_slice)!r}, '--out', {str(out)!r}], standalone_mode=False)\n"
            "finally:\n"
            "    print('matplotlib' in sys.modules)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-1] == "False", r.stdout
    assert {p.name for p in out.glob("*.png")} >= {"trajectories.png", "biases.png", "ape_over_time.png"}


def _imported(name: str) -> bool:
    import sys

    return name in sys.modules


def test_workers_import_the_preloaded_modules_as_they_start():
    import sys

    from fusion_eval import pool

    if "wave" in sys.modules:
        pytest.skip("this process imported the module already: its workers would inherit it")
    with pool.executor(2, preload=("wave",)) as ex:
        assert ex.submit(_imported, "wave").result()
    with pool.executor(2) as ex:
        assert not ex.submit(_imported, "wave").result()


def test_a_worker_whose_parent_died_before_it_started_exits_before_its_preload(tmp_path):
    """The parent-death signal is armed first; a parent gone before that (killed while the worker started) would
    never send it, so the worker checks and exits before the preload's import (a second it would spend orphaned,
    then wait on the queue for ever, holding the command's output open)."""
    import os
    import subprocess
    import sys

    (tmp_path / "marker_mod.py").write_text(f"open({str(tmp_path / 'imported')!r}, 'w').close()\n")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    for parent, code in (("os.getppid() + 1", 1), ("os.getppid()", 0)):
        r = subprocess.run([sys.executable, "-c", "import os\nfrom fusion_eval.pool import worker_init\n"
                            f"worker_init(('marker_mod',), parent={parent})\n"], env=env, capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == code, r.stderr
        assert (tmp_path / "imported").exists() == (code == 0)


def _blocked_signals() -> set:
    import signal

    return set(signal.pthread_sigmask(signal.SIG_BLOCK, []))


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_a_worker_takes_sigterm_whatever_its_start_method(method):
    """The pool starts its workers with SIGINT and SIGTERM blocked in the starting thread (signals_held); a spawned
    worker is exec'd with that mask, and kept it: the pool's terminate() then waited its full second per worker for
    a SIGTERM that stayed pending before it killed them (a sweep's Ctrl-C took 1.4-2.1 s instead of 0.45 s)."""
    import multiprocessing as mp
    import signal

    from fusion_eval import pool

    with pool.Pool(max_workers=1, mp_context=mp.get_context(method)) as ex:
        blocked = ex.submit(_blocked_signals).result(timeout=120)
    assert not blocked & {signal.SIGINT, signal.SIGTERM}, blocked


def test_a_spawned_workers_warnings_follow_the_command_lines_logging(capfd, monkeypatch):
    """A spawned worker (tune's pool) starts with no logging of its own: its warnings printed under -q, and without
    their 'warning:' (a tune review). It takes the command line's."""
    import logging
    import multiprocessing as mp

    import fusion_eval.cli as cli
    from fusion_eval.pool import Pool

    say = logging.getLogger("fusion_eval.test").warning
    for console, shown in (((0, 1), False), ((0, 0), True)):
        monkeypatch.setattr(cli, "CONSOLE", console)
        with Pool(1, mp.get_context("spawn")) as p:
            p.submit(say, "from a worker").result()
        err = capfd.readouterr().err
        assert ("warning: from a worker" in err) == shown and ("from a worker" in err) == shown, err
