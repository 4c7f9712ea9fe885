"""An online planner for n people (issue 16): lookahead from the factored belief.

The flat n = 2 model (55,000 states, 371,000 joint observations) is too large to
solve offline, so the planner decides at every step by a depth-limited expectimax
from the current :class:`~stack.planning.factored.PeopleBelief`:

    V_d(r, B) = max_a  E_B[R(r, S, a)] + gamma sum_r' T(r, a, r') C_d(r', B)
    C_1(r', B) = L(r', B T)                        (the leaf value, exact expectation)
    C_d(r', B) = sum_k w_k V_{d-1}(r', B'_k)        (K sampled observations, d >= 2)

Two facts of the task make this cheap, and the planner is built around them:

- The observations do not depend on the robot's action or cell (the camera sees the
  whole region; only the robot's own cell, which is observed exactly, depends on
  the action). So a belief node's observation samples, posteriors and children are
  shared by every action and every robot cell: a node's value is a vector over the
  13 robot values, computed for all of them at once, and the tree has K^d belief
  nodes instead of (A x 2 x K)^d. This is DESPOT's idea (the same sampled scenarios
  for every action, which makes the comparison of actions a paired one) taken to
  its limit: here it costs nothing.
- The belief is a product of per-person beliefs (see :mod:`stack.planning.factored`),
  so a node is n x 65 numbers, the expected reward is exact (P(anyone guard-worthy)
  = 1 - prod_i (1 - p_i)) and observations are sampled per person, stratified.

Leaf values ``L`` decompose per person (or per pair of people):

- ``"mdp"`` (default): the value of the fully observed n-person MDP (QMDP's
  bound, eq. 2.18), computed by value iteration on the factored model for up to
  two people (13 x 65^2 states; a product belief's expectation is b_1^T V[r] b_2).
  For n >= 3 the leaf is the best pair: max_{i<j} E V_2(r, S_i, S_j). The reward
  "any person guard-worthy" only grows with people, so V_n >= V_2 of any pair
  state by state: the pair value is a lower bound of the n-person MDP value.
- ``"single"``: max_i of the solved one-person POMDP policy's value at person i's
  belief (its alpha vectors). Also monotone in people, so a true lower bound of the
  n-person POMDP value (any policy reading one person's observations earns at
  least as much with more people around).

The search deepens one level at a time (K, K^2, ... belief nodes); with a time limit
it stops before a level that would not fit and answers from the deepest finished
one (anytime), so n = 3 degrades in depth rather than in time. Without a time
limit the work is fixed and the choice is deterministic given the seed.

Pure numpy; no ROS. See POMCP (Silver and Veness 2010) and DESPOT (Somani et al.
2013) for the sampled-tree planners this one borrows from.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from stack.planning.factored import PeopleBelief, PeopleModel
from stack.planning.policy import AlphaPolicy
from stack.vocabulary import ACTIONS

LEAVES = ("mdp", "single")
STAY = ACTIONS.index("Do nothing")
CHUNK = 64  # belief nodes between two looks at the clock (with a time limit)


class _OutOfTime(Exception):
    """The time limit passed while a level was being built."""


@dataclass(frozen=True)
class OnlineConfig:
    """How the online planner searches.

    Attributes:
        depth: the deepest lookahead (1: one step and the leaf, i.e. QMDP's action).
        samples: observation samples per belief node (K).
        leaf: ``"mdp"`` or ``"single"`` (see the module docstring).
        time_limit_s: stop deepening when the next level would not finish in this
            much wall time (None: always search to ``depth``: deterministic).
        seed: the observation samples' seed.
        tie_tolerance: actions within this (absolute) value of the best are ties,
            resolved toward "Do nothing" (move only when necessary, section 3.2.3).
    """

    depth: int = 2
    samples: int = 32
    leaf: str = "mdp"
    time_limit_s: float | None = None
    seed: int = 0
    tie_tolerance: float = 1e-6

    def __post_init__(self) -> None:
        if self.depth < 1:
            raise ValueError(f"depth must be >= 1, got {self.depth}")
        if self.samples < 1:
            raise ValueError(f"samples must be >= 1, got {self.samples}")
        if self.leaf not in LEAVES:
            raise ValueError(f"unknown leaf {self.leaf!r}; known: {', '.join(LEAVES)}")
        if self.time_limit_s is not None and not self.time_limit_s > 0:
            raise ValueError(f"time_limit_s must be > 0, got {self.time_limit_s}")


@dataclass
class Decision:
    action: int
    values: np.ndarray  # (A,) the root's action values at the deepest finished depth
    depth: int  # the deepest finished depth
    nodes: int  # belief nodes expanded
    seconds: float = 0.0
    history: list[np.ndarray] = field(default_factory=list)  # root values per depth


# -- leaf values --------------------------------------------------------------------------

_MDP_CACHE: dict[tuple[str, int], np.ndarray] = {}


def people_mdp_values(
    pm: PeopleModel, people: int, tolerance: float = 1e-4, max_iterations: int = 5000
) -> np.ndarray:
    """V(r, s_1, ..., s_m): the optimal value of the fully observed m-person task MDP.

    Value iteration on the factored model: the expectation over the people's next
    states is a product of the one-person transition along each person's axis, so an
    iteration costs 13 m 65^(m+1) products instead of the flat model's (13 65^m)^2.
    Stops when successive values differ by less than ``tolerance`` (the error in V is
    then below gamma tolerance / (1 - gamma)). Cached per task and m.

    Returns:
        (n_robot,) + (n_person,) * m array.
    """
    if people not in (1, 2):
        raise ValueError(f"the MDP values are tabulated for 1 or 2 people, not {people}")
    key = (repr(pm.task.replace(people=1).to_dict()), people)
    if key in _MDP_CACHE:
        return _MDP_CACHE[key]
    g = pm.task.discount
    PT = pm.transition
    nR, nP = pm.n_robot, pm.n_person
    # guard-worthiness of the restricted cell at each robot value, per person state
    k = pm.restricted_of_robot
    gk = np.zeros((nR, nP))
    gk[k >= 0] = pm.guard[k[k >= 0]]
    if people == 1:
        anyone = gk
    else:
        anyone = 1.0 - (1.0 - gk)[:, :, None] * (1.0 - gk)[:, None, :]
    base = pm.robot_reward  # (nR, A)
    bonus = pm.guard_bonus * anyone  # (nR, nP[, nP])
    V = np.zeros((nR,) + (nP,) * people)
    T = pm.robot_T  # (A, nR, nR)
    for _ in range(max_iterations):
        W = V @ PT.T if people == 1 else PT @ V @ PT.T  # E[V(r', s') | s]
        flatW = W.reshape(nR, -1)
        # Q[a, r, s] = base[r, a] + bonus[r, s] + gamma sum_r' T[a, r, r'] W[r', s]
        Q = np.einsum("arq,qs->ars", T, flatW) * g
        Q += base.T[:, :, None]
        Vn = Q.max(axis=0).reshape(V.shape) + bonus
        delta = float(np.abs(Vn - V).max())
        V = Vn
        if delta < tolerance:
            break
    _MDP_CACHE[key] = V
    return V


class Leaf:
    """L(r, B): leaf values at a batch of product beliefs, for every robot value."""

    def __init__(self, pm: PeopleModel, kind: str, single: AlphaPolicy | None = None):
        self.pm, self.kind = pm, kind
        n = pm.people
        if kind == "mdp":
            self.V = people_mdp_values(pm, min(n, 2))
            self.pairs = list(itertools.combinations(range(n), 2)) if n >= 2 else []
        elif kind == "single":
            if single is None:
                raise ValueError("the 'single' leaf needs the one-person policy")
            if single.n_states != pm.n_robot * pm.n_person:
                raise ValueError(
                    f"the one-person policy has {single.n_states} states, "
                    f"the one-person model {pm.n_robot * pm.n_person}"
                )
            self.alphas = single.alphas.reshape(-1, pm.n_robot, pm.n_person)
        else:
            raise ValueError(f"unknown leaf {kind!r}")

    def __call__(self, B: np.ndarray) -> np.ndarray:
        """(N, n_robot) values of the (N, n, n_person) beliefs."""
        if self.kind == "single":
            v = np.einsum("krs,Nis->Nikr", self.alphas, B)  # (N, n, K, nR)
            return v.max(axis=(1, 2))
        if not self.pairs:
            return B[:, 0, :] @ self.V.T
        nR, S = self.V.shape[0], self.V.shape[1]
        flat = self.V.reshape(nR * S, S)
        out = None
        for i, j in self.pairs:
            # sum_t V[r, s, t] B_j[t] as one matrix product (BLAS), then along s
            t = (flat @ B[:, j, :].T).reshape(nR, S, -1)  # (nR, S, N)
            v = np.einsum("rsN,Ns->Nr", t, B[:, i, :])
            out = v if out is None else np.maximum(out, v)
        assert out is not None
        return out


# -- the planner ----------------------------------------------------------------------


class OnlinePlanner:
    """Depth-limited expectimax over the factored belief (see the module docstring).

    Args:
        pm: the task's per-person tables.
        config: search settings.
        single: the one-person policy (alpha vectors over 13 x 65 states), needed for
            ``leaf="single"``.
        clock: the time source of the time limit (a test may pass a fake one).
    """

    name = "online"

    def __init__(
        self,
        pm: PeopleModel,
        config: OnlineConfig = OnlineConfig(),
        single: AlphaPolicy | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ):
        self.pm, self.config, self.clock = pm, config, clock
        self.leaf = Leaf(pm, config.leaf, single)
        self.rng = np.random.default_rng(config.seed)
        self.gamma = pm.task.discount
        self.obs = pm.observation_table  # (n_person, Z1)

    def reset(self, seed: int | None = None) -> None:
        """Restart the sample stream (a new episode)."""
        self.rng = np.random.default_rng(self.config.seed if seed is None else seed)

    # -- one level of the tree ---------------------------------------------------------
    def _children(self, B: np.ndarray, K: int) -> np.ndarray:
        """(N * K, n, n_person): K posteriors per node after sampled observations.

        Each person's observation is drawn from its predictive distribution by
        stratified sampling (one uniform per stratum of width 1/K), and the strata of
        different people are paired in a random order.
        """
        N, n, S = B.shape
        pred = B @ self.pm.transition  # (N, n, S)
        pz = pred @ self.obs  # (N, n, Z)
        cdf = np.cumsum(pz, axis=-1)
        cdf /= cdf[..., -1:]
        u = (np.arange(K) + self.rng.random((N, n, K))) / K
        if n > 1:
            perm = np.argsort(self.rng.random((N, n, K)), axis=-1)
            perm[:, 0, :] = np.arange(K)
            u = np.take_along_axis(u, perm, axis=-1)
        z = np.minimum((cdf[:, :, None, :] < u[..., None]).sum(-1), cdf.shape[-1] - 1)
        lik = self.obs.T[z]  # (N, n, K, S)
        post = pred[:, :, None, :] * lik
        post /= post.sum(-1, keepdims=True)
        return post.transpose(0, 2, 1, 3).reshape(N * K, n, S)

    def _backup(self, B: np.ndarray, C: np.ndarray) -> np.ndarray:
        """(N, n_robot) V(r, B) = max_a R(r, B, a) + gamma T[a] C(., B) for N nodes."""
        R = self.pm.expected_reward(B)  # (N, nR, A)
        future = np.einsum("arq,Nq->Nra", self.pm.robot_T, C)
        return (R + self.gamma * future).max(axis=-1)

    def decide(self, belief: PeopleBelief) -> Decision:
        """The action for ``belief``, by iterative deepening up to ``config.depth``.

        With a time limit a level is skipped when its predicted cost (K times the
        last level's) would overrun, and abandoned when the clock passes the limit
        while it is built (checked every ``CHUNK`` nodes): the answer is then the
        deepest finished level's.
        """
        cfg = self.config
        t0 = self.clock()
        deadline = None if cfg.time_limit_s is None else t0 + cfg.time_limit_s
        K = cfg.samples
        r0 = belief.robot
        levels = [belief.persons[None, :, :]]  # beliefs at depth 0, 1, ...
        history: list[np.ndarray] = []
        nodes = 1
        level_cost = 0.0
        R0 = self.pm.expected_reward(belief.persons)[r0]  # (A,)
        for d in range(1, cfg.depth + 1):
            ts = self.clock()
            try:
                if d >= 2:
                    # the next level has K times the nodes of the last
                    if deadline is not None and ts + level_cost * K > deadline:
                        break
                    step = max(1, CHUNK // K)
                    level = self._chunked(
                        lambda B: self._children(B, K), levels[-1], step, deadline
                    )
                else:
                    level = levels[-1]
                # values bottom-up: the leaf at the deepest level's prediction
                C = self._chunked(
                    lambda B: self.leaf(B @ self.pm.transition), level, CHUNK, deadline
                )
            except _OutOfTime:
                break
            if d >= 2:
                levels.append(level)
                nodes += len(level)
            for lvl in range(len(levels) - 1, 0, -1):
                V = self._backup(levels[lvl], C)  # (N_lvl, nR)
                C = V.reshape(len(levels[lvl - 1]), K, -1).mean(axis=1)
            q = R0 + self.gamma * (self.pm.robot_T[:, r0, :] @ C[0])
            history.append(q)
            level_cost = self.clock() - ts
        if not history:  # not even one step fitted: the one-step value with the leaf
            C = self.leaf(levels[0] @ self.pm.transition)
            history.append(R0 + self.gamma * (self.pm.robot_T[:, r0, :] @ C[0]))
        q = history[-1]
        best = q.max()
        near = q >= best - self.config.tie_tolerance
        action = STAY if near[STAY] else int(np.flatnonzero(near)[0])
        return Decision(action, q, len(history), nodes, self.clock() - t0, history)

    def _chunked(
        self, f: Callable[[np.ndarray], np.ndarray], X: np.ndarray, step: int, deadline
    ) -> np.ndarray:
        """f(X), in pieces of ``step`` rows with a look at the clock between pieces
        (in one piece without a deadline, so that the samples drawn do not depend on
        the chunking)."""
        if deadline is None:
            return f(X)
        out = []
        for i in range(0, len(X), step):
            if self.clock() > deadline:
                raise _OutOfTime
            out.append(f(X[i : i + step]))
        return np.concatenate(out)

    def action(self, belief: PeopleBelief) -> int:
        return self.decide(belief).action
