"""The evaluation of estimates against one reference (what ``fusion-eval evaluate`` and ``fusion_eval.evaluate``
report): evo's APE/RPE, the KITTI drift metric and the per-segment breakdown of each estimate."""

from __future__ import annotations

import math

from ..datasets.trajectory_file import BY_INDEX
from ..errors import ConfigError, DataFormatError
from ..types import PoseSeries
from . import keys
from .alignment import UP_AXES
from .run_metrics import estimate_metrics
from .segments import breakdown
from .trajectory import EstimateEvaluation, evaluate

ASSOCIATIONS = ("nearest", "interpolate")
ALIGNMENTS = ("none", "origin", "se3", "sim3", "scale", "4dof")
ENGINES = ("arrays", "evo")


def validate_options(association: str, alignment: str, t_max_diff_s: float, rpe_delta_m: float, segment_m: float,
                     segment_s: float | None, engine: str = "arrays", relations: tuple[str, ...] = keys.DEFAULT_RELATIONS,
                     up_axis: str = "auto", n_to_align: int = -1) -> None:
    """Refuse options ``evaluate`` cannot honour, naming the option."""
    if engine not in ENGINES:
        raise ConfigError(f"--engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    if association not in ASSOCIATIONS:
        raise ConfigError(f"--association must be one of {', '.join(ASSOCIATIONS)}, got {association!r}")
    if alignment not in ALIGNMENTS:
        raise ConfigError(f"--alignment must be one of {', '.join(ALIGNMENTS)}, got {alignment!r}")
    bad = [r for r in relations if r not in keys.RELATION_KEYS]
    if bad:
        raise ConfigError(f"--pose-relation must be among {', '.join(keys.RELATION_KEYS)}, got {bad[0]!r}")
    if up_axis not in UP_AXES:
        raise ConfigError(f"--up-axis must be one of {', '.join(UP_AXES)}, got {up_axis!r}")
    if n_to_align != -1 and not (isinstance(n_to_align, int) and n_to_align >= 3):
        raise ConfigError(f"--n-to-align must be -1 (all poses) or at least 3, got {n_to_align}")
    if n_to_align != -1 and alignment not in ("se3", "sim3", "scale", "4dof"):
        raise ConfigError(f"--n-to-align applies to the se3, sim3, scale and 4dof alignments, not {alignment!r}")
    for name, v in (("--t-max-diff", t_max_diff_s), ("--rpe-delta-m", rpe_delta_m), ("--segment-m", segment_m),
                    ("--segment-s", segment_s)):
        if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ConfigError(f"{name} must be a finite number > 0, got {v}")


def evaluate_series(ref, estimates: dict, association: str = "nearest",
                    alignment: str = "none", t_max_diff_s: float = 0.01, rpe_delta_m: float = 100.0,
                    segment_m: float = 100.0, segment_s: float | None = None,
                    about: dict | None = None, ref_stamps: str | None = None,
                    engine: str = "arrays", *, relations: tuple[str, ...] = keys.DEFAULT_RELATIONS,
                    up_axis: str = "auto", n_to_align: int = -1,
                    t_offset_s: float = 0.0, covariances: dict | None = None,
                    position_only: frozenset = frozenset(), ref_name: str = "reference"
                    ) -> tuple[dict, dict[str, EstimateEvaluation]]:
    """evo's APE/RPE, the KITTI drift metric and the per-segment breakdown of each estimate against ``ref``:
    the ``metrics.json`` of ``fusion-eval evaluate`` and the evaluations behind it. ``about`` adds, per
    estimate, where it came from (``file``, ``stamps``: how its stamps were obtained); stamps and frame indices
    are not mixed: matching a stamped trajectory to one matched by index would give meaningless numbers.
    ``position_only``: the estimates whose orientations are placeholders (APE translation only, as GNSS in a run);
    ``ref_name``: the reference's name in the evo result files."""
    about = about or {}
    for name, a in about.items():
        if ref_stamps is not None and (a.get("stamps") == BY_INDEX) != (ref_stamps == BY_INDEX):
            raise DataFormatError(a.get("file", name), None,
                                  "the reference and the estimates must both have stamps, or both be matched by index "
                                  "(give --times / --ref-times for KITTI pose files)")
    covariances = covariances or {}
    evals = {name: evaluate(ref, est, name, t_max_diff_s, rpe_delta_m, association, alignment, engine,
                            relations=relations, up_axis=up_axis, n_to_align=n_to_align, t_offset_s=t_offset_s,
                            cov=covariances.get(name), has_orientation=False if name in position_only else None,
                            ref_name=ref_name)
             for name, est in estimates.items()}
    if not isinstance(ref, PoseSeries):         # an evo trajectory as read: a series for the segment breakdown
        from .trajectory import from_evo

        ref = from_evo(ref, repeated_stamps=True)
    names = list(evals)
    errs = {k: (ev.ape_t_s, ev.ape_err_m) for k, ev in evals.items() if ev.ape_err_m is not None}
    seg = breakdown(ref, errs, segment_m, segment_s, primary=names[0], secondary=names[1] if len(names) > 1 else None,
                    parts={k: ev.ape_hv_m for k, ev in evals.items()}) if errs else None
    est_m = {k: {**(about.get(k) or {}), **estimate_metrics(ev)} for k, ev in evals.items()}
    metrics = {"evaluation": {"association": association, "alignment": alignment, "t_max_diff_s": t_max_diff_s,
                              "t_offset_s": t_offset_s, "rpe_delta_m": rpe_delta_m, "engine": engine,
                              "pose_relations": list(relations), "n_to_align": n_to_align,
                              **({"up_axis": up_axis} if alignment == "4dof" else {})},
               "estimates": est_m, "segments": seg}
    return metrics, evals
