"""Generic stamped vectors: ``t_s v1 v2 ... [std1 std2 ...]`` per line (format ``vector_txt``).

Whitespace- or comma-separated, ``#`` comments, an optional header line of names. With ``n`` components a
line holds ``1 + n`` values (the manifest entry's ``std`` gives the 1-sigma) or ``1 + 2n`` (the std per line).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ConfigError, DataFormatError
from ..types import VectorSeries
from ._text import is_float, parse_numeric_rows, read_text


def read_vectors(path: Path, n: int, what: str, std=None, manifest: Path | None = None, key: str = "std") -> VectorSeries:
    """Read ``n``-component vectors; ``std`` (a number or ``n`` numbers) when the file has no std columns."""
    path = Path(path)
    text = read_text(path, f"{what}: 't_s' and {n} values per line")
    lines = text.splitlines()
    first = next((i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")), None)
    delim = "," if first is not None and "," in lines[first] else None
    if first is not None and not all(is_float(x.strip()) for x in (lines[first].split(delim) if delim else lines[first].split())):
        lines[first] = "#" + lines[first]        # a header of names: skipped, line numbers kept
    rows, ln = parse_numeric_rows(path, "\n".join(lines), (1 + n, 1 + 2 * n), what, delimiter=delim)
    values = rows[:, 1:1 + n]
    if rows.shape[1] == 1 + 2 * n:
        sd = rows[:, 1 + n:]
    else:
        if std is None:
            raise DataFormatError(path, None, f"{what}: no std columns (1 + 2 x {n} values per line); give "
                                              f"'{key}' in the manifest")
        s = np.atleast_1d(np.asarray(std, float))
        if s.size not in (1, n) or not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ConfigError(f"{manifest or path}: '{key}' must be a positive number or {n} positive numbers, got {std!r}")
        sd = np.tile(np.resize(s, n), (rows.shape[0], 1))
    return VectorSeries(t_s=rows[:, 0], values=values, std=sd, source=str(path), lines=ln, what=what)
