"""Warnings said on behalf of one run among many: a sweep's or a tune's runs share one stderr, and a line such as
"gnss: median NIS 516 for 3 dof" said nothing of which setting or trial raised it."""

from __future__ import annotations

import logging
from contextlib import contextmanager
from typing import Iterator


@contextmanager
def prefixed(label: str) -> Iterator[None]:
    """Warnings (and worse) of fusion-eval's loggers inside the block begin with ``label: ``. The record factory is
    process-wide, as the block is: one run at a time per process (a pool worker's, or the main process's)."""
    old = logging.getLogRecordFactory()
    def factory(*args, **kwargs):
        rec = old(*args, **kwargs)
        if rec.levelno >= logging.WARNING and rec.name.startswith("fusion_eval"):
            # the message made now, its arguments spent: a label's '%' stays one (a message without arguments is
            # not %-formatted, so escaping it showed '%%')
            rec.msg, rec.args = f"{label}: {rec.getMessage()}", None
        return rec

    logging.setLogRecordFactory(factory)
    try:
        yield
    finally:
        logging.setLogRecordFactory(old)


class _Collector(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())


@contextmanager
def collected(show: bool = True) -> Iterator[list[str]]:
    """The warnings (and worse) of fusion-eval's loggers inside the block, as their messages; ``show`` False keeps them
    from the console (a Monte-Carlo trial's, which the run sums up once instead of repeating each trial's: a review)."""
    pkg = logging.getLogger("fusion_eval")
    # a block that keeps its warnings to itself keeps them from an enclosing block's collection too (a trial run in
    # the run's own process, with one worker, would count its findings as the run's)
    outer = [] if show else [x for x in pkg.handlers if isinstance(x, _Collector)]
    for x in outer:
        pkg.removeHandler(x)
    h = _Collector()
    pkg.addHandler(h)
    propagate = pkg.propagate
    if not show:
        pkg.propagate = False
    try:
        yield h.messages
    finally:
        pkg.removeHandler(h)
        for x in outer:
            pkg.addHandler(x)
        pkg.propagate = propagate
