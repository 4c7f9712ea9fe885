"""Belief-tree search on a mixed-observability model (SARSOP's MOMDP idea, issue 12).

In the case study the robot's cell x is observed exactly; only the person factor y is
hidden (the model: :mod:`stack.planning.momdp_model`). A belief is then a pair (x, b)
with b a distribution over y alone, and the value function a set of alpha vectors over
y *per robot cell* (Ong, Png, Hsu and Lee 2010). The person's dynamics and observation
depend neither on the robot nor on the action, so the successor person beliefs of a
node are the same for every action and every next robot cell: one posterior per
person observation.

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
  interpolating belief-value points (:class:`PersonPoints`). Measured on the task: the
  interpolation, and even a point-based value iteration of the upper bound over 550
  sampled beliefs to its fixed point, lowered V(b0)'s bound by less than 0.01; the
  bound's looseness is spread over the whole 100-step horizon (docs/BENCHMARKS.md).

The policy the rest of the system runs is flat: each cell's vectors become flat
vectors that hold the cell's values on its block and a lower bound of every state's
value (min R / (1 - gamma)) elsewhere, so ``AlphaPolicy`` picks, at any belief
over one robot cell, among that cell's vectors.

The tree's types (nodes, per-cell vectors, points) are in
:mod:`stack.planning.momdp_nodes`; what this search shares with the flat one
(settings, reports, result, stopping rules) in :mod:`stack.planning.search_base`. The
flat search (``sarsop.py``) is kept separate as its beliefs and vectors are flat.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from stack.planning import clock
from stack.planning.momdp_model import MixedModel, factored_fib
from stack.planning.momdp_nodes import (
    CellVectors,
    MixedChildren,
    MixedNode,
    MixedRoot,
    PersonPoints,
)
from stack.planning.policy import AlphaPolicy
from stack.planning.search_base import (
    SearchBase,
    SearchConfig,
    SearchResult,
    SearchStats,
    child_targets,
)
from stack.planning.threads import blas_threads

_PROB_EPS = 1e-12
# at least this share of a time limit goes to the fast informed bound: it starts from
# max R / (1 - gamma) (3,000 in the task) and, cut off early, would be looser than QMDP
# (r2 at 60 s under load ~6 with 10 %: 336.8 against QMDP's 264.2 and 229.0 converged)
FIB_SHARE = 0.3


class MixedSearch(SearchBase):
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
        self._begin(config, start, progress)
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
        self.points = PersonPoints(self._fib, X)
        alphas, actions = seed_alphas
        blocks = np.asarray(alphas, dtype=float).reshape(len(actions), X, Y)
        self.cells = [CellVectors(blocks[:, x, :], np.asarray(actions)) for x in range(X)]
        self.n_initial_alphas = len(actions)
        self.TYT = np.ascontiguousarray(m.TY.T)
        self.RT = np.ascontiguousarray(m.R.transpose(0, 2, 1))  # (X, A, Y)
        self.nodes: dict[bytes, MixedNode] = {}
        self.backed: list[MixedNode] = []  # nodes backed up at least once
        self._B = np.empty((0, Y))  # their beliefs, a row each (for pruning)
        self.roots: list[MixedRoot] = []
        for b in roots:
            x, by = m.split(b)
            if not any(r.x == x and np.array_equal(r.node.b, by) for r in self.roots):
                self.roots.append(MixedRoot(self._node(by), x))
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

    def _node(self, b: np.ndarray) -> MixedNode:
        key = self._key(b)
        node = self.nodes.get(key)
        if node is None:
            ub = self._fib_at(b[:, None])[:, 0]
            lb = np.minimum(self._lower_all(b), ub)
            node = MixedNode(b, ub, lb)
            self.nodes[key] = node
        return node

    def _posteriors(self, node: MixedNode, kids: MixedChildren) -> np.ndarray:
        """The successor person beliefs (Y, nz); the same operations as in ``_expand``,
        so the same numbers."""
        joint = self.m.OY * (self.TYT @ node.b)[:, None]
        return joint[:, kids.zs] / kids.pz

    def _expand(self, node: MixedNode) -> tuple[MixedChildren, np.ndarray]:
        """The node's successors with their bounds up to date, and the posteriors."""
        kids = node.kids
        if kids is None:
            joint = self.m.OY * (self.TYT @ node.b)[:, None]
            pz = joint.sum(axis=0)
            zs = np.flatnonzero(pz > _PROB_EPS)
            kids = MixedChildren(pz[zs], zs, np.einsum("xay,y->xa", self.RT, node.b), self.m.X)
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

    def _child(self, kids: MixedChildren, j: int, M: np.ndarray) -> MixedNode:
        node = kids.nodes.get(j)
        if node is None:
            b = M[:, j].copy()
            key = self._key(b)
            node = self.nodes.get(key)
            if node is None:
                node = MixedNode(
                    b,
                    kids.ub[:, j].copy(),
                    np.minimum(kids.lbv[:, j], kids.ub[:, j]),
                    int(kids.zs[j]),
                )
                self.nodes[key] = node
            kids.nodes[j] = node
        return node

    def _q(self, kids: MixedChildren, v: np.ndarray) -> np.ndarray:
        """Q(a, x) = R(x, b, a) + gamma sum_x' P(x'|x,a) sum_z P(z|b) v(x', z), (A, X)."""
        return kids.reward.T + self.g * (self.m.TX @ (v @ kids.pz))

    def _backup(self, node: MixedNode) -> None:
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

    def _add_alphas(
        self, node: MixedNode, kids: MixedChildren, a: np.ndarray, xs: np.ndarray
    ) -> None:
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

    def sample_nodes(self, n_traj: int, depth: int, seed: int = 0) -> list[MixedNode]:
        """Person beliefs reached from the starts by simulated observations. The person
        evolves whatever the robot does, so these are the beliefs any policy meets;
        the nodes are made as the search would make them (with their groups)."""
        rng = np.random.default_rng(seed)
        m = self.m
        out: list[MixedNode] = []
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

    @property
    def n_points(self) -> int:
        return self.points.n

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
        root, eps, L, U = self._trial_root()
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
            rest_l = float((w * lb).sum()) - w[i, j] * lb[i, j]
            rest_u = float((w * ub).sum()) - w[i, j] * ub[i, j]
            L, U = child_targets(
                L,
                U,
                float(q_lower.max()),
                eps * g**-t,
                kids.reward[x, a],
                g,
                w[i, j],
                rest_l,
                rest_u,
            )
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

    def run(self) -> SearchResult:
        with blas_threads(self.config.blas_threads):
            return self._run()

    def _run(self) -> SearchResult:
        for r in self.roots:
            self._backup(r.node)
        stopped = self._done()
        if self.rounds > 0 and self.n_beliefs > 0 and not stopped:
            stopped = self._rounds()
        stopped = self._trials(stopped)
        if not self._late():
            for x in range(self.m.X):
                self._prune(x)
        self._report(force=True)
        alphas, actions = self.flat_vectors()
        policy = AlphaPolicy(alphas, actions, meta={"solver": "sarsop-momdp"})
        return self._result(policy, stopped)

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
