"""Non-holonomic constraint: lateral and vertical body velocity are zero (a pseudo-observation).

Fires at IMU stamps at about ``filter.nhc_rate_hz``, and only while the vehicle is not turning
(``|w| < filter.nhc_max_turn_rate_rps``): in turns the IMU's lateral velocity (lever arm, slip) is not zero.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from ...spec import S
from .base import Bound, Observation, body_velocity


class NonHolonomic(Observation):
    name = "nhc"
    label = "non-holonomic constraint"
    dof = 2
    streams = ()
    blocks = frozenset({"V", "TH"})
    enabled_by = "filter.nhc"
    keys = {
        "filter.nhc": S(False, "non-holonomic constraint: lateral and vertical body velocity = 0 as a pseudo-observation "
                               "while not turning"),
        "filter.nhc_max_turn_rate_rps": S(0.13, "apply the constraint only while |angular rate| is below this, rad/s",
                                          positive=True),
        "filter.nhc_rate_hz": S(10.0, "rate of the constraint's pseudo-observations, Hz", positive=True),
        "filter.nhc_std_mps": S(0.1, "std of the constraint (lateral and vertical slip), m/s", positive=True),
    }

    def bind(self, run, s) -> Bound:
        f = s.filter
        t, w = run.imu.t_s, run.imu.w_b_rps
        dt = float(np.median(np.diff(t))) if t.size > 1 else np.inf
        step = max(1, int(round(1.0 / (f.nhc_rate_hz * dt)))) if np.isfinite(dt) else t.size
        cand = np.arange(run.k_start + step, t.size, step)
        k = cand[np.linalg.norm(w[cand], axis=1) < f.nhc_max_turn_rate_rps]
        std = np.full(3, f.nhc_std_mps)
        model = partial(body_velocity, v_obs_b=np.zeros(3), std_b=std, rows=(1, 2))
        return Bound(self.name, self.dof, t[k], lambda j: model)


OBSERVATION = NonHolonomic()
