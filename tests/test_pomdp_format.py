"""Tests for the Cassandra ``.pomdp`` reader and writer (stack/planning/pomdp_format/)."""

from __future__ import annotations

import dataclasses
import io
import re
from pathlib import Path

import numpy as np
import pytest

from stack.planning.pomdp import dense_to_pomdp
from stack.planning.pomdp_format import (
    PomdpFormatError,
    format_pomdp,
    parse_pomdp,
    read_pomdp,
    write_pomdp,
)

DATA = Path(__file__).resolve().parents[2] / "shared" / "pomdp"
needs_data = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"benchmark .pomdp files not found at {DATA}"
)

# file: (states, actions, observations, discount), from shared/pomdp/README.md -- except
# learning.c2, whose README row says 8 observations while the file lists 3
# (Unlearned Neutral Learned); the file is what is tested.
FILES = {
    "Tiger.pomdp": (2, 3, 2, 0.95),
    "4x3.95.POMDP": (11, 4, 6, 0.95),
    "cheese.95.POMDP": (11, 4, 7, 0.95),
    "Hallway.pomdp": (60, 5, 21, 0.95),
    "Hallway2.pomdp": (92, 5, 17, 0.95),
    "TagAvoid.pomdp": (870, 5, 30, 0.95),
    "RockSample_4_4.pomdp": (257, 9, 2, 0.95),
    "RockSample_5_7.pomdp": (3201, 12, 2, 0.95),
    "bulkhead.A.POMDP": (10, 6, 6, 1.0),
    "learning.c2.POMDP": (12, 8, 3, 1.0),
}
# Small enough for the dense reference parser below (R is A x S x S x Z dense there).
SMALL = [f for f in FILES if f not in ("TagAvoid.pomdp", "RockSample_5_7.pomdp")]

TIGER = """\
discount: 0.95
values: reward
states: tiger-left tiger-right
actions: listen open-left open-right
observations: obs-left obs-right
T:listen
identity
T:open-left
uniform
T:open-right
uniform
O:listen
0.85 0.15
0.15 0.85
O:open-left
uniform
O:open-right
uniform
R:listen : * : * : * -1
R:open-left : tiger-left : * : * -100
R:open-left : tiger-right : * : * 10
R:open-right : tiger-left : * : * 10
R:open-right : tiger-right : * : * -100
"""


def _tiny(body: str, preamble: str | None = None) -> str:
    """A 2-state, 2-action, 2-observation model whose T/O/R part is ``body``."""
    if preamble is None:
        preamble = "discount: 0.9\nvalues: reward\nstates: a b\nactions: x y\nobservations: u v\n"
    return preamble + body


_VALID_BODY = "T: * identity\nO: * uniform\n"


# -- a deliberately naive, dense reference reader to check semantics against ----------
def _reference(text: str, scale_rows: bool = False):
    """Token-by-token reading into dense arrays; slow and simple on purpose.

    With ``scale_rows`` every row of T and O is divided by its sum before R(s, a) is
    taken (rows must then be non-zero).
    """
    toks = re.findall(r":|[^\s:]+", re.sub(r"#[^\n]*", "", text))
    kws = {"discount", "values", "states", "actions", "observations", "start", "T", "O", "R"}
    stmts, i = [], 0
    while i < len(toks):
        kw = toks[i]
        i += 1
        if kw == "start" and toks[i] in ("include", "exclude"):
            kw, i = kw + " " + toks[i], i + 1
        assert toks[i] == ":"
        j = i + 1
        while j + 1 < len(toks) and not (
            toks[j] in kws and toks[j + 1] in (":", "include", "exclude")
        ):
            j += 1
        j = j if j + 1 < len(toks) else len(toks)
        stmts.append((kw, toks[i + 1 : j]))
        i = j
    pre = {kw: body for kw, body in stmts if kw not in ("T", "O", "R")}

    def names(body):
        return [str(k) for k in range(int(body[0]))] if body[0].isdigit() else body

    S, A, Z = (names(pre[k]) for k in ("states", "actions", "observations"))
    nS, nA, nZ = len(S), len(A), len(Z)

    def ix(tok, ns):
        return slice(None) if tok == "*" else (int(tok) if tok.isdigit() else ns.index(tok))

    T = np.zeros((nA, nS, nS))
    Ob = np.zeros((nA, nS, nZ))
    R = np.zeros((nA, nS, nS, nZ))
    for kw, body in stmts:
        if kw not in ("T", "O", "R"):
            continue
        fields = " ".join(body).split(" : ")
        ids = [f.split()[0] for f in fields]
        nums = fields[-1].split()[1:]
        spaces = [A, S, S, Z] if kw == "R" else [A, S, S if kw == "T" else Z]
        key = tuple(ix(t, sp_) for t, sp_ in zip(ids, spaces, strict=False))
        table = {"T": T, "O": Ob, "R": R}[kw]
        given = table.shape[len(ids) :]  # a row or matrix fills the dimensions not named
        if nums == ["identity"]:
            table[key] = np.eye(nS)
        elif nums == ["uniform"]:
            table[key] = 1.0 / given[-1]
        else:
            table[key] = np.array([float(x) for x in nums]).reshape(given)
    gamma = float(pre["discount"][0])
    if scale_rows:
        T /= T.sum(axis=2, keepdims=True)
        Ob /= Ob.sum(axis=2, keepdims=True)
    Rsa = np.einsum("asn,anz,asnz->sa", T, Ob, R)
    if pre.get("values", ["reward"])[0] == "cost":
        Rsa = -Rsa
    return S, A, Z, gamma, T, Ob, Rsa


# -- the benchmark files -----------------------------------------------------------------
@needs_data
@pytest.mark.parametrize("fname", list(FILES))
def test_benchmark_file_parses(fname: str) -> None:
    m = read_pomdp(DATA / fname)
    S, A, Z, gamma = FILES[fname]
    assert (m.n_states, m.n_actions, m.n_observations) == (S, A, Z)
    assert m.discount == gamma
    m.validate(1e-6)
    m.validate()  # rows are renormalised, so the default 1e-9 holds too
    assert m.name == Path(fname).stem
    assert np.isfinite(m.R).all()


@needs_data
@pytest.mark.parametrize("fname", SMALL)
def test_benchmark_file_matches_dense_reference(fname: str) -> None:
    text = (DATA / fname).read_text()
    m = parse_pomdp(text, normalize=False)
    S, A, Z, gamma, T, Ob, R = _reference(text)
    assert list(m.states) == S and list(m.actions) == A and list(m.observations) == Z
    assert m.discount == gamma
    for a in range(len(A)):
        np.testing.assert_array_equal(m.T[a].toarray(), T[a])
        np.testing.assert_array_equal(m.O[a].toarray(), Ob[a])
    np.testing.assert_allclose(m.R, R, rtol=1e-12, atol=1e-12)


@needs_data
def test_hallway_reward_depends_on_next_state() -> None:
    # Hallway rewards reaching the goal (states 56..59): R: * : * : 56 : * 1.0, ...
    m = read_pomdp(DATA / "Hallway.pomdp", normalize=False)
    for a in range(m.n_actions):
        expect = np.asarray(m.T[a][:, 56:60].sum(axis=1)).ravel()
        np.testing.assert_allclose(m.R[:, a], expect, atol=1e-12)
    assert m.R.max() > 0


@needs_data
def test_tagavoid_wildcards_and_overrides() -> None:
    m = read_pomdp(DATA / "TagAvoid.pomdp")
    catch = m.actions.index("Catch")
    assert m.R[m.states.index("s0"), catch] == 10.0
    assert m.R[m.states.index("s29"), catch] == 0.0
    assert m.R[m.states.index("s1"), catch] == -10.0
    assert (m.R[:, m.actions.index("North")] == -1.0).all()
    # 'T: * : * : * 0.0' leaves no explicit zeros in the sparse matrices
    assert all((t.data != 0).all() for t in m.T)


# -- Tiger by hand -----------------------------------------------------------------------
def test_tiger_values() -> None:
    m = parse_pomdp(TIGER, name="tiger")
    listen, left, right = (m.actions.index(a) for a in ("listen", "open-left", "open-right"))
    tl, tr = m.states.index("tiger-left"), m.states.index("tiger-right")
    np.testing.assert_array_equal(m.T[listen].toarray(), np.eye(2))
    np.testing.assert_array_equal(m.T[left].toarray(), np.full((2, 2), 0.5))
    assert m.O[listen][tl, m.observations.index("obs-left")] == 0.85
    assert m.O[listen][tr, m.observations.index("obs-left")] == 0.15
    np.testing.assert_array_equal(m.R[:, listen], [-1.0, -1.0])
    assert (m.R[tl, left], m.R[tr, left]) == (-100.0, 10.0)
    assert (m.R[tl, right], m.R[tr, right]) == (10.0, -100.0)
    np.testing.assert_array_equal(m.b0, [0.5, 0.5])  # no start: uniform
    assert (m.discount, m.values, m.name) == (0.95, "reward", "tiger")


def test_read_accepts_text_path_and_file(tmp_path: Path) -> None:
    p = tmp_path / "tiger.pomdp"
    p.write_text(TIGER)
    for src in (TIGER, p, str(p), io.StringIO(TIGER)):
        m = read_pomdp(src)
        assert m.n_states == 2 and m.R[0, 0] == -1.0
    assert read_pomdp(p).name == "tiger"


# -- semantics ---------------------------------------------------------------------------
def test_values_cost_negates_rewards() -> None:
    text = TIGER.replace("values: reward", "values: cost")
    m = parse_pomdp(text)
    assert m.values == "cost"
    np.testing.assert_array_equal(m.R, -parse_pomdp(TIGER).R)


@pytest.mark.parametrize(
    ("start", "b0"),
    [
        ("start: 0.25 0.75 0.0", [0.25, 0.75, 0.0]),
        ("start: c", [0.0, 0.0, 1.0]),
        ("start: 1", [0.0, 1.0, 0.0]),
        ("start: uniform", [1 / 3, 1 / 3, 1 / 3]),
        ("start include: a c", [0.5, 0.0, 0.5]),
        ("start include:\n  b\n  c", [0.0, 0.5, 0.5]),
        ("start exclude: a", [0.0, 0.5, 0.5]),
        ("start exclude: 0 1", [0.0, 0.0, 1.0]),
        ("start: 002", [0.0, 0.0, 1.0]),
        ("", [1 / 3, 1 / 3, 1 / 3]),
    ],
)
def test_start_belief_forms(start: str, b0: list[float]) -> None:
    pre = f"discount: 0.9\nvalues: reward\nstates: a b c\nactions: x\nobservations: u\n{start}\n"
    m = parse_pomdp(pre + "T: x identity\nO: x : * : u 1.0\n")
    np.testing.assert_allclose(m.b0, b0, atol=1e-15)


def test_later_entries_override_earlier_ones() -> None:
    body = (
        "T: * : * : * 0.0\n"  # clears (a no-op here, as in TagAvoid)
        "T: * : * : a 1.0\n"  # every row goes to a ...
        "T: y : b\n0.3 0.7\n"  # ... except y from b (a row)
        "T: y : b : a 0.6\n"  # ... which is then changed entry by entry
        "T: y : b : b 0.4\n"
        "O: x uniform\n"
        "O: y : * : u 0.2\n"
        "O: y : * : v 0.8\n"
        "O: y : b : u 1.0\n"
        "O: y : b : v 0.0\n"  # explicit zero overrides 0.8
        "R: * : * : * : * 5\n"
        "R: x : a : * : * -1\n"
    )
    m = parse_pomdp(_tiny(body))
    x, y = 0, 1
    np.testing.assert_array_equal(m.T[x].toarray(), [[1, 0], [1, 0]])
    np.testing.assert_array_equal(m.T[y].toarray(), [[1, 0], [0.6, 0.4]])
    np.testing.assert_array_equal(m.O[y].toarray(), [[0.2, 0.8], [1.0, 0.0]])
    assert m.O[y].nnz == 3  # the explicit zero is not stored
    np.testing.assert_array_equal(m.R, [[-1, 5], [5, 5]])


def test_reward_expectation_over_next_state_and_observation() -> None:
    body = (
        "T: * : * : a 0.25\nT: * : * : b 0.75\n"
        "O: * : a : u 0.5\nO: * : a : v 0.5\nO: * : b : u 0.1\nO: * : b : v 0.9\n"
        "R: x : a : * : * 1.0\n"  # constant: 1
        "R: x : b : b : * 4.0\n"  # depends on s': 0.25 * 0 + 0.75 * 4
        "R: y : a : b : v 10.0\n"  # depends on s' and z: 0.75 * 0.9 * 10
        "R: y : b : a\n2.0 4.0\n"  # row over z for s' = a: 0.25 * (0.5 * 2 + 0.5 * 4)
        "R: y : b : b : * 1.0\n"  # + 0.75 * 1
    )
    m = parse_pomdp(_tiny(body))
    np.testing.assert_allclose(m.R, [[1.0, 0.75 * 0.9 * 10], [0.75 * 4, 0.25 * 3 + 0.75]])


def test_reward_matrix_form() -> None:
    body = "T: * identity\nO: * uniform\nR: y : b\n1 2\n3 4\n"
    m = parse_pomdp(_tiny(body))
    # from b, y stays in b; uniform z: (3 + 4) / 2
    np.testing.assert_allclose(m.R, [[0.0, 0.0], [0.0, 3.5]])


def test_counts_indices_scientific_notation_and_spaced_colons() -> None:
    text = (
        "# comment line\n"
        "discount : 9.5e-1  # TagAvoid writes 'discount :'\n"
        "values: reward\nstates: 3\nactions: 2\nobservations: 2\n"
        "start:\n1.0 0.0\n0.0\n"
        "T : 0 : 0 : 1 1.0E0\nT: 0 : 1 : 2 1\nT: 0 : 2 : 2 1.0\n"
        "T: 1\n1 0 0\n0 1 0\n0 0 1\n"
        "O: * : * : 0 2.5e-1\nO: * : * : 1 7.5e-1\n"
        "R: 1 : 2 : * : * -2.5e+1\n"
    )
    m = parse_pomdp(text)
    assert m.states == ("0", "1", "2") and m.discount == 0.95
    np.testing.assert_array_equal(m.T[0].toarray(), [[0, 1, 0], [0, 0, 1], [0, 0, 1]])
    assert m.R[2, 1] == -25.0 and m.O[1][0, 0] == 0.25
    np.testing.assert_array_equal(m.b0, [1, 0, 0])


def test_statements_need_not_start_a_line() -> None:
    text = (
        "discount: 0.5 values: reward states: a b actions: x observations: u start: b "
        "T: x identity O: x : * : u 1.0 R: x : a : * : * 1.0 R: x : b : * : * 2.0"
    )
    m = parse_pomdp(text)
    np.testing.assert_array_equal(m.R[:, 0], [1.0, 2.0])
    np.testing.assert_array_equal(m.b0, [0.0, 1.0])


def test_names_over_several_lines() -> None:
    pre = (
        "discount: 1\nvalues: reward\nstates:\n\ta b\n\tc\nactions:\n x\n y\nobservations: u\n  v\n"
    )
    m = parse_pomdp(pre + "T: * identity\nO: * uniform\n")
    assert m.states == ("a", "b", "c") and m.actions == ("x", "y")
    assert m.observations == ("u", "v")


def test_normalize_option() -> None:
    body = "T: * : * : a 0.3333333\nT: * : * : b 0.6666666\nO: * uniform\n"
    raw = parse_pomdp(_tiny(body), normalize=False)
    assert raw.T[0][0, 0] == 0.3333333
    fixed = parse_pomdp(_tiny(body))
    np.testing.assert_allclose(fixed.T[0].sum(axis=1), 1.0, rtol=0, atol=1e-15)
    fixed.validate()


# -- errors ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        # bad count of probabilities in a row
        (_tiny("T: x : a\n0.5\nO: * uniform\n"), 6, "expected 2 probabilities"),
        # ... and in a matrix
        (_tiny("T: x\n1 0\n0\nO: * uniform\n"), 6, "expected 4 probabilities"),
        # unknown names and out-of-range indices
        (_tiny("T: x : a : c 1.0\n"), 6, "unknown state 'c'"),
        (_tiny("T: z : a : a 1.0\n"), 6, "unknown action 'z'"),
        (_tiny(_VALID_BODY + "O: x : a : w 1.0\n"), 8, "unknown observation 'w'"),
        (_tiny("T: x : 2 : a 1.0\n"), 6, "state index 2 out of range"),
        # rows that are not distributions, naming the action and the state
        (_tiny("T: * identity\nT: y : b : a 0.5\nO: * uniform\n"), 7, "'y' from state 'b'"),
        (_tiny("T: x identity\nO: * uniform\n"), 7, "T row for action 'y' from state 'a'"),
        (_tiny("T: * identity\nO: x : a\n0.6 0.6\nO: y uniform\n"), 7, "sums to 1.2"),
        (_tiny("T: * identity\nO: * : * : u 0.5\n"), 7, "O row for action 'x' in next state"),
        (_tiny("T: x : a : a 1.5\n"), 6, "not in [0, 1]"),
        (_tiny("T: x : a\n-0.5 1.5\n"), 6, ">= 0"),
        # the preamble
        (
            _tiny(_VALID_BODY, "values: reward\nstates: a b\nactions: x y\nobservations: u v\n"),
            5,
            "missing 'discount:'",
        ),
        (
            _tiny(_VALID_BODY, "discount: 0.9\nactions: x y\nobservations: u v\n"),
            4,
            "missing 'states:'",
        ),
        (
            _tiny(_VALID_BODY, "discount: 1.5\nstates: a b\nactions: x\nobservations: u\n"),
            1,
            "discount 1.5 is not in [0, 1]",
        ),
        (
            _tiny(
                _VALID_BODY,
                "discount: 0.9\nvalues: profit\nstates: 2\nactions: 1\nobservations: 1\n",
            ),
            2,
            "'reward' or 'cost'",
        ),
        (
            _tiny(_VALID_BODY, "discount: 0.9\nstates: a 2b\nactions: x\nobservations: u\n"),
            2,
            "bad state name '2b'",
        ),
        (
            _tiny(_VALID_BODY, "discount: 0.9\nstates: a a\nactions: x\nobservations: u\n"),
            2,
            "given twice",
        ),
        (
            _tiny(_VALID_BODY, "discount: 0.9\nstates: a uniform\nactions: x\nobservations: u\n"),
            2,
            "reserved word",
        ),
        # garbage
        ("hello\ndiscount: 0.9\n", 1, "unexpected 'hello'"),
        (_tiny("T: x : a : a 1.0 garbage\n"), 6, "next: 'garbage'"),
        (_tiny("T: x : a : a 1.0\nfoo\nT: x : b : b 1.0\n"), 7, "next: 'foo'"),
        (_tiny("T: x : a : a one\n"), 6, "got 'one'"),
        (
            _tiny("T: * identity\nO: * : * : u 0.5\nO: * : * : v 0.5\nR: x : a : * : * 1.0 2.0\n"),
            9,
            "'<observation> <reward>'",
        ),
        (_tiny("T: x : a : a : b 1.0\n"), 6, "too many ':'"),
        (_tiny("T: x identity\nstart: a\n"), 7, "must come before the first T/O/R entry"),
        (_tiny("T: x : a\nreset\n"), 6, "'reset'"),
        (_tiny("start: 0.5 0.6\n"), 6, "start probabilities sum to 1.1"),
    ],
)
def test_malformed_input_is_rejected_with_line_number(text: str, line: int, fragment: str) -> None:
    with pytest.raises(PomdpFormatError) as info:
        parse_pomdp(text)
    err = info.value
    assert isinstance(err, ValueError)
    assert err.line == line, str(err)
    assert str(err).startswith(f"line {line}: ")
    assert fragment in str(err), str(err)


def test_error_message_names_the_entry() -> None:
    with pytest.raises(
        PomdpFormatError,
        match=r"line 12: expected 4 probabilities \(2 x 2 "
        r"matrix\) after 'O: listen', got 3",
    ):
        parse_pomdp(TIGER.replace("0.85 0.15\n0.15 0.85", "0.85 0.15\n0.15"))
    text = TIGER.replace("T:open-left\nuniform", "T:open-left : tiger-left\n1.0")
    with pytest.raises(
        PomdpFormatError,
        match="expected 2 probabilities .* after 'T: open-left : tiger-left', got 1",
    ):
        parse_pomdp(text)


# -- writer ------------------------------------------------------------------------------
def _assert_same_model(m1, m2, exact: bool = False) -> None:
    assert (m1.states, m1.actions, m1.observations) == (m2.states, m2.actions, m2.observations)
    assert m1.discount == m2.discount and m1.values == m2.values
    tol = 0.0 if exact else 1e-15
    np.testing.assert_allclose(m1.b0, m2.b0, rtol=0, atol=tol)
    np.testing.assert_allclose(m1.R, m2.R, rtol=1e-15, atol=tol)
    for a in range(m1.n_actions):
        np.testing.assert_allclose(m1.T[a].toarray(), m2.T[a].toarray(), rtol=0, atol=tol)
        np.testing.assert_allclose(m1.O[a].toarray(), m2.O[a].toarray(), rtol=0, atol=tol)


def test_round_trip_tiger(tmp_path: Path) -> None:
    m = parse_pomdp(TIGER, name="tiger")
    path = tmp_path / "tiger.pomdp"
    write_pomdp(m, path)
    _assert_same_model(read_pomdp(path), m, exact=True)
    buf = io.StringIO()
    write_pomdp(m, buf)
    assert buf.getvalue() == format_pomdp(m)


@needs_data
def test_round_trip_4x3() -> None:
    m = read_pomdp(DATA / "4x3.95.POMDP")
    text = format_pomdp(m)
    assert "states: 11\n" in text  # counted states stay counted
    _assert_same_model(parse_pomdp(text), m)


@pytest.mark.parametrize("values", ["reward", "cost"])
def test_round_trip_random_model(values: str) -> None:
    rng = np.random.default_rng(7)
    A, S, Z = 3, 6, 4
    T = rng.random((A, S, S)) * (rng.random((A, S, S)) < 0.4)
    T[:, np.arange(S), np.arange(S)] += 0.1  # no empty rows
    T /= T.sum(axis=2, keepdims=True)
    Ob = rng.random((A, S, Z)) ** 3
    Ob /= Ob.sum(axis=2, keepdims=True)
    R = rng.normal(size=(S, A)) * 100
    R[0, 0] = 0.0
    b0 = rng.dirichlet(np.ones(S))
    m = dense_to_pomdp(T, Ob, R, 0.97, b0, name="random")
    if values == "cost":
        m = dataclasses.replace(m, values="cost")
    back = parse_pomdp(format_pomdp(m), normalize=False)
    _assert_same_model(back, m, exact=True)
    assert back.values == values


def test_writer_sanitizes_names() -> None:
    T = np.stack([np.eye(3)])
    Ob = np.ones((1, 3, 2)) / 2
    m = dense_to_pomdp(
        T, Ob, np.zeros((3, 1)), 0.9,
        states=["left room", "2nd", "left_room"], actions=["T"], observations=["ok", "ok!"],
    )  # fmt: skip
    back = parse_pomdp(format_pomdp(m))
    assert back.states == ("left_room", "s2nd", "left_room_2")
    assert back.actions == ("T_",)
    assert back.observations == ("ok", "ok_")
    np.testing.assert_array_equal(back.T[0].toarray(), np.eye(3))


def test_writer_refuses_non_finite() -> None:
    m = parse_pomdp(TIGER)
    m.R[0, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        format_pomdp(m)


# -- random statements against the dense reference ---------------------------------------
def _random_text(rng: np.random.Generator, n_statements: int) -> str:
    """Every T/O/R form, wildcards and overrides in random order (rows need not sum to 1)."""
    S, A, Z = ["a", "b", "c"], ["x", "y"], ["u", "v"]

    def pick(names):
        r = rng.random()
        return "*" if r < 0.3 else (str(rng.integers(len(names))) if r < 0.5 else rng.choice(names))

    def nums(n, lo=0.0):
        return " ".join(f"{v:.3f}" for v in rng.uniform(lo, 1.0, n))

    lines = ["discount: 0.9", "values: reward", "states: a b c", "actions: x y",
             "observations: u v"]  # fmt: skip
    for _ in range(n_statements):
        kw = rng.choice(["T", "O", "R"])
        cols = S if kw == "T" else Z
        form = rng.integers(3)
        if kw == "R":
            if form == 0:
                lines.append(f"R: {pick(A)} : {pick(S)} : {pick(S)} : {pick(Z)} {nums(1, -1)}")
            elif form == 1:
                lines.append(f"R: {pick(A)} : {pick(S)} : {pick(S)}\n{nums(len(Z), -1)}")
            else:
                lines.append(f"R: {pick(A)} : {pick(S)}\n{nums(len(S) * len(Z), -1)}")
        elif form == 0:
            lines.append(f"{kw}: {pick(A)} : {pick(S)} : {pick(cols)} {nums(1)}")
        elif form == 1:
            row = "uniform" if rng.random() < 0.2 else nums(len(cols))
            lines.append(f"{kw}: {pick(A)} : {pick(S)}\n{row}")
        else:
            special = ["uniform", "identity"] if kw == "T" else ["uniform"]
            mat = rng.choice(special) if rng.random() < 0.3 else nums(len(S) * len(cols))
            lines.append(f"{kw}: {pick(A)}\n{mat}")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("seed", range(40))
def test_random_statements_match_dense_reference(seed: int) -> None:
    text = _random_text(np.random.default_rng(seed), 25)
    # Rows left all zero get a uniform row at the end, so that every row is a (scaled)
    # distribution; rows are then compared after scaling. Sums are not the point here.
    _, A, _, _, T, Ob, _ = _reference(text)
    for kw, table in (("T", T), ("O", Ob)):
        for a, s in zip(*np.nonzero(table.sum(axis=2) == 0), strict=True):
            text += f"{kw}: {A[a]} : {s}\nuniform\n"
    m = parse_pomdp(text, tol=100.0)
    _, A, _, _, T, Ob, expect = _reference(text, scale_rows=True)
    for a in range(len(A)):
        np.testing.assert_allclose(m.T[a].toarray(), T[a], rtol=1e-14, atol=0, err_msg=text)
        np.testing.assert_allclose(m.O[a].toarray(), Ob[a], rtol=1e-14, atol=0, err_msg=text)
    np.testing.assert_allclose(m.R, expect, rtol=1e-12, atol=1e-12, err_msg=text)
