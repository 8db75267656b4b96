"""The compiled table formatter agrees with Python's own formatting."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_eval.fastfmt import format_table, table_chunks, table_text


def test_matches_python_formatting():
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.normal(size=500) * 1e3, rng.normal(size=500), rng.integers(-5, 5, 500), np.zeros(500)])
    a[0] = [-0.0000004, 0.5, -3, 0.0]
    dec = [6, 12, 0, 3]
    text = table_text(a, dec)
    expected = "".join(" ".join(f"{x:.{d}f}" for x, d in zip(row, dec)) + "\n" for row in a)
    # Python rounds half to even on the binary value; both agree except at exact ties, which random data avoids
    assert text.replace("-0.000000 ", "0.000000 ") == expected.replace("-0.000000 ", "0.000000 ")
    buf, offs = format_table(a, dec)
    assert offs[-1] == len(buf) and buf[offs[1] - 1] == ord("\n")
    assert np.allclose(np.loadtxt(text.splitlines()), a, atol=1e-6)


def test_rejects_values_it_cannot_write_exactly():
    with pytest.raises(ValueError):
        format_table(np.array([[1e10]]), [9])
    with pytest.raises(ValueError):
        format_table(np.array([[np.nan]]), [3])


def test_chunks_are_the_table_in_pieces_and_a_bad_value_stops_it_before_the_first():
    rng = np.random.default_rng(1)
    a = np.column_stack([np.arange(1000) * 0.005, rng.normal(size=(1000, 7))])
    whole = format_table(a, [6] + [9] * 7)[0].tobytes()
    pieces = list(table_chunks(a, [6] + [9] * 7, rows=97))
    assert len(pieces) == 11 and b"".join(pieces) == whole
    a[-1, 3] = np.nan                      # checked whole: a writer that streams never leaves a partial file
    with pytest.raises(ValueError):
        next(table_chunks(a, [6] + [9] * 7, rows=97))
