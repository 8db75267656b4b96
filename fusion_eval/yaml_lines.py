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
        self.empty: set = set()                  # keys written with no value at all (YAML's null, rarely meant)


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
    _refuse_repeated_keys(loader, node)
    loader.flatten_mapping(node)                 # merge keys (<<) first, as construct_mapping does
    data.update(loader.construct_mapping(node))
    for key_node, value_node in node.value:
        try:
            key = loader.construct_object(key_node)
            data.lines[key] = key_node.start_mark.line + 1    # the last one wins, as for the value
            if isinstance(value_node, yaml.ScalarNode) and value_node.value == "" and not value_node.style:
                data.empty.add(key)
        except TypeError:                        # an unhashable key: construct_mapping has already refused it
            pass


def _refuse_repeated_keys(loader: _Loader, node: yaml.MappingNode) -> None:
    """A key written twice in one mapping is an error: YAML loaders keep the last and drop the first without a
    word, so a second ``filter:`` section silently threw away the first (GNSS fused although the first said
    ``use_gnss: false``). Keys brought in by a merge (``<<: *base``) may be overridden, as YAML intends."""
    first: dict = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
            continue
        if _exp_only(key_node) or _yaml11_only(key_node):
            # a key is a name, not a number: a sweep's setting '1e-3' or '01' stays as written (YAML 1.2's floats
            # and the refusal of 1.1's octal and base-60 forms apply to values)
            key_node.tag = "tag:yaml.org,2002:str"
        key = loader.construct_object(key_node)
        try:
            hash(key)
        except TypeError:                        # construct_mapping refuses it in its own words
            continue
        if key in first:
            line, text = first[key]
            same = "" if text == key_node.value else f" as {text!r}, the same key once read"
            raise yaml.constructor.ConstructorError(
                None, None, f"key {key_node.value!r} given twice (first at line {line}{same}; only one may stand)",
                key_node.start_mark)
        first[key] = (key_node.start_mark.line + 1, key_node.value)


# YAML 1.2's floats: PyYAML (YAML 1.1) reads 1e-3 (no point) and 1.0e3 (no sign in the exponent) as strings, so a
# manifest's time_offset_s: 1e-3 was refused while --set took it; every value read here takes them as numbers
_FLOAT_12 = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$")
_FLOAT_11 = re.compile(r"^[-+]?(?:[0-9][0-9_]*)?\.[0-9_]*(?:[eE][-+][0-9]+)?$")


def _exp_only(node) -> bool:
    """A plain scalar that only YAML 1.2 reads as a float."""
    return (isinstance(node, yaml.ScalarNode) and not node.style and node.tag == "tag:yaml.org,2002:float"
            and bool(_FLOAT_12.match(node.value)) and not _FLOAT_11.match(node.value))


def _yaml11_only(node) -> bool:
    """A plain scalar in YAML 1.1's base-60 (``1:30``) or leading-zero octal (``010``) form."""
    if not (isinstance(node, yaml.ScalarNode) and not node.style and node.tag.rsplit(":", 1)[-1] in ("int", "float")):
        return False
    v = node.value.replace("_", "")
    return ":" in v or bool(re.match(r"^[-+]?0[0-7]+$", v))


def _number(loader: _Loader, node: yaml.ScalarNode):
    """YAML 1.1's integers and floats, but not its base-60 (``1:30`` = 90) and leading-zero octal (``010`` = 8)
    forms as values: nobody writing a configuration means those, and they read as plausible numbers (YAML 1.2
    dropped them); as keys they are names (:func:`_refuse_repeated_keys`)."""
    v = node.value.replace("_", "")
    if _yaml11_only(node):
        raise yaml.constructor.ConstructorError(
            None, None, f"{node.value!r} reads as a YAML 1.1 {'base-60' if ':' in v else 'octal'} number; quote it for "
            "text, or write the number in decimal", node.start_mark)
    ctor = _SafeLoader.construct_yaml_int if node.tag.endswith(":int") else _SafeLoader.construct_yaml_float
    return ctor(loader, node)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)
_Loader.add_constructor("tag:yaml.org,2002:int", _number)
_Loader.add_constructor("tag:yaml.org,2002:float", _number)
_Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))
for _d in {yaml.SafeDumper, _SafeDumper}:
    _d.add_representer(LineDict, yaml.representer.SafeRepresenter.represent_dict)


class _Dumper(_SafeDumper):
    """The safe dumper that quotes a string :func:`load` would read as a number ('1e5', a commit hash '1234e56')."""


_Dumper.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))


def dump(data: Any, sort_keys: bool = False) -> str:
    """``yaml.safe_dump(data, sort_keys=sort_keys)``, the same text (by libyaml where available), but for the
    quotes around a string that :func:`load` would read as a number."""
    return yaml.dump(data, Dumper=_Dumper, sort_keys=sort_keys)


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
