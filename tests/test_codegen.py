"""Generated compiled functions (the replay's loop, the propagation loop, the RTS pass) are compiled from files
of their own: numba reads their source lines when it saves its cache, and under the building module's name those
lines were an unrelated part of that module (Python 3.13's tokenizer raised on them: the first run failed)."""

from __future__ import annotations

import inspect
import sys
import types

import pytest

from fusion_eval import codegen
from fusion_eval.filters import compiled_replay
from fusion_eval.filters.formulations import eskf


def test_every_generated_loop_reads_back_its_own_source():
    for fn in (eskf.predict_to, compiled_replay.compiled_loop(eskf.ErrorStateKF)):
        lines, start = inspect.getsourcelines(fn.py_func)
        assert lines[0].startswith(f"def {fn.py_func.__name__}(") and start >= 1, lines[0]
        assert fn.py_func.__code__.co_filename != eskf.__file__


@pytest.fixture
def anchor(tmp_path, monkeypatch):
    """A module of its own on disk, and the generated files' folder in tmp_path."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    src = tmp_path / "anchor_mod.py"
    src.write_text("X = 1\n")
    mod = types.ModuleType("anchor_mod")
    mod.__file__ = str(src)
    monkeypatch.setitem(sys.modules, "anchor_mod", mod)
    return src


def test_the_file_is_named_by_the_template_and_the_anchoring_modules_source(anchor, tmp_path):
    tpl = "def f_gen(x):\n    return x + {k}\n"
    ns = codegen.build("anchor_mod", "f_gen", tpl.format(k=1), {})
    first = ns["f_gen"].__code__.co_filename
    assert ns["f_gen"](1) == 2 and first.startswith(str(tmp_path / "cache" / "fusion-eval-generated"))
    assert codegen.build("anchor_mod", "f_gen", tpl.format(k=1), {})["f_gen"].__code__.co_filename == first
    anchor.write_text("X = 2\n")             # a step the loop inlines changed: another file, a fresh compile
    assert codegen.build("anchor_mod", "f_gen", tpl.format(k=1), {})["f_gen"].__code__.co_filename != first
    assert codegen.build("anchor_mod", "f_gen", tpl.format(k=2), {})["f_gen"](1) == 3


def test_with_no_writable_folder_the_template_is_compiled_as_before(anchor, monkeypatch):
    monkeypatch.setattr(codegen, "_folders", lambda: [anchor / "not-a-folder"])     # under a file: cannot be made
    ns = codegen.build("anchor_mod", "g_gen", "def g_gen():\n    return 5\n", {})
    assert ns["g_gen"]() == 5 and ns["g_gen"].__code__.co_filename == str(anchor)
