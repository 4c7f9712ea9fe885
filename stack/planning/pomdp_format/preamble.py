"""The first half of the ``.pomdp`` reader: statements, names and the preamble.

:class:`PreambleParser` splits a text into statements (keyword pieces, see
:mod:`stack.planning.pomdp_format.syntax`), knows where each starts (for the ``line N:``
of error messages), resolves state, action and observation names or indices, and reads
the preamble (``discount:``, ``values:``, ``states:``, ``actions:``, ``observations:``)
and the start belief. :class:`stack.planning.pomdp_format.parser.Parser` adds the
``T:``, ``O:`` and ``R:`` entries and builds the model.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from stack.planning.pomdp_format.syntax import (
    ALL,
    COMMENT_RE,
    MAX_COUNTS,
    MAX_DENSE_ENTRIES,
    NAME_RE,
    RESERVED,
    SUM_SLACK,
    PomdpFormatError,
)


class PreambleParser:
    """A ``.pomdp`` text split into statements, with its preamble read by
    :meth:`preamble_statement` (the parser proper is
    :class:`stack.planning.pomdp_format.parser.Parser`)."""

    def __init__(
        self, text: str, name: str, normalize: bool, tol: float, splitter: re.Pattern
    ) -> None:
        self.name = name
        self.normalize = normalize
        self.tol = tol + SUM_SLACK
        # Comments go first; newlines stay, so line numbers still match the file.
        self.pieces = splitter.split(COMMENT_RE.sub("", text))
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
        """Index for a name or number (``ALL`` for ``*``) of a state/action/observation."""
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
        return list(range(n)) if i == ALL else [i]

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
                if not NAME_RE.match(t):
                    raise self.error(
                        k,
                        f"bad {kind} name {t!r} after '{kw}:' (names start with a letter "
                        "and hold letters, digits, '_' and '-'; or give one count)",
                    )
                if t in RESERVED:
                    raise self.error(k, f"{kind} name {t!r} after '{kw}:' is a reserved word")
            if len(set(toks)) != len(toks):
                dup = next(t for t in toks if toks.count(t) > 1)
                raise self.error(k, f"{kind} name {dup!r} given twice after '{kw}:'")
            names = tuple(toks)
        m = {name: i for i, name in enumerate(names)}
        m.update((str(i), i) for i in range(len(names)))
        m["*"] = ALL
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
                if i == ALL:
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
        if idx[0] == ALL:
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
