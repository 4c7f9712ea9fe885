"""Guarding metrics (vigil.report.metrics) on synthetic timelines with known answers."""

from __future__ import annotations

import pytest

from stack.cells import CellGrid
from vigil.report.metrics import (
    Timeline,
    classify_warnings,
    false_trips,
    find_visits,
    guard_metrics,
    needless_trips,
    step_counts,
    step_outcome,
    timeline_from_trace,
)

GRID = CellGrid()  # cell 1: x 5..6, y 0..1.5; cell 3: x 4..5; cell 12: x 0..1, y 1.5..3


def timeline(person: dict[tuple[float, float], int | None], robot, end: float = 30.0, dt=0.5):
    """Cells from piecewise-constant specs: {(from, to): cell}; robot likewise."""

    def at(spec, t):
        for (a, b), c in spec.items():
            if a <= t < b:
                return c
        return None

    ts = [k * dt for k in range(int(end / dt) + 1)]
    return Timeline.of(ts, [at(robot, t) for t in ts], [at(person, t) for t in ts])


def test_visit_guarded_with_delay():
    tl = timeline({(0, 5): 3, (5, 12): 1, (12, 30): 4}, {(0, 8): 5, (8, 30): 1})
    (v,) = find_visits(tl, [1])
    assert (v.cell, v.person_arrival_t, v.person_left_t) == (1, 5.0, 12.0)
    assert v.person_duration_s == 7.0
    assert v.guarded and v.robot_arrival_t == 8.0 and v.delay_s == 3.0
    assert not v.abandoned


def test_robot_already_there_has_zero_delay():
    tl = timeline({(5, 12): 1}, {(0, 30): 1})
    (v,) = find_visits(tl, [1])
    assert v.guarded and v.delay_s == 0.0 and v.robot_arrival_t == 5.0


def test_robot_arriving_after_the_person_left_is_not_guarded():
    tl = timeline({(5, 12): 1}, {(0, 14): 3, (14, 30): 1})
    (v,) = find_visits(tl, [1])
    assert not v.guarded and v.delay_s is None and v.robot_arrival_t is None
    assert v.robot_late_arrival_t == 14.0
    m = guard_metrics(tl, [1], [], [])
    assert m["every_visit_guarded"] is False and m["guarded"] == 0 and m["n_visits"] == 1


def test_a_visit_is_reachable_when_an_ideal_guard_could_have_been_there():
    from stack.cells import CellGrid
    from vigil.report.metrics import reach_time_s

    grid = CellGrid()  # from cell 7 the nearest point of cell 1 is 2.5 m away: 5 s
    assert reach_time_s(grid, 7, 1, 0.5) == pytest.approx(5.0)
    # the person enters the room (cell 4) at 2 s, is in cell 1 from 3 s to 6 s: no robot
    # at 0.5 m/s starting in 7 at 2 s could be there before 6 s
    short = timeline({(2, 3): 4, (3, 6): 1, (6, 30): 4}, {(0, 30): 7})
    (v,) = find_visits(short, [1], grid=grid)
    assert v.reachable is False and not v.guarded
    m = guard_metrics(short, [1], [], [], grid=grid)
    assert (m["n_visits"], m["reachable"], m["guarded_reachable"]) == (1, 0, 0)
    # the same walk with a 6 s stay is reachable (2 + 5 < 9), and unguarded here
    long = timeline({(2, 3): 4, (3, 9): 1, (9, 30): 4}, {(0, 30): 7})
    (v,) = find_visits(long, [1], grid=grid)
    assert v.reachable is True and not v.guarded
    # a second visit races from the end of the first, with the robot where it was then
    two = timeline(
        {(2, 3): 4, (3, 9): 1, (9, 11): 3, (11, 13): 1, (13, 30): 4},
        {(0, 4): 7, (4, 30): 11},
    )
    first, second = find_visits(two, [1], grid=grid)
    assert first.reachable is True and second.reachable is False  # from 11 it is 7 s
    assert find_visits(long, [1])[0].reachable is None  # no grid: not judged


def test_abandoned_when_the_robot_leaves_while_the_person_stays():
    tl = timeline({(5, 20): 1}, {(0, 7): 3, (7, 11): 1, (11, 30): 3})
    (v,) = find_visits(tl, [1])
    assert v.guarded and v.abandoned and v.abandoned_t == 11.0
    # the robot leaving after the person did is not abandoning
    tl = timeline({(5, 10): 1}, {(0, 7): 3, (7, 11): 1, (11, 30): 3})
    assert not find_visits(tl, [1])[0].abandoned


def test_short_stays_are_not_visits_and_cells_are_attributed_right():
    # 0.5 s in cell 1 (border hesitation), then 3 s in 12; cell 3 is not restricted
    tl = timeline({(2, 2.5): 1, (2.5, 6): 3, (10, 13): 12}, {(0, 30): 7})
    visits = find_visits(tl, [1, 12])
    assert [(v.cell, v.person_arrival_t, v.person_left_t) for v in visits] == [(12, 10.0, 13.0)]
    assert find_visits(tl, [1, 12], min_visit_s=0.5)[0].cell == 1
    # two visits in a row to the same cell are two visits
    tl = timeline({(2, 6): 1, (6, 9): 3, (9, 14): 1}, {(0, 30): 1})
    assert [v.person_arrival_t for v in find_visits(tl, [1])] == [2.0, 9.0]


def test_visit_still_going_at_the_end():
    tl = timeline({(20, 99): 12}, {(0, 99): 12}, end=30.0)
    (v,) = find_visits(tl, [12])
    assert v.person_left_t is None and v.person_duration_s == 10.0 and v.guarded


def test_warnings_timely_or_late():
    tl = timeline({(5, 12): 1, (12, 30): 4}, {(0, 30): 1})
    w = classify_warnings(tl, [1], [3.0, 6.0, 14.5, 15.5, 25.0])
    # 3.0 is 2 s before the entry: ahead of it (issue 26), so timely
    assert [x["timely"] for x in w] == [True, True, True, False, False]
    assert [x["ahead"] for x in w] == [True, False, False, False, False]
    assert w[0]["visit_cell"] == 1 and w[0]["person_cell"] is None
    assert w[1]["visit_cell"] == 1 and w[1]["person_cell"] == 1 and w[1]["robot_cell"] == 1
    assert w[3]["person_cell"] == 4
    m = guard_metrics(tl, [1], [3.0, 6.0, 14.5, 15.5, 25.0], [])
    assert (m["timely_warnings"], m["late_warnings"], m["ahead_warnings"]) == (3, 2, 1)
    # more than WARNING_BEFORE_S (10 s) before the entry is late
    far = timeline({(15, 20): 1}, {(0, 30): 1})
    assert [x["timely"] for x in classify_warnings(far, [1], [4.0, 5.0])] == [False, True]


def test_false_trips_need_an_empty_room_before_and_after():
    # nobody at all: the robot's trip to 1 at t=12 is false
    tl = timeline({}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    assert false_trips(tl, [1]) == [{"t": 12.0, "cell": 1}]
    # a person in the room (off the grid, by the door) 8 s before: not false
    ts = list(tl.t)
    present = [4.0 <= t < 5.0 for t in ts]
    tl2 = Timeline(tl.t, tl.robot, tl.robot_known, tl.person, tuple(present))
    assert false_trips(tl2, [1]) == []
    # ... but 11 s before is outside the window
    present = [0.0 <= t < 1.0 for t in ts]
    tl3 = Timeline(tl.t, tl.robot, tl.robot_known, tl.person, tuple(present))
    assert len(false_trips(tl3, [1])) == 1
    # starting in the cell is not an arrival
    assert false_trips(timeline({}, {(0, 40): 1}, end=40.0), [1]) == []


def test_step_outcomes_and_counts():
    assert step_outcome("No person", 3, True) == "miss"
    assert step_outcome("No person", None, True) == "absent"
    assert step_outcome("Unseen", 3, True) == "unseen"
    assert step_outcome("4", 3, True) == "wrong cell"
    assert step_outcome("3", 3, True) == "seen"
    assert step_outcome("3", None, False) == "phantom"
    assert step_outcome(None, 3, True) == "no observation"
    tl = timeline({(5, 20): 3}, {(0, 30): 7})
    steps = [
        (2.0, "No person", "none"),  # nobody: absent
        (6.0, "3", "camera"),
        (8.0, "No person", "none"),  # miss
        (10.0, "Unseen", "none"),  # camera out: not a miss
        (12.0, "5", "camera"),  # wrong cell
        (14.0, "3", "laser"),
        (16.0, None, None),  # no observation (timeout)
        (22.0, "No person", "none"),  # gone: absent
    ]
    c = step_counts(tl, steps)
    assert c["steps"] == 8 and c["steps_with_person"] == 5
    assert (c["misses"], c["wrong_cell_steps"], c["unseen_steps"]) == (1, 1, 1)
    assert c["miss_rate"] == pytest.approx(1 / 5)
    assert c["unseen_with_person"] == 1
    assert c["sources"] == {"camera": 2, "laser": 1, "none": 4}
    assert c["per_step"][3] == "unseen"


def test_timeline_from_trace_uses_positions_room_and_horizon():
    trace = [
        # the record's own cells are wrong on purpose: the positions decide
        {"t": 0.0, "robot": [2.5, 0.75, 0.0], "robot_cell": 9, "person": [5.5, 0.7],
         "person_cell": 3},
        {"t": 1.0, "robot": [5.5, 0.75, 0.0], "robot_cell": 9, "person": [7.0, 4.4],
         "person_cell": None},  # by the door: in the room, off the grid
        {"t": 2.0, "robot": [5.5, 0.75, 0.0], "robot_cell": 1, "person": [7.0, 6.4],
         "person_cell": None},  # outside the door
        {"t": 3.0, "robot": [5.5, 0.75, 0.0], "robot_cell": 1, "person": None},
    ]  # fmt: skip
    room = (-3.5, -2.2, 8.0, 5.2)
    tl = timeline_from_trace(trace, GRID, room)
    assert tl.person == (1, None, None, None) and tl.robot == (7, 1, 1, 1)
    assert tl.present == (True, True, False, False)
    assert tl.source == "ground truth"
    assert timeline_from_trace(trace, GRID).present == (True, False, False, False)
    assert len(timeline_from_trace(trace, GRID, room, until_t=1.5)) == 2
    # no ground truth (hardware): odometry and the camera's cell
    hw = [{"t": 0.0, "robot": None, "odom": [5.5, 0.7, 0.0],
           "camera": {"status": "person", "cell": 3}}]  # fmt: skip
    tl = timeline_from_trace(hw, GRID)
    assert (tl.robot, tl.person, tl.source) == ((1,), (3,), "odometry and camera")


def test_timeline_rejects_bad_input():
    with pytest.raises(ValueError, match="robot has 1 entries"):
        Timeline((0.0, 1.0), (1,), (True, True), (None, None), (False, False))
    with pytest.raises(ValueError, match="must not decrease"):
        Timeline.of([1.0, 0.0], [1, 1], [None, None])


def test_warning_lead_time_per_visit():
    tl = timeline({(5, 12): 1, (12, 16): 3, (16, 22): 1}, {(0, 30): 7})
    # before the entry: positive lead; the first warning of the window counts
    first, second = find_visits(tl, [1], warning_starts=[3.0, 6.0])
    assert (first.first_warning_t, first.warning_lead_s) == (3.0, 2.0)
    # the second visit's window starts where the first visit ended (12 s)
    assert second.first_warning_t is None and second.warning_lead_s is None
    # after the entry: negative; 13.0 is timely for the first visit and 3 s ahead of the
    # second, so it is the second's first warning
    first, second = find_visits(tl, [1], warning_starts=[7.5, 13.0])
    assert first.warning_lead_s == -2.5 and second.warning_lead_s == 3.0
    # a warning up to WARNING_AFTER_S after the exit still counts (late lead), later not
    (v,) = find_visits(timeline({(5, 8): 1}, {(0, 30): 7}), [1], warning_starts=[10.0, 11.5])
    assert v.warning_lead_s == -5.0
    (v,) = find_visits(timeline({(5, 8): 1}, {(0, 30): 7}), [1], warning_starts=[11.5])
    assert v.warning_lead_s is None
    # more than 10 s before the entry is no lead; no warning times: None
    (v,) = find_visits(timeline({(15, 20): 1}, {(0, 30): 7}), [1], warning_starts=[4.0])
    assert v.warning_lead_s is None
    assert find_visits(tl, [1])[0].warning_lead_s is None
    m = guard_metrics(tl, [1], [7.5, 13.0], [])
    assert [v["warning_lead_s"] for v in m["visits"]] == [-2.5, 3.0]
    assert (m["warned_visits"], m["warned_before_entry"]) == (2, 1)
    assert (m["min_warning_lead_s"], m["mean_warning_lead_s"]) == (-2.5, 0.25)
    m = guard_metrics(tl, [1], [], [])
    assert m["warned_visits"] == 0 and m["min_warning_lead_s"] is None


def test_robot_first_when_in_the_cell_at_the_entry():
    tl = timeline({(5, 12): 1, (12, 16): 3, (16, 22): 1}, {(0, 4): 3, (4, 13): 1, (13, 30): 5})
    first, second = find_visits(tl, [1])
    assert first.robot_first and first.delay_s == 0.0
    assert not second.robot_first and not second.guarded
    late = timeline({(5, 12): 1}, {(0, 6): 3, (6, 30): 1})
    (v,) = find_visits(late, [1])
    assert v.guarded and not v.robot_first and v.delay_s == 1.0
    assert guard_metrics(tl, [1], [], [])["robot_first"] == 1


def test_needless_trips_need_nobody_in_the_cell_before_and_after():
    # the person is in the room (cell 4) but never in cell 1: the trip at 12 is needless,
    # not false (the room was not empty)
    tl = timeline({(0, 40): 4}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    assert needless_trips(tl, [1]) == [{"t": 12.0, "cell": 1}]
    assert false_trips(tl, [1]) == []
    # the person in cell 1 8 s after the robot arrived: not needless
    tl = timeline({(0, 20): 4, (20, 25): 1}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    assert needless_trips(tl, [1]) == []
    # ... or until 2.5 s (the window starts at 2 s); until 1.5 s is outside it
    tl = timeline({(0, 2.5): 1, (2.5, 40): 4}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    assert needless_trips(tl, [1]) == []
    tl = timeline({(0, 1.5): 1, (1.5, 40): 4}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    assert needless_trips(tl, [1]) == [{"t": 12.0, "cell": 1}]
    # an empty room: false and needless; starting in the cell is no arrival
    empty = timeline({}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    assert len(needless_trips(empty, [1])) == len(false_trips(empty, [1])) == 1
    assert needless_trips(timeline({}, {(0, 40): 1}, end=40.0), [1]) == []
    # a second walker in the cell makes it needed
    other = timeline({(10, 15): 1}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    assert needless_trips(empty, [1], others=[other]) == []
    # each arrival counts: out and back in
    tl = timeline({(0, 40): 4}, {(0, 12): 1, (12, 14): 3, (14, 40): 1}, end=40.0)
    assert [x["t"] for x in needless_trips(tl, [1])] == [14.0]
    m = guard_metrics(tl, [1], [], [])
    assert m["n_needless_trips"] == 1 and m["n_false_trips"] == 0


def test_people_metrics_count_needless_trips_over_every_walker():
    from vigil.report.people import people_metrics

    a = timeline({(0, 40): 4}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    b = timeline({(15, 20): 1}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    m = people_metrics([a, b], [1], warning_starts=[14.0])
    assert m["n_needless_trips"] == 0 and m["robot_first"] == 1
    assert m["per_person"][1]["visits"][0]["warning_lead_s"] == 1.0
    assert people_metrics([a], [1])["n_needless_trips"] == 1
    # the warning at 14 s came before the second walker's visit: timely (for walker
    # 2), though walker 1 never went in; one at 35 s is late for both
    m = people_metrics([a, b], [1], warning_starts=[14.0, 35.0])
    assert (m["timely_warnings"], m["late_warnings"]) == (1, 1)
    assert people_metrics([a], [1], warning_starts=[14.0])["late_warnings"] == 1


def test_set_totals_add_the_new_metrics_and_read_old_records():
    from vigil.report.metrics import set_totals

    tl = timeline({(5, 12): 1, (12, 40): 4}, {(0, 4): 3, (4, 30): 1, (30, 40): 3}, end=40.0)
    new = guard_metrics(tl, [1], [3.0], [])
    trip = timeline({(0, 40): 4}, {(0, 12): 3, (12, 40): 1}, end=40.0)
    other = guard_metrics(trip, [1], [], [])
    old = {k: v for k, v in other.items() if k not in ("n_needless_trips", "robot_first")}
    old["visits"] = [{"cell": 1}]  # an old record's visit: no lead
    t = set_totals([new, other, old])
    assert (t["n_needless_trips"], t["robot_first"]) == (1, 1)
    assert (t["warned_visits"], t["warned_before_entry"], t["ahead_warnings"]) == (1, 1, 1)
    assert t["min_warning_lead_s"] == t["mean_warning_lead_s"] == 2.0
    assert set_totals([])["min_warning_lead_s"] is None


def test_a_warning_to_a_person_next_to_the_guarded_cell_is_an_approach_not_late():
    """Issue 26's warn-before-entry: the robot in cell 1 warns a person in cell 3 (next
    to it) who then turns away (a decoy): timely, an ``approach`` warning. The same
    warning to someone two cells away, or from a robot outside the cell, or to someone
    who has just left the cell, is late."""
    decoy = timeline({(2, 8): 3, (8, 30): 7}, {(0, 30): 1})
    w = classify_warnings(decoy, [1], [4.0, 9.0], grid=GRID)
    assert [(x["timely"], x["approach"]) for x in w] == [(True, True), (False, False)]
    assert [x["timely"] for x in classify_warnings(decoy, [1], [4.0])] == [False]  # no grid
    away = timeline({(2, 8): 3}, {(0, 30): 3})  # the robot is not in the cell
    assert classify_warnings(away, [1], [4.0], grid=GRID)[0]["timely"] is False
    left = timeline({(2, 6): 1, (6, 30): 3}, {(0, 30): 1})  # in, then next to it
    assert classify_warnings(left, [1], [12.0], grid=GRID)[0]["timely"] is False
    m = guard_metrics(decoy, [1], [4.0, 9.0], [], grid=GRID)
    assert (m["timely_warnings"], m["late_warnings"], m["approach_warnings"]) == (1, 1, 1)


def test_a_warning_to_a_person_just_off_the_grid_edge_next_to_the_cell_is_an_approach():
    """The door is 1 m east of the grid: a person walking in is 0.05-0.3 m off the grid
    beside cell 2 for a moment, and the camera (0.1 m foot-point error) already sees
    them in cell 2 walking towards the robot in cell 1. Within EDGE_M (0.3 m, the
    observations' border margin) of a cell next to the guarded one is an approach;
    further off the grid it is not."""

    def trace(px):
        return [{"t": k * 0.5, "robot": [5.5, 0.75, 0.0], "person": [px, 2.3]} for k in range(20)]

    near = timeline_from_trace(trace(6.1), GRID, (-3.5, -2.2, 8.0, 5.2))
    assert near.person[0] is None and near.person_edge[0] == 2
    w = classify_warnings(near, [1], [2.0], grid=GRID)
    assert w[0]["timely"] and w[0]["approach"]
    far = timeline_from_trace(trace(6.6), GRID, (-3.5, -2.2, 8.0, 5.2))
    assert far.person_edge[0] is None
    assert classify_warnings(far, [1], [2.0], grid=GRID)[0]["timely"] is False
