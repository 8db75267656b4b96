"""Tables as text: Markdown, LaTeX (booktabs) and CSV from one helper, shared by every report.

A table is a header and rows of raw values; :func:`cell` formats them (None and NaN print as ``n/a`` in Markdown
and LaTeX and empty in CSV, floats with a fixed number of decimals, everything else with ``str``). The layout
and the escaping of each format are `tabulate <https://github.com/astanin/python-tabulate>`_'s: Markdown pipe
tables and ``latex_booktabs`` (LaTeX special characters escaped), so that the same rows give both the report's
table and the one a paper includes.
"""

from __future__ import annotations

import csv
import io
import math
import re
from typing import Any, Iterable, Sequence

from tabulate import tabulate

_ALIGN = {"l": "left", "r": "right", "c": "center"}
# the characters tabulate escapes in cells, for the caption (outside the tabular)
_LATEX_ESCAPES = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                  "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\^{}"}


def cell(v: Any, nd: int = 3, na: str = "n/a") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return na
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def _cells(header: Sequence[str], rows: Iterable[Sequence[Any]], align: str | None,
           decimals: Sequence[int] | int) -> tuple[list[list[str]], tuple[str, ...]]:
    n = len(header)
    align = align or ("l" + "r" * (n - 1))
    if len(align) != n:
        raise ValueError(f"table: {len(align)} alignment letters for {n} columns")
    nd = [decimals] * n if isinstance(decimals, int) else list(decimals)
    body = [[v if isinstance(v, str) else cell(v, nd[i]) for i, v in enumerate(r)] for r in rows]
    return body, tuple(_ALIGN[a] for a in align)


def markdown(header: Sequence[str], rows: Iterable[Sequence[Any]], align: str | None = None,
             decimals: Sequence[int] | int = 3) -> list[str]:
    """Lines of a Markdown (pipe) table. ``align``: one letter per column, ``l``, ``r`` or ``c`` (default: first
    column left, the rest right); ``decimals``: per column or for all."""
    body, colalign = _cells(header, rows, align, decimals)
    body = [[c.replace("|", "\\|") for c in r] for r in body]      # a '|' inside a cell would end it
    return tabulate(body, headers=list(header), tablefmt="pipe", colalign=colalign, disable_numparse=True).splitlines()


def latex(header: Sequence[str], rows: Iterable[Sequence[Any]], align: str | None = None,
          decimals: Sequence[int] | int = 3, caption: str | None = None, label: str | None = None) -> str:
    """A booktabs ``tabular`` (``\\toprule``, ``\\midrule``, ``\\bottomrule``; needs ``\\usepackage{booktabs}``),
    wrapped in a ``table`` float when ``caption`` is given. Markdown code marks (backticks) are dropped, the rest
    escaped by tabulate."""
    body, colalign = _cells(header, rows, align, decimals)
    strip = re.compile(r"`([^`]*)`")
    body = [[strip.sub(r"\1", c) for c in r] for r in body]
    tab = tabulate(body, headers=[strip.sub(r"\1", h) for h in header], tablefmt="latex_booktabs", colalign=colalign,
                   disable_numparse=True)
    if caption is None:
        return tab + "\n"
    esc = "".join(_LATEX_ESCAPES.get(ch, ch) for ch in strip.sub(r"\1", caption))
    lab = f"\\label{{{label}}}\n" if label else ""
    # wide tables (a run's eight columns) are scaled down to the text width, never up
    tab = f"\\resizebox{{\\ifdim\\width>\\linewidth\\linewidth\\else\\width\\fi}}{{!}}{{%\n{tab}}}"
    return f"\\begin{{table}}[t]\n\\centering\n\\caption{{{esc}}}\n{lab}{tab}\n\\end{{table}}\n"


def latex_document(tables: Sequence[str], title: str) -> str:
    """Tables as a ``.tex`` file to ``\\input`` into a paper: a comment naming what it holds and the packages it needs."""
    return (f"% {title}\n% written by fusion-eval; needs \\usepackage{{booktabs}} and \\usepackage{{graphicx}}; "
            "\\input{} this file into a document\n\n"
            + "\n".join(tables))


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
