"""The filter variants and how they compose.

A variant is a point on independent axes, each a configuration key:

* formulation (``filter.formulation``): ``error_state`` | ``nominal_state`` -> the filter class;
* process model (``filter.process_model``): ``imu`` | ``odometer_gyro``;
* bias model (``filter.bias_model``): ``random_walk`` | ``constant`` -> the process noise of the bias states;
* update (``filter.iterations``): 1 = EKF, > 1 = iterated EKF;
* observation set: ``filter.lidar_update`` (relative | absolute | none), ``filter.use_gnss``,
  ``filter.odometer_update``, ``filter.nhc``.

Adding a formulation is one class (a :class:`~fusion_eval.filters.base.FilterBase`) and one line in
:data:`FORMULATIONS`; the tests run every combination that :func:`combinations` lists.
"""

from __future__ import annotations

import itertools

import numpy as np

from .eskf import ErrorStateKF
from .nominal import NominalStateEKF
from .odo_gyro import OdometerGyroKF
from . import odo_kernels as ok

FORMULATIONS = {"error_state": ErrorStateKF, "nominal_state": NominalStateEKF}
PROCESS_MODELS = ("imu", "odometer_gyro")
BIAS_MODELS = ("random_walk", "constant")
LIDAR_UPDATES = ("relative", "absolute", "none")


def make_filter(fp, x0, prm: np.ndarray, imu_t, imu_f, imu_w, k0: int, v_odo_on_imu: np.ndarray | None = None):
    """The filter of the configured formulation and process model, initialised at IMU sample ``k0``."""
    P0 = np.diag(fp.init_std ** 2)
    if fp.process_model == "odometer_gyro":
        oprm = np.zeros(ok.N_OPRM)
        oprm[ok.OPRM_QV], oprm[ok.OPRM_QSLIP] = fp.odo_speed_noise, fp.odo_slip_noise
        oprm[ok.OPRM_QG], oprm[ok.OPRM_QK] = fp.gyro_noise, fp.odo_scale_rw
        oprm[ok.OPRM_QBG] = fp.gyro_bias_rw if fp.bias_model == "random_walk" else 0.0
        return OdometerGyroKF(x0, P0, fp.odo_scale_init_std, prm, oprm, imu_t, v_odo_on_imu, imu_w, k0)
    return FORMULATIONS[fp.formulation](x0, P0, prm, imu_t, imu_f, imu_w, k0)


def combinations() -> list[dict]:
    """Every valid combination of formulation, process model, bias model and lidar update (as --set
    dictionaries), plus the iterated update and the velocity observations on the default filter."""
    out = []
    for form, proc, bias, lidar in itertools.product(FORMULATIONS, PROCESS_MODELS, BIAS_MODELS, LIDAR_UPDATES):
        if proc == "odometer_gyro" and form != "error_state":
            continue
        out.append({"filter.formulation": form, "filter.process_model": proc, "filter.bias_model": bias,
                    "filter.lidar_update": lidar})
    for form in FORMULATIONS:
        out.append({"filter.formulation": form, "filter.iterations": 3})
        out.append({"filter.formulation": form, "filter.odometer_update": True, "filter.nhc": True})
    return out
