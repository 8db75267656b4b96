"""Named layouts of the vectors the filters work on: the only place where state indices are written down.

A :class:`Layout` is an ordered set of named blocks (core blocks, then the blocks of a cloned pose) from
which every index is derived: ``ESKF.start("TH")``, ``ESKF.sl("BG")``. Formulations declare their own
layout in their module; this module holds the three that everything shares:

* :data:`CANONICAL`, the error state every observation model's Jacobian is written in (the error-state
  filter's own): ``[dp, dv, dtheta, dba, dbg]`` and a cloned pose ``[dp_c, dtheta_c]``, attitude errors
  right perturbations ``R = R_hat Exp(dtheta)``;
* :data:`NOMINAL`, the whole (nominal) state that every formulation keeps as one flat vector: ``p_w``,
  ``v_w``, ``R_wb`` (9, row-major), the accelerometer and gyro biases and the odometer scale error ``k``;
* :data:`CLONE`, the nominal pose of a clone: ``p_w``, ``R_wb``.

A formulation relates its own blocks to the canonical ones by pairs ``(canonical block, own block)``:
equal sizes mean the identity, a 3-vector attitude paired with a 4-vector quaternion ``q`` (w, x, y, z)
means ``dtheta = 2 Xi(q)^T dq``. :func:`canonical_map` builds ``D = d(canonical)/d(own)`` and
:func:`own_from_canonical` its right inverse ``E`` from these pairs; nothing else maps states by hand.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Block:
    name: str
    start: int
    size: int

    @property
    def stop(self) -> int:
        return self.start + self.size

    @property
    def sl(self) -> slice:
        return slice(self.start, self.stop)


class Layout:
    """Named blocks of a vector: ``core`` blocks, then ``clone`` blocks (present while a pose is cloned).

    ``clone_of`` maps each clone block to the core block it copies (the pose the clone is a copy of).
    """

    def __init__(self, name: str, core: list[tuple[str, int]], clone: list[tuple[str, int]] = (),
                 clone_of: dict[str, str] | None = None):
        self.name = name
        self.blocks: dict[str, Block] = {}
        i = 0
        for nm, size in [*core, *clone]:
            if nm in self.blocks:
                raise ValueError(f"{name}: block {nm!r} twice")
            self.blocks[nm] = Block(nm, i, size)
            i += size
        self.core = tuple(nm for nm, _ in core)
        self.clone = tuple(nm for nm, _ in clone)
        self.n_core = sum(s for _, s in core)
        self.n = i
        self.clone_of = dict(clone_of or {})
        for c, src in self.clone_of.items():
            if c not in self.clone or src not in self.core or self.blocks[c].size != self.blocks[src].size:
                raise ValueError(f"{name}: clone block {c!r} cannot copy {src!r}")
        self._clone_rows = self.index(*(self.clone_of[c] for c in self.clone)) if self.clone_of else np.zeros(0, int)

    def __getitem__(self, name: str) -> Block:
        return self.blocks[name]

    def __contains__(self, name: str) -> bool:
        return name in self.blocks

    def start(self, name: str) -> int:
        return self.blocks[name].start

    def sl(self, name: str) -> slice:
        return self.blocks[name].sl

    def index(self, *names: str) -> np.ndarray:
        """The indices of the named blocks, concatenated in the order given."""
        return np.concatenate([np.arange(self.blocks[n].start, self.blocks[n].stop) for n in names])

    def pack(self, **values) -> np.ndarray:
        """A vector of this layout from the value of every block (a parameter record, say)."""
        missing = set(self.blocks) - set(values)
        if missing:
            raise ValueError(f"{self.name}: no value for {sorted(missing)}")
        v = np.zeros(self.n)
        for name, value in values.items():
            v[self.sl(name)] = value
        return v

    def columns(self, **arrays) -> np.ndarray:
        """Rows ``(N, n)`` of this layout from an ``(N, size)`` (or ``(N,)``) array per block (input rows, say)."""
        first = next(iter(arrays.values()))
        out = np.empty((np.shape(first)[0], self.n))
        for name, a in arrays.items():
            out[:, self.sl(name)] = np.reshape(a, (out.shape[0], self[name].size))
        return out

    def clone_rows(self) -> np.ndarray:
        """The core rows a clone copies, in the order of the clone blocks."""
        return self._clone_rows

    def __repr__(self) -> str:
        return f"Layout({self.name!r}, " + ", ".join(f"{b.name}[{b.start}:{b.stop}]" for b in self.blocks.values()) + ")"


CANONICAL = Layout("canonical error state", [("P", 3), ("V", 3), ("TH", 3), ("BA", 3), ("BG", 3)],
                   clone=[("CP", 3), ("CTH", 3)], clone_of={"CP": "P", "CTH": "TH"})
NOMINAL = Layout("nominal state", [("p", 3), ("v", 3), ("R", 9), ("ba", 3), ("bg", 3), ("k", 1)])
CLONE = Layout("cloned pose", [("p", 3), ("R", 9)])

# The position and attitude blocks, whose joint covariance the filters record for NEES (in this layout).
POSE_BLOCKS = ("P", "TH")
POSE = Layout("recorded pose covariance", [(b, CANONICAL[b].size) for b in POSE_BLOCKS])

# It is recorded packed: the upper triangle row by row (21 of the 36 numbers: a simulated hour at 200 Hz records
# 720,001 of them, 115 MiB instead of 198). PACKED[i, j] (= PACKED[j, i]) is the place of entry (i, j).
_IU, _JU = np.triu_indices(POSE.n)
POSE_PACKED_N = _IU.size
PACKED = np.zeros((POSE.n, POSE.n), np.int64)
PACKED[_IU, _JU] = np.arange(POSE_PACKED_N)
PACKED[_JU, _IU] = np.arange(POSE_PACKED_N)


def pack_pose_cov(C: np.ndarray) -> np.ndarray:
    """Covariances ``(..., 6, 6)`` of [dp, dtheta] packed as the filters record them: ``(..., 21)``."""
    return np.asarray(C)[..., _IU, _JU]


def unpack_pose_cov(packed: np.ndarray) -> np.ndarray:
    """Packed pose covariances ``(..., 21)`` as the symmetric ``(..., 6, 6)`` matrices."""
    return np.asarray(packed)[..., PACKED]


def _xi(q: np.ndarray) -> np.ndarray:
    """Xi(q) = [q]_L[:, 1:4] for a quaternion (w, x, y, z): q (x) [1, dtheta/2] = q + Xi(q) dtheta / 2."""
    w, x, y, z = q
    return np.array([[-x, -y, -z], [w, -z, y], [z, w, -x], [-y, x, w]])


def _pair_blocks(own: Layout, pairs, n: int):
    for c, o in pairs:
        cb, ob = CANONICAL[c], own[o]
        if ob.stop <= n:
            yield cb, ob


def canonical_map(own: Layout, pairs, n: int, quats: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """``D = d(canonical error)/d(own state)``, ``(CANONICAL.n, n)``, for the first ``n`` own states.

    ``quats`` holds, for each own quaternion block, the quaternion (w, x, y, z) the map is taken at.
    """
    D = np.zeros((CANONICAL.n, n))
    for cb, ob in _pair_blocks(own, pairs, n):
        D[cb.sl, ob.sl] = np.eye(cb.size) if cb.size == ob.size else 2.0 * _xi(quats[ob.name]).T
    return D


def own_from_canonical(own: Layout, pairs, n: int, quats: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """``E = d(own state)/d(canonical error)``, ``(n, CANONICAL.n)``: ``D E = I`` on the mapped blocks."""
    E = np.zeros((n, CANONICAL.n))
    for cb, ob in _pair_blocks(own, pairs, n):
        E[ob.sl, cb.sl] = np.eye(cb.size) if cb.size == ob.size else 0.5 * _xi(quats[ob.name])
    return E


def canonical_index(own: Layout, pairs) -> np.ndarray:
    """For each core canonical state, the own state it equals (identity pairs), or -1: what the compiled
    recording of a formulation copies without arithmetic."""
    idx = np.full(CANONICAL.n_core, -1, np.int64)
    for c, o in pairs:
        cb, ob = CANONICAL[c], own[o]
        if c in CANONICAL.core and cb.size == ob.size:
            idx[cb.sl] = np.arange(ob.start, ob.stop)
    return idx


def canonical_blocks(own: Layout, pairs) -> frozenset[str]:
    """The canonical blocks a formulation has a counterpart for (an observation needing others is refused)."""
    return frozenset(c for c, _ in pairs)
