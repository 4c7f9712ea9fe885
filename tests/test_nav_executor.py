"""Navigation's core (stack.nav.executor): actions to motion, reported on entering the cell."""

from __future__ import annotations

from stack.cells import CellGrid
from stack.geometry import Pose2D
from stack.nav.base_model import KinematicBase
from stack.nav.config import FollowerConfig
from stack.nav.executor import ActionExecutor
from stack.nav.occupancy import OccupancyMap

GRID = CellGrid()
DT = 0.04


def setup(cell=7):
    occ = OccupancyMap.empty(8.0, 5.0, 0.05, (-1.0, -1.0))
    ex = ActionExecutor(GRID, FollowerConfig(), occ)
    base = KinematicBase(Pose2D(*GRID.center(cell), 0.0))
    ex.set_pose(base.pose, 0.0)
    return ex, base


def run(ex, base, t, until_s, stop_on_result=True):
    results = []
    while t < until_s:
        t += DT
        for o in ex.tick(t):
            if o.kind == "cmd":
                base.step(o.cmd, DT)
            elif o.kind == "result":
                results.append((t, o.body))
        ex.set_pose(base.pose, t)
        if results and stop_on_result:
            break
    return t, results


def test_a_move_is_reported_on_entering_the_cell_and_the_robot_drives_on():
    ex, base = setup(7)
    assert ex.action("East", 0.0) == []
    t, results = run(ex, base, 0.0, 10.0)
    ((_, body),) = results
    assert body["result"] == "succeeded" and body["target_cell"] == 5
    assert body["message"] == "in the target cell"
    x0, _, x1, _ = GRID.bounds(5)
    assert x0 + 0.2 <= base.pose.x_m < GRID.center(5)[0]  # inside, not yet at the waypoint
    assert ex.follower.active
    t, more = run(ex, base, t, t + 5.0, stop_on_result=False)
    assert more == []  # no second result for the same move
    assert abs(base.pose.x_m - GRID.center(5)[0]) < 0.1 and not ex.follower.active


def test_the_same_cell_again_keeps_driving_and_a_new_cell_follows_on():
    ex, base = setup(7)
    ex.action("East", 0.0)
    t, _ = run(ex, base, 0.0, 0.8, stop_on_result=False)  # still in 7, moving
    speed_before = base.velocity.vx_mps
    assert speed_before > 0.1
    assert ex.action("East", t) == []  # toward 5 again: no restart, no stop
    assert ex.task["target_cell"] == 5
    t, results = run(ex, base, t, 10.0)
    assert results[0][1]["target_cell"] == 5
    ex.action("East", t)  # on to 3 while still moving
    assert base.velocity.vx_mps > 0.2
    t, results = run(ex, base, t, t + 10.0)
    assert results[0][1]["target_cell"] == 3


def test_do_nothing_during_a_move_settles_in_the_current_cell():
    ex, base = setup(7)
    ex.action("East", 0.0)
    t, _ = run(ex, base, 0.0, 0.8, stop_on_result=False)
    out = ex.action("Do nothing", t)
    assert [o.body["result"] for o in out if o.kind == "result"] == ["succeeded"]
    t, _ = run(ex, base, t, t + 6.0, stop_on_result=False)
    assert GRID.cell_at(base.pose.x_m, base.pose.y_m) == 7
    assert abs(base.pose.x_m - GRID.center(7)[0]) < 0.1


def test_bad_inputs_are_refused_with_a_reason():
    ex, _ = setup(1)
    (log, result) = ex.action("Upwards", 0.0, goal_id=8)
    assert result.body["error_name"] == "INVALID_ACTION" and result.body["goal_id"] == 8
    refused = [o for o in ex.action("East", 0.0, goal_id=9) if o.kind == "result"]
    assert refused[0].body["error_name"] == "ACTION_LEAVES_MAP"
    assert refused[0].body["goal_id"] == 9  # each result carries its own goal's id
    assert ex.set_pose(Pose2D(float("nan"), 0.0, 0.0), 1.0)[0].kind == "log"
    assert ex.goal(float("inf"), 1.0, 1.0)[0].kind == "log"


def test_a_refused_goal_never_takes_over_the_id_of_the_goal_under_way():
    ex, base = setup(3)
    ex.action("East", 0.0, goal_id=5)  # 3 -> 1
    t, _ = run(ex, base, 0.0, 0.5, stop_on_result=False)
    for bad in ("Upwards", "South"):  # invalid; South from the south row leaves the map
        (refused,) = [o.body for o in ex.action(bad, t, goal_id=6) if o.kind == "result"]
        assert refused["result"] == "refused" and refused["goal_id"] == 6
    assert ex.goal_id == 5 and ex.task["target_cell"] == 1 and ex.follower.active
    t, results = run(ex, base, t, t + 10.0)
    assert results[0][1]["goal_id"] == 5 and results[0][1]["target_cell"] == 1


def test_cancel_ends_only_the_goal_under_way():
    ex, base = setup(7)
    ex.action("East", 0.0, goal_id=5)
    t, _ = run(ex, base, 0.0, 0.5, stop_on_result=False)
    assert ex.cancel(4, "not this one") == [] and ex.follower.active
    out = ex.cancel(5, "client asked")
    assert out[0].kind == "cmd" and out[0].cmd.vx_mps == 0.0
    (result,) = [o.body for o in out if o.kind == "result"]
    assert result["result"] == "canceled" and result["goal_id"] == 5
    assert not ex.follower.active and ex.cancel(5, "again") == []


def test_a_trip_drives_straight_into_the_cell_without_stopping_on_the_way():
    """ "To 1" from cell 6 (x 3-4, y 1.5-3) crosses cells 4 and 3 or 5 in one drive and
    ends just inside cell 1's nearest corner, not at its centre; sent again it keeps
    driving; its result comes on entering cell 1."""
    ex, base = setup(6)
    assert ex.action("To 1", 0.0, goal_id=3) == []
    t, _ = run(ex, base, 0.0, 1.5, stop_on_result=False)
    assert ex.action("To 1", t, goal_id=4) == []  # the same trip: no restart
    t, results = run(ex, base, t, 20.0)
    ((t_in, body),) = results
    assert body["result"] == "succeeded" and body["target_cell"] == 1
    assert body["action"] == "To 1" and body["goal_id"] == 4
    assert GRID.cell_at(base.pose.x_m, base.pose.y_m) == 1
    straight = ((5.2 - 3.5) ** 2 + (2.25 - 1.3) ** 2) ** 0.5  # centre of 6 to cell 1's border
    assert t_in < straight / 0.5 + 1.5  # top speed all the way (acceleration aside)
    run(ex, base, t, t + 5.0, stop_on_result=False)
    x0, y0, x1, y1 = GRID.bounds(1)
    assert abs(base.pose.x_m - (x0 + 0.35)) < 0.1 and abs(base.pose.y_m - (y1 - 0.35)) < 0.1


def test_a_trip_enters_where_the_person_is_not_and_bad_cells_are_refused():
    ex, base = setup(3)
    ex.set_people([(5.5, 0.5)])  # a person in the south of cell 1
    ex.action("To 1", 0.0, goal_id=1)
    gx, gy = ex.follower.goal
    assert GRID.cell_at(gx, gy) == 1 and ((gx - 5.5) ** 2 + (gy - 0.5) ** 2) ** 0.5 >= 0.6
    out = ex.action("To 99", 0.0, goal_id=2)
    assert [o.body["error_name"] for o in out if o.kind == "result"] == ["INVALID_ACTION"]
    assert "no such cell" in out[0].text and ex.goal_id == 1  # the trip under way stays


def test_a_person_who_stepped_up_to_the_robot_does_not_freeze_its_trip():
    """The person walked into cell 1 and stands 0.5 m from the robot at its border
    (closer than the 0.6 m contact clearance): the robot moves round them into the cell,
    keeping about its distance, instead of waiting to be reported blocked."""
    occ = OccupancyMap.empty(8.0, 5.0, 0.05, (-1.0, -1.0))
    ex = ActionExecutor(GRID, FollowerConfig(), occ)
    base = KinematicBase(Pose2D(4.96, 0.66, 0.0))
    ex.set_pose(base.pose, 0.0)
    person = (5.45, 0.82)
    ex.set_people([person])
    ex.action("To 1", 0.0, goal_id=1)
    t, gaps, results = 0.0, [], []
    while t < 6.0 and not results:
        t += DT
        for o in ex.tick(t):
            if o.kind == "cmd":
                base.step(o.cmd, DT)
            elif o.kind == "result":
                results.append(o.body)
        ex.set_pose(base.pose, t)
        gaps.append(((base.pose.x_m - person[0]) ** 2 + (base.pose.y_m - person[1]) ** 2) ** 0.5)
    assert results and results[0]["result"] == "succeeded" and results[0]["cell"] == 1
    assert min(gaps) > 0.4  # never into the person
