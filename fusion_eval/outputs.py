"""Atomic output directories: everything is written into a hidden staging folder beside the target
and renamed into place only when the whole run succeeded, so an interrupted or failed run never
leaves a half-written output directory and never destroys an earlier one."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from .errors import OutputError


class StagedDir:
    def __init__(self, final: Path, overwrite: bool = False):
        self.final = Path(final)
        self.overwrite = overwrite
        self.staging: Path | None = None
        self._made: list[Path] = []

    def check(self) -> None:
        """Fail early (before any work) if the target cannot be used."""
        if self.final.exists() and not self.final.is_dir():
            raise OutputError(f"{self.final}: output path exists and is not a directory")
        if self.final.is_dir() and any(self.final.iterdir()) and not self.overwrite:
            raise OutputError(f"{self.final}: output directory exists and is not empty (use --overwrite, or overwrite=True in Python, to replace it)")

    def __enter__(self) -> "StagedDir":
        self.check()
        try:
            # remember which parent folders this run creates, to remove them again if it fails
            self._made = [p for p in [self.final.parent, *self.final.parent.parents] if not p.exists()]
            self.final.parent.mkdir(parents=True, exist_ok=True)
            self.staging = self.final.parent / f".{self.final.name}.partial-{os.getpid()}"
            if self.staging.exists():
                shutil.rmtree(self.staging)
            self.staging.mkdir()
        except OSError as exc:
            raise OutputError(f"{self.final}: cannot create output directory ({exc.strerror})") from None
        return self

    def path(self, name: str) -> Path:
        """A path inside the staging folder (for writers that take a file name)."""
        return self.staging / name

    def write_text(self, name: str, text: str) -> Path:
        return self.write_bytes(name, text.encode("utf-8"))

    def write_bytes(self, name: str, data: bytes) -> Path:
        target = self.staging / name
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, target)
        return target

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            for p in self._made:   # deepest first
                try:
                    p.rmdir()
                except OSError:
                    break
            return False
        old = None
        if self.final.exists():
            old = self.final.parent / f".{self.final.name}.old-{os.getpid()}"
            os.replace(self.final, old)
        os.replace(self.staging, self.final)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return False
