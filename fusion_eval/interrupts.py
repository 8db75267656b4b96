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


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C, so that the same clean-up runs (staging folders removed,
    workers killed, finished sweep runs recorded)."""


_pending: int | None = None                  # a signal received inside the compiler, not yet delivered
_watcher: threading.Thread | None = None


_received: int | None = None                 # the last signal raised in this block


def received() -> int | None:
    """The signal number raised as an exception in the current :func:`handled` block, if any."""
    return _received


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


def _watch(main_ident: int) -> None:
    while _pending is not None:
        time.sleep(_POLL_S)
        signum = _pending
        frame = sys._current_frames().get(main_ident)           # noqa: SLF001 - the documented way to see a stack
        if frame is None:
            return                                              # the main thread has ended
        if signum is not None and not _in_llvmlite(frame):
            _thread.interrupt_main(signum)                      # the handler runs again, at the next bytecode
            time.sleep(5 * _POLL_S)


def _handler(signum, frame) -> None:
    global _pending, _watcher, _received
    if _in_llvmlite(frame):
        first = _pending is None
        _pending = signum
        if first and (_watcher is None or not _watcher.is_alive()):
            _watcher = threading.Thread(target=_watch, args=(threading.main_thread().ident,), daemon=True,
                                        name="fusion-eval-interrupt")
            _watcher.start()
        return
    _pending = None
    _received = signum
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


@contextmanager
def handled():
    """SIGINT and SIGTERM raise ``KeyboardInterrupt`` / :class:`Terminated` in the main thread inside the block, as
    soon as the code is outside llvmlite; the caller's handlers are restored after (so that invoking the CLI
    in-process, in tests or notebooks, leaves the process as it was). Outside the main thread: no change."""
    global _pending, _received
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s, h in old.items():
        if not (s == signal.SIGINT and h == signal.SIG_IGN):
            signal.signal(s, _handler)
    _received = None
    try:
        yield
    finally:
        _pending = None
        for s, h in old.items():
            if h is not None:                                   # None: set from C, cannot be restored from Python
                signal.signal(s, h)
