"""The evaluation layer: evo's metrics (the only door to evo, :mod:`.trajectory`), the metric names
(:mod:`.keys`), and what evo lacks: the KITTI drift metric (:mod:`.drift`), 4-DoF alignment
(:mod:`.alignment`), NEES/NIS (:mod:`.consistency`), the per-segment breakdown (:mod:`.segments`) and a
run's whole evaluation (:mod:`.run_metrics`).

The names below load :mod:`.trajectory` (and evo) on first use, so that reading metric names
(``fusion-eval check``) does not import evo.
"""

_LAZY = ("STATS", "EstimateEvaluation", "associate", "evaluate", "ratio", "to_evo")


def __getattr__(name: str):
    if name in _LAZY:
        from . import trajectory

        return getattr(trajectory, name)
    raise AttributeError(name)


__all__ = list(_LAZY)
