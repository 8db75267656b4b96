"""Shared parsing of whitespace-separated numeric text files with line-accurate errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataFormatError


def read_text(path: Path, what: str) -> str:
    """Read a whole text file, turning a missing or unreadable file into a one-line error."""
    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, None, f"file not found (expected {what})")
    if path.is_dir():
        raise DataFormatError(path, None, f"is a directory (expected {what})")
    try:
        return path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(path, None, f"cannot read {what}: {exc}") from None


def parse_numeric_rows(path: Path, text: str, ncols: int | tuple[int, ...], what: str,
                       comment: str = "#", delimiter: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Parse numeric rows, skipping blank and comment lines.

    Returns the ``(N, ncols)`` array and the 1-based line number of each row. A row with the wrong
    number of values, a value that is not a number, or a NaN/inf raises :class:`DataFormatError`
    naming the line and what was expected.
    """
    allowed = (ncols,) if isinstance(ncols, int) else tuple(ncols)
    rows: list[list[float]] = []
    lines: list[int] = []
    width = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or (comment and s.startswith(comment)):
            continue
        parts = s.split(delimiter) if delimiter else s.split()
        parts = [p.strip() for p in parts]
        if len(parts) not in allowed or (width is not None and len(parts) != width):
            exp = " or ".join(str(a) for a in allowed) if width is None else str(width)
            raise DataFormatError(path, lineno, f"{what} must have {exp} values per row, got {len(parts)}")
        width = len(parts)
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            bad = next(p for p in parts if not is_float(p))
            raise DataFormatError(path, lineno, f"{what}: expected a number, got {bad!r}") from None
        if not all(np.isfinite(vals)):
            raise DataFormatError(path, lineno, f"{what}: values must be finite numbers (found NaN or inf)")
        rows.append(vals)
        lines.append(lineno)
    if not rows:
        raise DataFormatError(path, None, f"no data rows (expected {what})")
    return np.array(rows, dtype=float), np.array(lines, dtype=np.int64)


def is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False
