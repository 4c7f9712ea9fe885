"""The flat belief-tree search's tree: beliefs found or made, expanded, and valued.

:class:`BeliefExpansion` is the layer of :class:`stack.planning.sarsop.BeliefTreeSearch`
between its vectors (:class:`stack.planning.sarsop_vectors.VectorStore`, below) and its
trials and backups (``sarsop.py``, above):

- ``_node``: the tree's node of a belief, made with its bounds where new (the tree is a
  graph: one node per belief, found by :func:`~stack.planning.sarsop_nodes.belief_key`);
- ``_expand``: the successors of a node under every action (computed once; dense
  tables where small, ``_expand_dense``, every action in one product), their nodes
  made in one pass (``_children``);
- the Q values of a node's actions from its successors' bounds: ``_q_bound`` from the
  cached bounds, ``_q_upper`` re-interpolating the best action's successors with the
  latest sawtooth points, ``_q_lower`` with the best vector at every successor (every
  action's successors as one matrix where small, ``_concatenate``).

Beliefs are sparse (index, probability) arrays, so a model whose beliefs cover a small
part of its states costs in proportion to that part.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stack.planning.sarsop_nodes import (
    BeliefNode,
    NodeChildren,
    UpperPoints,
    belief_key,
    gather_rows,
)
from stack.planning.sarsop_vectors import VectorStore

_PROB_EPS = 1e-12  # successor beliefs less likely than this are not expanded
_CAT_MAX = 4096  # values of one node's concatenated successors (BeliefExpansion._concatenate)
_CAT_BUDGET = 20_000_000  # ... of all nodes' (160 MB)


class BeliefExpansion(VectorStore):
    """Nodes, successors and Q values of a flat belief-tree search (see the module
    docstring); the attributes below are set by the search's ``__init__``."""

    A: int
    gamma: float
    R: np.ndarray
    O: list[sp.csr_matrix]
    O_dense: list[np.ndarray | None]
    O_stack: np.ndarray | None
    T_all: sp.csr_matrix
    T_all_dense: np.ndarray | None
    Q_upper: np.ndarray
    points: UpperPoints
    _cat_values: int

    # -- beliefs and bounds -----------------------------------------------------------
    def _upper_vectors(self, nz: np.ndarray, M: np.ndarray) -> np.ndarray:
        return (self.Q_upper[nz].T @ M).max(axis=0)

    def _node(self, idx: np.ndarray, val: np.ndarray, ub: float | None = None) -> BeliefNode:
        key = belief_key(idx.tobytes(), np.round(val, 10).tobytes())
        node = self.nodes.get(key)
        if node is None:
            M = val[:, None]
            if ub is None:
                ub = float(min(self._upper_vectors(idx, M)[0], self.points.values(idx, M)[0]))
            lb = self._best_at(idx, val)[1]
            node = BeliefNode(idx, val, ub, min(lb, ub))
            self.nodes[key] = node
        return node

    def _expand(self, node: BeliefNode) -> list[NodeChildren]:
        """Successor beliefs of ``node`` under every action (computed once)."""
        if node.kids is not None:
            return node.kids
        S = self.S
        if self.T_all_dense is not None and self.O_stack is not None:
            node.kids = self._expand_dense(node)
            return node.kids
        if self.T_all_dense is not None:
            pred_all = node.val @ self.T_all_dense[node.idx]
            starts = None
        else:
            # the predictions over the states reached only (all actions: A x S columns,
            # most never reached; RockSample_11_11: 4 million): from T_all's rows at the
            # belief's states, summed per column in row order as the product does
            r, c, v = gather_rows(self.T_all, node.idx)
            cols, inv = np.unique(c, return_inverse=True)
            pv = np.bincount(inv, weights=v * node.val[r], minlength=cols.size)
            cols, pv = cols[pv > 0].astype(np.int64), pv[pv > 0]  # keys hash int64 indices
            starts = np.searchsorted(cols, np.arange(self.A + 1) * S).tolist()
        kids = []
        for a in range(self.A):
            if starts is None:
                pred = pred_all[a * S : (a + 1) * S]
                nz = np.flatnonzero(pred > 0)
                pn = pred[nz]
            else:
                nz = cols[starts[a] : starts[a + 1]] - a * S
                pn = pv[starts[a] : starts[a + 1]]
            o_dense = self.O_dense[a]
            if o_dense is not None:
                joint = o_dense[nz] * pn[:, None]
                pz = joint.sum(axis=0)
                zs = np.flatnonzero(pz > _PROB_EPS)
                M = joint[:, zs] / pz[zs]
            else:
                # the rows of O[a] at nz gathered with numpy (scipy's fancy indexing and
                # sparse products cost more than the arithmetic on block models)
                r, z, p = gather_rows(self.O[a], nz)
                p = p * pn[r]
                pz = np.bincount(z, weights=p, minlength=self.O[a].shape[1])
                zs = np.flatnonzero(pz > _PROB_EPS)
                col = np.full(pz.size, -1)
                col[zs] = np.arange(zs.size)
                keep = col[z] >= 0
                M = np.zeros((nz.size, zs.size))
                M[r[keep], col[z[keep]]] = p[keep]
                M /= pz[zs]
            reward = float(self.R[node.idx, a] @ node.val)
            # the fast informed bound only: the sawtooth is interpolated when an action's
            # successors matter (see _q_upper)
            ub = self._upper_vectors(nz, M)
            kids.append(NodeChildren(reward, zs, pz[zs], self._children(nz, M, ub), M, nz))
        node.kids = kids
        node.flat = (
            [c for k in kids for c in k.nodes],
            np.repeat(np.arange(self.A), [k.zs.size for k in kids]),
            np.concatenate([k.pz for k in kids]),
            np.array([k.reward for k in kids]),
        )
        return kids

    def _children(self, nz: np.ndarray, M: np.ndarray, ub: np.ndarray) -> list[BeliefNode]:
        """The nodes of the beliefs M[:, j] (over states nz), made where new with the
        upper bound ``ub[j]``: one pass over all columns (a column's support, key and,
        for new nodes, lower bound come from arrays made once)."""
        cols, rows = np.nonzero(M.T > 0)  # column by column, rows ascending
        vals = M[rows, cols]
        idxs = nz[rows]
        keys = np.round(vals, 10)
        ends = np.searchsorted(cols, np.arange(1, M.shape[1] + 1))
        lbs = None
        nodes = []
        lo = 0
        for j, hi in enumerate(ends.tolist()):
            key = belief_key(idxs[lo:hi].tobytes(), keys[lo:hi].tobytes())
            child = self.nodes.get(key)
            if child is None:
                if lbs is None:  # every column's best vector, one product
                    lbs = self._best_cols(nz, M)[1]
                u = float(ub[j])
                # a belief over all of nz is a view of M's column and nz (which its
                # parent keeps): no copy; any other its own arrays (a slice would keep
                # the whole of vals and idxs alive)
                if hi - lo == nz.size:
                    idx, val = nz, M[:, j]
                else:
                    idx, val = idxs[lo:hi].copy(), vals[lo:hi].copy()
                child = BeliefNode(idx, val, u, min(float(lbs[j]), u))
                self.nodes[key] = child
            nodes.append(child)
            lo = hi
        return nodes

    def _expand_dense(self, node: BeliefNode) -> list[NodeChildren]:
        """:meth:`_expand` for a model whose tables are small enough to be dense: every
        action at once, the successors over the union of the states they cover."""
        A, S = self.A, self.S
        assert self.T_all_dense is not None and self.O_stack is not None
        pred = (node.val @ self.T_all_dense[node.idx]).reshape(A, S)
        nz = np.flatnonzero(pred.any(axis=0))
        pred = pred[:, nz]  # (A, n)
        joint = pred[:, :, None] * self.O_stack[:, nz, :]  # (A, n, Z)
        pz = joint.sum(axis=1)  # (A, Z)
        acts, zs = np.nonzero(pz > _PROB_EPS)  # by action, then observation
        pz_flat = pz[acts, zs]
        M = joint[acts, :, zs].T / pz_flat  # (n, successors)
        ub = (self.Q_upper[nz].T @ M).max(axis=0)  # the fast informed bound only
        reward = node.val @ self.R[node.idx]
        nodes = self._children(nz, M, ub)
        bounds = np.searchsorted(acts, np.arange(A + 1)).tolist()
        # the action's own states: the sawtooth reads only the points whose support
        # lies inside them
        own = pred > 0
        kids = []
        for a, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
            src = (M, nz, own[a], lo, hi)
            kids.append(
                NodeChildren(
                    float(reward[a]), zs[lo:hi], pz_flat[lo:hi], nodes[lo:hi], None, None, src
                )
            )
        node.flat = (nodes, acts, pz_flat, reward)
        # the concatenation _q_lower values every successor with is M itself
        n = M.shape[1]
        if n and M.size <= _CAT_MAX and self._cat_values + M.size <= _CAT_BUDGET:
            starts = bounds  # (A + 1) where each action's successors start
            leaf = np.array([c.kids is None for c in nodes])
            node.cat = (nz, M, acts, pz_flat, reward, starts, nodes, leaf)
            self._cat_values += M.size
        return kids

    def _refresh_upper(self, kids: NodeChildren) -> np.ndarray:
        """Upper bounds of the successors, re-interpolated with the latest points."""
        fresh = self.points.values(kids.nz, kids.M)
        ub = np.array([c.ub for c in kids.nodes])
        ub = np.minimum(ub, fresh)
        for c, u in zip(kids.nodes, ub.tolist(), strict=True):
            c.ub = u
        return ub

    def _q_bound(self, node: BeliefNode, upper: bool) -> np.ndarray:
        """Q(b, a) of every action from the successors' cached upper (lower) bounds."""
        children, acts, pz, reward = node.flat  # type: ignore[misc]
        v = np.array([c.ub for c in children] if upper else [c.lb for c in children])
        return reward + self.gamma * np.bincount(acts, weights=pz * v, minlength=self.A)

    def _q_upper(self, node: BeliefNode, kids: list[NodeChildren]) -> np.ndarray:
        """Q_U(b, a) for every action, the best one with freshly interpolated successors.

        The successors' cached bounds are valid, if loose (the bound only decreases):
        re-interpolate the best action's successors until the best action is fresh.
        """
        g = self.gamma
        q_upper = self._q_bound(node, upper=True)
        fresh = np.zeros(self.A, dtype=bool)
        while True:
            a = int(q_upper.argmax())
            if fresh[a]:
                return q_upper
            q_upper[a] = kids[a].reward + g * (kids[a].pz @ self._refresh_upper(kids[a]))
            fresh[a] = True

    def _concatenate(self, node: BeliefNode, kids: list[NodeChildren]) -> tuple | None:
        """Every action's successor beliefs as the columns of one matrix over the union
        of their states, so one product values every successor of every action (the
        loop over actions cost more than the products on RockSample). Kept while the
        cached matrices stay under ``_CAT_BUDGET`` values in all."""
        if node.cat is not None:
            return node.cat
        n = sum(k.zs.size for k in kids)
        if n == 0:
            return None
        nz = np.unique(np.concatenate([k.nz for k in kids]))
        if nz.size * n > _CAT_MAX or self._cat_values + nz.size * n > _CAT_BUDGET:
            return None
        M = np.zeros((nz.size, n))
        col = 0
        for k in kids:
            M[np.searchsorted(nz, k.nz), col : col + k.zs.size] = k.M
            col += k.zs.size
        seg = np.repeat(np.arange(self.A), [k.zs.size for k in kids])
        pz = np.concatenate([k.pz for k in kids])
        reward = np.array([k.reward for k in kids])
        starts = np.concatenate([[0], np.cumsum([k.zs.size for k in kids])])
        children = [c for k in kids for c in k.nodes]
        leaf = np.array([c.kids is None for c in children])
        node.cat = (nz, M, seg, pz, reward, starts, children, leaf)
        self._cat_values += M.size
        return node.cat

    def _q_lower(
        self, node: BeliefNode, kids: list[NodeChildren]
    ) -> tuple[np.ndarray, np.ndarray, list]:
        """Q_L(b, a) for every action, the best vector at each successor (every action's
        in turn) and where each action's successors start there (A + 1)."""
        g = self.gamma
        cat = self._concatenate(node, kids)
        if cat is not None:
            nz, M, seg, pz, reward, starts, children, leaf = cat
            best, lbs = self._best_cols(nz, M)
            if leaf.any():  # a leaf's bound is just its best vector's value
                values = lbs.tolist()
                for j in leaf.nonzero()[0].tolist():
                    c = children[j]
                    if c.kids is None:
                        c.lb = min(values[j], c.ub)
                    else:
                        leaf[j] = False
            q = reward + g * np.bincount(seg, weights=pz * lbs, minlength=self.A)
            return q, best, starts
        q_lower = np.empty(self.A)
        choice = []
        for a, k in enumerate(kids):
            best, lbs = self._best_cols(k.nz, k.M)  # the best vector at every successor
            for c, v in zip(k.nodes, lbs, strict=True):
                if c.kids is None:  # a leaf's bound is just its best vector's value
                    c.lb = min(float(v), c.ub)
            q_lower[a] = k.reward + g * (k.pz @ lbs)
            choice.append(best)
        return q_lower, np.concatenate(choice), np.cumsum([0] + [c.size for c in choice]).tolist()

    @property
    def n_points(self) -> int:
        return len(self.points)
