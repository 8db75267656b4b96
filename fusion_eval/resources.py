"""What the package ships: the default dataset and the configurations, found from any working directory.

The source checkout and an installed package hold the same tree: ``configs/`` (default, variants, sweeps,
baselines, profiles) and ``data/kitti-00``. In a checkout (and an editable install) it is the checkout
itself; a wheel carries it as package data under ``fusion_eval/_shipped`` (mapped there by
``pyproject.toml``), found with :mod:`importlib.resources`. A relative path a user gives is taken from the
working directory first; only when nothing is there is the shipped tree tried, so a user's own
``configs/`` or ``data/`` always wins.
"""

from __future__ import annotations

import functools
import logging
from importlib import resources
from pathlib import Path, PurePath

log = logging.getLogger(__name__)

DEFAULT_DATASET = "data/kitti-00"
VARIANTS = "configs/variants"
SWEEPS = "configs/sweeps"


def _is_root(p: Path) -> bool:
    return (p / "configs").is_dir() and (p / "data").is_dir()


@functools.lru_cache(maxsize=1)
def shipped_root() -> Path | None:
    """The folder holding the shipped ``configs/`` and ``data/``: the installed package data, else the checkout."""
    try:
        installed = Path(str(resources.files("fusion_eval").joinpath("_shipped")))
    except (ModuleNotFoundError, TypeError):   # pragma: no cover - not importable as a package
        installed = None
    checkout = Path(__file__).resolve().parent.parent
    for root in (installed, checkout):
        if root is not None and _is_root(root):
            return root
    return None


def project_root_of(path: Path) -> Path | None:
    """The nearest folder above ``path`` that holds ``configs/`` and ``data/`` (a checkout or the shipped tree)."""
    for p in Path(path).resolve().parents:
        if _is_root(p):
            return p
    return None


def dataset_label(path: str | Path) -> str:
    """A dataset's name in tables, keys and default output folders, from its path alone (a sweep.csv may come
    from another machine): a folder's name; a manifest file's stem, or its folder's name for a ``dataset.yaml``."""
    p = PurePath(str(path))
    if p.suffix in (".yaml", ".yml"):
        return p.parent.name if p.stem == "dataset" and p.parent.name else p.stem
    return p.name


def find(rel: str | Path, *bases: Path | None) -> Path:
    """``rel`` as given if it exists (absolute, or relative to the working directory); else inside each of
    ``bases``; else in the shipped tree. Returns the path as given when found nowhere (the caller's reader
    then names it in its error)."""
    p = Path(rel)
    if p.exists() or p.is_absolute():
        return p
    for b in (*bases, shipped_root()):
        if b is not None and (Path(b) / p).exists():
            q = Path(b) / p
            log.debug("%s: not in the working directory, using %s", rel, q)
            return q
    return p


def default_dataset() -> Path:
    return find(DEFAULT_DATASET)


def variant_dir() -> Path:
    return find(VARIANTS)


def sweep_file(name: str) -> Path:
    """A sweep file: a path, else a shipped sweep by name (``noise5`` -> ``configs/sweeps/noise5.yaml``)."""
    from .errors import ConfigError

    p = find(name)
    if p.exists():
        return p
    q = find(Path(SWEEPS) / (name if name.endswith((".yaml", ".yml")) else f"{name}.yaml"))
    if not q.exists():
        shipped = sorted(f.stem for f in find(SWEEPS).glob("*.yaml")) if find(SWEEPS).is_dir() else []
        raise ConfigError(f"{name}: sweep file not found (neither a file nor a shipped sweep: {', '.join(shipped) or 'none'})")
    return q
