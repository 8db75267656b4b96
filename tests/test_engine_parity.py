"""The array engine equals evo's own ``APE``/``RPE`` classes (to 1e-9) on real trajectories: KITTI poses,
TUM RGB-D and EuRoC, every pose relation, every alignment, deltas in frames, metres and degrees, consecutive
and all pairs; its ``Result`` objects equal ``evo.main_ape.ape``/``evo.main_rpe.rpe``'s, and a run evaluated
with ``evaluation.engine: arrays`` equals one with ``evo``, result files included.

The trajectories are cut to their first 600 associated poses so that evo's per-pose loops stay quick;
``test_whole_kitti_trajectory`` (slow) runs one full 4,541-pose trajectory.
"""

from __future__ import annotations

import copy
import dataclasses
import io

import numpy as np
import pytest
from conftest import shared_path

from evo.core import metrics, sync
from evo.core.lie_algebra import LieAlgebraException
from evo.main_ape import ape as evo_ape
from evo.main_rpe import rpe as evo_rpe
from evo.tools import file_interface
from fusion_eval.evaluation import engine

Rel, Unit = metrics.PoseRelation, metrics.Unit
TOL = 1e-9
N_POSES = 600
APE_RELATIONS = [r for r in Rel if r != Rel.point_distance_error_ratio]     # evo's APE refuses the ratio
ALIGNMENTS = ("none", "origin", "se3", "sim3")
# (delta, unit, all_pairs, pairs_from_reference)
DELTAS = [(1, Unit.frames, False, False), (10, Unit.frames, True, False), (2.0, Unit.meters, False, False),
          (1.0, Unit.meters, True, True), (10.0, Unit.degrees, False, False)]


def _cut(ref, est, n=N_POSES):
    ids = np.arange(min(n, ref.num_poses))
    for t in (ref, est):
        t.reduce_to_ids(ids)
    return ref, est


def _load(name: str):
    d = ("evo-test-data",)
    if name == "kitti":
        ref = file_interface.read_kitti_poses_file(shared_path(*d, "KITTI_00_gt.txt"))
        est = file_interface.read_kitti_poses_file(shared_path(*d, "KITTI_00_ORB.txt"))
        return _cut(ref, est)
    if name == "tum":
        ref = file_interface.read_tum_trajectory_file(shared_path(*d, "fr2_desk_groundtruth.txt"))
        est = file_interface.read_tum_trajectory_file(shared_path(*d, "fr2_desk_ORB.txt"))
    elif name == "tum-drift":
        ref = file_interface.read_tum_trajectory_file(shared_path(*d, "freiburg1_xyz-groundtruth.txt"))
        est = file_interface.read_tum_trajectory_file(shared_path(*d, "freiburg1_xyz-rgbdslam_drift.txt"))
    else:
        ref = file_interface.read_euroc_csv_trajectory(shared_path(*d, "V102_groundtruth.csv"))
        est = file_interface.read_tum_trajectory_file(shared_path(*d, "V102.txt"))
    return _cut(*sync.associate_trajectories(ref, est, max_diff=0.01))


DATASETS = ("kitti", "tum", "tum-drift", "euroc")


@pytest.fixture(scope="module")
def pairs():
    cache: dict = {}

    def get(name: str, alignment: str):
        if (name, alignment) not in cache:
            ref, est = _load(name)
            est_evo = copy.deepcopy(est)
            ref_T, est_T = engine.traj_se3(ref), engine.traj_se3(est)
            if alignment == "origin":
                est_evo.align_origin(ref)
                est_T, _ = engine.align_origin(est_T, ref_T)
            elif alignment in ("se3", "sim3"):
                est_evo.align(ref, correct_scale=alignment == "sim3")
                est_T, _ = engine.align_se3(est_T, est.positions_xyz, ref.positions_xyz, alignment == "sim3")
            cache[(name, alignment)] = (ref, est_evo, ref_T, est_T)
        return cache[(name, alignment)]
    return get


@pytest.mark.slow
def test_se3_stack_equals_evos_matrices(pairs):
    for name in DATASETS:
        ref, est, ref_T, est_T = pairs(name, "none")
        assert np.max(np.abs(ref_T - np.array(ref.poses_se3))) <= TOL
        assert np.max(np.abs(est_T - np.array(est.poses_se3))) <= TOL


@pytest.mark.slow
@pytest.mark.parametrize("alignment", ALIGNMENTS)
@pytest.mark.parametrize("name", DATASETS)
def test_alignment_equals_evos(pairs, name, alignment):
    _, est, _, est_T = pairs(name, alignment)
    assert np.max(np.abs(est_T - np.array(est.poses_se3))) <= TOL


@pytest.mark.slow
@pytest.mark.parametrize("relation", APE_RELATIONS, ids=lambda r: r.name)
@pytest.mark.parametrize("alignment", ALIGNMENTS)
@pytest.mark.parametrize("name", DATASETS)
def test_ape_equals_evos_class(pairs, name, alignment, relation):
    ref, est, ref_T, est_T = pairs(name, alignment)
    m = metrics.APE(relation)
    m.process_data((ref, est))
    ours = engine.ape_error(ref_T, est_T, relation)
    assert ours.shape == m.error.shape
    assert np.max(np.abs(ours - m.error)) <= TOL


@pytest.mark.parametrize("relation", list(Rel), ids=lambda r: r.name)
@pytest.mark.parametrize("delta,unit,all_pairs,from_ref", DELTAS,
                         ids=[f"{d}{u.name[0]}{'-all' if a else ''}{'-ref' if r else ''}" for d, u, a, r in DELTAS])
@pytest.mark.parametrize("name,alignment", [("kitti", "none"), ("tum", "sim3"), ("tum-drift", "none"),
                                            ("euroc", "se3")])
@pytest.mark.slow
def test_rpe_equals_evos_class(pairs, name, alignment, relation, delta, unit, all_pairs, from_ref):
    ref, est, ref_T, est_T = pairs(name, alignment)
    m = metrics.RPE(relation, delta, unit, 0.1, all_pairs, from_ref)
    m.process_data((ref, est))
    p = engine.rpe_pairs(ref_T, est_T, delta, unit, 0.1, all_pairs, from_ref)
    ours, ids = engine.rpe_error(ref_T, est_T, relation, p)
    assert list(ids) == list(m.delta_ids)
    assert ours.shape == m.error.shape and len(ours) > 0
    assert np.max(np.abs(ours - m.error)) <= TOL


def _same_result(a, b):
    assert a.info == b.info
    assert a.stats.keys() == b.stats.keys()
    for k in a.stats:
        # 1e-9, relative above 1: an SSE of 1e7 m^2 (dead reckoning) has a float spacing of 1.9e-9 by itself
        assert abs(a.stats[k] - b.stats[k]) <= TOL * max(1.0, abs(b.stats[k])), k
    assert a.np_arrays.keys() == b.np_arrays.keys()
    for k in a.np_arrays:
        assert a.np_arrays[k].shape == b.np_arrays[k].shape, k
        assert np.max(np.abs(a.np_arrays[k] - b.np_arrays[k]), initial=0.0) <= TOL, k
    assert a.trajectories.keys() == b.trajectories.keys()
    for k in a.trajectories:
        ta, tb = a.trajectories[k], b.trajectories[k]
        assert np.max(np.abs(ta.positions_xyz - tb.positions_xyz)) <= TOL
        qa, qb = ta.orientations_quat_wxyz, tb.orientations_quat_wxyz
        assert np.max(np.minimum(np.abs(qa - qb), np.abs(qa + qb))) <= TOL
        if hasattr(ta, "timestamps"):
            assert np.array_equal(ta.timestamps, tb.timestamps)


@pytest.mark.parametrize("name", ("tum", "euroc"))
def test_results_equal_evos_main_functions(pairs, name):
    """Statistics, arrays (times, distances), titles and the carried trajectories, APE and RPE, and what evo's
    result files read back."""
    ref, est, ref_T, est_T = pairs(name, "none")
    for rel in (Rel.translation_part, Rel.rotation_angle_deg):
        theirs = evo_ape(copy.deepcopy(ref), copy.deepcopy(est), rel)
        ours = engine.ape_result(ref, est, rel, engine.ape_error(ref_T, est_T, rel))
        _same_result(ours, theirs)
        bufs = []
        for r in (ours, theirs):
            bufs.append(io.BytesIO())
            file_interface.save_res_file(bufs[-1], r)
        _same_result(*(file_interface.load_res_file(io.BytesIO(b.getvalue()), load_trajectories=True) for b in bufs))
        for delta, unit in ((1, Unit.frames), (0.5, Unit.meters)):
            theirs = evo_rpe(copy.deepcopy(ref), copy.deepcopy(est), rel, delta=delta, delta_unit=unit)
            err, ids = engine.rpe_error(ref_T, est_T, rel, engine.rpe_pairs(ref_T, est_T, delta, unit))
            _same_result(engine.rpe_result(ref, est, rel, err, ids, delta, unit), theirs)


def test_invalid_rotation_refused_as_evo_refuses_it(pairs):
    ref, est, ref_T, est_T = pairs("tum", "none")
    bad = est_T.copy()
    bad[5, :3, :3] *= 1.01                      # not a rotation: evo's so3_log raises
    with pytest.raises(LieAlgebraException):
        engine.ape_error(ref_T, bad, Rel.rotation_angle_deg)


@pytest.mark.slow
@pytest.mark.parametrize("alignment", ("none", "se3", "sim3", "origin", "4dof"))
def test_run_evaluation_equal_with_either_engine(slice_run, alignment):
    """A run's estimates evaluated both ways: every metric, the drift figures and every result file."""
    from fusion_eval.datasets.tum import read_tum
    from fusion_eval.evaluation.trajectory import evaluate
    from fusion_eval.evaluation.keys import RELATION_KEYS
    from fusion_eval.report.files import evo_zips

    gt = read_tum(slice_run / "groundtruth.tum")
    for est_name in ("fused", "lidar", "gnss"):
        est = read_tum(slice_run / f"{est_name}.tum")
        if est_name == "gnss":
            est = dataclasses.replace(est, has_orientation=False)
        # every relation in one evaluation: the arrays engine makes each delta's error poses, and the stamps and
        # distances of each metric, once for all relations (the point-distance relation on its own path)
        rels = tuple(RELATION_KEYS)
        a = evaluate(gt, est, est_name, 0.01, 50.0, alignment=alignment, engine_name="arrays", relations=rels)
        b = evaluate(gt, est, est_name, 0.01, 50.0, alignment=alignment, engine_name="evo", relations=rels)
        assert len(b.results) == (18 if est_name != "gnss" else 2)
        assert a.metrics.keys() == b.metrics.keys()
        for g in b.metrics:
            for k, sb in b.metrics[g].items():
                sa = a.metrics[g][k]
                assert (sa is None) == (sb is None)
                for s in sb or {}:
                    assert abs(sa[s] - sb[s]) <= TOL, (est_name, g, k, s)
        assert (a.drift is None) == (b.drift is None)
        if a.drift is not None:
            assert abs(a.drift["t_err_pct"] - b.drift["t_err_pct"]) <= TOL
            assert abs(a.drift["r_err_deg_per_100m"] - b.drift["r_err_deg_per_100m"]) <= TOL
        if a.alignment_params:
            for k, v in a.alignment_params.items():
                if isinstance(v, (dict, str)):        # the 4-DoF's detected up axis: the same function both ways
                    assert v == b.alignment_params[k]
                    continue
                assert np.allclose(v, b.alignment_params[k], atol=TOL, rtol=0)
        for k in a.results:
            _same_result(a.results[k], b.results[k])
        za, zb = evo_zips(a, trajectories=True), evo_zips(b, trajectories=True)
        assert za.keys() == zb.keys()
        for k in za:
            _same_result(*(file_interface.load_res_file(io.BytesIO(z[k]), load_trajectories=True) for z in (za, zb)))
        # a run leaves the RPE results' reduced trajectories out (its files do not hold them): the same bytes
        c = evaluate(gt, est, est_name, 0.01, 50.0, alignment=alignment, engine_name="arrays", rpe_trajectories=False,
                     relations=rels)
        assert evo_zips(c, trajectories=True) == za
        # output.zip_trajectories off (the default, as evo's save_traj_in_zip): the same zips without them
        plain = {k: file_interface.load_res_file(io.BytesIO(z), load_trajectories=True) for k, z in evo_zips(c).items()}
        assert plain.keys() == za.keys() and not any(r.trajectories for r in plain.values())
        for k, r in plain.items():
            full = file_interface.load_res_file(io.BytesIO(za[k]))
            assert r.stats == full.stats and all(np.array_equal(r.np_arrays[n], full.np_arrays[n]) for n in full.np_arrays)
        rpe = [r for k, r in c.results.items() if k.startswith("rpe")]
        assert (len(rpe) > 0) == (est_name != "gnss") and not any(r.trajectories for r in rpe)


@pytest.mark.slow
def test_whole_kitti_trajectory():
    d = ("evo-test-data",)
    ref = file_interface.read_kitti_poses_file(shared_path(*d, "KITTI_00_gt.txt"))
    est = file_interface.read_kitti_poses_file(shared_path(*d, "KITTI_00_SPTAM.txt"))
    est.align(ref, correct_scale=False)
    ref_T, est_T = engine.traj_se3(ref), engine.traj_se3(est)
    for rel in (Rel.translation_part, Rel.rotation_angle_deg, Rel.full_transformation):
        m = metrics.APE(rel)
        m.process_data((ref, est))
        assert np.max(np.abs(engine.ape_error(ref_T, est_T, rel) - m.error)) <= TOL
        m = metrics.RPE(rel, 100.0, Unit.meters, 0.1, all_pairs=True)
        m.process_data((ref, est))
        err, ids = engine.rpe_error(ref_T, est_T, rel, engine.rpe_pairs(ref_T, est_T, 100.0, Unit.meters, 0.1, True))
        assert list(ids) == list(m.delta_ids)
        assert np.max(np.abs(err - m.error)) <= TOL
    # the README's reference figure for this pair: evo_ape kitti KITTI_00_gt.txt KITTI_00_SPTAM.txt -a
    assert abs(np.sqrt(np.mean(engine.ape_error(ref_T, est_T, Rel.translation_part) ** 2)) - 3.738488) < 1e-6


def test_result_zip_reads_back_as_evos_own_file(pairs):
    """Our result files (fixed entry times, the compiled text writer) read back with evo's ``load_res_file``
    as the file evo's ``save_res_file`` writes: the same info, statistics and arrays, the same trajectories
    (positions to 1e-9 m, stamps to the microsecond their text keeps for Unix stamps)."""
    from fusion_eval.report.files import result_zip

    ref, est, ref_T, est_T = pairs("tum", "none")
    res = engine.ape_result(ref, est, Rel.translation_part, engine.ape_error(ref_T, est_T, Rel.translation_part))
    theirs = io.BytesIO()
    file_interface.save_res_file(theirs, res)
    a = file_interface.load_res_file(io.BytesIO(result_zip(res)), load_trajectories=True)
    b = file_interface.load_res_file(io.BytesIO(theirs.getvalue()), load_trajectories=True)
    assert a.info == b.info and a.stats == b.stats
    assert a.np_arrays.keys() == b.np_arrays.keys()
    assert all(np.array_equal(a.np_arrays[k], b.np_arrays[k]) for k in a.np_arrays)
    assert a.trajectories.keys() == b.trajectories.keys() and len(a.trajectories) == 2
    for k in a.trajectories:
        assert np.max(np.abs(a.trajectories[k].positions_xyz - b.trajectories[k].positions_xyz)) <= 1e-9
        assert np.max(np.abs(a.trajectories[k].timestamps - b.trajectories[k].timestamps)) <= 1e-6
    assert result_zip(res) == result_zip(res)                          # same inputs, same bytes
    assert file_interface.load_res_file(io.BytesIO(result_zip(res, trajectories=False)),
                                        load_trajectories=True).trajectories == {}


def _full(name: str):
    d = ("evo-test-data",)
    if name == "kitti":
        # KITTI files have no stamps: index stamps, as the KITTI reader's fallback gives them
        ref = file_interface.read_kitti_poses_file(shared_path(*d, "KITTI_00_gt.txt"))
        est = file_interface.read_kitti_poses_file(shared_path(*d, "KITTI_00_ORB.txt"))
        from evo.core.trajectory import PoseTrajectory3D
        return (PoseTrajectory3D(poses_se3=ref.poses_se3, timestamps=np.arange(ref.num_poses) * 0.1),
                PoseTrajectory3D(poses_se3=est.poses_se3, timestamps=np.arange(est.num_poses) * 0.1 + 0.004))
    if name == "tum":
        return (file_interface.read_tum_trajectory_file(shared_path(*d, "fr2_desk_groundtruth.txt")),
                file_interface.read_tum_trajectory_file(shared_path(*d, "fr2_desk_ORB.txt")))
    if name == "tum-drift":
        return (file_interface.read_tum_trajectory_file(shared_path(*d, "freiburg1_xyz-groundtruth.txt")),
                file_interface.read_tum_trajectory_file(shared_path(*d, "freiburg1_xyz-rgbdslam_drift.txt")))
    return (file_interface.read_euroc_csv_trajectory(shared_path(*d, "V102_groundtruth.csv")),
            file_interface.read_tum_trajectory_file(shared_path(*d, "V102.txt")))


@pytest.mark.slow
@pytest.mark.parametrize("name", DATASETS)
def test_stamp_matching_equals_evos(name):
    """evo's association (nearest stamp) on whole arrays: the same index pairs as evo's loop, for several
    tolerances and offsets, and the same associated trajectories (whole files, not cut)."""
    from fusion_eval.evaluation.trajectory import associate_nearest

    ref, est = _full(name)
    for a, b in ((ref, est), (est, ref)):
        for max_diff in (0.001, 0.01, 0.05):
            for offset in (0.0, 0.0123, -0.02):
                i1, i2 = sync.matching_time_indices(a.timestamps, b.timestamps, max_diff, offset)
                j1, j2 = engine.matching_time_indices(a.timestamps, b.timestamps, max_diff, offset)
                assert list(j1) == i1 and list(j2) == i2, (max_diff, offset)
    r1, e1 = sync.associate_trajectories(ref, est, max_diff=0.01)
    r2, e2 = associate_nearest(ref, est, 0.01)
    for x, y in ((r1, r2), (e1, e2)):
        assert np.array_equal(x.timestamps, y.timestamps)
        assert np.array_equal(x.positions_xyz, y.positions_xyz)
        assert np.array_equal(x.orientations_quat_wxyz, y.orientations_quat_wxyz)
        assert x.name == y.name
    # consecutive RPE pairs by path length on the whole associated trajectories
    from evo.core import filters
    T = engine.traj_se3(e1)
    for delta in (0.05, 1.0, 7.5):
        want = filters.filter_pairs_by_path(list(T), delta)
        assert [tuple(p) for p in engine.rpe_pairs(T, T, delta, Unit.meters).tolist()] == want


def test_unsorted_stamps_fall_back_to_evos_linear_search():
    s1 = np.array([0.0, 1.0, 2.0, 3.0])
    s2 = np.array([2.001, 0.002, 1.0, 5.0])
    i1, i2 = sync.matching_time_indices(s1, s2, 0.01)
    j1, j2 = engine.matching_time_indices(s1, s2, 0.01)
    assert list(j1) == i1 and list(j2) == i2 == [1, 2, 0]


@pytest.mark.parametrize("relation", [Rel.translation_part, Rel.rotation_angle_deg, Rel.full_transformation])
def test_errors_in_chunks_are_the_errors_of_one_stack(monkeypatch, relation):
    """A long drive's error poses are made a chunk at a time (engine.CHUNK_POSES): the same numbers, bit for bit,
    as the whole stack at once, for APE and RPE, chunks that do not divide the poses included."""
    ref, est = _load("kitti")
    ref_T, est_T = engine.traj_se3(ref), engine.traj_se3(est)
    pairs = engine.rpe_pairs(ref_T, est_T, 1, Unit.frames)
    whole = engine.ape_error(ref_T, est_T, relation), engine.rpe_error(ref_T, est_T, relation, pairs)
    monkeypatch.setattr(engine, "CHUNK_POSES", 97)
    chunked = engine.ape_error(ref_T, est_T, relation), engine.rpe_error(ref_T, est_T, relation, pairs)
    assert len(ref_T) > 5 * 97 and len(pairs) > 2 * 97
    assert np.array_equal(chunked[0], whole[0])
    assert np.array_equal(chunked[1][0], whole[1][0]) and np.array_equal(chunked[1][1], whole[1][1])


def test_errors_of_several_relations_at_once_are_each_relations_own(monkeypatch):
    """``rpe_errors`` makes each chunk's error poses once for all relations: each array is bit for bit its relation's
    own call, a relation named twice included, and the point-distance ratio keeps its own (fewer) ids."""
    ref, est = _load("kitti")
    ref_T, est_T = engine.traj_se3(ref), engine.traj_se3(est)
    pairs = engine.rpe_pairs(ref_T, est_T, 1, Unit.frames)
    monkeypatch.setattr(engine, "CHUNK_POSES", 97)
    rels = [Rel.translation_part, Rel.rotation_angle_deg, Rel.point_distance_error_ratio, Rel.full_transformation,
            Rel.rotation_angle_deg]
    for r, (err, ids) in zip(rels, engine.rpe_errors(ref_T, est_T, rels, pairs)):
        own_err, own_ids = engine.rpe_error(ref_T, est_T, r, pairs)
        assert np.array_equal(err, own_err) and np.array_equal(ids, own_ids), r


def test_path_pairs_equal_evos_where_the_path_meets_delta_to_the_last_bit():
    """evo sums its per-pose norms (a BLAS dot: fused multiply-adds); the whole-array norm differs from it by an ulp on
    about a tenth of the steps. Where a path sum meets delta to the last bit that chose other pairs (a constructed
    trajectory: RPE 0.1171 against evo's 0.1222, a review); near such a tie the engine takes evo's own sums."""
    from evo.core.filters import filter_pairs_by_path

    rng = np.random.default_rng(1)
    p = np.cumsum(rng.normal(size=(400, 3)), axis=0)
    d = p[1:] - p[:-1]
    ours = np.linalg.norm(d, axis=1)
    evos = np.array([float(np.linalg.norm(v)) for v in d])
    k = int(np.flatnonzero(ours < evos)[0])           # a step the whole-array norm leaves an ulp short of evo's
    p = p[k:]                                         # the path starts with it, and delta is evo's length of it
    delta = float(evos[k])
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[:, :3, 3] = p
    want = np.asarray(filter_pairs_by_path(list(T), delta), int)
    got = engine.rpe_pairs(T, T, delta, metrics.Unit.meters)
    np.testing.assert_array_equal(got, want)
    assert got[0, 1] == 1
