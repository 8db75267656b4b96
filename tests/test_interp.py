"""Pose interpolation: queries at the series' own stamps take its rows (views for a run of them), equal to the
interpolation of the same stamps."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_eval import interp
from fusion_eval.so3 import euler_rpy_to_matrix, matrix_to_quat_xyzw
from fusion_eval.types import PoseSeries


def _series(n: int = 400) -> PoseSeries:
    t = 100.0 + np.cumsum(np.full(n, 0.005))
    R = euler_rpy_to_matrix(0.1 * np.sin(t), 0.05 * np.cos(t), 0.3 * t)
    return PoseSeries(t_s=t, p_w_m=np.column_stack([np.sin(t), t, t ** 2 / 1e3]), q_wb_xyzw=matrix_to_quat_xyzw(R),
                      v_w_mps=np.column_stack([np.cos(t), np.ones_like(t), t / 500]), source="x")


@pytest.mark.parametrize("pick", ["run", "subset", "with_outside"])
def test_queries_at_the_series_stamps_equal_their_interpolation(monkeypatch, pick):
    s = _series()
    t = s.t_s
    tq = {"run": t[37:301], "subset": t[::7],
          "with_outside": np.concatenate([[t[0] - 1.0], t[10:20], [t[-1] + 1.0]])}[pick]
    fast = interp.interpolate_poses(s, tq)
    monkeypatch.setattr(interp, "_at_stamps", lambda *a: None)
    slow = interp.interpolate_poses(s, tq)
    for a, b in ((fast.t_s, slow.t_s), (fast.p_w_m, slow.p_w_m), (fast.v_w_mps, slow.v_w_mps)):
        assert a.shape == b.shape and np.abs(a - b).max() <= 1e-12
    dq = np.minimum(np.abs(fast.q_wb_xyzw - slow.q_wb_xyzw).max(1), np.abs(fast.q_wb_xyzw + slow.q_wb_xyzw).max(1))
    assert dq.max() < 1e-15


def test_stamps_between_samples_are_interpolated():
    s = _series()
    assert interp._at_stamps(s.t_s, s.t_s[5:9] + 1e-4) is None
    assert interp._at_stamps(s.t_s, s.t_s[5:9]) == slice(5, 9)


def test_a_series_shifted_by_zero_is_itself_and_otherwise_a_moved_copy():
    from fusion_eval.types import shifted

    s = _series(10)
    assert shifted(s, 0.0) is s
    moved = shifted(s, 0.25)
    assert np.array_equal(moved.t_s, s.t_s + 0.25) and np.array_equal(moved.p_w_m, s.p_w_m) and moved is not s
