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


def install() -> None:
    """Listen for numba's compilations in this process (idempotent); the first one logs :data:`MESSAGE`."""
    global _listener
    if _listener is not None:
        return
    from numba.core import event

    class _FirstCompile(event.Listener):
        told = False

        def on_start(self, ev) -> None:
            if not self.told:
                self.told = True
                log.info(MESSAGE)

        def on_end(self, ev) -> None:
            pass

    _listener = _FirstCompile()
    event.register("numba:compile", _listener)
