"""The anticipation layer (stack.planning.anticipate, person_model: goal): where the
robot heads while a person walks, and how the agent and the step machine use it."""

from __future__ import annotations

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError
from stack.planning.agent import Observed, PlannerAgent
from stack.planning.anticipate import AnticipationConfig, Anticipator, first_move
from stack.planning.model import build_model
from stack.planning.policy import AlphaPolicy
from stack.planning.stepper import DecisionSteps, StepTiming
from stack.planning.task import Task, load_task
from vigil.run import REPO

GRID = CellGrid()  # 12 10 8 6 4 2 / 11 9 7 5 3 1; cell 1 is x 5-6, y 0-1.5
DOOR = (7.0, 4.4)


def walk(a, b, speed=1.0, dt=0.25):
    """Floor points from a to b at ``speed`` every ``dt`` seconds."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(1, int(np.linalg.norm(b - a) / (speed * dt)))
    return [tuple(a + (b - a) * k / n) for k in range(n + 1)]


def test_first_move_follows_a_shortest_path_of_cells():
    assert first_move(GRID, 7, 1) == "East"
    assert first_move(GRID, 12, 11) == "South"
    assert first_move(GRID, 1, 1) is None
    assert first_move(GRID, 2, 11) in ("West", "South")


def test_a_person_walking_to_cell_1_makes_the_robot_head_there_before_they_arrive():
    ant = Anticipator(GRID, (1,), AnticipationConfig())
    t, events, advised_at = 0.0, [], None
    for p in walk(DOOR, (5.5, 0.75)):
        if ant.observe(t, p):
            events.append((t, ant.target))
        if advised_at is None and ant.advise(7) == "East":
            advised_at = (t, p)
        t += 0.25
    assert advised_at is not None and GRID.cell_at(*advised_at[1]) != 1  # before entry
    assert ant.advise(1) in ("Do nothing", None)  # there first: wait for the person
    assert events[0][1] == 1
    # inside the cell the policy guards: no advice
    ant.observe(t, (5.5, 0.75))
    assert ant.target is None and ant.advise(7) is None


def test_a_decoy_who_turns_away_stops_the_robot_heading_there():
    ant = Anticipator(GRID, (1,), AnticipationConfig())
    t = 0.0
    for p in walk(DOOR, (5.5, 1.8)):  # to cell 1's northern border
        ant.observe(t, p)
        t += 0.25
    assert ant.target == 1
    for p in walk((5.5, 1.8), (1.0, 2.3)):  # and away west
        ant.observe(t, p)
        t += 0.25
    assert ant.target is None and ant.advise(5) is None


def test_the_task_chooses_the_person_model_and_refuses_a_bad_one():
    assert Anticipator.for_task(load_task(REPO / "config" / "task-r1.yaml")) is None
    goal = load_task(REPO / "config" / "task-r1-goal.yaml")
    assert isinstance(Anticipator.for_task(goal), Anticipator)
    with pytest.raises(ConfigError, match="person_model"):
        Task.from_dict({**goal.to_dict(), "person_model": "psychic"}).check()
    with pytest.raises(ConfigError, match="stay_probability"):
        AnticipationConfig(go_probability=0.5, stay_probability=0.7)
    again = Task.from_dict(goal.to_dict())
    assert again.person_model == "goal" and again.anticipation == goal.anticipation


def _agent(task_file: str) -> PlannerAgent:
    task = load_task(REPO / "config" / task_file)
    model = build_model(task)
    pomdp = model.flat()
    stay = AlphaPolicy(np.zeros((1, pomdp.n_states)), np.array([4]))  # always Do nothing
    return PlannerAgent(model, pomdp, stay, anticipator=Anticipator.for_task(task))


def observed(pos, robot="7") -> Observed:
    cell = GRID.cell_at(*pos)
    return Observed(robot, str(cell) if cell else "No person", "West higher",
                    position_m=pos)  # fmt: skip


def test_the_agent_takes_the_advised_move_and_records_why():
    agent = _agent("task-r1-goal.yaml")
    assert agent.decide() == 4  # no evidence yet: the policy's Do nothing
    agent.observe(observed((6.5, 3.8)))
    events = [agent.track(0.25 * k, observed(p)) for k, p in enumerate(walk(DOOR, (5.5, 1.6)))]
    assert "heading for 1" in events
    a = agent.decide()
    assert a == 2  # East, from cell 7 toward cell 1
    rec = agent.observe(observed((5.5, 1.6), robot="5"))
    assert rec["anticipation"]["target"] == 1 and rec["anticipation"]["policy"] == "Do nothing"
    # the thesis model: the same observations leave the policy's action alone
    plain = _agent("task-r1.yaml")
    plain.decide()
    plain.observe(observed((6.5, 3.8)))
    assert [plain.track(0.25 * k, observed(p)) for k, p in enumerate(walk(DOOR, (5.5, 1.6)))]
    assert plain.decide() == 4 and "anticipation" not in plain.observe(observed((5.5, 1.6)))


def test_a_new_target_ends_the_step_early_as_a_person_event_does():
    agent = _agent("task-r1-goal.yaml")
    steps = DecisionSteps(agent, StepTiming(start_delay_s=0.0, min_step_s=2.5,
                                            min_event_step_s=1.0, nav_timeout_s=10.0))  # fmt: skip
    cmds = steps.tick(0.0)
    assert [c.kind for c in cmds] == ["act"]
    triggers = []
    for k, p in enumerate(walk((7.0, 2.5), (6.2, 1.6))):  # within cell 2 all along
        for c in steps.on_observation(0.25 * (k + 1), observed(p)):
            if c.kind == "record":
                triggers.append(c.record["trigger"])
    assert "heading for 1" in triggers
