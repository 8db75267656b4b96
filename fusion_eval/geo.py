"""Geodetic <-> local ENU conversion (pymap3d, WGS84) and normal gravity.

The world frame of fusion-eval is a local East-North-Up tangent frame about a geodetic origin
(by default the first valid fix of the drive). Heights are ellipsoidal as given by the receiver.
"""

from __future__ import annotations

import numpy as np
import pymap3d


# Plausible geodetic coordinates of a ground vehicle's (or drone's) fix: beyond them a value is a corruption, not
# a place (an altitude of 1e12 m also stalls pymap3d's iteration).
LAT_RANGE_DEG, LON_RANGE_DEG, ALT_RANGE_M = (-90.0, 90.0), (-180.0, 360.0), (-1000.0, 100_000.0)


def check_geodetic(lat_deg, lon_deg, alt_m, source: str, lines=None, what: str = "fix") -> None:
    """Refuse latitudes, longitudes and altitudes outside :data:`LAT_RANGE_DEG` etc., naming the line and value."""
    from .errors import DataFormatError

    for name, v, (lo, hi), unit in (("latitude", lat_deg, LAT_RANGE_DEG, "deg"), ("longitude", lon_deg, LON_RANGE_DEG, "deg"),
                                    ("altitude", alt_m, ALT_RANGE_M, "m")):
        v = np.atleast_1d(np.asarray(v, float))
        bad = np.flatnonzero(~((v >= lo) & (v <= hi)))
        if bad.size:
            i = int(bad[0])
            line = None if lines is None or len(lines) == 0 else int(np.atleast_1d(lines)[min(i, len(lines) - 1)])
            raise DataFormatError(source, line, f"{what} {name} {float(v[i])!r} {unit} is outside [{lo:g}, {hi:g}] {unit}")


# A local ENU frame is a drive's: its origin farther than this from the data is a wrong origin (lat/lon swapped, a
# sign lost), whose frame would tilt the drive's gravity by degrees
MAX_ORIGIN_DISTANCE_M = 200e3


def great_circle_m(a_deg, b_deg) -> float:
    """The great-circle distance between two (lat, lon) points in degrees, on a sphere of the Earth's mean radius
    (haversine): good to 0.5 %, enough to tell a drive's neighbourhood from another continent."""
    la1, lo1, la2, lo2 = np.radians([a_deg[0], a_deg[1], b_deg[0], b_deg[1]])
    h = np.sin((la2 - la1) / 2) ** 2 + np.cos(la1) * np.cos(la2) * np.sin((lo2 - lo1) / 2) ** 2
    return float(2 * 6_371_008.8 * np.arcsin(min(1.0, np.sqrt(h))))


def geodetic_to_enu(lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray,
                    origin_lat_deg: float, origin_lon_deg: float, origin_alt_m: float, source: str = "<geodetic>",
                    lines=None) -> np.ndarray:
    """East/North/Up metres ``(N, 3)`` of WGS84 points about an origin (exact, not a flat-earth approximation).
    Points and origin outside the plausible ranges are refused (:func:`check_geodetic`), naming ``source``."""
    check_geodetic(origin_lat_deg, origin_lon_deg, origin_alt_m, f"{source} (the geodetic origin)", what="origin")
    check_geodetic(lat_deg, lon_deg, alt_m, source, lines)
    e, n, u = pymap3d.geodetic2enu(np.asarray(lat_deg), np.asarray(lon_deg), np.asarray(alt_m),
                                   origin_lat_deg, origin_lon_deg, origin_alt_m)
    return np.column_stack([e, n, u])


def enu_rotation(lat_deg: np.ndarray, lon_deg: np.ndarray, origin_lat_deg: float, origin_lon_deg: float) -> np.ndarray:
    """``(N, 3, 3)`` rotations from the local ENU frame at each point into the origin's ENU frame (each local axis
    taken to ECEF and back by pymap3d's vector rotations). An attitude given in the local level frame where it was
    measured (KITTI's OXTS roll, pitch, yaw; an INS's heading) is turned by this into the world frame the positions are
    in: over a few km the two differ by about distance / 6,400 km in tilt and by the meridians' convergence, longitude
    difference x sin(latitude), in yaw (0.5 mrad 3 km east at 49 deg N)."""
    lat, lon = (np.atleast_1d(np.asarray(a, float)) for a in (lat_deg, lon_deg))
    R = np.empty((lat.size, 3, 3))
    for axis in range(3):
        e = np.zeros((3, lat.size))
        e[axis] = 1.0
        R[:, :, axis] = np.column_stack(pymap3d.uvw2enu(*pymap3d.enu2uvw(*e, lat, lon), origin_lat_deg, origin_lon_deg))
    return R


def normal_gravity_mps2(lat_deg: float, alt_m: float) -> float:
    """WGS84 normal gravity (Somigliana's formula) with the free-air correction, in m/s^2.

    Used as the default gravity magnitude so that the filter needs no tuned constant: at the
    KITTI drives (49.0 deg N, 116 m) it gives 9.8094 m/s^2.
    """
    s2 = np.sin(np.radians(lat_deg)) ** 2
    g0 = 9.7803253359 * (1.0 + 0.00193185265241 * s2) / np.sqrt(1.0 - 0.00669437999013 * s2)
    return float(g0 - 3.086e-6 * alt_m)
