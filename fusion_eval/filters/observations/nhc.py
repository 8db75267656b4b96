"""Non-holonomic constraint: the velocity across and above the vehicle's direction of travel is zero (a
pseudo-observation).

Fires at IMU stamps at about ``filter.nhc_rate_hz``, and only while the vehicle is not turning
(``|w| < filter.nhc_max_turn_rate_rps``): in turns the IMU's lateral velocity (lever arm, slip) is not zero.

The vehicle's axes are taken in the IMU frame: an IMU pitched against the direction of travel (KITTI's OXTS by
8-14 mrad) would otherwise be told that a car driving straight climbs or sinks, and the constraint would hold its
pitch that far off, leaking gravity into the horizontal acceleration. ``filter.nhc_travel_pitch_mrad: auto``
takes the pitch from the lidar odometry's own increments, else from a smoothed IMU + GNSS pass
(:mod:`fusion_eval.calibration.travel`); with no estimate the vertical row is left out, since a wrong one does
more harm than none.
"""

from __future__ import annotations

import logging
from functools import partial

import numpy as np
from numba import njit

from ...spec import S
from ...calibration.travel import vehicle_axes
from .base import BODY_VELOCITY_ROW, Bound, Kernel, Observation, body_velocity_rows, kernel_model


log = logging.getLogger(__name__)

# manifest platforms that do not slide sideways or leave the road
WHEELED = ("car", "wheeled")


@njit(cache=True)
def nhc_kernel(x, xc, row, H, r, Rm):
    """The lateral and vertical rows of ``v_b = R^T v``, observed as zero (2 rows)."""
    return body_velocity_rows(x, row, H, r, Rm)


class NonHolonomic(Observation):
    name = "nhc"
    kernel = staticmethod(nhc_kernel)
    label = "non-holonomic constraint"
    # the odometer + gyro process model drives along it, and the mount's calibration takes it: not only the constraint's
    read_elsewhere = frozenset({"filter.nhc_travel_yaw_mrad"})
    dof = 2
    streams = ()
    blocks = frozenset({"V", "TH"})
    enabled_by = "filter.nhc"
    keys = {
        "filter.nhc": S("auto", "non-holonomic constraint: velocity across and above the direction of travel = 0 as a "
                                "pseudo-observation while not turning; 'auto' = on when the dataset's platform is a wheeled "
                                "vehicle (manifest 'platform: car'; plain KITTI raw drives) and the rest of the "
                                "configuration can take it; see \"The non-holonomic constraint\"", "bool", auto=True),
        "filter.nhc_max_turn_rate_rps": S(0.13, "apply the constraint only while |angular rate| is below this, rad/s",
                                          positive=True),
        "filter.nhc_rate_hz": S(10.0, "rate of the constraint's pseudo-observations, Hz: at every n-th IMU sample, "
                                      "the n nearest (a rate more than 10 % off the one asked for is said)", positive=True),
        "filter.nhc_std_mps": S(0.1, "std of the constraint (lateral and vertical slip), m/s", positive=True, reads="filter"),
        "filter.nhc_travel_pitch_mrad": S("auto", "pitch of the direction of travel above the IMU's x-y plane, mrad: the "
                                                  "constraint's vertical row is along it; 'auto' = from the lidar "
                                                  "odometry's body-frame increments on straight stretches, else from a "
                                                  "smoothed IMU + GNSS pass (see \"The non-holonomic constraint\"); null "
                                                  "(or no estimate) = the vertical row is left out", "float", auto=True,
                                          nullable=True),
        "filter.nhc_travel_yaw_mrad": S(0.0, "yaw of the direction of travel to the left of the IMU's x axis, mrad (not "
                                             "estimated: the lidar's increments carry its own mount's yaw error); the "
                                             "odometer's speed update is along it too (the odometer + gyro process model "
                                             "drives along the IMU's x axis)"),
    }

    def resolve_for(self, cfg: dict, description: dict) -> None:
        """'auto': on for a wheeled platform, where the rest of the configuration can take it (the odometer + gyro
        process model has no velocity state; the batch smoother has no factor for it)."""
        if cfg["filter"]["nhc"] != "auto":
            return
        from .. import check_combination
        from ...errors import ConfigError

        cfg["filter"]["nhc"] = description.get("platform") in WHEELED
        if cfg["filter"]["nhc"]:
            try:
                check_combination(cfg)
            except ConfigError as e:
                cfg["filter"]["nhc"] = False
                log.info("non-holonomic constraint left out on this %s: %s", description.get("platform"), e)

    def bind(self, run, s) -> Bound:
        f = s.filter
        t, w = run.imu.t_s, run.imu.w_b_rps
        dt = float(np.median(np.diff(t))) if t.size > 1 else np.inf
        step = max(1, int(round(1.0 / (f.nhc_rate_hz * dt)))) if np.isfinite(dt) else t.size
        if np.isfinite(dt) and abs(1.0 / (step * dt) / f.nhc_rate_hz - 1.0) > 0.1:
            # the constraint fires at IMU samples: 7, 10, 25 and 100 Hz on a 10 Hz IMU were all 10 Hz, with no word
            # (a configuration audit)
            which = "every sample" if step == 1 else f"every {step}{ {2: 'nd', 3: 'rd'}.get(step, 'th')} sample"
            log.warning("filter.nhc_rate_hz=%g: the constraint fires at IMU samples, at %s of this %.3g Hz stream: "
                        "%.3g Hz", f.nhc_rate_hz, which, 1.0 / dt, 1.0 / (step * dt))
        cand = np.arange(run.k_start + step, t.size, step)
        k = cand[np.linalg.norm(w[cand], axis=1) < f.nhc_max_turn_rate_rps]
        row = self.row(f)
        data = np.tile(row, (k.size, 1))
        model = partial(kernel_model, nhc_kernel, row=row)
        return Bound(self.name, int(row[BODY_VELOCITY_ROW.sl("used")].sum()), t[k], lambda j: model,
                     kernel=Kernel(nhc_kernel, data))

    @staticmethod
    def row(f) -> np.ndarray:
        """The data row: zero velocity across (and, with a pitch, above) the direction of travel."""
        pitch = f.nhc_travel_pitch_mrad
        vertical = pitch is not None and pitch != "auto"
        axes = vehicle_axes(float(pitch) * 1e-3 if vertical else 0.0, f.nhc_travel_yaw_mrad * 1e-3)
        return BODY_VELOCITY_ROW.pack(v=np.zeros(3), std=np.full(3, f.nhc_std_mps),
                                      used=[0.0, 1.0, 1.0 if vertical else 0.0], axes=axes.ravel())


OBSERVATION = NonHolonomic()
