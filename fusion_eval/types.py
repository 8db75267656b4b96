"""Immutable, validated time series that flow from the readers to the filter and the evaluation.

Units and frames are in the field names: ``t_s`` seconds (POSIX seconds of the recording clock),
``f_b_mps2`` specific force in the body frame, ``w_b_rps`` angular rate in the body frame,
``p_w_m`` position in the world (local ENU) frame, ``q_wb_xyzw`` body-to-world attitude in scipy's
quaternion order. Each series remembers where it came from (``source``, and per row the 1-based
``lines`` of that file) so that a validation failure names the file and the line.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .errors import DataFormatError


def _frozen(a: Any, dtype=float) -> np.ndarray:
    """A read-only array of ``a``: ``a`` itself when nothing can change it any more (read-only, and every array it
    views too: a series made from another one's arrays, as ``dataclasses.replace`` and ``select`` do, shares them
    instead of copying each; on an hour at 200 Hz those copies were hundreds of MB), else a frozen copy."""
    if isinstance(a, np.ndarray) and a.dtype == dtype and _immutable(a):
        return a
    arr = np.array(a, dtype=dtype, copy=True)
    arr.setflags(write=False)
    return arr


def _immutable(a: np.ndarray) -> bool:
    while isinstance(a, np.ndarray):
        if a.flags.writeable:
            return False
        if a.base is None:
            return True
        a = a.base
    return False            # a view of a buffer that is not an array (bytes, mmap): copied, to be safe


def _frozen_own(a: np.ndarray) -> np.ndarray:
    """``a``, just made by the caller and referenced nowhere else, frozen in place (no copy)."""
    a.setflags(write=False)
    return a


def line_of(lines: np.ndarray | None, i: int) -> int | None:
    """The 1-based file line of row ``i`` (None when the series knows no lines)."""
    if lines is None or len(lines) == 0:
        return None
    return int(lines[min(i, len(lines) - 1)])


def check_unit_quaternions(source, lines, q: np.ndarray, tol: float = 1e-2) -> None:
    """Quaternions whose norm is not 1 within ``tol`` (as every pose series requires): an
    all-zero or scaled quaternion is a corrupted pose, not one to normalise silently."""
    norms = np.linalg.norm(np.asarray(q, float), axis=1)
    bad = np.flatnonzero(~(np.abs(norms - 1.0) <= tol))
    if bad.size:
        raise DataFormatError(source, line_of(lines, int(bad[0])),
                              f"pose quaternion must have unit norm, got norm {norms[bad[0]]:.4f}")


def check_times(t: np.ndarray, source: str, lines: np.ndarray | None, what: str, allow_equal: bool = False) -> None:
    """Finite, increasing stamps (equal consecutive ones allowed with ``allow_equal``), or a one-line error naming the
    line of the first that is not."""
    if t.ndim != 1:
        raise DataFormatError(source, None, f"{what} times must be a 1-D array, got shape {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise DataFormatError(source, line_of(lines, bad[0]), f"{what} timestamp must be a finite number")
    if t.size > 1:
        d = np.diff(t)
        bad = np.flatnonzero(d < 0.0 if allow_equal else d <= 0.0)
        if bad.size:
            i = bad[0] + 1
            kind = "duplicate" if d[bad[0]] == 0 else "decreasing"
            must = "must not decrease" if allow_equal else "must strictly increase"
            raise DataFormatError(source, line_of(lines, i),
                                  f"{what} timestamps {must} ({kind} timestamp {t[i]:.9f} after {t[i - 1]:.9f})")


# Beyond these no vehicle or drone IMU measures (gyros saturate at a few thousand deg/s, accelerometers at tens of
# g): a value above is a corrupted sample or a unit error, refused with its line.
IMU_MAX_RATE_RPS = 100.0
IMU_MAX_SPECIFIC_FORCE_MPS2 = 1000.0


def _check_rows(name: str, a: np.ndarray, n: int, cols: int, source: str, lines: np.ndarray | None, what: str) -> None:
    if a.shape != (n, cols):
        raise DataFormatError(source, None, f"{what} {name} must have shape ({n}, {cols}), got {a.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if bad.size:
        raise DataFormatError(source, line_of(lines, bad[0]), f"{what} {name} must be finite numbers (found NaN or inf)")


def shifted(series, dt_s: float):
    """``series`` (any of the series below) with its stamps moved by ``dt_s`` seconds; the series itself for 0 s (its
    arrays are read-only; a copy of a long drive's ground truth was ~60 MB for nothing)."""
    return series if dt_s == 0.0 else replace(series, t_s=series.t_s + dt_s)


def _keeps_all(mask, t_s: np.ndarray) -> bool:
    """A boolean mask of one entry per row that keeps every row: ``select`` returns the series itself (its arrays
    are read-only), not a copy of each (a long drive's ground truth with no filled-in packet was ~60 MB copied for
    nothing). Any other mask (a wrong length too) is indexed as before."""
    mask = np.asarray(mask)
    return mask.dtype == bool and mask.shape == t_s.shape and bool(mask.all())


@dataclass(frozen=True)
class ImuSeries:
    """IMU samples: specific force and angular rate in the body frame.

    ``filled`` marks samples that the data provider interpolated or extrapolated (KITTI's filled
    OXTS packets); the configuration decides whether they are used.
    """

    t_s: np.ndarray
    f_b_mps2: np.ndarray
    w_b_rps: np.ndarray
    filled: np.ndarray | None = None
    source: str = "<imu>"
    lines: np.ndarray | None = None

    def __post_init__(self):
        t = _frozen(self.t_s)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "f_b_mps2", _frozen(self.f_b_mps2))
        object.__setattr__(self, "w_b_rps", _frozen(self.w_b_rps))
        filled = np.zeros(t.shape, bool) if self.filled is None else self.filled
        object.__setattr__(self, "filled", _frozen(filled, bool))
        if self.lines is not None:
            object.__setattr__(self, "lines", _frozen(self.lines, np.int64))
        check_times(t, self.source, self.lines, "IMU")
        _check_rows("specific force", self.f_b_mps2, t.size, 3, self.source, self.lines, "IMU")
        _check_rows("angular rate", self.w_b_rps, t.size, 3, self.source, self.lines, "IMU")
        for name, a, lim, unit in (("angular rate", self.w_b_rps, IMU_MAX_RATE_RPS, "rad/s"),
                                   ("specific force", self.f_b_mps2, IMU_MAX_SPECIFIC_FORCE_MPS2, "m/s^2")):
            bad = np.flatnonzero(np.abs(a).max(axis=1) > lim) if t.size else []
            if len(bad):
                raise DataFormatError(self.source, line_of(self.lines, bad[0]),
                                      f"IMU {name} {a[bad[0]].tolist()} {unit} exceeds {lim:g} {unit} (no IMU measures that: "
                                      "a corrupted sample, or deg/s or g given as rad/s or m/s^2?)")

    def __len__(self) -> int:
        return int(self.t_s.size)

    def select(self, mask: np.ndarray) -> "ImuSeries":
        if _keeps_all(mask, self.t_s):
            return self
        lines = None if self.lines is None else self.lines[mask]
        return replace(self, t_s=self.t_s[mask], f_b_mps2=self.f_b_mps2[mask], w_b_rps=self.w_b_rps[mask],
                       filled=self.filled[mask], lines=lines)


@dataclass(frozen=True)
class GnssSeries:
    """GNSS position fixes in the world (local ENU) frame with their 1-sigma per axis."""

    t_s: np.ndarray
    p_w_m: np.ndarray
    std_w_m: np.ndarray
    filled: np.ndarray | None = None
    source: str = "<gnss>"
    lines: np.ndarray | None = None

    def __post_init__(self):
        t = _frozen(self.t_s)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "p_w_m", _frozen(self.p_w_m))
        object.__setattr__(self, "std_w_m", _frozen(self.std_w_m))
        filled = np.zeros(t.shape, bool) if self.filled is None else self.filled
        object.__setattr__(self, "filled", _frozen(filled, bool))
        if self.lines is not None:
            object.__setattr__(self, "lines", _frozen(self.lines, np.int64))
        check_times(t, self.source, self.lines, "GNSS")
        _check_rows("position", self.p_w_m, t.size, 3, self.source, self.lines, "GNSS")
        _check_rows("std", self.std_w_m, t.size, 3, self.source, self.lines, "GNSS")
        if np.any(self.std_w_m <= 0):
            i = int(np.flatnonzero(np.any(self.std_w_m <= 0, axis=1))[0])
            raise DataFormatError(self.source, line_of(self.lines, i), "GNSS position std must be > 0")

    def __len__(self) -> int:
        return int(self.t_s.size)

    def as_poses(self) -> "PoseSeries":
        """The fixes as a position-only pose series (identity placeholder attitudes), for evaluation."""
        return PoseSeries(t_s=self.t_s, p_w_m=self.p_w_m, q_wb_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (len(self), 1)),
                          has_orientation=False, source=self.source)

    def select(self, mask: np.ndarray) -> "GnssSeries":
        if _keeps_all(mask, self.t_s):
            return self
        lines = None if self.lines is None else self.lines[mask]
        return replace(self, t_s=self.t_s[mask], p_w_m=self.p_w_m[mask], std_w_m=self.std_w_m[mask],
                       filled=self.filled[mask], lines=lines)


@dataclass(frozen=True)
class PoseSeries:
    """Poses of the body (IMU) frame in the world frame, optionally with world-frame velocity.

    ``has_orientation`` is False for position-only estimates (GNSS alone); their quaternions are
    identity placeholders and no rotation metric is computed for them. ``repeated_stamps``: equal consecutive
    stamps are accepted (a trajectory file to evaluate: evo accepts them, and its association copes); the
    filter's inputs keep strictly increasing time.
    """

    t_s: np.ndarray
    p_w_m: np.ndarray
    q_wb_xyzw: np.ndarray
    v_w_mps: np.ndarray | None = None
    filled: np.ndarray | None = None
    has_orientation: bool = True
    source: str = "<poses>"
    lines: np.ndarray | None = None
    repeated_stamps: bool = False

    def __post_init__(self):
        t = _frozen(self.t_s)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "p_w_m", _frozen(self.p_w_m))
        q = np.asarray(self.q_wb_xyzw, dtype=float)          # not changed in place: normalised into a new array
        if self.lines is not None:
            object.__setattr__(self, "lines", _frozen(self.lines, np.int64))
        check_times(t, self.source, self.lines, "pose", allow_equal=self.repeated_stamps)
        _check_rows("position", np.asarray(self.p_w_m), t.size, 3, self.source, self.lines, "pose")
        _check_rows("quaternion", q, t.size, 4, self.source, self.lines, "pose")
        check_unit_quaternions(self.source, self.lines, q)
        object.__setattr__(self, "q_wb_xyzw", _frozen_own(q / np.linalg.norm(q, axis=1)[:, None]))
        if self.v_w_mps is not None:
            _check_rows("velocity", np.asarray(self.v_w_mps), t.size, 3, self.source, self.lines, "pose")
            object.__setattr__(self, "v_w_mps", _frozen(self.v_w_mps))
        filled = np.zeros(t.shape, bool) if self.filled is None else self.filled
        object.__setattr__(self, "filled", _frozen(filled, bool))

    def __len__(self) -> int:
        return int(self.t_s.size)

    def R_wb(self) -> np.ndarray:
        """Rotation matrices ``(N, 3, 3)``."""
        from .so3 import quat_xyzw_to_matrix

        return quat_xyzw_to_matrix(self.q_wb_xyzw).reshape(-1, 3, 3)

    def select(self, mask: np.ndarray) -> "PoseSeries":
        if _keeps_all(mask, self.t_s):
            return self
        lines = None if self.lines is None else self.lines[mask]
        v = None if self.v_w_mps is None else self.v_w_mps[mask]
        return replace(self, t_s=self.t_s[mask], p_w_m=self.p_w_m[mask], q_wb_xyzw=self.q_wb_xyzw[mask],
                       v_w_mps=v, filled=self.filled[mask], lines=lines)


@dataclass(frozen=True)
class SpeedSeries:
    """Forward speed of the vehicle (a wheel odometer), m/s."""

    t_s: np.ndarray
    v_mps: np.ndarray
    source: str = "<odometer>"
    lines: np.ndarray | None = None

    def __post_init__(self):
        t = _frozen(self.t_s)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "v_mps", _frozen(self.v_mps))
        if self.lines is not None:
            object.__setattr__(self, "lines", _frozen(self.lines, np.int64))
        check_times(t, self.source, self.lines, "odometer")
        _check_rows("speed", self.v_mps.reshape(-1, 1), t.size, 1, self.source, self.lines, "odometer")

    def __len__(self) -> int:
        return int(self.t_s.size)


@dataclass(frozen=True)
class VectorSeries:
    """Stamped measurements of a vector quantity with their 1-sigma per component (the stream of an
    observation beyond the built-in ones, e.g. a GNSS receiver's ENU velocity). ``what`` names the quantity,
    with its frame and unit, for errors."""

    t_s: np.ndarray
    values: np.ndarray
    std: np.ndarray
    filled: np.ndarray | None = None
    source: str = "<vectors>"
    lines: np.ndarray | None = None
    what: str = "measurement"

    def __post_init__(self):
        t = _frozen(self.t_s)
        object.__setattr__(self, "t_s", t)
        v = np.asarray(self.values, float)
        v = v.reshape(t.size, -1) if v.ndim == 1 else v
        object.__setattr__(self, "values", _frozen(v))
        object.__setattr__(self, "std", _frozen(np.asarray(self.std, float).reshape(v.shape)))
        filled = np.zeros(t.shape, bool) if self.filled is None else self.filled
        object.__setattr__(self, "filled", _frozen(filled, bool))
        if self.lines is not None:
            object.__setattr__(self, "lines", _frozen(self.lines, np.int64))
        check_times(t, self.source, self.lines, self.what)
        _check_rows("values", self.values, t.size, v.shape[1], self.source, self.lines, self.what)
        _check_rows("std", self.std, t.size, v.shape[1], self.source, self.lines, self.what)
        if np.any(self.std <= 0):
            i = int(np.flatnonzero(np.any(self.std <= 0, axis=1))[0])
            raise DataFormatError(self.source, line_of(self.lines, i), f"{self.what} std must be > 0")

    def __len__(self) -> int:
        return int(self.t_s.size)

    def select(self, mask: np.ndarray) -> "VectorSeries":
        if _keeps_all(mask, self.t_s):
            return self
        lines = None if self.lines is None else self.lines[mask]
        return replace(self, t_s=self.t_s[mask], values=self.values[mask], std=self.std[mask], filled=self.filled[mask],
                       lines=lines)


@dataclass(frozen=True)
class Dataset:
    """Every stream of one drive, in one world frame and on one clock."""

    name: str
    imu: ImuSeries
    groundtruth: PoseSeries | None = None
    gnss: GnssSeries | None = None
    lidar: PoseSeries | None = None
    odometer: SpeedSeries | None = None
    geodetic_origin: tuple[float, float, float] | None = None
    description: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)     # streams of registered observations beyond the built-in ones

    BUILTIN = ("imu", "groundtruth", "gnss", "lidar", "odometer")

    def stream(self, name: str):
        """A stream by its manifest name (None when the dataset has none)."""
        return getattr(self, name) if name in self.BUILTIN else self.extra.get(name)
