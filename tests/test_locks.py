"""Locks of output folders (fusion_eval.locks) and the staging folder around them: a lock is let go on every way
out, works where flock does not, and says where a lock of another host lies (a diff review of the flock lock)."""

from __future__ import annotations

import errno
import os
import socket

import pytest

from fusion_eval import locks
from fusion_eval.errors import OutputError
from fusion_eval.outputs import StagedDir


def _open_fds_to(path) -> list[int]:
    out = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            if os.readlink(f"/proc/self/fd/{fd}") == str(path):
                out.append(int(fd))
        except OSError:
            pass
    return out


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="lists open files through /proc")
def test_a_staging_folder_that_cannot_be_made_lets_the_lock_go(tmp_path):
    """The lock was held until the process ended when the staging folder could not be made (a notebook then locked
    itself out: "another fusion-eval (pid <its own>)")."""
    out = tmp_path / "out"

    real = type(out).mkdir

    def no_mkdir(self, *a, **k):                     # the staging folder, made once the lock is held
        if ".partial-" in self.name:
            raise PermissionError(errno.EACCES, "Permission denied")
        return real(self, *a, **k)
    type(out).mkdir = no_mkdir
    try:
        with pytest.raises(OutputError, match="cannot create output directory"):
            with StagedDir(out):
                pass
    finally:
        type(out).mkdir = real
    assert not _open_fds_to(tmp_path / ".out.lock") and not (tmp_path / ".out.lock").exists()
    with StagedDir(out) as st:                       # and the same process takes it again
        st.write_text("x.txt", "1")
    assert (out / "x.txt").exists()


def test_a_filesystem_without_flock_takes_the_exclusive_file(tmp_path, monkeypatch):
    """NFS without its lock daemon refuses flock (ENOLCK): every run failed as "cannot create output directory (No
    locks available)" where the lock of before worked."""
    def no_flock(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")
    monkeypatch.setattr(locks.fcntl, "flock", no_flock)
    monkeypatch.setattr(locks, "_NO_FLOCK_DEVICES", set())
    path = tmp_path / ".out.lock"
    lock = locks.take(path, 0.0, str)
    assert lock.fd is None and path.read_text() == f"{socket.gethostname()} {os.getpid()}"
    path.write_text(f"{socket.gethostname()} {os.getppid()}")                # a live holder
    with pytest.raises(OutputError, match=f"busy {os.getppid()}"):
        locks.take(path, 0.0, lambda pid: f"busy {pid}")
    path.write_text(f"{socket.gethostname()} 999999999")                      # a killed one
    lock = locks.take(path, 0.0, str)
    locks.release(lock)
    assert not path.exists()


def test_a_lock_of_another_host_is_held_and_says_where_it_lies(tmp_path):
    path = tmp_path / ".out.lock"
    path.write_text("node-17 4242")
    with pytest.raises(OutputError, match=rf"busy 4242 \(on host node-17: if nothing of it runs there any more, "
                                          rf"delete {path}\)"):
        locks.take(path, 0.0, lambda pid: f"busy {pid}")


def test_release_leaves_a_lock_that_is_no_longer_ours(tmp_path):
    path = tmp_path / ".out.lock"
    lock = locks.take(path, 0.0, str)
    path.unlink()
    path.write_text("another 1")                     # replaced under us
    locks.release(lock)
    assert path.read_text() == "another 1"


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork")
def test_a_forked_child_does_not_keep_the_parents_lock(tmp_path):
    """Workers forked while a lock is held shared it: orphans (macOS does not end them with their parent) kept a killed
    run's folder locked. The child closes its copies."""
    path = tmp_path / ".out.lock"
    lock = locks.take(path, 0.0, str)
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:                                     # the child: is the lock's descriptor still open here?
        try:
            os.fstat(lock.fd)
            os.write(w, b"open")
        except OSError:
            os.write(w, b"closed")
        os._exit(0)
    os.close(w)
    got = os.read(r, 16)
    os.waitpid(pid, 0)
    os.close(r)
    locks.release(lock)
    assert got == b"closed"
