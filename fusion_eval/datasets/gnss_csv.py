"""GNSS fixes as CSV with geodetic coordinates and per-axis 1-sigma:

    t_s,lat_deg,lon_deg,alt_m,std_e_m,std_n_m,std_u_m

one header line, then one fix per line (``#`` comments allowed). Converted to local ENU with pymap3d.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geo import geodetic_to_enu
from ..types import GnssSeries
from ._text import parse_numeric_rows, read_text

HEADER = "t_s,lat_deg,lon_deg,alt_m,std_e_m,std_n_m,std_u_m"


def _rows(path: Path):
    text = read_text(path, f"GNSS CSV '{HEADER}'")
    lines = text.splitlines()
    if lines and lines[0].strip().startswith("t_s"):
        lines[0] = "#" + lines[0]   # the header: skipped, line numbers kept
    return parse_numeric_rows(path, "\n".join(lines), 7, f"GNSS CSV ({HEADER})", delimiter=",")


def first_fix(path: Path) -> tuple[float, float, float]:
    """The first fix (lat, lon, alt): a geodetic origin, or the fixes' check against another's."""
    rows, _ = _rows(Path(path))
    return first_valid(rows[:, 1:4])


def first_valid(lla: np.ndarray) -> tuple[float, float, float]:
    """The first fix that is one: finite, and not a receiver's no-fix placeholder at lat = lon = 0 (a CSV starting
    with one was refused as 'in radians?' by the origin check; a diff review); the first row where none is."""
    ok = np.all(np.isfinite(lla), axis=1) & ~((lla[:, 0] == 0.0) & (lla[:, 1] == 0.0))
    i = int(np.argmax(ok)) if ok.any() else 0
    return tuple(float(v) for v in lla[i])


def read_gnss_csv(path: Path, origin: tuple[float, float, float]) -> GnssSeries:
    path = Path(path)
    rows, ln = _rows(path)
    return GnssSeries(t_s=rows[:, 0], p_w_m=geodetic_to_enu(rows[:, 1], rows[:, 2], rows[:, 3], *origin, source=str(path), lines=ln),
                      std_w_m=rows[:, 4:7], source=str(path), lines=ln)


def format_gnss_csv(t_s: np.ndarray, lla: np.ndarray, std_m: np.ndarray) -> str:
    out = [HEADER]
    for t, (la, lo, al), (se, sn, su) in zip(t_s, lla, std_m):
        out.append(f"{t:.9f},{la:.10f},{lo:.10f},{al:.4f},{se:.4f},{sn:.4f},{su:.4f}")
    return "\n".join(out) + "\n"
