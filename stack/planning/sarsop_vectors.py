"""The flat belief-tree search's lower bound: its alpha vectors, their archive, the policy.

:class:`VectorStore` is the layer of :class:`stack.planning.sarsop.BeliefTreeSearch`
that holds the lower bound V_L(b) = max_k alpha_k . b:

- the **active** vectors, stored transposed (S, capacity) so that a belief's states
  are contiguous rows; the best one at a belief or at many (``_best_at``,
  ``_best_cols``, ``_best_nodes``), a new one (``_add_alpha``), pruning to those best
  at some backed-up belief (``_prune``, dominance at the sampled beliefs as SARSOP).
  :class:`stack.planning.blocksearch.BlockTreeSearch` overrides these vector-store
  methods (``_init_store``, ``_best_at``, ``_best_cols``, ``_best_nodes``, ``_store``,
  ``_compact``, ``_sample_vectors``) to keep its vectors per observed block;
- the **archive**: every vector ever made, by global id, with its action and the ids
  of the vectors it leads to after each observation. The written policy is a closed
  set (:meth:`VectorStore.closure`): its vectors and every successor they lead to, so
  the best vector's policy earns at least the bound (:mod:`stack.planning.controller`);
- what writing that policy will cost (``_values_to_write``, ``_measure_writing``),
  which the stopping rules keep time for.

The search's tree and expansion are the next layer
(:class:`stack.planning.sarsop_expand.BeliefExpansion`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stack.planning import clock
from stack.planning.controller import prune_closed
from stack.planning.policy import AlphaPolicy, seconds_per_value
from stack.planning.sarsop_nodes import BeliefNode
from stack.planning.search_base import SearchBase


class VectorStore(SearchBase):
    """The lower bound's vectors of a flat belief-tree search (see the module
    docstring); the attributes below are set by the search's ``__init__``."""

    S: int
    nodes: dict[bytes, BeliefNode]
    roots: list[BeliefNode]
    successors: np.ndarray
    _all_alpha: list[np.ndarray | None]
    _all_act: list[int]
    _all_succ: list[np.ndarray]
    _values_per_vector: int
    _n_archived: int
    _n_first: int
    _pruned_at: int

    # -- the vectors: stored, valued at beliefs ---------------------------------------
    # (BlockTreeSearch, stack/planning/blocksearch.py, stores them per observed block)
    def _init_store(
        self, alphas: np.ndarray, actions: np.ndarray, succ: np.ndarray, n_active: int
    ) -> None:
        """The initial vectors (blind, seeds): the first ``n_active`` are active."""
        # the vectors are stored transposed, (S, capacity): a gather of the states a
        # belief covers then reads contiguous rows
        self.K = n_active
        self._AT = np.empty((self.S, max(64, 2 * self.K)))
        self._AT[:, : self.K] = alphas[: self.K].T
        self._act = np.zeros(self._AT.shape[1], dtype=int)
        self._act[: self.K] = actions[: self.K]
        self._all_alpha.extend(alphas)
        self._all_act.extend(int(a) for a in actions)
        self._all_succ.extend(succ)
        self._gid = np.zeros(self._AT.shape[1], dtype=int)
        self._gid[: self.K] = np.arange(self.K)

    def _best_at(self, idx: np.ndarray, val: np.ndarray) -> tuple[int, float]:
        """The active vector best at the belief ``val`` over states ``idx`` (its
        position) and its value there."""
        v = val @ self._AT[idx, : self.K]
        k = int(v.argmax())
        return k, float(v[k])

    def _best_cols(self, nz: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The best active vector (position) at every belief M[:, j] (over states nz),
        and its value there."""
        G = M.T @ self._AT[nz, : self.K]  # (beliefs, K)
        best = G.argmax(axis=1)
        return best, G[np.arange(best.size), best]

    def _best_nodes(self, nodes: list[BeliefNode]) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_best_cols` at the beliefs of ``nodes``, as one sparse product."""
        indptr = np.concatenate([[0], np.cumsum([n.idx.size for n in nodes])])
        B = sp.csr_matrix(
            (
                np.concatenate([n.val for n in nodes]),
                np.concatenate([n.idx for n in nodes]),
                indptr,
            ),
            shape=(len(nodes), self.S),
        )
        V = np.asarray(B @ self._AT[:, : self.K])
        best = V.argmax(axis=1)
        return best, V[np.arange(len(nodes)), best]

    def _store(self, alpha: np.ndarray, action: int, node: BeliefNode) -> None:
        """Put a new vector (made at ``node``) at active position K."""
        if self.K == self._AT.shape[1]:
            grown = np.empty((self.S, 2 * self.K))
            grown[:, : self.K] = self._AT
            self._AT = grown
            self._act = np.concatenate([self._act, np.zeros(self.K, dtype=int)])
            self._gid = np.concatenate([self._gid, np.zeros(self.K, dtype=int)])
        self._AT[:, self.K] = alpha
        self._act[self.K] = action
        self._gid[self.K] = len(self._all_alpha)

    def _compact(self, kept: np.ndarray) -> None:
        """Keep the active vectors at positions ``kept`` (ascending), in that order."""
        self._AT[:, : kept.size] = self._AT[:, kept]
        self._act[: kept.size] = self._act[kept]
        self._gid[: kept.size] = self._gid[kept]
        self.K = kept.size

    def _sample_vectors(self) -> np.ndarray:
        """A block of stored values (at most 64 vectors x 512 states) to time writing."""
        return self._AT[: min(self.S, 512), : min(self.K, 64)].T

    @property
    def alphas(self) -> np.ndarray:
        """The lower bound's vectors, (K, S)."""
        return self._AT[:, : self.K].T

    @property
    def actions(self) -> np.ndarray:
        return self._act[: self.K]

    def _add_alpha(
        self, alpha: np.ndarray, succ: np.ndarray, action: int, node: BeliefNode
    ) -> None:
        self._store(alpha, action, node)
        self._all_alpha.append(alpha)
        self._all_act.append(action)
        self._all_succ.append(succ)
        self.K += 1
        if self.K > self.config.prune_growth * self._pruned_at + 50:
            self._prune()

    def _prune(self, until: float | None = None) -> None:
        """Keep the vectors that are best at some backed-up belief of the tree.

        Dominance at the sampled beliefs (SARSOP): a vector that is nowhere the best
        of the set at a belief the search has backed up is dropped. The best vector of
        every such node is kept, so their lower bounds (the roots' among them) never
        drop; a leaf's bound is re-read from the vectors when its parent is backed up.
        """
        nodes = [n for n in self.nodes.values() if n.kids is not None]
        keep = np.zeros(self.K, dtype=bool)
        chunk = max(1, 4_000_000 // max(self.K, 1))
        t0 = clock.now()
        for lo in range(0, len(nodes), chunk):
            if self._late() if until is None else clock.now() >= until:
                return  # a long pruning (many nodes, many vectors) is abandoned whole
            part = nodes[lo : lo + chunk]
            best, values = self._best_nodes(part)
            keep[best] = True
            for n, v in zip(part, values.tolist(), strict=True):
                n.lb = min(max(n.lb, v), n.ub)
        self._compact(np.flatnonzero(keep))
        self._measure_writing()
        self._pruned_at = self.K
        self._prune_s = clock.now() - t0

    def _policy(self) -> AlphaPolicy:
        """The policy written: the closed set of :meth:`_closed_policy`, less its
        pointwise dominated vectors in the time kept for it (a smaller file written
        sooner; the best vector's value is unchanged, the set stays closed)."""
        alphas, actions, succ = self._closed_policy()
        budget = self.deadline - clock.now() - alphas.size * self.write_seconds_per_value()
        if budget > 0:
            alphas, actions, succ = prune_closed(alphas, actions, succ, self._n_first, budget)
        self.successors = succ
        return AlphaPolicy(alphas, actions, meta={"solver": "sarsop"})

    def _closed_policy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The active vectors and, from the archive, every successor they lead to:
        (alphas (K', S), actions (K',), successors (K', Z) as positions, -1 unknown).
        The best vector's policy over a closed set earns its bound (controller.py)."""
        order = self.closure()
        where = {g: k for k, g in enumerate(order)}
        where[-1] = -1
        succ = np.array([[where[int(g)] for g in self._all_succ[k]] for k in order], dtype=int)
        alphas = np.vstack([self._all_alpha[k] for k in order])  # type: ignore[misc]
        actions = np.array([self._all_act[k] for k in order], dtype=int)
        return alphas, actions, succ.reshape(len(order), -1)

    def _reached(self) -> list[int]:
        """Positions in the active set of the best vector at every tree node the best
        vector's policy reaches from the roots (following its action into the tree)."""
        used: dict[int, None] = {}
        seen: set[int] = set()
        stack = list(self.roots)
        while stack:
            n = stack.pop()
            if id(n) in seen:
                continue
            seen.add(id(n))
            k = self._best_at(n.idx, n.val)[0]
            used[k] = None
            if n.kids is not None:
                stack.extend(n.kids[int(self._act[k])].nodes)
        return list(used)

    def closure(self, reached: bool = True) -> list[int]:
        """Global ids of the active vectors, then of the archived ones they lead to.

        With ``config.reached_only``, of the active vectors only those the policy uses
        at the tree's nodes it reaches from the roots: a closed set holding the roots'
        best vectors still earns the roots' bounds (controller.py), and it is the part
        of the policy the search has looked at (RockSample_5_7: a fraction of the file).
        """
        use = reached and self.config.reached_only
        active = self._reached() if use else range(self.K)
        order = [int(self._gid[k]) for k in active]
        self._n_first = len(order)
        seen = set(order)
        i = 0
        while i < len(order):
            for g in self._all_succ[order[i]]:
                g = int(g)
                if g >= 0 and g not in seen:
                    seen.add(g)
                    order.append(g)
            i += 1
        return order

    def _values_to_write(self) -> int:
        # the archived successors written with the active set, as counted at the last
        # pruning (RockSample_5_7: 2,027 vectors written for ~800 active), scaled by
        # the machine's measured speed of writing (TagAvoid's 888 x 870 values took
        # 5.5 s at load 10, 7 us a value against the 1 us assumed), and the share of
        # them the policy writes (reached_only)
        n = (self.K + self._n_archived) * self._write_share
        return int(n * self._values_per_vector * self._write_factor)

    def _measure_writing(self) -> None:
        """How much slower than ``config.write_s_per_value`` writing a value is now,
        and what share of the closure of the active set the written policy holds."""
        closure = self.closure(reached=False)
        self._n_archived = len(closure) - self.K  # an upper bound
        self._forget_unreachable(closure)
        if self.config.write_s_per_value <= 0:
            return
        self._write_share = self._written_share()
        # a sample block (at most 512 states x 64 vectors): the speed per value, cheaply
        per_value = seconds_per_value(self._sample_vectors())
        self._write_factor = max(1.0, per_value / self.config.write_s_per_value)

    def _written_share(self) -> float:
        """The share of the active set's closure that the written policy holds: with
        ``reached_only`` only the vectors the policy uses at the tree's nodes it reaches,
        and their successors (RockSample_7_8: 1,146 of 2,624 vectors, so 60 s solves kept
        18 s for writing and wrote in 5 s). Measured at each pruning; 1.0 before the tree
        has nodes, or when every active vector is written."""
        if not self.config.reached_only or not getattr(self, "nodes", None):
            return 1.0
        full = self.K + self._n_archived
        return min(1.0, len(self.closure(reached=True)) / max(1, full))

    def _forget_unreachable(self, closure: list[int]) -> None:
        """Release the archived vectors outside ``closure`` (the active set's closure).

        A new vector's successors are active vectors, so an archived vector that no vector
        of the closure leads to is never read again: its memory goes (one S-vector each;
        RockSample_11_11: 2 MB a vector). Its id stays, holding None."""
        keep = np.zeros(len(self._all_alpha), dtype=bool)
        keep[closure] = True
        for g in np.flatnonzero(~keep).tolist():
            self._all_alpha[g] = None

    @property
    def n_alphas(self) -> int:
        return self.K
