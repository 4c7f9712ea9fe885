"""The vocabulary of the ``.pomdp`` format shared by its reader and writer.

The error every reader function raises (:class:`PomdpFormatError`, with the line it
found the problem at), the size limits a file is checked against before anything is
allocated, the tolerance of a probability row's sum, and the regular expressions that
split a text into statements and check names (the writer makes names follow the same
rules, see :mod:`stack.planning.pomdp_format.writer`).
"""

from __future__ import annotations

import re

# Sizes refused before anything is allocated (a file may declare 10^8 states): the
# largest public files have 12,545 states; these limits leave room and fit in memory.
MAX_COUNTS = {"states": 200_000, "actions": 10_000, "observations": 200_000}
MAX_DENSE_ENTRIES = 50_000_000  # rewards (A x S) and any table given in full
MAX_BYTES = 256 * 1024 * 1024  # a .pomdp text larger than this is refused (/dev/zero)

PROB_SUM_TOL = 1e-6  # a row of T, O or the start belief must sum to 1 within this
# Rows written with 6 decimals (0.166667 x 3 + 0.5, TagAvoid) sum to 1 + 1e-6 exactly in
# decimal but a hair above it in binary floating point: allow for that rounding.
SUM_SLACK = 1e-12

ALL = -1  # a resolved '*'

# A statement starts at a keyword that stands alone (whitespace or start of text before
# it) and is followed by a colon. The outer group keeps the whole match so that newline
# counts (line numbers) stay exact; the inner group is the keyword.
KEYWORDS = (
    r"((discount|values|states|actions|observations"
    r"|start(?:[ \t\r\n]+(?:include|exclude))?|T|O|R)[ \t\r\n]*:)"
)
STMT_RE = re.compile(r"(?<!\S)" + KEYWORDS)
# Real files start every statement on its own line; splitting only there is 2-3x faster.
# A keyword hidden mid-line always leaves a stray ':' or token in some body, which is a
# format error, and on any error the text is split again with STMT_RE (see parse_pomdp).
STMT_AT_LINE_START_RE = re.compile(r"(?m)^[ \t]*" + KEYWORDS)
COMMENT_RE = re.compile(r"#[^\n]*")
NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_\-]*\Z")
RESERVED = frozenset(
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
