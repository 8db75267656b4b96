"""Tables as text: Markdown and CSV, one formatter each, shared by every report.

Cells are formatted by :func:`cell`: None (and NaN) print as ``n/a`` in Markdown and empty in CSV, floats
with a fixed number of decimals, everything else with ``str``.
"""

from __future__ import annotations

import csv
import io
import math
from typing import Any, Iterable, Sequence


def cell(v: Any, nd: int = 3, na: str = "n/a") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return na
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def markdown(header: Sequence[str], rows: Iterable[Sequence[Any]], align: str | None = None,
             decimals: Sequence[int] | int = 3) -> list[str]:
    """Lines of a Markdown table. ``align``: one letter per column, ``l`` or ``r`` (default: first column
    left, the rest right); ``decimals``: per column or for all."""
    n = len(header)
    align = align or ("l" + "r" * (n - 1))
    nd = [decimals] * n if isinstance(decimals, int) else list(decimals)
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---:" if a == "r" else "---" for a in align) + "|"]
    for r in rows:
        out.append("| " + " | ".join(v if isinstance(v, str) else cell(v, nd[i]) for i, v in enumerate(r)) + " |")
    return out


def csv_text(columns: Sequence[str], rows: Iterable[dict], float_format: str = "{:.6f}") -> str:
    """CSV with a header row; missing values empty, floats in ``float_format``."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _csv_cell(r.get(k), float_format) for k in columns})
    return buf.getvalue()


def _csv_cell(v, float_format: str) -> Any:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, float):
        return float_format.format(v)
    return v
