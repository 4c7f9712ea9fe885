"""The ``.pomdp`` writer: a flat :class:`~stack.planning.pomdp.POMDP` as Cassandra's text.

T and O as single entries for their non-zeros, R as ``R: a : s : * : * v``, floats
with ``repr`` precision, so that reading the text back
(:func:`stack.planning.pomdp_format.parser.parse_pomdp`) gives the same model; names
that the reader would refuse are made valid (:data:`~stack.planning.pomdp_format.syntax.RESERVED`
words, invalid characters, duplicates).
"""

from __future__ import annotations

import io
import os
import re
from collections.abc import Sequence
from typing import TextIO

import numpy as np
import scipy.sparse as sp

from stack.config import write_text
from stack.planning.pomdp import POMDP
from stack.planning.pomdp_format.syntax import RESERVED


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
        if t in RESERVED:
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
