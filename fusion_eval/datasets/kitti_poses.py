"""Reader of KITTI odometry pose files, their times and the KITTI calibration files.

A pose file has 12 values per line, the row-major 3x4 ``[R | t]`` of ``T_c0_ci``: the pose of the
sensor frame at frame i in the frame of frame 0 (for KITTI odometry, the cam0 frame: x right,
y down, z forward). Calibration files hold ``key: v1 v2 ...`` lines.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataFormatError
from ._text import parse_numeric_rows, read_text


# KITTI's files hold rotations to ~1e-6 (the calibration's 6 digits); beyond 1e-3 a block is not a rotation
ROTATION_TOL = 1e-3


def read_kitti_poses(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``(N, 4, 4)`` and the 1-based line of each, from a KITTI pose file."""
    path = Path(path)
    rows, lines = parse_numeric_rows(path, read_text(path, "KITTI poses, 12 values per line"), 12, "KITTI pose file")
    T = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    T[:, :3, :] = rows.reshape(-1, 3, 4)
    R = T[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero(err > ROTATION_TOL)
    if bad.size:
        raise DataFormatError(path, int(lines[bad[0]]), f"the 3x3 block of a KITTI pose must be a rotation (R^T R = I to "
                                                        f"{ROTATION_TOL:g}), off by {err[bad[0]]:.3g}")
    det = np.linalg.det(R)
    bad = np.flatnonzero(det < 0)
    if bad.size:
        raise DataFormatError(path, int(lines[bad[0]]), f"the 3x3 block of a KITTI pose must be a rotation (det +1), got a "
                                                        f"reflection (det {det[bad[0]]:.3f})")
    return T, lines


def read_times(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """One time in seconds per line (KITTI odometry ``times.txt``)."""
    path = Path(path)
    rows, lines = parse_numeric_rows(path, read_text(path, "one time in seconds per line"), 1, "times file")
    t = rows[:, 0]
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        raise DataFormatError(path, int(lines[bad[0] + 1]), "times must strictly increase")
    return t, lines


def read_kitti_calib(path: Path) -> dict[str, np.ndarray]:
    """All ``key: numbers`` entries of a KITTI calibration file (non-numeric entries are skipped)."""
    path = Path(path)
    out: dict[str, np.ndarray] = {}
    seen: dict[str, int] = {}
    for lineno, raw in enumerate(read_text(path, "KITTI calibration 'key: values' lines").splitlines(), start=1):
        if ":" not in raw:
            continue
        key, _, rest = raw.partition(":")
        try:
            vals = np.array([float(x) for x in rest.split()])
        except ValueError:
            continue  # e.g. 'calib_time: 25-May-2012 16:47:16'
        if vals.size and not np.all(np.isfinite(vals)):
            raise DataFormatError(path, lineno, f"calibration entry {key.strip()!r} must be finite numbers")
        key = key.strip()
        if key in seen:       # the last one silently won: two calibration files pasted into one (found by a review)
            raise DataFormatError(path, lineno, f"calibration entry {key!r} given twice (first on line {seen[key]}): "
                                                "one entry per key expected")
        seen[key] = lineno
        out[key] = vals
    return out


def calib_transform(path: Path, key: str | None = None) -> np.ndarray:
    """A 4x4 transform from a KITTI calibration file.

    With ``key`` (e.g. ``Tr``) the entry must hold 12 values (3x4, row-major). Without it the file
    must hold ``R`` (9 values) and ``T`` (3 values), as ``calib_imu_to_velo.txt`` does, meaning
    ``X_to = R X_from + T``.
    """
    entries = read_kitti_calib(path)
    T = np.eye(4)
    if key is not None:
        if key not in entries:
            raise DataFormatError(path, None, f"expected a calibration entry {key!r} (found: {', '.join(entries) or 'none'})")
        v = entries[key]
        if v.size != 12:
            raise DataFormatError(path, None, f"calibration entry {key!r} must have 12 values (3x4 row-major), got {v.size}")
        T[:3, :] = v.reshape(3, 4)
    else:
        if "R" not in entries or "T" not in entries:
            raise DataFormatError(path, None, "expected calibration entries 'R' (9 values) and 'T' (3 values)")
        if entries["R"].size != 9 or entries["T"].size != 3:
            raise DataFormatError(path, None, f"calibration 'R' must have 9 values and 'T' 3, got {entries['R'].size} and {entries['T'].size}")
        T[:3, :3] = entries["R"].reshape(3, 3)
        T[:3, 3] = entries["T"]
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOL or np.linalg.det(R) < 0:
        raise DataFormatError(path, None, f"calibration {key or 'R'} is not a rotation (R^T R = I to {ROTATION_TOL:g} and "
                                          f"det +1; det is {np.linalg.det(R):.3f})")
    check_lever_arm(T, path, key or "T")
    return T


# Two sensors of one vehicle are metres apart: a calibration's translation beyond this is a corrupted value (blamed
# otherwise on the poses it moves, as an implausible speed)
MAX_LEVER_ARM_M = 1000.0


def check_lever_arm(T: np.ndarray, where, what: str) -> None:
    d = float(np.linalg.norm(T[:3, 3]))
    if not d <= MAX_LEVER_ARM_M:
        raise DataFormatError(where, None, f"calibration {what} translates by {d:.6g} m: sensors of one vehicle are at most "
                                           f"{MAX_LEVER_ARM_M:g} m apart")
