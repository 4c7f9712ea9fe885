"""The anticipation layer (stack.planning.anticipate, person_model: goal): where the
robot heads while a person walks, and how the agent and the step machine use it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError, first_move
from stack.planning.agent import Observed, PlannerAgent
from stack.planning.anticipate import AnticipationConfig, Anticipator
from stack.planning.intent import IntentConfig
from stack.planning.model import build_model
from stack.planning.policy import AlphaPolicy
from stack.planning.standby import trip_lengths
from stack.planning.stepper import DecisionSteps, StepTiming
from stack.planning.task import Task, load_task
from vigil.run import REPO

GRID = CellGrid()  # 12 10 8 6 4 2 / 11 9 7 5 3 1; cell 1 is x 5-6, y 0-1.5
# steps as weak evidence (rationality 3 per metre, not the default 10): the goal of a
# walk stays unclear for metres, long enough to see what the layer does meanwhile
WEAK = IntentConfig(rationality_per_m=3.0)
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
        if advised_at is None and ant.advise(7) == "To 1":  # a trip straight into cell 1
            advised_at = (t, p)
        t += 0.25
    assert advised_at is not None and GRID.cell_at(*advised_at[1]) != 1  # before entry
    cells = Anticipator(GRID, (1,), AnticipationConfig(motion="cells"))
    for k, p in enumerate(walk(DOOR, (5.5, 1.6))):
        cells.observe(0.25 * k, p)
    assert cells.target == 1 and cells.advise(7) == "East"  # the thesis's moves: the first
    assert ant.advise(1) in ("Do nothing", None)  # there first: wait for the person
    assert events[0][1] == 1
    # inside the cell: the cell is the target, wherever the robot is
    ant.observe(t, (5.5, 0.75))
    assert ant.target == 1 and ant.advise(7) == "To 1" and ant.advise(1) == "Do nothing"


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
    assert a == 2  # East, from cell 7 toward cell 1: the model's first move of the trip
    assert agent.command == "To 1"  # what navigation is sent: the trip
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
    triggers, sent = [], []
    for k, p in enumerate(walk((7.0, 2.5), (6.2, 1.6))):  # within cell 2 all along
        for c in steps.on_observation(0.25 * (k + 1), observed(p)):
            if c.kind == "record":
                triggers.append(c.record["trigger"])
            elif c.kind == "act":
                sent.append(c.action)
    assert "heading for 1" in triggers
    assert sent[-1] == "To 1" and steps.sent_action == "To 1"  # navigation gets the trip


def test_the_watch_cell_is_one_move_from_a_lone_restricted_cell_and_equidistant_from_two():
    from stack.planning.standby import travel_m, watch_cell

    assert travel_m(GRID, 7)[1] == pytest.approx(3.0)  # 7 -> 5 -> 3 -> 1, 1 m each
    assert travel_m(GRID, 7)[12] == pytest.approx(3.5)  # 2 m west, 1.5 m north
    assert watch_cell(GRID, (1,)) == 3  # 1 m west of cell 1 (cell 2 is 1.5 m away)
    # r2 (1 and 12): 6 and 7 are both 3.5 m from the farther cell; the lower number wins
    assert watch_cell(GRID, (1, 12)) == 6
    with pytest.raises(ValueError, match="every cell is restricted"):
        watch_cell(CellGrid(numbering=((1, 2),)), (1, 2))


def test_rest_cell_auto_in_a_task_file_is_the_watch_cell_and_bad_cells_are_named():
    base = load_task(REPO / "config" / "task-r1.yaml").to_dict()
    assert Task.from_dict({**base, "rest_cell": "auto"}).rest_cell == 3
    assert Task.from_dict({**base, "rest_cell": "auto", "restricted_cells": [1, 12]}).rest_cell == 6
    assert load_task(REPO / "config" / "task-r1-goal.yaml").rest_cell == 3
    with pytest.raises(ConfigError, match="restricted_cells"):
        Task.from_dict({**base, "rest_cell": "auto", "restricted_cells": [99]}).check()
    with pytest.raises(ConfigError, match="rest_cell"):
        Task.from_dict({**base, "rest_cell": "nearby"})


def _standing_then(ant, point, seconds=3.0, t0=0.0):
    t = t0
    while t < t0 + seconds:
        ant.observe(t, point)
        t += 0.25
    return t


def test_the_layer_holds_back_an_entry_for_a_person_not_heading_there():
    """The thesis's policy enters cell 1 for a person next to it; a person standing in
    cell 3's far corner or walking away is not heading for it: Do nothing instead.
    Moves elsewhere, a person inside the cell, or an unseen person: the policy."""
    ant = Anticipator(GRID, (1,), AnticipationConfig())
    t = 0.0
    for p in walk((5.5, 0.75), (2.0, 0.75)):  # out of cell 1 and walking west
        ant.observe(t, p)
        t += 0.25
    assert ant.target is None and ant.estimate.p(1) < 0.35
    assert ant.advise(3, "East") == "Do nothing"  # into cell 1: held back
    assert ant.advise(3, "West") is None and ant.advise(5, "East") is None  # not into 1
    ant.observe(t + 10.0, None)  # unseen for 10 s: the policy's belief decides
    assert ant.advise(3, "East") is None
    ant.observe(t + 10.25, (5.5, 0.75))  # inside: the trip there, at once
    assert ant.advise(3, "East") == "To 1" and ant.advise(1, "West") == "Do nothing"


def test_the_layer_lets_the_robot_in_for_a_person_walking_to_the_cell():
    ant = Anticipator(GRID, (1,), AnticipationConfig())
    t = 0.0
    for p in walk((1.0, 0.75), (4.7, 0.75), speed=1.2):  # along the row, to cell 1
        ant.observe(t, p)
        t += 0.25
    assert ant.advise(3, "East") == "To 1"  # the layer's own trip, not just allowed in


def test_with_the_doorway_as_an_exit_a_person_walking_out_is_not_heading_for_cell_1():
    """A walk from cell 7 straight to the doorway north-east of cell 1: without the
    exit it is best explained by cell 1 (the robot heads there); with the room's
    doorway among the goals it is not, and the belief in cell 1 falls early."""
    path = walk((2.5, 0.75), (7.0, 5.2))[:-4]
    targets, p1 = {}, {}
    for exits in ((), ((7.0, 5.2),)):
        ant = Anticipator(GRID, (1,), AnticipationConfig(exits_m=exits, intent=WEAK))
        seen = set()
        for k, p in enumerate(path):
            ant.observe(0.25 * k, p)
            seen.add(ant.target)
            if k == 9:  # 2.25 s in (a track's first steps wait for its smoothing)
                p1[exits] = ant.estimate.p(1)
        targets[exits] = seen
    assert 1 in targets[()] and targets[((7.0, 5.2),)] == {None}
    assert p1[((7.0, 5.2),)] < 0.35 < p1[()]


def test_the_robot_heads_out_just_in_time_for_its_trip():
    """A slow walker (0.5 m/s) straight for cell 1: with the robot one move away (cell
    3: 1 m, 2.5 s at 0.4 m/s, + 1.5 s lead) the target is set only once the person's
    predicted entry is within those 4 s (2 m); with the robot three moves away (cell 7,
    9 s) as soon as the goal is likely, as with its cell unknown."""
    path = walk((0.5, 0.75), (5.2, 0.75), speed=0.5)
    first_at = {}
    for robot in (3, 7, None):
        ant = Anticipator(GRID, (1,), AnticipationConfig())
        for k, p in enumerate(path):
            ant.observe(0.25 * k, p, robot)
            if ant.target == 1 and robot not in first_at:
                first_at[robot] = (p, ant.estimate.forecast(1).eta_s)
                break
    (x3, _), eta3 = first_at[3]
    assert 5.0 - x3 <= 2.0 + 0.15 and eta3 <= 4.0
    assert first_at[None][0][0] == first_at[7][0][0] < x3 - 1.0


def test_a_trip_under_way_survives_a_planner_restart(tmp_path):
    agent = _agent("task-r1-goal.yaml")
    agent.decide()
    agent.observe(observed((6.5, 3.8)))
    for k, p in enumerate(walk(DOOR, (5.5, 1.6))):
        agent.track(0.25 * k, observed(p))
    agent.decide()
    assert agent.command == "To 1"
    path = tmp_path / "planner_state.json"
    path.write_text(json.dumps(agent.state()))
    again = _agent("task-r1-goal.yaml")
    assert again.restore(path) and again.command == "To 1" and again.action == agent.action
    path.write_text(json.dumps({**agent.state(), "command": "To 99"}))  # no such cell
    assert again.restore(path) and again.command == "East"  # the action's own name


def test_a_new_target_sends_the_trip_at_once_and_the_step_keeps_its_length():
    """The robot sets off the moment the goal is clear, not at the step's end; the
    belief's step (and its goal id) goes on."""
    agent = _agent("task-r1-goal.yaml")
    steps = DecisionSteps(agent, StepTiming(start_delay_s=0.0, min_step_s=2.5,
                                            min_event_step_s=10.0, nav_timeout_s=30.0))  # fmt: skip
    assert [c.action for c in steps.tick(0.0)] == ["Do nothing"]
    steps.on_nav_result(0.0, {"goal_id": 1, "result": "succeeded", "action": "Do nothing"})
    out = []
    for k, p in enumerate(walk((7.0, 2.5), (6.2, 1.6))):  # cell 2 all along: no person event
        out += [(0.25 * (k + 1), c) for c in steps.on_observation(0.25 * (k + 1), observed(p))]
    acts = [(t, c.action, c.goal_id) for t, c in out if c.kind == "act"]
    # first, maybe, the standby trip to the cell beside 1 (the robot starts elsewhere);
    # then the trip into 1: both under the same step's goal id
    assert acts and all(g == 1 for _, _, g in acts)
    assert [a for _, a, _ in acts] in (["To 1"], ["To 3", "To 1"])
    assert acts[-1][0] < 2.5  # before the step could end, and once
    assert not [c for _, c in out if c.kind == "record"]
    assert steps.waiting == "nav" and agent.anticipated["revised"] == "To 1"


def test_the_first_steps_through_the_doorway_are_no_evidence_of_a_goal():
    """Everyone entering walks straight in through the door (south here, towards cell
    1 below it): a walker who then turns west to cell 10 does not send the robot to
    cell 1, as they did when the doorway steps counted; a visitor still does, early."""
    from stack.planning.intent import IntentConfig

    door = (7.0, 5.2)
    inside = walk(door, (7.0, 4.4), dt=0.1)
    targets = {}
    for zone in (1.0, 0.0):
        cfg = AnticipationConfig(exits_m=(door,), intent=IntentConfig(door_zone_m=zone))
        ant = Anticipator(GRID, (1,), cfg)
        seen = set()
        for k, p in enumerate(inside + walk((7.0, 4.4), (1.5, 2.25), dt=0.1)[1:]):
            ant.observe(0.1 * k, p, 3)
            seen.add(ant.target)
        targets[zone] = seen
    assert targets[1.0] == {None} and 1 in targets[0.0]
    ant = Anticipator(GRID, (1,), AnticipationConfig(exits_m=(door,)))
    for k, p in enumerate(inside + walk((7.0, 4.4), (5.5, 0.75), dt=0.1)[1:]):
        ant.observe(0.1 * k, p, 3)
        if ant.target == 1:
            break
    assert ant.target == 1 and p[1] > 2.0  # still north of cell 1's row, 1.3 m off


def _estimate(p1: float, eta1: float, p12: float = 0.0, eta12: float = 99.0):
    from stack.planning.intent import CellForecast, IntentEstimate

    return IntentEstimate(
        t=0.0,
        forecasts=(CellForecast(1, p1, 1.0, eta1), CellForecast(12, p12, 1.0, eta12)),
        p_elsewhere=1.0 - p1 - p12,
        inside=None,
        position_m=(6.5, 3.0),
        speed_mps=1.0,
        moving=True,
        age_s=0.0,
    )


def test_expected_lateness_weighs_each_late_arrival_by_its_goal_probability():
    from stack.planning.standby import expected_lateness

    trip_s = {1: {6: 5.0, 3: 1.0}, 12: {6: 6.0, 3: 11.0}}
    est = _estimate(0.5, 2.0, 0.25, 8.0)
    # from 6: 3 s late to 1 (x 0.5), first at 12; from 3: first at 1, 3 s late to 12
    assert expected_lateness(trip_s, [est], 6) == pytest.approx(1.5)
    assert expected_lateness(trip_s, [est], 3) == pytest.approx(0.75)
    # two people: the sum; nobody heading anywhere: no lateness
    assert expected_lateness(trip_s, [est, est], 6) == pytest.approx(3.0)
    assert expected_lateness(trip_s, [_estimate(0.0, 2.0)], 6) == 0.0


def test_the_robot_stands_by_nearer_the_cell_a_person_may_be_heading_for():
    """Two restricted cells far apart (1 south-east, 12 north-west): a person walking
    from the door toward cell 1's side draws the standby cell toward 1 before the
    goal is clear; one walking west toward 12 draws it toward 12; and without anyone
    seen there is nothing to stand by for (the policy decides)."""
    cfg = AnticipationConfig(exits_m=((7.0, 5.2),), intent=WEAK)
    standby = {}
    for name, end in (("east", (5.8, 2.4)), ("west", (1.6, 3.4))):
        ant = Anticipator(GRID, (1, 12), cfg)
        for k, p in enumerate(walk((6.5, 3.6), end)):
            ant.observe(0.25 * k, p, robot_cell=6)
            if ant.target is not None:  # the goal is clear: the standby is over
                assert ant.standby is None
                break
            if ant.standby is not None:  # the last one before the goal is clear
                standby[name] = ant.standby
                assert ant.standby not in (1, 12)
                assert ant.advise(6, "Do nothing") == f"To {ant.standby}"
    trips = {r: trip_lengths(GRID, r, "trip") for r in (1, 12)}
    assert trips[1][standby["east"]] < trips[1][6]  # nearer cell 1 than the watch cell
    assert trips[12][standby["west"]] < trips[12][6]
    idle = Anticipator(GRID, (1, 12), cfg)
    idle.observe(0.0, None, robot_cell=6)
    assert idle.standby is None and idle.advise(6, "Do nothing") is None
    off = Anticipator(GRID, (1, 12), AnticipationConfig(standby=False))
    for k, p in enumerate(walk((6.5, 3.6), (5.8, 2.4))):
        off.observe(0.25 * k, p, robot_cell=6)
    assert off.standby is None


def test_the_standby_cell_changes_only_for_a_gain_of_its_margin():
    ant = Anticipator(GRID, (1, 12), AnticipationConfig(standby_margin_s=0.3))
    est = _estimate(0.6, 3.0, 0.1, 8.0)
    best = ant.choose_standby([est], 6, None)
    assert best is not None and best != 6
    # a cell in hand that is no more than the margin worse than the best is kept
    costs = {w: ant.lateness([est], w) for w in GRID.cells if w not in (1, 12)}
    near = [w for w in costs if w != best and costs[w] - costs[best] < 0.3]
    far = [w for w in costs if costs[w] - costs[best] >= 0.3]
    for w in near:
        assert ant.choose_standby([est], 6, w) == w
    for w in far:
        assert ant.choose_standby([est], 6, w) == best
    assert near or far


def test_several_people_stand_by_as_one_when_only_one_is_seen():
    """The n-person layer's standby is the one-person layer's on the same walk while the
    other slot sees nobody; a second walker seen heading the other way moves it."""
    from stack.planning.anticipate import PeopleAnticipator

    cfg = AnticipationConfig(exits_m=((7.0, 5.2),), intent=WEAK)
    one = Anticipator(GRID, (1, 12), cfg)
    two = PeopleAnticipator(GRID, (1, 12), cfg, people=2)
    path = walk((6.5, 3.6), (5.8, 2.4))
    for k, p in enumerate(path):
        one.observe(0.25 * k, p, robot_cell=6)
        two.observe(0.25 * k, [p, None], robot_cell=6)
        assert (two.target, two.standby) == (one.target, one.standby)
    assert one.standby is not None  # the walk drew it
    both = PeopleAnticipator(GRID, (1, 12), cfg, people=2)
    west = walk((3.0, 3.6), (1.2, 3.3))
    standbys = []
    for k, (p, q) in enumerate(zip(path, west, strict=False)):
        both.observe(0.25 * k, [p, q], robot_cell=6)
        if both.target is None and both.standby is not None:
            standbys.append(both.standby)
    # the walker heading west draws the robot nearer cell 12 than the one-person
    # standby, which leaned toward 1
    trips = {r: trip_lengths(GRID, r, "trip") for r in (1, 12)}
    assert standbys and all(trips[12][w] < trips[12][one.standby] for w in standbys)


def test_the_standby_ends_when_waiting_at_home_is_as_good():
    """A person who stopped or turned away no longer keeps the robot at a far corner:
    once no cell cuts the margin off waiting at the policy's rest cell, there is no
    standby cell (the policy takes the robot home), whatever cell was in hand."""
    ant = Anticipator(GRID, (1, 12), AnticipationConfig(standby_margin_s=0.3), home=6)
    faint = _estimate(0.01, 3.0, 0.1, 5.0)  # a person standing in the middle
    assert ant.lateness([faint], 6) - min(ant.lateness([faint], w) for w in (3, 10)) < 0.3
    for held in (None, 10, 3):
        assert ant.choose_standby([faint], 10, held) is None
    likely = _estimate(0.6, 3.0, 0.1, 8.0)  # heading for cell 1's side, nearly there
    best = ant.choose_standby([likely], 6, None)
    assert best is not None and ant.lateness([likely], 6) - ant.lateness([likely], best) >= 0.3


def test_entry_lateness_weighs_a_person_coming_in_at_the_door():
    from stack.planning.standby import entry_lateness, trip_times, watch_cell

    trip_s = trip_times(GRID, (1,), 0.5)
    door = (6.0, 3.5)  # 2 m north of cell 1's north-east corner (6.0, 1.5)
    # waiting in 3 (centre 4.5, 0.75): the trip to 0.35 m inside cell 1 is 0.85 m, 1.7 s;
    # the person needs 2 m / v: late only for walkers faster than 2 / 1.7 m/s
    late = entry_lateness(GRID, trip_s, [door], 3, speeds_mps=(1.0, 2.0))
    assert late == pytest.approx((0.0 + (1.7 - 1.0)) / 2)
    assert entry_lateness(GRID, trip_s, [], 3) == 0.0
    # r2's cells 1 and 12 with the door beside cell 1: the guard waits nearer it than
    # the cell equidistant from both (6), which it keeps without a door
    assert watch_cell(GRID, (1, 12)) == 6
    assert watch_cell(GRID, (1, 12), exits=[(7.0, 5.2)]) == 5
    assert watch_cell(GRID, (1, 12), exits=[(-1.0, 5.2)]) in (8, 10)  # a door by cell 12
    assert watch_cell(GRID, (1,), exits=[(7.0, 5.2)]) == 3
    assert load_task(REPO / "config" / "task-r2-goal.yaml").rest_cell == 5


def test_with_two_visits_under_way_the_guard_moves_on_once_it_has_warned_one():
    """A visitor the robot has been with for ``serve_s`` (warned) ranks after a visitor
    nobody has warned: the guard leaves for the other restricted cell then, not before,
    and does not come back while the one it went to is still inside."""
    from stack.planning.anticipate import PeopleAnticipator

    cfg = AnticipationConfig(exits_m=((7.0, 5.2),), serve_s=4.0)
    a = (5.5, 0.75)  # standing in cell 1 from the start
    b_walk = walk((3.0, 2.25), (0.5, 2.25))  # into cell 12 within 2.5 s, then stands
    targets = {}
    for robot_cell in (1, 5):  # with visitor a from t = 0; never in their cell
        ant = PeopleAnticipator(GRID, (1, 12), cfg, people=2)
        seq = []
        for k in range(40):
            t = 0.25 * k
            b = b_walk[min(k, len(b_walk) - 1)] if t >= 1.0 else None
            ant.observe(t, [a, b], robot_cell=robot_cell)
            seq.append((t, ant.target))
        targets[robot_cell] = seq
    with_a = targets[1]
    assert all(tg == 1 for t, tg in with_a if t < 4.0)  # b is inside by 3.5 s: not yet
    assert all(tg == 12 for t, tg in with_a if t >= 4.0)  # a warned: on to b
    assert all(tg == 1 for _, tg in targets[5])  # never with a: a's visit is kept
    ant = PeopleAnticipator(GRID, (1, 12), cfg, people=2)  # the robot goes: 6 s to 12
    for k in range(80):
        t = 0.25 * k
        robot_cell = 1 if t < 4.25 else (7 if t < 6.0 else 12)
        ant.observe(t, [a, b_walk[min(k, len(b_walk) - 1)] if t >= 1.0 else None], robot_cell)
        assert ant.target == (1 if t < 4.0 else 12)  # both warned by 10 s: it stays


def test_of_two_visits_under_way_the_guard_takes_the_one_it_is_nearer():
    from stack.planning.anticipate import PeopleAnticipator

    ant = PeopleAnticipator(GRID, (1, 12), AnticipationConfig(exits_m=((7.0, 5.2),)), people=2)
    for k in range(8):
        ant.observe(0.25 * k, [(5.5, 0.75), (0.5, 2.25)], robot_cell=10)
        assert ant.target == 12


def test_of_two_visits_the_guard_heads_for_the_one_it_can_reach_while_it_lasts():
    """One person walks toward cell 12, the other into cell 1. A guard near 12 keeps
    heading for 12, which it reaches in time, rather than turn to the visit under way
    across the room, which would be over before it got there; a guard near 1 takes 1."""
    from stack.planning.anticipate import PeopleAnticipator

    cfg = AnticipationConfig(exits_m=((7.0, 5.2),))
    west = walk((4.5, 2.6), (0.5, 2.25), speed=1.0)
    south = walk((6.5, 3.5), (5.5, 0.75), speed=1.0)
    chosen = {}
    for robot_cell in (9, 3):
        ant = PeopleAnticipator(GRID, (1, 12), cfg, people=2)
        for k in range(len(south) + 2):
            ant.observe(0.25 * k, [west[min(k, len(west) - 1)], south[min(k, len(south) - 1)]],
                        robot_cell=robot_cell)  # fmt: skip
        assert ant.slots[1].estimate.inside == 1 and ant.slots[0].target == 12
        values = ant.values(robot_cell)
        chosen[robot_cell] = (ant.target, values)
    assert chosen[9][0] == 12 and chosen[9][1][12] > chosen[9][1][1]
    assert chosen[3][0] == 1 and chosen[3][1][1] > chosen[3][1][12]


def test_the_note_says_when_its_estimate_was_taken():
    """The step record is written at the step's end with the note of the decision that
    began it: ``at_s`` says which observation the target and probabilities are of."""
    from stack.planning.anticipate import PeopleAnticipator

    one = Anticipator(GRID, (1, 12), AnticipationConfig())
    two = PeopleAnticipator(GRID, (1, 12), AnticipationConfig(), people=2)
    assert one.note() is None and two.note() is None
    for k, p in enumerate(walk((2.5, 0.75), (5.5, 0.75))[:6]):
        one.observe(0.25 * k, p, robot_cell=5)
        two.observe(0.25 * k, [p, None], robot_cell=5)
    assert one.note()["at_s"] == two.note()["at_s"] == 1.25
    assert set(one.note()["p_goal"]) == {"1", "12"} and len(two.note()["p_goal"]) == 2
