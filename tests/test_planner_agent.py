"""The run-time planner: decisions, belief updates, records, persistence."""

import argparse
import json

import numpy as np
import pytest

from stack.planning.agent import (
    ObservationError,
    Observed,
    PlannerAgent,
    StateFileError,
)
from stack.planning.replay import TABLES, policy_chooser, replay_table
from vigil.cli import TASKS, solve_task


@pytest.fixture(scope="module")
def solved():
    args = argparse.Namespace(
        beliefs=200, iterations=40, time_limit=None, fib_time=0.0, seed=0, quiet=True
    )
    model, pomdp, result = solve_task(TASKS["r1"], args)
    return model, pomdp, result.policy


def table_agent(solved, name="5.1"):
    model, pomdp, policy = solved
    t = TABLES[name]
    b0 = model.initial_belief(t.robot, [(t.person, t.direction)])
    return PlannerAgent(model, pomdp, policy, b0), t


def observed(step):
    person = "No person" if step.person is None else str(step.person)
    return Observed(str(step.robot), person, step.velocity)


def test_agent_chooses_what_the_replay_chooses(solved):
    model, pomdp, policy = solved
    agent, table = table_agent(solved)
    replay = replay_table(model, pomdp, table, policy_chooser(policy, pomdp))
    actions = ["North", "South", "East", "West", "Do nothing"]
    for st, res in zip(table.steps, replay.steps, strict=True):
        assert actions[agent.decide()] == res.chosen_action
        # the replay feeds the thesis's action; so does this check
        agent.action = actions.index(st.action)
        rec = agent.observe(observed(st))
        assert rec["observation"]["robot"] == str(st.robot)
    assert agent.step == len(table.steps)
    np.testing.assert_allclose(agent.belief, replay.beliefs[-1], atol=1e-12)


def test_record_holds_marginals_that_sum_to_one(solved):
    agent, table = table_agent(solved)
    agent.decide()
    rec = agent.observe(observed(table.steps[0]))
    assert rec["step"] == 1 and rec["note"] is None
    for name in ("robot", "person", "direction"):
        assert sum(rec["belief"][name].values()) == pytest.approx(1.0, abs=1e-5)
    assert rec["belief"]["robot"]["7"] == pytest.approx(1.0)
    assert set(rec["belief"]["person"]) == {str(c) for c in range(1, 13)} | {"No person"}
    assert len(rec["values"]) == 5


def test_bad_labels_leave_the_belief_alone(solved):
    agent, _ = table_agent(solved)
    agent.decide()
    before = agent.belief.copy()
    for bad in (
        Observed("13", "9", "Not moving"),
        Observed("7", "nine", "Not moving"),
        Observed("7", "9", "Eastish"),
    ):
        with pytest.raises(ObservationError):
            agent.observe(bad)
    np.testing.assert_array_equal(agent.belief, before)
    assert agent.step == 0
    with pytest.raises(ObservationError, match="without 'velocity'"):
        Observed.from_dict({"robot": "7", "person": "9"})


def test_impossible_observation_restarts_from_what_was_seen(solved):
    agent, _ = table_agent(solved)
    agent.decide()
    agent.action = 4  # Do nothing at 7: the robot cannot be seen at 1
    rec = agent.observe(Observed("1", "3", "East higher"))
    assert "impossible" in rec["note"]
    assert rec["belief"]["robot"]["1"] == pytest.approx(1.0)
    assert rec["belief"]["person"]["3"] == pytest.approx(1.0)
    assert rec["belief"]["direction"]["East"] == pytest.approx(1.0)


def test_state_file_round_trip_and_refusals(solved, tmp_path):
    agent, table = table_agent(solved)
    agent.decide()
    agent.observe(observed(table.steps[0]))
    agent.decide()
    path = tmp_path / "state.json"
    agent.save(path)
    other, _ = table_agent(solved)
    assert other.restore(path)
    np.testing.assert_array_equal(other.belief, agent.belief)
    assert (other.step, other.phase, other.action) == (1, "acting", agent.action)
    assert not other.restore(tmp_path / "none.json")
    data = json.loads(path.read_text())
    data["fingerprint"] = "0" * 16
    path.write_text(json.dumps(data))
    with pytest.raises(StateFileError, match="another model"):
        other.restore(path)
    path.write_text('{"belief": [1.0')
    with pytest.raises(StateFileError, match="unreadable"):
        other.restore(path)
    np.testing.assert_array_equal(other.belief, agent.belief)  # untouched by failures
