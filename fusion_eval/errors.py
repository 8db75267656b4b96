"""The one exception hierarchy of fusion-eval.

The CLI turns every :class:`FusionEvalError` into a one-line message and the exit code the
class carries; anything else that escapes is a bug and keeps its traceback.
"""

from __future__ import annotations

import reprlib
from pathlib import Path


class FusionEvalError(Exception):
    """Base class of every error the user can act on."""

    exit_code = 2


_SHOWN = reprlib.Repr()
_SHOWN.maxlevel, _SHOWN.maxlist, _SHOWN.maxtuple, _SHOWN.maxdict, _SHOWN.maxset = 3, 6, 6, 6, 6
_SHOWN.maxstring, _SHOWN.maxother, _SHOWN.maxlong = 80, 80, 40
# reprlib picks its bounded form by the type's name: the YAML loader's mappings (yaml_lines.LineDict) would fall back
# to the full repr, 600 MB and 6.7 s for a 649-byte YAML of nested mapping aliases (a review)
_SHOWN.repr_LineDict = _SHOWN.repr_dict
MAX_MESSAGE = 2000        # characters of an error's one line: beyond, it is cut (a value echoed whole ran to 254 MB)


def shown(value) -> str:
    """A value as an error message quotes it: its repr, bounded in depth, length and digits (``[1, 2, ...]``). A
    300-byte YAML of nested aliases expanded to a 254 MB message, and to 24 GB and the OOM killer one level deeper (a
    corrupted-input review); an integer of thousands of digits has no repr at all."""
    try:
        return _SHOWN.repr(value)
    except ValueError:                 # an int beyond Python's limit on digits for str()
        return f"<an integer of {value.bit_length()} bits>" if isinstance(value, int) else f"<a {type(value).__name__}>"


def one_line(message: str) -> str:
    """A message on one line of at most :data:`MAX_MESSAGE` characters (the cut said)."""
    text = " ".join(message.split())
    return text if len(text) <= MAX_MESSAGE else f"{text[:MAX_MESSAGE]} ... ({len(text) - MAX_MESSAGE} characters cut)"


def place(source: str, line: int | str | None) -> str:
    """Where in an input: ``file:line``, or for a bag topic (``drive.bag (topic /imu)``) its message number,
    ``drive.bag (topic /imu, message 5000)``: a bag's refusals named the topic alone, unusable in an hour's bag."""
    source = str(source)
    if line is None:
        return source
    if source.endswith(")") and " (topic " in source:
        return f"{source[:-1]}, message {line})"
    return f"{source}:{line}"


class DataFormatError(FusionEvalError):
    """An input file does not have the expected content.

    The message names the file, the 1-based line (when there is one) and what was expected,
    like ``oxts/data/0000000012.txt:1: expected 30 values per packet, got 29``.
    """

    def __init__(self, path: str | Path | None, line: int | None, expected: str):
        self.path = None if path is None else str(path)
        self.line = line
        self.expected = expected
        super().__init__(f"{place(self.path or '<input>', line)}: {expected}")

    def __reduce__(self):
        # rebuilt from its three fields, not from the message alone: raised in a worker, it travels back through the
        # pool's pickle as the same error (a message-only rebuild failed there and broke the pool with a traceback)
        return type(self), (self.path, self.line, self.expected)


class MissingTopicError(DataFormatError):
    """A bag holds no topic of the name asked for: where a manifest named it, the manifest's line is the place to fix."""


class ConfigError(FusionEvalError):
    """A configuration or manifest key is unknown, missing or has a wrong value."""


class DataRangeError(FusionEvalError):
    """Streams that must overlap in time do not, or too little data is left to work with."""


class ShiftAtSearchEdgeError(DataRangeError):
    """Two streams' signals match best at the end of the searched time shifts: their clocks or axes do not meet."""


class FilterDivergedError(FusionEvalError):
    """The filter produced a non-finite or non-positive-definite state."""

    exit_code = 3


class OutputError(FusionEvalError):
    """The output directory cannot be written as asked (exists, not writable)."""
