"""The replay's event loop in compiled code against the same loop stepped from Python (the oracle), and the
structured update kernels against their dense textbook forms."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from fusion_eval import session
from fusion_eval.errors import FilterDivergedError
from fusion_eval.filters import compiled_replay, linalg, make_filter, observations
from fusion_eval.filters.formulations.eskf import inject_reset, inject_reset_dense
from fusion_eval.filters.layout import CLONE, NOMINAL
from fusion_eval.prepare import prepare, settings_for
from fusion_eval.replay import replay

from conftest import KITTI00


def _prepared(*sets, mode="auto", data=KITTI00):
    ds = session.dataset(data)
    cfg = session.resolve(session.request(sets=tuple(sets)), ds)
    prep = prepare(ds, cfg)
    return prep, _with_mode(cfg, prep, mode)


def _with_mode(cfg, prep, mode):
    cfg = copy.deepcopy(cfg)
    cfg["filter"]["replay"] = mode
    return settings_for(cfg, prep)


@pytest.fixture(scope="module")
def default_run():
    return _prepared()


def _enable(o) -> tuple[str, ...]:
    """The --set items that turn one registered observation on (with the lidar off unless it is the lidar)."""
    sets = tuple(f"{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in o.enable_with.items())
    return sets if o.enabled_by == "filter.lidar_update" else (*sets, "filter.lidar_update=none")


# every registered observation with a compiled kernel, alone: a new one is dispatched and checked against Python
_ENABLE_EACH_KERNEL = {f"{o.name}:{type(o).__name__}": _enable(o) for o in observations.REGISTRY if o.kernel is not None}
_KITTI00_STREAMS = None


def _data_for(sets, request) -> str:
    """kitti-00, or a simulated drive where kitti-00 lacks a stream an enabled observation reads: the simulator
    writes every registered observation's sensor, so a new observation is checked without a real dataset of its own
    (kitti-00 alone made an extension author's barometer fail these tests)."""
    global _KITTI00_STREAMS
    if _KITTI00_STREAMS is None:
        ds = session.dataset(KITTI00)
        _KITTI00_STREAMS = {n for o in observations.REGISTRY for n in o.streams if ds.stream(n) is not None}
    cfg = session.resolve(session.request(sets=tuple(sets)), session.dataset(KITTI00))
    needed = {n for o in observations.enabled(cfg) for n in o.streams}
    return KITTI00 if needed <= _KITTI00_STREAMS else str(request.getfixturevalue("sim_drive"))


@pytest.fixture(scope="module")
def sim_drive(tmp_path_factory) -> Path:
    """A 60 s simulated drive with every registered sensor (asked for only where kitti-00 lacks a stream)."""
    from click.testing import CliRunner

    from fusion_eval.cli import main

    d = tmp_path_factory.mktemp("compiled") / "urban"
    r = CliRunner().invoke(main, ["-q", "simulate", str(d), "--duration", "60", "--set", "output.layout=csv"])
    assert r.exit_code == 0, r.output
    return d

CASES = [
    (),                                                                         # relative lidar + GNSS, adaptive noise
    ("filter.discretization=first_order", "lidar.noise_adapt=none", "lidar.gate_prob=0.9"),   # gated: rejections
    ("filter.lidar_update=absolute",),
    ("filter.use_gnss=false", "lidar.noise_adapt=nis_position", "gnss.lever_arm_b_m=[0.3, -0.2, 0.8]"),
    ("filter.odometer_update=true", "filter.nhc=true"),                        # the body-velocity kernels
    *_ENABLE_EACH_KERNEL.values(),
]


@pytest.mark.slow
@pytest.mark.parametrize("sets", CASES, ids=["default", "gated", "absolute", "no-gnss-adapt-position", "odometer-nhc",
                                             *(f"alone-{k}" for k in _ENABLE_EACH_KERNEL)])
def test_compiled_replay_equals_the_python_loop(sets, request):
    prep, s = _prepared(*sets, data=_data_for(sets, request))
    ref = replay(prep, _with_mode(s.cfg, prep, "python"))
    kf = make_filter(prep, s)
    bound = [o.bind(prep, s) for o in observations.enabled(s.cfg)]
    assert compiled_replay.usable(kf, bound, None, 1, "auto")
    got = replay(prep, s)
    assert np.max(np.abs(got.fused.p_w_m - ref.fused.p_w_m)) < 1e-9
    assert np.max(np.abs(got.fused.q_wb_xyzw - ref.fused.q_wb_xyzw)) < 1e-9
    assert np.max(np.abs(got.gyro_bias_b - ref.gyro_bias_b)) < 1e-12
    assert np.allclose(got.sigma, ref.sigma, rtol=1e-8, atol=1e-12, equal_nan=True)
    assert np.allclose(got.P_pos_att, ref.P_pos_att, rtol=1e-8, atol=1e-14, equal_nan=True)
    assert got.nis.keys() == ref.nis.keys()
    for k in ref.nis:
        a, b = got.nis[k], ref.nis[k]
        assert np.array_equal(a["t_s"], b["t_s"])
        assert np.allclose(a["nis"], b["nis"], rtol=1e-6)
        assert a["rejected"] == b["rejected"]
        if "adapt" in b:
            assert a["adapt"] == pytest.approx(b["adapt"], rel=1e-8)
    if "lidar.gate_prob=0.9" in sets:
        assert ref.nis["lidar"]["rejected"] > 0          # the case exercises the gate


@pytest.mark.slow
def test_the_compiled_loop_is_not_used_where_it_does_not_apply(default_run):
    prep, s = default_run
    kf = make_filter(prep, s)
    bound = [o.bind(prep, s) for o in observations.enabled(s.cfg)]
    assert compiled_replay.usable(kf, bound, None, 1, "auto")
    assert not compiled_replay.usable(kf, bound, None, 1, "python")
    assert not compiled_replay.usable(kf, bound, object(), 1, "auto")          # a smoother records from Python
    assert not compiled_replay.usable(kf, bound, None, 3, "auto")             # iterated EKF
    no_kernel = [*bound[:1], type(bound[0])(**{**bound[0].__dict__, "kernel": None})]      # e.g. GNSS velocity
    assert not compiled_replay.usable(kf, no_kernel, None, 1, "auto")
    for form in ("nominal_state", "invariant"):
        prep2, s2 = _prepared(f"filter.formulation={form}")
        kf2 = make_filter(prep2, s2)
        assert not compiled_replay.usable(kf2, [o.bind(prep2, s2) for o in observations.enabled(s2.cfg)], None, 1,
                                          "auto")


@pytest.mark.slow
def test_every_registered_kernel_is_dispatched(request):
    # the loop is built over the registry's kernels: a new observation with a kernel is one module, one line;
    # each kernel its own slot, and every kernel a bound observation carries is its class's declared one
    assert len(set(observations.KERNELS)) == len(observations.KERNELS) >= 5      # a slot per observation
    seen = set()
    for sets in _ENABLE_EACH_KERNEL.values():
        prep, s = _prepared(*sets, data=_data_for(sets, request))
        for o in observations.enabled(s.cfg):
            b = o.bind(prep, s)
            if o.kernel is not None:
                assert b.kernel is not None and b.kernel.fn is o.kernel, o.name
                seen.add(o.kernel)
    assert seen == set(observations.KERNELS)


def test_a_non_finite_increment_stops_the_compiled_replay_with_a_divergence(default_run):
    prep, s = default_run
    kf = make_filter(prep, s)
    bound = [o.bind(prep, s) for o in observations.enabled(s.cfg)]
    bound[0].kernel.data[50, 1] = np.nan            # lidar increment 50
    times = np.concatenate([b.t_s for b in bound])
    which = np.concatenate([np.full(b.t_s.size, i) for i, b in enumerate(bound)])
    index = np.concatenate([np.arange(b.t_s.size) for b in bound])
    with pytest.raises(FilterDivergedError, match="non-finite residual"):
        compiled_replay.run(kf, bound, times, which, index, np.lexsort((index, which, times)))
    assert kf.t == pytest.approx(bound[0].t_s[50])


@pytest.mark.parametrize("seed", range(5))
def test_structured_joseph_update_equals_the_dense_form(seed):
    rng = np.random.default_rng(seed)
    n, m = 21, int(rng.integers(1, 7))
    A = rng.normal(size=(n, n))
    P = A @ A.T + 0.1 * np.eye(n)
    H = rng.normal(size=(m, n)) * (rng.random((m, n)) < 0.4)            # sparse, as a pose residual's
    B = rng.normal(size=(m, m))
    Rm = B @ B.T + 0.5 * np.eye(m)
    r = rng.normal(size=m)
    P1, P2 = P.copy(), P.copy()
    dx1, nis1, ok1 = linalg.joseph_update(P1, n, H, r, Rm, np.inf)
    dx2, nis2, ok2 = linalg.joseph_update_dense(P2, n, H, r, Rm, np.inf)
    assert ok1 and ok2
    assert np.max(np.abs(P1 - P2)) < 1e-12 * np.max(np.abs(P2))
    assert np.max(np.abs(dx1 - dx2)) < 1e-12 * max(1.0, np.max(np.abs(dx2)))
    assert nis1 == pytest.approx(nis2, rel=1e-12)
    assert np.array_equal(P1, P1.T)                                      # symmetric to the last bit
    # gated: P untouched, no correction
    P3 = P.copy()
    dx3, nis3, ok3 = linalg.joseph_update(P3, n, H, r, Rm, 0.5 * nis2)
    assert not ok3 and np.array_equal(P3, P) and not dx3.any()
    # the block NIS of the innovation covariance
    S = H @ P @ H.T + Rm
    L, y = np.zeros((m, m)), np.zeros(m)
    lo = 0
    assert linalg.block_nis(S, lo, m, r, L, y) == pytest.approx(r @ np.linalg.solve(S, r), rel=1e-12)


def test_joseph_update_refuses_an_indefinite_innovation_covariance():
    P = np.eye(3)
    with pytest.raises(np.linalg.LinAlgError):
        linalg.joseph_update(P, 3, np.eye(3), np.ones(3), -2.0 * np.eye(3), np.inf)


@pytest.mark.parametrize("n", [15, 21])
def test_structured_reset_equals_the_dense_form(n):
    rng = np.random.default_rng(n)
    A = rng.normal(size=(n, n))
    P = A @ A.T
    x = np.zeros(NOMINAL.n)
    x[NOMINAL.sl("R")] = np.eye(3).ravel()
    xc = np.zeros(CLONE.n)
    xc[CLONE.sl("R")] = np.eye(3).ravel()
    dx = rng.normal(size=n) * 0.05
    P1, P2, x1, x2, c1, c2 = P.copy(), P.copy(), x.copy(), x.copy(), xc.copy(), xc.copy()
    inject_reset(x1, c1, P1, n, dx)
    inject_reset_dense(x2, c2, P2, n, dx)
    assert np.max(np.abs(P1 - P2)) < 1e-13 * np.max(np.abs(P2))
    assert np.max(np.abs(x1 - x2)) < 1e-15 and np.max(np.abs(c1 - c2)) < 1e-15


@pytest.mark.slow
def test_every_increment_gated_out_with_adaptive_noise():
    """No accepted update: the adaptive noise keeps its prior scales on both paths (nothing to summarise)."""
    prep, s = _prepared("lidar.gate_prob=1e-6")
    ref = replay(prep, _with_mode(s.cfg, prep, "python"))
    got = replay(prep, s)
    assert ref.nis["lidar"]["rejected"] == got.nis["lidar"]["rejected"] == ref.nis["lidar"]["nis"].size > 4000
    assert got.nis["lidar"]["adapt"] == ref.nis["lidar"]["adapt"]
    assert got.nis["lidar"]["adapt"]["pos_std_factor"] == 1.0
    assert np.max(np.abs(got.fused.p_w_m - ref.fused.p_w_m)) < 1e-9


@pytest.mark.parametrize("n_frames", [0, 1])
def test_relative_pose_binds_with_fewer_than_two_frames(n_frames):
    from types import SimpleNamespace as NS

    from fusion_eval.filters.observations.relative_pose import OBSERVATION

    class Lidar:
        t_s = np.array([0.5, 100.0, 100.1] if n_frames else [100.0, 100.1])     # the run spans 0..10 s
        p_w_m = np.zeros((t_s.size, 3))

        def R_wb(self):
            return np.tile(np.eye(3), (self.t_s.size, 1, 1))

    run = NS(lidar=Lidar(), imu=NS(t_s=np.linspace(0, 10, 101)), k_start=0)
    s = NS(lidar=NS(relative_pos_std_m=0.02, relative_pos_std_frac=0.01, relative_att_std_rad=1e-3,
                    relative_att_std_frac=0.0, relative_frame="body", noise_adapt="none", adapt_rate=0.02, gate_prob=None),
           filter=NS(use_gnss=True))
    b = OBSERVATION.bind(run, s)
    assert b.t_s.size == n_frames and b.kernel.data.shape == (n_frames, 16)
    assert not b.kernel.data[:, 0].any()          # a lone frame only starts the chain of clones


@pytest.mark.slow
def test_no_compiled_caller_passes_the_steps_covariance_flag_as_a_constant():
    """Numba types a constant ``True``/``False`` argument as a literal and compiles the callee once more for it: the
    ESKF's step and loop, most of a first run's compilation, were compiled twice by a default run (the Python callers'
    ``bool`` and the compiled replay's ``Literal[bool](True)``) and twice more by the compiled RTS pass. Every compiled
    function and generated loop of the package (its source, read here) passes ``cov`` as a plain bool
    (fusion_eval/filters/propagate.py). A cold cache cannot be had in a quick test, hence the source check."""
    import ast
    import importlib
    import pkgutil
    import re

    import fusion_eval

    steps = re.compile(r"^_?(step|predict|predict_to)(_\w+)?$")
    sources = []
    for m in pkgutil.walk_packages(fusion_eval.__path__, "fusion_eval."):
        if m.name.endswith("__main__"):
            continue
        mod = importlib.import_module(m.name)
        sources.append((m.name, ast.parse(open(mod.__file__).read()), False))
        for attr in ("_LOOP", "_SEGMENT"):                # the loops generated from templates (propagate, replay, RTS)
            template = getattr(mod, attr, None)
            if isinstance(template, str):
                template = re.sub(r"\{(\w+)\}", r"\1", re.sub(r"^\{\w+\}$", "        pass", template, flags=re.M))
                sources.append((f"{m.name}.{attr}", ast.parse(template), True))
    assert sum(generated for *_, generated in sources) == 3
    found = []
    for name, tree, generated in sources:
        for fn in ast.walk(tree):
            if not (isinstance(fn, ast.FunctionDef)
                    and (generated or any("jit" in ast.unparse(d) for d in fn.decorator_list))):
                continue
            for call in ast.walk(fn):
                callee = getattr(call, "func", None)
                callee = getattr(callee, "id", getattr(callee, "attr", ""))
                if (isinstance(call, ast.Call) and steps.match(callee)
                        and any(isinstance(a, ast.Constant) and isinstance(a.value, bool) for a in call.args)):
                    found.append(f"{name}:{call.lineno}: {ast.unparse(call)}")
    assert not found, found


def test_gnss_std_scale_multiplies_the_std_the_filter_is_given(kitti_slice):
    """gnss.std_scale scales each fix's std (not its variance): a mutation review found the square held by no test."""
    from fusion_eval.filters.observations.gnss_position import GnssPosition

    def stds(scale):
        prep, s = _prepared(f"gnss.std_scale={scale}", data=kitti_slice)
        b = next(o for o in observations.enabled(s.cfg) if isinstance(o, GnssPosition)).bind(prep, s)
        return np.array([b.model(j).keywords["row"][3:6] for j in range(len(b.t_s))])

    one, two = stds(1.0), stds(2.0)
    assert one.size and np.all(one > 0)
    np.testing.assert_allclose(two, 2.0 * one, rtol=1e-12)
