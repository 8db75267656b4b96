"""Where a report's numbers come from: the version, the date, the command line and the input files with checksums.

The date honours ``SOURCE_DATE_EPOCH`` (the reproducible-builds convention): with it set, two runs on the same
inputs write the same bytes, reports included. Input files are those the dataset manifest names (stream paths and
the calibration files they refer to); a folder (KITTI's ``oxts/``) gets one digest over its files' names and
contents, so that a changed packet changes it.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import shlex
import sys
from functools import lru_cache
from pathlib import Path

from . import __version__


def date_utc() -> str:
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    t = _dt.datetime.fromtimestamp(int(epoch), _dt.timezone.utc) if epoch and epoch.isdigit() else \
        _dt.datetime.now(_dt.timezone.utc)
    return t.strftime("%Y-%m-%d %H:%M UTC")


def command_line() -> str:
    """The command as typed (``fusion-eval`` for the entry point's path), or the Python process's arguments."""
    argv = list(sys.argv) or ["python"]
    if Path(argv[0]).name in ("fusion-eval", "__main__.py"):
        argv[0] = "fusion-eval"
    return shlex.join(argv)


@lru_cache(maxsize=4)
def code_id(root: Path | None = None) -> str:
    """12 hex digits of a digest over the package's Python sources (by relative name and content): the code that
    produced a result. The version alone named 563 commits, and a result could not be told from one made by other code
    (a change of an estimate moved kitti-00's figure with the same version: a reproducibility review); a digest works
    for any install, with or without git, and is the same for an editable install and a wheel of one commit (the
    wheel's shipped configurations and data, ``_shipped/``, are not code: a run records its configuration). ~10 ms,
    once. ``root``: the package's folder (this one's by default)."""
    root = Path(__file__).resolve().parent if root is None else Path(root)
    code = [f for f in sorted(root.rglob("*.py")) if f.is_file()
            and f.relative_to(root).parts[0] != "_shipped" and "__pycache__" not in f.relative_to(root).parts]
    return _hash_files(hashlib.sha256(), root, code)[0].hexdigest()[:12]


def _hash_files(h, root: Path, files_: list[Path]):
    """``h`` updated with each file's name relative to ``root`` (``/``-separated, then NUL) and its content, in
    the order given; (``h``, bytes read)."""
    total = 0
    for f in files_:
        h.update(f.relative_to(root).as_posix().encode() + b"\0")   # one checksum on every OS
        with open(f, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
                total += len(chunk)
    return h, total


def header() -> dict:
    return {"version": __version__, "code": code_id(), "date": date_utc(), "command": command_line()}


def block(inputs: list[dict], config_text: str | None = None) -> dict:
    """``metrics.json``'s ``provenance``: :func:`header`, the sha256 of the resolved configuration's text where there
    is one, and the input files (:func:`files` rows)."""
    made = header()
    if config_text is not None:
        made["config_sha256"] = hashlib.sha256(config_text.encode("utf-8", "surrogateescape")).hexdigest()
    return {**made, "inputs": inputs}


def header_line() -> str:
    """The one line a Markdown report starts with, under its title."""
    h = header()
    return f"fusion-eval {h['version']} (code {h['code']}), {h['date']}: `{h['command']}`"


@lru_cache(maxsize=256)
def _digest(path: str, mtime_ns: int, size: int) -> tuple[str, int, int]:
    """sha256 of a file, or of a folder's files (relative names and contents, in name order); (hex, bytes, files)."""
    p = Path(path)
    if not p.is_dir():
        h, total = hashlib.sha256(), 0
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
                total += len(chunk)
        return h.hexdigest(), total, 1
    found = sorted(f for f in p.rglob("*") if f.is_file())
    h, total = _hash_files(hashlib.sha256(), p, found)
    return h.hexdigest(), total, len(found)


def _paths(entry, base: Path):
    """The file paths a manifest stream entry names: its ``path`` and any nested ``file``."""
    if isinstance(entry, dict):
        for k, v in entry.items():
            if k in ("path", "file") and isinstance(v, str):
                yield base / v
            else:
                yield from _paths(v, base)


def files(named: list[tuple[str, str | Path]]) -> list[dict]:
    """(role, path) pairs as rows: streams (the roles of one path), path, sha256, bytes, files (1 for a file).
    Unreadable ones are listed with ``sha256`` None (a report is not refused for a checksum)."""
    seen: dict[str, dict] = {}
    for role, p in named:
        key = str(p)
        if key in seen:
            seen[key]["streams"].append(role)
            continue
        row = {"streams": [role], "path": key, "sha256": None, "bytes": None, "files": None}
        try:
            st = Path(p).stat()
            row["sha256"], row["bytes"], row["files"] = _digest(str(Path(p).resolve()), st.st_mtime_ns, st.st_size)
        except OSError:
            pass
        seen[key] = row
    return list(seen.values())


def fingerprint(description: dict) -> str:
    """A cheap digest of a dataset's input files as they are now: each file's name, size and modification time
    (no content read), for the folders the manifest names, every file under them. A sweep's run id folds it in,
    so that a sweep resumed after the data changed runs again rather than keeping the old figures."""
    base = Path(description.get("path") or ".")
    base = base.parent if base.is_file() else base
    h = hashlib.sha256()
    root = base.resolve()
    man = description.get("path")
    paths = sorted({*(str(p) for entry in (description.get("streams") or {}).values() for p in _paths(entry, base)),
                    *([str(man)] if man and Path(man).is_file() else [])})
    for p in (Path(x).resolve() for x in paths):
        for f in (sorted(x for x in p.rglob("*") if x.is_file()) if p.is_dir() else [p]):
            try:
                st = f.stat()
            except OSError:
                continue
            # names relative to the dataset's folder: the same files however the path was written, from anywhere
            rel = f.relative_to(root) if f.is_relative_to(root) else f
            h.update(f"{rel.as_posix()}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()[:16]


def input_files(description: dict) -> list[dict]:
    """The manifest itself (its geodetic origin, extrinsics, offsets and platform move the figures: two manifests of
    one drive that differ in geodetic_origin had the same inputs listed; a diff review) and the input files it names
    (its ``streams``, relative to its ``path``), as :func:`files`."""
    base = Path(description.get("path") or ".")
    base = base.parent if base.is_file() else base
    man = description.get("manifest")
    own = [("manifest", man)] if man and Path(man).is_file() else []
    return files(own + [(stream, p) for stream, entry in (description.get("streams") or {}).items()
                        for p in _paths(entry, base)])


def dataset_files(paths) -> list[dict]:
    """Rows for the datasets a sweep or a tune ran on: each one's manifest hashed (its data files are in each run's
    own report); a folder without a manifest (a plain KITTI or EuRoC folder) listed unhashed, as its data may be
    gigabytes of images the runs never read."""
    rows = []
    for p in dict.fromkeys(str(x) for x in paths):
        path = Path(p)
        manifest = path if path.is_file() else path / "dataset.yaml"
        if manifest.is_file():
            rows += files([("dataset manifest", manifest)])
        else:
            rows.append({"streams": ["dataset folder"], "path": p, "sha256": None, "bytes": None, "files": None})
    return rows
