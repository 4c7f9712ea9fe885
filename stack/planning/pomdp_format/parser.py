"""The ``.pomdp`` reader: the T, O and R entries, the model, and the public functions.

:class:`Parser` goes through the statements after the preamble (read by its base,
:class:`stack.planning.pomdp_format.preamble.PreambleParser`), fills the tables of
:mod:`stack.planning.pomdp_format.tables`, checks that every row of T and O sums to 1
and builds the flat :class:`~stack.planning.pomdp.POMDP`. Single entries
``T: a : s : s' p`` (the bulk of large files) and ``R: a : s : * : * v`` take a short
fast path in :meth:`Parser.parse`; every other shape goes through :meth:`prob_entry`
or :meth:`reward_entry`, which give each mistake its own message.

:func:`parse_pomdp`, :func:`read_pomdp` and :func:`read_text_capped` are the functions
the rest of the project calls (through :mod:`stack.planning.pomdp_format`).
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path
from typing import TextIO

import numpy as np
import scipy.sparse as sp

from stack.planning.pomdp import POMDP
from stack.planning.pomdp_format.preamble import PreambleParser
from stack.planning.pomdp_format.syntax import (
    ALL,
    MAX_BYTES,
    PROB_SUM_TOL,
    STMT_AT_LINE_START_RE,
    STMT_RE,
    PomdpFormatError,
)
from stack.planning.pomdp_format.tables import RewardTable, RowTable


class Parser(PreambleParser):
    """The whole file: :meth:`parse` returns the model or raises
    :class:`PomdpFormatError` at the first statement that breaks the format."""

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
        T = RowTable(A, S, S)
        Ob = RowTable(A, S, Z)
        R = RewardTable(A, S, Z)
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
                    # None: not a plain name/index; ALL (-1): a wildcard. Both go the long way.
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

    # -- T / O / R entries (general path) -----------------------------------------------
    def prob_entry(
        self, k: int, kw: str, parts: list[str], table: RowTable, colmap: dict, colkind: str
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

    def reward_entry(self, k: int, parts: list[str], R: RewardTable) -> None:
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
            s, mat = self.state_rewards(k, parts[1], head, "state", S * Z, f"{S} x {Z} matrix")
            R.set_matrix(acts, self.expand(s, S), mat.reshape(S, Z))
            return
        s = self.one_token(parts[1], "state", k, head)
        rows = self.expand(s, S)
        if len(parts) == 3:  # R: a : s : s'  + row over z
            n, vec = self.state_rewards(k, parts[2], head, "next state", Z, "one per observation")
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

    def state_rewards(
        self, k: int, field: str, head: str, what: str, size: int, layout: str
    ) -> tuple[int, np.ndarray]:
        """The ``<state> <reward> ...`` field of an ``R:`` entry: the state (the
        entry's ``what``) and its ``size`` finite rewards (``layout`` in the error)."""
        toks = field.split()
        if not toks:
            raise self.error(k, f"expected a {what} in '{head}'")
        head = f"{head} : {toks[0]}"
        s = self.resolve("state", toks[0], k, head)
        values = self.numbers(toks[1:], k, head, "rewards")
        if values.size != size:
            raise self.error(
                k, f"expected {size} rewards ({layout}) after '{head}', got {values.size}"
            )
        self.check_finite(values, k, head)
        return s, values

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
            if not first or amap.get(first[0]) not in (a, ALL):
                continue
            if len(parts) == 1:
                return k
            second = parts[1].split()
            if second and smap.get(second[0]) in (i, ALL):
                return k
        return None


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
        return Parser(text, name, normalize, tol, STMT_AT_LINE_START_RE).parse()
    except PomdpFormatError:
        pass
    # Either a real error, or statements that do not start a line: split at every keyword.
    return Parser(text, name, normalize, tol, STMT_RE).parse()


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
