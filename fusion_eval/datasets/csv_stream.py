"""Generic CSV streams: IMU, GNSS (geodetic or local), poses and wheel speed from a user's own log, with the
columns, units, time unit and delimiter named in the manifest entry (``format: csv``)::

    imu:
      format: csv
      path: logs/imu.csv
      columns: [t, wx, wy, wz, ax, ay, az]     # one name per column of the file; '_' (or '_anything') skips one
      time_unit: ns                            # s (default) | ms | us | ns
      gyro_unit: rad/s                         # rad/s (default) | deg/s
      accel_unit: m/s^2                        # m/s^2 (default) | g
      delimiter: ","                           # default ','; ' ' for whitespace-separated text

Column names per stream: IMU ``t ax ay az wx wy wz`` (body frame); GNSS ``t lat lon alt`` (degrees, metres) or
``t x y z`` (local ENU metres), and ``std_e std_n std_u`` or ``std`` (1-sigma, m) or the entry's ``std_m``;
poses (ground truth, lidar) ``t x y z qx qy qz qw`` and optionally ``vx vy vz`` (world frame); odometer ``t v``.
Leading lines that are not numbers (a header) and ``#`` lines are skipped. Stamps are read exactly: integer
nanoseconds (``time_unit: ns``), and milliseconds or microseconds with or without decimals (read from their text),
are converted with :func:`_text.ns_to_s`, decimal seconds with Python's parse, so the same stamp gives the same float
in every layout.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from ..errors import ConfigError, DataFormatError
from ..geo import geodetic_to_enu
from ..types import GnssSeries, ImuSeries, PoseSeries, SpeedSeries
from ._text import decimal_to_ns, exact_floats, is_float, ns_to_s, parse_numeric_rows, read_text
from .streams import ReadContext

TIME_UNITS = {"s": None, "ms": 1_000_000, "us": 1_000, "ns": 1}     # nanoseconds per unit (None: decimal seconds)
GYRO_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0}
ACCEL_UNITS = {"m/s^2": 1.0, "g": 9.80665}
NAMES = {
    "imu": ({"t", "ax", "ay", "az", "wx", "wy", "wz"}, set()),
    "gnss": ({"t"}, {"lat", "lon", "alt", "x", "y", "z", "std_e", "std_n", "std_u", "std"}),
    "poses": ({"t", "x", "y", "z", "qx", "qy", "qz", "qw"}, {"vx", "vy", "vz"}),
    "odometer": ({"t", "v"}, set()),
}
# per stream: a key a stream does not read is refused (std_m on an IMU, a unit on a GNSS, were ignored; a review)
_COMMON = frozenset({"columns", "time_unit", "delimiter"})
KEYS = {"imu": _COMMON | {"gyro_unit", "accel_unit"}, "gnss": _COMMON | {"std_m"}, "groundtruth": _COMMON,
        "lidar": _COMMON, "odometer": _COMMON}


_OTHER_DELIMITERS = "[,;\t]"


def _has_number(line: str, delimiter: str | None) -> bool:
    """Whether a field of ``line`` is a finite number: split on the configured delimiter and on the other common
    ones (a data row in another delimiter is still data), each field whole and unquoted. A header holds none
    ('Unnamed: 0', 'imu 2 ax', a column named 'nan' are names, not numbers)."""
    if delimiter in (None, " "):
        fields = line.split()
    else:
        fields = re.split(f"{_OTHER_DELIMITERS}|{re.escape(delimiter)}", line)
    for f in fields:
        f = f.strip().strip("\"'")
        if is_float(f) and math.isfinite(float(f)):
            return True
    return False


def load_table(path: Path, what: str, ncols_min: int, delimiter: str | None = ",", stamp_col: int | None = None,
               ncols_exact: int | None = None, per_ns: int = 1, skipped: tuple[int, ...] = ()):
    """Numeric rows of a delimited text file, skipping a leading header and ``#`` lines.

    Returns ``(rows (N, k) float, the stamps of column ``stamp_col`` as int64 nanoseconds or None, 1-based line of
    each row)``; the stamps are written in a unit of ``per_ns`` ns: integers for ns, decimals read from their
    text for ms and us. pandas' C parser reads it (with Python's correctly rounded float parse); anything it cannot
    read as a clean numeric table is re-read line by line to name the line and what was expected. The columns
    ``skipped`` (a manifest's '_' columns) may hold anything (a ROS export's frame_id), and read as 0.
    """
    import pandas as pd

    path = Path(path)
    text = read_text(path, what)
    # the leading header: '#' lines, blank lines, and at most one line with no number in it, whatever the
    # delimiter (a line with numbers is data the reader must check, not skip: a garbled first row, another
    # delimiter, ISO dates after a header)
    head, pos, named = 0, 0, False
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        ln = text[pos:end]
        if ln.strip() and not ln.lstrip().startswith("#"):
            if named or _has_number(ln, delimiter):
                break
            named = True
        head, pos = head + 1, end + 1
    # the common case, one clean block of rows after the header: read by pandas from a row count; otherwise (comment
    # or blank lines among the rows) each line is classified first (searched in place: the body's copy would be
    # the file's size again)
    clean = all(text.find(c, pos) < 0 for c in ("#", "\n\n", "\r"))
    if clean:
        n_rows = text.count("\n", pos) + (0 if text.endswith("\n") or pos >= len(text) else 1)
        line_no = np.arange(head + 1, head + 1 + n_rows)
        skip = head
    else:
        lines = text.splitlines()
        data = np.array([i >= head and bool(ln.strip()) and not ln.lstrip().startswith("#") for i, ln in enumerate(lines)], bool)
        line_no = np.flatnonzero(data) + 1
        skip = lambda i: not data[i] if i < data.size else False  # noqa: E731
    if line_no.size == 0:
        raise DataFormatError(path, None, f"no data rows (expected {what})")
    sep = r"\s+" if delimiter in (None, " ") else delimiter

    def read(dtype):
        return pd.read_csv(path, header=None, sep=sep, skiprows=skip, engine="c", skip_blank_lines=True,
                           **exact_floats(), **({} if dtype is None else {"dtype": {stamp_col: dtype}}))

    first_col = None
    try:
        if stamp_col is None or per_ns == 1:
            df = read(None if stamp_col is None else np.int64)
            if stamp_col is not None:
                first_col = df.iloc[:, stamp_col].to_numpy(np.int64)
        else:
            # milliseconds or microseconds, whole or decimal (a 400 Hz log: 2.5 ms apart), from their text: pandas'
            # int64 read of '1700000000000000.123' drops the fraction with no error
            df = read(str)
            stamps = df.iloc[:, stamp_col].to_numpy(str)
            first_col, bad = decimal_to_ns(stamps, per_ns)
            if bad.any():                   # '1.7e12': a number, though not a plain decimal (words: the slow reader)
                near = pd.to_numeric(stamps[bad], errors="coerce").astype(float) * per_ns
                if not (np.all(np.isfinite(near)) and np.all(np.abs(near) < 2.0 ** 63)):
                    raise ValueError("a stamp that is no finite int64 of nanoseconds")   # the slow reader names its line
                first_col[bad] = np.round(near).astype(np.int64)
            df[df.columns[stamp_col]] = 0.0
        for c in skipped:                    # whatever they hold ('imu_link': a frame_id was refused as no number)
            if c < df.shape[1]:
                df[df.columns[c]] = 0.0
        if not all(pd.api.types.is_numeric_dtype(d) for d in df.dtypes):
            # a column pandas kept as text: converting it would take what Python's float takes, '9_8.1' as 98.1 (a
            # corrupted-input review); the slow reader names the line
            raise ValueError("a column of text")
        rows = df.to_numpy(float)
        ok = rows.shape == (line_no.size, rows.shape[1]) and rows.shape[1] >= ncols_min and np.isfinite(rows).all()
    except (ValueError, TypeError, OverflowError, IndexError, pd.errors.ParserError):
        ok = False
    if not ok:                               # name the line: the slow reader raises on the first bad row
        lines = text.splitlines()
        masked = "\n".join("#" if i < head else ln for i, ln in enumerate(lines))
        rows, ln = parse_numeric_rows(path, masked, ncols_exact or tuple(range(ncols_min, 64)), what,
                                      delimiter=None if sep == r"\s+" else sep, skipped=skipped)
        if stamp_col is not None:
            t = rows[:, stamp_col]
            bad = np.flatnonzero(t != np.round(t)) if per_ns == 1 else np.array([], int)
            if bad.size:
                raise DataFormatError(path, int(ln[bad[0]]), f"{what}: the stamp must be an integer number of nanoseconds")
            bad = np.flatnonzero(np.abs(t) * per_ns >= 2.0 ** 63)
            if bad.size:
                raise DataFormatError(path, int(ln[bad[0]]), f"{what}: the stamp {t[bad[0]] * per_ns:.6g} ns is beyond any "
                                                             "date (int64 nanoseconds end in 2262): a corrupted stamp")
        raise DataFormatError(path, None, f"{what}: rows of unequal length or an empty field")
    return rows, first_col, line_no


def _columns(entry: dict, kind: str, ctx: ReadContext) -> dict[str, int]:
    cols = entry.get("columns")
    required, optional = NAMES[kind]
    if not (isinstance(cols, list) and cols and all(isinstance(c, str) for c in cols)):
        raise ConfigError(f"{ctx.at(entry, 'columns')}: a csv stream needs 'columns': a list naming each column of the file "
                          f"(needs {', '.join(sorted(required))})")
    named = {c: i for i, c in enumerate(cols) if not c.startswith("_")}
    unknown = set(named) - required - optional
    if unknown:
        raise ConfigError(f"{ctx.at(entry, 'columns')}: csv column {sorted(unknown)[0]!r} is not a {kind} column (known: "
                          f"{', '.join(sorted(required | optional))}; '_' skips a column)")
    repeated = sorted({c for c in cols if not c.startswith("_") and cols.count(c) > 1})
    if repeated:
        raise ConfigError(f"{ctx.at(entry, 'columns')}: csv column {repeated[0]!r} is named twice")
    delim = entry.get("delimiter", ",")
    if delim is not None and not (isinstance(delim, str) and delim):
        raise ConfigError(f"{ctx.at(entry, 'delimiter')}: delimiter must be a non-empty string (',' or ' ' for "
                          f"whitespace), got {delim!r}")
    missing = required - set(named)
    if missing:
        raise ConfigError(f"{ctx.at(entry, 'columns')}: csv {kind} stream needs the columns {', '.join(sorted(missing))}")
    return named


# a header's names for the stamp column, read as 't' when a header is compared with 'columns'
_STAMP_NAMES = frozenset({"t", "time", "timestamp", "stamp", "t_s", "time_s", "timestamp_s", "t_ns", "timestamp_ns"})
# and a unit written after a name ('wx_dps', 'lat_deg', 'std_e_m', as `simulate` writes them)
_UNIT_SUFFIX = r"_(dps|rps|deg|rad|m|mps|mps2|s|ns|us|ms|g)$"


def _check_header(path: Path, entry: dict, kind: str, delimiter: str | None) -> None:
    """A header whose names are this stream's own column names, in other places than ``columns`` puts them, is an
    error naming its line: the header was skipped unread, and a file headed ``t,x,y,z,qw,qx,qy,qz`` read with the
    README's ``qx qy qz qw`` ran at 225 m with exit 0 (a conventions review). The header is the last line above the
    first data row, a ``#`` comment's text included."""
    required, optional = NAMES[kind]
    known = required | optional
    # the last line above the first data row with one field per column, a '#' comment's text included (EuRoC's and
    # TUM's headers are comments; a comment after the header does not hide it, and a comment's sentence, whose words
    # do not fall one per column, is no header: reviews found both)
    above: list[tuple[str, int]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for i, ln in enumerate(fh, 1):
            if i > 1000:
                return
            text = ln.lstrip()
            if text.startswith("#"):
                above.append((text[1:], i))
            elif ln.strip():
                if _has_number(ln, delimiter):
                    break                   # the first data row
                above.append((ln, i))

    def split(line):
        return line.split() if delimiter in (None, " ") else line.rstrip("\r\n").split(delimiter)

    header, no = next(((h, i) for h, i in reversed(above) if len(split(h)) == len(entry["columns"])), (None, 0))
    if header is None:
        return
    fields = split(header)
    names = [f.strip().strip("\"'").strip().lower() for f in fields]
    names = ["t" if n in _STAMP_NAMES else re.sub(_UNIT_SUFFIX, "", n) for n in names]
    # 'q_w', 'v_x': the names with their underscore (EuRoC's way), where that is what makes them known
    names = [n.replace("_", "") if n not in known and n.replace("_", "") in known else n for n in names]
    for i, (h, c) in enumerate(zip(names, entry["columns"])):
        if h in known and not c.startswith("_") and h != c:
            raise DataFormatError(path, no, f"its header names column {i + 1} {fields[i].strip()!r} where the manifest's "
                                            f"'columns' says {c!r} ({', '.join(entry['columns'])}): give 'columns' in "
                                            "the file's order")


def _choice(entry: dict, key: str, table: dict, default: str, ctx: ReadContext):
    v = entry.get(key, default)
    if not isinstance(v, str) or v not in table:       # (a list or mapping: unhashable, a traceback once)
        raise ConfigError(f"{ctx.at(entry, key)}: {key} must be one of {', '.join(table)}, got {v!r}")
    return table[v]


def _skipped(entry: dict) -> tuple[int, ...]:
    """The indices of a manifest's '_' columns (skipped: they may hold text)."""
    return tuple(i for i, c in enumerate(entry["columns"]) if c.startswith("_"))


def _table(entry: dict, kind: str, ctx: ReadContext, what: str):
    named = _columns(entry, kind, ctx)
    per_ns = _choice(entry, "time_unit", TIME_UNITS, "s", ctx)
    path = ctx.path(entry)
    rows, ns, lines = load_table(path, f"{what[:-1]}: {' '.join(entry['columns'])})", len(entry["columns"]),
                                 entry.get("delimiter", ","), stamp_col=None if per_ns is None else named["t"],
                                 ncols_exact=len(entry["columns"]), per_ns=per_ns or 1, skipped=_skipped(entry))
    if rows.shape[1] != len(entry["columns"]):
        raise DataFormatError(path, int(lines[0]), f"{what}: expected {len(entry['columns'])} columns (as 'columns' names), "
                                                   f"got {rows.shape[1]}")
    if int(lines[0]) > 1:                   # something above the first row: a header, perhaps
        _check_header(path, entry, kind, entry.get("delimiter", ","))
    t = rows[:, named["t"]] if per_ns is None else ns_to_s(ns)
    return named, rows, t, lines, str(path)


def read_imu(entry: dict, ctx: ReadContext) -> ImuSeries:
    named, rows, t, lines, src = _table(entry, "imu", ctx, "IMU CSV (columns)")
    g = _choice(entry, "gyro_unit", GYRO_UNITS, "rad/s", ctx)
    a = _choice(entry, "accel_unit", ACCEL_UNITS, "m/s^2", ctx)
    f = rows[:, [named["ax"], named["ay"], named["az"]]] * a
    w = rows[:, [named["wx"], named["wy"], named["wz"]]] * g
    return ImuSeries(t_s=t, f_b_mps2=f, w_b_rps=w, source=src, lines=lines)


def read_gnss(entry: dict, ctx: ReadContext) -> GnssSeries:
    named, rows, t, lines, src = _table(entry, "gnss", ctx, "GNSS CSV (columns)")
    if {"lat", "lon", "alt"} <= set(named):
        if ctx.origin is None:
            raise ConfigError(f"{ctx.at(entry)}: GNSS in geodetic coordinates needs a geodetic_origin")
        p = geodetic_to_enu(rows[:, named["lat"]], rows[:, named["lon"]], rows[:, named["alt"]], *ctx.origin,
                            source=src, lines=lines)
    elif {"x", "y", "z"} <= set(named):
        p = rows[:, [named["x"], named["y"], named["z"]]]
    else:
        raise ConfigError(f"{ctx.at(entry, 'columns')}: a csv GNSS stream needs columns lat, lon, alt (geodetic) or x, y, z (local ENU m)")
    # checked where the columns give the std too (std_m: -1 passed unseen there; a review)
    given = std_m(entry, ctx) if "std_m" in entry else None
    if {"std_e", "std_n", "std_u"} <= set(named):
        std = rows[:, [named["std_e"], named["std_n"], named["std_u"]]]
    elif "std" in named:
        std = np.repeat(rows[:, [named["std"]]], 3, axis=1)
    else:
        std = np.tile(given if given is not None else std_m(entry, ctx), (t.size, 1))
    return GnssSeries(t_s=t, p_w_m=p, std_w_m=std, source=src, lines=lines)


def first_fix(entry: dict, ctx: ReadContext):
    """The first fix of a geodetic GNSS CSV (a geodetic origin), or None for local coordinates."""
    named = _columns(entry, "gnss", ctx)
    if not {"lat", "lon", "alt"} <= set(named):
        return None
    rows, _, _ = load_table(ctx.path(entry), "GNSS CSV", len(entry["columns"]), entry.get("delimiter", ","),
                            skipped=_skipped(entry))
    from .gnss_csv import first_valid

    return first_valid(rows[:, [named[k] for k in ("lat", "lon", "alt")]])


def std_m(entry: dict, ctx: ReadContext, default: float | None = None) -> np.ndarray:
    """The entry's ``std_m`` (a number or three, metres; ``default`` when absent) as a (3,) array."""
    std = entry.get("std_m", default)
    if std is None:
        raise ConfigError(f"{ctx.at(entry)}: the GNSS stream has no std columns: give 'std_m' (1-sigma, m)")
    if isinstance(std, (int, float)) and not isinstance(std, bool):
        std = [std] * 3
    if not (isinstance(std, list) and len(std) == 3 and all(isinstance(v, (int, float)) and v > 0 for v in std)):
        raise ConfigError(f"{ctx.at(entry, 'std_m')}: gnss 'std_m' must be a positive number or 3 positive numbers (m), got {entry.get('std_m')!r}")
    return np.asarray(std, float)


def read_poses(entry: dict, ctx: ReadContext) -> PoseSeries:
    named, rows, t, lines, src = _table(entry, "poses", ctx, "pose CSV (columns)")
    v = rows[:, [named["vx"], named["vy"], named["vz"]]] if {"vx", "vy", "vz"} <= set(named) else None
    return PoseSeries(t_s=t, p_w_m=rows[:, [named["x"], named["y"], named["z"]]],
                      q_wb_xyzw=rows[:, [named["qx"], named["qy"], named["qz"], named["qw"]]], v_w_mps=v,
                      source=src, lines=lines)


def read_speed(entry: dict, ctx: ReadContext) -> SpeedSeries:
    named, rows, t, lines, src = _table(entry, "odometer", ctx, "speed CSV (columns)")
    return SpeedSeries(t_s=t, v_mps=rows[:, named["v"]], source=src, lines=lines)
