"""The mixed search's tree: person-belief nodes, per-cell vectors, upper-bound points.

Used by :class:`stack.planning.momdp.MixedSearch`. A node of its tree is a person belief
b holding both bounds for every robot cell, since the person's dynamics and observations
do not depend on the robot (:mod:`stack.planning.momdp_model`):

- :class:`MixedNode`, a person belief with lb[x], ub[x] for every cell x;
- :class:`MixedChildren`, a node's successors: one person posterior per observation,
  shared by every action and next cell, with the bounds of every (cell, observation);
- :class:`CellVectors`, one robot cell's lower-bound vectors over the person factor;
- :class:`PersonPoints`, the upper bound's belief-value points (the sawtooth on the
  fast informed bound), shared by every cell;
- :class:`MixedRoot`, a start: a node and the robot's cell there.
"""

from __future__ import annotations

import numpy as np


class MixedNode:
    """A person belief b with the bounds of every robot cell at it: lb[x], ub[x]."""

    __slots__ = ("b", "ub", "lb", "kids", "point", "group")

    def __init__(self, b: np.ndarray, ub: np.ndarray, lb: np.ndarray, group: int = -1):
        self.b = b
        self.group = group  # the observation this belief followed (-1: a start)
        self.ub = ub  # (X,)
        self.lb = lb  # (X,) the best vector of each cell at b
        self.kids: MixedChildren | None = None
        self.point = -1  # row of the upper bound's points; -1 never backed up, -2 no point


class MixedChildren:
    """The successors of a node: one person posterior per observation z, shared by
    every action and next cell. The posteriors (Y, nz) are recomputed from the parent's
    belief when needed (cheap) rather than kept; the bounds of every (cell, z) pair
    are kept, with the vectors and points already folded in, so a refresh only
    evaluates what was added since."""

    __slots__ = ("pz", "zs", "nodes", "reward", "lbv", "lbk", "lb_seen", "lb_gen", "ub", "seen")

    def __init__(self, pz, zs, reward, X):
        self.pz = pz  # (nz,) P(z | b)
        self.zs = zs  # (nz,) the observations with P(z | b) > 0
        self.nodes: dict[int, MixedNode] = {}  # j -> successor node (made when entered)
        self.reward = reward  # (X, A) R(x, b, a)
        nz = zs.size
        self.lbv = np.full((X, nz), -np.inf)  # best vector value of cell x at posterior j
        self.lbk = np.zeros((X, nz), dtype=np.int32)  # ... and its column in the cell
        self.lb_seen = np.zeros(X, dtype=np.int64)  # columns of each cell evaluated
        self.lb_gen = np.full(X, -1, dtype=np.int64)  # the cell's pruning generation
        self.ub = np.empty((X, nz))
        self.seen = 0  # upper-bound points folded into ub


class CellVectors:
    """One robot cell's lower-bound vectors (columns of G, over the person factor)."""

    def __init__(self, alphas: np.ndarray, actions: np.ndarray):
        Y = alphas.shape[1]
        cap = max(64, 2 * len(actions))
        self.G = np.empty((Y, cap))
        self.G[:, : len(actions)] = alphas.T
        self.act = np.empty(cap, dtype=int)
        self.act[: len(actions)] = actions
        self.n = len(actions)
        self.gen = 0  # bumped by every pruning (column indices change)
        self.pruned_at = self.n

    @property
    def cols(self) -> np.ndarray:
        return self.G[:, : self.n]

    def add(self, alpha: np.ndarray, action: int) -> None:
        if self.n == self.G.shape[1]:
            G = np.empty((self.G.shape[0], 2 * self.n))
            G[:, : self.n] = self.G[:, : self.n]
            act = np.empty(2 * self.n, dtype=int)
            act[: self.n] = self.act[: self.n]
            self.G, self.act = G, act
        self.G[:, self.n] = alpha
        self.act[self.n] = action
        self.n += 1

    def keep(self, idx: np.ndarray) -> None:
        k = idx.size
        self.G[:, :k] = self.G[:, idx]
        self.act[:k] = self.act[idx]
        self.n = self.pruned_at = k
        self.gen += 1


class PersonPoints:
    """Belief-value points of the upper bound, shared by every robot cell.

    If b = r b_i + (1 - r) b' with b' a belief (any r <= min_y b(y) / b_i(y)), convexity
    of V* gives V*(b) <= r v_i + (1 - r) U(b') for any upper bound U. The sawtooth of
    Hauskrecht (2000) takes U linear (the corner values); here U is the fast informed
    bound, max_a Q_a . b', so a point's term is

        r v_i(x) + max_a (Q_xa . b - r Q_xa . b_i),

    which is never above the fast informed bound at b's neighbour b' (with 65-value
    beliefs the corner plane lies far above the fast informed bound and the plain
    sawtooth never wins). A point is a person belief with a value per cell; a posterior
    after observation z is compared only with the points that were themselves
    posteriors after z (their *group*): the minimum may run over any subset of the
    points, and those are the only ones near it.
    """

    def __init__(self, fib: np.ndarray, X: int):
        self.fib = fib  # (X*A, Y) the fast informed bound's vectors
        Y = fib.shape[1]
        self.X = X
        self.P = np.empty((0, Y))
        self.Pinv = np.empty((0, Y))
        self.v = np.empty((0, X))  # the upper bound at b_i per cell
        self.QB = np.empty((0, fib.shape[0]))  # Q_xa . b_i
        self.group = np.empty(0, dtype=np.int64)  # the observation that produced b_i
        self.n = 0

    def add(self, b: np.ndarray, v: np.ndarray, group: int) -> int:
        if self.n == self.P.shape[0]:
            cap = max(64, 2 * self.n)
            for name in ("P", "Pinv", "v", "QB"):
                old = getattr(self, name)
                new = np.empty((cap, old.shape[1]))
                new[: self.n] = old[: self.n]
                setattr(self, name, new)
            g = np.empty(cap, dtype=np.int64)
            g[: self.n] = self.group[: self.n]
            self.group = g
        i = self.n
        self.P[i] = b
        # 1e300, not inf, where the point has no mass: 0 * inf would be nan
        self.Pinv[i] = np.where(b > 0, 1.0 / np.where(b > 0, b, 1.0), 1e300)
        self.v[i] = v
        self.QB[i] = self.fib @ b
        self.group[i] = group
        self.n += 1
        return i

    def update(self, i: int, v: np.ndarray) -> None:
        np.minimum(self.v[i], v, out=self.v[i])

    def term(self, i: np.ndarray, ratio: np.ndarray, QM: np.ndarray) -> np.ndarray:
        """The points' terms (X, p) at beliefs with fast-informed values QM (X*A, p)."""
        X = self.X
        d = (QM - ratio * self.QB[i].T).reshape(X, -1, i.size).max(axis=1)
        return ratio * self.v[i].T + d

    def correct(self, out: np.ndarray, B: np.ndarray, col_of_z: np.ndarray, start: int) -> None:
        """Lower ``out`` (X, n), the bounds at the beliefs B (Y, n), by the points
        start.. whose group is the observation of each column (col_of_z: observation ->
        column, -1 if none)."""
        if self.n <= start:
            return
        g = self.group[start : self.n]
        j = np.where(g >= 0, col_of_z[g], -1)
        i = np.flatnonzero(j >= 0) + start
        if i.size == 0:
            return
        j = j[i - start]
        Bj = B[:, j]
        ratio = (self.Pinv[i] * Bj.T).min(axis=1)  # (p,)
        vals = self.term(i, ratio, self.fib @ Bj)
        np.minimum.at(out.T, j, vals.T)


class MixedRoot:
    """A start: a node and the robot's cell there (lb/ub as the stopping rules read them)."""

    def __init__(self, node: MixedNode, x: int):
        self.node = node
        self.x = x

    @property
    def lb(self) -> float:
        return float(self.node.lb[self.x])

    @property
    def ub(self) -> float:
        return float(self.node.ub[self.x])
