"""Degradation of a measurement stream: decimation, white noise and outages, seeded and deterministic.

KITTI's OXTS "GNSS" is the GPS/INS solution that is also the ground truth; fusing it unchanged would be
circular. The noise is drawn after decimation and before the outages are cut, so adding an outage does not
change the noise of the fixes that remain. The same degradation serves every vector stream (GNSS position,
GNSS velocity, ...): :func:`degrade_vectors` works on any series with a value and a std field.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .types import GnssSeries


def _rate_hz(t_s: np.ndarray) -> float | None:
    """A stream's own rate: one over its median step (None for fewer than two samples or repeated stamps)."""
    step = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 0.0
    return 1.0 / step if step > 0 else None


def in_outages(t_s: np.ndarray, t_ref_s: float, outages_s) -> np.ndarray:
    """Which stamps lie inside one of the ``outages_s`` windows, ``[start, end)`` seconds after ``t_ref_s``."""
    out = np.zeros(len(t_s), bool)
    for a, b in outages_s:
        out |= (t_s >= t_ref_s + a) & (t_s < t_ref_s + b)
    return out


def keep_receiver(series, t_ref_s: float, outages_s, std_given, unit: str, std_field: str = "std"):
    """A receiver's stream (not marked for degradation): no noise, its own rate, but the user's outages cut and a given
    std in place of the reported one; with the description :func:`degrade_vectors` gives (``degraded`` False)."""
    s = series if std_given == "auto" else replace(series, **{std_field: np.tile(np.asarray(std_given, float),
                                                                                (len(series), 1))})
    out = in_outages(s.t_s, t_ref_s, outages_s)
    s = s.select(~out)
    return s, {"degraded": False, "fixes_used": len(s), "outages_s": [list(map(float, w)) for w in outages_s],
               "fixes_in_outages": int(out.sum()),
               f"std_given_to_filter_{unit}": "as the stream reports" if std_given == "auto" else std_given}


def not_degraded_note(section: str, values: dict, keys, what: str, example: str, source, rest: str) -> str | None:
    """The degradation's keys set off their defaults (``section.key`` of ``keys`` in ``values``) on a stream not marked
    for degradation, where they do nothing, as one sentence (None when none is): a sweep over gnss.rate_hz gave
    identical rows and ranked a 'best' among them with no word (a corrupted-input review)."""
    from .config import schema

    sch = schema()
    unused = [f"{section}.{k}={values[k]}" for k in keys if values[k] != sch[f"{section}.{k}"].default]
    if not unused:
        return None
    return (f"{' and '.join(unused)} {'apply' if len(unused) > 1 else 'applies'} only to {what} stream marked for "
            f"degradation ({example}): {source} {rest}")


def degrade_vectors(series, t_ref_s: float, rate_hz: float | None, noise_std, outages_s, rng: np.random.Generator,
                    std_given, unit: str, value_field: str = "values", std_field: str = "std"):
    """The degraded series and a description of what was applied (for the report).

    ``outages_s`` windows are in seconds after ``t_ref_s``; ``std_given`` is the 1-sigma the filter is told:
    ``'auto'`` combines the reported accuracy and the added noise, or a vector; ``unit`` names the unit in
    the description's keys (``noise_std_m``, ``std_given_to_filter_mps``, ...).
    """
    n_in = len(series)
    keep = np.ones(n_in, bool)
    if rate_hz is not None and n_in > 0:
        # the first fix in each 1/rate bin, bins counted from t_ref (1e-6 s guards stamp rounding)
        bins = np.floor((series.t_s - t_ref_s) * rate_hz + 1e-6)
        keep = np.concatenate([[True], np.diff(bins) > 0])
    g = series.select(keep)
    values = getattr(g, value_field)
    noise_std = np.asarray(noise_std, float)
    noise = rng.standard_normal((len(g), values.shape[1])) * noise_std
    if std_given == "auto":
        std = np.sqrt(getattr(g, std_field) ** 2 + noise_std ** 2)
    else:
        std = np.tile(np.asarray(std_given, float), (len(g), 1))
    g = replace(g, **{value_field: values + noise, std_field: std})
    in_outage = in_outages(g.t_s, t_ref_s, outages_s)
    g = g.select(~in_outage)
    info = {
        "degraded": True,
        "fixes_in": int(n_in),
        "rate_hz": rate_hz,
        # the stream's own rate (median step): a rate_hz at or above it keeps every fix, which the report says
        # ('decimated to 1000 Hz (4409 -> 4409 fixes)' for 10 Hz data: a corrupted-input review)
        "stream_rate_hz": _rate_hz(series.t_s),
        "fixes_after_decimation": int(keep.sum()),
        f"noise_std_{unit}": [float(x) for x in noise_std],
        "outages_s": [list(map(float, w)) for w in outages_s],
        "fixes_in_outages": int(in_outage.sum()),
        "fixes_used": int(len(g)),
        f"std_given_to_filter_{unit}": "sqrt(reported^2 + noise^2)" if std_given == "auto" else [float(x) for x in std_given],
    }
    return g, info


def degrade_gnss(gnss: GnssSeries, t_ref_s: float, rate_hz: float | None, noise_std_m, outages_s, seed: int,
                 std_m) -> tuple[GnssSeries, dict]:
    """GNSS position fixes degraded (see :func:`degrade_vectors`), the noise drawn from ``seed``."""
    g, info = degrade_vectors(gnss, t_ref_s, rate_hz, noise_std_m, outages_s, np.random.default_rng(seed), std_m, "m",
                              "p_w_m", "std_w_m")
    # the description's order of keys (the report prints it)
    return g, {**{k: info[k] for k in ("degraded", "fixes_in", "rate_hz", "stream_rate_hz", "fixes_after_decimation",
                                       "noise_std_m")},
               "seed": int(seed), **{k: info[k] for k in ("outages_s", "fixes_in_outages", "fixes_used", "std_given_to_filter_m")}}
