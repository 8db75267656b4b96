"""Named state layouts: indices derive from named blocks; no literal state index outside the layout
definitions; the canonical map and recording index follow from the pairs."""

from __future__ import annotations

import re

import numpy as np
import pytest

from conftest import ROOT
from fusion_eval.filters import formulations
from fusion_eval.filters.layout import CANONICAL, Layout, unpack_pose_cov

PKG = ROOT / "fusion_eval"
# Where state vectors and covariances are indexed: the filters, the replay, and what reads their records.
SCANNED = [*sorted((PKG / "filters").rglob("*.py")), PKG / "replay.py", PKG / "evaluation" / "run_metrics.py",
           PKG / "evaluation" / "consistency.py", PKG / "report" / "plots.py"]
LAYOUT_DEFINITIONS = {PKG / "filters" / "layout.py"}
# A literal slice (``[3:6]``, ``[:3]``, ``[3:]``, also as a later axis, ``[:, 9:12]``), or a literal index constant
# (``P_ID = 0``, ``TH = 6``): what a hand-written state index looks like.
LITERAL = re.compile(r"[\[,]\s*-?\d*\s*:\s*-?\d+\s*[\],]|[\[,]\s*-?\d+\s*:\s*[\],]|\b[A-Z][A-Z0-9_]*\s*=\s*\d+\s*(#|$)")


def test_no_literal_state_index_outside_the_layout_definitions():
    hits = []
    for f in SCANNED:
        if f in LAYOUT_DEFINITIONS:
            continue
        for i, line in enumerate(f.read_text().splitlines(), 1):
            if line.rstrip().endswith("# not a state index") or "# not a state index:" in line:
                continue                                       # declared: rows, components or list items
            code = line.split("#")[0]
            if LITERAL.search(code):
                hits.append(f"{f.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not hits, "\n".join(hits)


def test_the_scan_finds_a_literal_index():
    for bad in ("H[:, 6:9] = np.eye(3)", "d = x[3:6]", "OP_ID = 0", "TH = 6", "P[:, :3, :3]", "v = x[3:]", "q[:3]"):
        assert LITERAL.search(bad), bad
    for good in ("H[:, TH] = np.eye(3)", "x[XP:XP + 3]", "u0[UF:UF + 3]", "R[i, 0]", "dt = 0.5 * (a + b)"):
        assert not LITERAL.search(good), good


def test_layouts_derive_indices_from_blocks():
    L = Layout("t", [("A", 3), ("B", 4)], clone=[("CA", 3)], clone_of={"CA": "A"})
    assert (L.start("B"), L.n_core, L.n) == (3, 7, 10)
    assert list(L.clone_rows()) == [0, 1, 2]
    with pytest.raises(ValueError):
        Layout("bad", [("A", 3)], clone=[("C", 4)], clone_of={"C": "A"})


@pytest.mark.parametrize("cls", formulations.REGISTRY, ids=lambda c: f"{c.name}+{c.process_model}")
def test_recorded_covariance_is_the_canonical_one(cls):
    """What each formulation's compiled recording writes equals D P D^T with D the canonical map (NaN where
    the formulation has no such state): the recording and the map agree, whatever the layout."""
    from fusion_eval.filters.layout import POSE_BLOCKS
    from fusion_eval.filters.state import NominalState
    from fusion_eval.so3 import exp_so3

    rng = np.random.default_rng(1)
    x = NominalState(rng.normal(size=3), rng.normal(size=3), exp_so3(rng.normal(size=3)), np.zeros(3), np.zeros(3))
    L = cls.layout
    kf = cls(x, np.eye(CANONICAL.n_core), np.zeros(8), np.array([0.0, 1.0]), np.zeros((2, 6 if cls.process_model == "imu" else 4)),
             0, extra_var={b: 1.0 for b in L.core if all(b != o for _, o in cls.pairs)})
    A = rng.normal(size=(L.n_core, L.n_core))
    kf.P[:L.n_core, :L.n_core] = A @ A.T
    kf.record(0)
    C = kf.D()[:CANONICAL.n_core] @ kf.P[:kf.n, :kf.n] @ kf.D()[:CANONICAL.n_core].T
    have = {c for c, _ in cls.pairs}
    for b in CANONICAL.core:
        got = kf.rec_x is not None and kf.arrays.rec_Pdiag[0, CANONICAL.sl(b)]
        if b in have:
            assert np.allclose(got, np.diag(C)[CANONICAL.sl(b)], rtol=1e-12), (cls.name, b)
        else:
            assert np.all(np.isnan(got)), (cls.name, b)
    pt = CANONICAL.index(*POSE_BLOCKS)
    assert np.allclose(unpack_pose_cov(kf.arrays.rec_Ppt[0]), C[np.ix_(pt, pt)], rtol=1e-12)
