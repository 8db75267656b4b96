"""Shared parsing of whitespace-separated numeric text files with line-accurate errors."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
from numba import njit

from ..errors import DataFormatError, shown


def check_file(path: Path, what: str) -> Path:
    """``path`` as a readable regular file, or a one-line error: missing, a dangling link or a loop of them, a
    directory, a device, a socket or a pipe (/dev/zero filled the memory; a pipe blocks a reader that opens the file
    twice, as several do: save its content to a file)."""
    path = Path(path)
    if not path.exists():
        if path.is_symlink():            # a link to nowhere, or a loop of links, exists() calls missing
            raise DataFormatError(path, None, f"a symbolic link that leads to no file (a loop, or a missing target: "
                                              f"{os.readlink(path)}); expected {what}")
        raise DataFormatError(path, None, f"file not found (expected {what})")
    if path.is_dir():
        raise DataFormatError(path, None, f"is a directory (expected {what})")
    if not path.is_file():
        raise DataFormatError(path, None, f"a pipe, device or socket, not a file (expected {what}; save the content to a "
                                          "file)")
    return path


def read_text(path: Path, what: str) -> str:
    """Read a whole text file, turning a missing or unreadable file into a one-line error."""
    path = check_file(path, what)
    try:
        # utf-8-sig: a byte-order mark (Windows editors write one) is dropped, as pandas and evo's readers drop it
        return path.read_text(encoding="utf-8-sig", errors="strict")
    except UnicodeDecodeError as exc:
        with open(path, "rb") as fh:
            head = fh.read(4)
        kind = next((k for magic, k in _COMPRESSED if head.startswith(magic)), None)
        if kind is not None:             # (it was a codec's message about byte 0x8b)
            raise DataFormatError(path, None, f"a {kind}-compressed file: decompress it first (expected {what})") from None
        if head[:2] in (b"\xff\xfe", b"\xfe\xff"):      # Windows Notepad's 'Unicode'
            raise DataFormatError(path, None, f"UTF-16 text: save it as UTF-8 (expected {what})") from None
        at = exc.start + (3 if head.startswith(b"\xef\xbb\xbf") else 0)     # the byte in the file, its BOM counted
        raise DataFormatError(path, None, f"cannot read {what}: not UTF-8 text ({exc.reason} at byte {at})") from None
    except OSError as exc:
        raise DataFormatError(path, None, f"cannot read {what}: {exc}") from None


_COMPRESSED = ((b"\x1f\x8b", "gzip"), (b"BZh", "bzip2"), (b"\xfd7zXZ", "xz"), (b"PK\x03\x04", "zip"),
               (b"\x28\xb5\x2f\xfd", "zstd"))


def parse_numeric_rows(path: Path, text: str, ncols: int | tuple[int, ...], what: str,
                       comment: str = "#", delimiter: str | None = None,
                       skipped: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Parse numeric rows, skipping blank and comment lines.

    Returns the ``(N, ncols)`` array and the 1-based line number of each row. A row with the wrong
    number of values, a value that is not a number, or a NaN/inf raises :class:`DataFormatError`
    naming the line and what was expected. The columns ``skipped`` may hold anything and read as 0.
    """
    allowed = (ncols,) if isinstance(ncols, int) else tuple(ncols)
    fast = None if skipped else _parse_clean(text, allowed, comment, delimiter)
    if fast is not None:
        return fast
    rows: list[list[float]] = []
    lines: list[int] = []
    width = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or (comment and s.startswith(comment)):
            continue
        parts = s.split(delimiter) if delimiter else s.split()
        parts = [p.strip() for p in parts]
        if len(parts) not in allowed or (width is not None and len(parts) != width):
            exp = _counts(allowed) if width is None else str(width)
            hint = (" (the row holds ';': values separated by ';' with decimal commas, a spreadsheet's export in some "
                    "locales? write ',' or blanks between values and '.' for decimals)" if ";" in s else "")
            raise DataFormatError(path, lineno, f"{what} must have {exp} values per row, got {len(parts)}{hint}")
        width = len(parts)
        parts = ["0" if i in skipped else p for i, p in enumerate(parts)]
        try:
            vals = [strict_float(p) for p in parts]
        except ValueError:
            bad = next(p for p in parts if not is_float(p))
            raise DataFormatError(path, lineno, f"{what}: expected a number, got {shown(bad)}") from None
        if not all(np.isfinite(vals)):
            raise DataFormatError(path, lineno, f"{what}: values must be finite numbers (found NaN or inf)")
        rows.append(vals)
        lines.append(lineno)
    if not rows:
        raise DataFormatError(path, None, f"no data rows (expected {what})")
    return np.array(rows, dtype=float), np.array(lines, dtype=np.int64)


def _parse_clean(text: str, allowed: tuple[int, ...], comment: str, delimiter: str | None):
    """:func:`parse_numeric_rows` of a file with nothing wrong in it, by numpy's compiled parser (correctly rounded,
    as ``float``): 5-10x faster than the line loop on a long drive's files. None for anything it does not take
    cleanly (a bad value, a ragged row, NaN/inf, a width not allowed): the line loop then names the line."""
    if delimiter is not None and len(delimiter) != 1:
        return None                              # numpy's parser takes one character; the line loop any string
    lines = text.splitlines()
    keep = [i for i, s in enumerate(lines, start=1)
            if (t := s.strip()) and not (comment and t.startswith(comment))]
    if not keep:
        return None
    data = lines if len(keep) == len(lines) else [lines[i - 1] for i in keep]
    joined = text if data is lines else "\n".join(data)
    if "_" in joined or not joined.isascii():
        # numbers Python reads and files do not write (strict_float), in the rows only: a header or comment with an
        # underscore or a 'µ' (EuRoC's '#timestamp, p_RS_R_x', our own '# t_s') sent whole files to the line loop, 6x
        # slower (a review of the diff)
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            arr = np.loadtxt(data, dtype=float, delimiter=delimiter, comments=None, ndmin=2)
    except (ValueError, Warning):
        return None
    if arr.shape[0] != len(keep) or arr.shape[1] not in allowed or not np.isfinite(arr).all():
        return None
    return arr, np.asarray(keep, dtype=np.int64)


def strict_float(s: str) -> float:
    """``float(s)`` for a number as data files write it. Python's ``float`` also reads '9_7.47' (97.47: a digit group
    separator) and digits of other scripts ('5.\u0661' as 5.1), and numpy's parser the same: an accelerometer's
    '9_7.47' ran to a fused 3.6 m for 0.72 with the GNSS blamed (a corrupted-input review)."""
    if "_" in s or not s.isascii():
        raise ValueError(f"not a plain number: {s!r}")
    return float(s)


def is_float(s: str) -> bool:
    try:
        strict_float(s)
        return True
    except ValueError:
        return False


def ns_to_s(ns) -> np.ndarray:
    """Seconds of integer nanoseconds, correctly rounded (as Python's exact ``int / int``).

    Every reader turns a stamp into seconds this way or by parsing its decimal text with a correctly rounded parse:
    the same stamp gives the same float whichever file or bag carried it (a stamp off by one unit in the last place,
    0.24 us at 1.3e9 s, moves an update by that much and its estimate by ~1e-6 m). Vectorised as ``sec + rem * 1e-9``,
    which is correctly rounded from 2^21 s on (the decimal never lies within the product's 1e-16 s error of a
    rounding midpoint there); smaller stamps take the exact division.
    """
    ns = np.asarray(ns, dtype=np.int64)
    sec, rem = np.divmod(ns, 1_000_000_000)
    t = sec.astype(float) + rem.astype(float) * 1e-9
    small = np.abs(t) < 2.0 ** 21
    if np.any(small):
        t[small] = [n / 1_000_000_000 for n in ns[small].tolist()]
    return t


def s_to_ns(t_s) -> np.ndarray:
    """Nearest integer nanoseconds of float seconds (``t - floor(t)`` is exact, so only the ns rounding errs). For
    stamps of POSIX size (> 4.5e6 s, where floats are spaced by more than 1 ns), :func:`ns_to_s` gives back the
    very same float."""
    t = np.asarray(t_s, dtype=float)
    sec = np.floor(t)
    return sec.astype(np.int64) * 1_000_000_000 + np.round((t - sec) * 1e9).astype(np.int64)


def exact_floats() -> dict:
    """The ``pandas.read_csv`` argument for correctly rounded floats: pandas 3 parses so by default (and warns on
    the argument); older versions need ``float_precision='round_trip'``."""
    import pandas as pd

    return {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}


def _counts(allowed) -> str:
    """``8 or 12``, or ``8 to 63`` for a run of consecutive counts (once 56 alternatives listed one by one)."""
    a = sorted(set(allowed))
    if len(a) > 2 and a[-1] - a[0] == len(a) - 1:
        return f"{a[0]} to {a[-1]}"
    return " or ".join(map(str, a))



def decimal_to_ns(text: np.ndarray, per_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer nanoseconds of decimal stamps written in a unit of ``per_ns`` ns (ms: 10^6, us: 10^3), from their
    text, exactly (a float's product of epoch milliseconds is off by up to 0.24 us): ``(ns, bad)``, where ``bad``
    marks entries that are no plain decimal (an exponent, a sign alone, words) or whose nanoseconds are beyond int64.
    Digits finer than a nanosecond are rounded half up.

    The characters are read in one compiled pass over the strings' code points (numpy's string functions took 1.6 s
    for an hour of 200 Hz stamps; this, 20 ms)."""
    u = np.ascontiguousarray(np.asarray(text, dtype=str))
    if u.size == 0 or u.dtype.itemsize == 0:        # no stamps, or only empty strings (numpy gives them no width)
        return np.zeros(u.shape, np.int64), np.full(u.shape, u.size > 0)
    codes = u.reshape(-1).view(np.uint32).reshape(-1, u.dtype.itemsize // 4)
    ns, bad = _decimal_codes_to_ns(codes, per_ns, len(str(per_ns)) - 1)
    return ns.reshape(u.shape), bad.reshape(u.shape)


@njit(cache=True)
def _decimal_codes_to_ns(codes, per_ns, digits):
    """:func:`decimal_to_ns` on the code points ``codes`` (n, width; zero-padded): ``[+-]int[.frac]`` with optional
    blanks around it, ``int`` or ``frac`` possibly empty but not both."""
    n, w = codes.shape
    ns = np.zeros(n, np.int64)
    bad = np.zeros(n, np.bool_)
    limit = (2 ** 63 - 1) // per_ns - 1             # whole units whose nanoseconds, fraction and rounding fit int64
    for r in range(n):
        c = codes[r]
        i = 0
        while i < w and (c[i] == 32 or c[i] == 9 or c[i] == 13 or c[i] == 10):
            i += 1
        neg = False
        if i < w and (c[i] == 45 or c[i] == 43):
            neg = c[i] == 45
            i += 1
        ip, n_int, over = 0, 0, False
        while i < w and 48 <= c[i] <= 57:
            if ip > (limit - 9) // 10:
                over = True
            else:
                ip = ip * 10 + (c[i] - 48)
            n_int += 1
            i += 1
        frac, n_frac, rnd = 0, 0, 0
        if i < w and c[i] == 46:
            i += 1
            while i < w and 48 <= c[i] <= 57:
                if n_frac < digits:
                    frac = frac * 10 + (c[i] - 48)
                elif n_frac == digits:
                    rnd = c[i] - 48
                n_frac += 1
                i += 1
        while i < w and (c[i] == 32 or c[i] == 9 or c[i] == 13 or c[i] == 10):
            i += 1
        if over or (i < w and c[i] != 0) or (n_int == 0 and n_frac == 0):
            bad[r] = True
            continue
        for _ in range(min(n_frac, digits), digits):
            frac *= 10
        v = ip * per_ns + frac + (1 if rnd >= 5 else 0)
        ns[r] = -v if neg else v
    return ns, bad
