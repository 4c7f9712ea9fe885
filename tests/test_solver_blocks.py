"""The belief-tree search with vectors per observed block (stack/planning/blocksearch.py)
on .pomdpx models whose fully observed variable's dynamics and observations depend on
the action and on the hidden variables (unlike the task's mixed search, momdp.py)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from test_heldout_rocksample import _random_factored

from stack.planning.blocksearch import BlockTreeSearch, search_blocks
from stack.planning.policy import AlphaPolicy, read_policy_xml
from stack.planning.pomdpx import observed_blocks, read_pomdpx
from stack.planning.sarsop import BeliefTreeSearch
from stack.planning.search_base import SearchConfig
from stack.planning.solve import SolverConfig, solve


def _model(tmp_path, seed: int, x0: int | None = 1):
    """The random factored model (x observed, 3 values; y, w hidden), its start x0 known
    (None: b0 spread over the three x as the fixture has it)."""
    text = _random_factored(np.random.default_rng(seed))[0]
    if x0 is not None:
        point = " ".join("1.0" if i == x0 else "0.0" for i in range(3))
        text, n = re.subn(
            r"(<Var>x0</Var><Parent>null</Parent>.*?<ProbTable>)[^<]*(</ProbTable>)",
            rf"\g<1>{point}\g<2>",
            text,
            count=1,
        )
        assert n == 1
    f = tmp_path / f"m{seed}.pomdpx"
    f.write_text(text)
    return f, read_pomdpx(f)


CONFIG = SearchConfig(time_limit_s=None, target_gap=1e-6, max_trials=80)


@pytest.mark.parametrize("seed", range(4))
def test_block_search_brackets_the_flat_search_value(tmp_path, seed):
    """Both searches bound the same V*(b0): each one's lower bound is below the other's
    upper bound, both gaps small."""
    _, m = _model(tmp_path, seed)
    blocks = search_blocks(m)
    assert blocks is not None and blocks.shape == (3, 4)
    rb = BlockTreeSearch(m, blocks, CONFIG).run()
    rf = BeliefTreeSearch(m, CONFIG).run()
    tol = 1e-9
    assert rb.lower_bound <= rf.upper_bound + tol and rf.lower_bound <= rb.upper_bound + tol
    assert rb.lower_bound <= rb.upper_bound + tol
    assert rb.gap < 0.1 * abs(rb.lower_bound) and rf.gap < 0.1 * abs(rf.lower_bound)
    # the lower bound reported is the written policy's value at b0, and it never fell
    assert rb.policy.value(m.b0) == pytest.approx(rb.lower_bound, abs=1e-9)
    lows = [h.lower for h in rb.history]
    assert all(b >= a - 1e-12 for a, b in zip(lows, lows[1:], strict=False))


def test_block_vectors_cover_their_block_only(tmp_path):
    """A block policy's vectors hold one block's values: a belief in block x is valued by
    the vectors of block x alone, a belief across blocks by none."""
    _, m = _model(tmp_path, 0)
    blocks = search_blocks(m)
    r = BlockTreeSearch(m, blocks, CONFIG).run()
    pol = r.policy
    assert pol.blocks is not None and pol.alphas.shape[1] == 4 and pol.n_states == 12
    assert set(pol.obs.tolist()) == {0, 1, 2}
    b = np.zeros(12)
    b[blocks[2]] = 0.25
    v = pol.values(b)
    assert np.isfinite(v[pol.obs == 2]).all() and np.isneginf(v[pol.obs != 2]).all()
    assert np.isneginf(pol.values(np.full(12, 1 / 12))).all()


def test_block_policy_round_trip_sarsop_layout_and_npz(tmp_path):
    """Written as SARSOP's factored XML (obsValue per vector, vectorLength the block
    size) and as .npz, read back: same values and actions at beliefs in every block."""
    _, m = _model(tmp_path, 2)
    pol = BlockTreeSearch(m, search_blocks(m), CONFIG).run().policy
    xml = pol.save(tmp_path / "p.policy")
    head = xml.read_text().splitlines()[2]
    assert 'vectorLength="4" numObsValue="3"' in head
    back = read_policy_xml(xml, 12, observed_blocks(m))
    npz = AlphaPolicy.load(pol.save(tmp_path / "p.npz"), n_states=12)
    assert npz.blocks is not None and (npz.obs == pol.obs).all()
    rng = np.random.default_rng(0)
    for rows in observed_blocks(m):
        for _ in range(5):
            b = np.zeros(12)
            b[rows] = rng.dirichlet(np.ones(rows.size))
            assert back.action(b) == pol.action(b) == npz.action(b)
            assert back.value(b) == pytest.approx(pol.value(b), abs=1e-9)
            assert back.value(b) <= pol.value(b)  # written values are rounded down


def test_solve_takes_the_block_search_when_b0_is_in_one_block(tmp_path):
    _, m = _model(tmp_path, 1)
    r = solve(m, SolverConfig(trials=50))
    assert r.policy.meta["solver"] == "sarsop-blocks" and r.policy.blocks is not None
    # off, or b0 spread over several blocks: the flat search
    assert solve(m, SolverConfig(trials=50, factored=False)).policy.blocks is None
    _, spread = _model(tmp_path, 1, x0=None)
    assert search_blocks(spread) is None
    assert solve(spread, SolverConfig(trials=50)).policy.meta["solver"] == "sarsop"


def test_cli_writes_the_factored_layout_and_evaluates_it(tmp_path, capsys):
    from vigil.cli import main as vigil

    f, _ = _model(tmp_path, 3)
    out = tmp_path / "m.policy"
    assert vigil(["solve-pomdp", str(f), "--trials", "30", "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["backups"] > summary["iterations"] > 0  # the root, then each trial
    assert 'numObsValue="3"' in out.read_text()[:400]
    assert vigil(["evaluate", str(f), "--policy", str(out), "--episodes", "5", "--json"]) == 0
    assert "mean" in capsys.readouterr().out


def test_block_policy_must_fit_its_blocks():
    with pytest.raises(ValueError, match="blocks"):
        AlphaPolicy(np.zeros((1, 3)), np.zeros(1, dtype=int), blocks=np.arange(4).reshape(2, 2))
    with pytest.raises(ValueError, match="obs"):
        AlphaPolicy(
            np.zeros((1, 2)),
            np.zeros(1, dtype=int),
            blocks=np.arange(4).reshape(2, 2),
            obs=np.array([2]),
        )
    with pytest.raises(ValueError, match="once"):
        AlphaPolicy(
            np.zeros((1, 2)),
            np.zeros(1, dtype=int),
            blocks=np.array([[0, 1], [1, 2]]),
            obs=np.array([0]),
        )


@pytest.mark.slow
def test_rocksample_7_8_pomdpx_policy_in_sarsop_layout(tmp_path, capsys):
    """SARSOP's RockSample_7_8.pomdpx: solve-pomdp writes vectors per robot cell over the
    256 rock values, read back onto the flat states they value b0 at the lower bound;
    SARSOP's pomdpsim (when built) simulates the file as written."""
    import json
    import shutil
    import subprocess

    from test_heldout_rocksample import SARSOP_EXAMPLES

    from vigil.cli import main as vigil

    model = SARSOP_EXAMPLES / "RockSample_7_8.pomdpx"
    if not model.is_file():
        pytest.skip("SARSOP's examples are not here")
    out = tmp_path / "rs.policy"
    assert vigil(["solve-pomdp", str(model), "--trials", "20", "-o", str(out), "--json"]) == 0
    lower = json.loads(capsys.readouterr().out)["lower_bound"]
    assert 'vectorLength="256" numObsValue="50"' in out.read_text()[:400]
    m = read_pomdpx(model)
    back = AlphaPolicy.load(out, n_states=m.n_states, obs_blocks=observed_blocks(m))
    assert back.value(m.b0) == pytest.approx(lower, abs=1e-6)
    sim = SARSOP_EXAMPLES.parents[1] / "src" / "pomdpsim"
    if not sim.is_file() or shutil.which(str(sim)) is None:
        return
    run = subprocess.run(
        [str(sim), str(model), "--policy-file", str(out), "--simLen", "20", "--simNum", "5"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    assert "Exp Total Reward" in run.stdout, run.stdout


def test_best_vectors_of_beliefs_within_one_block_and_across_blocks(tmp_path):
    """_best_cols: the best vector of each belief (column) among its block's vectors, the
    same whether all the beliefs lie in one block or in several."""
    _, m = _model(tmp_path, 2)
    blocks = search_blocks(m)
    s = BlockTreeSearch(m, blocks, SearchConfig(time_limit_s=None, max_trials=20))
    s.run()
    rng = np.random.default_rng(0)
    alphas, blk = s.alphas, s.blocks_of

    def brute(idx, M):
        x = s._where[idx[0]]
        vals = M.T @ alphas[blk == x][:, s._pos[idx]].T
        return vals.max(axis=1)

    one = np.sort(rng.choice(blocks[1], size=3, replace=False))
    M1 = rng.dirichlet(np.ones(3), size=4).T
    best, values = s._best_cols(one, M1)
    np.testing.assert_allclose(values, brute(one, M1))
    assert (s.blocks_of[best] == 1).all()
    # two blocks: columns 0-1 in block 0, 2-3 in block 2
    both = np.concatenate([blocks[0], blocks[2]])
    M2 = np.zeros((both.size, 4))
    M2[:4, :2] = rng.dirichlet(np.ones(4), size=2).T
    M2[4:, 2:] = rng.dirichlet(np.ones(4), size=2).T
    best, values = s._best_cols(both, M2)
    np.testing.assert_allclose(values[:2], brute(blocks[0], M2[:4, :2]))
    np.testing.assert_allclose(values[2:], brute(blocks[2], M2[4:, 2:]))
    assert (s.blocks_of[best] == [0, 0, 2, 2]).all()
