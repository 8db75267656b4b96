"""Variant lookup: a variant is a configuration overlay, a YAML path or a name in a variant folder
(``configs/variants`` of the working directory, else the shipped one)."""

from __future__ import annotations

import re
from pathlib import Path

from . import resources
from .errors import ConfigError


def resolve_variant(name: str, variant_dir: Path | None = None) -> Path:
    """The file of a variant: ``name`` itself if it is an existing YAML file, else ``<variant_dir>/<name>.yaml``."""
    p = Path(name)
    if p.suffix in (".yaml", ".yml") and p.exists():
        return p
    vdir = Path(variant_dir) if variant_dir is not None else resources.variant_dir()
    cand = vdir / f"{name}.yaml"
    if cand.exists():
        return cand
    known = sorted(f.stem for f in vdir.glob("*.yaml")) if vdir.is_dir() else []
    raise ConfigError(f"unknown variant {name!r} (no {cand}; known: {', '.join(known) or 'none'})")


def folder_name(name: str, taken: set) -> str:
    """A safe, unique folder name for a variant (a path given as a variant must not leave the output)."""
    base = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(name).stem) or "variant"
    out, i = base, 1
    while out in taken:
        i += 1
        out = f"{base}-{i}"
    taken.add(out)
    return out
