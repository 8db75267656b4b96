"""Compiled functions built from source templates (the replay's event loop, the propagation loop, the RTS pass):
each generated source is written to a file of its own before it is compiled.

numba's cache needs a real source file (it keys its index on the file's stamp and puts the cache beside it), and
numba reads the function's source lines from that file when it saves a cache entry. Compiled under the name of
the module that builds them, the templates' line numbers pointed into an unrelated part of that module: Python
3.10-3.12 returned the wrong lines without a word, and Python 3.13's tokenizer raised on them, so that the first
run on 3.13 failed with a traceback (a portability review). A file of their own gives numba both.

The file's name carries a digest of the template and of the anchoring module's whole source: numba's cache sees
only the file itself, and the loop inlines functions of that module (a formulation's step), whose change must give
a fresh compile. Where no folder is writable, the template is compiled under the anchoring module's name as before.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from pathlib import Path


def build(module_name: str, name: str, src: str, ns: dict) -> dict:
    """Execute the generated ``src`` (defining ``name``) into ``ns``, compiled from a file of its own (see the
    module docstring); returns ``ns``."""
    mod = sys.modules[module_name]
    path = _written(module_name, name, src, Path(mod.__file__))
    exec(compile(src, str(path) if path is not None else mod.__file__, "exec"), ns)  # noqa: S102 - our own template
    return ns


def _written(module_name: str, name: str, src: str, anchor: Path) -> Path | None:
    h = hashlib.sha1(src.encode())
    try:
        h.update(anchor.read_bytes())
    except OSError:
        pass
    file_name = f"{module_name.replace('.', '_')}__{name}__{h.hexdigest()[:12]}.py"   # not a state index
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


def _folders() -> list[Path]:
    """Where generated sources go: numba's own cache folder when one is set (NUMBA_CACHE_DIR), the user's cache
    folder, then the temporary folder."""
    out = []
    if os.environ.get("NUMBA_CACHE_DIR"):
        out.append(Path(os.environ["NUMBA_CACHE_DIR"]) / "fusion-eval-generated")
    try:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    except RuntimeError:              # no home folder to be found
        base = None
    if base:
        out.append(Path(base) / "fusion-eval" / "generated")
    out.append(Path(tempfile.gettempdir()) / f"fusion-eval-generated-{_user()}")
    return out


def _user() -> str:
    try:
        return str(os.getuid())
    except AttributeError:            # Windows
        return os.environ.get("USERNAME", "user")
