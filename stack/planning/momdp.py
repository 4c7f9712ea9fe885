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

Both bounds are kept per robot cell:

- **lower bound**: alpha vectors over y for each x, started from the flat model's
  blind and "walk to a cell and wait" policies cut into their robot-cell blocks;
  every backup adds a vector at its node's cell (never a wholesale replacement),
  and a cell's set is pruned to the vectors that are best at some backed-up belief
  of that cell (dominance at the sampled beliefs);
- **upper bound**: the fast informed bound computed on the factors (a sweep is one
  (X, Y, Y) x (Y, Z) product per action, milliseconds, against a second for the
  flat form), refined by sawtooth interpolation of belief-value points per cell.
  A node's bound is cached and only re-interpolated against the points added since
  it was last computed (a cached upper bound stays valid: the bound only decreases).

The trial rule is the flat search's (:mod:`stack.planning.sarsop`): the action with
the best upper bound, the observation (here the pair next cell, person observation)
with the largest weighted excess gap, SARSOP's target levels, backups deepest first.
The search is deterministic.

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
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from stack.planning.policy import AlphaPolicy
from stack.planning.sarsop import SearchConfig, SearchResult, SearchStats, StoppingRules
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


def factored_fib(
    m: MixedModel, tol: float = 1e-3, max_iterations: int = 5000, deadline: float = math.inf
) -> np.ndarray:
    """The fast informed bound on the factors, Q (X, Y, A).

    H(Q)(x,y,a) = R(x,y,a) + gamma sum_x' P(x'|x,a) sum_z max_a' sum_y' P(y'|y) P(z|y') Q(x',y',a')

    H is monotone and a contraction, so any Q with H(Q) <= Q lies above the fixed point
    (H^n(Q) decreases to it). The iteration starts from max R / (1 - gamma) and, as
    gamma = 0.99 makes plain iteration slow (~600 sweeps), extrapolates each step
    along the last decrease (Q - beta (Q_prev - Q)) and keeps the extrapolated table
    only where that check H(Q) <= Q holds for the whole table; otherwise beta halves.
    Every accepted table is an upper bound, so stopping at the deadline is safe.
    """
    g = m.discount

    def H(Q: np.ndarray) -> np.ndarray:
        # W[x', y, z, a'] = sum_y' TY[y, y'] OY[y', z] Q[x', y', a']
        W = np.einsum("yk,kz,xka->xyza", m.TY, m.OY, Q, optimize=True)
        U = W.max(axis=3).sum(axis=2)  # (X', Y)
        return m.R + g * np.einsum("axk,ky->xya", m.TX, U)

    Q = np.full(m.R.shape, float(m.R.max()) / (1 - g))  # H(Q) <= Q holds
    HQ = np.minimum(H(Q), Q)
    beta = 1.0
    for _ in range(max_iterations):
        step = Q - HQ  # >= 0
        if step.max() < tol or time.perf_counter() > deadline:
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
    __slots__ = ("x", "b", "ub", "lb", "seen", "kids", "point", "key")

    def __init__(self, x: int, b: np.ndarray, ub: float, lb: float, seen: int):
        self.x = x
        self.b = b
        self.ub = ub
        self.lb = lb
        self.seen = seen  # points of cell x already interpolated into ub
        self.kids: _Kids | None = None
        self.point = -1


class _Kids:
    """The successors of a node: one person posterior per observation z, and per
    action the next cells with their probabilities. Successor nodes are made only
    when a trial descends into them; until then their bounds live in ``lb``/``ub``."""

    __slots__ = ("pz", "zs", "b", "xs", "nodes", "reward", "px", "lb", "ub", "seen")

    def __init__(self, pz, zs, b, xs, reward, px, lb, ub, seen):
        self.pz = pz  # (nz,) P(z | b)
        self.zs = zs  # (nz,) the observations
        # the parent's belief: the posteriors (Y, nz) are recomputed from it when needed
        # (MixedSearch._posteriors) rather than kept, 88 kB a node in the task
        self.b = b
        self.xs = xs  # next cells reachable under some action
        self.nodes: dict[tuple[int, int], _Node] = {}  # (i, j) -> node (xs[i], M[:, j])
        self.reward = reward  # (A,) R(x, b, a)
        self.px = px  # (A, len(xs)) P(x' | x, a)
        self.lb = lb  # (len(xs), nz)
        self.ub = ub  # (len(xs), nz)
        self.seen = seen  # (len(xs),) points of each next cell interpolated into ub


class _Cell:
    """One robot cell's lower-bound vectors and upper-bound points."""

    def __init__(self, Y: int, alphas: np.ndarray, actions: np.ndarray, corner: np.ndarray):
        self.G = np.ascontiguousarray(alphas.T)  # (Y, K)
        self.act = np.asarray(actions, dtype=int)
        self.pruned_at = self.G.shape[1]
        self.corner = corner  # (Y,) upper bound at the certain beliefs
        self.P = np.empty((0, Y))  # points
        self.Pinv = np.empty((0, Y))  # 1 / P where P > 0, 1e300 elsewhere
        self.excess = np.empty(0)  # v_i - corner . b_i (<= 0)
        self.n_points = 0

    def add_alpha(self, alpha: np.ndarray, action: int) -> None:
        self.G = np.hstack([self.G, alpha[:, None]])
        self.act = np.append(self.act, action)

    def add_point(self, b: np.ndarray, v: float) -> int:
        ex = v - float(self.corner @ b)
        if ex >= -1e-12:
            return -1
        if self.n_points == self.P.shape[0]:
            cap = max(16, 2 * self.n_points)
            P = np.empty((cap, b.size))
            P[: self.n_points] = self.P[: self.n_points]
            Pinv = np.empty((cap, b.size))
            Pinv[: self.n_points] = self.Pinv[: self.n_points]
            excess = np.empty(cap)
            excess[: self.n_points] = self.excess[: self.n_points]
            self.P, self.Pinv, self.excess = P, Pinv, excess
        i = self.n_points
        self.P[i] = b
        # 1e300, not inf, where the point has no mass: 0 * inf would be nan
        self.Pinv[i] = np.where(b > 0, 1.0 / np.where(b > 0, b, 1.0), 1e300)
        self.excess[i] = ex
        self.n_points += 1
        return i

    def update_point(self, i: int, b: np.ndarray, v: float) -> None:
        self.excess[i] = min(self.excess[i], v - float(self.corner @ b))

    def sawtooth(self, B: np.ndarray, start: int = 0) -> np.ndarray:
        """min over points start.. of the sawtooth at the beliefs B (Y, n): the
        correction below the corner plane (<= 0), shape (n,)."""
        n = B.shape[1]
        if self.n_points <= start:
            return np.zeros(n)
        out = np.zeros(n)
        Pinv = self.Pinv[start : self.n_points]
        ex = self.excess[start : self.n_points]
        # ratio[i, j] = min_y B[y, j] / P[i, y]; chunks bound the (pts, Y, n) temporary
        step = max(1, 2_000_000 // max(1, B.size))
        for lo in range(0, Pinv.shape[0], step):
            R = (Pinv[lo : lo + step, :, None] * B[None, :, :]).min(axis=1)
            out = np.minimum(out, (R * ex[lo : lo + step, None]).min(axis=0))
        return out


class MixedSearch(StoppingRules):
    """HSVI2/SARSOP-style search over (observed cell, person belief) pairs.

    Args:
        m: the model.
        config: the flat search's settings (time limit, gaps, trials, pruning).
        seed_alphas: flat (K, X*Y) lower-bound vectors and their actions, each the
            exact value of a policy (blind policies, plans); cut into cell blocks.
        roots: flat beliefs, each certain about x; the first is b0 (bounds reported).
        start: time.perf_counter() at which the time limit started.
        progress: called with :class:`SearchStats` at most once per progress_every_s.
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
    ):
        self.m = m
        self.sawtooth = sawtooth
        self.config = config
        self.start = time.perf_counter() if start is None else start
        self.deadline = (
            math.inf if config.time_limit_s is None else self.start + config.time_limit_s
        )
        self.progress = progress
        self.g = m.discount
        X, Y = m.X, m.Y
        self.v_min = float(m.R.min()) / (1 - self.g)
        remaining = self.deadline - time.perf_counter()
        fib_deadline = (
            math.inf
            if not math.isfinite(remaining)
            else time.perf_counter() + max(0.0, remaining) * max(config.fib_share, FIB_SHARE)
        )
        self.Q_upper = factored_fib(m, deadline=fib_deadline)  # (X, Y, A)
        self.upper_initial = self.Q_upper
        alphas, actions = seed_alphas
        blocks = np.asarray(alphas, dtype=float).reshape(len(actions), X, Y)
        self.cells = [
            _Cell(Y, blocks[:, x, :], actions, self.Q_upper[x].max(axis=1)) for x in range(X)
        ]
        self.n_initial_alphas = len(actions)
        self.TYT = np.ascontiguousarray(m.TY.T)
        # the next cells of each cell, and their probabilities per action
        self.next_cells = []
        for x in range(X):
            xs = np.flatnonzero(m.TX[:, x, :].max(axis=0) > 0)
            self.next_cells.append((xs, np.ascontiguousarray(m.TX[:, x, xs])))
        self.nodes: dict[bytes, _Node] = {}
        self._post_for: _Kids | None = None
        self._post = np.empty((0, 0))
        self.backups = 0
        self.trials = 0
        self.history: list[SearchStats] = []
        self._last_report = -math.inf
        self.roots: list[_Node] = []
        for b in roots:
            x, by = m.split(b)
            node = self._node(x, by)
            if all(node is not r for r in self.roots):
                self.roots.append(node)
        self.root = self.roots[0]
        self.initial_lower = self.root.lb

    # -- bounds at beliefs ----------------------------------------------------------
    def _lower(self, x: int, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Best vector value and index at the beliefs B (Y, n) of cell x."""
        V = B.T @ self.cells[x].G
        k = V.argmax(axis=1)
        return V[np.arange(k.size), k], k

    def _upper_fresh(self, x: int, B: np.ndarray, start: int = 0) -> np.ndarray:
        c = self.cells[x]
        fib = (self.Q_upper[x].T @ B).max(axis=0) if start == 0 else np.inf
        return np.minimum(fib, c.corner @ B + c.sawtooth(B, start))

    def _node(self, x: int, b: np.ndarray) -> _Node:
        key = bytes([x]) + np.round(b, 10).tobytes() if self.m.X < 256 else None
        assert key is not None
        node = self.nodes.get(key)
        if node is None:
            B = b[:, None]
            ub = float(self._upper_fresh(x, B)[0])
            lb = float(self._lower(x, B)[0][0])
            node = _Node(x, b, ub, min(lb, ub), self.cells[x].n_points)
            self.nodes[key] = node
        return node

    def _expand(self, node: _Node) -> _Kids:
        if node.kids is not None:
            return node.kids
        m = self.m
        pred = self.TYT @ node.b
        joint = m.OY * pred[:, None]
        pz = joint.sum(axis=0)
        zs = np.flatnonzero(pz > _PROB_EPS)
        M = joint[:, zs] / pz[zs]
        xs, px = self.next_cells[node.x]
        lb = np.empty((xs.size, zs.size))
        ub = np.empty((xs.size, zs.size))
        seen = np.empty(xs.size, dtype=int)
        for i, x2 in enumerate(xs):
            ub[i] = self._upper_fresh(int(x2), M)
            lb[i] = np.minimum(self._lower(int(x2), M)[0], ub[i])
            seen[i] = self.cells[int(x2)].n_points
        reward = node.b @ m.R[node.x]  # (A,)
        node.kids = _Kids(pz[zs], zs, node.b, xs, reward, px, lb, ub, seen)
        return node.kids

    def _posteriors(self, kids: _Kids) -> np.ndarray:
        """The successor person beliefs (Y, nz) of ``kids``, computed as ``_expand`` did
        (the same operations, so the same numbers); the last one is kept."""
        if self._post_for is not kids:
            joint = self.m.OY * (self.TYT @ kids.b)[:, None]
            self._post = joint[:, kids.zs] / kids.pz
            self._post_for = kids
        return self._post

    def _child(self, kids: _Kids, i: int, j: int) -> _Node:
        node = kids.nodes.get((i, j))
        if node is None:
            x2 = int(kids.xs[i])
            b = self._posteriors(kids)[:, j].copy()
            key = bytes([x2]) + np.round(b, 10).tobytes()
            node = self.nodes.get(key)
            if node is None:
                node = _Node(x2, b, float(kids.ub[i, j]), float(kids.lb[i, j]), kids.seen[i])
                self.nodes[key] = node
            kids.nodes[(i, j)] = node
        return node

    def _refresh_upper(self, kids: _Kids, i: int) -> None:
        """Re-interpolate the successors in next cell xs[i] against new points."""
        c = self.cells[int(kids.xs[i])]
        if kids.seen[i] < c.n_points:
            M = self._posteriors(kids)
            fresh = c.corner @ M + c.sawtooth(M, int(kids.seen[i]))
            np.minimum(kids.ub[i], fresh, out=kids.ub[i])
            kids.seen[i] = c.n_points

    def _child_bounds(self, kids: _Kids) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) of every successor, (len(xs), nz), freshly interpolated;
        the successors that are nodes contribute their own (backed-up) bounds."""
        for i in range(len(kids.xs)):
            self._refresh_upper(kids, i)
        for (i, j), n in kids.nodes.items():
            kids.ub[i, j] = n.ub = min(n.ub, kids.ub[i, j])
            kids.lb[i, j] = n.lb = min(max(n.lb, kids.lb[i, j]), n.ub)
        return kids.lb, kids.ub

    def _backup(self, node: _Node) -> None:
        kids = self._expand(node)
        g = self.g
        nx = len(kids.xs)
        lbs = np.empty((nx, kids.zs.size))
        best = []
        for i, x2 in enumerate(kids.xs):
            v, k = self._lower(int(x2), self._posteriors(kids))
            best.append(k)
            lbs[i] = v
            # the vector values are what the new vector achieves: q_lower uses them, so
            # the bound reported is the policy's own value
            np.maximum(kids.lb[i], v, out=kids.lb[i])
        _, ubs = self._child_bounds(kids)
        q_lower = kids.reward + g * (kids.px @ (lbs @ kids.pz))
        q_upper = kids.reward + g * (kids.px @ (ubs @ kids.pz))
        self.backups += 1
        cell = self.cells[node.x]
        u = float(q_upper.max())
        if u < node.ub:
            node.ub = u
            if node.point < 0:
                if self.sawtooth:
                    node.point = cell.add_point(node.b, u)
            else:
                cell.update_point(node.point, node.b, u)
        a = int(q_lower.argmax())
        if q_lower[a] > node.lb + 1e-12 * max(1.0, abs(node.lb)):
            self._add_alpha(node, kids, a, best)
            node.lb = float(q_lower[a])
        node.lb = min(node.lb, node.ub)

    def _add_alpha(self, node: _Node, kids: _Kids, a: int, best: list[np.ndarray]) -> None:
        """The backed-up vector at ``node`` for action a:

        alpha(y) = R(x,y,a) + gamma sum_y' P(y'|y) sum_x' P(x'|x,a) sum_z P(z|y') alpha_x'z(y')
        """
        m = self.m
        Z = m.OY.shape[1]
        acc = np.zeros(m.Y)
        pred = self.TYT @ node.b
        for i, x2 in enumerate(kids.xs):
            p = kids.px[a, i]
            if p <= 0:
                continue
            c = self.cells[int(x2)]
            # observations b cannot produce: the vector best at the prediction
            k = np.full(Z, int((pred @ c.G).argmax()))
            k[kids.zs] = best[i]
            acc += p * (m.OY * c.G[:, k]).sum(axis=1)
        alpha = m.R[node.x, :, a] + self.g * (m.TY @ acc)
        cell = self.cells[node.x]
        cell.add_alpha(alpha, a)
        if cell.G.shape[1] > self.config.prune_growth * cell.pruned_at + 50:
            self._prune(node.x)

    def _prune(self, x: int) -> None:
        """Keep the vectors of cell x that are best at some backed-up belief there."""
        c = self.cells[x]
        nodes = [n for n in self.nodes.values() if n.x == x and n.kids is not None]
        if not nodes:
            return
        B = np.column_stack([n.b for n in nodes])
        V = B.T @ c.G
        k = V.argmax(axis=1)
        for n, v in zip(nodes, V[np.arange(k.size), k], strict=True):
            n.lb = min(max(n.lb, float(v)), n.ub)
        keep = np.unique(k)
        c.G = np.ascontiguousarray(c.G[:, keep])
        c.act = c.act[keep]
        c.pruned_at = keep.size

    # -- the search -----------------------------------------------------------------
    @property
    def n_alphas(self) -> int:
        return sum(c.G.shape[1] for c in self.cells)

    def _values_to_write(self) -> int:
        return self.n_alphas * self.m.X * self.m.Y

    def _trial(self) -> None:
        g = self.g
        open_roots = [r for r in self.roots if not self._met(r)] or [self.root]
        root = max(open_roots, key=lambda r: r.ub - r.lb)
        eps = self.config.trial_improvement * (root.ub - root.lb)
        L, U = root.lb, root.lb + eps
        path = [root]
        node = root
        t = 0
        while t < self.config.max_depth and not self._late():
            if node.ub - node.lb <= eps * g**-t:
                break
            if self.config.target_levels and node.ub <= U:
                break
            kids = self._expand(node)
            lb, ub = self._child_bounds(kids)
            q_upper = kids.reward + g * (kids.px @ (ub @ kids.pz))
            q_lower = kids.reward + g * (kids.px @ (lb @ kids.pz))
            a = int(q_upper.argmax())
            # weighted excess over (next cell, observation) pairs
            w = kids.px[a][:, None] * kids.pz[None, :]
            excess = w * (ub - lb - eps * g ** -(t + 1))
            i, j = np.unravel_index(int(excess.argmax()), excess.shape)
            if w[i, j] <= 0:
                break
            Lp = max(L, float(q_lower.max()))
            Up = max(U, float(q_lower.max()) + eps * g**-t)
            rest_l = float((w * lb).sum()) - w[i, j] * lb[i, j]
            rest_u = float((w * ub).sum()) - w[i, j] * ub[i, j]
            L = (Lp - kids.reward[a] - g * rest_l) / (g * w[i, j])
            U = (Up - kids.reward[a] - g * rest_u) / (g * w[i, j])
            node = self._child(kids, int(i), int(j))
            path.append(node)
            t += 1
        late = False
        for n in reversed(path):
            # past the deadline only the root is backed up (the clock is read until then)
            late = late or self._late()
            if late and n is not root:
                continue
            self._backup(n)
        self.trials += 1

    def _report(self, force: bool = False) -> None:
        now = time.perf_counter()
        if not force and now - self._last_report < self.config.progress_every_s:
            return
        self._last_report = now
        stats = SearchStats(
            trials=self.trials,
            lower=self.root.lb,
            upper=self.root.ub,
            n_alphas=self.n_alphas,
            n_points=sum(c.n_points for c in self.cells),
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
            self._backup(r)
        stopped = self._done()
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
            seconds=time.perf_counter() - self.start,
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
            F = np.full((c.G.shape[1], X, Y), self.v_min)
            F[:, x, :] = c.G.T
            out.append(F.reshape(c.G.shape[1], X * Y))
            acts.append(c.act)
        return np.vstack(out), np.concatenate(acts)
