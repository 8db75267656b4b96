"""Atomic output directories: everything is written into a hidden staging folder beside the target
and renamed into place only when the whole run succeeded, so an interrupted or failed run never
leaves a half-written output directory and never destroys an earlier one."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import logging
import os
import re
import shutil
from pathlib import Path

from . import interrupts, locks
from .errors import OutputError

log = logging.getLogger(__name__)


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file beside it (with this process's id, so that two processes
    writing one file, such as two ``tune`` runs sharing a study, do not share it): a reader sees the old or the new
    file, never half of one."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(text, encoding="utf-8")      # not the locale's: a cp1252 best.yaml was refused by run
        os.replace(tmp, path)
    except OSError as exc:                  # a folder in the way, a path under /proc: one line, no temporary left
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None


@contextlib.contextmanager
def default_dir(base: Path):
    """A new, empty output directory for a command run without ``--out``: ``base`` or, when that is taken (another
    command started in the same second: the second was refused as writing the first one's folder), ``base-2``,
    ``base-3``... The directory is created here, atomically, so that two commands cannot pick one name; it is
    removed again (with any parent this made) if the block fails or is interrupted while it is still empty."""
    base = Path(base)
    made = [p for p in [base.parent, *base.parent.parents] if not p.exists()]
    try:
        base.parent.mkdir(parents=True, exist_ok=True)
        k = 1
        while True:
            d = base if k == 1 else base.with_name(f"{base.name}-{k}")
            try:
                d.mkdir(parents=True)          # parents: another command's clean-up may have removed results/ meanwhile
                if _sibling(d, "lock").exists():       # an explicit --out of that name is being written
                    d.rmdir()
                    raise FileExistsError
                break
            except FileExistsError:
                k += 1
    except OSError as exc:
        raise OutputError(f"{base}: cannot create output directory ({_why(base, exc)})") from None

    def discard() -> None:
        for p in [d, *made]:             # only empty folders: a finished command's output is never removed
            try:
                p.rmdir()
            except OSError:
                break
    token = interrupts.on_abort(discard)
    try:
        yield d
    except BaseException:
        discard()
        raise
    finally:
        interrupts.forget(token)


def write_atomic(target: Path, data: bytes) -> Path:
    """``target`` written whole or not at all (a temporary beside it, then a rename): a reader never sees half a
    file, and a worker writing into a staging folder (a run's result zips) does it the same way."""
    with atomic_file(target) as fh:
        fh.write(data)
    return Path(target)


@contextlib.contextmanager
def atomic_file(target: Path):
    """A binary file that becomes ``target`` when the block ends without an error (as :func:`write_atomic`), for
    writers that stream: a long drive's TUM text or result zip is never held whole in memory."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.tmp")
    try:
        with open(tmp, "wb") as fh:
            yield fh
        os.replace(tmp, target)
    except OSError as exc:             # a full device: the file it was writing, not a bare "No space left on device"
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{target}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


OUTPUT_MARKERS = ("metrics.json", "report.html", "compare.json", "dataset.yaml")   # what a command's folder holds
# the first line of the manifest `simulate` writes: a dataset.yaml without it is a user's own dataset, which --overwrite
# once deleted whole (its OXTS packets, lidar poses and calibration) because any dataset.yaml counted as ours
SIMULATED_MANIFEST_HEADER = "# fusion-eval dataset manifest of a simulated drive"


def resumable_dir(out: Path, markers: tuple[str, ...], what: str, inputs=()) -> None:
    """A sweep's or a tune's folder, which a second command resumes: refuse a path that is a file, that overlaps an
    input (:func:`refuse_overlap`), or a non-empty folder that is not one of its kind (none of ``markers`` in it: a
    sweep or a tune once mixed its files into a run's output and replaced its report.html)."""
    out = Path(out)
    refuse_overlap(out, inputs)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: output path exists and is not a directory")
    if _foreign(out, markers):
        raise OutputError(f"{out}: the folder is not empty and is not a {what}'s (no {' or '.join(markers)} in it): give "
                          f"a new --out, or the folder of the {what} to resume")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create output directory ({_why(out, exc)})") from None


def _why(path: Path, exc: OSError) -> str:
    """The OS's reason, or which part of the path is a file where a folder is due ('File exists' said nothing)."""
    for parent in Path(path).parents:
        if parent.exists():
            return exc.strerror or str(exc) if parent.is_dir() else f"{parent} is a file, not a folder"
    return exc.strerror or str(exc)


def _foreign(folder: Path, markers: tuple[str, ...]) -> bool:
    """A non-empty folder holding none of ``markers``: not one this kind of command wrote (a ``dataset.yaml`` counts
    only as `simulate` writes it, under :data:`SIMULATED_MANIFEST_HEADER`)."""
    return folder.is_dir() and any(folder.iterdir()) and not any(_ours(folder / m) for m in markers)


def _ours(path: Path) -> bool:
    if path.name != "dataset.yaml":
        return path.exists()
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return path.is_file() and f.readline().rstrip("\r\n") == SIMULATED_MANIFEST_HEADER
    except OSError:
        return False


def repeated_path(paths) -> tuple | None:
    """The first of ``paths`` that names a file an earlier one named (a relative and an absolute spelling, a variant
    by name and by path), as ``(earlier, later)``; None when every path is another file."""
    seen: dict = {}
    for p in paths:
        key = Path(p).resolve()
        if key in seen:
            return seen[key], p
        seen[key] = p
    return None


def dataset_roots(*paths) -> tuple[Path, ...]:
    """Datasets given as a folder or a manifest file, as inputs an output must not replace (None, the embedded
    default, is left out)."""
    return tuple(Path(p) for p in paths if p is not None)


def refuse_link_loop(path) -> None:
    """A path that is or lies under a loop of symbolic links, as one line: pathlib's ``resolve`` raised it as a
    RuntimeError traceback up to Python 3.12, and from 3.13 passes it on as a path that later reads fail on."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputError(f"{path}: a loop of symbolic links (the link leads, through others, back to "
                              "itself)") from None


def refuse_overlap(out: Path, inputs=()) -> None:
    """An output folder that is or holds an input, or the current directory: replacing it (``--overwrite``)
    deleted the inputs (a run with ``--out`` its own dataset folder exited 0 with the dataset gone). A folder inside
    a dataset's is allowed (``results/`` beside a manifest, or in a dataset folder one works in)."""
    for p in (out, *inputs):
        refuse_link_loop(p)
    final = Path(out).resolve()
    for p in inputs:
        q = Path(p).resolve()
        if final == q or final in q.parents:
            raise OutputError(f"{out}: the output directory {'is' if final == q else 'holds'} the input {p}, which "
                              "replacing it would delete: give another --out")
    cwd = Path.cwd().resolve()
    if final == cwd or final in cwd.parents:
        raise OutputError(f"{out}: the output directory {'is' if final == cwd else 'holds'} the current directory: "
                          "give a new folder")


def _sibling(final: Path, tag: str) -> Path:
    """The hidden working file or folder ``.<name>.<tag>`` beside ``final``; for a name too long to take the
    prefix and the tag (a legal 245-character --out failed as "File name too long" and left its lock file behind), a
    digest of the name stands in."""
    base = final.name
    if len(base.encode("utf-8", "surrogateescape")) > 180:       # by the name alone: every tag of one --out alike
        base = f"fe-{hashlib.sha1(base.encode('utf-8', 'surrogateescape')).hexdigest()[:16]}"
    return final.parent / f".{base}.{tag}"


class StagedDir:
    def __init__(self, final: Path, overwrite: bool = False, wait_lock_s: float = 0.0, inputs=()):
        self.final = Path(final)
        if self.final.is_symlink() and self.final.is_dir():
            # a link to a folder: the results go into the folder it names (the link itself was replaced by a folder
            # beside it, on the link's filesystem, and the target left empty: a failure-injection review)
            self.final = self.final.resolve()
        self.overwrite = overwrite
        self.inputs = tuple(Path(p) for p in inputs if p is not None)   # what must survive the replacement
        # a sweep's run may be retried on another worker while the first (lost to the scheduler, not yet dead)
        # still writes it: the retry waits for that writer instead of failing
        self.wait_lock_s = wait_lock_s
        self.staging: Path | None = None
        self._made: list[Path] = []
        # an existing folder that is a mount point (a container's volume, a bind mount) cannot be renamed or replaced:
        # the results are staged inside it and moved into it at the end (a finished run was lost to 'Device or
        # resource busy' after all its work, its staging folder left beside; an interruption review)
        self._into = self.final.is_dir() and os.path.ismount(self.final)
        self._home = self.final if self._into else self.final.parent     # where the hidden lock and staging go

    def _near(self, tag: str) -> Path:
        """The hidden lock, staging or old copy of this target: beside it, or inside a mount point."""
        return self._home / _sibling(self.final, tag).name

    def _ours(self, p: Path) -> bool:
        # this tool's hidden lock and staging folder inside a mount point, and a fresh ext4 volume's lost+found
        return self._into and (p.name.startswith(_sibling(self.final, "").name) or p.name == "lost+found")

    def _entries(self) -> list[Path]:
        """What the target folder holds, but for this tool's own hidden files inside a mount point."""
        return [p for p in self.final.iterdir() if not self._ours(p)]

    def check(self) -> None:
        """Fail early (before any work) if the target cannot be used."""
        refuse_overlap(self.final, self.inputs)
        if self.final.exists() and not self.final.is_dir():
            raise OutputError(f"{self.final}: output path exists and is not a directory")
        if self.final.is_dir() and self._entries() and not self.overwrite:
            raise OutputError(f"{self.final}: output directory exists and is not empty (use --overwrite, or overwrite=True in Python, to replace it)")
        # (an empty mount point holds our lock once we hold it: not a foreign folder; a diff review)
        if self.overwrite and self.final.is_dir() and self._entries() and _foreign(self.final, OUTPUT_MARKERS):
            # --out DATASET/oxts --overwrite once deleted the IMU packets
            raise OutputError(f"{self.final}: --overwrite replaces only a folder fusion-eval wrote (holding "
                              f"{', '.join(OUTPUT_MARKERS[:-1])}, or a simulated drive's dataset.yaml), and this one "
                              "holds none of them (a dataset of your own is never replaced)")

    def __enter__(self) -> "StagedDir":
        self.check()
        try:
            # remember which parent folders this run creates, to remove them again if it fails
            self._made = [p for p in [self.final.parent, *self.final.parent.parents] if not p.exists()]
            self.final.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"{self.final}: cannot create output directory ({_why(self.final, exc)})") from None
        self._lock()
        try:
            self._recover()
            self.check()          # another process may have finished this directory while we worked
            self.staging = self._near(f"partial-{os.getpid()}")
            self.staging.mkdir()
            self._abort_token = interrupts.on_abort(self._abandon)
        except BaseException as exc:          # the lock let go on every way out (a notebook locked itself out)
            self._abandon()
            if isinstance(exc, OSError):
                raise OutputError(f"{self.final}: cannot create output directory ({_why(self.final, exc)})") from None
            raise
        return self

    def _beside(self) -> Path:
        """The staging folder moved to ``<name>-k``, a folder made new (so no other run's) and locked for the move."""
        for k in range(2, 1000):
            beside = self.final.parent / f"{self.final.name}-{k}"
            try:
                beside.mkdir()
                with locks.held(_sibling(beside, "lock"), str):
                    os.replace(self.staging, beside)
                return beside
            except (FileExistsError, OutputError):
                continue
            except OSError as exc:
                raise OutputError(f"{beside}: cannot move this run's results there ({exc.strerror or exc}); they are "
                                  f"in {self.staging}") from None
        raise OutputError(f"{self.final}: no free <name>-k beside it; this run's results are in {self.staging}")

    def _recover(self) -> None:
        """With the lock held no other process writes this target: every staging folder of it is a killed run's
        (SIGKILL, the OOM killer, a CI timeout left 3.4 MB of half-written results beside --out for good: a
        corrupted-input review), and every old copy a finished swap's, removed; except the old copy of a run killed
        between the swap's two renames (its staging folder beside it, the target missing), which is put back."""
        def siblings(tag):                    # ours exactly: '.out.old-123', not '.out.old-2024.lock' of 'out.old-2024'
            pattern = re.compile(re.escape(_sibling(self.final, tag).name) + r"(\d+)")
            return {int(m.group(1)): self._home / m.group(0) for p in self._home.iterdir()
                    if (m := pattern.fullmatch(p.name))}
        partials, olds = siblings("partial-"), siblings("old-")
        if not self.final.exists():
            cut = [pid for pid in olds if pid in partials]
            if cut:
                os.replace(olds.pop(max(cut)), self.final)
                log.warning("%s: put back from the copy a run killed as it replaced it had moved aside", self.final)
        for p in (*partials.values(), *olds.values()):
            shutil.rmtree(p, ignore_errors=True)

    def path(self, name: str) -> Path:
        """A path inside the staging folder (for writers that take a file name)."""
        return self.staging / name

    def write_text(self, name: str, text: str) -> Path:
        return self.write_bytes(name, text.encode("utf-8", "surrogateescape"))   # a non-UTF-8 path in a report

    def write_bytes(self, name: str, data: bytes) -> Path:
        return write_atomic(self.staging / name, data)

    def link(self, name: str, src: Path) -> bool:
        """``name`` as a hard link to ``src`` (a file an earlier run of the same batch wrote, byte for byte what this
        one would write: a sweep's shared estimates), or a copy of it where the file system takes no links. False
        where neither can be made (the source gone: its run's folder replaced meanwhile): the caller writes its own."""
        dst = self.staging / name
        dst.unlink(missing_ok=True)
        try:
            os.link(src, dst)
        except OSError:
            try:
                with open(src, "rb") as f, atomic_file(dst) as fh:
                    shutil.copyfileobj(f, fh)
            except (OSError, OutputError):
                dst.unlink(missing_ok=True)
                return False
        return True

    def _lock(self) -> None:
        """Take ``.<name>.lock`` beside the target (:mod:`fusion_eval.locks`): a second process writing the same
        directory at the same time is refused instead of silently replacing the first one's results."""
        self._held = locks.take(self._near("lock"), self.wait_lock_s,
                                lambda pid: f"{self.final}: another fusion-eval (pid {pid}) is writing this output "
                                            "directory; wait for it, or choose another --out", target=self.final)

    def _unlock(self) -> None:
        held, self._held = getattr(self, "_held", None), None      # once, whichever thread gets here first
        locks.release(held)

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is not None:
                self._abandon()
                if isinstance(exc, OutputError) and self.staging is not None and str(self.staging) in str(exc):
                    # a write that failed (a full device) named the hidden staging folder, not the --out given (a
                    # corrupted-input review): the file as it would have been
                    raise OutputError(str(exc).replace(str(self.staging), str(self.final))) from None
                return False
            # the two renames as one step: a signal between them left the old results and the new ones both hidden
            # (.out.old-PID, .out.partial-PID) and nothing at --out (a failure-injection review); it is raised after
            if self._into:
                with interrupts.deferred():
                    self._move_into()
                return False
            with interrupts.deferred():
                if not self.overwrite and self.final.is_dir() and any(self.final.iterdir()):
                    # written by a command that takes no lock of this folder (a sweep started in it) while this
                    # one worked: its files are not replaced (a diff review), this run's results go beside them
                    beside = self._beside()
                    raise OutputError(f"{self.final}: another command wrote there while this run worked; its files "
                                      f"are left as they are and this run's results are in {beside}")
                old = None
                try:
                    if self.final.exists():
                        old = _sibling(self.final, f"old-{os.getpid()}")
                        os.replace(self.final, old)
                    os.replace(self.staging, self.final)
                except OSError as exc:
                    # the finished results are not lost to a rename the filesystem refuses: the old folder back,
                    # and this run's in a visible folder beside it (a hidden one is a killed run's to the next)
                    if old is not None and not self.final.exists():
                        os.replace(old, self.final)
                    beside = self._beside()
                    raise OutputError(f"{self.final}: cannot put this run's results there ({_why(self.final, exc)}); "
                                      f"they are in {beside}") from None
                interrupts.wrote(self.final)
            if old is not None:                # (a copy left by a signal here is removed by the next run's _recover)
                shutil.rmtree(old, ignore_errors=True)
            return False
        finally:
            interrupts.forget(getattr(self, "_abort_token", None))
            self._unlock()

    def _move_into(self) -> None:
        """The staged results moved into the mount point (each entry renamed: one filesystem), replacing what it
        held with --overwrite; a folder written meanwhile by another command keeps its files, and this run's stay
        in a visible folder inside it."""
        held = self._entries()
        if held and not self.overwrite:
            keep = self.final / f"{self.final.name}-{os.getpid()}"
            os.replace(self.staging, keep)
            raise OutputError(f"{self.final}: another command wrote there while this run worked; its files are left "
                              f"as they are and this run's results are in {keep}")
        for p in held:
            shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
        for p in sorted(self.staging.iterdir()):
            os.replace(p, self.final / p.name)
        self.staging.rmdir()
        interrupts.wrote(self.final)

    def _abandon(self) -> None:
        """What a failed run's exit does (also for a signal that ends the command from another thread,
        :func:`fusion_eval.interrupts.on_abort`): the staging folder removed, the lock let go, the parent folders
        this run made removed again (deepest first)."""
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            if self.overwrite and self.final.is_dir():
                interrupts.kept(self.final)        # the run it was to replace, untouched
        self._unlock()
        for p in self._made:
            try:
                p.rmdir()
            except OSError:
                break
