"""GNSS degradation: decimation, white noise and outages, seeded and deterministic.

KITTI's OXTS "GNSS" is the GPS/INS solution that is also the ground truth; fusing it unchanged
would be circular. The noise is drawn after decimation and before the outages are cut, so adding
an outage does not change the noise of the fixes that remain.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .types import GnssSeries


def degrade_gnss(gnss: GnssSeries, t_ref_s: float, rate_hz: float | None, noise_std_m, outages_s, seed: int,
                 std_m) -> tuple[GnssSeries, dict]:
    """Return the degraded series and a description of what was applied (for the report).

    ``outages_s`` windows are in seconds after ``t_ref_s``; ``std_m`` is the 1-sigma the filter is
    told: ``'auto'`` combines the reported accuracy and the added noise, or a 3-vector.
    """
    n_in = len(gnss)
    keep = np.ones(n_in, bool)
    if rate_hz is not None and n_in > 0:
        # the first fix in each 1/rate bin, bins counted from t_ref (1e-6 s guards stamp rounding)
        bins = np.floor((gnss.t_s - t_ref_s) * rate_hz + 1e-6)
        keep = np.concatenate([[True], np.diff(bins) > 0])
    g = gnss.select(keep)
    noise_std = np.asarray(noise_std_m, float)
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((len(g), 3)) * noise_std
    if std_m == "auto":
        std = np.sqrt(g.std_w_m ** 2 + noise_std ** 2)
    else:
        std = np.tile(np.asarray(std_m, float), (len(g), 1))
    g = replace(g, p_w_m=g.p_w_m + noise, std_w_m=std)
    in_outage = np.zeros(len(g), bool)
    for a, b in outages_s:
        in_outage |= (g.t_s >= t_ref_s + a) & (g.t_s < t_ref_s + b)
    g = g.select(~in_outage)
    info = {
        "degraded": True,
        "fixes_in": int(n_in),
        "rate_hz": rate_hz,
        "fixes_after_decimation": int(keep.sum()),
        "noise_std_m": [float(x) for x in noise_std],
        "seed": int(seed),
        "outages_s": [list(map(float, w)) for w in outages_s],
        "fixes_in_outages": int(in_outage.sum()),
        "fixes_used": int(len(g)),
        "std_given_to_filter_m": "sqrt(reported^2 + noise^2)" if std_m == "auto" else [float(x) for x in std_m],
    }
    return g, info
