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
observed variable is observed exactly, as SARSOP's MOMDP treats it. Tables are
multiplied out densely, so the flat model is limited to ``MAX_FLAT_STATES``.
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

MAX_FLAT_STATES = 20_000
MAX_DENSE = 60_000_000  # entries of the largest dense table built while flattening


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


def _broadcast(order: list[str], arr: np.ndarray, axes: list[str]) -> np.ndarray:
    """``arr`` (over ``order``) laid out over ``axes`` with length-1 axes elsewhere."""
    perm = sorted(range(len(order)), key=lambda i: axes.index(order[i]))
    moved = np.transpose(arr, perm)
    shape = [1] * len(axes)
    for i in perm:
        shape[axes.index(order[i])] = arr.shape[i]
    return moved.reshape(shape)


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
    S = int(np.prod(sizes))
    A = len(variables[act].values)
    if S > MAX_FLAT_STATES or A * S * S > MAX_DENSE:
        raise PomdpxError(f"{path}: {S:,} flat states is more than this reader flattens")

    # transitions: product of each current variable's table over (a, prev..., curr...)
    axes = [act, *prev, *curr]
    tables = root.find("StateTransitionFunction")
    if tables is None:
        raise PomdpxError(f"{path}: no <StateTransitionFunction>")
    T = np.ones([A] + sizes + sizes)
    done = set()
    for cp in tables.findall("CondProb"):
        order, arr = _table(cp, variables, "ProbTable")
        if order[-1] not in curr or any(p not in axes[: 1 + len(prev)] for p in order[:-1]):
            raise PomdpxError(f"{path}: transition of {order[-1]!r} has unsupported parents")
        T = T * _broadcast(order, arr, axes)
        done.add(order[-1])
    if done != set(curr):
        raise PomdpxError(f"{path}: no transition table for {sorted(set(curr) - done)}")
    T = T.reshape(A, S, S)

    # observations over (a, curr..., observed...): fully observed variables, then obs vars
    seen = [c for c, f in zip(curr, fully, strict=True) if f]
    oaxes = [act, *curr, *obs]
    osizes = [len(variables[v].values) for v in obs]
    O = np.ones([A] + sizes + osizes)
    ofun = root.find("ObsFunction")
    done = set()
    for cp in [] if ofun is None else ofun.findall("CondProb"):
        order, arr = _table(cp, variables, "ProbTable")
        if order[-1] not in obs or any(p not in oaxes[: 1 + len(curr)] for p in order[:-1]):
            raise PomdpxError(f"{path}: observation {order[-1]!r} has unsupported parents")
        O = O * _broadcast(order, arr, oaxes)
        done.add(order[-1])
    if done != set(obs):
        raise PomdpxError(f"{path}: no observation table for {sorted(set(obs) - done)}")
    Z_obs = int(np.prod(osizes)) if osizes else 1
    O = O.reshape(A, S, Z_obs)
    if seen:  # the fully observed values join the observation
        idx = np.indices(sizes).reshape(len(sizes), -1)
        seen_sizes = [len(variables[c].values) for c in seen]
        seen_val = np.ravel_multi_index(
            [idx[curr.index(c)] for c in seen], seen_sizes
        )  # per flat state
        n_seen = int(np.prod(seen_sizes))
        full = np.zeros((A, S, n_seen, Z_obs))
        full[:, np.arange(S), seen_val, :] = O
        O = full.reshape(A, S, n_seen * Z_obs)

    # rewards: sum of the reward functions, in expectation over the next state
    raxes = [act, *prev, *curr]
    R_full = np.zeros([A] + sizes + [1] * len(curr))
    rfun = root.find("RewardFunction")
    for fn in [] if rfun is None else rfun.findall("Func"):
        parents, arr = _table(fn, variables, "ValueTable")
        if any(p not in raxes for p in parents):
            raise PomdpxError(f"{path}: reward depends on {parents} (unsupported)")
        R_full = R_full + _broadcast(parents, arr, raxes)
    if R_full.shape[1 + len(prev) :] != tuple([1] * len(curr)):
        R = (T * R_full.reshape(A, S, -1)).sum(axis=2)
    else:
        R = R_full.reshape(A, S)

    # the initial belief
    b0 = np.ones(sizes)
    ini = root.find("InitialStateBelief")
    for cp in [] if ini is None else ini.findall("CondProb"):
        order, arr = _table(cp, variables, "ProbTable")
        if any(v not in prev for v in order):
            raise PomdpxError(f"{path}: initial belief of {order[-1]!r} names other variables")
        b0 = b0 * _broadcast(order, arr, prev)
    b0 = b0.reshape(S)
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
        T=tuple(sp.csr_matrix(T[a]) for a in range(A)),
        O=tuple(sp.csr_matrix(O[a]) for a in range(A)),
        R=np.ascontiguousarray(R.T),
        discount=discount,
        b0=b0,
        name=path.stem,
    )
    try:
        pomdp.validate(tol=1e-6)
    except ValueError as exc:
        raise PomdpxError(f"{path}: {exc}") from None
    return pomdp


def _joint_names(value_lists: list[list[str]]) -> list[str]:
    if not value_lists:
        return ["none"]
    return reduce(lambda xs, ys: [f"{x}_{y}" for x in xs for y in ys], value_lists)
