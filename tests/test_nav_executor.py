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
