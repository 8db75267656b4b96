"""GNSS degradation: rate, noise, outages; seeded and deterministic."""

from __future__ import annotations

import numpy as np

from conftest import KITTI00
from fusion_eval.degrade import degrade_gnss
from fusion_eval.datasets.manifest import load_dataset


def _gnss():
    g = load_dataset(KITTI00).gnss
    return g.select(~g.filled)


def test_decimation_noise_and_outages():
    g = _gnss()
    t0 = g.t_s[0]
    out, info = degrade_gnss(g, t0, 1.0, [1.0, 1.0, 2.0], [[100, 150]], 7, "auto")
    dt = np.diff(out.t_s)
    assert np.median(dt) > 0.95 and info["fixes_after_decimation"] < len(g) / 9
    assert not np.any((out.t_s >= t0 + 100) & (out.t_s < t0 + 150))
    assert info["fixes_in_outages"] >= 45
    # the noise is what was asked for: compare with the undegraded positions at the same stamps
    idx = np.searchsorted(g.t_s, out.t_s)
    err = out.p_w_m - g.p_w_m[idx]
    assert np.allclose(err.std(axis=0), [1.0, 1.0, 2.0], rtol=0.12)
    assert np.allclose(out.std_w_m[:, 2], np.sqrt(g.std_w_m[idx, 2] ** 2 + 4.0))


def test_same_seed_same_fixes_other_seed_other_noise():
    g = _gnss()
    a, _ = degrade_gnss(g, g.t_s[0], 1.0, [1, 1, 2], [], 3, "auto")
    b, _ = degrade_gnss(g, g.t_s[0], 1.0, [1, 1, 2], [], 3, "auto")
    c, _ = degrade_gnss(g, g.t_s[0], 1.0, [1, 1, 2], [], 4, "auto")
    assert np.array_equal(a.p_w_m, b.p_w_m) and not np.allclose(a.p_w_m, c.p_w_m)


def test_outage_does_not_change_the_noise_of_other_fixes():
    g = _gnss()
    a, _ = degrade_gnss(g, g.t_s[0], 1.0, [1, 1, 2], [], 3, "auto")
    b, _ = degrade_gnss(g, g.t_s[0], 1.0, [1, 1, 2], [[50, 60]], 3, "auto")
    keep = np.isin(a.t_s, b.t_s)
    assert np.array_equal(a.p_w_m[keep], b.p_w_m)


def test_no_degradation_keeps_every_fix():
    g = _gnss()
    out, info = degrade_gnss(g, g.t_s[0], None, [0, 0, 0], [], 0, "auto")
    assert len(out) == len(g) and np.array_equal(out.p_w_m, g.p_w_m)


def test_a_rate_at_or_above_the_streams_own_is_said_as_every_fix_kept():
    """--set gnss.rate_hz=1000 on 10 Hz data read 'decimated to 1000 Hz (4409 -> 4409 fixes)' (a corrupted-input
    review): the stream's own rate is recorded, and the report says every fix was kept."""
    from fusion_eval.report.markdown import _rate_words

    g = _gnss()
    _, info = degrade_gnss(g, g.t_s[0], 1000.0, [1.0, 1.0, 2.0], [], 0, "auto")
    assert info["fixes_after_decimation"] == len(g) and abs(info["stream_rate_hz"] - 10.0) < 0.1
    assert _rate_words(info, "fix") == "every fix kept (its own rate, 10 Hz, is at or below the 1000 Hz set)"
    _, info = degrade_gnss(g, g.t_s[0], 1.0, [1.0, 1.0, 2.0], [], 0, "auto")
    assert _rate_words(info, "fix") == "decimated to 1 Hz"
