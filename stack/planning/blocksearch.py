"""The belief-tree search with its vectors per observed block (SARSOP's MOMDP form).

A ``.pomdpx`` model with fully observed state variables (RockSample's robot cell)
has flat states in blocks, one per joint value x of those variables
(:func:`stack.planning.pomdpx.observed_blocks`), all of the same size n (the other
variables' joint values). The observation tells x' exactly, so a belief reached from
a belief within one block lies within one block: it is a pair (x, b) with b over the
block's n states, and a vector only ever needs its values on one block (Ong, Png, Hsu
and Lee 2010). :class:`BlockTreeSearch` is :class:`stack.planning.sarsop.BeliefTreeSearch`
(the same tree, trials, target levels, upper bound, pruning rule, stopping rules and
clock) with the lower bound's vectors stored that way:

- a vector belongs to one block and holds n values (RockSample_11_11: 2,048 doubles,
  16 KB, against 249,856 flat, 2 MB);
- a backup at a belief in block x computes the new vector's values on block x only:
  the successors of block x's states under the action, and the observation's
  rows of the blocks they lie in;
- the best vector at a belief is searched among its block's vectors only;
- the policy is written in SARSOP's factored layout (``obsValue`` x, the vector
  over block x), which SARSOP's ``pomdpsim`` reads and
  :func:`stack.planning.policy.read_policy_xml` reads back per block (given the
  model's observed blocks).

Unlike :mod:`stack.planning.momdp` (the task model: the hidden factor's dynamics
and observations independent of x and the action, one node for every cell), this
needs no such independence: the flat model's T, O and R are used as they are, row
slices per block. The initial belief must lie within one block (RockSample's start is
known); a model whose b0 spreads over several (TagAvoid's robot start is uniform) is
searched flat.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from stack.planning.policy import AlphaPolicy
from stack.planning.pomdp import POMDP
from stack.planning.pomdpx import observed_blocks
from stack.planning.sarsop import BeliefTreeSearch
from stack.planning.sarsop_nodes import BeliefNode, NodeChildren
from stack.planning.search_base import SearchConfig, SearchStats


def search_blocks(pomdp: POMDP, b0: np.ndarray | None = None) -> np.ndarray | None:
    """The (X, n) observed blocks of a model the block search applies to: read from a
    ``.pomdpx`` with fully observed variables, b0 within one block. None otherwise."""
    blocks = observed_blocks(pomdp)
    if not blocks or len(blocks) < 2 or len({len(b) for b in blocks}) != 1:
        return None
    arr = np.vstack(blocks)
    where = np.empty(pomdp.n_states, dtype=int)
    where[arr.ravel()] = np.repeat(np.arange(len(arr)), arr.shape[1])
    b0 = pomdp.b0 if b0 is None else b0
    return arr if np.unique(where[np.flatnonzero(b0 > 0)]).size == 1 else None


class BlockTreeSearch(BeliefTreeSearch):
    """The search of :class:`BeliefTreeSearch` with vectors per observed block.

    Args:
        pomdp: a discounted model.
        blocks: (X, n) the flat states of each observed value (:func:`search_blocks`);
            every observation must tell the next state's block.
        The rest as :class:`BeliefTreeSearch` (seeds are flat vectors, cut into blocks).
    """

    def __init__(
        self,
        pomdp: POMDP,
        blocks: np.ndarray,
        config: SearchConfig | None = None,
        seed_alphas: tuple[np.ndarray, ...] | None = None,
        start: float | None = None,
        progress: Callable[[SearchStats], None] | None = None,
        q_upper: np.ndarray | None = None,
        b0: np.ndarray | None = None,
    ):
        S = pomdp.n_states
        blocks = np.asarray(blocks, dtype=np.int64)
        X, n = blocks.shape
        if blocks.size != S or np.unique(blocks).size != S:
            raise ValueError(f"blocks {blocks.shape} do not cover the {S} states once")
        self._blocks = blocks
        self._n = n
        self._where = np.empty(S, dtype=np.int64)  # block of each flat state
        self._where[blocks.ravel()] = np.repeat(np.arange(X), n)
        self._pos = np.empty(S, dtype=np.int64)  # its position in the block
        self._pos[blocks.ravel()] = np.tile(np.arange(n), X)
        b0 = pomdp.b0 if b0 is None else np.asarray(b0, dtype=float)
        if np.unique(self._where[np.flatnonzero(b0 > 0)]).size != 1:
            raise ValueError("b0 is not within one observed block")
        config = SearchConfig() if config is None else config
        super().__init__(pomdp, config, seed_alphas, start, progress, b0=b0, q_upper=q_upper)
        # block x's rows of T[a], O[a] and R: a slice (rows x*n .. (x+1)*n)
        order = blocks.ravel()
        same = bool((order == np.arange(S)).all())
        self._Tb = self.T if same else [T[order] for T in self.T]
        self._Ob = self.O if same else [O[order] for O in self.O]
        self._Tb_rows = (
            self.T_rows if same else [np.repeat(np.arange(S), np.diff(T.indptr)) for T in self._Tb]
        )
        self._Ob_rows = (
            self.O_rows if same else [np.repeat(np.arange(S), np.diff(O.indptr)) for O in self._Ob]
        )
        self._Rb = self.R[order].reshape(X, n, self.A)

    # -- the vectors, per block ---------------------------------------------------------
    def _obs_blocks(self) -> np.ndarray:
        """(Z,) the block every observation tells (-1: an observation never made)."""
        zx = np.full(self.pomdp.n_observations, -1)
        for O, rows in zip(self.O, self.O_rows, strict=True):
            zx[O.indices] = self._where[rows]
        for O, rows in zip(self.O, self.O_rows, strict=True):
            if (zx[O.indices] != self._where[rows]).any():
                raise ValueError("an observation is made in several observed blocks")
        return zx

    def _init_store(
        self, alphas: np.ndarray, actions: np.ndarray, succ: np.ndarray, n_active: int
    ) -> None:
        """Every initial flat vector i cut into its blocks: global id i * X + x; its
        successor after z is the successor's part on the block z tells."""
        X, n = self._blocks.shape
        self._zx = self._obs_blocks()
        self._values_per_vector = n
        N = len(alphas)
        for i in range(N):
            for x in range(X):
                self._all_alpha.append(alphas[i, self._blocks[x]])
                self._all_act.append(int(actions[i]))
                nxt = succ[i]
                self._all_succ.append(
                    np.where((nxt >= 0) & (self._zx >= 0), nxt * X + self._zx, -1)
                )
        self._all_blk: list[int] = [x for _ in range(N) for x in range(X)]
        self.K = n_active * X
        cap = max(64, 2 * self.K)
        self._act = np.zeros(cap, dtype=int)
        self._gid = np.zeros(cap, dtype=int)
        self._blk = np.zeros(cap, dtype=int)  # the block of each active vector
        self._col = np.zeros(cap, dtype=int)  # ... its column in the block's array
        self._act[: self.K] = np.repeat(actions[:n_active], X)
        self._gid[: self.K] = np.arange(self.K)
        self._blk[: self.K] = np.tile(np.arange(X), n_active)
        self._col[: self.K] = np.repeat(np.arange(n_active), X)
        # per block: its vectors transposed (n, capacity), their positions, their count
        self._bAT = []
        self._bpos = []
        for x in range(X):
            AT = np.empty((n, max(16, 2 * n_active)))
            AT[:, :n_active] = alphas[:n_active, self._blocks[x]].T
            self._bAT.append(AT)
            pos = np.zeros(AT.shape[1], dtype=int)
            pos[:n_active] = np.arange(n_active) * X + x
            self._bpos.append(pos)
        self._bK = np.full(X, n_active)

    def _best_at(self, idx: np.ndarray, val: np.ndarray) -> tuple[int, float]:
        x = int(self._where[idx[0]])
        v = val @ self._bAT[x][self._pos[idx], : self._bK[x]]
        j = int(v.argmax())
        return int(self._bpos[x][j]), float(v[j])

    def _best_cols(self, nz: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n_cols = M.shape[1]
        row_blk = self._where[nz]
        if row_blk.size and row_blk.min() == row_blk.max():
            # all in one block (RockSample: the robot's move is deterministic)
            x = int(row_blk[0])
            G = M.T @ self._bAT[x][self._pos[nz], : self._bK[x]]
            j = G.argmax(axis=1)
            return self._bpos[x][j], G[np.arange(n_cols), j]
        col_blk = row_blk[(M > 0).argmax(axis=0)]  # each belief lies in one block
        best = np.empty(n_cols, dtype=int)
        values = np.empty(n_cols)
        for x in np.unique(col_blk).tolist():
            c = np.flatnonzero(col_blk == x)
            r = np.flatnonzero(row_blk == x)
            Mx = M if c.size == n_cols and r.size == nz.size else M[np.ix_(r, c)]
            G = Mx.T @ self._bAT[x][self._pos[nz[r]], : self._bK[x]]
            j = G.argmax(axis=1)
            best[c] = self._bpos[x][j]
            values[c] = G[np.arange(c.size), j]
        return best, values

    def _best_nodes(self, nodes: list[BeliefNode]) -> tuple[np.ndarray, np.ndarray]:
        best = np.empty(len(nodes), dtype=int)
        values = np.empty(len(nodes))
        by_block: dict[int, list[int]] = {}
        for i, node in enumerate(nodes):
            by_block.setdefault(int(self._where[node.idx[0]]), []).append(i)
        for x, members in by_block.items():
            B = np.zeros((len(members), self._n))
            for row, i in enumerate(members):
                B[row, self._pos[nodes[i].idx]] = nodes[i].val
            V = B @ self._bAT[x][:, : self._bK[x]]
            j = V.argmax(axis=1)
            best[members] = self._bpos[x][j]
            values[members] = V[np.arange(len(members)), j]
        return best, values

    def _store(self, alpha: np.ndarray, action: int, node: BeliefNode) -> None:
        x = int(self._where[node.idx[0]])
        if self.K == self._act.size:
            grow = np.zeros(self.K, dtype=int)
            self._act, self._gid, self._blk, self._col = (
                np.concatenate([a, grow]) for a in (self._act, self._gid, self._blk, self._col)
            )
        k = int(self._bK[x])
        if k == self._bAT[x].shape[1]:
            self._bAT[x] = np.concatenate([self._bAT[x], np.empty_like(self._bAT[x])], axis=1)
            self._bpos[x] = np.concatenate([self._bpos[x], np.zeros(k, dtype=int)])
        self._bAT[x][:, k] = alpha
        self._bpos[x][k] = self.K
        self._bK[x] = k + 1
        self._act[self.K] = action
        self._gid[self.K] = len(self._all_alpha)
        self._blk[self.K] = x
        self._col[self.K] = k
        self._all_blk.append(x)

    def _compact(self, kept: np.ndarray) -> None:
        # a block where the search has backed up no belief keeps its vectors: dominance
        # is judged at the sampled beliefs, and every block needs a vector (a successor
        # after an observation the beliefs cannot produce)
        empty = ~np.isin(self._blk[: self.K], self._blk[kept])
        kept = np.union1d(kept, np.flatnonzero(empty))
        m = kept.size
        for arr in (self._act, self._gid, self._blk, self._col):
            arr[:m] = arr[kept]
        blk, col = self._blk[:m], self._col[:m]
        for x in range(len(self._blocks)):
            sel = np.flatnonzero(blk == x)
            AT = self._bAT[x]
            AT[:, : sel.size] = AT[:, col[sel]]
            self._bpos[x][: sel.size] = sel
            self._bK[x] = sel.size
            col[sel] = np.arange(sel.size)
        self.K = m

    def _sample_vectors(self) -> np.ndarray:
        x = int(self._bK.argmax())
        return self._bAT[x][: min(self._n, 512), : min(int(self._bK[x]), 64)].T

    @property
    def alphas(self) -> np.ndarray:
        """The active vectors, (K, n): each over its own block (:attr:`blocks_of`)."""
        blk, col = self._blk[: self.K].tolist(), self._col[: self.K].tolist()
        return np.vstack([self._bAT[x][:, c] for x, c in zip(blk, col, strict=True)])

    @property
    def blocks_of(self) -> np.ndarray:
        """(K,) the block of each active vector."""
        return self._blk[: self.K]

    # -- the backup ---------------------------------------------------------------------
    def _alpha(
        self, kids: NodeChildren, a: int, best: np.ndarray, node: BeliefNode
    ) -> tuple[np.ndarray, np.ndarray]:
        """The backed-up vector on the node's block x only:
        alpha(s) = R(s,a) + gamma sum_s' T(s,a,s') sum_z O(s',a,z) alpha_k(z)(s'),
        s in block x; and its successors by observation (global ids, -1 where none)."""
        n = self._n
        x = int(self._where[node.idx[0]])
        kstar = np.full(self.pomdp.n_observations, -1)
        kstar[kids.zs] = best
        T = self._Tb[a]
        p0, p1 = T.indptr[x * n], T.indptr[(x + 1) * n]
        rows = self._Tb_rows[a][p0:p1] - x * n
        nxt = T.indices[p0:p1]
        nxt_blk = self._where[nxt]
        pred = None
        v = np.empty(nxt.size)
        O = self._Ob[a]
        for y in np.unique(nxt_blk).tolist():
            q0, q1 = O.indptr[y * n], O.indptr[(y + 1) * n]
            zs = O.indices[q0:q1]
            missing = np.unique(zs[kstar[zs] < 0])
            if missing.size:
                # observations the belief cannot produce here: any vector of block y keeps
                # the bound; take the best at the predicted belief on block y
                if pred is None:
                    pred = kids.M @ kids.pz
                on_y = self._where[kids.nz] == y
                if on_y.any() and pred[on_y].sum() > 0:
                    kstar[missing] = self._best_at(kids.nz[on_y], pred[on_y])[0]
                else:
                    kstar[missing] = self._best_at(self._blocks[y], np.full(n, 1.0 / n))[0]
            orow = self._Ob_rows[a][q0:q1] - y * n
            vy = np.bincount(
                orow, weights=O.data[q0:q1] * self._bAT[y][orow, self._col[kstar[zs]]], minlength=n
            )
            here = nxt_blk == y
            v[here] = vy[self._pos[nxt[here]]]
        Tv = np.bincount(rows, weights=T.data[p0:p1] * v, minlength=n)
        succ = np.where(kstar >= 0, self._gid[kstar], -1)
        return self._Rb[x, :, a] + self.gamma * Tv, succ

    # -- the policy ---------------------------------------------------------------------
    def _policy(self) -> AlphaPolicy:
        """The active vectors (or, with ``config.reached_only``, those the policy uses
        at the tree's nodes) and the archived ones they lead to, each over its block."""
        order = self.closure()
        where = {g: k for k, g in enumerate(order)}
        where[-1] = -1
        self.successors = np.array(
            [[where.get(int(g), -1) for g in self._all_succ[k]] for k in order], dtype=int
        )
        alphas = np.vstack([self._all_alpha[g] for g in order])  # type: ignore[misc]
        actions = np.array([self._all_act[g] for g in order], dtype=int)
        obs = np.array([self._all_blk[g] for g in order], dtype=int)
        return AlphaPolicy(
            alphas, actions, meta={"solver": "sarsop-blocks"}, blocks=self._blocks, obs=obs
        )
