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

The package's modules, in reading order: ``syntax.py`` (the error, the limits, the
statement and name patterns), ``tables.py`` (T, O and R built entry by entry),
``preamble.py`` (statements, names, the preamble and start belief), ``parser.py``
(the T/O/R entries, the model; :func:`parse_pomdp`, :func:`read_pomdp`) and
``writer.py`` (:func:`format_pomdp`, :func:`write_pomdp`). Import from the package.
"""

from __future__ import annotations

from stack.planning.pomdp_format.parser import parse_pomdp, read_pomdp, read_text_capped
from stack.planning.pomdp_format.syntax import PROB_SUM_TOL, PomdpFormatError
from stack.planning.pomdp_format.writer import format_pomdp, write_pomdp

__all__ = [
    "PROB_SUM_TOL",
    "PomdpFormatError",
    "format_pomdp",
    "parse_pomdp",
    "read_pomdp",
    "read_text_capped",
    "write_pomdp",
]
