"""Ctrl-C and SIGTERM for the duration of a command, never lost inside numba's compiler.

Python raises ``KeyboardInterrupt`` at the next bytecode the main thread runs. While numba compiles a kernel (a fresh
install's first run compiles for about a minute) that bytecode is often numba's or llvmlite's, and there the exception
is lost or changed: raised inside llvmlite's object-cache ctypes callback it is printed ("Exception ignored on calling
ctypes callback function") and dropped, so the run went on to the end and exited 0; raised inside numba's type
inference it came out as a traceback with exit 1. So the handler looks at the main thread's stack first: inside
llvmlite (its ctypes callbacks and thin wrappers) it only records the signal, and a watcher thread delivers it again
(``_thread.interrupt_main``) as soon as the main thread has left llvmlite, within milliseconds; anywhere else it
raises, and the CLI reports any error that follows a received signal as the interruption it is
(:func:`received`), whatever numba made of the exception.

A compilation step can hold the main thread in one LLVM call for seconds, where no Python handler runs. So a signal
still pending after :data:`ABORT_AFTER_S` ends the command from the watcher thread: the clean-ups registered with
:func:`on_abort` run (the pool's workers killed, then the staging folder and its lock removed; the most recent
first), one line is printed, and the process exits with the signal's code. Nothing is written in that time (the main
thread is inside the compiler), so nothing half-written is left; a sweep's finished runs are already recorded by
their workers, and a tune's cut-off trials are enqueued again by the next run.

A SIGINT that the process inherited as ignored (a background job of a non-interactive shell) stays ignored, as POSIX
tools do; SIGTERM is always handled.
"""

from __future__ import annotations

import _thread
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager

_POLL_S = 0.02
ABORT_AFTER_S = 1.0          # a signal held this long inside llvmlite ends the command from the watcher


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C, so that the same clean-up runs (staging folders removed,
    workers killed, finished sweep runs recorded)."""


class HungUp(Terminated):
    """SIGHUP (the terminal closed, an ssh session dropped): ended as SIGTERM is. Its default action killed the
    command outright, leaving a visible empty output folder, a staging folder and a lock that a later default run,
    of another timestamped name, never cleaned (an interruption review)."""


_SIGHUP = getattr(signal, "SIGHUP", None)                                # (POSIX)
# what a terminal sends the command: Ctrl-C and its hang-up. An ignoring parent keeps them ignored (a background job's
# SIGINT, nohup's SIGHUP), as POSIX tools do; workers leave them to the parent; a command that is over ignores them
TERMINAL_SIGNALS = tuple(s for s in (signal.SIGINT, _SIGHUP) if s is not None)
# the signals a command ends on by its own clean-up
SIGNALS = (*TERMINAL_SIGNALS, signal.SIGTERM)


def ignore_terminal_signals() -> None:
    """Ctrl-C and the hang-up ignored from here (a worker's, or a command whose exit status is decided)."""
    for s in TERMINAL_SIGNALS:
        signal.signal(s, signal.SIG_IGN)


def as_exception(signum: int) -> KeyboardInterrupt:
    """What a signal is raised as in the main thread."""
    if signum == _SIGHUP:
        return HungUp()
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


_pending: int | None = None                  # a signal received inside llvmlite, not yet delivered
_deferring = 0                               # depth of deferred() blocks: record signals, raise them after
_handler_calls = 0                           # calls of the handler so far (deferring or raising)
_generation = 0                              # handled() blocks ended so far: a watcher of an ended block stops
_on_abort: dict[int, object] = {}             # token -> clean-up, run (newest first) when the watcher ends the command
_tokens = iter(range(1, 1 << 62))


def on_abort(cleanup) -> int:
    """Register ``cleanup()`` to run if a signal has to end the command from the watcher thread; returns a token for
    :func:`forget`. Clean-ups must be quick and must not need the main thread."""
    token = next(_tokens)
    _on_abort[token] = cleanup
    return token


def forget(token: int | None) -> None:
    if token is not None:
        _on_abort.pop(token, None)


def _abort(signum: int) -> None:
    for token in sorted(_on_abort, reverse=True):
        try:
            _on_abort[token]()
        except Exception:  # noqa: BLE001 - the others must still run, and the process must still end
            pass
    what = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted"
    os.write(2, f"\n{what} during numba's compilation: nothing half-written is left (finished sweep runs and tune "
                f"trials are kept; run the same command again)\n".encode())
    os._exit(143 if signum == signal.SIGTERM else 130)


_received: int | None = None                 # the last signal raised in this block
_written: list[str] = []                     # output folders completed in this block (said if a signal then ends it)
_active: list[bool] = []                     # handled() blocks open


def wrote(path) -> None:
    """Record a completed output folder: a signal that ends the command after it must not say nothing was written
    (a failure-injection review: "no output directory was written" beside a complete one). Only inside a command's
    :func:`handled` block (a program calling the API does not collect them)."""
    if _active:
        _written.append(str(path))


def written() -> list[str]:
    """The output folders completed in the current :func:`handled` block."""
    return list(_written)


_kept: list[str] = []                        # existing output folders an interrupted --overwrite left as they were


def kept(path) -> None:
    """Record an existing output folder left as it was by a run that did not finish (``--overwrite`` interrupted: it
    said "no output directory was written", which read as the old results gone too; an interruption review)."""
    if _active:
        _kept.append(str(path))


def left_as_they_were() -> list[str]:
    return list(_kept)


@contextmanager
def deferred():
    """Inside: a signal is recorded, not raised, and raised as soon as the block ends. For code around which CPython
    runs Python from C and drops what it raises, such as a fork's at-fork hooks (an exception raised in one is printed
    as "Exception ignored" and lost: a run once exited 0 after a SIGTERM). Blocking the signals in the forking thread
    is not enough: a process-directed signal is then taken by another thread, and Python runs its handler in the main
    thread at the next bytecode, wherever that is."""
    global _deferring
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1
        pending = _pending
        if not _deferring and pending is not None and threading.current_thread() is threading.main_thread():
            _thread.interrupt_main(pending)                     # the handler runs at the next bytecode, and raises


def received() -> int | None:
    """The signal number raised as an exception in the current :func:`handled` block, if any."""
    return _received


def reraise_if_received() -> None:
    """For a handler that takes any error as one job's failure (a sweep's run, a tune's trial): a signal raised in
    this block comes out of numba's compiled code as another error ("SystemError: CPUDispatcher(...) returned a
    result with an exception set"), which was recorded as the run's failure while the sweep went on (a clean-clone
    CI run caught it); it is raised again as the interruption it is."""
    if _received is not None:
        raise as_exception(_received) from None


def _in_llvmlite(frame) -> bool:
    # only a package already imported can be on the stack; importing llvmlite here would slow every command's start
    m = sys.modules.get("llvmlite")
    if m is None or not getattr(m, "__file__", None):
        return False
    root = os.path.dirname(m.__file__) + os.sep
    while frame is not None:
        if frame.f_code.co_filename.startswith(root):
            return True
        frame = frame.f_back
    return False


def _watch(rfd: int, main_ident: int) -> None:
    """The watcher: woken by every signal (Python's C-level handler writes its number to ``rfd`` at once, even while
    the main thread is inside a C call), it follows the signal until the handler has raised it: re-delivers a
    deferred one once the main thread has left llvmlite, and ends the command if the main thread stays inside
    llvmlite for :data:`ABORT_AFTER_S` (one long LLVM call, where the handler cannot run)."""
    try:
        _follow(rfd, main_ident, _generation)
    finally:
        os.close(rfd)


def _follow(rfd: int, main_ident: int, generation: int) -> None:
    seen_calls = _handler_calls
    while True:
        try:
            data = os.read(rfd, 64)
        except OSError:
            return
        if not data or generation != _generation:
            return                                              # the block ended: the write end is closed
        sigs = [b for b in data if b in SIGNALS]
        if not sigs:
            continue
        t_arrived = time.monotonic()
        # done once the handler has run since we last looked and left nothing deferred (it may have run before this
        # read: the byte is written first, the handler runs at the next bytecode)
        while not (_handler_calls > seen_calls and _pending is None):
            if generation != _generation:
                return
            time.sleep(_POLL_S)
            frame = sys._current_frames().get(main_ident)       # noqa: SLF001 - the documented way to see a stack
            if frame is None:
                return                                          # the main thread has ended
            inside = _in_llvmlite(frame)
            pending = _pending
            if pending is not None and not inside and not _deferring:
                _thread.interrupt_main(pending)                 # the handler runs again, at the next bytecode
                time.sleep(5 * _POLL_S)
            elif inside and time.monotonic() - t_arrived > ABORT_AFTER_S:
                _abort(pending if pending is not None else sigs[-1])
        seen_calls = _handler_calls


def _handler(signum, frame) -> None:
    global _pending, _received, _handler_calls
    _handler_calls += 1
    if _received is not None:
        # already raised in this block: the clean-up it started (staging folder, lock, workers) must run to its end,
        # not be cut by a second Ctrl-C, which would leave the folder and its lock behind
        _pending = None
        return
    if _deferring or _in_llvmlite(frame):
        _pending = signum                                       # delivered again, by deferred() or the watcher
        return
    _pending = None
    _received = signum
    raise as_exception(signum)


@contextmanager
def handled():
    """SIGINT and SIGTERM raise ``KeyboardInterrupt`` / :class:`Terminated` in the main thread inside the block, as
    soon as the code is outside llvmlite; the caller's handlers are restored after (so that invoking the CLI
    in-process, in tests or notebooks, leaves the process as it was). Outside the main thread: no change."""
    global _pending, _received, _generation
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in SIGNALS}
    for s, h in old.items():
        if not (s in TERMINAL_SIGNALS and h == signal.SIG_IGN):
            signal.signal(s, _handler)
    _received = None
    _written.clear()
    _kept.clear()
    _active.append(True)
    rfd, wfd = os.pipe()
    os.set_blocking(wfd, False)
    old_fd = signal.set_wakeup_fd(wfd, warn_on_full_buffer=False)
    watcher = threading.Thread(target=_watch, args=(rfd, threading.main_thread().ident), daemon=True,
                               name="fusion-eval-interrupt")
    watcher.start()
    try:
        yield
    finally:
        _active.pop()
        _pending = None
        _generation += 1
        signal.set_wakeup_fd(old_fd)
        os.close(wfd)                                           # the watcher reads an end of file and ends
        # ... and is waited for: a daemon thread that wakes while the interpreter finalizes can crash it (CPython
        # gh-110052, 3.9-3.12; seen in CI as "Fatal Python error: PyThreadState_Get" and exit -6 right after an
        # interrupted run printed its last line, the watcher woken by this very close)
        watcher.join(timeout=2.0)
        for s, h in old.items():
            if h is not None:                                   # None: set from C, cannot be restored from Python
                signal.signal(s, h)
