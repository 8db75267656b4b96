"""One line when numba compiles the kernels, so that a fresh install's first run says why it takes a minute.

numba compiles each kernel the first time it is called after an install (or a change of its source) and caches the
machine code beside the module; later runs load it in milliseconds. Without a word a first run sat on 'prepare ...'
for 48 s and on 'filter ...' for 40 s (found by a new-user review). numba announces each compilation as an event
(``numba.core.event``, kind ``numba:compile``); the first of a command's prints the line, a warm run prints nothing.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

MESSAGE = ("compiling the numerical kernels for this installation (once: a minute or two on 2 cores; "
           "later runs load them from numba's cache)")
_listener = None


def compile_seconds() -> float:
    """Wall seconds this process has spent compiling since :func:`install` (0 without it): a timing that spans a
    first call subtracts what it gained here (compare's filter time of a variant compiled in the same command, 18 s
    against 0.6 s warm, read as the formulation's speed)."""
    return 0.0 if _listener is None else _listener.total_s


def install() -> None:
    """Listen for numba's compilations in this process (idempotent); the first one logs :data:`MESSAGE`."""
    global _listener
    if _listener is not None:
        return
    import time

    from numba.core import event

    class _FirstCompile(event.Listener):
        told = False
        depth = 0              # a kernel's compilation compiles its callees inside it: the outermost one is timed
        total_s = 0.0
        t0 = 0.0

        def on_start(self, ev) -> None:
            if not self.told:
                self.told = True
                log.info(MESSAGE)
            if self.depth == 0:
                self.t0 = time.perf_counter()
            self.depth += 1

        def on_end(self, ev) -> None:
            self.depth = max(self.depth - 1, 0)
            if self.depth == 0:
                self.total_s += time.perf_counter() - self.t0

    _listener = _FirstCompile()
    event.register("numba:compile", _listener)
