"""The one place a run's configuration is assembled, for ``run``, ``compare``, ``sweep``, the Python API
and the tests.

Layers, later ones winning: the built-in defaults < the dataset manifest's suggested settings (``config:``)
< the base configuration (``--config``, a sweep's ``config:``) < the variant < the overrides (``--set``
items, or plain Python values through the API). Everything the user gave is validated when the request is
made (:func:`request`), before any data is read; the manifest's layer joins when the dataset is known
(:func:`resolve`). Gravity ``auto`` needs no second pass: the prepared run resolves it from the dataset's
geodetic origin.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from . import yaml_lines
from .errors import ConfigError
from .config import Layer, merge_layers, parse_file, parse_overrides, parse_sets, validate
from .types import Dataset

_log = logging.getLogger(__name__)
_SAID: set = set()


@dataclass(frozen=True)
class ConfigRequest:
    """The user's layers (validated) and the name the run reports its configuration by."""

    layers: tuple[Layer, ...]
    source: str = "default"


def request(config: Path | dict | None = None, variant: Path | None = None, sets: tuple[str, ...] = (),
            overrides: dict | None = None) -> ConfigRequest:
    """Validate the user's layers: a base configuration (a file, or a ``{section: {key: value}}`` dict), a
    variant file, ``--set`` items and Python overrides (``{"gnss.rate_hz": 2.0}``)."""
    from . import resources

    layers: list[Layer] = []
    source = "default"
    if isinstance(config, dict):
        layers.append(validate(config, "config"))
    elif config is not None:
        layers.append(parse_file(resources.find(config)))     # e.g. configs/lidar-imu.yaml from any directory
        source = Path(config).stem
    if variant is not None:
        layers.append(parse_file(resources.find(variant)))
        source = Path(variant).stem
    if sets:
        layers.append(parse_sets(tuple(sets)))
    if overrides:
        layers.append(parse_overrides(overrides))
    return ConfigRequest(tuple(layers), source)


def config_file(req: ConfigRequest) -> dict:
    """The request's own layers merged, ``{section: {key: value}}`` without the built-in defaults: what a
    ``best.yaml`` (of a sweep or a tune) holds, so that ``run -c best.yaml`` runs the same configuration."""
    out: dict = {}
    for layer in req.layers:
        for sect, body in layer.body.items():
            out.setdefault(sect, {}).update(body)
    return out


def manifest_layer(ds: Dataset) -> tuple[Layer, ...]:
    body = ds.description.get("config")
    # errors name the manifest's line when its 'config' mapping came from a file (it knows its lines); a built-in
    # manifest (a plain KITTI raw or EuRoC folder) has none, and is named as the suggested config of that folder
    where = str(ds.description["manifest"]) + ("" if yaml_lines.line_of(body) else " (config)")
    if body:
        _refuse_two_values(ds, body, where)
    return (validate(body, where),) if body else ()


def _refuse_two_values(ds: Dataset, body: dict, where: str) -> None:
    """A manifest that gives a stream's offset or lag twice, in its stream entry and in its 'config' section, with two
    values: the config's won and the stream's was ignored with no word (a simulated drive's config.imu.gyro_lag_s: 0.0
    hid a streams.imu.gyro_lag_s: 0.3 that moved its APE from 0.686 to 0.917 m: a corrupted-input review)."""
    from .errors import ConfigError

    streams = ds.description.get("streams") or {}
    for sect, keys in body.items():
        spec = streams.get(sect)
        if not isinstance(spec, dict) or not isinstance(keys, dict):
            continue
        for key in ("time_offset_s", "gyro_lag_s", "accel_lag_s"):
            if key in spec and keys.get(key) is not None and keys[key] != spec[key]:
                raise ConfigError(f"{yaml_lines.at(where, keys, key)}: config {sect}.{key} = {keys[key]!r} and the stream "
                                  f"entry's {key} = {spec[key]!r} ({yaml_lines.at(ds.description['manifest'], spec, key)}) "
                                  "both set it; the config's would win: give it once")


def resolve(req: ConfigRequest, ds: Dataset) -> dict:
    """The resolved (human-unit) configuration of a run of ``ds``."""
    from .filters import observations

    cfg = merge_layers([*manifest_layer(ds), *req.layers])
    _other_dataset(req, ds)
    for o in observations.REGISTRY:
        o.resolve_for(cfg, ds.description)
    return cfg


def inactive_warnings(ds: Dataset, cfg: dict) -> list[str]:
    """The settings that do nothing in this configuration (:func:`fusion_eval.filters.observations.inactive_settings`),
    for a run's data warnings: in the report, the run's metrics and a sweep's summary (logged where the configuration
    was resolved they reached none of them, and a sweep said them twice: a review of the diff). Not in the prepared
    data's: a sweep's batch shares one preparation among runs that differ in exactly such keys. Those the user gave:
    the values off their defaults that are not the dataset manifest's own suggestions (which a run's
    config.resolved.yaml repeats)."""
    from .config import get, schema
    from .filters import observations

    suggested = {f"{sect}.{k}": v for layer in manifest_layer(ds) for sect, body in layer.body.items()
                 for k, v in body.items()}
    sch = schema()
    given = {f"{sect}.{k}": v for sect, body in cfg.items() if isinstance(body, dict) for k, v in body.items()
             if f"{sect}.{k}" in sch and v != sch[f"{sect}.{k}"].default
             and not (f"{sect}.{k}" in suggested and suggested[f"{sect}.{k}"] == v)}
    out = observations.inactive_settings(cfg, given)
    for key, v in given.items():          # keys declared to act only under another key's value
        cond = sch[key].only_with
        if cond:
            has = get(cfg, cond[0])           # (a declared key: every resolved configuration holds it)
            if has != cond[1]:
                out.append(f"{key}={v} does nothing here: it applies only with {cond[0]}={cond[1]} (this configuration "
                           f"has {cond[0]}={has})")
    return out


def _other_dataset(req: ConfigRequest, ds: Dataset) -> None:
    """A ``config.resolved.yaml`` given with ``-c`` and no DATASET ran the default dataset with no word, whatever drive
    the file was written for (a reproducibility review): said, naming both."""
    if not ds.description.get("default_dataset"):
        return
    for layer in req.layers:
        ran = (layer.dataset or {}).get("name")
        if ran is not None and ran != ds.name and (layer.where, ran) not in _SAID:
            _SAID.add((layer.where, ran))        # once: compare resolves one request per variant
            _log.warning(
                "%s was written by a run on the dataset %r (%s); with no DATASET given this one runs the default, %r: "
                "give the DATASET to run that drive again", layer.where, ran, (layer.dataset or {}).get("path"), ds.name)


def dataset(path: str | Path | None = None) -> Dataset:
    """The dataset at ``path`` (a folder with a manifest, a manifest file, or a raw KITTI drive folder; a
    relative path not found in the working directory is looked up in the shipped tree); None: the default."""
    from . import resources
    from .datasets.manifest import load_dataset

    p = resources.default_dataset() if path is None else resources.find(path)
    ds = load_dataset(p)
    ds.description.setdefault("path", str(p))
    if path is None:
        ds.description["default_dataset"] = True
    return ds


def same_evaluation(labels: list[str], cfgs: list[dict], where: str, why: str, keys: tuple[str, ...] | None = None
                    ) -> None:
    """Refuse configurations that are ranked against each other but scored differently (``evaluation.*``, or only
    its ``keys``), naming the first key and the two labels (``compare``'s variants, a ``sweep``'s runs of one
    dataset): such a ranking compared an aligned APE with an unaligned one."""
    first = cfgs[0]["evaluation"]
    for label, c in zip(labels[1:], cfgs[1:]):
        diff = sorted(k for k in set(first) | set(c["evaluation"])
                      if (keys is None or k in keys) and first.get(k) != c["evaluation"].get(k))
        if diff:
            k = diff[0]
            raise ConfigError(f"{where}: {label} sets evaluation.{k} = {c['evaluation'].get(k)!r} and {labels[0]} "
                              f"{first.get(k)!r}: {why}")
