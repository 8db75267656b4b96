"""YAML mappings that remember their lines, so that a bad value in a configuration or a dataset manifest is
reported as ``file:line: what was expected`` like a bad line of a data file.

:func:`load` is ``yaml.safe_load`` whose mappings are :class:`LineDict` (plain dicts otherwise: equality, JSON and
``yaml.safe_dump`` see a dict); :func:`at` names a key's place, ``path:line``, or the path alone for a mapping that
did not come from a file (``--set`` values, built-in layers).
"""

from __future__ import annotations

import re
from typing import Any

import yaml


class LineDict(dict):
    """A YAML mapping: ``line`` is the 1-based line it starts on, ``lines`` each key's line."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.line: int | None = None
        self.lines: dict = {}


# libyaml's parser and emitter where PyYAML was built with it (the wheels are): the same documents and the same
# text, 5x faster than the pure-Python ones (a run's resolved configuration took 6 ms to write, 1 ms with libyaml)
_SafeLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_SafeDumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


class _Loader(_SafeLoader):
    pass


def _mapping(loader: _Loader, node: yaml.MappingNode):
    data = LineDict()
    data.line = node.start_mark.line + 1
    yield data                                   # as PyYAML's own constructor: anchors may refer to it
    loader.flatten_mapping(node)                 # merge keys (<<) first, as construct_mapping does
    data.update(loader.construct_mapping(node))
    for key_node, _ in node.value:
        try:
            key = loader.construct_object(key_node)
            data.lines[key] = key_node.start_mark.line + 1    # the last one wins, as it does for the value
        except TypeError:                        # an unhashable key: construct_mapping has already refused it
            pass


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)
# YAML 1.2's floats: PyYAML (YAML 1.1) reads 1e-3 (no point) and 1.0e3 (no sign in the exponent) as strings, so a
# manifest's time_offset_s: 1e-3 was refused while --set took it; every file read here takes them as numbers
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))
for _d in {yaml.SafeDumper, _SafeDumper}:
    _d.add_representer(LineDict, yaml.representer.SafeRepresenter.represent_dict)


def dump(data: Any, sort_keys: bool = False) -> str:
    """``yaml.safe_dump(data, sort_keys=sort_keys)``, the same text (by libyaml where available)."""
    return yaml.dump(data, Dumper=_SafeDumper, sort_keys=sort_keys)


def load(text: str) -> Any:
    """``yaml.safe_load(text)`` with :class:`LineDict` mappings."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass


def line_of(mapping: Any, key: Any = None) -> int | None:
    """The line of ``key`` in ``mapping`` (of the mapping itself when ``key`` is None or not in it), if known."""
    if not isinstance(mapping, LineDict):
        return None
    if key is not None and key in mapping.lines:
        return mapping.lines[key]
    return mapping.line


def at(path: Any, mapping: Any = None, key: Any = None) -> str:
    """``path:line`` of ``key`` in ``mapping`` (see :func:`line_of`), or ``path`` when the line is unknown."""
    line = line_of(mapping, key)
    return f"{path}" if line is None else f"{path}:{line}"
