"""The flat POMDP: the form every solver in this package works on.

A discrete POMDP (S, A, Z, T, O, R, gamma, b0) as chapter 2 of the thesis writes
it, stored so that the solvers can stay vectorised:

- ``T[a]``: scipy CSR matrix of shape (S, S), ``T[a][s, s'] = P(s' | s, a)``;
- ``O[a]``: scipy CSR matrix of shape (S, Z), ``O[a][s', z] = P(z | s', a)``;
- ``R``: dense array (S, A), the expected immediate reward R(s, a);
- ``b0``: dense initial belief (S,).

Transition and observation matrices are sparse because the models of interest
are (the robot moves to one of two cells; its position is observed exactly).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

PROB_TOL = 1e-9


class ModelError(ValueError):
    """A POMDP whose tables are inconsistent (shapes, non-distributions)."""


@dataclass(frozen=True, eq=False)
class POMDP:
    """A flat discrete POMDP.

    Attributes:
        states, actions, observations: names, in index order.
        T: per action, CSR (S, S) transition matrix.
        O: per action, CSR (S, Z) observation matrix over the *next* state.
        R: (S, A) expected immediate reward.
        discount: gamma in [0, 1].
        b0: (S,) initial belief.
    """

    states: tuple[str, ...]
    actions: tuple[str, ...]
    observations: tuple[str, ...]
    T: tuple[sp.csr_matrix, ...]
    O: tuple[sp.csr_matrix, ...]
    R: np.ndarray
    discount: float
    b0: np.ndarray
    name: str = "pomdp"
    values: str = "reward"
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        S, A, Z = len(self.states), len(self.actions), len(self.observations)
        if S == 0 or A == 0 or Z == 0:
            raise ModelError(f"need at least one state, action and observation, got {S}, {A}, {Z}")
        if len(self.T) != A or len(self.O) != A:
            raise ModelError(
                f"T and O need one matrix per action ({A}), got {len(self.T)}, {len(self.O)}"
            )
        for a in range(A):
            if self.T[a].shape != (S, S):
                raise ModelError(
                    f"T[{self.actions[a]}] has shape {self.T[a].shape}, expected {(S, S)}"
                )
            if self.O[a].shape != (S, Z):
                raise ModelError(
                    f"O[{self.actions[a]}] has shape {self.O[a].shape}, expected {(S, Z)}"
                )
        if self.R.shape != (S, A):
            raise ModelError(f"R has shape {self.R.shape}, expected {(S, A)}")
        if self.b0.shape != (S,):
            raise ModelError(f"b0 has shape {self.b0.shape}, expected {(S,)}")
        if not 0.0 <= self.discount <= 1.0:
            raise ModelError(f"discount {self.discount} is not in [0, 1]")

    # -- sizes --------------------------------------------------------------
    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def n_actions(self) -> int:
        return len(self.actions)

    @property
    def n_observations(self) -> int:
        return len(self.observations)

    # -- checks -------------------------------------------------------------
    def validate(self, tol: float = PROB_TOL) -> None:
        """Check that every row of T, O and b0 is a distribution within ``tol``.

        Raises:
            ModelError: naming the first table, action and row that is not.
        """
        _check_rows("b0", self.b0[None, :], tol, self.states[:1], "")
        for a, name in enumerate(self.actions):
            _check_rows(f"T[{name}]", self.T[a], tol, self.states, "from state")
            _check_rows(f"O[{name}]", self.O[a], tol, self.states, "in next state")
        if not np.all(np.isfinite(self.R)):
            raise ModelError("R has non-finite entries")

    def fingerprint(self) -> str:
        """SHA-256 of the model's numbers (T, O, R, discount, b0): a policy records
        it, so that a policy solved for one model is refused for another."""
        if "fingerprint" not in self._cache:
            h = hashlib.sha256()
            h.update(repr((self.n_states, self.n_actions, self.n_observations)).encode())
            h.update(np.float64(self.discount).tobytes())
            for M in (*self.T, *self.O):
                M = M.tocsr()
                M.sort_indices()
                for arr in (M.indptr, M.indices, M.data):
                    h.update(np.ascontiguousarray(arr).tobytes())
            h.update(np.ascontiguousarray(self.R, dtype=float).tobytes())
            h.update(np.ascontiguousarray(self.b0, dtype=float).tobytes())
            self._cache["fingerprint"] = h.hexdigest()
        return self._cache["fingerprint"]

    def note(self, key: str, value: Any) -> None:
        """Keep ``value`` with the model under ``key``: what a reader learnt from the
        file beyond the flat tables (a ``.pomdpx``'s observed blocks)."""
        self._cache[key] = value

    def noted(self, key: str) -> Any:
        """The value kept by :meth:`note` under ``key`` (None if none)."""
        return self._cache.get(key)

    # -- derived quantities (cached; the model is immutable) -----------------
    def obs_independent_of_action(self) -> bool:
        """True when O[a] is the same matrix for every action (the task model's case)."""
        if "obs_same" not in self._cache:
            O0 = self.O[0]
            self._cache["obs_same"] = all(O is O0 or (O != O0).nnz == 0 for O in self.O[1:])
        return self._cache["obs_same"]

    def TT(self, a: int) -> sp.csr_matrix:
        """Transpose of T[a] in CSR form (predictions b @ T[a] as T[a].T @ b)."""
        key = ("TT", a)
        if key not in self._cache:
            self._cache[key] = self.T[a].T.tocsr()
        return self._cache[key]

    def OT(self, a: int) -> sp.csr_matrix:
        """Transpose of O[a] in CSR form: rows are observations."""
        key = ("OT", a)
        if key not in self._cache:
            self._cache[key] = self.O[a].T.tocsr()
        return self._cache[key]

    def index(self, kind: str, name: str | int) -> int:
        """Index of a state/action/observation given its name (or an index, checked)."""
        names: Sequence[str] = {
            "state": self.states,
            "action": self.actions,
            "observation": self.observations,
        }[kind]
        if isinstance(name, int | np.integer):
            if not 0 <= int(name) < len(names):
                raise KeyError(f"{kind} index {name} out of range 0..{len(names) - 1}")
            return int(name)
        try:
            return names.index(name)
        except ValueError:
            raise KeyError(f"unknown {kind} {name!r}") from None


def _check_rows(table: str, M, tol: float, names: Sequence[str], what: str) -> None:
    if sp.issparse(M):
        if M.nnz and (M.data < -tol).any():
            raise ModelError(f"{table} has a negative probability")
        sums = np.asarray(M.sum(axis=1)).ravel()
    else:
        if (M < -tol).any():
            raise ModelError(f"{table} has a negative probability")
        sums = M.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > tol)
    if bad.size:
        i = int(bad[0])
        label = f" {what} {names[i]!r}" if what else ""
        raise ModelError(f"{table}{label} sums to {sums[i]:.12g}, not 1 (tolerance {tol:g})")


def dense_to_pomdp(
    T: np.ndarray,
    O: np.ndarray,
    R: np.ndarray,
    discount: float,
    b0: np.ndarray | None = None,
    states: Sequence[str] | None = None,
    actions: Sequence[str] | None = None,
    observations: Sequence[str] | None = None,
    name: str = "pomdp",
) -> POMDP:
    """Build a POMDP from dense arrays T[a,s,s'], O[a,s',z], R[s,a] (handy in tests)."""
    A, S, _ = T.shape
    Z = O.shape[2]
    return POMDP(
        states=tuple(states or (f"s{i}" for i in range(S))),
        actions=tuple(actions or (f"a{i}" for i in range(A))),
        observations=tuple(observations or (f"o{i}" for i in range(Z))),
        T=tuple(sp.csr_matrix(T[a]) for a in range(A)),
        O=tuple(sp.csr_matrix(O[a]) for a in range(A)),
        R=np.asarray(R, dtype=float),
        discount=float(discount),
        b0=np.full(S, 1.0 / S) if b0 is None else np.asarray(b0, dtype=float),
        name=name,
    )
