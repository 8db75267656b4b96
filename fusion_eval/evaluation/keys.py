"""The names of every metric, in one place.

A run's ``metrics.json`` holds, per estimate, groups (``ape``, ``rpe_1frame``, ``rpe_<delta>m``) of
relations (``translation_m``, ``rotation_deg``) of statistics (``rmse`` ... ``max``), plus ``kitti_drift``.
``check`` addresses them by dotted paths (``fused.ape.translation_m.rmse``), a sweep's CSV by column names
(``fused_ape_trans_rmse_m``). The distance of the per-distance RPE is a setting
(``evaluation.rpe_delta_m``), so every name that contains it comes from :func:`rpe_distance_group`;
``metrics.json`` records the setting (``evaluation.rpe_delta_m``) for readers of the file.
"""

from __future__ import annotations

import re

STATS = ("rmse", "mean", "median", "std", "min", "max")
APE = "ape"
RPE_FRAME = "rpe_1frame"
RELATIONS = {"translation_m": ("trans", "m"), "rotation_deg": ("rot", "deg")}
# evo's pose relations (``evo_ape -r``), the key each has in metrics.json and the name of its result file
RELATION_KEYS = {"trans_part": "translation_m", "angle_deg": "rotation_deg", "angle_rad": "rotation_rad",
                 "rot_part": "rotation_part", "full": "full_transformation", "point_distance": "point_distance_m"}
RESULT_NAMES = {"translation_m": "translation", "rotation_deg": "rotation", "rotation_rad": "rotation_rad",
                "rotation_part": "rotation_part", "full_transformation": "full_transformation",
                "point_distance_m": "point_distance"}
POSITION_RELATIONS = ("trans_part", "point_distance")     # defined for position-only estimates
DEFAULT_RELATIONS = ("trans_part", "angle_deg")
DEFAULT_RPE_DELTA_M = 100.0


# how each evaluation.alignment reads in a table's heading or caption
ALIGNMENT_WORDS = {"none": "no alignment", "origin": "aligned at the first pose", "se3": "SE(3) alignment (Umeyama)",
                   "sim3": "Sim(3) alignment (Umeyama, with scale)", "scale": "scale alignment",
                   "4dof": "4-DoF alignment (yaw and translation)"}


def alignment_words(alignment: str) -> str:
    """'no alignment', 'SE(3) alignment (Umeyama)', ... for ``evaluation.alignment``."""
    return ALIGNMENT_WORDS.get(alignment, f"{alignment} alignment")


def rpe_distance_group(delta_m: float) -> str:
    """``rpe_100m`` for 100 m: the group of the per-distance RPE."""
    return f"rpe_{float(delta_m):g}m"


def groups(delta_m: float) -> tuple[str, str, str]:
    return APE, RPE_FRAME, rpe_distance_group(delta_m)


def rpe_delta_of(metrics: dict) -> float:
    """The per-distance RPE length a metrics dict was computed with (older files: 100 m)."""
    return float((metrics.get("evaluation") or {}).get("rpe_delta_m", DEFAULT_RPE_DELTA_M))


def column(estimate: str, group: str, relation: str, stat: str) -> str:
    """A sweep CSV column: ``fused_ape_trans_rmse_m``."""
    short, unit = RELATIONS[relation]
    return f"{estimate}_{group}_{short}_{stat}_{unit}"


def path(estimate: str, group: str, relation: str, stat: str) -> str:
    """A ``check`` path: ``fused.ape.translation_m.rmse``."""
    return f"{estimate}.{group}.{relation}.{stat}"


def summary_columns(delta_m: float) -> list[tuple[str, tuple]]:
    """The metric columns of a sweep's CSV and where each is in a ``metrics.json`` (``estimates`` -> path)."""
    d = rpe_distance_group(delta_m)
    cols = [(column("fused", APE, "translation_m", s), ("fused", APE, "translation_m", s)) for s in ("rmse", "mean", "max")]
    cols += [(column("fused", APE, "rotation_deg", "rmse"), ("fused", APE, "rotation_deg", "rmse")),
             (column("fused", RPE_FRAME, "translation_m", "rmse"), ("fused", RPE_FRAME, "translation_m", "rmse")),
             (column("fused", d, "translation_m", "rmse"), ("fused", d, "translation_m", "rmse")),
             ("fused_kitti_t_err_pct", ("fused", "kitti_drift", "t_err_pct")),
             ("fused_kitti_r_err_deg_per_100m", ("fused", "kitti_drift", "r_err_deg_per_100m")),
             (column("lidar", APE, "translation_m", "rmse"), ("lidar", APE, "translation_m", "rmse")),
             (column("gnss", APE, "translation_m", "rmse"), ("gnss", APE, "translation_m", "rmse"))]
    return cols


def smoothed_columns() -> list[tuple[str, tuple]]:
    """The sweep columns of a smoothed estimate (``smoother.method``), when the runs have one."""
    return [(column("smoothed", APE, "translation_m", "rmse"), ("smoothed", APE, "translation_m", "rmse")),
            (column("smoothed", APE, "rotation_deg", "rmse"), ("smoothed", APE, "rotation_deg", "rmse"))]


RANK_COLUMN = column("fused", APE, "translation_m", "rmse")   # what sweeps rank by


def check_patterns(delta_m: float) -> tuple[str, ...]:
    """The metrics ``check`` compares by default in a ``metrics.json``: the RMSE of APE and RPE of every
    estimate, and the ratios."""
    return (f"*.{APE}.translation_m.rmse", f"*.{APE}.rotation_deg.rmse", f"*.{RPE_FRAME}.translation_m.rmse",
            f"*.{rpe_distance_group(delta_m)}.translation_m.rmse", "ratios.*")


def csv_check_patterns() -> tuple[str, ...]:
    """The columns ``check`` compares by default in a sweep's CSV (the per-distance RPE of any length: a sweep
    may vary ``evaluation.rpe_delta_m``)."""
    return (f"*.{column('fused', APE, 'translation_m', 'rmse')}", f"*.{column('fused', APE, 'rotation_deg', 'rmse')}",
            f"*.{column('fused', RPE_FRAME, 'translation_m', 'rmse')}",
            f"*.{column('fused', 'rpe_*m', 'translation_m', 'rmse')}")


def is_number(v) -> bool:
    """A finite int or float (not a bool): a value a metric, a table or a plot can use."""
    import math

    try:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    except OverflowError:          # an integer beyond any float (a JSON number of 400 digits): no metric value
        return False


# figures that are not errors, so "lower is better" does not rank them: a NEES or NIS mean is best at its dof and a
# share inside the 95 % interval at 0.95 (check called a NEES share rising from 0.67 to 0.77 a regression, and a sweep
# ranked by it chose a setting with 33 % inside as best: a review); a sweep.csv's wall time is the machine's
_TWO_SIDED = re.compile(r"(^|\.)(nis|nees|nees_smoothed)\.[^.]+\.(mean|fraction_in_95)$|(^|\.)(nees|nis)_\w*_(mean|in95_frac)$")
_NOT_ERROR = re.compile(r"(^|\.)runtime_s$|_noise_(pos|att)_x$")


def not_an_error(key: str) -> str:
    """Why ``key`` (a check path, or a sweep.csv key ``run.column``) is no error figure, or "" where lower is better."""
    if _TWO_SIDED.search(key):
        return ("a consistency figure, best at its dof (a mean) or at 0.95 (a share inside the 95 % interval), not at "
                "0: gate it with --require (e.g. 'nees.position.fraction_in_95 > 0.9'), rank by the nis objective")
    if _NOT_ERROR.search(key):
        return ("the run's wall time on this machine, not an error figure" if key.endswith("runtime_s") else
                "an adapted noise's factor over its configured std, best near 1, not an error figure")
    return ""


def flatten(metrics: dict, raw: bool = False) -> dict[str, float]:
    """A ``metrics.json`` as ``{check path: value}``: ``<estimate>.<group>.<relation>.<stat>`` (and the translation
    part also as ``<estimate>.<group>.<stat>``), ``<estimate>.kitti_drift.<stat>``, ``ratios.<name>``,
    ``innovations.nll_per_update|nis_calibration`` (no ground truth needed), ``nis.<observation>.mean|fraction_in_95|nll_mean`` and ``nees.<position|attitude>.mean|fraction_in_95`` (``nees_smoothed.`` for the smoother's).
    Only finite numbers are kept, unless ``raw`` (every scalar at those paths as it is: NaN, strings, None), which
    ``check`` uses to say what is wrong with a baseline's value."""
    keep = (lambda v: not isinstance(v, (dict, list))) if raw else is_number
    conv = (lambda v: v) if raw else float
    out: dict = {}
    for est, d in (metrics.get("estimates") or {}).items():
        if not isinstance(d, dict):
            continue
        for group, rels in d.items():
            if not isinstance(rels, dict):
                continue
            for rel, stats in rels.items():
                if isinstance(stats, dict):
                    for stat, v in stats.items():
                        if keep(v):
                            out[f"{est}.{group}.{rel}.{stat}"] = conv(v)
                            if rel == "translation_m":
                                out[f"{est}.{group}.{stat}"] = conv(v)
                elif keep(stats) and group == "kitti_drift" and rel != "segments":
                    # the segment count is no error: a longer drive's more segments read as a regression under
                    # 'fused.kitti_drift.*' (a review)
                    out[f"{est}.{group}.{rel}"] = conv(stats)
    for k, v in (metrics.get("ratios") or {}).items():
        if keep(v):
            out[f"ratios.{k}"] = conv(v)
    for k, v in (metrics.get("innovations") or {}).items():
        if k != "updates" and keep(v):
            out[f"innovations.{k}"] = conv(v)
    for section in ("nis", "nees", "nees_smoothed"):
        for kind, d in (metrics.get(section) or {}).items():
            for k in ("mean", "fraction_in_95", "nll_mean"):
                if isinstance(d, dict) and k in d and keep(d.get(k)):
                    out[f"{section}.{kind}.{k}"] = conv(d[k])
    return out


class _EvoRelations(dict):
    """``RELATION_KEYS``' names -> evo's ``PoseRelation`` (evo imported on first use: ``--help`` stays fast)."""

    def __missing__(self, name: str):
        from evo.core.metrics import PoseRelation as R

        table = {"trans_part": R.translation_part, "angle_deg": R.rotation_angle_deg, "angle_rad": R.rotation_angle_rad,
                 "rot_part": R.rotation_part, "full": R.full_transformation, "point_distance": R.point_distance}
        self.update(table)
        return table[name]


EVO_RELATIONS = _EvoRelations()
