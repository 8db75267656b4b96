"""Progress over a whole command: what the engine reports (:class:`Stages`) and how the CLI shows it (:class:`Display`).

The engine names its stages as it enters them (load, prepare, filter, evaluate, write, ...), gives a total where it
knows one, and advances; a plain callable ``progress(fraction)`` (the Python API's older form) is wrapped by
:func:`as_stages` and hears the filter's fraction only. The engine never prints: :class:`Display`, made by the CLI,
draws on stderr with `tqdm <https://tqdm.github.io>`_ on a terminal (a bar per stage, or a running clock where the
stage has no total, redrawn every 0.25 s so a long stage never looks stuck) and, on anything else (a CI log, a
pipe), one plain line per stage and a summary of the stage times at the end. :class:`Counter` is the same for
sweeps and tunes: runs done, failed, and an ETA.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import Callable, TextIO


def _size() -> dict:
    """tqdm's ``ncols`` and ``nrows`` from the terminal, or 100 x 24 where it reports none (a pseudo-terminal
    without a size says 0 x 0, and tqdm hides every bar below row ``nrows``)."""
    import shutil

    cols, rows = shutil.get_terminal_size((100, 24))
    return {"ncols": cols if cols >= 40 else 100, "nrows": rows if rows >= 2 else 24}


class Stages:
    """The progress interface the engine calls; this base ignores everything (no display)."""

    def start(self, name: str, total: float | None = None) -> None:
        """Enter stage ``name`` (``total``: the units :meth:`advance` counts to, None if unknown)."""

    def advance(self, n: float = 1) -> None:
        """``n`` more units of the current stage done (may be called from a worker's callback thread)."""

    def __call__(self, fraction: float) -> None:
        """The current stage's fraction done (the filter's replay reports this way)."""

    def close(self) -> None:
        """The command is over (done or failed): clear what is drawn."""


class _Callable(Stages):
    """A plain ``progress(fraction)`` callable: told the filter's fraction (and 1.0 at its end), nothing else."""

    def __init__(self, fn: Callable[[float], None]):
        self.fn, self.stage = fn, None

    def start(self, name: str, total: float | None = None) -> None:
        self.stage = name

    def __call__(self, fraction: float) -> None:
        if self.stage in ("filter", "trials"):
            self.fn(fraction)


def as_stages(progress) -> Stages:
    if isinstance(progress, Stages):
        return progress
    return Stages() if progress is None else _Callable(progress)


class Display(Stages):
    """Stages drawn on ``stream``: tqdm bars on a terminal, one line per stage elsewhere."""

    def __init__(self, stream: TextIO | None = None, tty: bool | None = None, refresh_s: float = 0.25):
        # stderr closed (2>&-): Python's sys.stderr is None; progress is then written nowhere
        self.stream = stream or sys.stderr or open(os.devnull, "w")  # noqa: SIM115 - lives as long as the process
        self.tty = self.stream.isatty() if tty is None else tty
        self.lock = threading.Lock()
        self.bar = None
        self.name: str | None = None
        self.t_stage = time.perf_counter()
        self.times: list[tuple[str, float]] = []
        self.total: float | None = None
        self._stop = threading.Event()
        self._ticker = None
        if self.tty:
            self._ticker = threading.Thread(target=self._tick, args=(refresh_s,), daemon=True, name="progress")
            self._ticker.start()

    def _tick(self, every_s: float) -> None:
        while not self._stop.wait(every_s):
            with self.lock:
                if self.bar is not None:
                    self.bar.refresh()           # the elapsed clock moves even when the stage reports nothing

    def _end_stage(self) -> None:
        if self.name is not None:
            self.times.append((self.name, time.perf_counter() - self.t_stage))
        if self.bar is not None:
            if self.total is not None:
                self.bar.n = self.total
            self.bar.close()
            self.bar = None

    def start(self, name: str, total: float | None = None) -> None:
        from tqdm import tqdm

        with self.lock:
            self._end_stage()
            self.name, self.total, self.t_stage = name, total, time.perf_counter()
            if not self.tty:
                self.stream.write(f"{name}{'' if total is None else f' ({total:g})'} ...\n")
                self.stream.flush()
                return
            fmt = ("{desc:>10}: {percentage:3.0f}%|{bar:30}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}]" if total
                   else "{desc:>10}: ... [{elapsed}]")
            self.bar = tqdm(total=total, desc=name, file=self.stream, bar_format=fmt, leave=True, **_size(),
                            mininterval=0.1)

    def advance(self, n: float = 1) -> None:
        with self.lock:
            if self.bar is not None:
                if self.bar.total is None:          # a count without a total: say how many are done
                    self.bar.bar_format = "{desc:>10}: {n_fmt} done [{elapsed}]"
                self.bar.update(n)

    def __call__(self, fraction: float) -> None:
        with self.lock:
            if self.bar is None:
                return
            if self.bar.total is None:          # a fraction on a stage started without a total: make it a bar
                self.bar.total, self.total = 100, 100
                self.bar.bar_format = "{desc:>10}: {percentage:3.0f}%|{bar:30}| [{elapsed}<{remaining}]"
            target = fraction * self.bar.total
            if target > self.bar.n:
                self.bar.update(target - self.bar.n)

    def close(self, summary: bool = True) -> None:
        self._stop.set()
        with self.lock:
            self._end_stage()
            self.name = None
            if not self.tty and self.times and summary:
                # wall time spent in each stage (work of one stage that overlaps another, such as the evaluations
                # that run alongside the filter, counts where it was waited for)
                self.stream.write("stage times (wall): " + ", ".join(f"{n} {t:.1f} s" for n, t in self.times) + "\n")
                self.stream.flush()
            self.times = []
        if self._ticker is not None and self._ticker is not threading.current_thread():
            self._ticker.join(timeout=1.0)       # no daemon thread left to wake while the interpreter exits
            self._ticker = None


class Counter:
    """Runs of a sweep or trials of a tune: done, failed, remaining and an ETA, on ``stream``. On a terminal a tqdm
    bar; elsewhere a line at most every ``every_s`` seconds and one at the end."""

    def __init__(self, label: str, stream: TextIO | None = None, tty: bool | None = None, every_s: float = 10.0,
                 failures: bool = True):
        self.label, self.stream, self.failures = label, stream or sys.stderr, failures      # failures: count them
        self.tty = self.stream.isatty() if tty is None else tty
        self.bar, self.every_s, self.t_line, self.t0 = None, every_s, 0.0, time.perf_counter()

    def update(self, done: int, failed: int, total: int, note: str = "") -> None:
        """``done`` finished (failed included) of ``total``, ``failed`` of them failed."""
        if self.tty:
            from tqdm import tqdm

            if self.bar is None:
                self.bar = tqdm(total=max(total, 1), desc=self.label, file=self.stream, **_size(),
                                bar_format="{desc}: {percentage:3.0f}%|{bar:30}| {n_fmt}/{total_fmt} "
                                           "[{elapsed}<{remaining}]{postfix}")
            self.bar.total = max(total, 1)
            post = [f"failed {failed}"] if self.failures else []
            self.bar.set_postfix_str(", ".join(post + ([note] if note else [])), refresh=False)
            self.bar.update(done - self.bar.n)
            return
        now = time.perf_counter()
        if now - self.t_line >= self.every_s or done == total:
            self.t_line = now
            self.stream.write(self._line(done, failed, total, note) + "\n")
            self.stream.flush()

    def _line(self, done: int, failed: int, total: int, note: str) -> str:
        el = time.perf_counter() - self.t0
        eta = "" if not done or done >= total else f", ETA {el / done * (total - done):.0f} s"
        failed_s = f", {failed} failed" if self.failures else ""
        return f"{self.label}: {done}/{total} done{failed_s} ({el:.0f} s{eta})" + (f"; {note}" if note else "")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
