"""The tables a ``.pomdp`` file is read into, entry by entry, before the model is built.

A file may set a probability or a reward many times ("later entries override earlier
ones"), by single entries, rows, whole matrices and ``*`` wildcards. :class:`RowTable`
holds T or O as one row object per (action, state) -- a dict for sparse rows, a numpy
array for rows given in full -- so an override is one item assignment and the CSR
matrices are assembled once at the end; :class:`RewardTable` holds R(a, s, s', z) as a
base per (a, s) with sparse overrides and computes the expected reward R(s, a).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import scipy.sparse as sp

from stack.planning.pomdp_format.syntax import ALL, MAX_DENSE_ENTRIES, PomdpFormatError


class RowTable:
    """Per-action matrix (n_rows, n_cols) built entry by entry.

    ``rows[a][i]`` is None (all zero), a dict {col: value} (sparse) or a float array of
    length n_cols (a row given in full). Both row kinds take ``row[j] = p``, so a single
    entry is one item assignment whatever came before it.
    """

    def __init__(self, n_actions: int, n_rows: int, n_cols: int) -> None:
        self.n_rows = n_rows
        self.n_cols = n_cols
        self.rows: list[list[dict | np.ndarray | None]] = [
            [None] * n_rows for _ in range(n_actions)
        ]

    def set_entry(self, acts: Iterable[int], rows: Iterable[int], col: int, p: float) -> None:
        rows = list(rows)
        for a in acts:
            ra = self.rows[a]
            for i in rows:
                if col == ALL:
                    ra[i] = {} if p == 0.0 else np.full(self.n_cols, p)
                else:
                    r = ra[i]
                    if r is None:
                        ra[i] = {col: p}
                    else:
                        r[col] = p

    def set_row(self, acts: Iterable[int], rows: Iterable[int], vec: np.ndarray) -> None:
        rows = list(rows)
        for a in acts:
            ra = self.rows[a]
            for i in rows:
                ra[i] = vec.copy()

    def set_identity(self, acts: Iterable[int]) -> None:
        for a in acts:
            self.rows[a] = [{i: 1.0} for i in range(self.n_rows)]

    def to_csr(self, a: int) -> sp.csr_matrix:
        # One pass of list extends, then numpy once: per-row numpy calls would dominate.
        counts = [0] * self.n_rows
        cols: list[int] = []
        vals: list[float] = []
        for i, r in enumerate(self.rows[a]):
            if r is None:
                continue
            if isinstance(r, dict):
                cols.extend(r.keys())
                vals.extend(r.values())
                counts[i] = len(r)
            else:
                nz = np.flatnonzero(r)
                cols.extend(nz.tolist())
                vals.extend(r[nz].tolist())
                counts[i] = nz.size
        indices = np.array(cols, dtype=np.int64)
        data = np.array(vals, dtype=float)
        row_of = np.repeat(np.arange(self.n_rows), counts)
        keep = data != 0.0  # explicit zeros ("T: * : * : * 0.0") are not stored
        if not keep.all():
            indices, data, row_of = indices[keep], data[keep], row_of[keep]
        indptr = np.zeros(self.n_rows + 1, dtype=np.int64)
        np.cumsum(np.bincount(row_of, minlength=self.n_rows), out=indptr[1:])
        m = sp.csr_matrix((data, indices, indptr), shape=(self.n_rows, self.n_cols))
        m.has_sorted_indices = False
        m.sort_indices()
        return m


class RewardTable:
    """R(a, s, s', z) as a base per (a, s) plus sparse overrides per next state s'.

    For each (a, s) the reward of a (s', z) is ``over[(a, s)][s']`` when present (a float,
    the same for every z, or an array over z), else ``zbase[(a, s)][z]`` when present,
    else ``default[a, s]``. The usual ``R: a : s : * : * v`` is one write to ``default``;
    no form costs more than the numbers it names (``R: * : * : * : z v`` is one array
    per (a, s), never one per (a, s, s')).
    """

    def __init__(self, A: int, S: int, Z: int) -> None:
        self.A, self.S, self.Z = A, S, Z
        if A * S > MAX_DENSE_ENTRIES:
            raise PomdpFormatError(
                0,
                f"{S:,} states x {A:,} actions: the reward table would exceed "
                f"{MAX_DENSE_ENTRIES:,} entries",
            )
        self.default = np.zeros((A, S))
        self.zbase: dict[tuple[int, int], np.ndarray] = {}
        self.over: dict[tuple[int, int], dict[int, float | np.ndarray]] = {}

    def reset(self, acts: list[int], rows: list[int]) -> None:
        """Forget every override of the given (a, s): what follows sets them afresh."""
        for store in (self.over, self.zbase):
            if not store:
                continue
            if len(acts) == 1 and len(rows) == 1:
                store.pop((acts[0], rows[0]), None)
                continue
            aset, sset = set(acts), set(rows)
            for key in [k for k in store if k[0] in aset and k[1] in sset]:
                del store[key]

    def _with_z(self, cur: float | np.ndarray, z: int, v: float) -> np.ndarray:
        arr = cur.copy() if isinstance(cur, np.ndarray) else np.full(self.Z, cur)
        arr[z] = v
        return arr

    def set_value(self, acts: list[int], rows: list[int], nxt: int, z: int, v: float) -> None:
        if nxt == ALL and z == ALL:
            if len(acts) == 1 and len(rows) == 1:
                self.default[acts[0], rows[0]] = v
            else:
                self.default[np.ix_(acts, rows)] = v
            self.reset(acts, rows)
            return
        for a in acts:
            for s in rows:
                key = (a, s)
                if nxt == ALL:  # one z, every s': the base and each override change at z
                    base = self.zbase.get(key, self.default[a, s])
                    self.zbase[key] = self._with_z(base, z, v)
                    d = self.over.get(key)
                    if d:
                        for n, cur in d.items():
                            d[n] = self._with_z(cur, z, v)
                    continue
                d = self.over.setdefault(key, {})
                if z == ALL:
                    d[nxt] = v
                else:
                    cur = d.get(nxt)  # type: ignore[assignment]
                    if cur is None:
                        cur = self.zbase.get(key, self.default[a, s])
                    d[nxt] = self._with_z(cur, z, v)

    def set_row(self, acts: list[int], rows: list[int], nxt: int, vec: np.ndarray) -> None:
        if nxt == ALL:
            self.reset(acts, rows)
        for a in acts:
            for s in rows:
                if nxt == ALL:
                    self.zbase[(a, s)] = vec  # never mutated in place: _with_z copies
                else:
                    self.over.setdefault((a, s), {})[nxt] = vec

    def set_matrix(self, acts: list[int], rows: list[int], mat: np.ndarray) -> None:
        self.reset(acts, rows)
        for a in acts:
            for s in rows:
                self.default[a, s] = 0.0
                self.over[(a, s)] = {n: mat[n] for n in range(self.S)}

    def expected(self, T: Sequence[sp.csr_matrix], Obs: Sequence[sp.csr_matrix]) -> np.ndarray:
        """R(s, a) as an (S, A) array; the expectation runs only where overrides exist.

        Walks the non-zeros of row s of T[a] (and of row s' of O[a] where the reward
        depends on z), so its cost is that of the sparse tables, not S x S x Z.
        """
        R = self.default.T.copy()
        for key in self.over.keys() | self.zbase.keys():
            a, s = key
            d = self.over.get(key, {})
            base = self.zbase.get(key, self.default[a, s])
            Ta, Oa = T[a], Obs[a]
            lo, hi = Ta.indptr[s], Ta.indptr[s + 1]
            total = 0.0
            for n, p in zip(Ta.indices[lo:hi].tolist(), Ta.data[lo:hi].tolist(), strict=True):
                v = d.get(n, base)
                if isinstance(v, np.ndarray):
                    olo, ohi = Oa.indptr[n], Oa.indptr[n + 1]
                    v = float(Oa.data[olo:ohi] @ v[Oa.indices[olo:ohi]])
                total += p * v
            R[s, a] = total
        return R
