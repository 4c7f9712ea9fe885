"""Held-out family members: the RockSample generator (bench/gen_rocksample.py) and
larger factored .pomdpx files flattened sparsely (stack/planning/pomdpx.py)."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from stack.planning import pomdpx
from stack.planning.pomdp_format import parse_pomdp, read_pomdp
from stack.planning.pomdpx import PomdpxError, read_pomdpx

REPO = Path(__file__).resolve().parents[1]
POMDP_DIR = REPO.parent / "shared" / "pomdp"


def _gen():
    spec = importlib.util.spec_from_file_location(
        "gen_rocksample", REPO / "bench" / "gen_rocksample.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules["gen_rocksample"] = mod
    spec.loader.exec_module(mod)
    return mod


gen = _gen()


def _same_model(a, b, atol=0.0):
    """Same T, O, R, b0 (to ``atol``), state for state."""
    assert a.n_states == b.n_states and a.actions == b.actions
    assert a.discount == b.discount
    for x in range(a.n_actions):
        for ma, mb in ((a.T[x], b.T[x]), (a.O[x], b.O[x])):
            diff = abs(ma - mb)
            assert diff.nnz == 0 or diff.max() <= atol
    np.testing.assert_allclose(a.R, b.R, atol=atol, rtol=0)
    np.testing.assert_allclose(a.b0, b.b0, atol=atol, rtol=0)


@pytest.mark.parametrize("n,k", [(4, 4), (5, 7)])
def test_generated_rocksample_is_the_shared_file(n, k):
    shared = POMDP_DIR / f"RockSample_{n}_{k}.pomdp"
    if not shared.is_file():
        pytest.skip(f"{shared} not present")
    text = gen.format_rocksample(gen.instance(n, k))
    ours, theirs = parse_pomdp(text), read_pomdp(shared)
    _same_model(ours, theirs)
    assert ours.states == theirs.states
    assert text == shared.read_text()  # and byte for byte the published text


def test_generated_rocksample_dynamics_by_hand():
    m = gen.RockSample(3, ((1, 1), (2, 0)), (0, 1), 20.0, False)
    p = parse_pomdp(gen.format_rocksample(m))
    assert p.n_states == 3 * 3 * 4 + 1 and p.actions == (
        "amn",
        "ame",
        "ams",
        "amw",
        "ac0",
        "ac1",
        "as",
    )
    s = p.states.index
    a = p.actions.index
    nxt = lambda act, st: p.states[p.T[a(act)][s(st)].indices[0]]  # noqa: E731
    assert nxt("amn", "s1111") == "s1211" and nxt("ame", "s1111") == "s2111"
    assert nxt("ame", "s2111") == "st" and p.R[s("s2111"), a("ame")] == 10.0
    assert nxt("amw", "s0111") == "st" and p.R[s("s0111"), a("amw")] == -100.0
    assert nxt("as", "s1110") == "s1100" and p.R[s("s1110"), a("as")] == 10.0  # good -> bad
    assert nxt("as", "s1101") == "s1101" and p.R[s("s1101"), a("as")] == -10.0
    assert nxt("as", "s0001") == "st" and p.R[s("s0001"), a("as")] == -100.0
    # a check at distance 0 is exact; further away it reads right with (1 + 2^(-d/20)) / 2
    assert p.O[a("ac0")][s("s1110")].toarray().tolist() == [[1.0, 0.0]]
    right = 0.5 + 0.5 * 2 ** (-np.hypot(2, 1) / 20)
    assert p.O[a("ac1")][s("s0101")].toarray()[0, 0] == pytest.approx(right, abs=1e-6)
    assert p.b0[[s(f"s01{r:02b}") for r in range(4)]].tolist() == [0.25] * 4


def test_non_standard_sizes_place_rocks_by_seed():
    a, b, c = gen.instance(6, 5, seed=1), gen.instance(6, 5, seed=1), gen.instance(6, 5, seed=2)
    assert a == b and a != c and len(set(a.rocks)) == 5
    with pytest.raises(ValueError, match="do not fit"):
        gen.instance(2, 5)


# -- .pomdpx flattened sparsely ----------------------------------------------------------
SARSOP_EXAMPLES = REPO.parent / "sarsop-build" / "sarsop" / "examples" / "POMDPX"
if not SARSOP_EXAMPLES.is_dir():
    SARSOP_EXAMPLES = Path("/work/sarsop-build/sarsop/examples/POMDPX")


def _cpt(tag, var, parents, table):
    """A <CondProb>/<Func> giving every entry with one '-' per axis."""
    value = "ValueTable" if tag == "Func" else "ProbTable"
    nums = " ".join(repr(float(x)) for x in np.ravel(table))
    dashes = " ".join("-" for _ in range(table.ndim))
    return (
        f"<{tag}><Var>{var}</Var><Parent>{' '.join(parents) or 'null'}</Parent>"
        f"<Parameter type='TBL'><Entry><Instance>{dashes}</Instance>"
        f"<{value}>{nums}</{value}></Entry></Parameter></{tag}>"
    )


def _random_factored(rng):
    """A random factored model as .pomdpx text and its flat (T, O, R, b0) by brute force."""
    sizes, fully, A, Zo = [3, 2, 2], [True, False, False], 3, 2
    names = ["x", "y", "w"]
    dirich = lambda shape: rng.dirichlet(np.ones(shape[-1]) * 0.5, size=shape[:-1])  # noqa: E731
    # x' | a, x ; y' | a, x, y ; w' | a, w, y ; o | a, x', w' ; R(a, x, y) + R(a, y')
    tx, ty, tw = dirich((A, 3, 3)), dirich((A, 3, 2, 2)), dirich((A, 2, 2, 2))
    ty[1] = 0.0
    ty[1, ..., 0] = 1.0  # a deterministic table (sparse rows)
    to = dirich((A, 3, 2, Zo))
    r1, r2 = rng.normal(size=(A, 3, 2)), rng.normal(size=(A, 2))
    b_x, b_yw = dirich((3,)), dirich((2, 4)).reshape(2, 2, 2)[0]
    var = "".join(
        f"<StateVar vnamePrev='{n}0' vnameCurr='{n}1' fullyObs='{str(f).lower()}'>"
        f"<NumValues>{k}</NumValues></StateVar>"
        for n, k, f in zip(names, sizes, fully, strict=True)
    )
    var += f"<ObsVar vname='o'><NumValues>{Zo}</NumValues></ObsVar>"
    var += f"<ActionVar vname='a'><NumValues>{A}</NumValues></ActionVar><RewardVar vname='r'/>"
    b_yw = b_yw / b_yw.sum()
    text = (
        "<?xml version='1.0'?><pomdpx><Discount>0.9</Discount>"
        f"<Variable>{var}</Variable>"
        "<InitialStateBelief>"
        + _cpt("CondProb", "x0", [], b_x)
        + _cpt("CondProb", "w0", [], b_yw.sum(axis=0))
        + _cpt("CondProb", "y0", ["w0"], (b_yw / b_yw.sum(axis=0)).T)
        + "</InitialStateBelief><StateTransitionFunction>"
        + _cpt("CondProb", "w1", ["a", "w0", "y0"], tw)
        + _cpt("CondProb", "x1", ["a", "x0"], tx)
        + _cpt("CondProb", "y1", ["a", "x0", "y0"], ty)
        + "</StateTransitionFunction><ObsFunction>"
        + _cpt("CondProb", "o", ["a", "x1", "w1"], to)
        + "</ObsFunction><RewardFunction>"
        + _cpt("Func", "r", ["a", "x0", "y0"], r1)
        + _cpt("Func", "r", ["a", "y1"], r2)
        + "</RewardFunction></pomdpx>"
    )
    S = 12
    T = np.zeros((A, S, S))
    O = np.zeros((A, S, 3 * Zo))
    R = np.zeros((S, A))
    b0 = np.zeros(S)
    for a in range(A):
        for s, (x, y, w) in enumerate(np.ndindex(3, 2, 2)):
            b0[s] = b_x[x] * b_yw[y, w]
            R[s, a] = r1[a, x, y]
            for s2, (x2, y2, w2) in enumerate(np.ndindex(3, 2, 2)):
                p = tx[a, x, x2] * ty[a, x, y, y2] * tw[a, w, y, w2]
                T[a, s, s2] = p
                R[s, a] += p * r2[a, y2]
            O[a, s, x * Zo : (x + 1) * Zo] = to[a, x, w]
    return text, T, O, R, b0


@pytest.mark.parametrize("seed", range(3))
def test_pomdpx_sparse_flattening_matches_the_dense_product(tmp_path, seed):
    text, T, O, R, b0 = _random_factored(np.random.default_rng(seed))
    f = tmp_path / "m.pomdpx"
    f.write_text(text)
    m = read_pomdpx(f)
    assert m.n_states == 12 and m.n_observations == 3 * 2
    for a in range(3):
        np.testing.assert_allclose(m.T[a].toarray(), T[a], atol=1e-12)
        np.testing.assert_allclose(m.O[a].toarray(), O[a], atol=1e-12)
    np.testing.assert_allclose(m.R, R, atol=1e-12)
    np.testing.assert_allclose(m.b0, b0, atol=1e-12)
    assert m.T[1].nnz < np.count_nonzero(T[0])  # the deterministic table stays sparse


def test_pomdpx_oversized_and_malformed_input_is_refused(tmp_path, monkeypatch):
    text = _random_factored(np.random.default_rng(0))[0]
    f = tmp_path / "m.pomdpx"
    f.write_text(text)
    monkeypatch.setattr(pomdpx, "MAX_FLAT_NONZEROS", 100)
    with pytest.raises(PomdpxError, match="non-zeros"):
        read_pomdpx(f)
    monkeypatch.setattr(pomdpx, "MAX_FLAT_STATES", 10)
    with pytest.raises(PomdpxError, match="12 flat states"):
        read_pomdpx(f)
    monkeypatch.undo()
    w1 = text[text.index("<CondProb><Var>w1") : text.index("<CondProb><Var>x1")]
    f.write_text(text.replace(w1, w1 + w1))
    with pytest.raises(PomdpxError, match="two transition tables for 'w1'"):
        read_pomdpx(f)
    f.write_text(text.replace(w1, ""))
    with pytest.raises(PomdpxError, match=r"no transition table for \['w1'\]"):
        read_pomdpx(f)
    big = text.replace("<NumValues>3</NumValues>", "<NumValues>3000000</NumValues>", 1)
    f.write_text(big)
    with pytest.raises(PomdpxError, match="values|flat states|entries"):
        read_pomdpx(f)


def _lumped(x, p, state_map, obs_map):
    """``x`` maps onto ``p`` exactly: states by ``state_map`` (x -> p), observations by
    ``obs_map``; then both models have the same values (x's states are p's, split)."""
    P = sp.csr_matrix((np.ones(x.n_states), state_map, np.arange(x.n_states + 1)))
    Q = sp.csr_matrix((np.ones(x.n_observations), obs_map, np.arange(x.n_observations + 1)))
    assert x.n_actions == p.n_actions and x.discount == p.discount
    for a in range(x.n_actions):
        diff = abs(x.T[a] @ P - p.T[a][state_map])
        assert diff.nnz == 0 or diff.max() < 1e-9
        diff = abs(x.O[a] @ Q - p.O[a][state_map])
        assert diff.nnz == 0 or diff.max() < 2e-6  # the .pomdp's 6 decimals
    np.testing.assert_allclose(x.R, p.R[state_map], atol=1e-9)
    np.testing.assert_allclose(x.b0 @ P, p.b0, atol=1e-9)


@pytest.mark.slow
def test_rocksample_7_8_pomdpx_is_the_generated_pomdp():
    f = SARSOP_EXAMPLES / "RockSample_7_8.pomdpx"
    if not f.is_file():
        pytest.skip(f"{f} not present")
    x = read_pomdpx(f)
    p = parse_pomdp(gen.format_rocksample(gen.instance(7, 8)))
    assert (x.n_states, p.n_states, x.n_observations) == (12_800, 12_545, 100)
    # robot square r (x-major, 49 = the terminal 'st') x 256 rock values: the .pomdp has the
    # same numbering and one terminal state for the 256; observations (square, reading)
    state_map = np.minimum(np.arange(x.n_states), 12_544)
    _lumped(x, p, state_map, np.arange(x.n_observations) % 2)


def test_write_reserve_counts_the_vectors_the_policy_writes():
    """The time kept for writing the policy counts the vectors the written policy holds
    (reached_only: the closure of the vectors used at the reached nodes), not every
    active vector's closure (RockSample_7_8: 2.3 times as many, 11 s of a 60 s limit)."""
    from stack.planning.sarsop import BeliefTreeSearch
    from stack.planning.search_base import SearchConfig

    m = gen.RockSample(4, ((3, 1), (2, 1), (1, 3), (1, 0)), (0, 2), 20.0, True)
    pomdp = parse_pomdp(gen.format_rocksample(m))
    cfg = SearchConfig(time_limit_s=None, max_trials=30, write_s_per_value=1.0)
    search = BeliefTreeSearch(pomdp, cfg)
    search.run()
    search._measure_writing()
    written = search._closed_policy()[0].shape[0]
    everything = search.K + search._n_archived
    assert written < everything  # the case this is for
    assert search._values_to_write() == pytest.approx(written * pomdp.n_states, rel=1e-9)
    off = BeliefTreeSearch(pomdp, SearchConfig(**{**cfg.__dict__, "reached_only": False}))
    off.run()
    off._measure_writing()
    assert off._values_to_write() == (off.K + off._n_archived) * pomdp.n_states


@pytest.mark.parametrize("seed", range(3))
def test_fast_informed_bound_matches_the_dense_operator(seed):
    """The bound is built over the (s, z) pairs that occur, not Z x S rows: the same
    numbers as the operator written out densely."""
    from stack.planning.bounds import fast_informed_bound, qmdp
    from stack.planning.pomdp import dense_to_pomdp

    rng = np.random.default_rng(seed)
    S, A, Z, g = 6, 3, 4, 0.9
    T = rng.dirichlet(np.ones(S) * 0.3, size=(A, S))
    O = rng.dirichlet(np.ones(Z) * 0.3, size=(A, S))
    T[T < 0.05] = 0.0  # sparse rows, some (s, z) pairs that never occur
    T /= T.sum(axis=2, keepdims=True)
    O[O < 0.05] = 0.0
    O /= O.sum(axis=2, keepdims=True)
    R = rng.normal(size=(S, A))
    pomdp = dense_to_pomdp(T, O, R, g, np.full(S, 1.0 / S))
    Q = qmdp(pomdp)
    got = fast_informed_bound(pomdp, Q, max_iterations=3, tol=0.0)
    want = Q.copy()
    for _ in range(3):
        new = np.empty_like(want)
        for a in range(A):
            # sum_z max_a' sum_s' T(s, a, s') O(s', a, z) Q(s', a')
            per_z = np.einsum("ij,jz,jb->izb", T[a], O[a], want).max(axis=2)
            new[:, a] = R[:, a] + g * per_z.sum(axis=1)
        want = np.minimum(new, want)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_archived_vectors_no_policy_can_reach_are_released():
    """Pruned vectors outside the active set's closure are forgotten (memory), and the
    written policy, which reads only the closure, is the same as with all of them kept."""
    from stack.planning.sarsop import BeliefTreeSearch
    from stack.planning.search_base import SearchConfig

    m = gen.RockSample(4, ((3, 1), (2, 1), (1, 3), (1, 0)), (0, 2), 20.0, True)
    pomdp = parse_pomdp(gen.format_rocksample(m))
    search = BeliefTreeSearch(pomdp, SearchConfig(time_limit_s=None, max_trials=60))
    result = search.run()
    released = [g for g, v in enumerate(search._all_alpha) if v is None]
    assert released  # pruning dropped vectors that nothing leads to
    closure = set(search.closure(reached=False))
    assert not closure & set(released)
    alphas, actions, succ = search._closed_policy()
    assert np.isfinite(alphas).all() and (succ < len(alphas)).all()
    assert result.policy.value(pomdp.b0) == pytest.approx(result.lower_bound, abs=1e-9)


def test_sarsop_policy_of_a_pomdpx_file_reads_onto_the_flat_states(tmp_path, capsys):
    """SARSOP writes a .pomdpx model's vectors per value of the fully observed variables
    (obsValue) over the other variables; `vigil evaluate` lays them onto the flat states."""
    from stack.planning.policy import AlphaPolicy
    from stack.planning.pomdpx import observed_blocks
    from vigil.cli import main as vigil

    text = _random_factored(np.random.default_rng(0))[0]
    f = tmp_path / "m.pomdpx"
    f.write_text(text)
    m = read_pomdpx(f)
    blocks = observed_blocks(m)
    assert [b.tolist() for b in blocks] == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]
    assert observed_blocks(parse_pomdp(gen.format_rocksample(gen.instance(4, 4)))) is None
    xml = (
        "<?xml version='1.0'?><Policy><AlphaVector vectorLength='4' numObsValue='3' "
        "numVectors='3'><Vector action='0' obsValue='1'>1 2 3 4</Vector>"
        "<Vector action='1' obsValue='2'>5 6 7 8</Vector>"
        "<Vector action='2' obsValue='0'>9 9 9 9</Vector></AlphaVector></Policy>"
    )
    pol_file = tmp_path / "m.policy"
    pol_file.write_text(xml)
    pol = AlphaPolicy.load(pol_file, n_states=12, obs_blocks=blocks)
    assert pol.obs.tolist() == [1, 2, 0] and pol.alphas[0].tolist() == [1, 2, 3, 4]
    b = np.zeros(12)
    b[[9, 10]] = 0.5  # x = 2: only the obsValue 2 vector counts
    assert pol.action(b) == 1
    assert pol.values(b)[1] == 6.5 and np.isneginf(pol.values(b)[[0, 2]]).all()
    b = np.zeros(12)
    b[5] = 1.0  # x = 1: its second state
    assert pol.value(b) == 2.0
    assert vigil(["evaluate", str(f), "--policy", str(pol_file), "--episodes", "3", "--json"]) == 0
    assert "mean" in capsys.readouterr().out


def test_flat_policy_of_a_pomdpx_model_rewritten_in_sarsop_layout(tmp_path):
    """bench/factored_policy.py: every flat vector once per observed value, over that
    value's states; read back onto the flat states it values every belief the same."""
    from stack.planning.policy import AlphaPolicy, read_policy_xml, write_policy_xml
    from stack.planning.pomdpx import observed_blocks

    spec = importlib.util.spec_from_file_location(
        "factored_policy", REPO / "bench" / "factored_policy.py"
    )
    fp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fp)
    text = _random_factored(np.random.default_rng(1))[0]
    model = tmp_path / "m.pomdpx"
    model.write_text(text)
    m = read_pomdpx(model)
    rng = np.random.default_rng(2)
    flat = AlphaPolicy(rng.normal(size=(4, 12)), np.array([0, 1, 2, 1]))
    write_policy_xml(flat, tmp_path / "flat.policy")
    assert fp.main([str(model), str(tmp_path / "flat.policy"), str(tmp_path / "f.policy")]) == 0
    back = read_policy_xml(tmp_path / "f.policy", 12, observed_blocks(m))
    assert len(back.alphas) == 4 * 3
    for rows in observed_blocks(m):
        b = np.zeros(12)
        b[rows] = rng.dirichlet(np.ones(rows.size))
        np.testing.assert_allclose(back.value(b), flat.value(b), atol=1e-9)
        assert back.action(b) == flat.action(b)
