"""Non-holonomic constraint: lateral and vertical body velocity are zero (a pseudo-observation).

Fires at IMU stamps at about ``filter.nhc_rate_hz``, and only while the vehicle is not turning
(``|w| < filter.nhc_max_turn_rate_rps``): in turns the IMU's lateral velocity (lever arm, slip) is not zero.
"""

from __future__ import annotations

from functools import partial

import numpy as np
from numba import njit

from ...spec import S
from .base import BODY_VELOCITY_ROW, Bound, Kernel, Observation, body_velocity_rows, kernel_model


@njit(cache=True)
def nhc_kernel(x, xc, row, H, r, Rm):
    """The lateral and vertical rows of ``v_b = R^T v``, observed as zero (2 rows)."""
    return body_velocity_rows(x, row, H, r, Rm)


class NonHolonomic(Observation):
    name = "nhc"
    kernel = staticmethod(nhc_kernel)
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
        data = BODY_VELOCITY_ROW.columns(v=np.zeros((k.size, 3)), std=np.full((k.size, 3), f.nhc_std_mps),
                                         used=np.tile([0.0, 1.0, 1.0], (k.size, 1)))
        model = partial(kernel_model, nhc_kernel, row=BODY_VELOCITY_ROW.pack(v=np.zeros(3), std=np.full(3, f.nhc_std_mps),
                                                                            used=[0.0, 1.0, 1.0]))
        return Bound(self.name, self.dof, t[k], lambda j: model, kernel=Kernel(nhc_kernel, data))


OBSERVATION = NonHolonomic()
