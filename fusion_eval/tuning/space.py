"""The search space of a tune: a YAML file naming configuration keys (the ``--set`` keys) with ranges, and keys
held fixed::

    params:
      imu.gyro_noise_dps_sqrthz: {low: 0.002, high: 0.2, log: true}
      gnss.std_m: {low: 0.3, high: 10.0, log: true, shape: [1, 1, 2]}   # a vector key: one value times a shape
      filter.discretization: {choices: [first_order, van_loan]}
    fixed:
      lidar.noise_adapt: none

Only what the filter believes may be tuned: keys that change the data (the GNSS noise added by the degradation,
its rate, outages and seeds) or the evaluation would let the tuner improve the score by changing what is scored.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

from .. import yaml_lines
from ..config import check_value, keys_read_by, read_yaml, schema
from ..errors import ConfigError

# keys that change the data or its scoring, not the filter's belief (see the module docstring): declared with
# reads="data" beside their defaults
DATA_KEYS = keys_read_by("data")
DATA_SECTIONS = ("evaluation", "output")


@dataclass(frozen=True)
class Param:
    key: str
    low: float | None = None
    high: float | None = None
    log: bool = False
    shape: tuple[float, ...] | None = None
    choices: tuple | None = None

    def suggest(self, trial):
        if self.choices is not None:
            return trial.suggest_categorical(self.key, list(self.choices))
        return trial.suggest_float(self.key, self.low, self.high, log=self.log)

    def value(self, v):
        """The configuration value of a sampled ``v`` (a vector key: ``v`` times the shape)."""
        return [float(v) * s for s in self.shape] if self.shape is not None else v


@dataclass(frozen=True)
class Space:
    path: str
    params: tuple[Param, ...]
    fixed: dict

    def overrides(self, sampled: dict) -> dict:
        """``--set``-style overrides of one trial: the fixed keys and the sampled values."""
        by_key = {p.key: p for p in self.params}
        return {**self.fixed, **{k: by_key[k].value(v) for k, v in sampled.items()}}

    def digest(self) -> str:
        """Equal for equal spaces: a study resumed with another space is refused."""
        body = {"params": [p.__dict__ for p in self.params], "fixed": self.fixed}
        return hashlib.sha256(json.dumps(body, sort_keys=True, default=str).encode()).hexdigest()[:12]


def load_space(path: Path) -> Space:
    body = read_yaml(path, "tune space")
    where = str(path)
    if not isinstance(body, dict) or not isinstance(body.get("params"), dict) or not body["params"]:
        raise ConfigError(f"{where}: a tune space is a mapping with 'params' (config key: {{low, high, log}})")
    bad = set(body) - {"params", "fixed"}
    if bad:
        raise ConfigError(f"{yaml_lines.at(path, body, sorted(bad)[0])}: unknown key {sorted(bad)[0]!r} (known: params, fixed)")
    known = schema()

    def tunable(key: str, at: str) -> None:
        if key not in known:
            raise ConfigError(f"{at}: unknown configuration key {key!r}")
        if key in DATA_KEYS or key.split(".")[0] in DATA_SECTIONS:
            raise ConfigError(f"{at}: {key} changes the data or how it is scored, not the filter's belief: "
                              "it cannot be tuned")

    params = []
    for key, spec in body["params"].items():
        at = yaml_lines.at(path, body["params"], key)             # file:line of this key, for its errors
        tunable(key, at)
        if not isinstance(spec, dict):
            raise ConfigError(f"{at}: {key} needs {{low, high, log}} or {{choices}}, got {spec!r}")
        if "choices" in spec:
            ch = spec["choices"]
            if not isinstance(ch, list) or len(ch) < 2 or set(spec) - {"choices"}:
                raise ConfigError(f"{at}: {key}: 'choices' must be a list of at least two values, alone")
            choices = tuple(check_value(key, known[key], c, at) for c in ch)
            if len(set(map(repr, choices))) != len(choices):    # (a sweep's grid refuses them too)
                raise ConfigError(f"{at}: {key}: 'choices' lists a value twice: {ch!r}")
            params.append(Param(key, choices=choices))
            continue
        if set(spec) - {"low", "high", "log", "shape"}:
            raise ConfigError(f"{at}: {key}: unknown field {sorted(set(spec) - {'low', 'high', 'log', 'shape'})[0]!r} "
                              "(known: low, high, log, shape, or choices)")
        try:
            low, high = float(spec["low"]), float(spec["high"])
        except (KeyError, TypeError, ValueError):
            raise ConfigError(f"{at}: {key} needs numbers low and high, got {spec!r}") from None
        log = spec.get("log", False)
        if not isinstance(log, bool):
            raise ConfigError(f"{at}: {key}: log must be true or false, got {log!r}")
        if not (math.isfinite(low) and math.isfinite(high)):
            raise ConfigError(f"{at}: {key}: low and high must be finite numbers, got [{low:g}, {high:g}]")
        if not (low < high and (low > 0 or not log)):
            raise ConfigError(f"{at}: {key}: the range must be low < high{' with low > 0 (log scale)' if log else ''}, "
                              f"got [{low:g}, {high:g}]")
        shape = spec.get("shape")
        if shape is not None:
            if not isinstance(shape, list) or not all(isinstance(s, (int, float)) and not isinstance(s, bool)
                                                      and s > 0 for s in shape):
                raise ConfigError(f"{at}: {key}: shape must be a list of positive numbers, got {shape!r}")
            shape = tuple(float(s) for s in shape)
        p = Param(key, low, high, log, shape)
        for v in (low, high):
            check_value(key, known[key], p.value(v), at)
        params.append(p)
    fixed = body.get("fixed") or {}
    if not isinstance(fixed, dict):
        raise ConfigError(f"{yaml_lines.at(path, body, 'fixed')}: 'fixed' must map configuration keys to values")
    for key, v in fixed.items():
        at = yaml_lines.at(path, fixed, key)
        tunable(key, at)
        fixed[key] = check_value(key, known[key], v, at)
    overlap = set(fixed) & {p.key for p in params}
    if overlap:
        raise ConfigError(f"{yaml_lines.at(path, fixed, sorted(overlap)[0])}: {sorted(overlap)[0]} is both tuned and fixed")
    return Space(where, tuple(params), dict(fixed))
