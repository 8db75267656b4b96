"""The local worker pool that a run and a comparison spread their evaluations over.

evo's metrics loop over poses in Python, so a run evaluates its estimates in worker processes while the
main process filters and writes. ``jobs=1`` runs everything in this process (inside a sweep's worker).
"""

from __future__ import annotations

import multiprocessing as mp
import os
from concurrent.futures import Future, ProcessPoolExecutor


class Inline:
    """A stand-in executor that runs the work in this process, at submission."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def submit(self, fn, *args, **kwargs):
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - re-raised by .result()
            fut.set_exception(exc)
        return fut


def executor(jobs: int | None = None):
    """A process pool of ``jobs`` workers (default: the cores, at most 4), or :class:`Inline` for one job."""
    jobs = (os.cpu_count() or 1) if jobs is None else jobs
    if jobs <= 1:
        return Inline()
    # fork: the workers inherit the imported modules and the data, so they start in milliseconds
    return ProcessPoolExecutor(max_workers=min(jobs, 4), mp_context=mp.get_context("fork"))
