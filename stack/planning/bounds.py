"""Value bounds from the underlying MDP: QMDP (eq. 2.18), the fast informed bound,
and the blind-policy lower bound.

QMDP assumes the state becomes fully known after one step; the fast informed bound
(Hauskrecht 2000) only that the observation does, so it is tighter. Both are upper
bounds on the optimal POMDP value; the blind policies ("always do a") give lower bounds.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stack.planning import clock
from stack.planning.pomdp import POMDP, ModelError
from stack.planning.threads import blas_threads

# systems up to this many states are solved densely (numpy's LAPACK, already loaded),
# so the solve path of a small model never imports scipy.sparse.linalg (~0.08 s of
# start-up). Dense LU grows as S^3: RockSample_4_4's 257 states take ~0.7 ms a solve
# (its QMDP and blind bounds 0.027 s against 0.015 s sparse); at 600 states a solve
# would cost ~10 ms per action and iteration, more than the import (docs/BENCHMARKS.md)
_DENSE_SOLVE_MAX_STATES = 300


def _solve_value(T: sp.spmatrix, discount: float, rewards: np.ndarray) -> np.ndarray:
    """V with V = rewards + discount T V, T a row-stochastic (S, S) matrix."""
    S = T.shape[0]
    if S <= _DENSE_SOLVE_MAX_STATES:
        M = -discount * (T.toarray() if sp.issparse(T) else np.asarray(T, dtype=float))  # type: ignore[union-attr]
        M[np.diag_indices(S)] += 1.0
        # one thread: OpenBLAS's second thread made this 257-state solve 0.2 s instead
        # of 1 ms on the shared 2-core machine (docs/BENCHMARKS.md)
        with blas_threads(1):
            return np.linalg.solve(M, np.asarray(rewards, dtype=float))
    import scipy.sparse.linalg as spla  # only for large models (its import is slow)

    eye = sp.identity(S, format="csc")
    return spla.spsolve((eye - discount * T).tocsc(), rewards)


def require_discounted(pomdp: POMDP) -> None:
    if not pomdp.discount < 1.0:
        raise ModelError(
            f"discount {pomdp.discount} is not below 1: an infinite-horizon solver needs a "
            "discount < 1 (give the model a discount, or solve it with a finite horizon)"
        )


def _policy_matrix(pomdp: POMDP, policy: np.ndarray) -> sp.csr_matrix:
    rows = [sp.diags((policy == a).astype(float)) @ pomdp.T[a] for a in range(pomdp.n_actions)]
    return sp.csr_matrix(sum(rows[1:], rows[0]))


def qmdp(pomdp: POMDP, max_iterations: int = 100) -> np.ndarray:
    """Optimal Q-values of the fully observable MDP, by policy iteration.

    Returns:
        Q (S, A). max_a Q(s, a) is an upper bound on the POMDP value of state s, and
        argmax_a b . Q(:, a) is the QMDP action (eq. 2.18).
    """
    require_discounted(pomdp)
    g = pomdp.discount
    S = pomdp.n_states
    R = pomdp.R
    policy = R.argmax(axis=1)
    states = np.arange(S)
    # small models: every action's table dense, (A, S, S); a policy's table is then one
    # gather and Q one product
    dense = (
        np.stack([pomdp.T[a].toarray() for a in range(pomdp.n_actions)])
        if S <= _DENSE_SOLVE_MAX_STATES
        else None
    )
    for _ in range(max_iterations):
        if dense is not None:
            V = _solve_value(dense[policy, states], g, R[states, policy])
            Q = R + g * (dense @ V).T
        else:
            Tpi = _policy_matrix(pomdp, policy)
            V = _solve_value(Tpi, g, R[states, policy])
            Q = R + g * np.column_stack([pomdp.T[a] @ V for a in range(pomdp.n_actions)])
        new = Q.argmax(axis=1)
        # keep the old action on ties so that policy iteration terminates
        keep = Q[np.arange(S), policy] >= Q[np.arange(S), new] - 1e-12
        new[keep] = policy[keep]
        if np.array_equal(new, policy):
            return Q
        policy = new
    return Q


def fast_informed_bound(
    pomdp: POMDP,
    Q0: np.ndarray | None = None,
    max_iterations: int = 200,
    tol: float = 1e-6,
    time_limit_s: float | None = None,
) -> np.ndarray:
    """The fast informed bound, iterated down from QMDP.

    Q(s,a) <- R(s,a) + gamma sum_z max_a' sum_s' T(s,a,s') O(s',a,z) Q(s',a')

    The operator is monotone and QMDP lies above its fixed point, so every iterate
    started from QMDP is itself an upper bound: stopping early (``max_iterations``,
    ``time_limit_s``) still gives a valid, if looser, bound.

    Returns:
        Q (S, A).
    """
    require_discounted(pomdp)
    Q = qmdp(pomdp) if Q0 is None else Q0.copy()
    g = pomdp.discount
    A, S, Z = pomdp.n_actions, pomdp.n_states, pomdp.n_observations
    start = clock.now()
    # TO[a]: one row per (s, z) that can occur, columns s': T(s, a, s') O(s', a, z),
    # built once; then an iteration is one sparse-by-dense product per action
    TO = [_joint_rows(pomdp.T[a], pomdp.O[a], Z) for a in range(A)]
    for _ in range(max_iterations):
        new = np.empty_like(Q)
        for a in range(A):
            M, state_of_row = TO[a]
            best = np.asarray(M @ Q).max(axis=1)  # max over a' per (s, z)
            new[:, a] = pomdp.R[:, a] + g * np.bincount(state_of_row, best, minlength=S)
        new = np.minimum(new, Q)  # numerical safety: iterates only decrease
        delta = np.abs(new - Q).max()
        Q = new
        if delta < tol or (time_limit_s is not None and clock.now() - start > time_limit_s):
            break
    return Q


def _joint_rows(T: sp.spmatrix, O: sp.spmatrix, Z: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """T(s, s') O(s', z) as a sparse matrix with one row per (s, z) pair that occurs
    (columns s'), and each row's s. Its size is the non-zeros of T times those of O's
    rows, never Z x S rows: a model whose observation joins a fully observed variable
    (RockSample_11_11.pomdpx: 249,856 states, 244 observations) would need 61 million
    rows per action, 7.8 GB in all, and as many per product."""
    T, O = sp.csr_matrix(T), sp.csr_matrix(O)
    S = T.shape[0]
    row_s = np.repeat(np.arange(S), np.diff(T.indptr))
    per = np.diff(O.indptr)[T.indices]  # observations of each transition's next state
    t = np.repeat(np.arange(T.nnz), per)  # the transition of each (s, s', z)
    within = np.arange(t.size) - np.repeat(np.cumsum(per) - per, per)
    o = O.indptr[T.indices[t]] + within  # its entry of O
    key = row_s[t].astype(np.int64) * Z + O.indices[o]
    rows, row_of = np.unique(key, return_inverse=True)
    M = sp.csr_matrix((T.data[t] * O.data[o], (row_of.ravel(), T.indices[t])), shape=(rows.size, S))
    return M, (rows // Z).astype(np.int64)


def blind_lower_bound(pomdp: POMDP) -> np.ndarray:
    """Alpha vectors of the blind policies "always do a" (one per action), shape (A, S).

    Each is the exact value of a policy, so max_a alpha_a . b is a lower bound.
    """
    require_discounted(pomdp)
    return np.vstack(
        [_solve_value(pomdp.T[a], pomdp.discount, pomdp.R[:, a]) for a in range(pomdp.n_actions)]
    )


def plan_alphas(pomdp: POMDP, plans: list[list[int]], stay_action: int) -> np.ndarray:
    """Exact alpha vectors of open-loop plans: the listed actions, then ``stay_action``
    forever. Each is the value of a policy, hence a valid lower-bound vector.

    For the task model, "walk to cell c and wait there" plans give a far better start
    than the blind policies: the value of guarding a cell shows up at once instead of
    creeping in one Bellman step per iteration.

    Returns:
        (len(plans), S) alpha vectors.
    """
    require_discounted(pomdp)
    S = pomdp.n_states
    stay = _solve_value(pomdp.T[stay_action], pomdp.discount, pomdp.R[:, stay_action])
    out = []
    for plan in plans:
        v = stay
        for a in reversed(plan):
            v = pomdp.R[:, a] + pomdp.discount * (pomdp.T[a] @ v)
        out.append(v)
    return np.vstack(out) if out else np.empty((0, S))
