"""Fast fixed-point text formatting of numeric tables (compiled), for writers of large files.

Python formats about 2 million numbers a second; a simulated hour at 200 Hz writes 30 million.
:func:`format_table` writes every row of a float table into one byte buffer, column ``j`` with
``decimals[j]`` digits after the point (no point for 0), rounding half away from zero, and returns the
buffer and the offset of each row, so a caller can write the whole table or one file per row.
Values must satisfy ``|x| * 10**decimals < 2**53`` (checked), so each is exact to its last digit.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .errors import DataRangeError


@njit(cache=True)
def _format(a, dec, sep, end):
    N, M = a.shape
    width = 1
    for j in range(M):
        width += 20 + dec[j] + 3
    buf = np.empty(N * width, np.uint8)
    offs = np.empty(N + 1, np.int64)
    tmp = np.empty(40, np.uint8)
    pos = 0
    for i in range(N):
        offs[i] = pos
        for j in range(M):
            if j > 0:
                buf[pos] = sep
                pos += 1
            d = dec[j]
            v = a[i, j] * 10.0 ** d
            neg = v < 0.0
            if neg:
                v = -v
            n = np.int64(np.floor(v + 0.5))
            if n == 0:
                neg = False
            k = 0
            while n > 0:
                tmp[k] = 48 + n % 10
                n //= 10
                k += 1
            while k < d + 1:
                tmp[k] = 48
                k += 1
            if neg:
                buf[pos] = 45
                pos += 1
            for q in range(k - 1, -1, -1):
                buf[pos] = tmp[q]
                pos += 1
                if q == d and d > 0:
                    buf[pos] = 46
                    pos += 1
        buf[pos] = end
        pos += 1
    offs[N] = pos
    return buf[:pos], offs


class ValueTooLargeError(DataRangeError, ValueError):
    """A value :func:`format_table` cannot write exactly (a ``ValueError`` too, for callers that catch those)."""


def _checked(a: np.ndarray, decimals) -> tuple[np.ndarray, np.ndarray]:
    a = np.ascontiguousarray(a, dtype=np.float64)
    dec = np.broadcast_to(np.asarray(decimals, np.int64), (a.shape[1],)).copy()
    if not np.all(np.isfinite(a)):
        raise ValueError("format_table: values must be finite")
    if a.size and np.any(np.abs(a).max(axis=0) * 10.0 ** dec >= 2.0 ** 53):
        # not a bug to trace back but a value no plausible setting or datum gives (a simulated noise of 1e12 m):
        # one line, like every bad input
        col = int(np.argmax(np.abs(a).max(axis=0) * 10.0 ** dec))
        raise ValueTooLargeError(f"a value to write, {float(np.abs(a[:, col]).max()):.3g}, is too large for its "
                                 f"{int(dec[col])} decimals: an implausible setting or datum")
    return a, dec


def format_table(a: np.ndarray, decimals, sep: str = " ") -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``a`` as text (``\\n``-terminated): returns ``(bytes as uint8 array, row offsets (N+1,))``."""
    a, dec = _checked(a, decimals)
    return _format(a, dec, ord(sep), ord("\n"))


# rows formatted at a time by table_chunks: ~6 MB of text for a TUM row, where the buffer of a whole table is
# sized for the widest row (257 bytes for TUM): 185 MB for a simulated hour at 200 Hz, then copied as bytes
CHUNK_ROWS = 1 << 16


def table_chunks(a: np.ndarray, decimals, sep: str = " ", rows: int = CHUNK_ROWS):
    """The text of :func:`format_table` as ``bytes`` chunks of ``rows`` rows (checked whole before the first),
    for writers that stream: the same bytes, without the whole table's buffer and its copies."""
    a, dec = _checked(a, decimals)
    for i in range(0, a.shape[0], rows):
        yield _format(a[i:i + rows], dec, ord(sep), ord("\n"))[0].tobytes()


def table_text(a: np.ndarray, decimals, sep: str = " ") -> str:
    return b"".join(table_chunks(a, decimals, sep)).decode("ascii")
