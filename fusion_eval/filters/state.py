"""The nominal (whole) state shared by every formulation, as named views of one flat vector.

The compiled kernels work on the flat vector (layout :data:`~fusion_eval.filters.layout.NOMINAL`); the
observation models and the rest of the package read it through the views ``p_w_m``, ``v_w_mps``,
``R_wb``, ``ba_b``, ``bg_b`` and ``k_odo``, which always see what the kernels wrote.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .layout import CLONE, NOMINAL

_P, _V, _R, _BA, _BG, _K = (NOMINAL.sl(b) for b in ("p", "v", "R", "ba", "bg", "k"))

# an observation model, called as model(x, clone_p, clone_R) -> (H over the canonical error state, r, R)
ObservationModel = Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]]


def unpack(rec_x: np.ndarray) -> dict[str, np.ndarray]:
    """Recorded nominal vectors ``(N, NOMINAL.n)`` as arrays: p, v (N, 3), R (N, 3, 3), ba, bg (N, 3), k (N,)."""
    out = {b: rec_x[:, NOMINAL.sl(b)] for b in NOMINAL.core}
    out["R"] = out["R"].reshape(-1, 3, 3)
    out["k"] = out["k"][:, 0]
    return out


class NominalState:
    """Position ``p_w_m`` and velocity ``v_w_mps`` in the world frame, attitude ``R_wb``, accelerometer and
    gyro biases in the body frame (SI), and the odometer scale error ``k_odo`` (odometer + gyro model)."""

    __slots__ = ("vec", "p_w_m", "v_w_mps", "R_wb", "ba_b", "bg_b", "_k")

    def __init__(self, p_w_m, v_w_mps, R_wb, ba_b, bg_b, k_odo: float = 0.0):
        vec = np.zeros(NOMINAL.n)
        vec[_P], vec[_V], vec[_R] = p_w_m, v_w_mps, np.asarray(R_wb, float).ravel()
        vec[_BA], vec[_BG], vec[_K] = ba_b, bg_b, k_odo
        self._bind(vec)

    def _bind(self, vec: np.ndarray) -> None:
        self.vec = vec
        self.p_w_m, self.v_w_mps, self.ba_b, self.bg_b = vec[_P], vec[_V], vec[_BA], vec[_BG]
        self.R_wb = vec[_R].reshape(3, 3)
        self._k = vec[_K]

    @classmethod
    def from_vector(cls, vec: np.ndarray) -> "NominalState":
        """Views over ``vec`` itself (not a copy)."""
        x = cls.__new__(cls)
        x._bind(vec)
        return x

    @property
    def k_odo(self) -> float:
        return float(self._k[0])

    @k_odo.setter
    def k_odo(self, value: float) -> None:
        self._k[0] = value

    def copy(self) -> "NominalState":
        return NominalState.from_vector(self.vec.copy())


class ClonePose:
    """The nominal pose of a clone (``p_w_m``, ``R_wb``), views of one flat vector (layout ``CLONE``)."""

    __slots__ = ("vec", "p_w_m", "R_wb")

    def __init__(self, vec: np.ndarray | None = None):
        self.vec = np.zeros(CLONE.n) if vec is None else vec
        self.p_w_m = self.vec[CLONE.sl("p")]
        self.R_wb = self.vec[CLONE.sl("R")].reshape(3, 3)

    def set(self, p_w_m: np.ndarray, R_wb: np.ndarray) -> None:
        self.p_w_m[:] = p_w_m
        self.R_wb[:] = R_wb

    def copy(self) -> "ClonePose":
        return ClonePose(self.vec.copy())
