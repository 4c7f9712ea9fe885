"""Chapter 5 replayed: our planner against tables 5.1-5.4 (solves both task models)."""

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from stack.planning.replay import TABLES
from vigil.cli import build_parser, main
from vigil.replay import run_replay

REPO = Path(__file__).resolve().parents[1]


def _args() -> argparse.Namespace:
    """The replay command's own defaults: the task solver (TASK_CONFIG)."""
    return build_parser().parse_args(["replay", "--quiet"])


@pytest.fixture(scope="module")
def replay():
    results, solved = run_replay(list(TABLES), _args())
    return results, solved


def test_tables_are_complete():
    assert [len(t.steps) for t in TABLES.values()] == [12, 11, 10, 17]
    assert sum(len(t.quotes) for t in TABLES.values()) == 32


@pytest.mark.slow  # solves both tasks (minutes); CI runs it
def test_replay_agrees_with_the_thesis(replay):
    results, _ = replay
    agree = sum(r.agreement for r in results)
    with_ties = sum(r.agreement_with_ties for r in results)
    assert agree >= 47, [
        (r.table.name, s.step, s.thesis_action, s.chosen_action)
        for r in results
        for s in r.steps
        if not s.agrees
    ]
    assert with_ties >= agree


@pytest.mark.slow  # solves both tasks (minutes); CI runs it
def test_quoted_beliefs_are_close_to_the_thesis(replay):
    results, _ = replay
    errors = np.array([q.ours - q.quote.thesis for r in results for q in r.quotes])
    # issue 12's bar: every quoted belief within 0.1 (the recalibrated model: 0.072)
    assert np.sqrt(np.mean(errors**2)) < 0.05
    assert np.abs(errors).max() < 0.1


@pytest.mark.slow  # solves both tasks (minutes); CI runs it
def test_the_first_quoted_beliefs(replay):
    """After step 1 of table 5.1: P(East) = 0.75, P(at 9) = 0.22, P(at 11) = 0.73, each
    within issue 12's 0.1 (the second fit gives 0.70, 0.26, 0.70: it trades these for
    the largest errors elsewhere, max 0.208 -> 0.072)."""
    results, _ = replay
    q = {(x.quote.what, x.quote.values): x.ours for x in results[0].quotes if x.quote.step == 1}
    assert q[("direction", ("East",))] == pytest.approx(0.75, abs=0.1)
    assert q[("position", (9,))] == pytest.approx(0.22, abs=0.1)
    assert q[("position", (11,))] == pytest.approx(0.73, abs=0.1)


@pytest.mark.slow  # solves both tasks (minutes); CI runs it
def test_solved_bounds_are_consistent(replay):
    _, solved = replay
    for _model, _pomdp, result in solved.values():
        assert result.lower_bound <= result.upper_bound
        values = [s.value_b0 for s in result.history]
        assert values[-1] >= values[0]


@pytest.mark.slow  # solves both tasks (minutes); CI runs it
def test_cli_replay_json(capsys):
    code = main(["replay", "--table", "5.2", "--json", "--quiet", "--iterations", "60"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    table = out["5.2"]
    assert len(table["steps"]) == 11
    first = table["steps"][0]
    assert first["thesis_action"] == "South"
    assert first["observation"] == {"robot": 7, "person": None, "velocity": "Not moving"}
    assert {"step", "belief", "thesis", "ours"} <= set(table["quoted_beliefs"][0])


def test_the_action_is_the_plain_argmax_and_only_equal_values_tie():
    """The policy's action: the argmax; "Do nothing" wins only among equal values (up to
    rounding), not within a band (the 0.5 % band the replay used before issue 12)."""
    from stack.planning.model import build_model
    from stack.planning.policy import AlphaPolicy
    from stack.planning.replay import policy_chooser
    from stack.planning.task import load_task
    from stack.vocabulary import ACTIONS

    pomdp = build_model(load_task(REPO / "config" / "task-r1.yaml")).flat()
    stay, north = ACTIONS.index("Do nothing"), ACTIONS.index("North")
    b = pomdp.b0

    def chosen(v_north: float, v_stay: float) -> int:
        alphas = np.full((2, pomdp.n_states), 0.0)
        alphas[0], alphas[1] = v_north, v_stay
        policy = AlphaPolicy(alphas, np.array([north, stay]))
        return policy_chooser(policy, pomdp, lookahead=False)(b)[0]

    assert chosen(100.0, 99.9) == north  # 0.1 % better: moves
    assert chosen(99.9, 100.0) == stay
    assert chosen(100.0, 100.0 - 1e-9) == stay  # equal up to rounding: waits
