"""Reader and writer for Tony Cassandra's ``.pomdp`` file format.

The format is the one pomdp-solve, SARSOP (APPL), ZMDP and pomdp-py read. A file is a
preamble (``discount:``, ``values:``, ``states:``, ``actions:``, ``observations:``),
an optional start belief (``start:``, ``start include:``, ``start exclude:``), then
any number of ``T:``, ``O:`` and ``R:`` entries, each in one of three shapes (single
entry, row, matrix), with ``*`` wildcards, names or indices, ``#`` comments, and
later entries overriding earlier ones.

The target is the flat :class:`~stack.planning.pomdp.POMDP`: ``T[a]`` and ``O[a]``
sparse CSR, and ``R`` the expected immediate reward

    R(s, a) = sum_{s', z} T(s, a, s') O(a, s', z) R(s, a, s', z),

computed only where a file makes the reward depend on s' or z (most files use the
``R: a : s : * : * v`` form, which needs no expectation at all).

Speed: the text is split into statements with one regular expression (one C call
over the whole file), single entries ``T: a : s : s' p`` take a short fast path, and
tables are kept as one row object per (action, state) -- a dict for sparse rows, a
numpy array for rows given in full -- so that "later overrides earlier" costs one
``row[j] = p`` and the CSR matrices are assembled once at the end.
The module is over 500 lines because the format has many statement shapes, each
with its own error message; the reader and writer share the name rules.
"""

from __future__ import annotations

import io
import math
import os
import re
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TextIO

import numpy as np
import scipy.sparse as sp

from stack.config import write_text
from stack.planning.pomdp import POMDP

__all__ = [
    "PROB_SUM_TOL",
    "PomdpFormatError",
    "format_pomdp",
    "parse_pomdp",
    "read_pomdp",
    "read_text_capped",
    "write_pomdp",
]

# Sizes refused before anything is allocated (a file may declare 10^8 states): the
# largest public files have 12,545 states; these limits leave room and fit in memory.
MAX_COUNTS = {"states": 200_000, "actions": 10_000, "observations": 200_000}
MAX_DENSE_ENTRIES = 50_000_000  # rewards (A x S) and any table given in full
MAX_BYTES = 256 * 1024 * 1024  # a .pomdp text larger than this is refused (/dev/zero)

PROB_SUM_TOL = 1e-6  # a row of T, O or the start belief must sum to 1 within this
# Rows written with 6 decimals (0.166667 x 3 + 0.5, TagAvoid) sum to 1 + 1e-6 exactly in
# decimal but a hair above it in binary floating point: allow for that rounding.
_SUM_SLACK = 1e-12

_ALL = -1  # a resolved '*'

# A statement starts at a keyword that stands alone (whitespace or start of text before
# it) and is followed by a colon. The outer group keeps the whole match so that newline
# counts (line numbers) stay exact; the inner group is the keyword.
_KEYWORDS = (
    r"((discount|values|states|actions|observations"
    r"|start(?:[ \t\r\n]+(?:include|exclude))?|T|O|R)[ \t\r\n]*:)"
)
_STMT_RE = re.compile(r"(?<!\S)" + _KEYWORDS)
# Real files start every statement on its own line; splitting only there is 2-3x faster.
# A keyword hidden mid-line always leaves a stray ':' or token in some body, which is a
# format error, and on any error the text is split again with _STMT_RE (see parse_pomdp).
_STMT_AT_LINE_START_RE = re.compile(r"(?m)^[ \t]*" + _KEYWORDS)
_COMMENT_RE = re.compile(r"#[^\n]*")
_NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_\-]*\Z")
_RESERVED = frozenset(
    {
        "discount", "values", "states", "actions", "observations", "start", "include",
        "exclude", "reward", "cost", "uniform", "identity", "reset", "T", "O", "R",
    }
)  # fmt: skip


class PomdpFormatError(ValueError):
    """A ``.pomdp`` text that does not follow the format.

    Attributes:
        line: 1-based line number the problem was found at (0 when it has none).
        detail: the message without the ``line N:`` prefix.
    """

    def __init__(self, line: int, detail: str) -> None:
        self.line = line
        self.detail = detail
        super().__init__(f"line {line}: {detail}" if line else detail)


# ---------------------------------------------------------------------------------------
# Tables of rows with "later overrides earlier" semantics
# ---------------------------------------------------------------------------------------
class _Table:
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
                if col == _ALL:
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


class _Rewards:
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
        if nxt == _ALL and z == _ALL:
            if len(acts) == 1 and len(rows) == 1:
                self.default[acts[0], rows[0]] = v
            else:
                self.default[np.ix_(acts, rows)] = v
            self.reset(acts, rows)
            return
        for a in acts:
            for s in rows:
                key = (a, s)
                if nxt == _ALL:  # one z, every s': the base and each override change at z
                    base = self.zbase.get(key, self.default[a, s])
                    self.zbase[key] = self._with_z(base, z, v)
                    d = self.over.get(key)
                    if d:
                        for n, cur in d.items():
                            d[n] = self._with_z(cur, z, v)
                    continue
                d = self.over.setdefault(key, {})
                if z == _ALL:
                    d[nxt] = v
                else:
                    cur = d.get(nxt)  # type: ignore[assignment]
                    if cur is None:
                        cur = self.zbase.get(key, self.default[a, s])
                    d[nxt] = self._with_z(cur, z, v)

    def set_row(self, acts: list[int], rows: list[int], nxt: int, vec: np.ndarray) -> None:
        if nxt == _ALL:
            self.reset(acts, rows)
        for a in acts:
            for s in rows:
                if nxt == _ALL:
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


# ---------------------------------------------------------------------------------------
# Parser
# ---------------------------------------------------------------------------------------
class _Parser:
    def __init__(
        self, text: str, name: str, normalize: bool, tol: float, splitter: re.Pattern
    ) -> None:
        self.name = name
        self.normalize = normalize
        self.tol = tol + _SUM_SLACK
        # Comments go first; newlines stay, so line numbers still match the file.
        self.pieces = splitter.split(_COMMENT_RE.sub("", text))
        self.discount: float | None = None
        self.values: str | None = None
        self.names: dict[str, tuple[str, ...]] = {}
        self.maps: dict[str, dict[str, int]] = {}
        self.start: np.ndarray | None = None
        self.first_entry_stmt = 0

    # -- locations --------------------------------------------------------------
    def line_of(self, k: int, extra_newlines: int = 0) -> int:
        """Line of statement k (index of its whole-keyword piece in ``pieces``)."""
        n = self.pieces[0].count("\n")
        for j in range(1, k, 3):
            n += self.pieces[j].count("\n") + self.pieces[j + 2].count("\n")
        return n + 1 + extra_newlines

    def error(self, k: int, detail: str, body_offset: int | None = None) -> PomdpFormatError:
        extra = 0
        if body_offset is not None:
            extra = self.pieces[k].count("\n") + self.pieces[k + 2].count("\n", 0, body_offset)
        return PomdpFormatError(self.line_of(k, extra), detail)

    @staticmethod
    def token_offset(parts: list[str], field: int, index: int) -> int:
        """Offset in a statement's body of token ``index`` of its ':'-separated ``field``."""
        start = sum(len(p) + 1 for p in parts[:field])
        for i, m in enumerate(re.finditer(r"\S+", parts[field])):
            if i == index:
                return start + m.start()
        return start

    # -- name resolution --------------------------------------------------------
    def resolve(self, kind: str, tok: str, k: int, head: str) -> int:
        """Index for a name or number (``_ALL`` for ``*``) of a state/action/observation."""
        i = self.maps[kind].get(tok)
        if i is not None:
            return i
        n = len(self.names[kind])
        if tok.isdigit():
            if int(tok) < n:  # "007"
                return int(tok)
            raise self.error(k, f"{kind} index {tok} out of range 0..{n - 1} in '{head}'")
        raise self.error(k, f"unknown {kind} {tok!r} in '{head}'")

    def one_token(self, field: str, kind: str, k: int, head: str) -> int:
        toks = field.split()
        if len(toks) != 1:
            what = "nothing" if not toks else repr(" ".join(toks))
            raise self.error(k, f"expected one {kind} name or index in '{head}', got {what}")
        return self.resolve(kind, toks[0], k, head)

    @staticmethod
    def expand(i: int, n: int) -> list[int]:
        return list(range(n)) if i == _ALL else [i]

    def numbers(self, toks: Sequence[str], k: int, head: str, what: str) -> np.ndarray:
        try:
            return np.array([float(t) for t in toks], dtype=float)
        except ValueError:
            for t in toks:
                try:
                    float(t)
                except ValueError:
                    raise self.error(k, f"expected {what} after '{head}', got {t!r}") from None
            raise

    def probs(self, toks: Sequence[str], k: int, head: str, n: int, shape: str) -> np.ndarray:
        if len(toks) != n:
            raise self.error(
                k, f"expected {n} probabilities ({shape}) after '{head}', got {len(toks)}"
            )
        vec = self.numbers(toks, k, head, "probabilities")
        if (vec < 0.0).any() or not np.isfinite(vec).all():
            raise self.error(k, f"probabilities after '{head}' must be finite and >= 0")
        return vec

    # -- the whole file -----------------------------------------------------------
    def parse(self) -> POMDP:
        pieces = self.pieces
        if pieces[0].strip():
            tok = pieces[0].split()[0]
            line = pieces[0][: pieces[0].find(tok)].count("\n") + 1
            raise PomdpFormatError(
                line,
                f"unexpected {tok!r}: expected a 'discount:', 'values:', 'states:', "
                "'actions:', 'observations:', 'start:', 'T:', 'O:' or 'R:' statement",
            )
        n_pieces = len(pieces)
        k0 = 1
        # Preamble and start belief: everything up to the first T/O/R entry.
        while k0 < n_pieces and pieces[k0 + 1] not in ("T", "O", "R"):
            self.preamble_statement(k0, pieces[k0 + 1], pieces[k0 + 2])
            k0 += 3
        self.first_entry_stmt = k0
        self.check_preamble(k0)
        S, A, Z = (len(self.names[x]) for x in ("state", "action", "observation"))
        T = _Table(A, S, S)
        Ob = _Table(A, S, Z)
        R = _Rewards(A, S, Z)
        smap, amap, zmap = self.maps["state"], self.maps["action"], self.maps["observation"]
        Trows, Orows = T.rows, Ob.rows
        for k in range(k0, n_pieces, 3):
            kw, body = pieces[k + 1], pieces[k + 2]
            parts = body.split(":")
            # Fast path: the single entries that make up the bulk of large files.
            if len(parts) == 3 and (kw == "T" or kw == "O"):
                tail = parts[2].split()
                if len(tail) == 2:
                    a = amap.get(parts[0].strip())
                    s = smap.get(parts[1].strip())
                    j = (smap if kw == "T" else zmap).get(tail[0])
                    # None: not a plain name/index; _ALL (-1): a wildcard. Both go the long way.
                    if (
                        a is not None
                        and s is not None
                        and j is not None
                        and a >= 0
                        and s >= 0
                        and j >= 0
                    ):
                        try:
                            p = float(tail[1])
                        except ValueError:
                            p = -1.0
                        if 0.0 <= p <= 1.0:
                            rows_a = (Trows if kw == "T" else Orows)[a]
                            r = rows_a[s]
                            if r is None:
                                rows_a[s] = {j: p}
                            else:
                                r[j] = p
                            continue
            elif len(parts) == 4 and kw == "R" and parts[2].strip() == "*":
                # Fast path for the usual reward form R: a : s : * : * v.
                tail = parts[3].split()
                if len(tail) == 2 and tail[0] == "*":
                    a = amap.get(parts[0].strip())
                    s = smap.get(parts[1].strip())
                    if a is not None and s is not None and a >= 0 and s >= 0:
                        try:
                            v = float(tail[1])
                        except ValueError:
                            v = math.nan
                        if math.isfinite(v):
                            R.default[a, s] = v
                            if R.over or R.zbase:
                                R.reset([a], [s])
                            continue
            if kw == "T":
                self.prob_entry(k, "T", parts, T, smap, "state")
            elif kw == "O":
                self.prob_entry(k, "O", parts, Ob, zmap, "observation")
            elif kw == "R":
                self.reward_entry(k, parts, R)
            else:
                raise self.error(k, f"'{kw}:' must come before the first T/O/R entry")
        Tm = tuple(T.to_csr(a) for a in range(A))
        Om = tuple(Ob.to_csr(a) for a in range(A))
        Tm = tuple(self.check_rows("T", a, Tm[a], "from state") for a in range(A))
        Om = tuple(self.check_rows("O", a, Om[a], "in next state") for a in range(A))
        Rm = R.expected(Tm, Om)
        if self.values == "cost":
            Rm = -Rm
        if not np.isfinite(Rm).all():
            s, a = np.argwhere(~np.isfinite(Rm))[0]
            raise PomdpFormatError(
                0,
                f"R for action {self.names['action'][a]!r} in state "
                f"{self.names['state'][s]!r} is not finite",
            )
        b0 = self.start if self.start is not None else np.full(S, 1.0 / S)
        return POMDP(
            states=self.names["state"],
            actions=self.names["action"],
            observations=self.names["observation"],
            T=Tm,
            O=Om,
            R=Rm,
            discount=float(self.discount),  # type: ignore[arg-type]  # checked when parsed
            b0=b0,
            name=self.name,
            values=self.values or "reward",
        )

    # -- preamble -------------------------------------------------------------------
    def preamble_statement(self, k: int, kw: str, body: str) -> None:
        toks = body.split()
        if kw == "discount":
            if len(toks) != 1:
                raise self.error(k, f"expected one number after 'discount:', got {len(toks)}")
            try:
                g = float(toks[0])
            except ValueError:
                raise self.error(
                    k, f"expected a number after 'discount:', got {toks[0]!r}"
                ) from None
            if not 0.0 <= g <= 1.0:
                raise self.error(k, f"discount {g} is not in [0, 1]")
            self.discount = g
        elif kw == "values":
            if len(toks) != 1 or toks[0] not in ("reward", "cost"):
                raise self.error(
                    k, f"expected 'reward' or 'cost' after 'values:', got {body.strip()!r}"
                )
            self.values = toks[0]
        elif kw in ("states", "actions", "observations"):
            self.define(k, kw, toks)
        else:
            self.start_statement(k, kw, toks)

    def check_dense(self, k: int, head: str, entries: int) -> None:
        if entries > MAX_DENSE_ENTRIES:
            raise self.error(
                k, f"'{head} uniform' fills {entries:,} entries (limit {MAX_DENSE_ENTRIES:,})"
            )

    def define(self, k: int, kw: str, toks: list[str]) -> None:
        kind = {"states": "state", "actions": "action", "observations": "observation"}[kw]
        if kind in self.names:
            raise self.error(k, f"'{kw}:' given twice")
        if not toks:
            raise self.error(k, f"expected a count or a list of names after '{kw}:'")
        if len(toks) == 1 and toks[0].isdigit():
            n = int(toks[0])
            if n < 1:
                raise self.error(k, f"'{kw}: {n}': need at least one")
            if n > MAX_COUNTS[kw]:
                raise self.error(
                    k, f"'{kw}: {n}': more than this reader's limit of {MAX_COUNTS[kw]:,}"
                )
            names = tuple(str(i) for i in range(n))
        else:
            for t in toks:
                if not _NAME_RE.match(t):
                    raise self.error(
                        k,
                        f"bad {kind} name {t!r} after '{kw}:' (names start with a letter "
                        "and hold letters, digits, '_' and '-'; or give one count)",
                    )
                if t in _RESERVED:
                    raise self.error(k, f"{kind} name {t!r} after '{kw}:' is a reserved word")
            if len(set(toks)) != len(toks):
                dup = next(t for t in toks if toks.count(t) > 1)
                raise self.error(k, f"{kind} name {dup!r} given twice after '{kw}:'")
            names = tuple(toks)
        m = {name: i for i, name in enumerate(names)}
        m.update((str(i), i) for i in range(len(names)))
        m["*"] = _ALL
        self.names[kind] = names
        self.maps[kind] = m

    def start_statement(self, k: int, kw: str, toks: list[str]) -> None:
        if "state" not in self.names:
            raise self.error(k, f"'{kw.split()[0]}:' must come after 'states:'")
        if self.start is not None:
            raise self.error(k, "start belief given twice")
        S = len(self.names["state"])
        smap = self.maps["state"]
        kw = " ".join(kw.split())
        if kw == "start":
            if toks == ["uniform"]:
                self.start = np.full(S, 1.0 / S)
                return
            if len(toks) == 1 and (S > 1 or toks[0] in smap):
                i = self.resolve("state", toks[0], k, "start:")
                if i == _ALL:
                    raise self.error(
                        k, "expected a state, 'uniform' or probabilities after 'start:'"
                    )
                self.start = np.zeros(S)
                self.start[i] = 1.0
                return
            b = self.probs(toks, k, "start:", S, "one per state")
            total = b.sum()
            if not abs(total - 1.0) <= self.tol:
                raise self.error(k, f"start probabilities sum to {total:.12g}, not 1")
            self.start = b / total if self.normalize else b
            return
        if not toks:
            raise self.error(k, f"expected state names after '{kw}:'")
        idx = sorted({self.resolve("state", t, k, kw + ":") for t in toks})
        if idx[0] == _ALL:
            idx = list(range(S))
        mask = np.zeros(S, dtype=bool)
        mask[idx] = True
        if kw.endswith("exclude"):
            mask = ~mask
        if not mask.any():
            raise self.error(k, f"'{kw}:' leaves no state to start in")
        self.start = mask / mask.sum()

    def check_preamble(self, k: int) -> None:
        where = "before this entry" if k < len(self.pieces) else "and no T/O/R entry follows"
        missing = [kw for kw in ("states", "actions", "observations") if kw[:-1] not in self.names]
        if self.discount is None:
            missing.append("discount")
        if missing:
            raise self.error(k, f"missing '{missing[0]}:' in the preamble (expected {where})")

    # -- T / O / R entries (general path) -----------------------------------------------
    def prob_entry(
        self, k: int, kw: str, parts: list[str], table: _Table, colmap: dict, colkind: str
    ) -> None:
        A = len(self.names["action"])
        S = table.n_rows
        ncol = table.n_cols
        rowkind = "state"  # T rows: start state; O rows: next state
        if len(parts) == 3:
            head = f"{kw}: {parts[0].strip()} : {parts[1].strip()}"
            a = self.one_token(parts[0], "action", k, head)
            s = self.one_token(parts[1], rowkind, k, head)
            tail = parts[2].split()
            head = f"{head} : {tail[0] if tail else ''}"
            if len(tail) != 2:
                off = self.token_offset(parts, 2, 2)
                if len(tail) < 2:
                    raise self.error(k, f"expected '<{colkind}> <probability>' in '{head}'")
                raise self.error(
                    k,
                    f"expected one probability after '{head}', got {len(tail) - 1} numbers "
                    f"(next: {tail[2]!r})",
                    off,
                )
            j = self.resolve(colkind, tail[0], k, head)
            p = self.numbers(tail[1:], k, head, "a probability")[0]
            if not 0.0 <= p <= 1.0 + self.tol:
                raise self.error(k, f"probability {tail[1]} after '{head}' is not in [0, 1]")
            table.set_entry(self.expand(a, A), self.expand(s, S), j, float(p))
        elif len(parts) == 2:
            toks = parts[1].split()
            head = f"{kw}: {parts[0].strip()} : {toks[0] if toks else ''}"
            a = self.one_token(parts[0], "action", k, head)
            if not toks:
                raise self.error(k, f"expected a {rowkind} in '{head}'")
            s = self.resolve(rowkind, toks[0], k, head)
            rest = toks[1:]
            if rest == ["uniform"]:
                self.check_dense(k, head, len(self.expand(a, A)) * len(self.expand(s, S)) * ncol)
                vec = np.full(ncol, 1.0 / ncol)
            elif rest == ["reset"]:
                raise self.error(k, f"'reset' after '{head}' is not supported")
            else:
                vec = self.probs(rest, k, head, ncol, f"one per {colkind}")
            table.set_row(self.expand(a, A), self.expand(s, S), vec)
        elif len(parts) == 1:
            toks = parts[0].split()
            if not toks:
                raise self.error(k, f"expected an action after '{kw}:'")
            head = f"{kw}: {toks[0]}"
            a = self.resolve("action", toks[0], k, head)
            rest = toks[1:]
            acts = self.expand(a, A)
            if rest == ["uniform"]:
                self.check_dense(k, head, len(acts) * S * ncol)
                table.set_row(acts, range(S), np.full(ncol, 1.0 / ncol))
            elif rest == ["identity"]:
                if kw != "T":
                    raise self.error(k, f"'identity' after '{head}' is only defined for T")
                table.set_identity(acts)
            else:
                mat = self.probs(rest, k, head, S * ncol, f"{S} x {ncol} matrix")
                mat = mat.reshape(S, ncol)
                for a_ in acts:
                    table.rows[a_] = list(mat.copy())
        else:
            raise self.error(k, f"too many ':' in a '{kw}:' entry (at most 3)")

    def reward_entry(self, k: int, parts: list[str], R: _Rewards) -> None:
        A, S, Z = R.A, R.S, R.Z
        if len(parts) < 2 or len(parts) > 4:
            raise self.error(
                k,
                f"expected 'R: <action> : <state> [: <next-state> [: <observation>]]', got "
                f"{len(parts) - 1} ':'-separated fields",
            )
        head = f"R: {' : '.join(p.strip() for p in parts[:-1])}"
        a = self.one_token(parts[0], "action", k, head)
        acts = self.expand(a, A)
        if len(parts) == 2:  # R: a : s  + matrix over (s', z)
            toks = parts[1].split()
            if not toks:
                raise self.error(k, f"expected a state in '{head}'")
            head = f"{head} : {toks[0]}"
            s = self.resolve("state", toks[0], k, head)
            mat = self.numbers(toks[1:], k, head, "rewards")
            if mat.size != S * Z:
                raise self.error(
                    k, f"expected {S * Z} rewards ({S} x {Z} matrix) after '{head}', got {mat.size}"
                )
            self.check_finite(mat, k, head)
            R.set_matrix(acts, self.expand(s, S), mat.reshape(S, Z))
            return
        s = self.one_token(parts[1], "state", k, head)
        rows = self.expand(s, S)
        if len(parts) == 3:  # R: a : s : s'  + row over z
            toks = parts[2].split()
            if not toks:
                raise self.error(k, f"expected a next state in '{head}'")
            head = f"{head} : {toks[0]}"
            n = self.resolve("state", toks[0], k, head)
            vec = self.numbers(toks[1:], k, head, "rewards")
            if vec.size != Z:
                raise self.error(
                    k, f"expected {Z} rewards (one per observation) after '{head}', got {vec.size}"
                )
            self.check_finite(vec, k, head)
            R.set_row(acts, rows, n, vec)
            return
        n = self.one_token(parts[2], "state", k, head)
        toks = parts[3].split()
        if len(toks) != 2:
            detail = f"expected '<observation> <reward>' after '{head} :', got {len(toks)} tokens"
            raise self.error(k, detail)
        head = f"{head} : {toks[0]}"
        z = self.resolve("observation", toks[0], k, head)
        v = self.numbers(toks[1:], k, head, "a reward")
        self.check_finite(v, k, head)
        R.set_value(acts, rows, n, z, float(v[0]))

    def check_finite(self, v: np.ndarray, k: int, head: str) -> None:
        if not np.isfinite(v).all():
            raise self.error(k, f"non-finite reward after '{head}'")

    # -- final checks ------------------------------------------------------------------
    def check_rows(self, kw: str, a: int, M: sp.csr_matrix, what: str) -> sp.csr_matrix:
        """Every row must sum to 1 within PROB_SUM_TOL; rows are then renormalised exactly."""
        sums = np.asarray(M.sum(axis=1)).ravel()
        bad = np.flatnonzero(~(np.abs(sums - 1.0) <= self.tol))
        if bad.size:
            i = int(bad[0])
            action, state = self.names["action"][a], self.names["state"][i]
            k = self.last_statement(kw, a, i)
            detail = (
                f"{kw} row for action {action!r} {what} {state!r} sums to {sums[i]:.12g}, "
                f"not 1 (tolerance {self.tol:.3g})"
            )
            if k is None:
                detail += f"; no '{kw}:' entry sets it"
                text = "".join(p for j, p in enumerate(self.pieces) if j % 3 != 2)
                raise PomdpFormatError(len(text.splitlines()), detail)
            raise self.error(k, detail)
        if self.normalize and np.any(sums != 1.0):
            M = M.copy()
            M.data /= np.repeat(sums, np.diff(M.indptr))
        return M

    def last_statement(self, kw: str, a: int, i: int) -> int | None:
        """The last T/O statement that writes row i of action a (for error messages)."""
        amap, smap = self.maps["action"], self.maps["state"]
        for k in range(len(self.pieces) - 3, self.first_entry_stmt - 1, -3):
            if self.pieces[k + 1] != kw:
                continue
            parts = self.pieces[k + 2].split(":")
            first = parts[0].split()
            if not first or amap.get(first[0]) not in (a, _ALL):
                continue
            if len(parts) == 1:
                return k
            second = parts[1].split()
            if second and smap.get(second[0]) in (i, _ALL):
                return k
        return None


# ---------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------
def parse_pomdp(
    text: str, name: str = "pomdp", *, normalize: bool = True, tol: float = PROB_SUM_TOL
) -> POMDP:
    """Parse the text of a ``.pomdp`` file.

    Rows of T and O and the start belief must sum to 1 within ``PROB_SUM_TOL`` (1e-6,
    the precision of the published files); with ``normalize`` they are then rescaled to
    sum to 1 exactly, so the model passes ``POMDP.validate()`` at its default tolerance.

    Args:
        text: the whole file.
        name: the model's name (``POMDP.name``).
        normalize: rescale rows that are within tolerance to sum to 1 exactly.
        tol: how far from 1 a row may sum.

    Returns:
        The flat POMDP, with ``R`` the expected immediate reward R(s, a) (negated when the
        file says ``values: cost``; ``POMDP.values`` records which it said).

    Raises:
        PomdpFormatError: the text does not follow the format; the message starts with
            ``line N:`` and says what was expected.
    """
    try:
        return _Parser(text, name, normalize, tol, _STMT_AT_LINE_START_RE).parse()
    except PomdpFormatError:
        pass
    # Either a real error, or statements that do not start a line: split at every keyword.
    return _Parser(text, name, normalize, tol, _STMT_RE).parse()


def read_pomdp(
    path_or_text: str | os.PathLike | TextIO, *, normalize: bool = True, tol: float = PROB_SUM_TOL
) -> POMDP:
    """Read a ``.pomdp`` model from a file path, an open text file, or the text itself.

    A ``str`` holding a newline is taken as the text; any other ``str`` or path-like as a
    file name.

    Args:
        path_or_text: path, open text file, or the file's contents.
        normalize, tol: see :func:`parse_pomdp`.

    Returns:
        The flat POMDP, named after the file's stem when read from a path.

    Raises:
        PomdpFormatError: the contents do not follow the format.
        OSError: the file cannot be read.
    """
    if hasattr(path_or_text, "read"):
        name = Path(getattr(path_or_text, "name", "pomdp")).stem or "pomdp"
        return parse_pomdp(path_or_text.read(), name=name, normalize=normalize, tol=tol)
    if isinstance(path_or_text, str) and "\n" in path_or_text:
        return parse_pomdp(path_or_text, normalize=normalize, tol=tol)
    path = Path(path_or_text)
    return parse_pomdp(read_text_capped(path), name=path.stem, normalize=normalize, tol=tol)


def read_text_capped(path: str | os.PathLike, max_bytes: int = MAX_BYTES) -> str:
    """The text of a model file, refusing directories and files over ``max_bytes``.

    Raises:
        PomdpFormatError: a directory, or more than ``max_bytes`` bytes (a device such
            as /dev/zero never ends; it is cut off there).
        FileNotFoundError: no such file.
    """
    from stack.config import open_regular

    path = Path(path)
    if path.is_dir():
        raise PomdpFormatError(0, f"{path} is a directory, not a model file")
    try:  # a regular file only: a named pipe would block, a device never end
        with open_regular(path, sys.maxsize) as f:
            data = f.read(max_bytes + 1)
    except ValueError as exc:
        raise PomdpFormatError(0, str(exc)) from None
    if len(data) > max_bytes:
        raise PomdpFormatError(0, f"{path}: larger than this reader's limit of {max_bytes:,} bytes")
    return data.decode("utf-8", errors="replace")


def _fmt(x: float) -> str:
    """Shortest round-trip repr, always with a decimal point (older C lexers need it)."""
    r = repr(float(x))
    if "e" in r:
        mant, exp = r.split("e")
        if "." not in mant:
            mant += ".0"
        return f"{mant}e{exp}"
    return r


def _sanitize(names: Sequence[str], prefix: str) -> list[str]:
    """Names made into valid, distinct, non-reserved tokens (unchanged when already so).

    Names that are just their indices ("0", "1", ...: a file that gave a count) stay
    indices; the caller then writes the count.
    """
    if all(n == str(i) for i, n in enumerate(names)):
        return [str(i) for i in range(len(names))]
    out: list[str] = []
    seen: set[str] = set()
    for raw in names:
        t = re.sub(r"[^A-Za-z0-9_\-]", "_", str(raw))
        if not t or not t[0].isalpha():
            t = prefix + t
        if t in _RESERVED:
            t = t + "_"
        base, n = t, 2
        while t in seen:
            t, n = f"{base}_{n}", n + 1
        seen.add(t)
        out.append(t)
    return out


def format_pomdp(pomdp: POMDP) -> str:
    """The ``.pomdp`` text of a model.

    T and O are written as single entries for their non-zeros, R as
    ``R: a : s : * : * v`` for its non-zeros, floats with ``repr`` precision so that
    reading the text back gives the same model. Names that are not valid tokens are
    sanitised (invalid characters to ``_``, a letter prefixed, duplicates numbered).

    Args:
        pomdp: the model.

    Returns:
        The file's text.

    Raises:
        ValueError: the model has non-finite numbers.
    """
    if not np.isfinite(pomdp.R).all() or not np.isfinite(pomdp.b0).all():
        raise ValueError("cannot write a POMDP with non-finite R or b0")
    S = _sanitize(pomdp.states, "s")
    A = _sanitize(pomdp.actions, "a")
    Z = _sanitize(pomdp.observations, "o")
    cost = pomdp.values == "cost"
    out = io.StringIO()
    w = out.write
    w(f"# {pomdp.name}: {len(S)} states, {len(A)} actions, {len(Z)} observations\n")
    w(f"discount: {_fmt(pomdp.discount)}\n")
    w(f"values: {'cost' if cost else 'reward'}\n")
    for kw, names in (("states", S), ("actions", A), ("observations", Z)):
        w(f"{kw}: {len(names) if names[0] == '0' else ' '.join(names)}\n")
    w(f"start: {' '.join(_fmt(p) for p in pomdp.b0)}\n\n")
    for kw, mats, cols in (("T", pomdp.T, S), ("O", pomdp.O, Z)):
        for a, M in enumerate(mats):
            M = sp.csr_matrix(M)
            M.sort_indices()
            rows = np.repeat(np.arange(M.shape[0]), np.diff(M.indptr))
            an = A[a]
            w(
                "".join(
                    f"{kw}: {an} : {S[i]} : {cols[j]} {_fmt(p)}\n"
                    for i, j, p in zip(
                        rows.tolist(), M.indices.tolist(), M.data.tolist(), strict=True
                    )
                    if p != 0.0
                )
            )
    w("\n")
    R = -pomdp.R if cost else pomdp.R
    for a in range(len(A)):
        for s in np.flatnonzero(R[:, a]).tolist():
            w(f"R: {A[a]} : {S[s]} : * : * {_fmt(R[s, a])}\n")
    return out.getvalue()


def write_pomdp(pomdp: POMDP, path_or_file: str | os.PathLike | TextIO) -> None:
    """Write a model as a ``.pomdp`` file (see :func:`format_pomdp`).

    Args:
        pomdp: the model.
        path_or_file: a path, or an open text file to write to.

    Raises:
        ValueError: the model has non-finite numbers.
        OSError: the file cannot be written.
    """
    text = format_pomdp(pomdp)
    if hasattr(path_or_file, "write"):
        path_or_file.write(text)
        return
    write_text(path_or_file, text)
