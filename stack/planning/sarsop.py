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
the vector-store methods below (``_init_store``, ``_best_at``, ``_best_cols``, ...).

The search stops when the root's gap is below the target, or at the deadline, which
is checked between backups (a backup costs milliseconds), so the time limit holds.
Same model, same settings, same result: there is no randomness in the search.

The module is over 500 lines because the tree, both bounds and the trial rule share
one set of cached per-node arrays; split apart they would pass them back and forth.
"""

from __future__ import annotations

import gc
import hashlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from stack.planning import clock
from stack.planning.bounds import blind_lower_bound, fast_informed_bound, qmdp, require_discounted
from stack.planning.controller import prune_closed
from stack.planning.policy import AlphaPolicy, BoundedResult, seconds_per_value
from stack.planning.pomdp import POMDP
from stack.planning.threads import blas_threads

_PROB_EPS = 1e-12  # successor beliefs less likely than this are not expanded
_CAT_MAX = 4096  # values of one node's concatenated successors (BeliefTreeSearch._concatenate)
_CAT_BUDGET = 20_000_000  # ... of all nodes' (160 MB)


def _canonical(m: sp.csr_matrix) -> sp.csr_matrix:
    """``m`` with sorted, summed indices (a copy only where it has not)."""
    if m.has_canonical_format:
        return m
    m = m.copy()
    m.sum_duplicates()
    return m


def _gather_rows(csr: sp.csr_matrix, rows: np.ndarray) -> tuple:
    """The non-zeros of ``csr``'s rows ``rows`` (canonical CSR: no duplicates), as
    (position in ``rows``, column, value) arrays, row by row."""
    starts = csr.indptr[rows]
    counts = csr.indptr[rows + 1] - starts
    r = np.repeat(np.arange(rows.size), counts)
    pos = np.arange(r.size) + np.repeat(starts - (np.cumsum(counts) - counts), counts)
    return r, csr.indices[pos], csr.data[pos]


def _belief_key(idx: bytes, val: bytes) -> bytes:
    """The tree's key of a belief (its states, its probabilities rounded): a 128-bit
    digest, not the bytes themselves, which were a third copy of every node's arrays
    (RockSample_11_11: 16 KB a node over ~1,000 states)."""
    return hashlib.blake2b(idx + val, digest_size=16).digest()


class SolveError(RuntimeError):
    """A solve whose result cannot be used (a degenerate value at b0)."""


@dataclass(frozen=True)
class SearchConfig:
    """Settings of the belief-tree search.

    Attributes:
        time_limit_s: stop when this much time has passed since ``start`` on the
            solvers' clock (``clock.now``: wall time, or CPU time); None: no limit.
        target_gap: stop when V_U(b0) - V_L(b0) is at most this (absolute).
        relative_gap: ... or at most this fraction of max(|V_L(b0)|, |V_U(b0)|).
        trial_improvement: each trial aims to shrink the root's gap to this fraction.
        max_trials: stop after this many trials (None: no limit); the deterministic
            alternative to a time limit.
        max_depth: deepest node of a trial.
        prune_growth: prune the lower bound when the vector set has grown by this
            factor since the last pruning.
        fib_share: at most this share of the time limit for the fast informed bound.
        progress_every_s: at most one progress report per this many seconds.
    """

    time_limit_s: float | None = 60.0
    target_gap: float = 1e-3
    relative_gap: float = 0.0
    trial_improvement: float = 0.5
    max_trials: int | None = None
    max_depth: int = 2000
    prune_growth: float = 2.0
    fib_share: float = 0.1
    progress_every_s: float = 1.0
    target_levels: bool = True
    # [s] per vector entry kept from the time limit for writing the policy afterwards
    write_s_per_value: float = 0.0
    blas_threads: int = 1  # see stack/planning/threads.py: one thread is faster here
    # share of the time limit kept for dropping pointwise dominated vectors before the
    # policy is written (controller.prune_closed; Hallway: 6,953 vectors to 3,639)
    finish_share: float = 0.01
    # write the vectors the policy uses at the tree nodes it reaches from the roots, and
    # their successors, rather than every active vector (see BeliefTreeSearch._closure)
    reached_only: bool = True


@dataclass
class SearchStats:
    """One progress report (also kept as the solve's history)."""

    trials: int
    lower: float
    upper: float
    n_alphas: int
    n_points: int
    n_nodes: int
    backups: int
    elapsed_s: float

    @property
    def gap(self) -> float:
        return self.upper - self.lower

    # the names pbvi.IterationStats uses, so the two print the same way
    @property
    def value_b0(self) -> float:
        return self.lower

    @property
    def upper_b0(self) -> float:
        return self.upper


def format_search_progress(s: SearchStats) -> str:
    rel = s.gap / max(abs(s.lower), abs(s.upper), 1e-12)
    return (
        f"{s.elapsed_s:7.2f} s  LB {s.lower:11.5f}  UB {s.upper:11.5f}  gap {s.gap:10.5f} "
        f"({100 * rel:6.2f} %)  vectors {s.n_alphas:5d}  points {s.n_points:6d}  "
        f"trials {s.trials:6d}"
    )


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


@dataclass
class SearchResult(BoundedResult):
    policy: AlphaPolicy
    lower_bound: float
    upper_bound: float
    seconds: float
    history: list[SearchStats] = field(default_factory=list)
    trials: int = 0
    backups: int = 0
    stopped: str = ""  # "gap", "time", "trials"

    @property
    def n_iterations(self) -> int:
        return self.trials

    def summary(self) -> dict:
        return {
            **super().summary(),
            "trials": self.trials,
            "backups": self.backups,
            "stopped": self.stopped,
        }


class _UpperPoints:
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


class StoppingRules:
    """When a belief-tree search stops (shared by the flat and the mixed search): the
    roots' gaps met (absolute or relative), the deadline less the time writing the
    vectors will take, or the trial budget. A search has ``config`` (SearchConfig),
    ``roots`` (nodes with ``lb``/``ub``), ``deadline``, ``trials`` and says how many
    values its policy holds (:meth:`_values_to_write`)."""

    config: SearchConfig
    roots: list
    deadline: float
    trials: int
    _write_factor: float = 1.0  # measured writing speed / config.write_s_per_value
    _prune_s: float = 0.0  # how long the last pruning of the active set took
    _write_share: float = 1.0  # share of the values counted that the policy writes

    def _write_s_per_value(self) -> float:
        return self.config.write_s_per_value * self._write_factor

    def _values_to_write(self) -> int:
        raise NotImplementedError

    def _late(self) -> bool:
        """Past the deadline, less the time writing the vectors will take and the
        share of the limit kept for pruning them (``config.finish_share``)."""
        if self.deadline == math.inf:
            return False
        return clock.now() >= self.deadline - self._reserve()

    def _reserve(self) -> float:
        limit = self.config.time_limit_s or 0.0
        return (
            self._values_to_write() * self.config.write_s_per_value
            + self.config.finish_share * limit
            + 1.5 * self._prune_s  # the final pruning of the active set (it grows)
        )

    def _met(self, r) -> bool:
        gap = r.ub - r.lb
        return gap <= self.config.target_gap or gap <= self.config.relative_gap * max(
            abs(r.lb), abs(r.ub)
        )

    def _done(self) -> str:
        if all(self._met(r) for r in self.roots):
            return "gap"
        if self._late():
            return "time"
        if self.config.max_trials is not None and self.trials >= self.config.max_trials:
            return "trials"
        return ""


def _written_share(search: BeliefTreeSearch) -> float:
    """The share of the active set's closure that the written policy holds: with
    ``reached_only`` only the vectors the policy uses at the tree's nodes it reaches,
    and their successors (RockSample_7_8: 1,146 of 2,624 vectors, so 60 s solves kept
    18 s for writing and wrote in 5 s). Measured at each pruning; 1.0 before the tree
    has nodes, or when every active vector is written."""
    if not search.config.reached_only or not getattr(search, "nodes", None):
        return 1.0
    full = search.K + search._n_archived
    return min(1.0, len(search._closure(reached=True)) / max(1, full))


def _forget_unreachable(search: BeliefTreeSearch, closure: list[int]) -> None:
    """Release the archived vectors outside ``closure`` (the active set's closure).

    A new vector's successors are active vectors, so an archived vector that no vector
    of the closure leads to is never read again: its memory goes (one S-vector each;
    RockSample_11_11: 2 MB a vector). Its id stays, holding None."""
    keep = np.zeros(len(search._all_alpha), dtype=bool)
    keep[closure] = True
    for g in np.flatnonzero(~keep).tolist():
        search._all_alpha[g] = None


class BeliefTreeSearch(StoppingRules):
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
        config: SearchConfig = SearchConfig(),
        seed_alphas: tuple[np.ndarray, ...] | None = None,
        start: float | None = None,
        progress: Callable[[SearchStats], None] | None = None,
        b0: np.ndarray | None = None,
        extra_roots: list[np.ndarray] | None = None,
        q_upper: np.ndarray | None = None,
    ):
        require_discounted(pomdp)
        self.pomdp = pomdp
        self.config = config
        self.start = clock.now() if start is None else start
        self.deadline = (
            math.inf if config.time_limit_s is None else self.start + config.time_limit_s
        )
        self.progress = progress
        self.gamma = pomdp.discount
        S, A = pomdp.n_states, pomdp.n_actions
        self.S, self.A = S, A
        self.R = np.ascontiguousarray(pomdp.R, dtype=float)
        self.T = [pomdp.T[a].tocsr() for a in range(A)]
        self.O = [_canonical(pomdp.O[a].tocsr()) for a in range(A)]
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
        self.backups = 0
        self.trials = 0
        self._cat_values = 0
        self.history: list[SearchStats] = []
        self._last_report = -math.inf

        # -- the upper bound: QMDP, tightened by the fast informed bound ----------------
        Q = qmdp(pomdp) if q_upper is None else q_upper
        remaining = self.deadline - clock.now()
        fib_budget = (
            30.0 if not math.isfinite(remaining) else max(0.0, remaining) * config.fib_share
        )
        if fib_budget > 0:
            Q = fast_informed_bound(pomdp, Q, max_iterations=500, tol=1e-9, time_limit_s=fib_budget)
        self.Q_upper = Q  # (S, A)
        self.points = _UpperPoints(Q.max(axis=1))

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
        self._all_alpha: list[np.ndarray | None] = []
        self._all_act: list[int] = []
        self._all_succ: list[np.ndarray] = []
        self._values_per_vector = S  # what writing a vector costs, in values
        self._init_store(np.asarray(alphas, dtype=float), actions, succ, n_active)
        self._n_archived = 0  # archived vectors the policy will hold (at the last pruning)
        self._write_factor = 1.0
        self._measure_writing()
        self.n_initial_alphas = self.K
        self._pruned_at = self.K

        self.nodes: dict[bytes, BeliefNode] = {}
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

    # -- the lower bound's vectors: stored, valued at beliefs, pruned -------------------
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

    # -- beliefs and bounds -----------------------------------------------------------
    def _upper_vectors(self, nz: np.ndarray, M: np.ndarray) -> np.ndarray:
        return (self.Q_upper[nz].T @ M).max(axis=0)

    def _node(self, idx: np.ndarray, val: np.ndarray, ub: float | None = None) -> BeliefNode:
        key = _belief_key(idx.tobytes(), np.round(val, 10).tobytes())
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
            r, c, v = _gather_rows(self.T_all, node.idx)
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
                r, z, p = _gather_rows(self.O[a], nz)
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
            key = _belief_key(idxs[lo:hi].tobytes(), keys[lo:hi].tobytes())
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
        budget = self.deadline - clock.now() - alphas.size * self._write_s_per_value()
        if budget > 0:
            alphas, actions, succ = prune_closed(alphas, actions, succ, self._n_first, budget)
        self.successors = succ
        return AlphaPolicy(alphas, actions, meta={"solver": "sarsop"})

    def _closed_policy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The active vectors and, from the archive, every successor they lead to:
        (alphas (K', S), actions (K',), successors (K', Z) as positions, -1 unknown).
        The best vector's policy over a closed set earns its bound (controller.py)."""
        order = self._closure()
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

    def _closure(self, reached: bool = True) -> list[int]:
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

    # -- the search -----------------------------------------------------------------
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
        closure = self._closure(reached=False)
        self._n_archived = len(closure) - self.K  # an upper bound
        _forget_unreachable(self, closure)
        if self.config.write_s_per_value <= 0:
            return
        self._write_share = _written_share(self)
        # a sample block (at most 512 states x 64 vectors): the speed per value, cheaply
        per_value = seconds_per_value(self._sample_vectors())
        self._write_factor = max(1.0, per_value / self.config.write_s_per_value)

    def _trial(self) -> None:
        g = self.gamma
        # the root furthest from its target (b0 first on ties)
        open_roots = [r for r in self.roots if not self._met(r)] or [self.root]
        root = max(open_roots, key=lambda r: r.ub - r.lb)
        eps = self.config.trial_improvement * (root.ub - root.lb)
        L, U = root.lb, root.lb + eps
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
            Lp = max(L, float(q_lower.max()))
            Up = max(U, float(q_lower.max()) + eps * g**-t)
            rest_l = k.pz @ lb - k.pz[j] * lb[j]
            rest_u = k.pz @ ub - k.pz[j] * ub[j]
            L = (Lp - k.reward - g * rest_l) / (g * k.pz[j])
            U = (Up - k.reward - g * rest_u) / (g * k.pz[j])
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

    def _report(self, force: bool = False) -> None:
        now = clock.now()
        if not force and now - self._last_report < self.config.progress_every_s:
            return
        self._last_report = now
        stats = SearchStats(
            trials=self.trials,
            lower=self.root.lb,
            upper=self.root.ub,
            n_alphas=self.K,
            n_points=len(self.points),
            n_nodes=len(self.nodes),
            backups=self.backups,
            elapsed_s=now - self.start,
        )
        self.history.append(stats)
        if self.progress:
            self.progress(stats)

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
        while not stopped:
            self._trial()
            self._report()
            stopped = self._done()
        # the active set pruned to the vectors best at some backed-up belief, in the
        # time kept for it (fewer active vectors: fewer archived successors written)
        self._prune(until=self.deadline - self._values_to_write() * self.config.write_s_per_value)
        self._report(force=True)
        policy = self._policy()
        result = SearchResult(
            policy=policy,
            lower_bound=self.root.lb,
            upper_bound=self.root.ub,
            seconds=clock.now() - self.start,
            history=self.history,
            trials=self.trials,
            backups=self.backups,
            stopped=stopped,
        )
        policy.meta.update(result.summary())
        return result
