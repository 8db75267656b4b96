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


def test_a_lock_that_cannot_be_made_is_one_error_not_a_spin(tmp_path):
    """A folder this user cannot write, or one removed under the run, spun at full CPU for good (a review): one
    error naming the lock file."""
    with pytest.raises(OutputError, match=r"\.out\.lock: cannot create the lock file"):
        locks.take(tmp_path / "gone" / ".out.lock", 0.0, str)
    if os.geteuid() != 0:                            # (root writes anywhere)
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o555)
        with pytest.raises(OutputError, match="cannot create the lock file"):
            locks.take(ro / ".out.lock", 0.0, str)


def test_a_link_at_the_locks_path_is_not_followed(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / ".out.lock").symlink_to(victim)
    with pytest.raises(OutputError, match="cannot create the lock file"):
        locks.take(tmp_path / ".out.lock", 0.0, str)
    assert victim.read_text() == "precious"


def test_the_exclusive_file_is_made_whole_and_a_fresh_empty_one_is_held(tmp_path, monkeypatch):
    monkeypatch.setattr(locks, "fcntl", None)
    path = tmp_path / ".out.lock"
    path.write_text("")                              # being made by another process (or unreadable): held a minute
    with pytest.raises(OutputError, match="busy 0"):
        locks.take(path, 0.0, lambda pid: f"busy {pid}")
    old = os.path.getmtime(path) - 120
    os.utime(path, (old, old))                       # a minute on: stale
    lock = locks.take(path, 0.0, str)
    assert path.read_text() == f"{socket.gethostname()} {os.getpid()}"
    with pytest.raises(OutputError, match="busy"):  # our own pid: held (two threads of one process)
        locks.take(path, 0.0, lambda pid: f"busy {pid}")
    locks.release(lock)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_recovery_touches_only_this_targets_working_folders(tmp_path):
    """'.out.old-' also matched the working files of a target named 'out.old-2024' (a run deleted another run's
    staging folder); and an old copy is put back only for a run killed between the two renames."""
    (tmp_path / ".out.old-2024.partial-77").mkdir()                 # another target's (out.old-2024) staging folder
    (tmp_path / ".out.old-55").mkdir()                              # a finished swap's leftover, out missing,
    with StagedDir(tmp_path / "out") as st:                         # no staging of pid 55: not put back
        st.write_text("metrics.json", "1")
    assert (tmp_path / ".out.old-2024.partial-77").is_dir() and not (tmp_path / ".out.old-55").exists()
    (tmp_path / "out").rename(tmp_path / ".out.old-66")             # killed between the renames:
    (tmp_path / ".out.partial-66").mkdir()                          # its staging beside it
    with StagedDir(tmp_path / "out", overwrite=True):
        assert (tmp_path / "out" / "metrics.json").read_text() == "1"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".out.old-2024.partial-77", "out"]
