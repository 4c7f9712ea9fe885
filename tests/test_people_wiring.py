"""Two people end to end (issue 16): the run-time agent on the factored belief, the
observations' person slots, the step machine's events, the per-person metrics and the
system's parameters for a two-person scenario."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from stack.perception.slots import SlotPerson, slot_labels
from stack.planning.agent import ObservationError, Observed, StateFileError
from stack.planning.factored import PeopleModel
from stack.planning.people_agent import PeopleAgent, initial_people_belief
from stack.planning.stepper import DecisionSteps, StepTiming
from stack.planning.task import load_task
from stack.vocabulary import ACTIONS
from vigil.report.metrics import Timeline, timeline_from_trace
from vigil.report.people import people_markdown, people_metrics, walkers_in_trace

REPO = Path(__file__).resolve().parents[1]
TASK = REPO / "config" / "task-r2-n2.yaml"


@pytest.fixture(scope="module")
def pm():
    return PeopleModel.of(load_task(TASK))


def agent(pm, robot=7):
    return PeopleAgent(pm, initial_people_belief(pm, robot, None, "not moving"))


def obs(robot, *people, hidden=None):
    d = {"robot": str(robot), "person": people[0][0], "velocity": people[0][1]}
    d["people"] = [{"person": p, "velocity": v} for p, v in people]
    if hidden:
        d["hidden"] = hidden
    return Observed.from_dict(d)


def test_each_slot_updates_its_own_person(pm):
    a = agent(pm)
    a.decide()
    rec = a.observe(obs(a.belief.robot and 7, ("2", "West higher"), ("No person", "Not moving")))
    p1, p2 = rec["belief"]["person_1"], rec["belief"]["person_2"]
    assert max(p1, key=p1.get) == "2" and p1["2"] > 0.5
    assert max(p2, key=p2.get) == "No person"
    assert abs(sum(p1.values()) - 1.0) < 1e-4 and abs(sum(p2.values()) - 1.0) < 1e-4
    assert rec["step"] == 1 and rec["depth"] >= 1


def test_unseen_slots_follow_the_transition_alone(pm):
    a = agent(pm)
    a.decide()
    before = a.belief.predict(pm)
    a.observe(obs(7, ("Unseen", "Not moving"), ("Unseen", "Not moving")))
    assert np.allclose(a.belief.persons, before)


def test_no_person_in_a_wholly_hidden_cell_is_no_evidence_there(pm):
    seen, hidden = agent(pm), agent(pm)
    for a in (seen, hidden):
        a.decide()
        a.observe(obs(7, ("2", "Not moving"), ("No person", "Not moving")))
        a.decide()
    seen.observe(obs(7, ("No person", "Not moving"), ("No person", "Not moving")))
    hidden.observe(
        obs(7, ("No person", "Not moving"), ("No person", "Not moving"), hidden={"2": 1.0})
    )
    cell2 = pm.model.position_index(2)
    p_seen = seen.belief.position(pm, 0)[cell2]
    p_hidden = hidden.belief.position(pm, 0)[cell2]
    assert p_hidden > 5 * p_seen


def test_a_one_person_observation_feeds_slot_one_only(pm):
    a = agent(pm)
    a.decide()
    before = a.belief.predict(pm)
    a.observe(Observed("7", "2", "Not moving"))
    # slot one's person (absent before) is now likeliest at 2 of all cells (with the
    # fitted 14 % false positives one sighting may leave "No person" likelier still)
    p = a.belief.position(pm, 0)
    cells = [pm.model.position_index(c) for c in range(1, 13)]
    assert max(cells, key=lambda i: p[i]) == pm.model.position_index(2)
    prior = before[0].reshape(p.size, -1).sum(axis=1)  # the predicted cell marginal
    assert p[pm.model.position_index(2)] > 10 * prior[pm.model.position_index(2)]
    assert np.allclose(a.belief.persons[1], before[1])


def test_the_obvious_action_one_person_in_a_restricted_cell(pm):
    # person 1 in cell 1 (south-east corner) stays, person 2 absent; the robot in 3
    a = agent(pm, robot=3)
    for _ in range(3):
        a.decide()
        a.observe(obs(3, ("1", "Not moving"), ("No person", "Not moving")))
    # cell 1 lies south of cell 3 in the grid (columns 12 10 8 6 4 2 / 11 9 7 5 3 1)
    assert ACTIONS[a.decide()] == "East"


def test_bad_labels_and_too_many_people_are_refused(pm):
    a = agent(pm)
    a.decide()
    with pytest.raises(ObservationError, match="person cell"):
        a.observe(obs(7, ("13", "Not moving"), ("No person", "Not moving")))
    with pytest.raises(ObservationError, match="3 people"):
        a.observe(obs(7, *[("No person", "Not moving")] * 3))
    with pytest.raises(ObservationError, match="'people'"):
        Observed.from_dict({"robot": "7", "person": "1", "velocity": "Not moving", "people": 3})
    with pytest.raises(ObservationError, match="'people' entry 2"):
        Observed.from_dict(
            {
                "robot": "7",
                "person": "1",
                "velocity": "Not moving",
                "people": [{"person": "1", "velocity": "Not moving"}, {"person": 1}],
            }
        )
    assert a.step == 0


def test_a_robot_beyond_its_move_moves_the_belief_and_an_impossible_one_restarts(pm, monkeypatch):
    a = agent(pm)
    a.decide()
    rec = a.observe(obs(1, ("12", "Not moving"), ("No person", "Not moving")))  # robot jumps
    assert rec["note"] and "beyond the action's move" in rec["note"]
    assert a.belief.robot == pm.model.robot_index(1)
    assert 0.0 < a.belief.position(pm, 0)[pm.model.position_index(12)] < 1.0  # updated
    a.decide()
    monkeypatch.setattr(a, "likelihood", lambda *args: np.zeros(pm.n_person))
    rec = a.observe(obs(1, ("12", "Not moving"), ("No person", "Not moving")))
    assert rec["note"] and "restarted" in rec["note"]


def test_one_person_observations_keep_their_json():
    o = Observed.from_dict({"robot": "7", "person": "1", "velocity": "Not moving"})
    assert "people" not in o.to_dict() and o.people == ()


def test_state_round_trip_same_decision_and_refusals(pm, tmp_path):
    a = agent(pm)
    a.decide()
    a.observe(obs(7, ("4", "West higher"), ("2", "West higher")))
    path = tmp_path / "state.json"
    a.save(path)
    b = PeopleAgent(pm)
    assert b.restore(path) and b.step == 1
    assert np.allclose(a.belief.persons, b.belief.persons)
    assert a.decide() == b.decide() and np.allclose(a.values, b.values)
    other = PeopleModel.of(load_task(TASK).replace(people=3))
    with pytest.raises(StateFileError, match="another task"):
        PeopleAgent(other).restore(path)
    path.write_text("{")
    with pytest.raises(StateFileError, match="unreadable"):
        b.restore(path)


def test_any_slot_in_a_new_cell_is_an_event(pm):
    a = agent(pm)
    steps = DecisionSteps(a, StepTiming(start_delay_s=0.0, min_event_step_s=1.0))
    assert steps.tick(0.0)[0].kind == "act"
    quiet = obs(7, ("No person", "Not moving"), ("No person", "Not moving"))
    assert steps.on_observation(2.0, quiet) == []
    second = obs(7, ("No person", "Not moving"), ("2", "West higher"))
    kinds = [c.kind for c in steps.on_observation(2.5, second)]
    assert kinds == ["record", "act"]


def test_slot_labels_in_slot_order():
    people = (SlotPerson(1, track_id=4, cell=3), SlotPerson(0))
    people = (SlotPerson(1, track_id=4, position_m=(4.5, 0.75), cell=3), SlotPerson(0))
    assert slot_labels(people) == [
        {"person": "No person", "velocity": "Not moving", "position_m": None},
        {"person": "3", "velocity": "Not moving", "position_m": [4.5, 0.75]},
    ]
    assert [s["person"] for s in slot_labels(people, unseen=True)] == ["Unseen", "Unseen"]


def test_visits_are_counted_per_person_and_false_trips_need_an_empty_room():
    t = list(range(12))
    robot = [7, 7, 3, 1, 1, 1, 1, 3, 5, 7, 7, 7]
    first = [None, 2, 1, 1, 1, 1, 1, 2, None, None, None, None]
    second = [None, 2, 4, 6, 8, 10, 12, 12, 12, 10, None, None]
    tls = [Timeline.of(t, robot, first), Timeline.of(t, robot, second)]
    m = people_metrics(tls, (1, 12))
    one, two = m["per_person"]
    assert (one["n_visits"], one["guarded"], one["max_delay_s"]) == (1, 1, 1.0)
    assert (two["n_visits"], two["guarded"]) == (1, 0)
    assert m["n_false_trips"] == 0 and m["guarded"] == 1
    md = people_markdown(m)
    assert "| 1 | 1 | 2.0 | 7.0 | yes | 1.0 |" in md and "| 2 | 12 | 6.0 | 9.0 | no |" in md


def test_walker_timelines_from_the_trace():
    grid = load_task(TASK).grid
    rec = {
        "t": 0.0,
        "robot": [3.5, 0.75, 0.0],
        "person": [5.5, 0.75],
        "people": [{"position": [5.5, 0.75]}, {"position": [0.5, 2.25]}],
    }
    trace = [rec, {**rec, "t": 1.0}]
    assert walkers_in_trace(trace) == 2 and walkers_in_trace([{"t": 0}]) == 0
    first = timeline_from_trace(trace, grid, walker=0)
    second = timeline_from_trace(trace, grid, walker=1)
    assert first.person[0] == grid.cell_at(5.5, 0.75)
    assert second.person[0] == grid.cell_at(0.5, 2.25) != first.person[0]


def test_a_two_person_scenario_prepares_the_nodes_for_slots(tmp_path):
    from vigil.deployment import parse_deployment
    from vigil.scenario import load_scenario
    from vigil.system import prepare

    data = yaml.safe_load((REPO / "config" / "twin.yaml").read_text())
    data["twin"]["scene"] = str(REPO / "config" / "twin-scene.yaml")
    data["task"] = str(TASK)
    dep = parse_deployment(data, tmp_path / "twin.yaml")
    scenario = load_scenario(REPO / "scenarios" / "people" / "split.yaml")
    system = prepare(dep, tmp_path / "run", scenario, say=lambda s: None)
    p = system.params
    assert p["observations"]["people"] == 2
    assert p["planner"]["policy_file"] == ""
    stack = yaml.safe_load((tmp_path / "run" / "stack.yaml").read_text())
    assert stack["camera"]["max_people"] == 2
    twin = yaml.safe_load((tmp_path / "run" / "twin.yaml").read_text())["twin"]
    assert len(twin["people"]) == 2


def test_two_people_anticipated_the_visit_the_robot_reaches_then_the_other():
    """Person 1 walks to cell 1, person 2 stands in cell 12: a robot waiting next to
    12 heads for 12 (a visit under way it reaches at once), one next to 1 for 1 (the
    entry it reaches while the stay lasts); once person 2 has left the map, for 1."""
    from stack.planning.anticipate import AnticipationConfig, PeopleAnticipator

    grid = load_task(TASK).grid
    for robot_cell, first_target in ((10, 12), (3, 1)):
        ant = PeopleAnticipator(grid, (1, 12), AnticipationConfig(), 2)
        t = 0.0
        for k in range(17):  # person 1 from (5.5, 4.0) south to (5.5, 1.6), person 2 in 12
            ant.observe(t, [(5.5, 4.0 - 0.15 * k), (0.5, 2.25)], robot_cell)
            t += 0.25
        assert ant.target == first_target and ant.slots[0].target == 1
        assert ant.slots[1].target == 12
        assert ant.advise(robot_cell) == f"To {first_target}"
    for _ in range(12):  # person 2 gone (unseen): person 1's visit is the one left
        ant.observe(t, [(5.5, 1.6), None], 12)
        t += 0.25
    assert ant.target == 1 and ant.advise(12) == "To 1"
    note = ant.note()
    assert note["target"] == 1 and len(note["p_goal"]) == 2


def test_the_people_agent_sends_the_trip_the_layer_advises(pm):
    from stack.planning.anticipate import AnticipationConfig, PeopleAnticipator

    ant = PeopleAnticipator(pm.task.grid, (1, 12), AnticipationConfig(), 2)
    a = PeopleAgent(pm, initial_people_belief(pm, 6, None, "not moving"), anticipator=ant)
    a.decide()
    quiet = ("No person", "Not moving")
    for k in range(17):
        d = {"robot": "6", "person": "No person", "velocity": "Not moving"}
        slot = {"person": "No person", "velocity": "Not moving"}
        d["people"] = [{**slot, "position_m": [5.5, 4.0 - 0.15 * k]}, {**slot, "position_m": None}]
        a.track(0.25 * k, Observed.from_dict(d))
    assert ant.target == 1
    rec = a.observe(obs(6, quiet, quiet))
    a.decide()
    assert a.command == "To 1" and ACTIONS[a.action] in ("South", "East")  # its first move
    rec = a.observe(obs(1, quiet, quiet))  # the trip crossed three cells in one step
    assert "beyond the action's move" in rec["note"] and rec["belief"]["robot"] == {"1": 1.0}
    assert rec["anticipation"]["target"] == 1


def _visit(cell, arrive, left, reachable=True):
    return {"cell": cell, "person_arrival_t": arrive, "person_left_t": left, "reachable": reachable}


def test_one_guard_counts_the_visits_one_robot_could_be_in_one_after_the_other():
    from stack.cells import CellGrid
    from vigil.report.people import one_guard_reachable

    grid = CellGrid()  # cells 1 and 12 are 4 m apart (x 5-6 and 0-1): 8 s at 0.5 m/s
    # two people in 1 and 12 at once, for 5 s: one robot can be in one of them
    assert one_guard_reachable([_visit(1, 10.0, 15.0), _visit(12, 10.0, 15.0)], grid) == 1
    # the second stays 10 s: the robot goes on to it (8 s) while they are still in
    assert one_guard_reachable([_visit(1, 10.0, 15.0), _visit(12, 10.0, 20.0)], grid) == 2
    # two people in the same cell at once: one robot guards both
    assert one_guard_reachable([_visit(1, 10.0, 12.0), _visit(1, 11.0, 13.0)], grid) == 2
    # a visit still under way at the end can always be reached; unreachable ones never
    assert one_guard_reachable([_visit(1, 10.0, 11.0), _visit(12, 10.5, None)], grid) == 2
    assert one_guard_reachable([_visit(1, 10.0, 15.0, reachable=False)], grid) == 0
    assert one_guard_reachable([], grid) == 0
    # three at once in 1, 12, 1 again later: 1 -> 1 (same cell) beats 1 -> 12
    visits = [_visit(1, 0.0, 3.0), _visit(12, 0.0, 3.0), _visit(1, 2.0, 4.0)]
    assert one_guard_reachable(visits, grid) == 2


def test_one_guard_counts_every_reachable_visit_beyond_the_exact_limit():
    from stack.cells import CellGrid
    from vigil.report.people import ONE_GUARD_EXACT_MAX, one_guard_reachable

    many = [_visit(1 if k % 2 else 12, 10.0, 11.0) for k in range(ONE_GUARD_EXACT_MAX + 1)]
    assert one_guard_reachable(many, CellGrid()) == len(many)  # no failure, an upper bound
