"""The flat belief-tree search's tree: its nodes, their successors, the sawtooth points.

Used by :class:`stack.planning.sarsop.BeliefTreeSearch` (and its block form in
:mod:`stack.planning.blocksearch`):

- :class:`BeliefNode`, a belief as sparse (state index, probability) arrays with its
  two bounds, its successors once expanded and cached per-node arrays;
- :class:`NodeChildren`, the successors of one node under one action (P(z | b, a),
  R(b, a), the successor nodes, and their beliefs as the columns of one matrix);
- :class:`UpperPoints`, the upper bound's belief-value points with the sawtooth
  interpolation between them (Hauskrecht 2000; HSVI2, Smith and Simmons 2005);
- helpers on sparse rows (:func:`canonical`, :func:`gather_rows`) and the key a
  belief is found by in the tree (:func:`belief_key`).
"""

from __future__ import annotations

import hashlib

import numpy as np
import scipy.sparse as sp


def canonical(m: sp.csr_matrix) -> sp.csr_matrix:
    """``m`` with sorted, summed indices (a copy only where it has not)."""
    if m.has_canonical_format:
        return m
    m = m.copy()
    m.sum_duplicates()
    return m


def gather_rows(csr: sp.csr_matrix, rows: np.ndarray) -> tuple:
    """The non-zeros of ``csr``'s rows ``rows`` (canonical CSR: no duplicates), as
    (position in ``rows``, column, value) arrays, row by row."""
    starts = csr.indptr[rows]
    counts = csr.indptr[rows + 1] - starts
    r = np.repeat(np.arange(rows.size), counts)
    pos = np.arange(r.size) + np.repeat(starts - (np.cumsum(counts) - counts), counts)
    return r, csr.indices[pos], csr.data[pos]


def belief_key(idx: bytes, val: bytes) -> bytes:
    """The tree's key of a belief (its states, its probabilities rounded): a 128-bit
    digest, not the bytes themselves, which were a third copy of every node's arrays
    (RockSample_11_11: 16 KB a node over ~1,000 states)."""
    return hashlib.blake2b(idx + val, digest_size=16).digest()


class NodeChildren:
    """The successors of one node under one action."""

    __slots__ = ("reward", "zs", "pz", "nodes", "_M", "_nz", "_src")

    def __init__(self, reward, zs, pz, nodes, M, nz, src=None):
        self.reward: float = reward  # R(b, a)
        self.zs: np.ndarray = zs  # the reachable observations
        self.pz: np.ndarray = pz  # P(z | b, a) of the reachable observations
        self.nodes = nodes  # successor node per reachable observation
        self._M = M
        self._nz = nz
        # or, made when first read (most actions' never are): (M, nz) of every action's
        # successors, this action's states among nz (bool), its columns lo:hi
        self._src = src

    def _make(self) -> None:
        M, nz, own, lo, hi = self._src
        if own.all():
            self._M, self._nz = M[:, lo:hi], nz
        else:
            rows = np.flatnonzero(own)
            self._M, self._nz = M[rows, lo:hi], nz[rows]
        self._src = None

    @property
    def M(self) -> np.ndarray:
        """(len(nz), len(pz)) successor beliefs as columns, over states nz."""
        if self._src is not None:
            self._make()
        return self._M

    @property
    def nz(self) -> np.ndarray:
        """The states reachable from b under a."""
        if self._src is not None:
            self._make()
        return self._nz


class BeliefNode:
    __slots__ = ("idx", "val", "ub", "lb", "kids", "point", "cat", "flat")

    def __init__(self, idx: np.ndarray, val: np.ndarray, ub: float, lb: float):
        self.idx = idx
        self.val = val
        self.ub = ub
        self.lb = lb
        self.kids: list[NodeChildren] | None = None
        self.point = -1  # index of this belief's upper-bound point, -1 if none
        # every action's successors side by side (see BeliefTreeSearch._concatenate)
        self.cat: tuple | None = None
        # (successors of every action in order, their actions, P(z | b, a), R(b, .)):
        # Q of every action in one bincount (BeliefTreeSearch._q_bound)
        self.flat: tuple | None = None


class UpperPoints:
    """Belief-value points of the upper bound, with sawtooth interpolation.

    sawtooth_i(b) = c . b + (v_i - c . b_i) min_{s in supp b_i} b(s) / b_i(s), with c
    the corner values (the bound at the certain beliefs, refined by backups there);
    the bound is the minimum over the points and the corner plane.
    """

    def __init__(self, corner: np.ndarray):
        self.corner = corner.astype(float).copy()
        self.S = corner.size
        self.idx: list[np.ndarray] = []
        self.val: list[np.ndarray] = []
        self.value: list[float] = []
        self.by_state: dict[int, list[int]] = {}  # smallest support state -> points
        self._has = np.zeros(self.S, dtype=bool)  # the states by_state holds
        self._pos = np.full(self.S, -1)  # scratch: a belief's position of each state
        self._value_arr = np.empty(64)  # self.value as an array
        # per group (s; -1: all points): (support states, probabilities, offsets, point
        # ids, heights c . b_i), kept while the corners stay; and the excesses
        # min(v_i - c . b_i, 0), kept while the group's values stay
        self._struct: dict[int, tuple] = {}
        self._excess: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.idx)

    def add(self, idx: np.ndarray, val: np.ndarray, value: float) -> int:
        if idx.size == 1:
            self.set_corner(int(idx[0]), value)
            return -1
        height = float(self.corner[idx] @ val)
        if value - height >= -1e-12:
            return -1
        i = len(self.idx)
        self.idx.append(idx)
        self.val.append(val)
        self.value.append(value)
        if i == self._value_arr.size:
            self._value_arr = np.concatenate([self._value_arr, np.empty(i)])
        self._value_arr[i] = value
        s = int(idx[0])
        self.by_state.setdefault(s, []).append(i)
        self._has[s] = True
        for key in (s, -1):  # the point joins its group's arrays and all points'
            self._excess.pop(key, None)
            g = self._struct.get(key)
            if g is not None:
                states, probs, offsets, ids, heights = g
                self._struct[key] = (
                    np.concatenate([states, idx]),
                    np.concatenate([probs, val]),
                    np.append(offsets, states.size),
                    np.append(ids, i),
                    np.append(heights, height),
                )
        return i

    def update(self, i: int, value: float) -> None:
        if value < self.value[i]:
            self.value[i] = value
            self._value_arr[i] = value
            self._excess.pop(int(self.idx[i][0]), None)
            self._excess.pop(-1, None)

    def set_corner(self, s: int, value: float) -> None:
        if value < self.corner[s] - 1e-12:
            self.corner[s] = value
            # every point's height above the corner plane moves
            self._struct.clear()
            self._excess.clear()

    def _group(self, s: int) -> tuple:
        """Concatenated (support states, probabilities, offsets, excess) of the points
        whose smallest support state is s (s = -1: of all points, for models whose
        points are few and spread)."""
        g = self._struct.get(s)
        if g is None:
            ids = np.array(self.by_state[s] if s >= 0 else range(len(self.idx)), dtype=int)
            sizes = np.array([self.idx[i].size for i in ids])
            states = np.concatenate([self.idx[i] for i in ids])
            probs = np.concatenate([self.val[i] for i in ids])
            offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
            heights = np.add.reduceat(self.corner[states] * probs, offsets)
            g = (states, probs, offsets, ids, heights)
            self._struct[s] = g
        states, probs, offsets, ids, heights = g
        excess = self._excess.get(s)
        if excess is None:
            excess = np.minimum(self._value_arr[ids] - heights, 0.0)
            self._excess[s] = excess
        return states, probs, offsets, excess

    def values(self, nz: np.ndarray, M: np.ndarray) -> np.ndarray:
        """Sawtooth bound at the beliefs M[:, j] (over states nz), shape (M.shape[1],)."""
        base = self.corner[nz] @ M
        if not self.idx:
            return base
        groups = nz[self._has[nz]].tolist()
        if not groups:
            return base
        pos = self._pos  # -1 outside nz (restored below)
        pos[nz] = np.arange(nz.size)
        # a zero row last: a point with a state outside nz reads it (pos -1), so its
        # ratio is 0 and it adds nothing, as the sawtooth says; no filtering needed
        Mx = np.concatenate([M, np.zeros((1, M.shape[1]))])
        try:
            if len(groups) > 4:
                return base + self._interpolate(self._group(-1), pos, Mx)
            best = self._interpolate(self._group(groups[0]), pos, Mx)
            for s in groups[1:]:
                best = np.minimum(best, self._interpolate(self._group(s), pos, Mx))
        finally:
            pos[nz] = -1
        return base + best

    @staticmethod
    def _interpolate(group: tuple, pos: np.ndarray, Mx: np.ndarray) -> np.ndarray:
        """min over the group's points of (v_i - c . b_i) min_s b(s) / b_i(s) (<= 0)."""
        states, probs, offsets, excess = group
        ratio = np.minimum.reduceat(Mx[pos[states]] / probs[:, None], offsets, axis=0)
        return (ratio * excess[:, None]).min(axis=0)
