"""The observation registry: one module per observation, one line each below.

The order is the order of updates at equal stamps (lidar first). ``replay`` iterates over the enabled
entries; the configuration schema takes their keys; reports, ``compare`` and the simulator find them by name.
"""

from __future__ import annotations

from . import gnss_position, gnss_velocity, nhc, odometer, pose, relative_pose
from .base import Bound, Observation

REGISTRY: tuple[Observation, ...] = (
    relative_pose.OBSERVATION,
    pose.OBSERVATION,
    gnss_position.OBSERVATION,
    odometer.OBSERVATION,
    nhc.OBSERVATION,
    gnss_velocity.OBSERVATION,
)

# the compiled models, in registry order: the compiled replay dispatches on them (filters/compiled_replay.py)
KERNELS: tuple = tuple(o.kernel for o in REGISTRY if o.kernel is not None)


def enabled(cfg: dict) -> list[Observation]:
    """The observations the configuration turns on, in update order."""
    return [o for o in REGISTRY if o.enabled(cfg)]


def inactive_settings(cfg: dict, given: dict) -> list[str]:
    """Sentences for the settings the user gave (``given``: ``{"section.key": value}`` of the config files, variants and
    ``--set``, off their defaults) that do nothing in this configuration: a key of an observation that is off, which
    no enabled observation shares. (A sweep of lidar.relative_pos_std_m under filter.lidar_update=absolute gave identical
    rows with no word: a configuration audit.)"""
    on = [o for o in REGISTRY if o.enabled(cfg)]
    read = {k for o in on for k in (*o.keys, *o.also_reads, *((o.gate_key,) if o.gate_key else ()))}
    switches = {k for o in REGISTRY for k in (o.enabled_by, *o.enable_with, *o.disable_with)}
    out = []
    for o in REGISTRY:
        if o in on:
            continue
        for key, spec in o.keys.items():
            if key in given and key not in read and key not in switches and key not in o.read_elsewhere:
                how = ", ".join(f"{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in o.enable_with.items())
                out.append(f"{key}={given[key]} does nothing here: it is a setting of the {o.label}, which this "
                           f"configuration does not fuse ({how} does)")
    return out


def extra_streams() -> tuple:
    """The streams the registered observations bring (beyond imu, groundtruth, gnss, lidar, odometer)."""
    return tuple(spec for o in REGISTRY for spec in o.extra_streams)


def sim_keys() -> dict:
    """The simulator settings of the observations' simulated sensors."""
    out: dict = {}
    for o in REGISTRY:
        out.update(o.sim_keys)
    return out


def keys() -> dict:
    """Every observation's configuration keys (each declared by exactly one module)."""
    out: dict = {}
    for o in REGISTRY:
        for k, spec in o.keys.items():
            if k in out:
                raise RuntimeError(f"configuration key {k!r} declared by two observations")
            out[k] = spec
    return out


__all__ = ["REGISTRY", "KERNELS", "Bound", "Observation", "enabled", "keys", "extra_streams", "sim_keys"]
