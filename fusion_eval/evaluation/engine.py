"""evo's APE and RPE computed on stacked arrays: the same quantities as ``evo.core.metrics.APE``/``RPE``,
without their per-pose Python loops or deep copies.

evo stays the definition. What is kept as it is: the association (``evo.core.sync``), the Umeyama
alignment (``evo.core.geometry.umeyama_alignment``), the RPE pair selection
(``evo.core.metrics.id_pairs_from_delta``, i.e. ``evo.core.filters``), the statistics (``PE.get_result``)
and the ``Result`` objects, decorated as ``evo.main_ape.ape``/``evo.main_rpe.rpe`` decorate them. What is
replaced is only the loops over poses: building the SE(3) matrices from the quaternions (evo's
``quaternion_matrix``, vectorised), the error poses (``relative_se3``), and the error of each pose relation
(the rotation angle by scipy's ``Rotation`` on the whole stack, as evo's ``so3_log`` does on one matrix,
after the same ``is_so3`` check). ``tests/test_engine_parity.py`` holds every relation, alignment and
delta equal to evo's own classes on real trajectories to 1e-9.

Cost on kitti-00 (4.4k poses): ~0.3 ms per error series, against ~1 s for evo's loops.
"""

from __future__ import annotations

import numpy as np
from evo.core import geometry, metrics
from numba import njit
from evo.core.lie_algebra import LieAlgebraException
from evo.core.result import Result
from evo.core.trajectory import PoseTrajectory3D
from scipy.spatial.transform import Rotation

from ..so3 import det3

Rel = metrics.PoseRelation
_EPS_QUAT = np.finfo(float).eps * 4.0     # evo.core.transformations._EPS: below it a quaternion maps to identity


def se3_of(positions_xyz: np.ndarray, quat_wxyz: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses as evo's ``PoseCache.poses_se3`` builds them (``quaternion_matrix`` normalises each
    quaternion; a near-zero one gives the identity)."""
    q = np.ascontiguousarray(quat_wxyz, dtype=float)
    T = np.empty((len(q), 4, 4))
    _se3_into(np.ascontiguousarray(positions_xyz, dtype=float), q, T)
    return T


@njit(cache=True)
def _se3_into(p, q, T):
    """evo's ``quaternion_matrix`` (q scaled by sqrt(2 / |q|^2), then ``1 - q_j q_j - q_k q_k`` and the like) with
    the position, pose by pose."""
    for i in range(q.shape[0]):
        n = q[i, 0] * q[i, 0] + q[i, 1] * q[i, 1] + q[i, 2] * q[i, 2] + q[i, 3] * q[i, 3]
        M = T[i]
        if n < _EPS_QUAT:
            for a in range(3):
                for b in range(3):
                    M[a, b] = 1.0 if a == b else 0.0
        else:
            f = np.sqrt(2.0 / n)
            w, x, y, z = q[i, 0] * f, q[i, 1] * f, q[i, 2] * f, q[i, 3] * f
            M[0, 0] = 1.0 - y * y - z * z
            M[0, 1] = x * y - z * w
            M[0, 2] = x * z + y * w
            M[1, 0] = x * y + z * w
            M[1, 1] = 1.0 - x * x - z * z
            M[1, 2] = y * z - x * w
            M[2, 0] = x * z - y * w
            M[2, 1] = y * z + x * w
            M[2, 2] = 1.0 - x * x - y * y
        for a in range(3):
            M[a, 3] = p[i, a]
            M[3, a] = 0.0
        M[3, 3] = 1.0


def traj_se3(traj) -> np.ndarray:
    """The (N, 4, 4) poses of an evo path: its own matrices if it holds them (an aligned or KITTI path),
    else built from its positions and quaternions."""
    if traj._cache.has_poses_se3():          # noqa: SLF001 - avoid evo's per-pose rebuild, not its values
        return np.array(traj.poses_se3)
    return se3_of(traj.positions_xyz, traj.orientations_quat_wxyz)


def inverse(T: np.ndarray) -> np.ndarray:
    """``se3_inverse`` of every pose of a stack."""
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.zeros_like(T)
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


# The stacks of a long drive are large (720,000 poses: 92 MB each), and every temporary of that size is fresh
# memory the kernel must clear; the error poses are therefore formed pose by pose into one output array.
@njit(cache=True)
def _inv_mul_into(A, B, out):
    """``out = se3_inverse(A) @ B`` for one pair of 4x4 poses (the inverse as ``[R^T, -R^T t]``)."""
    ti = np.empty(3)
    for i in range(3):
        ti[i] = -(A[0, i] * A[0, 3] + A[1, i] * A[1, 3] + A[2, i] * A[2, 3])
    for i in range(3):
        for j in range(4):
            out[i, j] = A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j] + ti[i] * B[3, j]
    for j in range(4):
        out[3, j] = B[3, j]


@njit(cache=True)
def _relative_stack(A, B, out):
    for n in range(A.shape[0]):
        _inv_mul_into(A[n], B[n], out[n])


@njit(cache=True)
def _rpe_poses(ref_T, est_T, i, j, out):
    """``(Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` of every pair, with no stack-sized temporaries."""
    Q = np.empty((4, 4))
    P = np.empty((4, 4))
    for m in range(i.size):
        _inv_mul_into(ref_T[i[m]], ref_T[j[m]], Q)
        _inv_mul_into(est_T[i[m]], est_T[j[m]], P)
        _inv_mul_into(Q, P, out[m])


def relative(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``relative_se3(A_i, B_i) = A_i^-1 B_i`` of every pair."""
    A, B = np.broadcast_arrays(*(np.asarray(x, float).reshape(-1, 4, 4) for x in (A, B)))   # a single pose pairs with all
    A, B = np.ascontiguousarray(A), np.ascontiguousarray(B)
    out = np.empty(A.shape)
    _relative_stack(A, B, out)
    return out


# ---------------------------------------------------------------------------------------------- alignment
def align_se3(est_T: np.ndarray, est_p: np.ndarray, ref_p: np.ndarray, with_scale: bool, only_scale: bool = False,
              n: int = -1):
    """``PosePath3D.align``: evo's Umeyama fit of the positions (the first ``n``; -1: all), applied as evo applies
    it (scale the translations, then left-multiply by ``se3(r, t)`` unless ``only_scale``). Returns the moved
    stack and ``(r, t, s)``."""
    with_scale = with_scale or only_scale
    if n == -1:
        r, t, s = geometry.umeyama_alignment(est_p.T, ref_p.T, with_scale)
    else:
        r, t, s = geometry.umeyama_alignment(est_p[:n, :].T, ref_p[:n, :].T, with_scale)
    moved = np.array(est_T)
    if with_scale:
        moved[:, :3, 3] *= s
    if only_scale:
        return moved, (r, t, s)
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = r, t
    return A @ moved, (r, t, s)


def align_origin(est_T: np.ndarray, ref_T: np.ndarray):
    """``PosePath3D.align_origin``: the first estimated pose moved onto the first reference pose."""
    to_ref = ref_T[0] @ inverse(est_T[:1])[0]
    return to_ref @ est_T, to_ref


# ---------------------------------------------------------------------------------------------- errors
@njit(cache=True)
def _all_so3(R):
    """evo's ``is_so3`` on every matrix: ``isclose(det, 1)`` and ``isclose(R^T R, I)`` (atol 1e-6, rtol 1e-5)."""
    for n in range(R.shape[0]):
        M = R[n]
        if not abs(det3(M) - 1.0) <= 1e-6 + 1e-5:
            return False
        for i in range(3):
            for j in range(i, 3):              # R^T R is symmetric
                g = M[0, i] * M[0, j] + M[1, i] * M[1, j] + M[2, i] * M[2, j]
                e = 1.0 if i == j else 0.0
                if not abs(g - e) <= 1e-6 + 1e-5 * e:
                    return False
    return True


def _check_so3(R: np.ndarray) -> None:
    """evo's ``is_so3`` on every matrix (``so3_log`` refuses anything else)."""
    if not _all_so3(np.asarray(R, float)):
        raise LieAlgebraException("matrix is not a valid SO(3) group element")


def _angle_rad(R: np.ndarray) -> np.ndarray:
    from ..so3 import log_so3          # scipy's Rotation, compiled (equal to it, tests/test_so3.py)

    _check_so3(R)
    return np.linalg.norm(log_so3(R), axis=1)


def pose_error(E: np.ndarray, relation: Rel) -> np.ndarray:
    """The error of each error pose ``E`` (N, 4, 4) under a pose relation, as evo's metrics define it."""
    if relation in (Rel.translation_part, Rel.point_distance):
        return np.linalg.norm(E[:, :3, 3], axis=1)
    if relation == Rel.rotation_part:
        return np.linalg.norm(E[:, :3, :3] - np.eye(3), axis=(1, 2))
    if relation == Rel.full_transformation:
        return np.linalg.norm(E - np.eye(4), axis=(1, 2))
    if relation == Rel.rotation_angle_rad:
        return _angle_rad(E[:, :3, :3])
    if relation == Rel.rotation_angle_deg:
        return np.rad2deg(_angle_rad(E[:, :3, :3]))
    raise metrics.MetricsException("unsupported pose_relation")


def ape_error(ref_T: np.ndarray, est_T: np.ndarray, relation: Rel) -> np.ndarray:
    """``APE.process_data``'s error array: translation by the position difference, every other relation on
    ``relative_se3(est, ref)``."""
    if len(ref_T) != len(est_T):
        raise metrics.MetricsException("trajectories must have same number of poses")
    if relation in (Rel.translation_part, Rel.point_distance):
        return np.linalg.norm(est_T[:, :3, 3] - ref_T[:, :3, 3], axis=1)
    if relation == Rel.point_distance_error_ratio:
        raise metrics.MetricsException("unsupported pose_relation")
    return _chunked(len(ref_T), lambda a, b: pose_error(relative(est_T[a:b], ref_T[a:b]), relation))


# error poses per call of pose_error: each 4x4 pose and the temporaries of its error cost ~400 bytes, so the whole
# stack of a long drive (an hour at 200 Hz) would be ~300 MB at once; a chunk's is 26 MB, as fast
CHUNK_POSES = 1 << 16


def _chunks(n: int):
    """``(a, b)`` of the chunks of :data:`CHUNK_POSES` poses that cover ``0..n`` (one, ``(0, n)``, when it is short)."""
    if n <= CHUNK_POSES:
        return [(0, n)]
    return [(a, min(a + CHUNK_POSES, n)) for a in range(0, n, CHUNK_POSES)]


def _joined(parts: list) -> np.ndarray:
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _chunked(n: int, error_of) -> np.ndarray:
    """``error_of(a, b)`` (the errors of the poses ``a:b``) over ``0..n`` in chunks of :data:`CHUNK_POSES`,
    concatenated: each pose's error is computed alone, so the result is the same numbers as one call."""
    return _joined([error_of(a, b) for a, b in _chunks(n)])


def rpe_pairs(ref_T: np.ndarray, est_T: np.ndarray, delta: float, delta_unit: metrics.Unit, rel_tol: float = 0.1,
              all_pairs: bool = False, pairs_from_reference: bool = False) -> np.ndarray:
    """evo's pair selection (``id_pairs_from_delta``) as an (M, 2) index array. Consecutive pairs by frames
    (a range) and by path length, whose selection evo makes in Python loops over poses, are selected here, the
    path by :func:`path_pair_ids` (the same arithmetic, compiled); both equal evo's on real trajectories
    (``tests/test_engine_parity.py``). Everything else is evo's own selection."""
    T = ref_T if pairs_from_reference else est_T
    if delta_unit == metrics.Unit.frames and not all_pairs and int(delta) >= 1 and len(T) > int(delta):
        ids = np.arange(0, len(T), int(delta))           # filter_pairs_by_index, consecutive
        return np.column_stack([ids[:-1], ids[1:]])
    if delta_unit == metrics.Unit.meters and not all_pairs and len(T) > 0:
        d = T[1:, :3, 3] - T[:-1, :3, 3]
        ids, margin = path_pair_ids(np.linalg.norm(d, axis=1), float(delta))
        if margin <= NEAR_TIE * max(float(delta), 1e-300):
            # a path that meets delta within the last bits: evo's per-pose norm (a BLAS dot, fused multiply-adds)
            # and the whole-array one differ by an ulp on a tenth of the steps, which chose other pairs on a
            # constructed trajectory (RPE 0.1171 against evo's 0.1222: a review); there, evo's own sums
            ids, _ = path_pair_ids(np.array([float(np.linalg.norm(v)) for v in d]), float(delta))
        if ids.size < 2:
            from evo.core.filters import FilterException

            raise FilterException(f"delta = {delta} ({delta_unit.value}) produced an empty index list - try lower "
                                  "values or a less strict tolerance")
        return np.column_stack([ids[:-1], ids[1:]])
    pairs = metrics.id_pairs_from_delta(T, delta, delta_unit, rel_tol, all_pairs=all_pairs)
    return np.asarray(pairs, dtype=int).reshape(-1, 2)


# how close (relative to delta) a path sum may come to delta before the decision could depend on an ulp of a step:
# a sum of up to a million steps, each off by one ulp (2.2e-16), moves by under 2.2e-10 of itself
NEAR_TIE = 1e-9


@njit(cache=True)
def path_pair_ids(steps, delta):
    """The pose indices ``evo.core.filters.filter_pairs_by_path`` keeps in consecutive mode: the first, then
    each pose at which the path travelled since the last kept one reaches ``delta`` (``steps[i]``: the
    distance from pose i to pose i + 1, summed one by one as evo sums them); and the smallest distance of a sum
    from ``delta`` at any decision (a near tie, where the steps' last bits decide)."""
    ids = np.empty(steps.size + 1, np.int64)
    ids[0] = 0
    n = 1
    current = 0.0
    margin = np.inf
    for i in range(steps.size):
        current += steps[i]
        margin = min(margin, abs(current - delta))
        if current >= delta:
            ids[n] = i + 1
            n += 1
            current = 0.0
    return ids[:n], margin


def matching_time_indices(stamps_1: np.ndarray, stamps_2: np.ndarray, max_diff: float = 0.01,
                          offset_2: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``evo.core.sync.matching_time_indices`` on whole arrays: for each stamp of ``stamps_1`` the nearest of
    the sorted ``stamps_2`` (+ ``offset_2``) within ``max_diff``, with evo's comparisons and tie rule (the
    earlier stamp on an exact tie). Unsorted ``stamps_2`` fall back to evo's own linear search."""
    s2 = np.asarray(stamps_2, float) + offset_2
    s1 = np.asarray(stamps_1, float)
    if s2.size == 0 or not np.all(np.diff(s2) >= 0):
        from evo.core import sync

        a, b = sync.matching_time_indices(stamps_1, stamps_2, max_diff, offset_2)
        return np.asarray(a, int), np.asarray(b, int)
    inside = ~((s1 < s2[0] - max_diff) | (s1 > s2[-1] + max_diff))
    j = np.minimum(np.searchsorted(s2, s1, side="right"), s2.size - 1)
    diff_ub = s2[j] - s1
    diff_lb = np.where(j > 0, s1 - s2[np.maximum(j - 1, 0)], np.inf)
    up = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    down = ~up & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    keep = inside & (up | down)
    return np.flatnonzero(keep), np.where(up, j, j - 1)[keep]


def rpe_error(ref_T: np.ndarray, est_T: np.ndarray, relation: Rel, pairs: np.ndarray):
    """``RPE.process_data``'s error array and delta ids for the pairs ``(i, j)``: the error pose
    ``(Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (TUM RGB-D), or for the point-distance relations the difference of the
    pair distances."""
    return rpe_errors(ref_T, est_T, (relation,), pairs)[0]


def rpe_errors(ref_T: np.ndarray, est_T: np.ndarray, relations, pairs: np.ndarray) -> list:
    """:func:`rpe_error` of each relation on the same pairs, the error poses made once for all of them (a chunk
    at a time): each relation's array is the same numbers as its own call."""
    if len(ref_T) != len(est_T):
        raise metrics.MetricsException("trajectories must have same number of poses")
    i, j = pairs[:, 0], pairs[:, 1]
    out: dict = {}
    for relation in dict.fromkeys(relations):           # each once, however often named
        if relation in (Rel.point_distance, Rel.point_distance_error_ratio):
            d_ref = np.linalg.norm(ref_T[i, :3, 3] - ref_T[j, :3, 3], axis=1)
            d_est = np.linalg.norm(est_T[i, :3, 3] - est_T[j, :3, 3], axis=1)
            err, delta_ids = np.abs(d_ref - d_est), j
            if relation == Rel.point_distance_error_ratio:
                nz = d_ref.nonzero()[0]
                delta_ids = delta_ids[nz]
                err = np.divide(err[nz], d_ref[nz]) * 100
            out[relation] = (err, delta_ids)
    on_poses = [r for r in dict.fromkeys(relations) if r not in out]
    if on_poses:
        ref_T, est_T = np.ascontiguousarray(ref_T, float), np.ascontiguousarray(est_T, float)
        i, j = np.ascontiguousarray(i), np.ascontiguousarray(j)
        parts: dict = {r: [] for r in on_poses}
        for a, b in _chunks(i.size):                # each chunk's error poses, then every relation's errors of them
            E = np.empty((b - a, 4, 4))
            _rpe_poses(ref_T, est_T, i[a:b], j[a:b], E)
            for r in on_poses:
                parts[r].append(pose_error(E, r))
        for r in on_poses:
            out[r] = (_joined(parts[r]), j)
    return [out[r] for r in relations]


# ---------------------------------------------------------------------------------------------- results
def _metric_result(metric, err: np.ndarray, ref_name: str, est_name: str, title_suffix: str) -> Result:
    metric.error = np.asarray(err, dtype=float)
    res = metric.get_result(ref_name, est_name)
    res.info["title"] = str(metric) + title_suffix
    return res


TIME_ARRAYS = ("seconds_from_start", "timestamps", "distances_from_start", "distances")


def _add_time_arrays(res: Result, traj_ref, traj_est, skip_first: bool, ids: np.ndarray | None = None,
                     time_arrays: dict | None = None) -> None:
    """The arrays ``evo_ape``/``evo_rpe`` add for a timed trajectory (computed on the whole arrays), of the poses
    ``ids`` (RPE: the trajectories evo reduces to them) or of all; the distances are evo's ``traj.distances``
    (``geometry.accumulated_distances`` of the positions). ``time_arrays``: those of another result of the same
    poses (:data:`TIME_ARRAYS` -> array), taken as they are instead of computed again."""
    if not isinstance(traj_est, PoseTrajectory3D):
        return
    if time_arrays is not None:
        for name in TIME_ARRAYS:
            res.add_np_array(name, time_arrays[name])
        return
    sel = slice(None) if ids is None else ids
    k = 1 if skip_first else 0
    ts = np.asarray(traj_est.timestamps)[sel]
    res.add_np_array("seconds_from_start", (ts - ts[0])[k:])
    res.add_np_array("timestamps", ts[k:])
    res.add_np_array("distances_from_start", geometry.accumulated_distances(traj_ref.positions_xyz[sel])[k:])
    res.add_np_array("distances", geometry.accumulated_distances(traj_est.positions_xyz[sel])[k:])


def names(traj_ref, traj_est) -> tuple[str, str]:
    return traj_ref.name or "reference", traj_est.name or "estimate"


def ape_result(traj_ref, traj_est, relation: Rel, err: np.ndarray, title_suffix: str = "\n(not aligned)",
               time_arrays: dict | None = None) -> Result:
    """The ``Result`` of ``evo.main_ape.ape`` for an error series computed here (``traj_*``: the associated,
    already aligned, evo trajectories the result carries; ``time_arrays``: see :func:`_add_time_arrays`)."""
    ref_name, est_name = names(traj_ref, traj_est)
    res = _metric_result(metrics.APE(relation), err, ref_name, est_name, title_suffix)
    res.add_trajectory(ref_name, traj_ref)
    res.add_trajectory(est_name, traj_est)
    _add_time_arrays(res, traj_ref, traj_est, skip_first=False, time_arrays=time_arrays)
    return res


def rpe_result(traj_ref, traj_est, relation: Rel, err: np.ndarray, delta_ids: np.ndarray, delta: float,
               delta_unit: metrics.Unit, rel_tol: float = 0.1, all_pairs: bool = False,
               pairs_from_reference: bool = False, title_suffix: str = "\n(not aligned)",
               trajectories: bool = True, time_arrays: dict | None = None) -> Result:
    """The ``Result`` of ``evo.main_rpe.rpe``: statistics of the error series, and the trajectories reduced
    to the first pose and each pair's second pose (copies: the inputs are left as they are). Without
    ``trajectories`` the result carries the same statistics and arrays but not the reduced trajectories (a run's
    RPE result files do not hold them; on a long drive they are two copies of the drive, ~0.5 s of evo's
    constructors and 176 MB for an hour at 200 Hz)."""
    ref_name, est_name = names(traj_ref, traj_est)
    metric = metrics.RPE(relation, delta, delta_unit, rel_tol, all_pairs, pairs_from_reference)
    res = _metric_result(metric, err, ref_name, est_name, title_suffix)
    ids = np.concatenate([[0], np.asarray(delta_ids, dtype=int)])
    if trajectories:
        res.add_trajectory(ref_name, reduced(traj_ref, ids))
        res.add_trajectory(est_name, reduced(traj_est, ids))
    _add_time_arrays(res, traj_ref, traj_est, skip_first=True, ids=ids, time_arrays=time_arrays)
    return res


def reduced(traj, ids: np.ndarray):
    """A new evo trajectory of the poses ``ids`` of ``traj`` (positions and quaternions only: no matrices)."""
    kw = {"positions_xyz": traj.positions_xyz[ids], "orientations_quat_wxyz": traj.orientations_quat_wxyz[ids],
          "meta": dict(traj.meta), "name": traj.name}
    if isinstance(traj, PoseTrajectory3D):
        return PoseTrajectory3D(timestamps=np.asarray(traj.timestamps)[ids], **kw)
    from evo.core.trajectory import PosePath3D

    return PosePath3D(**kw)


def with_poses(traj, T: np.ndarray):
    """A new evo trajectory with the poses ``T`` (an aligned estimate): the matrices, and the positions and
    quaternions of them (evo derives these per pose with ``quaternion_from_matrix``, w >= 0; scipy's
    canonical quaternion is the same to rounding)."""
    q_xyzw = Rotation.from_matrix(T[:, :3, :3]).as_quat(canonical=True)
    kw = {"poses_se3": list(T), "positions_xyz": T[:, :3, 3].copy(), "orientations_quat_wxyz": q_xyzw[:, [3, 0, 1, 2]],
          "meta": dict(traj.meta), "name": traj.name}
    if isinstance(traj, PoseTrajectory3D):
        return PoseTrajectory3D(timestamps=np.asarray(traj.timestamps), **kw)
    from evo.core.trajectory import PosePath3D

    return PosePath3D(**kw)
