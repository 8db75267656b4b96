"""The time span every estimate of a report is scored over.

A ratio "fused / lidar" compares like with like only on the same stretch of road: the fused estimate runs from
the first IMU sample to the last, the lidar from its anchor to its last scan, the GNSS stream from its first fix
to its last (before the rate and outages a run configures: :func:`stream_coverage`). ``evaluation.span: common``
(the default) scores every estimate over the intersection of their coverage with the ground truth; ``own`` scores
each over its own poses.

The span is applied as evo's ``--t_start``/``--t_end`` are: the reference is reduced to the time range
(``reduce_to_time_range``) before association, so ``evo_ape tum groundtruth.tum fused.tum --t_start T0 --t_end T1``
on the written files reproduces the metrics. The ends are rounded outwards to the microsecond, so that the
file's 9-decimal stamps and the in-memory ones fall on the same side of them.
"""

from __future__ import annotations

import math

from ..errors import DataRangeError
from ..types import PoseSeries

MODES = ("common", "own")


def coverage(series: PoseSeries) -> tuple[float, float]:
    return float(series.t_s[0]), float(series.t_s[-1])


def stream_coverage(name: str, series: PoseSeries, applied: dict) -> tuple[float, float]:
    """A stream's extent for the common span: the GNSS's before the configured outages and rate (an outage to the
    end of the drive is the GNSS-denied stretch a user means to score, not the end of the stream; it had every
    estimate scored without it)."""
    if name == "gnss" and applied.get("gnss_coverage_s"):
        a, b = applied["gnss_coverage_s"]
        return float(a), float(b)
    return coverage(series)


def _names(names: list[str]) -> str:
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def common_span(gt: PoseSeries, spans: dict[str, tuple[float, float]]) -> dict:
    """The intersection of the estimates' spans (``name -> (t0, t1)``) with the ground truth's, and which
    estimate limits each end."""
    ends = {"groundtruth": coverage(gt), **spans}
    t0, t1 = max(a for a, _ in ends.values()), min(b for _, b in ends.values())
    # every estimate at the limit is named: one of two that started together was named, the lidar by run and the
    # filter by compare, for the same stamp (a student's review)
    lo_by = _names([n for n, (a, _) in ends.items() if a == t0])
    hi_by = _names([n for n, (_, b) in ends.items() if b == t1])
    if not t1 > t0:
        raise DataRangeError(f"the estimates share no time span with each other and the ground truth "
                             f"({', '.join(f'{k} {a:.3f}..{b:.3f} s' for k, (a, b) in spans.items())})")
    g0 = coverage(gt)[0]
    t0, t1 = math.floor((t0 - 1e-6) * 1e6) / 1e6, math.ceil((t1 + 1e-6) * 1e6) / 1e6
    return {"mode": "common", "t0_s": t0, "t1_s": t1, "duration_s": t1 - t0, "start_set_by": lo_by, "end_set_by": hi_by,
            "from_groundtruth_start_s": [t0 - g0, t1 - g0]}


def crop(series: PoseSeries, span: dict | None) -> PoseSeries:
    """The poses inside the span, as evo's ``reduce_to_time_range`` keeps them (applied to the reference)."""
    if span is None:
        return series
    m = (series.t_s >= span["t0_s"]) & (series.t_s <= span["t1_s"])
    return series if m.all() else series.select(m)


def evo_options(span: dict | None) -> str:
    """The evo command-line options that score a written trajectory over the same span."""
    return "" if span is None else f"--t_start {span['t0_s']:.6f} --t_end {span['t1_s']:.6f}"


def describe(span: dict | None) -> str:
    if span is None:
        return "each estimate over its own poses (evaluation.span=own)"
    # a start a rounding before the truth's read "-0.00 .. 114.85 s" (a review): rounded first, then +0.0 drops the sign
    a, b = (round(v, 2) + 0.0 for v in span["from_groundtruth_start_s"])
    return (f"every estimate over the same {span['duration_s']:.1f} s, {a:.2f} .. {b:.2f} s after the ground truth's first "
            f"pose (start set by {span['start_set_by']}, end by {span['end_set_by']}; evaluation.span=common; evo_ape / evo_rpe "
            f"on the written files: `{evo_options(span)}`; fusion-eval evaluate: `{evo_options(span).replace('_', '-')}`)")


def span_for(mode: str, gt: PoseSeries, spans: dict[str, tuple[float, float]]) -> dict | None:
    return common_span(gt, spans) if mode == "common" else None


# the share of the IMU's time with the ground truth below which the common span is said to be short: a 1 Hz GNSS or
# a lidar starting after the vehicle moved costs seconds of a drive (the highway drive's lidar: 94 %)
MIN_COVERED = 0.8


def short_span_warning(sp: dict | None, gt: PoseSeries, imu: tuple[float, float],
                       streams: dict[str, tuple[float, float]] | None = None) -> str | None:
    """A data warning when the common span covers less than :data:`MIN_COVERED` of the longest input stream (the
    ground truth, the IMU's first and last samples ``imu``, and ``streams``, the other inputs' coverage): a lidar
    stream overlapping the drive's last 2 s (a clock offset, a cut file) had every figure scored over 2 s of 470, and an
    IMU or a ground truth cut short (30 s of a 60 s drive; 6 s; 2 rows) was scored over its stub with no word, the
    share being taken of the time they shared (a corrupted-input review)."""
    if sp is None:
        return None
    ends = {"ground truth": coverage(gt), "IMU": imu, **(streams or {})}
    longest = max(ends, key=lambda n: ends[n][1] - ends[n][0])
    full = ends[longest][1] - ends[longest][0]
    if not full > 0 or sp["duration_s"] >= MIN_COVERED * full:
        return None
    a, b = (round(v, 1) + 0.0 for v in sp["from_groundtruth_start_s"])
    cover = ", ".join(f"{n} {e[1] - e[0]:.1f} s" for n, e in ends.items())
    by = sp["start_set_by"]
    return (f"every estimate is scored over {sp['duration_s']:.1f} s only ({a:.1f} .. {b:.1f} s after the ground truth's "
            f"first pose) of the {full:.1f} s the {longest} covers ({cover}): {by} {'set' if ' and ' in by else 'sets'} "
            f"its start and {sp['end_set_by']} its end (a clock offset, or a stream cut short?); evaluation.span=own "
            "scores each estimate over its own poses")
