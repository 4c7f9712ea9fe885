"""Reader for SARSOP's factored ``.pomdpx`` XML, flattened into a :class:`POMDP`.

A ``.pomdpx`` file names state variables (each with a previous and a current name,
and ``fullyObs`` when the agent sees it), observation variables, one action
variable and reward variables, and gives every variable's conditional table
(``<CondProb>``, or ``<Func>`` for rewards) as ``<Entry>`` rows: an ``<Instance>``
with one token per parent and the variable itself (a value name, ``*`` for every
value, ``-`` for "the values follow in order") and a ``<ProbTable>`` or
``<ValueTable>`` (numbers, ``identity`` or ``uniform``).

The flat model's states are the joint values of the state variables (the first
declared varies slowest); its observations the joint values of the fully observed
state variables (after the step) and the observation variables, so that a fully
observed variable is observed exactly, as SARSOP's MOMDP treats it.

Flattening is sparse: each variable's table stays dense over its own parents (at most
``MAX_DENSE`` entries), and for every action the flat T[a] (and O[a]) is built row by
row as the Kronecker product of the variables' distributions given that row, over
their non-zeros only -- never an S x S array. RockSample_7_8.pomdpx (12,800 flat
states) reads in about a second. The flat model is limited to ``MAX_FLAT_STATES``
states and ``MAX_FLAT_NONZEROS`` non-zeros in T and O.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import reduce
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from stack.planning.pomdp import POMDP
from stack.planning.pomdp_format import PomdpFormatError, read_text_capped

MAX_FLAT_STATES = 2_000_000
MAX_DENSE = 60_000_000  # entries of one variable's table (over its parents and itself)
MAX_FLAT_NONZEROS = 80_000_000  # non-zeros of the flat T and O together (about 1.3 GB)


class PomdpxError(PomdpFormatError):
    """A ``.pomdpx`` file this reader cannot turn into a flat model."""

    def __init__(self, detail: str) -> None:
        super().__init__(0, detail)


@dataclass
class _Var:
    name: str
    values: list[str]
    numbered: bool = False  # <NumValues>: tokens s3, a3, o3 (any prefix) mean value 3

    def index(self, token: str) -> int:
        try:
            return self.values.index(token)
        except ValueError:
            pass
        m = re.fullmatch(r"[A-Za-z_]*(\d+)", token) if self.numbered else None
        if m and int(m.group(1)) < len(self.values):
            return int(m.group(1))
        raise PomdpxError(f"{token!r} is not a value of {self.name!r}")


def _values(el: ET.Element, what: str) -> list[str]:
    enum = el.find("ValueEnum")
    if enum is not None and enum.text:
        return enum.text.split()
    num = el.find("NumValues")
    if num is not None and num.text:
        n = int(num.text)
        if not 0 < n <= MAX_FLAT_STATES:
            raise PomdpxError(f"{what}: {n} values (this reader takes 1..{MAX_FLAT_STATES})")
        return [f"s{i}" for i in range(n)]
    raise PomdpxError(f"{what} has neither <ValueEnum> nor <NumValues>")


def _table(el: ET.Element, variables: dict[str, _Var], value_tag: str) -> tuple[list, np.ndarray]:
    """A <CondProb> or <Func> as (axis names, dense array over parents..., var)."""
    var = (el.findtext("Var") or "").strip()
    parents = (el.findtext("Parent") or "null").split()
    parents = [] if parents == ["null"] else parents
    # a reward <Func>'s instance names only its parents; a <CondProb>'s ends in its variable
    order = parents if value_tag == "ValueTable" else parents + [var]
    for v in order:
        if v not in variables:
            raise PomdpxError(f"<{el.tag}> of {var!r} names an unknown variable {v!r}")
    shape = [len(variables[v].values) for v in order]
    if int(np.prod(shape)) > MAX_DENSE:
        raise PomdpxError(f"the table of {var!r} would hold {int(np.prod(shape)):,} entries")
    arr = np.zeros(shape)
    param = el.find("Parameter")
    if param is None:
        raise PomdpxError(f"<{el.tag}> of {var!r} has no <Parameter>")
    if param.get("type", "TBL").strip() != "TBL":
        raise PomdpxError(f"<{el.tag}> of {var!r}: only TBL parameters are supported")
    for entry in param.findall("Entry"):
        inst = (entry.findtext("Instance") or "").split()
        vals = (entry.findtext(value_tag) or "").split()
        if len(inst) != len(order):
            raise PomdpxError(
                f"<Instance>{' '.join(inst)}</Instance> of {var!r}: {len(inst)} tokens for "
                f"{len(order)} variables ({' '.join(order)})"
            )
        index: list = []
        dash: list[int] = []
        star: list[int] = []
        for axis, (tok, v) in enumerate(zip(inst, order, strict=True)):
            if tok == "*":
                index.append(slice(None))
                star.append(axis)
            elif tok == "-":
                index.append(slice(None))
                dash.append(axis)
            else:
                index.append(variables[v].index(tok))
        sub_shape = [shape[a] for a in sorted(star + dash)]
        if vals == ["identity"]:
            if len(dash) != 2 or shape[dash[0]] != shape[dash[1]]:
                raise PomdpxError(f"'identity' for {var!r} needs two '-' of the same size")
            block = np.eye(shape[dash[0]])
        elif vals == ["uniform"] and value_tag == "ProbTable":
            block = np.full([shape[a] for a in dash], 1.0 / shape[-1])
        else:
            try:
                nums = np.array(vals, dtype=float)
            except ValueError:
                raise PomdpxError(f"non-numeric <{value_tag}> for {var!r}") from None
            want = int(np.prod([shape[a] for a in dash])) if dash else 1
            if nums.size not in (1, want):
                raise PomdpxError(
                    f"<{value_tag}> for {var!r} ({' '.join(inst)}) has {nums.size} numbers, "
                    f"expected {want}"
                )
            block = nums.reshape([shape[a] for a in dash]) if nums.size == want else nums[0]
        if not np.all(np.isfinite(block)):
            raise PomdpxError(f"non-finite <{value_tag}> for {var!r}")
        # '*' axes repeat the block: give them length-1 axes in the block's layout
        block = np.asarray(block, dtype=float)
        expand = [shape[a] if a in dash else 1 for a in sorted(star + dash)]
        arr[tuple(index)] = np.broadcast_to(block.reshape(expand), sub_shape)
    return order, arr


class _Budget:
    """Non-zeros of the flat T and O so far, refused past ``MAX_FLAT_NONZEROS``."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.used = 0

    def take(self, n: int, what: str) -> None:
        self.used += n
        if self.used > MAX_FLAT_NONZEROS:
            raise PomdpxError(
                f"{self.path}: {what} bring the flat model to {self.used:,} non-zeros "
                f"(this reader's limit is {MAX_FLAT_NONZEROS:,})"
            )


def _cond_probs(
    tables: ET.Element | None,
    variables: dict[str, _Var],
    path: str | os.PathLike,
    children: list[str],
    parents: list[str],
    kind: str,
    naming: str,
) -> dict[str, tuple[list[str], np.ndarray]]:
    """The ``<CondProb>`` tables under ``tables``, one per variable of ``children``,
    each over ``parents`` only, by child (``kind`` and ``naming`` word the errors:
    "two {kind} tables", "{naming} 'x' has unsupported parents")."""
    cpts: dict[str, tuple[list[str], np.ndarray]] = {}
    for cp in [] if tables is None else tables.findall("CondProb"):
        order, arr = _table(cp, variables, "ProbTable")
        if order[-1] not in children or any(p not in parents for p in order[:-1]):
            raise PomdpxError(f"{path}: {naming} {order[-1]!r} has unsupported parents")
        if order[-1] in cpts:
            raise PomdpxError(f"{path}: two {kind} tables for {order[-1]!r}")
        cpts[order[-1]] = (order, arr)
    if set(cpts) != set(children):
        raise PomdpxError(f"{path}: no {kind} table for {sorted(set(children) - set(cpts))}")
    return cpts


def _fix_action(
    order: list[str], arr: np.ndarray, act: str, a: int
) -> tuple[np.ndarray, list[str]]:
    """``arr`` (over ``order``) at action ``a``, and the axes left."""
    if act not in order:
        return arr, list(order)
    i = order.index(act)
    return np.take(arr, a, axis=i), order[:i] + order[i + 1 :]


def _factor_rows(
    order: list[str], arr: np.ndarray, act: str, a: int, vals: dict[str, np.ndarray], S: int
) -> sp.csr_matrix:
    """One variable's distribution given (a, flat state) as a sparse (S, n_values) matrix.

    ``order`` is the table's parents then the variable; ``vals[p]`` the value of parent
    ``p`` in each flat state. The table's rows (one per parent configuration) are made
    sparse once and picked per flat state, so the cost is the rows' non-zeros.
    """
    sub, rest = _fix_action(order, arr, act, a)
    parents = rest[:-1]
    rows = sp.csr_matrix(sub.reshape(-1, sub.shape[-1]))
    if not parents:
        pick = np.zeros(S, dtype=np.int64)
    else:
        pick = np.ravel_multi_index(tuple(vals[p] for p in parents), sub.shape[:-1])
    return rows[pick]


def _kron_nnz(factors: list[sp.csr_matrix]) -> int:
    """Non-zeros of the row-wise Kronecker product of ``factors``."""
    per_row = np.ones(factors[0].shape[0], dtype=np.int64)
    for M in factors:
        per_row *= np.diff(M.indptr)
    return int(per_row.sum())


def _rowwise_kron(A: sp.csr_matrix, B: sp.csr_matrix) -> sp.csr_matrix:
    """Row s of the result is kron(A[s], B[s]): columns j * B.shape[1] + l."""
    ca, cb = np.diff(A.indptr), np.diff(B.indptr)
    row_a = np.repeat(np.arange(A.shape[0]), ca)
    reps = cb[row_a]  # each A entry pairs with every entry of B's same row
    ea = np.repeat(np.arange(A.nnz), reps)
    offset = np.arange(ea.size) - np.repeat(np.cumsum(reps) - reps, reps)
    eb = np.repeat(B.indptr[:-1][row_a], reps) + offset
    data = A.data[ea] * B.data[eb]
    cols = A.indices[ea].astype(np.int64) * B.shape[1] + B.indices[eb]
    indptr = np.zeros(A.shape[0] + 1, dtype=np.int64)
    np.cumsum(ca * cb, out=indptr[1:])
    out = sp.csr_matrix((data, cols, indptr), shape=(A.shape[0], A.shape[1] * B.shape[1]))
    out.eliminate_zeros()
    return out


def read_pomdpx(path: str | os.PathLike) -> POMDP:
    """Read and flatten a ``.pomdpx`` file.

    Raises:
        PomdpxError: the file is not a ``.pomdpx`` model this reader supports (the
            message says what), or its flat model would be too large.
    """
    path = Path(path)
    text = read_text_capped(path)
    try:
        root = ET.fromstring(text.encode("utf-8"))
    except ET.ParseError as exc:
        raise PomdpxError(f"{path}: not XML ({exc})") from None
    try:
        discount = float(root.findtext("Discount") or "")
    except (TypeError, ValueError):
        raise PomdpxError(f"{path}: no numeric <Discount>") from None
    varel = root.find("Variable")
    if varel is None:
        raise PomdpxError(f"{path}: no <Variable> section")
    variables: dict[str, _Var] = {}
    prev: list[str] = []
    curr: list[str] = []
    fully: list[bool] = []

    def name(el: ET.Element, attr: str) -> str:
        value = el.get(attr)
        if not value:
            raise PomdpxError(f"{path}: a <{el.tag}> without {attr}")
        return value

    for sv in varel.findall("StateVar"):
        vals = _values(sv, f"state variable {sv.get('vnameCurr')}")
        p, c = name(sv, "vnamePrev"), name(sv, "vnameCurr")
        num = sv.find("ValueEnum") is None
        variables[p], variables[c] = _Var(p, vals, num), _Var(c, vals, num)
        prev.append(p)
        curr.append(c)
        fully.append(sv.get("fullyObs", "false").strip().lower() == "true")
    obs: list[str] = []
    for ov in varel.findall("ObsVar"):
        num = ov.find("ValueEnum") is None
        vname = name(ov, "vname")
        variables[vname] = _Var(vname, _values(ov, "observation"), num)
        obs.append(vname)
    acts = varel.findall("ActionVar")
    if len(acts) != 1:
        raise PomdpxError(f"{path}: {len(acts)} action variables (this reader takes one)")
    act = name(acts[0], "vname")
    variables[act] = _Var(
        act, _values(acts[0], "action variable"), acts[0].find("ValueEnum") is None
    )
    if not prev:
        raise PomdpxError(f"{path}: no state variables")
    sizes = [len(variables[v].values) for v in prev]
    S = int(np.prod(sizes, dtype=object))
    A = len(variables[act].values)
    if S > MAX_FLAT_STATES:
        raise PomdpxError(
            f"{path}: {S:,} flat states is more than this reader flattens ({MAX_FLAT_STATES:,})"
        )
    # every flat state's value of each state variable (previous and current names alike)
    strides = np.cumprod([1, *sizes[::-1]])[-2::-1]
    flat = np.arange(S, dtype=np.int64)
    value_of: dict[str, np.ndarray] = {}
    for p, c, n, stride in zip(prev, curr, sizes, strides, strict=True):
        value_of[p] = value_of[c] = (flat // int(stride)) % n
    del flat
    budget = _Budget(path)

    # transitions: T[a] row s is the product of each current variable's distribution
    # given (a, s), multiplied out row by row over the non-zeros only
    tables = root.find("StateTransitionFunction")
    if tables is None:
        raise PomdpxError(f"{path}: no <StateTransitionFunction>")
    cpts = _cond_probs(tables, variables, path, curr, [act, *prev], "transition", "transition of")
    T = []
    for a in range(A):
        factors = [_factor_rows(*cpts[c], act, a, value_of, S) for c in curr]
        budget.take(_kron_nnz(factors), f"the transitions of action {a}")
        T.append(reduce(_rowwise_kron, factors))

    # observations over (a, s'): the fully observed variables' values, then the
    # observation variables' joint value, each observation variable's table given (a, s')
    seen = [c for c, f in zip(curr, fully, strict=True) if f]

    ofun = root.find("ObsFunction")
    ocpts = _cond_probs(ofun, variables, path, obs, [act, *curr], "observation", "observation")
    seen_sizes = [len(variables[c].values) for c in seen]
    seen_rows = None
    if seen:  # the fully observed values join the observation
        seen_val = np.zeros(S, dtype=np.int64)
        for c, n in zip(seen, seen_sizes, strict=True):
            seen_val = seen_val * n + value_of[c]
        n_seen = int(np.prod(seen_sizes))
        seen_rows = sp.csr_matrix((np.ones(S), seen_val, np.arange(S + 1)), shape=(S, n_seen))
    O = []
    for a in range(A):
        factors = [_factor_rows(*ocpts[v], act, a, value_of, S) for v in obs]
        if seen_rows is not None:
            factors.insert(0, seen_rows)
        if not factors:
            O.append(sp.csr_matrix((np.ones(S), np.zeros(S, dtype=np.int64), np.arange(S + 1))))
            continue
        budget.take(_kron_nnz(factors), f"the observations of action {a}")
        O.append(reduce(_rowwise_kron, factors))

    # rewards: sum of the reward functions, in expectation over the next state
    R = np.zeros((S, A))
    rfun = root.find("RewardFunction")
    for fn in [] if rfun is None else rfun.findall("Func"):
        parents, arr = _table(fn, variables, "ValueTable")
        if any(p not in [act, *prev, *curr] for p in parents):
            raise PomdpxError(f"{path}: reward depends on {parents} (unsupported)")
        for a in range(A):
            sub, rest = _fix_action(parents, arr, act, a)
            if not any(p in curr for p in rest):
                R[:, a] += sub[tuple(value_of[p] for p in rest)] if rest else sub
                continue
            Ta = T[a]  # the reward of (s, s'), weighed by T(s, a, s') over T's non-zeros
            rows = np.repeat(np.arange(S), np.diff(Ta.indptr))
            idx = tuple(value_of[p][rows if p in prev else Ta.indices] for p in rest)
            R[:, a] += np.bincount(rows, weights=Ta.data * sub[idx], minlength=S)

    # the initial belief
    b0 = np.ones(S)
    ini = root.find("InitialStateBelief")
    for cp in [] if ini is None else ini.findall("CondProb"):
        order, arr = _table(cp, variables, "ProbTable")
        if any(v not in prev for v in order):
            raise PomdpxError(f"{path}: initial belief of {order[-1]!r} names other variables")
        b0 = b0 * arr[tuple(value_of[v] for v in order)]
    if ini is None:
        b0 = np.full(S, 1.0 / S)

    states = _joint_names([variables[v].values for v in prev])
    obs_names = _joint_names(
        [variables[c].values for c in seen] + [variables[v].values for v in obs]
    )
    pomdp = POMDP(
        states=tuple(states),
        actions=tuple(variables[act].values),
        observations=tuple(obs_names),
        T=tuple(T),
        O=tuple(O),
        R=R,
        discount=discount,
        b0=b0,
        name=path.stem,
    )
    try:
        pomdp.validate(tol=1e-6)
    except ValueError as exc:
        raise PomdpxError(f"{path}: {exc}") from None
    if seen_rows is not None:  # SARSOP's policies for the file index states this way
        by_value = np.argsort(seen_rows.indices, kind="stable")
        cut = np.searchsorted(seen_rows.indices[by_value], np.arange(seen_rows.shape[1] + 1))
        pomdp.note(_BLOCKS, [by_value[lo:hi] for lo, hi in zip(cut, cut[1:], strict=False)])
    return pomdp


_BLOCKS = "pomdpx_observed_blocks"


def observed_blocks(pomdp: POMDP) -> list[np.ndarray] | None:
    """For a model read from a ``.pomdpx`` with fully observed variables: per joint
    value x of those variables, the flat states that have it, in the order of the
    other variables' joint value -- the layout of SARSOP's vectors ``obsValue=x``
    (:func:`stack.planning.policy.read_policy_xml`). None for any other model."""
    return pomdp.noted(_BLOCKS)


def _joint_names(value_lists: list[list[str]]) -> list[str]:
    if not value_lists:
        return ["none"]
    return reduce(lambda xs, ys: [f"{x}_{y}" for x in xs for y in ys], value_lists)
