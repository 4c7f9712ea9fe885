"""Belief-tree search on a mixed-observability model (SARSOP's MOMDP idea, issue 12).

In the case study the robot's cell x is observed exactly; only the person factor y
(position and direction, 65 values on the 12-cell grid) is hidden. A belief is then
a pair (x, b) with b a distribution over y alone, and the value function a set of
65-value alpha vectors *per robot cell* (Ong, Png, Hsu and Lee 2010). The task adds
more structure that this module uses:

- the person's dynamics P(y' | y) and observation P(z | y') depend neither on the
  robot nor on the action, so the successor person beliefs of a node are the same
  for every action and every next robot cell: one posterior per person observation;
- the robot's dynamics P(x' | x, a) do not depend on the person.

A node of the search is therefore a person belief b alone, holding both bounds for
every robot cell; a backup at b updates all cells at once:

- **lower bound**: alpha vectors over y for each x, started from the flat model's
  blind and "walk to a cell and wait" policies cut into their robot-cell blocks;
  a backup adds, for every cell whose bound improves at b, the backed-up vector
  (never a wholesale replacement), and a cell's set is pruned to the vectors that
  are best at some backed-up belief (dominance at the sampled beliefs). Before the
  trials, person beliefs sampled from the starts (the person evolves whatever the
  robot does, so these are the beliefs every policy meets) are backed up in rounds,
  deepest first: this raises the lower bound far faster than trials, which SARSOP's
  target levels stop a few steps from the root; under a time limit a plateau of the
  rounds adds a further batch of sampled beliefs (``grow``);
- **upper bound**: the fast informed bound computed on the factors (a sweep is one
  (X, Y, Y) x (Y, Z) product per action, milliseconds, against a second for the
  flat form), refined by the backups in the tree, and optionally (``sawtooth``) by
  interpolating belief-value points (:class:`_Points`). Measured on the task: the
  interpolation, and even a point-based value iteration of the upper bound over 550
  sampled beliefs to its fixed point, lowered V(b0)'s bound by less than 0.01; the
  bound's looseness is spread over the whole 100-step horizon (docs/BENCHMARKS.md).

The policy the rest of the system runs is flat: each cell's vectors become flat
vectors that hold the cell's values on its block and a lower bound of every state's
value (min R / (1 - gamma)) elsewhere, so ``AlphaPolicy`` picks, at any belief
over one robot cell, among that cell's vectors.

The module is over 500 lines because the model, its fast informed bound and the
search share the per-cell arrays; the flat search (sarsop.py) is kept separate as
its beliefs and vectors are flat.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from stack.planning import clock
from stack.planning.policy import AlphaPolicy
from stack.planning.search_base import SearchConfig, SearchResult, SearchStats, StoppingRules
from stack.planning.threads import blas_threads

_PROB_EPS = 1e-12
# at least this share of a time limit goes to the fast informed bound: it starts from
# max R / (1 - gamma) (3,000 in the task) and, cut off early, would be looser than QMDP
# (r2 at 60 s under load ~6 with 10 %: 336.8 against QMDP's 264.2 and 229.0 converged)
FIB_SHARE = 0.3


@dataclass(frozen=True, eq=False)
class MixedModel:
    """A model with an observed factor x and a hidden factor y.

    Attributes:
        TX: (A, X, X) P(x' | x, a), independent of y.
        TY: (Y, Y) P(y' | y), independent of x and a.
        OY: (Y, Z) P(z | y'), independent of x' and a; x' is observed exactly.
        R: (X, Y, A) reward.
        discount: gamma < 1.
    Flat state index: x * Y + y (the task model's order, robot slowest).
    """

    TX: np.ndarray
    TY: np.ndarray
    OY: np.ndarray
    R: np.ndarray
    discount: float

    @property
    def X(self) -> int:
        return self.TX.shape[1]

    @property
    def Y(self) -> int:
        return self.TY.shape[0]

    @property
    def A(self) -> int:
        return self.TX.shape[0]

    def split(self, b: np.ndarray) -> tuple[int, np.ndarray]:
        """(x, person belief) of a flat belief that is certain about x."""
        t = np.asarray(b, dtype=float).reshape(self.X, self.Y)
        mass = t.sum(axis=1)
        x = int(mass.argmax())
        if mass[x] < 1.0 - 1e-9:
            raise ValueError("the belief is not certain about the observed factor")
        return x, t[x] / mass[x]


def mixed_from_task(model) -> MixedModel:
    """The task's factored model (one person) as a :class:`MixedModel`."""
    if model.people != 1:
        raise ValueError("the mixed-observability search handles one person")
    X = model.n_cells + 1
    R = model.reward_table().reshape(X, -1, model.reward_table().shape[-1])
    return MixedModel(
        TX=np.asarray(model.robot_T, dtype=float),
        TY=model.person_transition(),
        OY=model.person_observation(),
        R=R,
        discount=model.task.discount,
    )


def _mdp_start(m: MixedModel, deadline: float, sweeps: int = 4000) -> np.ndarray:
    """A start for the fast informed bound: value iteration of the fully observable
    MDP down from max R / (1 - gamma) (a sweep costs ~0.1 ms against ~10 ms for the
    fast informed bound's). Every iterate Q satisfies M(Q) <= Q for the MDP operator M,
    and the fast informed bound's operator H lies below M, so H(Q) <= Q: the start is
    above the fast informed bound's fixed point, as its iteration needs."""
    g = m.discount
    Q = np.full(m.R.shape, float(m.R.max()) / (1 - g))
    TYT = m.TY
    for i in range(sweeps):
        U = Q.max(axis=2) @ TYT.T  # (X', Y): sum_y' P(y'|y) max_a' Q(x', y', a')
        new = np.minimum(m.R + g * np.einsum("axk,ky->xya", m.TX, U), Q)
        done = float((Q - new).max()) < 1e-9
        Q = new
        if done or (i % 100 == 0 and clock.now() > deadline):
            break
    return Q


def factored_fib(
    m: MixedModel,
    tol: float = 1e-3,
    max_iterations: int = 5000,
    deadline: float = math.inf,
    start: np.ndarray | None = None,
) -> np.ndarray:
    """The fast informed bound on the factors, Q (X, Y, A).

    H(Q)(x,y,a) = R(x,y,a) + gamma sum_x' P(x'|x,a) sum_z max_a' sum_y' P(y'|y) P(z|y') Q(x',y',a')

    H is monotone and a contraction, so any Q with H(Q) <= Q lies above the fixed point
    (H^n(Q) decreases to it). The iteration starts from the MDP's values (QMDP) and, as
    gamma = 0.99 makes plain iteration slow (~600 sweeps), extrapolates each step
    along the last decrease (Q - beta (Q_prev - Q)) and keeps the extrapolated table
    only where that check H(Q) <= Q holds for the whole table; otherwise beta halves.
    Every accepted table is an upper bound, so stopping at the deadline is safe.
    ``start``: a table from an earlier call (H(Q) <= Q holds for it), to go on from it
    to a smaller ``tol`` instead of starting again from the MDP's values.
    """
    g = m.discount

    def H(Q: np.ndarray) -> np.ndarray:
        # W[x', y, z, a'] = sum_y' TY[y, y'] OY[y', z] Q[x', y', a']
        W = np.einsum("yk,kz,xka->xyza", m.TY, m.OY, Q, optimize=True)
        U = W.max(axis=3).sum(axis=2)  # (X', Y)
        return m.R + g * np.einsum("axk,ky->xya", m.TX, U)

    Q = _mdp_start(m, deadline) if start is None else np.array(start, dtype=float)
    HQ = np.minimum(H(Q), Q)  # H(Q) <= Q holds
    beta = 1.0
    for _ in range(max_iterations):
        step = Q - HQ  # >= 0
        if step.max() < tol or clock.now() > deadline:
            return HQ
        Qe = HQ - beta * step
        HQe = H(Qe)
        if (HQe <= Qe + 1e-12 * np.abs(Qe)).all():
            Q, HQ = Qe, np.minimum(HQe, Qe)
            beta = min(2.0 * beta, 1e4)
        else:
            HH = np.minimum(H(HQ), HQ)
            Q, HQ = HQ, HH
            beta = max(beta / 4.0, 1.0)
    return HQ


class _Node:
    """A person belief b with the bounds of every robot cell at it: lb[x], ub[x]."""

    __slots__ = ("b", "ub", "lb", "kids", "point", "group")

    def __init__(self, b: np.ndarray, ub: np.ndarray, lb: np.ndarray, group: int = -1):
        self.b = b
        self.group = group  # the observation this belief followed (-1: a start)
        self.ub = ub  # (X,)
        self.lb = lb  # (X,) the best vector of each cell at b
        self.kids: _Kids | None = None
        self.point = -1  # row of the upper bound's points; -1 never backed up, -2 no point


class _Kids:
    """The successors of a node: one person posterior per observation z, shared by
    every action and next cell. The posteriors (Y, nz) are recomputed from the parent's
    belief when needed (cheap) rather than kept; the bounds of every (cell, z) pair
    are kept, with the vectors and points already folded in, so a refresh only
    evaluates what was added since."""

    __slots__ = ("pz", "zs", "nodes", "reward", "lbv", "lbk", "lb_seen", "lb_gen", "ub", "seen")

    def __init__(self, pz, zs, reward, X):
        self.pz = pz  # (nz,) P(z | b)
        self.zs = zs  # (nz,) the observations with P(z | b) > 0
        self.nodes: dict[int, _Node] = {}  # j -> successor node (made when entered)
        self.reward = reward  # (X, A) R(x, b, a)
        nz = zs.size
        self.lbv = np.full((X, nz), -np.inf)  # best vector value of cell x at posterior j
        self.lbk = np.zeros((X, nz), dtype=np.int32)  # ... and its column in the cell
        self.lb_seen = np.zeros(X, dtype=np.int64)  # columns of each cell evaluated
        self.lb_gen = np.full(X, -1, dtype=np.int64)  # the cell's pruning generation
        self.ub = np.empty((X, nz))
        self.seen = 0  # upper-bound points folded into ub


class _Vectors:
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


class _Points:
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


class _Root:
    """A start: a node and the robot's cell there (lb/ub as the stopping rules read them)."""

    def __init__(self, node: _Node, x: int):
        self.node = node
        self.x = x

    @property
    def lb(self) -> float:
        return float(self.node.lb[self.x])

    @property
    def ub(self) -> float:
        return float(self.node.ub[self.x])


class MixedSearch(StoppingRules):
    """HSVI2/SARSOP-style search over person beliefs, every robot cell at once.

    A node of the tree is a person belief b; since the person's dynamics and
    observations do not depend on the robot, the tree is the same for every robot
    cell, and a node holds both bounds for all cells (13 values each in the task). A
    backup at b then updates every cell: the bounds of all (cell, action) pairs are one
    (A, X, X) x (X,) product over the successors' expected values, and the new lower-
    bound vectors of all cells share the successors' best vectors.

    Args:
        m: the model.
        config: the flat search's settings (time limit, gaps, trials, pruning).
        seed_alphas: flat (K, X*Y) lower-bound vectors and their actions, each the
            exact value of a policy (blind policies, plans); cut into cell blocks.
        roots: flat beliefs, each certain about x; the first is b0 (bounds reported).
        start: clock.now() at which the time limit started.
        progress: called with :class:`SearchStats` at most once per progress_every_s.
        sawtooth: refine the upper bound between nodes by sawtooth interpolation.
        beliefs, rounds, depth, plateau: the rounds over sampled person beliefs (see
            ``_rounds``).
        grow: at a plateau, sample a further batch of beliefs and go on with the rounds
            instead of ending them (for time-limited solves).
    """

    def __init__(
        self,
        m: MixedModel,
        config: SearchConfig,
        seed_alphas: tuple[np.ndarray, np.ndarray],
        roots: Sequence[np.ndarray],
        start: float | None = None,
        progress: Callable[[SearchStats], None] | None = None,
        sawtooth: bool = False,
        beliefs: int = 0,
        rounds: int = 0,
        depth: int = 30,
        plateau: float = 0.01,
        grow: bool = False,
    ):
        self.m = m
        self.plateau = plateau
        self.grow = grow
        self._batches = 0
        self.sawtooth = sawtooth
        self.n_beliefs = beliefs
        self.rounds = rounds
        self.depth = depth
        self.rounds_done = 0
        self.config = config
        self.start = clock.now() if start is None else start
        self.deadline = (
            math.inf if config.time_limit_s is None else self.start + config.time_limit_s
        )
        self.progress = progress
        self.g = m.discount
        X, Y = m.X, m.Y
        self.v_min = float(m.R.min()) / (1 - self.g)
        remaining = self.deadline - clock.now()
        fib_deadline = (
            math.inf
            if not math.isfinite(remaining)
            else clock.now() + max(0.0, remaining) * max(config.fib_share, FIB_SHARE)
        )
        self.Q_upper = factored_fib(m, deadline=fib_deadline)  # (X, Y, A)
        self.upper_initial = self.Q_upper
        # (X*A, Y): the fast informed bound's vectors, a row per (cell, action)
        self._fib = np.ascontiguousarray(self.Q_upper.transpose(0, 2, 1).reshape(X * m.A, Y))
        self.points = _Points(self._fib, X)
        alphas, actions = seed_alphas
        blocks = np.asarray(alphas, dtype=float).reshape(len(actions), X, Y)
        self.cells = [_Vectors(blocks[:, x, :], np.asarray(actions)) for x in range(X)]
        self.n_initial_alphas = len(actions)
        self.TYT = np.ascontiguousarray(m.TY.T)
        self.RT = np.ascontiguousarray(m.R.transpose(0, 2, 1))  # (X, A, Y)
        self.nodes: dict[bytes, _Node] = {}
        self.backed: list[_Node] = []  # nodes backed up at least once
        self._B = np.empty((0, Y))  # their beliefs, a row each (for pruning)
        self.backups = 0
        self.trials = 0
        self.history: list[SearchStats] = []
        self._last_report = -math.inf
        self.roots: list[_Root] = []
        for b in roots:
            x, by = m.split(b)
            if not any(r.x == x and np.array_equal(r.node.b, by) for r in self.roots):
                self.roots.append(_Root(self._node(by), x))
        self.root = self.roots[0]
        self.initial_lower = self.root.lb
        # upper bounds at the roots found elsewhere (delayed.DelayedWorker sets them from
        # its thread); taken at the next stopping check
        self.root_caps: np.ndarray | None = None
        self.search_upper: float | None = None
        self.delayed_note = ""

    # -- bounds at beliefs ----------------------------------------------------------
    def _lower_all(self, b: np.ndarray) -> np.ndarray:
        """The best vector value of every cell at the person belief b, (X,)."""
        return np.array([float((b @ c.cols).max()) for c in self.cells])

    def _fib_at(self, B: np.ndarray) -> np.ndarray:
        """The fast informed bound of every cell at the beliefs B (Y, n), (X, n)."""
        X, A = self.m.X, self.m.A
        return (self._fib @ B).reshape(X, A, -1).max(axis=1)

    def _key(self, b: np.ndarray) -> bytes:
        return np.round(b, 10).tobytes()

    def _node(self, b: np.ndarray) -> _Node:
        key = self._key(b)
        node = self.nodes.get(key)
        if node is None:
            ub = self._fib_at(b[:, None])[:, 0]
            lb = np.minimum(self._lower_all(b), ub)
            node = _Node(b, ub, lb)
            self.nodes[key] = node
        return node

    def _posteriors(self, node: _Node, kids: _Kids) -> np.ndarray:
        """The successor person beliefs (Y, nz); the same operations as in ``_expand``,
        so the same numbers."""
        joint = self.m.OY * (self.TYT @ node.b)[:, None]
        return joint[:, kids.zs] / kids.pz

    def _expand(self, node: _Node) -> tuple[_Kids, np.ndarray]:
        """The node's successors with their bounds up to date, and the posteriors."""
        kids = node.kids
        if kids is None:
            joint = self.m.OY * (self.TYT @ node.b)[:, None]
            pz = joint.sum(axis=0)
            zs = np.flatnonzero(pz > _PROB_EPS)
            kids = _Kids(pz[zs], zs, np.einsum("xay,y->xa", self.RT, node.b), self.m.X)
            M = joint[:, zs] / kids.pz
            kids.ub[:] = self._fib_at(M)
            node.kids = kids
        else:
            M = self._posteriors(node, kids)
        if kids.seen < self.points.n:
            col = np.full(self.m.OY.shape[1], -1)
            col[kids.zs] = np.arange(kids.zs.size)
            self.points.correct(kids.ub, M, col, kids.seen)
            kids.seen = self.points.n
        for x, c in enumerate(self.cells):
            if kids.lb_gen[x] != c.gen:
                V = M.T @ c.cols  # (nz, K)
                k = V.argmax(axis=1)
                kids.lbv[x] = V[np.arange(k.size), k]
                kids.lbk[x] = k
                kids.lb_gen[x] = c.gen
            elif kids.lb_seen[x] < c.n:
                s = int(kids.lb_seen[x])
                V = M.T @ c.G[:, s : c.n]
                k = V.argmax(axis=1)
                v = V[np.arange(k.size), k]
                better = v > kids.lbv[x]
                kids.lbv[x, better] = v[better]
                kids.lbk[x, better] = k[better] + s
            kids.lb_seen[x] = c.n
        for j, n in kids.nodes.items():
            np.minimum(kids.ub[:, j], n.ub, out=kids.ub[:, j])
            n.ub = kids.ub[:, j].copy()
            n.lb = np.minimum(kids.lbv[:, j], n.ub)
        return kids, M

    def _child(self, kids: _Kids, j: int, M: np.ndarray) -> _Node:
        node = kids.nodes.get(j)
        if node is None:
            b = M[:, j].copy()
            key = self._key(b)
            node = self.nodes.get(key)
            if node is None:
                node = _Node(
                    b,
                    kids.ub[:, j].copy(),
                    np.minimum(kids.lbv[:, j], kids.ub[:, j]),
                    int(kids.zs[j]),
                )
                self.nodes[key] = node
            kids.nodes[j] = node
        return node

    def _q(self, kids: _Kids, v: np.ndarray) -> np.ndarray:
        """Q(a, x) = R(x, b, a) + gamma sum_x' P(x'|x,a) sum_z P(z|b) v(x', z), (A, X)."""
        return kids.reward.T + self.g * (self.m.TX @ (v @ kids.pz))

    def _backup(self, node: _Node) -> None:
        kids, M = self._expand(node)
        q_upper = self._q(kids, kids.ub)
        q_lower = self._q(kids, kids.lbv)
        self.backups += 1
        if node.point == -1:
            self.backed.append(node)
            node.point = -2  # backed up, no point yet
        u = np.minimum(node.ub, q_upper.max(axis=0))
        if (u < node.ub).any():
            node.ub = u
            if self.sawtooth:
                if node.point < 0:
                    node.point = self.points.add(node.b, u, node.group)
                else:
                    self.points.update(node.point, u)
        cur = self._lower_all(node.b)
        a = q_lower.argmax(axis=0)  # (X,)
        v = q_lower[a, np.arange(self.m.X)]
        xs = np.flatnonzero(v > cur + 1e-12 * np.maximum(1.0, np.abs(cur)))
        if xs.size:
            self._add_alphas(node, kids, a, xs)
            cur[xs] = v[xs]
        node.lb = np.minimum(cur, node.ub)

    def _add_alphas(self, node: _Node, kids: _Kids, a: np.ndarray, xs: np.ndarray) -> None:
        """The backed-up vectors at ``node`` of the cells xs, each for its action a[x]:

        alpha(y) = R(x,y,a) + gamma sum_y' P(y'|y) sum_x' P(x'|x,a) sum_z P(z|y') alpha_x'z(y')
        """
        m = self.m
        Z = m.OY.shape[1]
        S = np.empty((m.X, m.Y))
        pred = self.TYT @ node.b
        for x2, c in enumerate(self.cells):
            if kids.zs.size == Z:
                k = kids.lbk[x2]
            else:
                # observations b cannot produce: the vector best at the prediction
                k = np.full(Z, int((pred @ c.cols).argmax()))
                k[kids.zs] = kids.lbk[x2]
            S[x2] = (m.OY * c.G[:, k]).sum(axis=1)
        acts = a[xs]
        C = m.TX[acts, xs, :] @ S  # (n, Y)
        alphas = m.R[xs, :, acts] + self.g * (C @ self.TYT)
        for x, act, alpha in zip(xs, acts, alphas, strict=True):
            c = self.cells[int(x)]
            c.add(alpha, int(act))
            if c.n > max(self.config.prune_growth * c.pruned_at, c.pruned_at + 200):
                self._prune(int(x))

    def _prune(self, x: int) -> None:
        """Keep the vectors of cell x that are best at some backed-up belief."""
        if not self.backed:
            return
        c = self.cells[x]
        if self._B.shape[0] < len(self.backed):
            new = np.vstack([n.b for n in self.backed[self._B.shape[0] :]])
            self._B = np.vstack([self._B, new])
        k = (self._B @ c.cols).argmax(axis=1)
        c.keep(np.unique(k))

    def _rounds(self) -> str:
        """Back up the sampled beliefs, deepest of each trajectory first, ``rounds``
        times or until a round gains less than ``plateau`` of the roots' gaps
        (Perseus's order of work with the search's backups: each adds the improved
        vector of every robot cell). The lower bound climbs far faster this
        way than by trials, whose targets stop them a few steps from the root."""
        n_traj = max(1, -(-self.n_beliefs // self.depth))
        sampled = self.sample_nodes(n_traj, self.depth)
        order = list(reversed([r.node for r in self.roots] + sampled))
        stopped = ""
        for _ in range(self.rounds):
            before = [(r.lb, r.ub - r.lb) for r in self.roots]
            for n in order:
                if self._late():
                    break
                self._backup(n)
                self._report()
            self.rounds_done += 1
            stopped = self._done()
            if stopped:
                break
            # a plateau: no root's lower bound rose by ``plateau`` of its gap in this
            # round; the trials, which go where the gap is, take over (r2: 20 rounds
            # took 160 s, the last 14 of them gained 0.1 % of V)
            gains = [(r.lb - lb, gap) for r, (lb, gap) in zip(self.roots, before, strict=True)]
            if all(gain < self.plateau * gap for gain, gap in gains):
                if not self.grow:
                    break
                # with a time limit the rounds go on over a further batch of sampled
                # beliefs (the lower bound keeps rising with more beliefs: r1 192.85
                # with 300, 194.47 with 1,000, docs/BENCHMARKS.md)
                self._batches += 1
                more = self.sample_nodes(n_traj, self.depth, seed=self._batches)
                order = list(reversed([r.node for r in self.roots] + sampled + more))
                sampled = sampled + more
        return stopped

    def sample_nodes(self, n_traj: int, depth: int, seed: int = 0) -> list[_Node]:
        """Person beliefs reached from the starts by simulated observations. The person
        evolves whatever the robot does, so these are the beliefs any policy meets;
        the nodes are made as the search would make them (with their groups)."""
        rng = np.random.default_rng(seed)
        m = self.m
        out: list[_Node] = []
        for t in range(n_traj):
            node = self.roots[t % len(self.roots)].node
            y = int(rng.choice(m.Y, p=node.b / node.b.sum()))
            for _ in range(depth):
                if self._late():
                    return out
                kids, M = self._expand(node)
                y = int(rng.choice(m.Y, p=m.TY[y]))
                z = int(rng.choice(m.OY.shape[1], p=m.OY[y]))
                j = int(np.searchsorted(kids.zs, z))
                if j >= kids.zs.size or kids.zs[j] != z:
                    break
                node = self._child(kids, j, M)
                out.append(node)
        return out

    # -- the search -----------------------------------------------------------------
    @property
    def n_alphas(self) -> int:
        return sum(c.n for c in self.cells)

    def _values_to_write(self) -> int:
        return self.n_alphas * self.m.X * self.m.Y

    def take_root_caps(self) -> str:
        """Lower each root's upper bound to its cap, when caps have arrived; a cap
        below a root's lower bound is a broken bound: none is taken, and the returned
        text says so ("" otherwise)."""
        caps, self.root_caps = self.root_caps, None
        if caps is None:
            return ""
        for i, (r, cap) in enumerate(zip(self.roots, caps, strict=True)):
            if cap < r.lb - 1e-9 * max(1.0, abs(r.lb)):
                return (
                    f"delayed bound {float(cap):.6f} below root {i}'s lower bound "
                    f"{r.lb:.6f}: not taken"
                )
        if self.search_upper is None:
            self.search_upper = self.root.ub  # the search's own bound when the caps came
        for r, cap in zip(self.roots, caps, strict=True):
            r.node.ub[r.x] = min(r.node.ub[r.x], float(cap))
        return ""

    def _done(self) -> str:
        if self.root_caps is not None:
            self.delayed_note = self.take_root_caps() or self.delayed_note
        return super()._done()

    def _trial(self) -> None:
        g = self.g
        TX = self.m.TX
        open_roots = [r for r in self.roots if not self._met(r)] or [self.root]
        root = max(open_roots, key=lambda r: r.ub - r.lb)
        eps = self.config.trial_improvement * (root.ub - root.lb)
        L, U = root.lb, root.lb + eps
        path = [root.node]
        node, x = root.node, root.x
        t = 0
        while t < self.config.max_depth and not self._late():
            if node.ub[x] - node.lb[x] <= eps * g**-t:
                break
            if self.config.target_levels and node.ub[x] <= U:
                break
            kids, M = self._expand(node)
            lb, ub = kids.lbv, kids.ub
            q_upper = kids.reward[x] + g * (TX[:, x, :] @ (ub @ kids.pz))
            q_lower = kids.reward[x] + g * (TX[:, x, :] @ (lb @ kids.pz))
            a = int(q_upper.argmax())
            # weighted excess over (next cell, observation) pairs
            w = TX[a, x, :][:, None] * kids.pz[None, :]
            excess = w * (ub - lb - eps * g ** -(t + 1))
            i, j = np.unravel_index(int(excess.argmax()), excess.shape)
            if w[i, j] <= 0:
                break
            Lp = max(L, float(q_lower.max()))
            Up = max(U, float(q_lower.max()) + eps * g**-t)
            rest_l = float((w * lb).sum()) - w[i, j] * lb[i, j]
            rest_u = float((w * ub).sum()) - w[i, j] * ub[i, j]
            L = (Lp - kids.reward[x, a] - g * rest_l) / (g * w[i, j])
            U = (Up - kids.reward[x, a] - g * rest_u) / (g * w[i, j])
            node, x = self._child(kids, int(j), M), int(i)
            path.append(node)
            t += 1
        late = False
        for n in reversed(path):
            # past the deadline only the root is backed up (the clock is read until then)
            late = late or self._late()
            if late and n is not root.node:
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
            n_alphas=self.n_alphas,
            n_points=self.points.n,
            n_nodes=len(self.nodes),
            backups=self.backups,
            elapsed_s=now - self.start,
        )
        self.history.append(stats)
        if self.progress:
            self.progress(stats)

    def run(self) -> SearchResult:
        with blas_threads(self.config.blas_threads):
            return self._run()

    def _run(self) -> SearchResult:
        for r in self.roots:
            self._backup(r.node)
        stopped = self._done()
        if self.rounds > 0 and self.n_beliefs > 0 and not stopped:
            stopped = self._rounds()
        while not stopped:
            self._trial()
            self._report()
            stopped = self._done()
        if not self._late():
            for x in range(self.m.X):
                self._prune(x)
        self._report(force=True)
        alphas, actions = self.flat_vectors()
        policy = AlphaPolicy(alphas, actions, meta={"solver": "sarsop-momdp"})
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

    def flat_vectors(self) -> tuple[np.ndarray, np.ndarray]:
        """Each cell's vectors as flat vectors: the cell's values on its block, the
        lowest value any state can have elsewhere (so each stays a lower bound)."""
        X, Y = self.m.X, self.m.Y
        out, acts = [], []
        for x, c in enumerate(self.cells):
            F = np.full((c.n, X, Y), self.v_min)
            F[:, x, :] = c.cols.T
            out.append(F.reshape(c.n, X * Y))
            acts.append(c.act[: c.n])
        return np.vstack(out), np.concatenate(acts)
