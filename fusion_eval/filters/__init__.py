"""Strapdown mechanization and Kalman filters: formulations and observations, each a registered module.

A filter variant is a point on independent axes, each a configuration key: the formulation and process
model (``filter.formulation``, ``filter.process_model``: :mod:`.formulations`), the bias model
(``filter.bias_model``), the update (``filter.iterations``: 1 = EKF, > 1 = iterated EKF) and the
observation set (:mod:`.observations`: ``filter.lidar_update``, ``filter.use_gnss``, ...).
:func:`check_combination` refuses the points no registry entry supports, naming the keys.
"""

from __future__ import annotations

import itertools

from ..errors import ConfigError
from . import formulations, observations
from .layout import canonical_blocks

_NAMES = {"V": "velocity", "BA": "accelerometer bias", "P": "position", "TH": "attitude", "BG": "gyro bias",
          "CP": "cloned position", "CTH": "cloned attitude"}


def formulation_of(cfg: dict):
    f = cfg["filter"]
    return formulations.lookup(f["formulation"], f["process_model"])


def check_combination(cfg: dict) -> None:
    """Reject combinations of variant axes that do not make sense, naming the keys."""
    cls = formulation_of(cfg)
    bias = cfg["filter"]["bias_model"]
    if bias not in cls.bias_models:
        raise ConfigError(f"filter.bias_model={bias} is not implemented by filter.formulation={cls.name} with "
                          f"filter.process_model={cls.process_model} (it has: {', '.join(cls.bias_models)})")
    disc = cfg["filter"].get("discretization", "auto")
    if disc != "auto" and disc not in cls.discretizations:
        raise ConfigError(f"filter.discretization={disc} is not implemented by filter.formulation={cls.name} with "
                          f"filter.process_model={cls.process_model} (it has: {', '.join(cls.discretizations)})")
    from .. import smoothing

    smoothing.check(cfg, cls)
    have = canonical_blocks(cls.layout, cls.pairs)
    for o in observations.enabled(cfg):
        missing = sorted(o.blocks - have)
        if missing:
            what = ", ".join(_NAMES.get(b, b) for b in missing)
            off = ", ".join(f"{k}={_text(v)}" for k, v in o.disable_with.items())
            raise ConfigError(f"{o.enabled_by}={_value(cfg, o.enabled_by)} ({o.label}) needs the {what} state, which "
                              f"filter.formulation={cls.name} with filter.process_model={cls.process_model} does not "
                              f"have: set {off}")


def _text(v) -> str:
    return str(v).lower() if isinstance(v, bool) else str(v)


def _value(cfg: dict, key: str):
    s, k = key.split(".")
    return _text(cfg[s][k])


def make_filter(run, s):
    """The configured filter for a prepared run, initialised at its start sample (``s``: SI settings)."""
    return formulations.lookup(s.filter.formulation, s.filter.process_model).from_run(run, s)


def combinations() -> list[dict]:
    """Every registered formulation x bias model x lidar form that :func:`check_combination` accepts (as
    ``--set`` dictionaries), plus, on each formulation, the iterated update, each registered observation the
    defaults leave off, and all of those at once."""
    from ..config import default_config

    base = default_config()
    extra = [o for o in observations.REGISTRY if not o.enabled(base) and o.enabled_by != "filter.lidar_update"]
    out = []
    for cls, bias, lidar in itertools.product(formulations.REGISTRY, formulations.BIAS_MODELS, pose_forms()):
        out.append({"filter.formulation": cls.name, "filter.process_model": cls.process_model, "filter.bias_model": bias,
                    "filter.lidar_update": lidar})
    for cls in formulations.REGISTRY:
        axes = {"filter.formulation": cls.name, "filter.process_model": cls.process_model}
        out.append({**axes, "filter.iterations": 3})
        out += [{**axes, **o.enable_with} for o in extra]
        out.append({**axes, **{k: v for o in extra for k, v in o.enable_with.items()}})
    ok = []
    for c in out:
        cfg = default_config()
        for k, v in c.items():
            s, n = k.split(".")
            cfg[s][n] = v
        try:
            check_combination(cfg)
        except ConfigError:
            continue
        ok.append(c)
    return ok


def pose_forms() -> tuple[str, ...]:
    """The lidar forms: the registered pose observations' and 'none'."""
    return (*(o.enable_with["filter.lidar_update"] for o in observations.REGISTRY if o.enabled_by == "filter.lidar_update"),
            "none")
