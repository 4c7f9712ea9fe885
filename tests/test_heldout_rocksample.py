"""Held-out family members: the RockSample generator (bench/gen_rocksample.py) and
larger factored .pomdpx files flattened sparsely (stack/planning/pomdpx.py)."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from stack.planning.pomdp_format import parse_pomdp, read_pomdp

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
