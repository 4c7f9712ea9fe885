"""Point-based value iteration: the backup operator, belief sampling and Perseus.

The point-based backup at a belief b (section 2.2.3.3) picks, for every action a and
observation z, the alpha vector that is best for the successor belief, and returns

    alpha(s) = R(s, a*) + gamma sum_s' T(s, a*, s') sum_z O(s', a*, z) alpha_{k*(z)}(s')

for the best action a*. It is vectorised with sparse matrices: the work is
proportional to the non-zeros reachable from b, not to |S| x |Z|.

Perseus (Spaan and Vlassis 2005) backs up randomly chosen sampled beliefs until
every belief's value has improved (or stayed), which keeps few alpha vectors.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from stack.planning import belief as belief_ops
from stack.planning import clock
from stack.planning.bounds import blind_lower_bound, qmdp, require_discounted
from stack.planning.policy import AlphaPolicy
from stack.planning.pomdp import POMDP

MAX_OBSERVATION_BLOCKS = 256  # Backup.lookahead_values's kept blocks (about 0.1 MB each)


class Backup:
    """The point-based backup for one model, with its sparse tables prepared once."""

    def __init__(self, pomdp: POMDP):
        require_discounted(pomdp)
        self.pomdp = pomdp
        self.gamma = pomdp.discount
        self.S, self.A, self.Z = pomdp.n_states, pomdp.n_actions, pomdp.n_observations
        self.O = [pomdp.O[a].tocsr() for a in range(self.A)]
        # row index of every stored entry of O[a], for the gather in alpha construction
        self.O_rows = [np.repeat(np.arange(self.S), np.diff(O.indptr)) for O in self.O]
        self.T = [pomdp.T[a].tocsr() for a in range(self.A)]
        self.kept_blocks: dict[tuple[int, bytes], tuple[np.ndarray, np.ndarray]] = {}
        self.TT = [pomdp.TT(a) for a in range(self.A)]
        self.R = pomdp.R

    def action_values(
        self, alphas: np.ndarray, b: np.ndarray
    ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
        """Q(b, a) under the lower bound ``alphas`` for every a, and the chosen vectors.

        Returns:
            q: (A,) one-step lookahead values.
            choice: per action, (reachable observations, index of the best vector for each).
        """
        q = np.empty(self.A)
        choice = []
        for a in range(self.A):
            pred = self.TT[a] @ b
            idx = np.flatnonzero(pred)
            Osub = self.O[a][idx]  # (n, Z) rows of the reachable next states
            scaled = alphas[:, idx] * pred[idx]  # (K, n)
            G = (Osub.T @ scaled.T).T if alphas.shape[0] > 1 else (Osub.T @ scaled[0])[None, :]
            pz = Osub.T @ pred[idx]
            zs = np.flatnonzero(pz > 0)
            Gz = G[:, zs]
            k = Gz.argmax(axis=0)
            q[a] = self.R[:, a] @ b + self.gamma * Gz[k, np.arange(zs.size)].sum()
            choice.append((zs, k))
        return q, choice

    def lookahead_values(
        self, alphas: np.ndarray, b: np.ndarray, blocks: BlockVectors | None = None
    ) -> np.ndarray:
        """Q(b, a) of :meth:`action_values` alone, for choosing an action at run time:
        the observations reachable from ``b`` are found first and the vectors are
        scored only on them (a dense (K, n) x (n, |Z_b|) product instead of a sparse
        one over every observation; the same sums in another order).

        With ``blocks`` (a partition of the states into blocks, :class:`BlockVectors`),
        an observation whose successor states all lie in one block is scored with only
        the vectors that can be best there: the same maximum (a vector dominated on a
        block scores no more than its dominator on any observation of that block), for
        a tenth of the products on the task, whose blocks are the robot's cells.

        The prediction sums only b's support's rows of T, in the full product's order,
        and the observation block of each set of successor states is kept
        (:meth:`_observation_block`): the values are the same to the last bit, three
        to four times sooner at run time (a handful of successor sets recur)."""
        q = np.empty(self.A)
        support = np.flatnonzero(b)
        b_support = b[support]
        for a in range(self.A):
            # the prediction from b's support only: each T[a] row's entries scaled and
            # summed per next state in the order of the full product (the same sums)
            T = self.T[a]
            at, lengths = rows_of(T.indptr, support)
            pred = np.bincount(
                T.indices[at], T.data[at] * np.repeat(b_support, lengths), minlength=self.S
            )
            idx = np.flatnonzero(pred)
            zs, block = self._observation_block(a, idx)
            weighted = block * pred[idx][:, None]  # (n, |Z_b|): O(s', z) P(s')
            if blocks is None:
                best = (alphas[:, idx] @ weighted).max(axis=0).sum()
            else:
                best = blocks.best_sum(idx, weighted)
            q[a] = self.R[:, a] @ b + self.gamma * best
        return q

    def _observation_block(self, a: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The observations possible from the next states ``idx`` under action ``a`` and
        the dense (|idx|, |Z_b|) block of O[a] on them, kept for the next belief with the
        same successors (at run time a handful of sets recur all episode long)."""
        key = (a, idx.tobytes())
        hit = self.kept_blocks.get(key)
        if hit is None:
            Osub = self.O[a][idx]  # (n, Z) rows of the reachable next states
            zs = np.flatnonzero(np.asarray((Osub > 0).sum(axis=0)).ravel())
            hit = (zs, Osub[:, zs].toarray())
            if len(self.kept_blocks) >= MAX_OBSERVATION_BLOCKS:
                self.kept_blocks.clear()
            self.kept_blocks[key] = hit
        return hit

    def __call__(self, alphas: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, int, float]:
        """Back up ``alphas`` at belief ``b``.

        Returns:
            (alpha vector (S,), its action, its value at b).
        """
        q, choice = self.action_values(alphas, b)
        a = int(np.argmax(q))
        zs, k = choice[a]
        # observations unreachable from b: any vector gives a valid alpha; take b's best
        kstar = np.full(self.Z, int(np.argmax(alphas @ b)))
        kstar[zs] = k
        self.last_successors = kstar  # the vector followed after each observation
        O = self.O[a]
        rows = self.O_rows[a]
        v = np.bincount(rows, weights=O.data * alphas[kstar[O.indices], rows], minlength=self.S)
        alpha = self.R[:, a] + self.gamma * (self.T[a] @ v)
        return alpha, a, float(q[a])


def rows_of(indptr: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The positions of the stored entries of a CSR matrix's ``rows`` (in order) and
    each row's count: ``data[at]``, ``indices[at]`` without building a sub-matrix."""
    starts = indptr[rows]
    lengths = indptr[rows + 1] - starts
    ends = np.cumsum(lengths)
    at = np.arange(int(ends[-1]) if ends.size else 0) + np.repeat(starts - ends + lengths, lengths)
    return at, lengths


def nondominated(vectors: np.ndarray) -> np.ndarray:
    """Indices of the rows no other row is at least as large as everywhere (of equal
    rows, one is kept)."""
    keep = np.ones(len(vectors), bool)
    for i in np.argsort(-vectors.sum(axis=1), kind="stable").tolist():  # dominators first
        if keep[i]:
            beaten = (vectors <= vectors[i]).all(axis=1)
            beaten[i] = False
            keep &= ~beaten
    return np.flatnonzero(keep)


class BlockVectors:
    """A policy's vectors that can be best on each block of states.

    The blocks partition the states; on the task they are the robot's cells, which
    every observation names, so each observation's successor states lie in one block.
    A vector that another is at least as large as on every state of a block never
    scores more than it on an observation of that block (the weights are
    probabilities), so :meth:`Backup.lookahead_values` leaves it out there. Each set
    of blocks' vectors are found when first needed (a fraction of a second).

    Args:
        alphas: (K, S) the policy's vectors.
        blocks: (S,) each state's block.
    """

    def __init__(self, alphas: np.ndarray, blocks: np.ndarray):
        self.alphas = alphas
        self.blocks = np.asarray(blocks)
        if self.blocks.shape != (alphas.shape[1],):
            raise ValueError(f"blocks: one per state ({alphas.shape[1]}), got {self.blocks.shape}")
        self._rows: dict[tuple[int, ...], np.ndarray] = {}

    def rows(self, key: tuple[int, ...]) -> np.ndarray:
        """The vectors that can be best on the states of the blocks ``key``."""
        if key not in self._rows:
            cols = np.flatnonzero(np.isin(self.blocks, key))
            self._rows[key] = nondominated(self.alphas[:, cols])
        return self._rows[key]

    def best_sum(self, idx: np.ndarray, weighted: np.ndarray) -> float:
        """sum_z max_k alphas[k, idx] @ weighted[:, z], scoring each observation with
        its blocks' vectors only (``idx``: the successor states, ``weighted``: (n, Z_b)
        their weight per observation)."""
        bi = self.blocks[idx]
        present = np.unique(bi)
        if present.size == 1:
            sub = self.alphas[np.ix_(self.rows((int(present[0]),)), idx)]
            return float((sub @ weighted).max(axis=0).sum())
        touches = np.stack([(weighted[bi == u] != 0).any(axis=0) for u in present])
        single = touches.sum(axis=0) == 1
        best = np.empty(weighted.shape[1])  # each observation's maximum, summed in order
        for j, u in enumerate(present.tolist()):
            z = single & touches[j]
            if z.any():
                r = bi == u
                sub = self.alphas[np.ix_(self.rows((u,)), idx[r])]
                best[z] = (sub @ weighted[np.ix_(r, z)]).max(axis=0)
        if not single.all():  # observations that several blocks lead to
            sub = self.alphas[np.ix_(self.rows(tuple(present.tolist())), idx)]
            best[~single] = (sub @ weighted[:, ~single]).max(axis=0)
        return float(best.sum())


def sample_beliefs(
    pomdp: POMDP,
    starts: Sequence[np.ndarray],
    n_beliefs: int,
    rng: np.random.Generator,
    Q: np.ndarray | None = None,
    explore: float = 0.3,
    horizon: int = 40,
    deadline: float | None = None,
) -> np.ndarray:
    """Reachable beliefs from trajectories of a QMDP policy (random actions with
    probability ``explore``), as Symbolic Perseus samples them (section 4.3); fewer
    when ``clock.now()`` passes ``deadline``.

    Returns:
        (N, S) array of distinct beliefs; the start beliefs come first.
    """
    if Q is None:
        Q = qmdp(pomdp)
    S, A = pomdp.n_states, pomdp.n_actions
    seen: set[bytes] = set()
    out: list[np.ndarray] = []

    def add(b: np.ndarray) -> bool:
        key = np.round(b, 7).tobytes()
        if key in seen:
            return False
        seen.add(key)
        out.append(b)
        return True

    for b in starts:
        add(np.asarray(b, dtype=float))
    T = [pomdp.T[a].tocsr() for a in range(A)]
    O = [pomdp.O[a].tocsr() for a in range(A)]
    # absorbing states ("robot out of the map", whatever the person does): a trajectory
    # whose belief is all in them has nothing more to show, so it ends there. Without
    # this, task r1 spent 200-230 of its 300 beliefs there (with seed 2, all but the
    # useless ones, and the solve failed).
    absorbing = absorbing_states(pomdp)
    attempts = 0
    last_new = 0  # small models have fewer reachable beliefs than asked for: stop looking
    while len(out) < n_beliefs and attempts < 50 * n_beliefs and attempts - last_new < 2000:
        b = starts[attempts % len(starts)]
        s = draw(np.arange(S), b, rng)
        if deadline is not None and clock.now() >= deadline:
            break
        for _ in range(horizon):
            attempts += 1
            a = int(rng.integers(A)) if rng.random() < explore else int(np.argmax(b @ Q))
            s = draw_row(T[a], s, rng)
            z = draw_row(O[a], s, rng)
            b = belief_ops.update(pomdp, b, a, z)
            if absorbing[s] and b[absorbing].sum() > 1.0 - 1e-9:
                break  # all the belief is absorbed: its value is known, sample elsewhere
            if add(b):
                last_new = attempts
            if len(out) >= n_beliefs:
                break
    return np.vstack(out)


def absorbing_states(pomdp: POMDP) -> np.ndarray:
    """States in closed sets of equal rewards: (S,) bool.

    A set X is such a trap when no action leads out of it and every state in it has
    the same reward row R(s, .). Every belief inside X then has the same value (that
    of a one-state MDP), so sampling beliefs there teaches a solver nothing. Found as
    the largest fixed point: start from "every state, grouped by its reward row" and
    drop states with a successor outside their group until nothing changes.
    """
    S = pomdp.n_states
    _, gid = np.unique(np.round(pomdp.R, 12), axis=0, return_inverse=True)
    gid = np.asarray(gid).ravel()
    cand = np.ones(S, dtype=bool)
    Ts = [pomdp.T[a].tocsr() for a in range(pomdp.n_actions)]
    rows = [np.repeat(np.arange(S), np.diff(T.indptr)) for T in Ts]
    while True:
        bad = np.zeros(S, dtype=bool)
        for T, r in zip(Ts, rows, strict=True):
            off = ~cand[T.indices] | (gid[T.indices] != gid[r])
            bad[r[off & (T.data > 0)]] = True
        new = cand & ~bad
        if (new == cand).all():
            return cand
        cand = new


def draw(values: np.ndarray, p: np.ndarray, rng: np.random.Generator) -> int:
    """One of ``values`` drawn with (unnormalised) probabilities ``p``."""
    c = np.cumsum(p)
    return int(values[min(np.searchsorted(c, rng.random() * c[-1], side="right"), len(c) - 1)])


def draw_row(M, i: int, rng: np.random.Generator) -> int:
    """A column index drawn from row ``i`` of a CSR matrix of probabilities."""
    lo, hi = M.indptr[i], M.indptr[i + 1]
    return draw(M.indices[lo:hi], M.data[lo:hi], rng)


@dataclass
class IterationStats:
    iteration: int
    value_b0: float
    n_alphas: int
    backups: int
    elapsed_s: float
    upper_b0: float | None = None

    @property
    def gap(self) -> float | None:
        return None if self.upper_b0 is None else self.upper_b0 - self.value_b0


def perseus(
    pomdp: POMDP,
    beliefs: np.ndarray,
    iterations: int = 50,
    rng: np.random.Generator | None = None,
    initial: AlphaPolicy | None = None,
    time_limit_s: float | None = None,
    progress: Callable[[IterationStats], None] | None = None,
    b0: np.ndarray | None = None,
    closure: dict | None = None,
    tolerance: float | None = None,
) -> tuple[AlphaPolicy, list[IterationStats]]:
    """Perseus: randomised point-based value iteration over a fixed belief set.

    Args:
        pomdp: the model (discount < 1).
        beliefs: (N, S) belief set, e.g. from :func:`sample_beliefs`.
        iterations: Perseus iterations (the thesis used 50).
        rng: source of the random backup order.
        initial: starting lower bound; default the blind policies.
        time_limit_s: stop after the iteration that passes this time.
        progress: called after every iteration.
        b0: belief whose value is reported (default pomdp.b0).
        closure: if given, filled with "alphas", "actions", "successors" (positions,
            -1 unknown) and "active": the final vectors first, then every earlier vector
            they lead to. Perseus replaces its set every iteration, so its vectors are
            values of plans whose later steps are earlier vectors; with those kept the
            best vector's policy earns the bound (stack/planning/controller.py).
        tolerance: stop after an iteration that raised no belief's value by more than
            this (None: run every iteration, or until the time limit). The rest of the
            value a set can gain is about gain * discount / (1 - discount), so
            ``target_gap * (1 - discount) / discount`` stops once Perseus can add less
            than a search's gap target.

    Returns:
        The policy and the per-iteration statistics.
    """
    rng = rng or np.random.default_rng(0)
    b0 = pomdp.b0 if b0 is None else b0
    backup = Backup(pomdp)
    if initial is None:
        alphas = blind_lower_bound(pomdp)
        actions = np.arange(pomdp.n_actions)
    else:
        alphas, actions = initial.alphas.copy(), initial.actions.copy()
    B = np.asarray(beliefs)
    Z = pomdp.n_observations
    # every vector made, by global id, with its successors' ids (blind: itself; given
    # initial vectors: unknown)
    arch_alpha = list(alphas)
    arch_act = [int(a) for a in actions]
    arch_succ = [np.full(Z, i if initial is None else -1, dtype=int) for i in range(len(alphas))]
    gids = np.arange(len(alphas))
    start = clock.now()
    history: list[IterationStats] = []
    n_backups = 0
    values = (alphas @ B.T).max(axis=0)  # the set's value at every sampled belief
    for it in range(1, iterations + 1):
        old = values
        new_alphas: list[np.ndarray] = []
        new_actions: list[int] = []
        new_gids: list[int] = []
        new_vals = np.full(len(B), -np.inf)
        todo = np.arange(len(B))
        while todo.size:
            if time_limit_s is not None and clock.now() - start > time_limit_s:
                break  # mid-iteration: the new vectors join the old (all valid, closed)
            i = int(rng.choice(todo))
            # Gauss-Seidel: back up against the old vectors and those made this iteration,
            # so value travels further than one step per iteration (gamma = 0.99 is slow)
            pool = alphas if not new_alphas else np.vstack([alphas, *new_alphas])
            alpha, a, _ = backup(pool, B[i])
            n_backups += 1
            if alpha @ B[i] < old[i]:
                k = int(np.argmax(alphas @ B[i]))
                alpha, a = alphas[k], int(actions[k])
                new_gids.append(int(gids[k]))
            else:
                pool_gids = np.concatenate([gids, np.asarray(new_gids, dtype=int)])
                new_gids.append(len(arch_alpha))
                arch_alpha.append(alpha)
                arch_act.append(a)
                arch_succ.append(pool_gids[backup.last_successors])
            new_alphas.append(alpha)
            new_actions.append(a)
            new_vals = np.maximum(new_vals, B @ alpha)
            todo = np.flatnonzero(new_vals < old - 1e-9)
        if todo.size:  # stopped mid-iteration: the old vectors still hold where no new one
            new_alphas = [*alphas, *new_alphas]
            new_actions = [*actions.tolist(), *new_actions]
            new_gids = [*gids.tolist(), *new_gids]
        alphas = np.vstack(new_alphas)
        actions = np.asarray(new_actions)
        gids = np.asarray(new_gids, dtype=int)
        stats = IterationStats(
            iteration=it,
            value_b0=float((alphas @ b0).max()),
            n_alphas=len(alphas),
            backups=n_backups,
            elapsed_s=clock.now() - start,
        )
        history.append(stats)
        if progress:
            progress(stats)
        if time_limit_s is not None and stats.elapsed_s > time_limit_s:
            break
        values = (alphas @ B.T).max(axis=0)  # the next iteration's start, computed once
        if tolerance is not None and float(np.max(values - old)) <= tolerance:
            break
    if closure is not None:
        order = list(dict.fromkeys(int(g) for g in gids))  # the final set, duplicates once
        seen = set(order)
        i = 0
        while i < len(order):
            for g in arch_succ[order[i]]:
                if g >= 0 and int(g) not in seen:
                    seen.add(int(g))
                    order.append(int(g))
            i += 1
        where = {g: k for k, g in enumerate(order)}
        where[-1] = -1
        closure["alphas"] = np.vstack([arch_alpha[g] for g in order])
        closure["actions"] = np.array([arch_act[g] for g in order], dtype=int)
        closure["successors"] = np.array(
            [[where[int(g)] for g in arch_succ[k]] for k in order], dtype=int
        ).reshape(len(order), Z)
        closure["active"] = len(set(int(g) for g in gids))
    return AlphaPolicy(alphas=alphas, actions=actions, meta={"solver": "perseus"}), history
