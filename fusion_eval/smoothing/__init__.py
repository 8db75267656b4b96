"""Offline smoothing beside the filter (``smoother.method``): a registry of methods, each one module.

A method is a class with ``name``, ``check(cfg, formulation)`` (refuse, before any data is read, what it cannot do,
naming the keys) and, per replay, ``__init__(kf, s, n_events)``, ``epoch(kf)`` (after everything at a stamp),
``before_update(kf, bound, j)`` / ``after_update(kf, res)`` (around each update) and ``finish(kf, k0)`` returning
the smoothed record (:class:`.rts.Smoothed`) and what it did (a dict; keys ending in ``_s`` are timings).

* ``rts``: the Rauch-Tung-Striebel backward pass over the filter's own models (:mod:`.rts`, fed by :mod:`.record`);
* ``batch``: the GTSAM factor graph of every measurement the filter used (:mod:`.batch`).

The smoothed estimate is evaluated and reported like the fused one, under the name ``smoothed``.
"""

from __future__ import annotations


def methods() -> dict:
    from .batch import BatchSmoother
    from .rts import RtsSmoother

    return {m.name: m for m in (RtsSmoother, BatchSmoother)}


def check(cfg: dict, formulation) -> None:
    """Refuse a smoother that cannot run with this configuration (no-op for ``none``)."""
    name = cfg.get("smoother", {}).get("method", "none")
    if name != "none":
        methods()[name].check(cfg, formulation)


def start(kf, s, n_events: int):
    """The configured smoother attached to a filter about to replay ``n_events`` events, or None."""
    name = s.smoother.method
    return None if name == "none" else methods()[name](kf, s, n_events)
