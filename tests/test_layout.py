"""Named state layouts: indices derive from named blocks; no literal state index outside the layout
definitions; the canonical map and recording index follow from the pairs."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from fusion_eval.filters import formulations
from fusion_eval.filters.layout import CANONICAL, Layout, canonical_index

PKG = ROOT / "fusion_eval"
# Where state vectors and covariances are indexed: the filters, the replay, and what reads their records.
SCANNED = [*sorted((PKG / "filters").rglob("*.py")), PKG / "replay.py", PKG / "evaluation" / "run_metrics.py",
           PKG / "report" / "plots.py"]
LAYOUT_DEFINITIONS = {PKG / "filters" / "layout.py"}
# A literal slice ``[3:6]``, a literal index constant ``P_ID = 0``, or a literal column range ``[:, 9:12]``.
LITERAL = re.compile(r"\[\s*-?\d+\s*:\s*-?\d+\s*[\],]|_ID\s*=\s*\d|\[\s*:\s*,\s*\d+\s*:\s*\d+\s*\]")


def test_no_literal_state_index_outside_the_layout_definitions():
    hits = []
    for f in SCANNED:
        if f in LAYOUT_DEFINITIONS:
            continue
        for i, line in enumerate(f.read_text().splitlines(), 1):
            code = line.split("#")[0]
            if LITERAL.search(code):
                hits.append(f"{f.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not hits, "\n".join(hits)


def test_the_scan_finds_a_literal_index():
    assert LITERAL.search("H[:, 6:9] = np.eye(3)") and LITERAL.search("d = x[3:6]") and LITERAL.search("OP_ID = 0")
    assert not LITERAL.search("H[:, TH] = np.eye(3)") and not LITERAL.search("x[XP:XP + 3]")


def test_layouts_derive_indices_from_blocks():
    L = Layout("t", [("A", 3), ("B", 4)], clone=[("CA", 3)], clone_of={"CA": "A"})
    assert (L.start("B"), L.n_core, L.n) == (3, 7, 10)
    assert list(L.clone_rows()) == [0, 1, 2]
    with pytest.raises(ValueError):
        Layout("bad", [("A", 3)], clone=[("C", 4)], clone_of={"C": "A"})


@pytest.mark.parametrize("cls", formulations.REGISTRY, ids=lambda c: f"{c.name}+{c.process_model}")
def test_recording_index_maps_the_identity_pairs(cls):
    idx = canonical_index(cls.layout, cls.pairs)
    for c, o in cls.pairs:
        if c in CANONICAL.core and cls.layout[o].size == CANONICAL[c].size:
            assert list(idx[CANONICAL.sl(c)]) == list(range(cls.layout.start(o), cls.layout[o].stop))
    mapped = {c for c, _ in cls.pairs}
    for c in CANONICAL.core:
        if c not in mapped:
            assert np.all(idx[CANONICAL.sl(c)] == -1)
