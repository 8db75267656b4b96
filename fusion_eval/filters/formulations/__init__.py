"""The formulation registry: each (filter.formulation, filter.process_model) pair is one class, one line below.

A formulation module declares its state layout (named blocks), its pairs with the canonical error state,
its compiled propagation step and covariance recording, its injection/reset, and the configuration keys
it owns (``keys``). The configuration's choices of ``filter.formulation``, ``filter.process_model`` and
``filter.bias_model`` come from here, and so does the refusal of combinations nobody registered.
"""

from __future__ import annotations

from ...errors import ConfigError
from .base import FilterBase, bias_decays, bias_walks, gap_of
from .eskf import ErrorStateKF
from .invariant import RightInvariantEKF
from .nominal import NominalStateEKF
from .odo_gyro import OdometerGyroKF

REGISTRY: tuple[type[FilterBase], ...] = (
    ErrorStateKF,
    NominalStateEKF,
    OdometerGyroKF,
    RightInvariantEKF,
)

# Bias models: what the bias states' process noise is (see base.bias_walks).
BIAS_MODELS = {
    "random_walk": "biases as random walks with the imu.*_bias_rw_* densities",
    "constant": "bias states kept, no process noise",
    "gauss_markov": "first-order Gauss-Markov biases: db/dt = -b/tau + w, tau = imu.*_bias_corr_time_s, w the "
                    "imu.*_bias_rw_* densities (steady-state std = density * sqrt(tau / 2))",
}


def formulations() -> tuple[str, ...]:
    return tuple(dict.fromkeys(c.name for c in REGISTRY))


def process_models() -> tuple[str, ...]:
    return tuple(dict.fromkeys(c.process_model for c in REGISTRY))


def lookup(formulation: str, process_model: str) -> type[FilterBase]:
    for c in REGISTRY:
        if c.name == formulation and c.process_model == process_model:
            return c
    known = ", ".join(f"{c.name} + {c.process_model}" for c in REGISTRY)
    raise ConfigError(f"filter.formulation={formulation} with filter.process_model={process_model} is not a "
                      f"registered filter (registered: {known})")


def keys() -> dict:
    out: dict = {}
    for c in REGISTRY:
        out.update(getattr(c, "keys", {}))
    return out


__all__ = ["REGISTRY", "BIAS_MODELS", "FilterBase", "lookup", "formulations", "process_models", "bias_walks", "bias_decays", "gap_of",
           "keys"]
