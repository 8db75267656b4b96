"""Wheel-odometer forward speed as a body-frame velocity observation: the forward row of ``v_b = R^T v``."""

from __future__ import annotations

from functools import partial

import numpy as np
from numba import njit

from ...spec import S
from ...calibration.travel import vehicle_axes
from .base import BODY_VELOCITY_ROW, IDENTITY_AXES, Bound, Kernel, Observation, body_velocity_rows, kernel_model, rows_inside


@njit(cache=True)
def odometer_kernel(x, xc, row, H, r, Rm):
    """The forward row of ``v_b = R^T v`` (1 row)."""
    return body_velocity_rows(x, row, H, r, Rm)


class Odometer(Observation):
    name = "odometer"
    kernel = staticmethod(odometer_kernel)
    label = "odometer forward speed"
    also_reads = frozenset({"filter.nhc_travel_yaw_mrad"})      # its speed is along the direction of travel
    dof = 1
    streams = ("odometer",)
    blocks = frozenset({"V", "TH"})
    enabled_by = "filter.odometer_update"
    keys = {
        "filter.odometer_update": S(False, "fuse the odometer's forward speed as a body-frame velocity observation"),
        "odometer.speed_std_mps": S(0.1, "odometer forward-speed std of one reading (the velocity observation), m/s",
                                    positive=True),
    }

    def bind(self, run, s) -> Bound:
        odo = run.odometer
        t = run.imu.t_s
        rows = rows_inside(odo.t_s, float(t[run.k_start]), float(t[-1]))
        n = rows.size
        v = np.zeros((n, 3))
        v[:, 0] = odo.v_mps[rows]                     # forward
        # along the vehicle's forward axis: the IMU's x axis, or turned by the direction of travel's yaw where the
        # IMU is mounted yawed on the vehicle (filter.nhc_travel_yaw_mrad, which the constraint shares)
        yaw = s.filter.nhc_travel_yaw_mrad * 1e-3
        axes = IDENTITY_AXES if yaw == 0.0 else vehicle_axes(0.0, yaw).ravel()
        data = BODY_VELOCITY_ROW.columns(v=v, std=np.full((n, 3), s.odometer.speed_std_mps),
                                         used=np.tile([1.0, 0.0, 0.0], (n, 1)), axes=np.tile(axes, (n, 1)))

        def model(j):
            return partial(kernel_model, odometer_kernel, row=data[j])

        return Bound(self.name, self.dof, odo.t_s[rows], model, kernel=Kernel(odometer_kernel, data))


OBSERVATION = Odometer()
