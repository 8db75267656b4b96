"""Reader of KITTI raw OXTS packets (``oxts/timestamps.txt`` + ``oxts/data/NNNNNNNNNN.txt``).

Each packet holds 30 values (see KITTI's ``dataformat.txt``): lat lon alt [deg deg m];
roll pitch yaw [rad] (yaw 0 = east, counter-clockwise positive); vn ve [m/s]; vf vl vu [m/s];
ax ay az [m/s^2] (body: x forward, y left, z up; specific force, az ~ +9.8 at rest); af al au;
wx wy wz [rad/s] (body); wf wl wu; pos_accuracy [m]; vel_accuracy [m/s]; navstat; numsats;
posmode; velmode; orimode.

KITTI filled in some packets (a linear ramp over a gap). They are recognisable because their
five status fields are written as floats (``4.00000000000000``) and their modes are -1; this
reader flags them rather than dropping them, and the caller decides.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataFormatError
from ..geo import enu_rotation, geodetic_to_enu
from ..so3 import euler_rpy_to_matrix, matrix_to_quat_xyzw
from ..types import GnssSeries, ImuSeries, PoseSeries, SpeedSeries
from ._text import check_file, exact_floats, is_float, read_text, strict_float

N_FIELDS = 30
FIELDS = ("lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu", "ax", "ay", "az", "af", "al", "au",
          "wx", "wy", "wz", "wf", "wl", "wu", "pos_accuracy", "vel_accuracy", "navstat", "numsats", "posmode", "velmode",
          "orimode")
FIELD = {name: i for i, name in enumerate(FIELDS)}
LAT, LON, ALT, ROLL, PITCH, YAW = (FIELD[k] for k in ("lat", "lon", "alt", "roll", "pitch", "yaw"))
VN, VE = FIELD["vn"], FIELD["ve"]
VF, VL, VU = FIELD["vf"], FIELD["vl"], FIELD["vu"]
AX, AY, AZ = FIELD["ax"], FIELD["ay"], FIELD["az"]
WX, WY, WZ = FIELD["wx"], FIELD["wy"], FIELD["wz"]
POS_ACC, VEL_ACC = FIELD["pos_accuracy"], FIELD["vel_accuracy"]
POSMODE, VELMODE, ORIMODE = FIELD["posmode"], FIELD["velmode"], FIELD["orimode"]

_STAMP = re.compile(r"^(\d{4}-\d{2}-\d{2}) (\d{2}:\d{2}:\d{2})(?:\.(\d{1,9}))?$")


@dataclass(frozen=True)
class OxtsPackets:
    """All packets of one drive: ``values`` ``(N, 30)``, stamps ``t_s`` (POSIX s), ``filled`` flags."""

    t_s: np.ndarray
    values: np.ndarray
    filled: np.ndarray
    stamps_path: Path
    packet_paths: tuple[Path, ...]


def parse_kitti_stamp(s: str) -> float | None:
    """POSIX seconds of a KITTI ``YYYY-MM-DD HH:MM:SS.nnnnnnnnn`` stamp read as UTC, or None if malformed.

    The KITTI clock is local time without a zone; reading it as UTC keeps the numbers unchanged and
    only matters when comparing against another clock, which a stream time offset handles.
    """
    m = _STAMP.match(s.strip())
    if not m:
        return None
    date, hms, frac = m.groups()
    try:
        whole = np.datetime64(f"{date}T{hms}", "s").astype(np.int64)
    except ValueError:
        return None
    ns = int((frac or "0").ljust(9, "0"))
    return (int(whole) * 1_000_000_000 + ns) / 1_000_000_000     # correctly rounded (see _text.ns_to_s)


CSV_NAME = "packets.csv"
CSV_HEADER = "t_s," + ",".join(FIELDS)


def find_oxts_dir(path: Path) -> Path:
    """Accept a drive folder (holding ``oxts/``) or the ``oxts`` folder itself."""
    path = Path(path)
    for d in (path / "oxts", path):
        if (d / "timestamps.txt").exists() or (d / CSV_NAME).exists():
            return d
    raise DataFormatError(path, None, "expected a KITTI raw drive folder with oxts/timestamps.txt and oxts/data/*.txt "
                                      f"(or oxts/{CSV_NAME})")


def read_oxts(path: Path) -> OxtsPackets:
    """Read and validate every packet of a KITTI raw OXTS folder."""
    oxts = find_oxts_dir(path)
    if (oxts / CSV_NAME).exists():
        return _read_packets_csv(oxts / CSV_NAME)
    stamps_path = oxts / "timestamps.txt"
    text = read_text(stamps_path, "KITTI timestamps 'YYYY-MM-DD HH:MM:SS.nnnnnnnnn', one per line")
    lines = [ln for ln in text.splitlines()]
    while lines and not lines[-1].strip():
        lines.pop()
    t = np.empty(len(lines))
    for i, ln in enumerate(lines):
        v = parse_kitti_stamp(ln)
        if v is None:
            raise DataFormatError(stamps_path, i + 1, f"expected a timestamp 'YYYY-MM-DD HH:MM:SS.nnnnnnnnn', got {ln.strip()!r}")
        t[i] = v
    if t.size == 0:
        raise DataFormatError(stamps_path, None, "no timestamps")
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        kind = "duplicate" if d[bad[0]] == 0 else "decreasing"
        raise DataFormatError(stamps_path, i + 1, f"timestamps must strictly increase ({kind} timestamp)")

    data_dir = oxts / "data"
    if not data_dir.is_dir():
        raise DataFormatError(data_dir, None, "folder not found (expected one OXTS packet file per timestamp)")
    # names as strings, sorted, and one open per packet: pathlib's glob and sorting and read_text's two stats per
    # file were most of the read (kitti-00's 4,544 packets: 0.41 -> 0.17 s)
    names = sorted(n for n in os.listdir(data_dir) if n.endswith(".txt"))
    if len(names) != t.size:
        have = set(names)
        missing = next((f"{i:010d}.txt" for i in range(t.size) if f"{i:010d}.txt" not in have), None)
        extra = [n for n in names if not (n[:-4].isdigit() and int(n[:-4]) < t.size)]    # notes.txt, 0000004544.txt
        what = (f": {missing} is missing" if missing else f": {len(names) - t.size} more than the stamps"
                + (f" ({', '.join(extra[:3])}{', ...' if len(extra) > 3 else ''})" if extra else ""))
        raise DataFormatError(data_dir, None, f"expected {t.size} packet files (one per line of timestamps.txt), found "
                                              f"{len(names)}{what}")
    packet_paths = tuple(data_dir / n for n in names)
    values = np.empty((t.size, N_FIELDS))
    filled = np.zeros(t.size, bool)
    for i, name in enumerate(names):
        if name != f"{i:010d}.txt":
            raise DataFormatError(packet_paths[i], None, f"expected packet file {i:010d}.txt at position {i} (packets must "
                                                         "be numbered consecutively from 0)")
        parts, plain = _packet_tokens(packet_paths[i])
        if len(parts) != N_FIELDS:
            twice = len(parts) % N_FIELDS == 0 and len(parts) > N_FIELDS
            raise DataFormatError(packet_paths[i], 1, f"expected {N_FIELDS} values per OXTS packet, got {len(parts)}"
                                                      + (f" ({len(parts) // N_FIELDS} packets in one file?)" if twice else ""))
        try:
            # Python's float where the bytes are plain (strict_float's check, on the file's bytes at once: per value
            # it was a tenth of the read)
            row = [float(x) for x in parts] if plain else [strict_float(x) for x in parts]
        except ValueError:
            bad_tok = next(x for x in parts if not is_float(x))
            raise DataFormatError(packet_paths[i], 1, f"expected a number, got {bad_tok!r}") from None
        if not all(map(math.isfinite, row)):          # here, not after the loop: the first bad packet is named
            raise DataFormatError(packet_paths[i], 1, "OXTS values must be finite numbers (found NaN or inf)")
        values[i] = row
        # KITTI's filled packets print the integer status fields as floats and set the modes to -1.
        filled[i] = any("." in x for x in parts[25:])
    filled |= values[:, POSMODE:ORIMODE + 1].min(axis=1) < 0
    _check_plausible(values, lambda i: (packet_paths[i], 1))
    return OxtsPackets(t_s=t, values=values, filled=filled, stamps_path=stamps_path, packet_paths=packet_paths)


def _packet_tokens(path: Path) -> tuple[list[str], bool]:
    """The whitespace-separated tokens of one packet file, and whether its bytes are plain (ASCII, no '_'); a file
    that cannot be opened or decoded is read again by :func:`read_text` for its one-line error."""
    try:
        with open(path, "rb") as f:
            raw = f.read()
        # a byte-order mark dropped, as read_text drops it
        return raw.decode("utf-8-sig").split(), raw.isascii() and b"_" not in raw
    except (OSError, UnicodeDecodeError):
        return read_text(path, "one OXTS packet of 30 values").split(), False


def _read_packets_csv(path: Path) -> OxtsPackets:
    """All packets in one CSV (``t_s`` then the 30 OXTS fields): the compact layout for high-rate
    simulated drives, read with pandas' C parser instead of one file per packet."""
    import pandas as pd

    check_file(path, "a packets.csv of OXTS packets")
    try:
        # round_trip: Python's correctly rounded parse (pandas' default fast parse can be off by one ulp)
        df = pd.read_csv(path, dtype=float, engine="c", **exact_floats())
    except (ValueError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        _locate_csv_error(path)              # pandas names no line (a wrong delimiter: the whole line as one value)
        raise DataFormatError(path, None, f"expected a CSV '{CSV_HEADER[:40]}...' of numbers ({exc})") from None
    if list(df.columns) != CSV_HEADER.split(","):
        raise DataFormatError(path, 1, f"expected the header '{CSV_HEADER}'")
    a = df.to_numpy()
    if a.shape[0] == 0:                  # (it was reported as 'every packet filled in')
        raise DataFormatError(path, 2, "no packets: the file holds only its header")
    bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if bad.size:
        raise DataFormatError(path, _line_of_row(path, int(bad[0])),
                              "OXTS values must be finite numbers (found NaN, inf or an empty field)")
    t = a[:, 0]
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.flatnonzero(d <= 0)[0]) + 1
        raise DataFormatError(path, _line_of_row(path, i), "timestamps must strictly increase")
    vals = a[:, 1:]
    filled = vals[:, POSMODE:ORIMODE + 1].min(axis=1) < 0
    _check_plausible(vals, lambda i: (path, _line_of_row(path, i)))
    return OxtsPackets(t_s=t, values=vals, filled=filled, stamps_path=path, packet_paths=(path,))


def _line_of_row(path: Path, i: int) -> int:
    """The file line of data row ``i`` of ``packets.csv`` (pandas skips blank lines, so row + 2 was off by one per
    blank line before it); read only when a row is refused."""
    n = -1
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for line_no, line in enumerate(fh, 1):
            if line_no == 1 or not line.strip():
                continue
            n += 1
            if n == i:
                return line_no
    return i + 2


def _locate_csv_error(path: Path) -> None:
    """The line of ``packets.csv`` that pandas could not read, as a :class:`DataFormatError`: its header, or the first
    row that is not 31 numbers (returns where the line-by-line reading finds nothing wrong)."""
    from ._text import parse_numeric_rows

    text = read_text(path, "a packets.csv")
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise DataFormatError(path, 1, f"expected the header '{CSV_HEADER[:40]}...', got an empty line (an empty file?)")
    if lines[0].strip() != CSV_HEADER:
        raise DataFormatError(path, 1, f"expected the header '{CSV_HEADER[:40]}...' (comma-separated)")
    for n, line in enumerate(lines[1:], 2):
        if line.lstrip().startswith("#"):
            raise DataFormatError(path, n, "expected a row of 31 numbers, got a comment line (packets.csv has none)")
    parse_numeric_rows(path, "\n" + "\n".join(lines[1:]), len(CSV_HEADER.split(",")),
                       "OXTS packets.csv (t_s and the 30 OXTS fields)", delimiter=",")


def _check_plausible(values: np.ndarray, locate) -> None:
    """Refuse packets whose position or IMU values no vehicle produces (a corrupted packet would otherwise become a
    plausible-looking estimate); ``locate(i)`` gives the file and line of packet ``i``."""
    from ..geo import check_geodetic
    from ..types import IMU_MAX_RATE_RPS, IMU_MAX_SPECIFIC_FORCE_MPS2

    try:
        check_geodetic(values[:, LAT], values[:, LON], values[:, ALT], "<packets>", np.arange(values.shape[0]), "OXTS")
    except DataFormatError as exc:
        f, ln = locate(exc.line)
        raise DataFormatError(f, ln, exc.expected) from None
    for name, cols, lim, unit in (("angular rate", slice(WX, WZ + 1), IMU_MAX_RATE_RPS, "rad/s"),
                                  ("acceleration", slice(AX, AZ + 1), IMU_MAX_SPECIFIC_FORCE_MPS2, "m/s^2")):
        bad = np.flatnonzero(np.abs(values[:, cols]).max(axis=1) > lim)
        if bad.size:
            f, ln = locate(int(bad[0]))
            v = values[bad[0], cols]
            raise DataFormatError(f, ln, f"OXTS {name} {v.tolist()} {unit} exceeds {lim:g} {unit} (no vehicle IMU measures "
                                         "that: a corrupted packet)")
    # the attitude in radians within its range (yaw in degrees ran to a fused APE of 46.6 m with exit 0: the ground
    # truth's heading, and so the start and the lidar's anchoring, turned by up to 180 rad)
    # (2 pi for roll and yaw: a converter's heading in 0..2 pi is an angle in radians; 1e-3 for a value written to 4
    # decimals, 3.1416)
    for name, col, lim in (("roll", ROLL, 2 * np.pi), ("pitch", PITCH, np.pi / 2), ("yaw", YAW, 2 * np.pi)):
        bad = np.flatnonzero(np.abs(values[:, col]) > lim + 1e-3)
        if bad.size:
            f, ln = locate(int(bad[0]))
            raise DataFormatError(f, ln, f"OXTS {name} {values[bad[0], col]:g} rad is outside +/-{lim:.4g} rad (an angle in "
                                         "degrees?)")


def imu_from_oxts(pk: OxtsPackets) -> ImuSeries:
    """Specific force (ax ay az) and angular rate (wx wy wz) in the OXTS body frame (x fwd, y left, z up)."""
    v = pk.values
    return ImuSeries(t_s=pk.t_s, f_b_mps2=v[:, AX:AZ + 1], w_b_rps=v[:, WX:WZ + 1], filled=pk.filled,
                     source=str(pk.stamps_path), lines=np.arange(1, pk.t_s.size + 1))


def first_valid_fix(pk: OxtsPackets) -> tuple[float, float, float]:
    """Latitude, longitude, altitude of the first packet that was not filled in (default ENU origin)."""
    ok = np.flatnonzero(~pk.filled)
    if ok.size == 0:
        raise DataFormatError(pk.stamps_path, None, "every OXTS packet is a filled-in packet; no valid fix")
    v = pk.values[ok[0]]
    return float(v[LAT]), float(v[LON]), float(v[ALT])


def positions_enu(pk: OxtsPackets, origin: tuple[float, float, float]) -> np.ndarray:
    v = pk.values
    return geodetic_to_enu(v[:, LAT], v[:, LON], v[:, ALT], *origin)


def accuracy(pk: OxtsPackets, field: int) -> np.ndarray:
    """A reported accuracy column (``pos_accuracy``, ``vel_accuracy``), 1-sigma; a non-positive one (seen in
    filled packets) is replaced by the median of the valid ones."""
    acc = pk.values[:, field].copy()
    good = acc > 0
    acc[~good] = float(np.median(acc[good])) if good.any() else 1.0
    return acc


def gnss_from_oxts(pk: OxtsPackets, origin: tuple[float, float, float]) -> GnssSeries:
    """GNSS fixes in local ENU about ``origin``; 1-sigma from ``pos_accuracy`` on each axis.

    OXTS gives no per-axis accuracy, so the same sigma is used for East, North and Up.
    """
    acc = accuracy(pk, POS_ACC)
    return GnssSeries(t_s=pk.t_s, p_w_m=positions_enu(pk, origin), std_w_m=np.repeat(acc[:, None], 3, axis=1),
                      filled=pk.filled, source=str(pk.stamps_path), lines=np.arange(1, pk.t_s.size + 1))


def speed_from_oxts(pk: OxtsPackets) -> SpeedSeries:
    """Forward speed ``vf`` as an odometer (filled-in packets dropped)."""
    ok = ~pk.filled
    return SpeedSeries(t_s=pk.t_s[ok], v_mps=pk.values[ok, VF], source=str(pk.stamps_path),
                       lines=np.arange(1, pk.t_s.size + 1)[ok])


def poses_from_oxts(pk: OxtsPackets, origin: tuple[float, float, float]) -> PoseSeries:
    """Ground-truth IMU poses: ENU position, attitude from roll/pitch/yaw, world velocity R_wb [vf vl vu]. The OXTS
    attitude is of the local level frame at each packet; it is turned into the origin's ENU frame, the positions' (a
    stress test found the simulator's, the same, left in the local frame: 0.06 deg of yaw 6.7 km from the origin)."""
    v = pk.values
    R = np.einsum("nij,njk->nik", enu_rotation(v[:, LAT], v[:, LON], origin[0], origin[1]),
                  euler_rpy_to_matrix(v[:, ROLL], v[:, PITCH], v[:, YAW]))
    v_w = np.einsum("nij,nj->ni", R, v[:, VF:VU + 1])
    return PoseSeries(t_s=pk.t_s, p_w_m=positions_enu(pk, origin), q_wb_xyzw=matrix_to_quat_xyzw(R), v_w_mps=v_w,
                      filled=pk.filled, source=str(pk.stamps_path), lines=np.arange(1, pk.t_s.size + 1))
