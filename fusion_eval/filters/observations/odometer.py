"""Wheel-odometer forward speed as a body-frame velocity observation: the forward row of ``v_b = R^T v``."""

from __future__ import annotations

from functools import partial

import numpy as np

from ...spec import S
from .base import Bound, Observation, body_velocity, rows_inside


class Odometer(Observation):
    name = "odometer"
    label = "odometer forward speed"
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
        std = np.full(3, s.odometer.speed_std_mps)

        def model(j):
            return partial(body_velocity, v_obs_b=np.array([odo.v_mps[rows[j]], 0.0, 0.0]), std_b=std, rows=(0,))

        return Bound(self.name, self.dof, odo.t_s[rows], model)


OBSERVATION = Odometer()
