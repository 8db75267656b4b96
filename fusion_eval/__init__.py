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
