"""The planner's step machine (stack.planning.stepper): when a decision step ends."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stack.planning.agent import Observed, PlannerAgent
from stack.planning.bounds import qmdp
from stack.planning.model import build_model
from stack.planning.policy import AlphaPolicy
from stack.planning.stepper import DecisionSteps, StepTiming
from stack.planning.task import load_task

TASK = Path(__file__).resolve().parents[1] / "config" / "task-r1.yaml"


@pytest.fixture(scope="module")
def parts():
    model = build_model(load_task(TASK))
    pomdp = model.flat()
    q = qmdp(pomdp)  # (S, A): one vector per action is enough to drive the machine
    policy = AlphaPolicy(q.T.copy(), np.arange(q.shape[1]))
    return model, pomdp, policy


def machine(parts, **timing):
    model, pomdp, policy = parts
    agent = PlannerAgent(model, pomdp, policy, model.initial_belief(7, [(None, "Not moving")]))
    t = StepTiming(start_delay_s=1.0, min_step_s=2.5, min_event_step_s=1.5, **timing)
    return DecisionSteps(agent, t, first_person=None)


def kinds(commands):
    return [c.kind for c in commands]


def obs(person="No person", robot="7", velocity="Not moving"):
    return Observed(robot, person, velocity)


def test_starts_after_the_delay_and_acts(parts):
    m = machine(parts)
    assert m.tick(0.5) == []
    cmds = m.tick(1.0)
    assert kinds(cmds) == ["act"] and m.waiting == "nav"


def test_on_a_real_clock_the_delay_counts_from_the_origin(parts):
    """Off lock-step the node's clock is an epoch time: the delay counts from when the
    machine was made (before, any epoch time was past the delay: no wait at all)."""
    m = machine(parts)
    m.origin_s = 1.8e9
    assert m.tick(1.8e9 + 0.5) == []
    assert kinds(m.tick(1.8e9 + 1.0)) == ["act"]


def test_do_nothing_holds_min_step_s_then_asks(parts):
    m = machine(parts)
    m.tick(1.0)
    m.sent_action = "Do nothing"
    assert m.on_nav_result(1.1, {"result": "succeeded", "action": "Do nothing"}) == []
    assert m.waiting == "hold"
    assert m.tick(3.0) == []
    assert kinds(m.tick(3.5)) == ["request"]
    cmds = m.on_observation(3.6, obs())
    assert kinds(cmds) == ["record", "act"] and cmds[0].record["trigger"] == "step"


def test_a_move_ends_when_the_robot_enters_its_cell(parts):
    m = machine(parts)
    m.tick(1.0)
    m.sent_action = "East"
    assert kinds(m.on_nav_result(2.0, {"result": "succeeded", "action": "East"})) == ["request"]


def test_a_superseded_result_is_ignored(parts):
    m = machine(parts)
    m.tick(1.0)
    m.sent_action = "East"
    assert m.on_nav_result(1.2, {"result": "succeeded", "action": "West"}) == []
    assert m.waiting == "nav"


def test_a_person_in_a_new_cell_ends_the_step_early(parts):
    m = machine(parts)
    m.tick(1.0)
    # too soon after the step began: no event
    assert m.on_observation(2.0, obs("2", velocity="South higher")) == []
    cmds = m.on_observation(2.6, obs("2", velocity="South higher"))
    assert kinds(cmds) == ["record", "act"]
    assert cmds[0].record["trigger"] == "person in 2"
    assert cmds[0].record["nav"]["result"] == "in progress"
    # the same cell again is no event; nobody seen is no event either
    assert m.on_observation(4.5, obs("2")) == []
    assert m.on_observation(4.6, obs("No person")) == []
    assert kinds(m.on_observation(4.7, obs("1"))) == ["record", "act"]


def test_events_off_and_timeouts(parts):
    m = machine(parts, nav_timeout_s=5.0, obs_timeout_s=2.0)
    m.timing = StepTiming(start_delay_s=1.0, min_step_s=2.5, min_event_step_s=0.0,
                          nav_timeout_s=5.0, obs_timeout_s=2.0)  # fmt: skip
    m.tick(1.0)
    assert m.on_observation(3.0, obs("2", velocity="South higher")) == []
    cmds = m.tick(6.5)  # no navigation result: read the observations anyway
    assert kinds(cmds) == ["log", "request"] and m.last_nav == {"result": "timeout"}
    assert kinds(m.tick(9.0)) == ["log", "request"]  # no observation: ask again


def test_max_steps_ends_the_run(parts):
    m = machine(parts, max_steps=1)
    m.tick(1.0)
    m.sent_action = "East"
    m.on_nav_result(2.0, {"result": "succeeded", "action": "East"})
    cmds = m.on_observation(2.1, obs())
    assert kinds(cmds) == ["record", "done"] and m.agent.phase == "done"


def test_each_step_sends_its_own_goal_id_and_a_late_result_is_not_taken(parts):
    """Issue 14: step 1's goal times out; its result arrives during step 2 (same action
    name even): it must not end step 2; step 2's own result does."""
    m = machine(parts, nav_timeout_s=5.0)
    (act,) = m.tick(1.0)
    assert act.kind == "act" and act.goal_id == 1
    m.tick(6.5)  # no result: the step reads the observations anyway
    cmds = m.on_observation(6.6, obs())
    assert kinds(cmds) == ["record", "act"]
    assert cmds[0].record["goal_id"] == 1 and cmds[0].record["nav"] == {"result": "timeout"}
    second = cmds[1]
    assert second.goal_id == 2 and m.waiting == "nav"
    late = {"goal_id": 1, "result": "succeeded", "action": second.action}
    assert m.on_nav_result(7.0, late) == [] and m.waiting == "nav" and m.last_nav is None
    assert m.on_nav_result(7.1, {**late, "goal_id": 0}) == []  # an operator's goal
    own = {**late, "goal_id": 2}
    m.on_nav_result(7.2, own)
    assert m.last_nav == own and m.waiting in ("obs", "hold")


def test_a_move_that_arrives_the_instant_it_is_sent_is_held_not_repeated():
    """Navigation answering "succeeded" at the very instant of the action (it already
    sees the robot in the target cell) must not end the step at once: that looped
    decide-act-observe without time passing."""
    from stack.planning.agent import Observed

    class Always:
        step, phase, action = 0, "start", None

        def decide(self):
            self.action = 2  # East
            return 2

        def observe(self, observed):
            self.step += 1
            return {"step": self.step}

        def track(self, t, observed):
            return None

    m = DecisionSteps(Always(), StepTiming(start_delay_s=0.0, min_step_s=2.5))
    assert [c.kind for c in m.tick(10.0)] == ["act"]
    assert m.on_nav_result(10.0, {"result": "succeeded", "action": "East"}) == []
    assert m.waiting == "hold"
    obs = Observed("3", "1", "Not moving")
    assert m.on_observation(10.0, obs) == []  # no step ends while holding
    assert [c.kind for c in m.tick(12.5)] == ["request"]  # the hold ends after min_step_s
