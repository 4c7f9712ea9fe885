"""The run-time lookahead with per-block vectors (stack.planning.pbvi.BlockVectors)."""

import numpy as np
import pytest

from stack.planning.model import build_model
from stack.planning.pbvi import Backup, BlockVectors, nondominated
from stack.planning.task import load_task
from vigil.run import REPO


def test_nondominated_keeps_what_can_be_best_and_one_of_equal_rows():
    v = np.array(
        [
            [1.0, 1.0, 1.0],
            [2.0, 0.0, 1.0],  # best at the second state's absence: kept
            [0.5, 0.5, 0.5],  # below row 0 everywhere
            [1.0, 1.0, 1.0],  # equal to row 0: one of them
            [0.0, 3.0, 0.0],
            [1.0, 1.0, 0.9],  # below row 0 everywhere (ties count)
        ]
    )
    kept = nondominated(v).tolist()
    assert len(kept) == 3 and {1, 4} <= set(kept) and len({0, 3} & set(kept)) == 1


@pytest.fixture(scope="module")
def task_model():
    model = build_model(load_task(REPO / "config" / "task-r1.yaml"))
    return model, model.flat()


def test_per_block_vectors_give_the_lookahead_of_all_vectors(task_model):
    """Whatever the vectors, scoring each observation with its block's undominated
    vectors gives the values of scoring it with all of them (the robot's cell is the
    block; beliefs with the robot certain and uncertain, so that some observations
    come from several blocks)."""
    model, pomdp = task_model
    rng = np.random.default_rng(4)
    S = pomdp.n_states
    # vectors with structure (a few dominate on some cells, none everywhere) and noise
    alphas = rng.normal(size=(300, S)) + rng.normal(size=(300, 1)) * 3
    blocks = model.robot_blocks()
    assert blocks.shape == (S,) and set(np.unique(blocks)) == set(range(model.state_shape[0]))
    by_block = BlockVectors(alphas, blocks)
    backup = Backup(pomdp)
    for k in range(12):
        b = np.zeros(S)
        robots = [int(rng.integers(model.state_shape[0]))] if k % 2 else rng.choice(13, 3)
        states = [s for s in range(S) if blocks[s] in set(np.atleast_1d(robots))]
        b[rng.choice(states, 20, replace=False)] = rng.random(20)
        b /= b.sum()
        full = backup.lookahead_values(alphas, b)
        fast = backup.lookahead_values(alphas, b, by_block)
        np.testing.assert_allclose(fast, full, rtol=1e-12, atol=1e-9)
    # the point of it: far fewer vectors per block than in all
    assert max(len(by_block.rows((c,))) for c in range(13)) < 300
    # a partition the observations do not reveal: observations from several blocks
    # are scored with the vectors undominated on all of them, still the same values
    arbitrary = BlockVectors(alphas, np.arange(S) % 7)
    b = rng.random(S) * (rng.random(S) < 0.05)
    b /= b.sum()
    np.testing.assert_allclose(
        backup.lookahead_values(alphas, b, arbitrary),
        backup.lookahead_values(alphas, b),
        rtol=1e-12,
        atol=1e-9,
    )


def test_blocks_must_match_the_states():
    with pytest.raises(ValueError, match="one per state"):
        BlockVectors(np.zeros((3, 5)), np.zeros(4, int))


def _reference_lookahead(backup, alphas, b):
    """The lookahead as it was before its kept blocks: the full sparse products."""
    q = np.empty(backup.A)
    for a in range(backup.A):
        pred = backup.TT[a] @ b
        idx = np.flatnonzero(pred)
        Osub = backup.O[a][idx]
        zs = np.flatnonzero(Osub.T @ pred[idx] > 0)
        weighted = Osub[:, zs].toarray() * pred[idx][:, None]
        q[a] = backup.R[:, a] @ b + backup.gamma * (alphas[:, idx] @ weighted).max(axis=0).sum()
    return q


def test_the_kept_observation_blocks_give_the_same_values_to_the_last_bit(task_model):
    """The lookahead keeps each successor set's observation block (a run reuses a
    handful): the same values, bit for bit, as the full products, whether the block
    was kept or not; and the kept blocks are bounded."""
    from stack.planning import pbvi

    model, pomdp = task_model
    rng = np.random.default_rng(7)
    S = pomdp.n_states
    alphas = rng.normal(size=(50, S))
    backup = Backup(pomdp)
    beliefs = []
    for _ in range(6):
        b = np.zeros(S)
        b[rng.choice(S, 15, replace=False)] = rng.random(15)
        beliefs.append(b / b.sum())
    for b in beliefs + beliefs:  # the second round finds its blocks kept
        assert np.array_equal(
            backup.lookahead_values(alphas, b), _reference_lookahead(backup, alphas, b)
        )
    assert 0 < len(backup.kept_blocks) <= 6 * backup.A
    for _ in range(pbvi.MAX_OBSERVATION_BLOCKS):  # many distinct successor sets
        b = np.zeros(S)
        b[rng.choice(S, 3, replace=False)] = 1 / 3
        backup.lookahead_values(alphas, b)
    assert len(backup.kept_blocks) <= pbvi.MAX_OBSERVATION_BLOCKS
