"""Reader and writer of the lidar/radar measurement file, one tab-separated measurement per line:

    L  x  y  timestamp_us  x_gt  y_gt  vx_gt  vy_gt  [yaw_gt  yawrate_gt]
    R  rho  phi  rho_dot  timestamp_us  x_gt  y_gt  vx_gt  vy_gt  [yaw_gt  yawrate_gt]

(metres, radians, m/s; timestamps in microseconds, non-decreasing).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..datasets._text import is_float, read_text
from ..errors import DataFormatError

LIDAR, RADAR = "L", "R"


@dataclass(frozen=True)
class Measurements:
    """``kind`` (N,) of 'L'/'R'; ``z`` (N, 3) (lidar uses the first two); ``t_us`` (N,) int64; ``gt`` (N, 4)
    [x, y, vx, vy]; ``lines`` (N,) 1-based line numbers."""

    kind: np.ndarray
    z: np.ndarray
    t_us: np.ndarray
    gt: np.ndarray
    lines: np.ndarray
    source: str


def read_measurements(path: Path) -> Measurements:
    path = Path(path)
    text = read_text(path, "lidar/radar measurements, one tab-separated line each")
    kinds, zs, ts, gts, lines = [], [], [], [], []
    prev_t = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split("\t") if "\t" in s else s.split()
        k = parts[0]
        if k == LIDAR:
            n_meas, allowed = 2, (8, 10)
        elif k == RADAR:
            n_meas, allowed = 3, (9, 11)
        else:
            raise DataFormatError(path, lineno, f"expected a line starting with 'L' (lidar) or 'R' (radar), got {k!r}")
        if len(parts) not in allowed:
            raise DataFormatError(path, lineno, f"a {'lidar' if k == LIDAR else 'radar'} line must have "
                                                f"{' or '.join(str(a) for a in allowed)} fields, got {len(parts)}")
        try:
            vals = [float(x) for x in parts[1:]]
        except ValueError:
            bad = next(x for x in parts[1:] if not is_float(x))
            raise DataFormatError(path, lineno, f"expected a number, got {bad!r}") from None
        if not np.all(np.isfinite(vals)):
            raise DataFormatError(path, lineno, "values must be finite numbers (found NaN or inf)")
        meas = vals[:n_meas] + vals[n_meas + 1:]
        if max(abs(v) for v in meas) > 1e7:
            raise DataFormatError(path, lineno, "a measurement or ground-truth value above 1e7 (m, rad, m/s) is not plausible")
        z = vals[:n_meas]
        t = vals[n_meas]
        if t != int(t) or t < 0 or t > MAX_T_US:
            raise DataFormatError(path, lineno, f"timestamp must be a non-negative integer of microseconds (at most "
                                                f"{MAX_T_US:.0e}, the year 2286), got {parts[n_meas + 1]!r}")
        t = int(t)
        if prev_t is not None and t < prev_t:
            raise DataFormatError(path, lineno, f"timestamps must not decrease ({t} us after {prev_t} us)")
        if k == RADAR and z[0] < 0:
            raise DataFormatError(path, lineno, f"radar range rho must be >= 0, got {z[0]}")
        if k == RADAR and abs(z[1]) > 2 * np.pi:
            # any radian convention ([-pi, pi], [0, 2 pi)) stays within 2 pi; beyond it the bearing is in degrees
            raise DataFormatError(path, lineno, f"radar bearing phi must be an angle in radians (within +/-2 pi), got "
                                                f"{z[1]} (degrees?)")
        prev_t = t
        kinds.append(k)
        zs.append(z + [0.0] * (3 - n_meas))
        ts.append(t)
        gts.append(vals[n_meas + 1:n_meas + 5])
        lines.append(lineno)
    if not kinds:
        raise DataFormatError(path, None, "no measurement lines")
    return Measurements(kind=np.array(kinds), z=np.array(zs), t_us=np.array(ts, dtype=np.int64), gt=np.array(gts),
                        lines=np.array(lines), source=str(path))


MAX_T_US = 1e16     # POSIX microseconds until 2286; beyond, a corrupted stamp (and int64 overflows at 9.2e18)


def format_line(kind: str, z, t_us: int, gt, yaw: float, yawrate: float) -> str:
    zs = "\t".join(f"{v:.6e}" for v in z)
    g = "\t".join(f"{v:.6e}" for v in gt)
    return f"{kind}\t{zs}\t{t_us}\t{g}\t{yaw:.6e}\t{yawrate:.6e}"
