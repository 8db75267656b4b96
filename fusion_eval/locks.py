"""Locks of output folders: one process writes a folder (a run's ``--out``, a sweep's folder) at a time.

A lock is a file beside the folder holding its writer's host and pid, under an exclusive ``flock``, which the kernel
releases when its holder ends, however it ends: a killed writer's lock is taken over by the next process, and only by
one (with the pid alone read from the file, two processes took over a killed run's lock at once and both wrote: a
failure-injection review). Where ``flock`` is missing or refused (a filesystem without it: NFS without its lock
daemon, Lustre mounted without it), the file is created exclusively instead and a holder is alive while its pid is.
A lock file naming another host (a cluster's shared filesystem) counts as held: its process cannot be probed.
"""

from __future__ import annotations

import errno
import os
import socket
import stat
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from .errors import OutputError

try:
    import fcntl
except ImportError:                         # not POSIX: the exclusive-file protocol alone
    fcntl = None

# the errors of a filesystem that has no flock, or refuses it
_NO_FLOCK = {errno.ENOLCK, errno.ENOSYS, errno.EOPNOTSUPP, getattr(errno, "ENOTSUP", errno.EOPNOTSUPP)}
_RETRY = object()
_HELD: dict[int, Path] = {}                # this process's lock descriptors, which a forked child closes
_NO_FLOCK_DEVICES: set[int] = set()         # filesystems (st_dev) found to refuse flock


def _close_in_child() -> None:
    # a worker forked while its parent holds a lock shares the lock (one open file): on a system that does not end the
    # children with their parent (macOS), orphaned workers kept a killed run's folder locked
    for fd in list(_HELD):
        try:
            os.close(fd)
        except OSError:
            pass
    _HELD.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_close_in_child)


@dataclass
class Lock:
    path: Path
    fd: int | None                          # None: held as an exclusively created file (no flock)


def alive(pid: int) -> bool:
    """Whether process ``pid`` of this host exists (a lock's or a study trial's owner)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def take(path: Path, wait_s: float, busy: Callable[[int], str], target: Path | None = None) -> Lock:
    """Take the lock ``path``; while another process holds it, wait up to ``wait_s`` and then raise
    :class:`OutputError` with ``busy(pid)`` (and, for a holder on another host, where to delete a lock left behind).
    A lock file that cannot be made is an :class:`OutputError` naming ``target``, the folder it guards (else the
    lock file)."""
    path = Path(path)
    t_end = time.monotonic() + wait_s
    retries = 0
    while True:
        try:
            got = _try(path)
        except OSError as exc:              # a missing or read-only folder, a full quota: one line naming the file
            why = exc.strerror or str(exc)
            raise OutputError(f"{target}: cannot create output directory ({why})" if target is not None
                              else f"{path}: cannot create the lock file ({why})") from None
        if isinstance(got, Lock):
            return got
        if got is _RETRY:                   # the file changed under us (released, replaced): again, but not forever
            retries += 1
            if retries > 200:
                raise OutputError(f"{path}: the lock file keeps changing under this process; is another program "
                                  "deleting it?")
            time.sleep(0.005)
            continue
        host, pid = got
        if time.monotonic() < t_end:
            time.sleep(0.2)
            continue
        other = f" (on host {host}: if nothing of it runs there any more, delete {path})" \
            if host not in ("", socket.gethostname()) else ""
        raise OutputError(busy(pid) + other)


def release(lock: Lock | None) -> None:
    """Delete the lock file while still holding it (a process waiting on it then finds it gone and takes a new one),
    unless it is no longer ours, then let it go."""
    if lock is None:
        return
    if lock.fd is None:
        if _holder_of_file(lock.path) == _me():
            lock.path.unlink(missing_ok=True)
        return
    try:
        if _same_file(lock.fd, lock.path):
            lock.path.unlink(missing_ok=True)
    finally:
        _HELD.pop(lock.fd, None)
        os.close(lock.fd)


@contextmanager
def held(path: Path, busy: Callable[[int], str]):
    """:func:`take` (no waiting) for the length of a ``with`` block."""
    lock = take(path, 0.0, busy)
    try:
        yield lock
    finally:
        release(lock)


def _open(path: Path, flags: int) -> int:
    """``os.open`` that does not follow a link at the lock's path (a link there made the lock truncate and write its
    target: a diff review) and takes only a regular file."""
    fd = os.open(path, flags | getattr(os, "O_NOFOLLOW", 0), 0o644)
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise OSError(errno.EINVAL, "not a regular file")
    return fd


def _try(path: Path):
    """A :class:`Lock`, the holder's ``(host, pid)``, or :data:`_RETRY`; an ``OSError`` where the file cannot be made."""
    if fcntl is None or _device(path.parent) in _NO_FLOCK_DEVICES:
        return _try_exclusive(path)
    readonly = created = False
    try:
        try:
            fd = _open(path, os.O_CREAT | os.O_EXCL | os.O_RDWR)
            created = True
        except FileExistsError:
            fd = _open(path, os.O_RDWR)
    except FileNotFoundError:
        if not path.parent.is_dir():          # the folder itself is missing: no lock to wait for
            raise
        return _RETRY                         # deleted between the two opens
    except PermissionError:
        if not path.exists():                 # a folder this user cannot write: said, not retried
            raise
        # another user's lock file in a shared folder: readable, and flock works on a read-only descriptor
        try:
            fd = _open(path, os.O_RDONLY)
        except FileNotFoundError:
            return _RETRY
        readonly = True
    keep = False
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return _holder(fd)
        except OSError as exc:
            if exc.errno not in _NO_FLOCK:
                raise
            # no flock here: the exclusive file, for this attempt; remembered only where the filesystem has none at
            # all (ENOLCK, a lock daemon not answering, may pass: processes would then mix the two protocols)
            if exc.errno != errno.ENOLCK:
                _NO_FLOCK_DEVICES.add(_device(path.parent))
            if created:
                path.unlink(missing_ok=True)
            return _try_exclusive(path)
        if not _same_file(fd, path):          # its holder deleted it after we opened it: a new one is due
            return _RETRY
        host, pid = _holder(fd)
        if pid and host not in ("", socket.gethostname()):
            return host, pid
        if readonly:                          # a stale lock of another user's: replaced by one of ours
            try:
                path.unlink()
            except PermissionError:
                raise OutputError(f"{path}: a stale lock file of another user that cannot be removed (permission "
                                  "denied): delete it") from None
            except FileNotFoundError:
                pass
            return _RETRY
        mine = _text(_me()).encode()
        os.pwrite(fd, mine, 0)                # the new content, then the old tail cut: never read empty ("pid 0")
        os.ftruncate(fd, len(mine))
        keep = True
        _HELD[fd] = path
        return Lock(path, fd)
    finally:
        if not keep:
            os.close(fd)


def _try_exclusive(path: Path):
    """The protocol without flock: the file made whole at once (a link to a written temporary file, which NFS makes
    atomically too); a holder of this host is alive while its pid is; an empty or unreadable file is held until it is
    a minute old (another user's, or one being made)."""
    try:
        host, pid = _holder_of_file(path)
        if pid and (host not in ("", socket.gethostname()) or pid == os.getpid() or alive(pid)):
            return host, pid
        if not pid and time.time() - os.lstat(path).st_mtime < 60.0:
            return "", 0
        # stale: moved aside under a name of our own first, so that of two processes taking it over only one removes it
        aside = path.with_name(f"{path.name}.stale-{os.getpid()}")
        os.rename(path, aside)
        if _holder_of_file(aside) != (host, pid):     # another process's new lock, made since we read: put back
            try:
                os.link(aside, path)
            except FileExistsError:
                pass
            aside.unlink(missing_ok=True)
            return _RETRY
        aside.unlink(missing_ok=True)
    except FileNotFoundError:
        pass
    tmp = path.with_name(f"{path.name}.new-{os.getpid()}")
    fd = os.open(tmp, os.O_CREAT | os.O_TRUNC | os.O_WRONLY | getattr(os, "O_NOFOLLOW", 0), 0o644)
    try:
        os.write(fd, _text(_me()).encode())
    finally:
        os.close(fd)
    try:
        os.link(tmp, path)
    except FileExistsError:
        return _RETRY
    finally:
        tmp.unlink(missing_ok=True)
    return Lock(path, None)


def _me() -> tuple[str, int]:
    """This process as a lock file names it: host and pid."""
    return socket.gethostname(), os.getpid()


def _text(holder: tuple[str, int]) -> str:
    return f"{holder[0]} {holder[1]}"


def _holder(fd: int) -> tuple[str, int]:
    """The host and pid written in a lock file ('' and 0 when unreadable)."""
    try:
        host, _, pid_s = os.pread(fd, 4096, 0).decode("utf-8", "replace").strip().rpartition(" ")
        return host, int(pid_s or 0)
    except (OSError, ValueError):
        return "", 0


def _holder_of_file(path: Path) -> tuple[str, int]:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return "", 0
    try:
        return _holder(fd)
    finally:
        os.close(fd)


def _device(folder: Path) -> int:
    try:
        return os.stat(folder).st_dev
    except OSError:
        return -1


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except FileNotFoundError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)
