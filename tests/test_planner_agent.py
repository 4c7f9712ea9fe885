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
from vigil.solving import TASKS, solve_task_file


@pytest.fixture(scope="module")
def solved():
    args = argparse.Namespace(
        beliefs=200, iterations=40, time_limit=None, fib_time=0.0, seed=0, quiet=True
    )
    model, pomdp, result = solve_task_file(TASKS["r1"], args)
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


def test_a_robot_seen_beyond_its_move_moves_the_belief_with_it(solved):
    """A trip crosses several cells in one step: the robot's cell is observed exactly
    and people move whatever the robot does, so the belief follows the robot there and
    the person's belief is updated, not restarted."""
    agent, _ = table_agent(solved)
    agent.decide()
    agent.action = 4  # Do nothing at 7: under the model the robot cannot be seen at 1
    rec = agent.observe(Observed("1", "3", "East higher"))
    assert "beyond the action's move" in rec["note"]
    assert rec["belief"]["robot"]["1"] == pytest.approx(1.0)
    assert 0.5 < rec["belief"]["person"]["3"] < 1.0  # Bayes' rule on the old belief


def test_impossible_observation_restarts_from_what_was_seen(solved, monkeypatch):
    agent, _ = table_agent(solved)
    agent.decide()
    monkeypatch.setattr(agent, "likelihood", lambda *a: np.zeros(agent.pomdp.n_states))
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


def _after(solved, observed_, robot=3, person=1):
    model, pomdp, policy = solved
    agent = PlannerAgent(
        model, pomdp, policy, model.initial_belief(robot, [(person, "Not moving")])
    )
    agent.action = 4  # Do nothing
    agent.observe(observed_)
    return agent


def test_no_person_where_the_camera_cannot_see_keeps_the_person(solved):
    seen_empty = _after(solved, Observed("3", "No person", "Not moving"))
    hidden = _after(solved, Observed("3", "No person", "Not moving", ((1, 1.0),)))
    # the robot hid cell 1: the person is still most likely there, and "No person"
    # barely moved from what the transition alone gives
    p = hidden.marginals()["person"]
    assert p["1"] > 0.5 and p["1"] > 2 * p["No person"]
    # the camera could see cell 1 and saw nobody: the person is far likelier gone
    assert seen_empty.marginals()["person"]["No person"] > 3 * p["No person"]
    # a half-hidden cell keeps less than a hidden one, more than a visible one
    half = _after(solved, Observed("3", "No person", "Not moving", ((1, 0.5),)))
    assert seen_empty.marginals()["person"]["1"] < half.marginals()["person"]["1"] < p["1"]


def test_unseen_follows_the_transition_alone(solved):
    model, pomdp, _ = solved
    agent = _after(solved, Observed("3", "Unseen", "Not moving"))
    b0 = model.initial_belief(3, [(1, "Not moving")])
    pred = (pomdp.TT(4) @ b0).reshape(model.state_shape)
    pred = pred[model.robot_index(3)]  # the robot's cell is still observed exactly
    want = pred.sum(axis=1) / pred.sum()
    got = agent.belief.reshape(model.state_shape)[model.robot_index(3)].sum(axis=1)
    np.testing.assert_allclose(got, want, atol=1e-9)
    assert agent.record(None)["belief"]["robot"]["3"] == pytest.approx(1.0)


def test_malformed_hidden_and_impossible_out_of_map_are_refused(solved):
    with pytest.raises(ObservationError):
        Observed.from_dict({"robot": "3", "person": "No person", "velocity": "Not moving",
                            "hidden": {"1": 7.0}})  # fmt: skip
    with pytest.raises(ObservationError):
        Observed.from_dict({"robot": 3, "person": "No person", "velocity": "Not moving"})
    model, pomdp, policy = solved
    agent = PlannerAgent(model, pomdp, policy, model.initial_belief(7, [(None, "Not moving")]))
    agent.action = 4
    before = agent.belief.copy()
    with pytest.raises(ObservationError, match="Out of the map"):
        agent.observe(Observed("Out of the map", "No person", "Not moving"))
    # a rogue publisher's cell 99 (issue 13) names what is wrong and changes nothing
    with pytest.raises(ObservationError, match="person cell '99'"):
        agent.observe(Observed("3", "99", "Not moving"))
    with pytest.raises(ObservationError, match="robot cell '99'"):
        agent.observe(Observed("99", "No person", "Not moving"))
    np.testing.assert_array_equal(agent.belief, before)


@pytest.mark.parametrize(
    "mutate",
    [
        lambda d: d.update(action=99),
        lambda d: d.update(action="East"),
        lambda d: d.update(step=-1),
        lambda d: d.update(values=["x"]),
        lambda d: d["belief"].__setitem__(0, float("nan")),
        lambda d: d.update(belief=[1.0]),
        lambda d: d.update(phase="dancing"),
    ],
)
def test_a_corrupt_state_file_is_refused_not_crashed_on(solved, tmp_path, mutate):
    agent, _ = table_agent(solved)
    path = tmp_path / "state.json"
    agent.save(path)
    data = json.loads(path.read_text())
    mutate(data)
    path.write_text(json.dumps(data))
    fresh, _ = table_agent(solved)
    with pytest.raises(StateFileError):
        fresh.restore(path)
    path.write_text("[1, 2]")
    with pytest.raises(StateFileError):
        fresh.restore(path)
