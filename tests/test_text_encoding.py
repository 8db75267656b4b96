"""Every text file the package reads or writes names its encoding (UTF-8): under a cp1252 locale a sweep setting
named with a Greek letter stopped the summary with a traceback after every run had finished, and a best.yaml with an
umlaut was written in cp1252, which `run -c` then refused (a portability review)."""

from __future__ import annotations

import ast

from conftest import ROOT


def _unnamed_encodings(source: str) -> list[int]:
    """Lines of calls that read or write text in the locale's encoding: ``p.read_text()``, ``p.write_text(text)``
    (one argument: a Path's; the staged folder's ``write_text(name, text)`` encodes UTF-8 itself) and ``open(...)``
    in a text mode, none with ``encoding=``."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call) or any(k.arg == "encoding" for k in node.keywords):
            continue
        f = node.func
        if isinstance(f, ast.Attribute) and f.attr == "read_text":
            out.append(node.lineno)
        elif isinstance(f, ast.Attribute) and f.attr == "write_text" and len(node.args) == 1:
            out.append(node.lineno)
        elif isinstance(f, ast.Name) and f.id == "open":
            mode = node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
            text_mode = mode is None or (isinstance(mode, ast.Constant) and "b" not in str(mode.value))
            devnull = node.args and isinstance(node.args[0], ast.Attribute) and node.args[0].attr == "devnull"
            if text_mode and not devnull:
                out.append(node.lineno)
    return out


def test_every_text_read_and_write_names_its_encoding():
    hits = [f"{f.relative_to(ROOT)}:{line}" for f in sorted((ROOT / "fusion_eval").rglob("*.py"))
            for line in _unnamed_encodings(f.read_text(encoding="utf-8"))]
    assert not hits, "text I/O in the locale's encoding (add encoding='utf-8'):\n" + "\n".join(hits)


def test_the_scan_finds_an_unnamed_encoding():
    bad = ["p.read_text()", "p.write_text(s)", "open(p)", "open(p, 'w')", "open(p, mode='a')"]
    good = ["p.read_text(encoding='utf-8')", "p.write_text(s, encoding='utf-8')", "out.write_text('a.txt', s)",
            "open(p, 'rb')", "open(p, encoding='utf-8')", "open(os.devnull, 'w')", "p.read_bytes()"]
    assert [bool(_unnamed_encodings(s)) for s in bad] == [True] * len(bad)
    assert [bool(_unnamed_encodings(s)) for s in good] == [False] * len(good)
