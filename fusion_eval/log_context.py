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
