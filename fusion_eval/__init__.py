"""fusion-eval: offline Kalman-filter fusion of IMU, GNSS and lidar odometry, evaluated with evo.

The Python API (see :mod:`fusion_eval.api`)::

    import fusion_eval as fe
    ds = fe.load_dataset("data/kitti-00")
    res = fe.run(ds, overrides={"gnss.rate_hz": 2.0})
    res.metrics["estimates"]["fused"]["ape"]["translation_m"]["rmse"]
    res.write("out/")
    fe.evaluate("groundtruth.tum", "estimate.tum", alignment="se3")
"""

import os as _os

# LLVM at -O2 instead of numba's -O3 (unless the user set NUMBA_OPT): a fresh install's first run compiles the
# kernels in 0.71x the time (kitti-00: 40.8 s against 57.8 s of compilation, same load), and the compiled replay
# runs as fast (12.2-12.5 against 12.5-12.6 us per IMU sample, alternated). Set before numba is imported, which
# every module that compiles does after this package's import.
_os.environ.setdefault("NUMBA_OPT", "2")


def _writable(path: str) -> bool:
    """Whether ``path``, or the nearest folder above it that exists, can be written to."""
    while not _os.path.exists(path):
        parent = _os.path.dirname(path)
        if parent == path:
            return False
        path = parent
    return _os.path.isdir(path) and _os.access(path, _os.W_OK | _os.X_OK)


def _caches_in_temp() -> None:
    """numba's and matplotlib's caches in the temporary folder when neither their usual places nor (for numba) the
    installed package's folder can be written: a read-only install used with an unwritable home stopped every data
    command with numba's 53-line "cannot cache function ... no locator available" traceback, and matplotlib warned
    four times per run and left two temporary folders behind (a failure-injection review). A user's own setting is
    kept."""
    home = _os.path.expanduser("~")
    cache = _os.environ.get("XDG_CACHE_HOME") or _os.path.join(home, ".cache")
    config = _os.environ.get("XDG_CONFIG_HOME") or _os.path.join(home, ".config")
    here = _os.path.dirname(_os.path.abspath(__file__))
    todo = []
    if "NUMBA_CACHE_DIR" not in _os.environ and not (_writable(_os.path.join(here, "__pycache__"))
                                                      or _writable(_os.path.join(cache, "numba"))):
        todo.append(("NUMBA_CACHE_DIR", "numba"))
    if "MPLCONFIGDIR" not in _os.environ and not _writable(_os.path.join(config, "matplotlib")):
        todo.append(("MPLCONFIGDIR", "matplotlib"))
    for var, what in todo:
        # the first of a few fixed names that is a private folder of this user's (one left group-writable by another
        # version is passed over, not replaced by a new random folder on every import: a diff review)
        folder = next((f for f in (_private_temp(f"fusion-eval-{what}" + (f"-{k}" if k else "")) for k in range(4))
                       if f is not None), None)
        if folder is None:                   # none ours to trust: a fresh folder, no cache kept between runs
            import tempfile

            folder = tempfile.mkdtemp(prefix=f"fusion-eval-{what}-")
        _os.environ[var] = folder


def _private_temp(name: str) -> str | None:
    """``<temp>/<name>-<uid>``, made private (0700) if missing; None unless it is a folder of this user's that no one
    else can write, not a link: at a predictable path in the shared temporary folder, another user could have made it
    first and left code there that numba's cache would load (a diff review)."""
    import stat
    import tempfile

    uid = getattr(_os, "getuid", lambda: None)()
    path = _os.path.join(tempfile.gettempdir(), f"{name}-{uid if uid is not None else 'user'}")
    try:
        _os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    except OSError:
        return None
    try:
        st = _os.lstat(path)
    except OSError:
        return None
    mine = uid is None or st.st_uid == uid
    if not stat.S_ISDIR(st.st_mode) or not mine or st.st_mode & 0o022:
        return None
    return path


_caches_in_temp()

__version__ = "0.1.0"

_API = ("load_dataset", "run", "evaluate", "Result")


def __getattr__(name: str):
    # the API loads the filters and evo on first use, so that `fusion-eval --help` and `check` stay light
    if name in _API:
        from . import api

        return getattr(api, name)
    if name in ("Settings",):
        from .config import Settings

        return Settings
    raise AttributeError(name)


__all__ = ["__version__", *_API, "Settings"]
