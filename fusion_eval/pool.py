"""The local worker pool that a run and a comparison spread their evaluations over.

evo's metrics loop over poses in Python, so a run evaluates its estimates in worker processes while the
main process filters and writes. ``jobs=1`` runs everything in this process (inside a sweep's worker).
"""

from __future__ import annotations

import importlib
import logging
import multiprocessing as mp
import os
import signal
import sys
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures import process as cf_process
from contextlib import contextmanager

from . import interrupts


class Inline:
    """A stand-in executor that runs the work in this process, at submission."""

    def __enter__(self):
        return self

    def share(self, obj):
        """See :meth:`Pool.share`: here, the object itself."""
        return obj

    def __exit__(self, *exc):
        return False

    def submit(self, fn, *args, **kwargs):
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - re-raised by .result()
            fut.set_exception(exc)
        return fut


def _worker_dispositions() -> None:
    interrupts.ignore_terminal_signals()           # Ctrl-C and the hang-up are the parent's to handle
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def worker_init(preload: tuple[str, ...] = (), parent: int | None = None, console=None) -> None:
    """In each worker: Ctrl-C is the parent's to handle (a Ctrl-C to the process group must not print a traceback
    from every worker), SIGTERM ends the worker at once, and the worker dies with its parent (Linux), so that no
    worker outlives the command that started it, whatever signal ends it. ``preload``: modules to import then, while
    the parent still prepares and filters (matplotlib for a run's plots: about a second per process); ``parent``:
    the pid of the process that made the pool; ``console``: the command line's logging (``cli.CONSOLE``), for a
    spawned worker, which has none of its own."""
    _worker_dispositions()
    if console is not None and not logging.getLogger().handlers:
        from .cli import worker_logging

        worker_logging(console)
    # a spawned worker is exec'd from the thread that held SIGINT and SIGTERM blocked (signals_held) and inherits
    # that mask: SIGTERM would stay pending, and the pool's terminate() waited its full second before SIGKILL
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _FORK_SIGNALS)
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)      # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    # a parent that died before the line above armed it would never send the signal: this worker would wait on the
    # pool's queue for ever, holding the command's stdout and stderr open (a captured run would hang)
    if parent is not None and os.getppid() != parent:
        os._exit(1)
    for name in preload:
        importlib.import_module(name)


# A worker forked at the moment the run is interrupted would run the parent's Python signal handler inside
# CPython's own after-fork code (threading._after_fork) and print "Exception ignored ... Terminated" before
# worker_init could set its dispositions (seen once in CI: SIGINT during the first run's compilation, the pool
# terminated while a worker was being forked). So SIGINT and SIGTERM are blocked in the forking thread across the
# fork; the child sets the worker's dispositions first and only then unblocks, so a signal already sent to it is
# taken by those (SIGTERM ends it, SIGINT is ignored), never by the parent's handler.
#
# The parent must not raise them inside an at-fork hook either: an exception raised in one is printed and dropped
# by CPython ("Exception ignored in: _after_fork_in_parent"), and the run went on to exit 0 after a SIGTERM (seen
# in CI). So the pools fork inside :func:`signals_held`, which also defers the command's handler
# (interrupts.deferred): a signal sent meanwhile is raised when the hold ends, in ordinary code.
_FORK_SIGNALS = set(interrupts.SIGNALS)
_fork_mask: list = []


@contextmanager
def signals_held():
    """SIGINT and SIGTERM blocked in this thread and deferred by the command's handler inside the block (around a
    fork), raised after it."""
    with interrupts.deferred():              # ends after the mask is restored: what it raises cannot skip that
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _FORK_SIGNALS)
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _before_fork() -> None:
    _fork_mask.append(signal.pthread_sigmask(signal.SIG_BLOCK, _FORK_SIGNALS))


def _after_fork_in_parent() -> None:
    if _fork_mask:
        signal.pthread_sigmask(signal.SIG_SETMASK, _fork_mask.pop())


def _after_fork_in_child() -> None:
    try:
        _worker_dispositions()
    finally:
        # a worker never keeps them blocked: not when forked inside signals_held(), nor by a thread created in one
        # (multiprocessing.Pool's, which forks replacement workers), whose mask it inherits
        _fork_mask.clear()
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _FORK_SIGNALS)
        intr = sys.modules.get(__package__ + ".interrupts")
        if intr is not None:
            intr._deferring = 0                 # noqa: SLF001 - the parent's hold is not this process's


if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_before_fork, after_in_parent=_after_fork_in_parent,
                        after_in_child=_after_fork_in_child)


# Objects registered by Pool.share, by token: a worker forked after the registration has them in its memory (fork
# copies the parent's pages only when either side writes them), so a job names them by token instead of pickling them.
_SHARED: dict[int, object] = {}
_share_tokens = iter(range(1, 1 << 62))


def _shared_object(token: int):
    return _SHARED[token]


def _as_is(obj):
    return obj


class Handle:
    """An argument of a pool's jobs that its forked workers already hold (:meth:`Pool.share`)."""

    __slots__ = ("token", "obj", "pool")

    def __init__(self, token: int, obj, pool: "Pool"):
        self.token, self.obj, self.pool = token, obj, pool

    def __reduce__(self):
        # pickled by the executor when the job is sent: by then the pool's workers exist
        if self.token <= self.pool._inherited_upto:
            return _shared_object, (self.token,)
        return _as_is, (self.obj,)


class Pool(ProcessPoolExecutor):
    """A process pool that, when the block it serves ends by an exception (Ctrl-C, SIGTERM, an error), cancels
    what has not started and kills its workers instead of waiting for them (a run's workers write into its staging
    folder: they must be gone before it is removed)."""

    def __init__(self, max_workers: int, mp_context, preload: tuple[str, ...] = ()):
        cli = sys.modules.get("fusion_eval.cli")          # a command line's logging, for spawned workers
        super().__init__(max_workers=max_workers, mp_context=mp_context, initializer=worker_init,
                         initargs=(tuple(preload), os.getpid(), getattr(cli, "CONSOLE", None)))
        self._abort_token = interrupts.on_abort(self.terminate)
        self._shared: list[int] = []
        self._inherited_upto = 0                 # the last shared token every worker was forked after
        self._forks = mp_context.get_start_method() == "fork"

    def share(self, obj) -> Handle:
        """``obj`` as an argument of this pool's jobs: the workers forked after this call (a pool forks them at its
        first job) hold it already, and the jobs name it instead of pickling it (a simulated hour's ground truth
        and estimates are tens of MB each, sent to four jobs). Otherwise it is pickled as usual. Held until the
        pool ends."""
        token = next(_share_tokens)
        _SHARED[token] = obj
        self._shared.append(token)
        return Handle(token, obj, self)

    def _spawn_process(self):
        # every worker is forked here, in the thread that submits (see signals_held)
        with signals_held():
            super()._spawn_process()
        # what this worker holds; a pool that has forked before holds its earlier value for the older workers
        upto = self._shared[-1] if (self._forks and self._shared) else 0
        self._inherited_upto = upto if len(self._processes) == 1 else min(self._inherited_upto, upto)

    def _forget_shared(self) -> None:
        for t in self._shared:
            _SHARED.pop(t, None)
        self._shared = []

    def __exit__(self, exc_type, exc, tb):
        interrupts.forget(self._abort_token)
        try:
            return self._exit(exc_type, exc, tb)
        finally:
            self._forget_shared()

    def _exit(self, exc_type, exc, tb):
        if exc_type is not None:
            self.terminate()
            return False
        return super().__exit__(exc_type, exc, tb)

    def terminate(self) -> None:
        procs = list((getattr(self, "_processes", None) or {}).values())
        queue = getattr(self, "_result_queue", None)          # shutdown() forgets it
        manager = getattr(self, "_executor_manager_thread", None)     # so does it this
        self.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=1.0)
            if p.is_alive():
                p.kill()
                p.join(timeout=1.0)
        # A worker killed while it sent a result leaves half a message in the result pipe, and the executor's manager
        # thread blocked reading the rest: it would never end, and the interpreter joins it at exit (a hang after
        # the command is done). Closing our own end for writing gives that read an end of file: the thread sees a
        # broken pool and ends.
        if queue is not None:
            queue._writer.close()                               # noqa: SLF001 - see above
        # That thread closes its wake-up pipe as it ends; Python's exit hook for process pools writes to the pipes of
        # the pools still registered, and could find this one closed under it (CPython 3.11 checks, then writes,
        # unlocked): an EBADF traceback after "terminated" (seen once in CI). The thread no longer needs waking.
        if manager is not None:
            cf_process._threads_wakeups.pop(manager, None)      # noqa: SLF001


def executor(jobs: int | None = None, preload: tuple[str, ...] = ()):
    """A process pool of ``jobs`` workers (default: the cores, at most 4), or :class:`Inline` for one job.
    ``preload``: modules each worker imports as it starts (:func:`worker_init`)."""
    jobs = (os.cpu_count() or 1) if jobs is None else jobs
    if jobs <= 1:
        return Inline()
    # fork: the workers inherit the imported modules and the data, so they start in milliseconds
    return Pool(max_workers=min(jobs, 4), mp_context=mp.get_context("fork"), preload=preload)


@contextmanager
def dask_client(scheduler: str | None, local_workers: int = 0):
    """A Dask client on the scheduler at ``scheduler``, or on a local cluster of ``local_workers`` single-threaded
    processes started here (``--dask local``), closed on the way out whatever happens. An address nobody answers is
    one line naming the option (Dask's own error names neither the option nor what to check)."""
    from dask.distributed import Client, LocalCluster

    from .errors import ConfigError

    cluster = LocalCluster(n_workers=local_workers, threads_per_worker=1, processes=True, dashboard_address=None) \
        if local_workers else None
    try:
        try:
            client = Client(cluster if cluster is not None else scheduler)
        except (OSError, TimeoutError) as exc:
            raise ConfigError(f"--scheduler {scheduler}: no Dask scheduler answers there ({exc})") from None
        try:
            if cluster is not None:
                dask_console(client)
            yield client
        finally:
            client.close()
    finally:
        if cluster is not None:
            cluster.close()


def dask_console(client) -> None:
    """The command line's logging (-q, -v) on a local Dask cluster's workers, whose stderr is the user's terminal: they
    start with Dask's own, and printed run warnings under -q (a reproducibility review). A spawned pool's workers get
    it from their initializer."""
    from . import cli

    if getattr(cli, "CONSOLE", None) is not None:
        client.run(cli.worker_logging, cli.CONSOLE)
