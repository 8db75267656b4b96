"""``report.html``: a command's Markdown report as one self-contained page, to open from disk and read at a glance.

The page is the Markdown report itself, rendered by `Python-Markdown <https://python-markdown.github.io>`_ (pipe
tables, fenced code), so the text, the tables and the figures are those of ``report.md`` (one source, no second
copy to drift). Around it: a header (what ran, version, date, command line), a table of contents, the plots
embedded as ``data:`` URIs (base64 PNG), and a provenance section (versions, input files with sha256).

Static images, not an interactive plotting library: the default run's page is about 1.8 MB with every plot, opens
without a network or a JavaScript engine, prints to PDF as it looks, and shows the very figures ``report.md``
links. Plotly's offline bundle alone is 3.6 MB (the budget is 5 MB). A click on a figure widens it to the page
width (a few lines of script; without script the page is the same, only the click does nothing).
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

import markdown as md_lib

from .. import provenance
from .files import versions

WIDE_PX = 1400          # figures this wide (several panels) start at the page's width, the others two side by side
WIDE_ASPECT = 1.8       # ... and so do figures this much wider than high (a time series: the APE over time, ~480 px
                        # wide beside another, had a legend no one could read without a click; a plot review)
_IMG = re.compile(r'<img alt="([^"]*)" src="([^"]+)"\s*/?>')

_CSS = """
:root { --fg: #1d2430; --muted: #5b6678; --line: #d8dde6; --accent: #1f5fbf; --bg-alt: #f5f7fa; }
* { box-sizing: border-box; }
body { margin: 0; font: 15px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: var(--fg); }
header { padding: 18px 32px 10px; border-bottom: 1px solid var(--line); background: var(--bg-alt); }
header h1 { margin: 0 0 4px; font-size: 22px; }
header .meta { color: var(--muted); font-size: 13px; }
header code { font-size: 12px; }
.layout { display: flex; align-items: flex-start; }
nav { position: sticky; top: 0; flex: 0 0 220px; max-height: 100vh; overflow-y: auto; padding: 16px 12px 16px 24px;
      font-size: 13px; border-right: 1px solid var(--line); }
nav ul { list-style: none; padding-left: 0; margin: 0; }
nav ul ul { padding-left: 12px; }
nav a { color: var(--muted); text-decoration: none; display: block; padding: 2px 0; }
nav a:hover { color: var(--accent); }
main { flex: 1; min-width: 0; padding: 8px 32px 48px; max-width: 1400px; }
h2 { margin-top: 32px; padding-bottom: 4px; border-bottom: 1px solid var(--line); font-size: 19px; }
h3 { font-size: 16px; }
table { border-collapse: collapse; margin: 12px 0; font-size: 13px; font-variant-numeric: tabular-nums; }
@media screen { table { display: block; overflow-x: auto; max-width: 100%; } }
th, td { padding: 4px 10px; border-bottom: 1px solid var(--line); }
td { white-space: nowrap; }
td code { white-space: normal; word-break: break-all; }
th { background: var(--bg-alt); position: sticky; top: 0; text-align: left; white-space: normal; max-width: 150px;
     vertical-align: bottom; }
tbody tr:nth-child(even) { background: #fafbfc; }
tbody tr:hover { background: #eef3fb; }
td:first-child { font-weight: 600; }
figure { margin: 12px 0; display: inline-block; vertical-align: top; width: calc(50% - 12px); margin-right: 8px; }
figure.wide { width: 100%; }
figure img { width: 100%; height: auto; border: 1px solid var(--line); cursor: zoom-in; }
figure.wide img { cursor: zoom-out; }
figcaption { color: var(--muted); font-size: 12px; }
pre { background: var(--bg-alt); padding: 10px 12px; overflow-x: auto; font-size: 12px; border: 1px solid var(--line); }
code { font-family: ui-monospace, SFMono-Regular, Menlo, Consolas, monospace; }
.missing { color: #b00020; }
@media (max-width: 900px) { nav { display: none; } figure { width: 100%; } main { padding: 8px 12px; } }
@media print { nav { display: none; } figure { width: 100%; page-break-inside: avoid; } table { font-size: 9px; }
  td { white-space: normal; } }
"""

# widen a figure on click; nothing else runs
_JS = """document.addEventListener('click', function (e) {
  var f = e.target.closest('figure'); if (f) { f.classList.toggle('wide'); }
});"""


def _figure(folder: Path, alt: str, src: str) -> str:
    """An ``<img>`` of the report as a figure with the PNG embedded (a missing file is shown as missing, not hidden)."""
    p = folder / src
    name = html.escape(src)
    try:
        data = base64.b64encode(p.read_bytes()).decode("ascii")
    except OSError:
        return f'<p class="missing">figure {name} was not written</p>'
    mime = "image/svg+xml" if src.endswith(".svg") else "image/png"
    w, h = _png_size(p)
    wide = ' class="wide"' if w >= WIDE_PX or (h > 0 and w >= WIDE_ASPECT * h) else ""
    return (f'<figure{wide}><img alt="{alt}" src="data:{mime};base64,{data}" title="{name}: click to widen or narrow">'
            f"<figcaption>{name}</figcaption></figure>")


def _png_size(path: Path) -> tuple[int, int]:
    """A PNG's width and height in pixels from its IHDR chunk ((0, 0) for anything else)."""
    with open(path, "rb") as fh:
        head = fh.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n":
        return 0, 0
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def _int(v) -> str:
    return "" if v is None else f"{v:,}"


def _provenance(inputs: list[dict] | None) -> str:
    v = versions()
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(str(val))}</td></tr>" for k, val in v.items())
    out = ['<h2 id="provenance">Provenance</h2>', "<h3>Versions</h3>", f"<table><tbody>{rows}</tbody></table>"]
    if inputs:
        body = "".join(
            f"<tr><td>{html.escape(r['path'])}</td><td>{html.escape(', '.join(r['streams']))}</td>"
            f"<td>{'' if r['files'] is None else r['files']}</td>"
            f"<td>{_int(r['bytes'])}</td>"
            f"<td><code>{r['sha256'] or 'not hashed'}</code></td></tr>" for r in inputs)
        out += ["<h3>Input files</h3>", "<p>sha256 of each input file; of a folder, over its files' relative names and "
                "contents in name order.</p>",
                "<table><thead><tr><th>path</th><th>streams</th><th>files</th><th>bytes</th><th>sha256</th></tr></thead>"
                f"<tbody>{body}</tbody></table>"]
    return "\n".join(out)


def page(report_md: str, folder: Path, images: list[str] = (), inputs: list[dict] | None = None) -> str:
    """The HTML page of ``report_md`` (whose first line is its ``# title``), with the figures it links and any of
    ``images`` it does not, read from ``folder``, and the provenance (``inputs``: :func:`provenance.input_files`)."""
    lines = report_md.splitlines()
    title = lines[0].lstrip("# ").strip() if lines and lines[0].startswith("# ") else "fusion-eval report"
    body_md = "\n".join(lines[1:] if lines and lines[0].startswith("# ") else lines)
    body_md = _HEADER_LINE.sub("", body_md, count=1)        # the page's header says it
    linked = set(_IMG_MD.findall(body_md))
    extra = [i for i in images if i not in linked]
    if extra:
        body_md += "\n\n## Plots\n\n" + "\n".join(f"![{i}]({i})" for i in extra) + "\n"
    conv = md_lib.Markdown(extensions=["tables", "fenced_code", "toc"], extension_configs={"toc": {"toc_depth": "2-3"}})
    body = conv.convert(body_md)
    body = _IMG.sub(lambda m: _figure(folder, m.group(1), html.unescape(m.group(2))), body)
    toc = conv.toc.replace("</ul>\n</div>", '<li><a href="#provenance">Provenance</a></li></ul>\n</div>', 1) \
        if '<div class="toc">' in conv.toc else conv.toc
    h = provenance.header()
    meta = (f'fusion-eval {html.escape(h["version"])} (code {html.escape(h["code"])}) &middot; {html.escape(h["date"])} &middot; '
            f'<code>{html.escape(h["command"])}</code>')
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="fusion-eval {html.escape(h['version'])}">
<title>{html.escape(title)}</title>
<style>{_CSS}</style>
</head>
<body>
<header><h1>{html.escape(title)}</h1><div class="meta">{meta}</div></header>
<div class="layout">
<nav>{toc}</nav>
<main>
{body}
{_provenance(inputs)}
</main>
</div>
<script>{_JS}</script>
</body>
</html>
"""


_HEADER_LINE = re.compile(r"^fusion-eval \S+, [^\n]* UTC: `[^\n]*`$", re.M)
_IMG_MD = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")
