"""One configuration key's specification (:class:`Spec`): the leaf every module that declares keys imports.

The configuration (:mod:`fusion_eval.config`) assembles the schema from the core keys and the keys the
registered formulations, observations and simulated sensors declare with :func:`S` in their own modules.
"""

from __future__ import annotations

from typing import Any, NamedTuple


class Spec(NamedTuple):
    """One configuration key: default, meaning, and what values it accepts.

    ``kind``: ``choice`` (one of ``choices``), ``bool``, ``int``, ``float``, ``vec3`` (3 numbers, or one
    number for all three), ``windows`` (list of ``[start, end]``), ``jumps``. ``auto`` admits the string
    'auto', ``nullable`` admits null; ``positive``/``nonneg``/``below``/``above`` bound numbers (strictly).
    ``reads``: who reads the key, where that decides how runs may share work. ``filter``: only the filter (its noise,
    gates, initial uncertainty), so a sweep's runs differing only in such keys share one preparation of the data
    (:func:`fusion_eval.batch.batch_key`); ``data``: it changes the data the filter is given (a simulated degradation
    of a stream), so ``tune`` refuses to tune it. Empty: the preparation or the evaluation reads it too.
    ``only_with``: ``(key, value)``: the key does something only where that key has that value (the Gauss-Markov
    correlation times under ``filter.bias_model: gauss_markov``); set otherwise it is said to do nothing
    (:func:`fusion_eval.session.inactive_warnings`).
    """

    default: Any
    doc: str
    kind: str = "float"
    choices: tuple = ()
    positive: bool = False
    nonneg: bool = False
    nullable: bool = False
    auto: bool = False
    below: float | None = None
    above: float | None = None
    reads: str = ""
    only_with: tuple = ()


def S(default, doc, kind=None, *, below_one: bool = False, **kw) -> Spec:
    if kind is None:
        kind = {bool: "bool", int: "int", float: "float", list: "vec3", str: "choice"}.get(type(default), "float")
    if below_one:
        kw["below"] = 1.0
    return Spec(default, doc, kind, **kw)
