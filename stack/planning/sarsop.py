"""Heuristic search over the belief tree reachable from b0 (the HSVI2 / SARSOP family).

Two bounds on the optimal value V* are kept and tightened where the search goes:

- the **lower bound** is a set of alpha vectors, V_L(b) = max_k alpha_k . b. It starts
  from the blind policies ("always do a", plus any seed plans), and every backup at a
  visited belief *adds* one vector (the point-based backup of eq. 2.21); vectors are
  never replaced wholesale, only pruned when another vector is at least as good at
  every belief the search has visited (dominance at the sampled beliefs, as SARSOP).
- the **upper bound** is the fast informed bound (a vector per action, Hauskrecht
  2000) refined by belief-value points: every backup stores (b, V_U(b)) and the bound
  at any belief is the sawtooth interpolation of the points with the corner values
  (Hauskrecht 2000; HSVI2, Smith and Simmons 2005).

The search runs trials from b0. A trial descends by the action with the best upper
bound and the observation with the largest weighted gap, until the gap at a node is
small enough for the root to reach its target, SARSOP's target-level rule
(Kurniawati, Hsu and Lee 2008): each trial asks the root's gap to shrink by a factor,
and propagates the matching targets (L, U) down the tree. The nodes of the trial are
then backed up deepest first. Beliefs are sparse (index, probability) arrays, so a
model whose beliefs cover a small part of its states (the robot's own cell observed
exactly, as in the task model and RockSample) costs in proportion to that part: the
mixed-observability saving of SARSOP's MOMDP solver falls out of the sparsity for the
beliefs. Its vectors are flat here; :mod:`stack.planning.blocksearch` is this search
with vectors per observed block (a ``.pomdpx`` with fully observed variables), through
the vector-store methods of :mod:`stack.planning.sarsop_vectors` (``_init_store``,
``_best_at``, ``_best_cols``, ...).

The search stops when the root's gap is below the target, or at the deadline, which
is checked between backups (a backup costs milliseconds), so the time limit holds.
Same model, same settings, same result: there is no randomness in the search.

The search is one class, :class:`BeliefTreeSearch`, written in layers that share its
cached per-node arrays, each a module:

- :mod:`stack.planning.search_base`: settings, reports, result and stopping rules
  (shared with the mixed-observability search, :mod:`stack.planning.momdp`);
- :mod:`stack.planning.sarsop_nodes`: the tree's nodes and the sawtooth points;
- :mod:`stack.planning.sarsop_vectors`: the lower bound's vectors, their archive and
  the written policy (:class:`~stack.planning.sarsop_vectors.VectorStore`);
- :mod:`stack.planning.sarsop_expand`: nodes made, expanded and valued
  (:class:`~stack.planning.sarsop_expand.BeliefExpansion`);
- this module: the set-up of both bounds, the backup and the trials.
"""

from __future__ import annotations

import gc
import math
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from stack.planning import clock
from stack.planning.bounds import blind_lower_bound, fast_informed_bound, qmdp, require_discounted
from stack.planning.pomdp import POMDP
from stack.planning.sarsop_expand import BeliefExpansion
from stack.planning.sarsop_nodes import BeliefNode, NodeChildren, UpperPoints, canonical
from stack.planning.search_base import SearchConfig, SearchResult, SearchStats, child_targets
from stack.planning.threads import blas_threads


class BeliefTreeSearch(BeliefExpansion):
    """The solver for one model. See the module docstring.

    Args:
        pomdp: a discounted model.
        config: search settings.
        seed_alphas: extra lower-bound vectors (alphas (K, S), actions (K,)), each the
            exact value of some policy (e.g. :func:`bounds.plan_alphas`), optionally
            with a third array, (K, Z) successors (indices into the seeds) of a closed
            set (:func:`stack.planning.controller.close_vectors`). Seeds without one
            are values of plans whose later steps the set need not hold, so the best
            vector's policy may fall short of them.
        start: clock.now() at which the time limit started (default: now), so
            that a command's own set-up counts against its limit exactly once.
        q_upper: the model's QMDP values (S, A) if already computed (an upper bound).
        progress: called with a :class:`SearchStats` at most once per
            ``config.progress_every_s``.
    """

    def __init__(
        self,
        pomdp: POMDP,
        config: SearchConfig = SearchConfig(),  # noqa: B008 (frozen: immutable)
        seed_alphas: tuple[np.ndarray, ...] | None = None,
        start: float | None = None,
        progress: Callable[[SearchStats], None] | None = None,
        b0: np.ndarray | None = None,
        extra_roots: list[np.ndarray] | None = None,
        q_upper: np.ndarray | None = None,
    ):
        require_discounted(pomdp)
        self.pomdp = pomdp
        self._begin(config, start, progress)
        self.gamma = pomdp.discount
        S, A = pomdp.n_states, pomdp.n_actions
        self.S, self.A = S, A
        self.R = np.ascontiguousarray(pomdp.R, dtype=float)
        self.T = [pomdp.T[a].tocsr() for a in range(A)]
        self.O = [canonical(pomdp.O[a].tocsr()) for a in range(A)]
        self.O_rows = [np.repeat(np.arange(S), np.diff(O.indptr)) for O in self.O]
        self.T_rows = [np.repeat(np.arange(S), np.diff(T.indptr)) for T in self.T]
        # dense observation tables where they are small (row gathers are then cheap);
        # actions that share one table share the dense copy
        self.O_dense: list[np.ndarray | None] = [None] * A
        if S * pomdp.n_observations <= 4_000_000:
            for a in range(A):
                same = next((b for b in range(a) if pomdp.O[b] is pomdp.O[a]), None)
                self.O_dense[a] = self.O_dense[same] if same is not None else self.O[a].toarray()
        # all actions' observation tables as one (A, S, Z) array where small
        self.O_stack = (
            np.stack(self.O_dense)  # type: ignore[arg-type]
            if all(o is not None for o in self.O_dense)
            and A * S * pomdp.n_observations <= 4_000_000
            else None
        )
        # one row slice gives the predictions of every action: T_all[s] = [T_0[s] ... T_A[s]]
        self.T_all = sp.hstack(self.T, format="csr")
        # ... dense where it is small: a row gather is then a numpy slice, not scipy's
        # fancy indexing (RockSample_4_4: 1 s of its search)
        self.T_all_dense = self.T_all.toarray() if S * S * A <= 4_000_000 else None
        self._cat_values = 0

        # -- the upper bound: QMDP, tightened by the fast informed bound ----------------
        Q = qmdp(pomdp) if q_upper is None else q_upper
        remaining = self.deadline - clock.now()
        fib_budget = (
            30.0 if not math.isfinite(remaining) else max(0.0, remaining) * config.fib_share
        )
        if fib_budget > 0:
            Q = fast_informed_bound(pomdp, Q, max_iterations=500, tol=1e-9, time_limit_s=fib_budget)
        self.Q_upper = Q  # (S, A)
        self.points = UpperPoints(Q.max(axis=1))

        # -- the lower bound: blind policies and seeds -----------------------------------
        alphas = blind_lower_bound(pomdp)
        actions = np.arange(A)
        Z = pomdp.n_observations
        # successors[k, z]: the vector whose plan vector k follows after observation z
        # (-1: not known, a seed's), by a global id. Pruned vectors stay in an archive:
        # the written policy adds the successors of its vectors from there, so the
        # best vector's policy earns at least the bound (controller.py's docstring).
        succ = np.repeat(np.arange(A)[:, None], Z, axis=1)  # "always do a" loops
        n_active = A
        if seed_alphas is not None and len(seed_alphas[0]):
            alphas = np.vstack([alphas, seed_alphas[0]])
            actions = np.concatenate([actions, np.asarray(seed_alphas[1], dtype=int)])
            n_seeds = len(seed_alphas[0])
            seed_succ = (
                np.where(seed_alphas[2] >= 0, seed_alphas[2] + A, -1)  # type: ignore[misc]
                if len(seed_alphas) > 2
                else np.full((n_seeds, Z), -1)
            )
            succ = np.vstack([succ, seed_succ])
            # a fourth entry: only the first n seeds are active, the rest are archived
            # successors (Perseus's earlier vectors)
            n_active += int(seed_alphas[3]) if len(seed_alphas) > 3 else n_seeds  # type: ignore[misc]
        # every vector ever made, by global id (alphas, actions, successors' ids); the
        # active set's ids (_gid) and actions (_act) by position; pruning drops vectors
        # from the active set only
        self._all_alpha = []
        self._all_act = []
        self._all_succ = []
        self._values_per_vector = S  # what writing a vector costs, in values
        self._init_store(np.asarray(alphas, dtype=float), actions, succ, n_active)
        self._n_archived = 0  # archived vectors the policy will hold (at the last pruning)
        self._write_factor = 1.0
        self._measure_writing()
        self.n_initial_alphas = self.K
        self._pruned_at = self.K

        self.nodes = {}
        self._corners: dict[int, BeliefNode] = {}  # the certain beliefs' nodes, by state
        b0 = pomdp.b0 if b0 is None else np.asarray(b0, dtype=float)
        idx = np.flatnonzero(b0 > 0)
        self.root = self._node(idx, b0[idx] / b0[idx].sum())
        self.initial_lower = self.root.lb
        # more beliefs to search from (the policy must be good there too); the bounds
        # reported are b0's, and the search stops when every root meets the target
        self.roots = [self.root]
        for b in extra_roots or []:
            b = np.asarray(b, dtype=float)
            i = np.flatnonzero(b > 0)
            node = self._node(i, b[i] / b[i].sum())
            if all(node is not r for r in self.roots):
                self.roots.append(node)

    # -- the backup ------------------------------------------------------------------
    def _backup(self, node: BeliefNode) -> None:
        """Back up both bounds at ``node``: one alpha vector and one upper point."""
        kids = self._expand(node)
        q_lower, best, starts = self._q_lower(node, kids)
        q_upper = self._q_upper(node, kids)
        self.backups += 1
        # upper bound: a point at this belief
        u = float(q_upper.max())
        if u < node.ub:
            node.ub = u
            if node.point < 0:
                node.point = self.points.add(node.idx, node.val, u)
            else:
                self.points.update(node.point, u)
        # lower bound: add the backed-up vector if it improves the value here
        a = int(q_lower.argmax())
        if q_lower[a] > node.lb + 1e-12 * max(1.0, abs(node.lb)):
            choice = best[starts[a] : starts[a + 1]]
            self._add_alpha(*self._alpha(kids[a], a, choice, node), a, node)
            node.lb = float(q_lower[a])
        node.lb = min(node.lb, node.ub)

    def _alpha(
        self, kids: NodeChildren, a: int, best: np.ndarray, node: BeliefNode
    ) -> tuple[np.ndarray, np.ndarray]:
        """alpha(s) = R(s,a) + gamma sum_s' T(s,a,s') sum_z O(s',a,z) alpha_k(z)(s'),
        and its successors k (Z,)."""
        O = self.O[a]
        # observations that b cannot produce: any vector keeps the bound valid; take the
        # best one at b so the new vector is good near b too
        kstar = np.full(O.shape[1], self._best_at(node.idx, node.val)[0])
        kstar[kids.zs] = best
        rows = self.O_rows[a]
        v = np.bincount(rows, weights=O.data * self._AT[rows, kstar[O.indices]], minlength=self.S)
        T = self.T[a]  # T @ v as a bincount: scipy's product costs ~25 us of overhead
        Tv = np.bincount(self.T_rows[a], weights=T.data * v[T.indices], minlength=self.S)
        return self.R[:, a] + self.gamma * Tv, self._gid[kstar]

    # -- the search -----------------------------------------------------------------
    def _trial(self) -> None:
        g = self.gamma
        root, eps, L, U = self._trial_root()
        path = [root]
        node = root
        t = 0
        while t < self.config.max_depth:
            if self._late():
                break
            # stop where the gap is small enough for the root's target (HSVI), or where
            # both target levels are met, or where the upper bound cannot reach L
            if node.ub - node.lb <= eps * g**-t:
                break
            if self.config.target_levels and node.ub <= U:
                break
            kids = self._expand(node)
            q_upper = self._q_upper(node, kids)
            q_lower = self._q_bound(node, upper=False)
            a = int(q_upper.argmax())
            k = kids[a]
            if not k.nodes:
                break
            ub = np.array([c.ub for c in k.nodes])
            lb = np.array([c.lb for c in k.nodes])
            # HSVI's weighted excess: the observation whose gap is furthest above the
            # level its depth needs, weighted by its probability
            j = int((k.pz * (ub - lb - eps * g ** -(t + 1))).argmax())
            # SARSOP's target levels for the chosen child
            rest_l = k.pz @ lb - k.pz[j] * lb[j]
            rest_u = k.pz @ ub - k.pz[j] * ub[j]
            L, U = child_targets(
                L, U, float(q_lower.max()), eps * g**-t, k.reward, g, k.pz[j], rest_l, rest_u
            )
            node = k.nodes[j]
            path.append(node)
            t += 1
        # refine the corners under the deepest belief first: beliefs that approach
        # certainty (Tiger after many listens) are bounded by the corner values
        # (a corner whose gap already meets the leaf's level, HSVI's rule, is skipped:
        # on RockSample_4_4 the corners were most of the backups)
        leaf = path[-1]
        if leaf.idx.size <= 32:
            for s in leaf.idx.tolist():
                if self._late():
                    break
                corner = self._corners.get(s)
                if corner is None:
                    corner = self._corners[s] = self._node(np.array([s]), np.ones(1))
                if corner.ub - corner.lb > eps * g**-t:
                    self._backup(corner)
        for n in reversed(path):
            if self._late() and n is not root:
                continue
            self._backup(n)
        self.trials += 1

    def run(self) -> SearchResult:
        """Search until the target gap, the time limit or the trial limit.

        Python's cyclic garbage collector is paused meanwhile: the search frees nothing
        until it ends (the belief graph's cycles go with the search object), and the
        collections' scans of the growing tree were 8 % of RockSample_4_4's search."""
        collecting = gc.isenabled()
        gc.disable()
        try:
            with blas_threads(self.config.blas_threads):
                return self._run()
        finally:
            if collecting:
                gc.enable()

    def _run(self) -> SearchResult:
        for r in self.roots:
            self._backup(r)
        stopped = self._done()
        stopped = self._trials(stopped)
        # the active set pruned to the vectors best at some backed-up belief, in the
        # time kept for it (fewer active vectors: fewer archived successors written)
        self._prune(until=self.deadline - self._values_to_write() * self.config.write_s_per_value)
        self._report(force=True)
        return self._result(self._policy(), stopped)
