"""Compiled functions built from source templates (the replay's event loop, the propagation loop, the RTS pass):
each generated source is written to a file of its own before it is compiled.

numba's cache needs a real source file (it keys its index on the file's stamp and puts the cache beside it), and
numba reads the function's source lines from that file when it saves a cache entry. Compiled under the name of
the module that builds them, the templates' line numbers pointed into an unrelated part of that module: Python
3.10-3.12 returned the wrong lines without a word, and Python 3.13's tokenizer raised on them, so that the first
run on 3.13 failed with a traceback (a portability review). A file of their own gives numba both.

The file's name carries a digest of the template, of the anchoring module's whole source and of every module of the
filters and the smoother: numba's cache sees only the file itself, and the loop inlines functions of those (a
formulation's step, the mechanization, the discretisation), whose change must give a fresh compile. Copies made
from other sources stay (another installation on this account may use them; they are not pruned by age, since a
copy's stamp cannot be refreshed on use without invalidating numba's cache of it): delete the folder to reclaim them.
Where no folder is writable, the template is compiled under the anchoring module's name as before.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

from . import _private_temp


def build(module_name: str, name: str, src: str, ns: dict) -> dict:
    """Execute the generated ``src`` (defining ``name``) into ``ns``, compiled from a file of its own (see the
    module docstring); returns ``ns``."""
    mod = sys.modules[module_name]
    path = _written(module_name, name, src, Path(mod.__file__))
    exec(compile(src, str(path) if path is not None else mod.__file__, "exec"), ns)  # noqa: S102 - our own template
    return ns


def _written(module_name: str, name: str, src: str, anchor: Path) -> Path | None:
    h = hashlib.sha1(src.encode())
    h.update(_compiled_sources())
    try:
        h.update(anchor.read_bytes())
    except OSError:
        pass
    stem = f"{module_name.replace('.', '_')}__{name}__"
    file_name = f"{stem}{h.hexdigest()[:12]}.py"   # not a state index
    for folder in _folders():
        path = folder / file_name
        try:
            if path.is_file() and path.read_text(encoding="utf-8") == src:
                return path               # as written before: its stamp unchanged, numba's cache of it still valid
            folder.mkdir(parents=True, exist_ok=True)
            tmp = folder / f".{file_name}.{os.getpid()}.tmp"
            tmp.write_text(src, encoding="utf-8")
            os.replace(tmp, path)         # whole, for another process compiling the same template at once
            return path
        except OSError:
            continue
    return None


_SOURCES: list[bytes] = []


def _compiled_sources() -> bytes:
    """A digest of every module of the filters and the smoother, once per process: the loops inline functions of
    many of them (the step's mechanization, discretisation, the kernels' helpers), and a callee changed in one that the
    name did not cover was served from numba's cache as it was (a diff review)."""
    if not _SOURCES:
        h = hashlib.sha1()
        root = Path(__file__).parent
        for sub in ("filters", "smoothing"):
            for f in sorted((root / sub).rglob("*.py")):
                h.update(f.relative_to(root).as_posix().encode() + b"\0")
                try:
                    h.update(f.read_bytes())
                except OSError:
                    pass
        _SOURCES.append(h.digest())
    return _SOURCES[0]


def _folders():
    """Where generated sources go, in order of preference: numba's own cache folder when one is set
    (NUMBA_CACHE_DIR), the user's cache folder, then a private folder in the temporary one (made only if reached)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        yield Path(os.environ["NUMBA_CACHE_DIR"]) / "fusion-eval-generated"
    try:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    except RuntimeError:              # no home folder to be found
        base = None
    if base:
        yield Path(base) / "fusion-eval" / "generated"
    private = _private_temp("fusion-eval-generated")      # a shared folder: only a private one of this user's
    if private is not None:
        yield Path(private)
