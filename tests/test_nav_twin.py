"""The navigation stack drives the MuJoCo twin in closed loop (no rendering).

The twin's map is saved as map_server YAML + PGM and loaded with stack.nav's loader, the
PathFollower turns each action into velocity commands for ``Twin.step`` (one 20 ms
control period per follower step), and the twin's ground truth judges where the robot
ended up. The person walks far from the cells (a single waypoint in the room's
north-west corner), so no replanning is involved.
"""

from __future__ import annotations

import math

import pytest

from stack.nav.config import FollowerConfig
from stack.nav.follower import NavResult, PathFollower, Pose2D
from stack.nav.occupancy import load_map_yaml
from stack.nav.waypoints import ActionOutcome, CellWaypoints
from twin.config import PersonConfig, TwinConfig, Waypoint
from twin.twin import Twin, VelocityCommand

SETTLE_STEPS = 50  # 1 s of zero commands after a result: the base stops within ~0.3 s


@pytest.fixture
def twin():
    # the person stands in the north-west corner of the room, 3 m from the region
    person = PersonConfig(waypoints=(Waypoint(x_m=-2.5, y_m=4.3),))
    tw = Twin(TwinConfig(person=person), seed=0)
    yield tw
    tw.close()


@pytest.fixture
def follower(twin, tmp_path):
    _, yaml_path = twin.save_map(tmp_path, "lrm")
    return PathFollower(FollowerConfig(), load_map_yaml(yaml_path))


def _pose(twin: Twin, source: str) -> tuple[Pose2D, float]:
    if source == "odometry":
        o = twin.odometry()
        return Pose2D(o.pose.x_m, o.pose.y_m, o.pose.yaw_rad), o.time_s
    gt = twin.ground_truth()
    return Pose2D(gt.robot.x_m, gt.robot.y_m, gt.robot.yaw_rad), gt.time_s


def _drive(twin: Twin, follower: PathFollower, goal: tuple[float, float], source: str):
    """Run the follower against the twin until it reports a result; then let the base stop."""
    follower.start(goal, twin.time_s)
    limit = round(follower.config.timeout_s / twin.config.control_period_s) + 10
    for _ in range(limit):
        pose, stamp = _pose(twin, source)
        status = follower.step(pose, stamp, twin.time_s)
        if status.result is not None:
            break
        c = status.cmd
        twin.step(VelocityCommand(c.vx_mps, c.vy_mps, c.wz_radps))
    else:
        pytest.fail("the follower never reported a result")
    final, _ = _pose(twin, source)
    for _ in range(SETTLE_STEPS):
        twin.step(VelocityCommand())  # what the node sends after a task: one zero
    return status, final


@pytest.mark.parametrize("source", ["ground_truth", "odometry"])
def test_actions_from_cell_7_reach_their_cells(twin, follower, source):
    waypoints = CellWaypoints(twin.config.grid)
    tol = follower.config.goal_tolerance_m
    cell = twin.ground_truth().robot_cell
    assert cell == 7
    for action, expected in (("East", 5), ("North", 6), ("West", 8)):
        target = waypoints.target(cell, action)
        assert target.outcome is ActionOutcome.MOVE and target.cell == expected
        t0 = twin.time_s
        status, pose_at_end = _drive(twin, follower, target.waypoint_m, source)
        assert status.result is NavResult.SUCCEEDED, status.message
        assert status.replans == 0  # the person is nowhere near
        gx, gy = target.waypoint_m
        # the follower's own view at the result is within its tolerance
        assert math.hypot(pose_at_end.x_m - gx, pose_at_end.y_m - gy) <= tol
        # a 1 m move takes ~2.4 s and a 1.5 m move ~4 s at 0.5 m/s (0.8 m/s^2)
        assert twin.time_s - t0 < 6.0
        gt = twin.ground_truth()
        assert max(abs(v) for v in gt.robot_velocity) < 1e-3, "the base has not stopped"
        assert gt.robot_cell == expected
        err = math.hypot(gt.robot.x_m - gx, gt.robot.y_m - gy)
        if source == "odometry":
            # odometry drifts ~1 cm per move; allow what it is off by right now
            o = twin.odometry().pose
            drift = math.hypot(o.x_m - gt.robot.x_m, o.y_m - gt.robot.y_m)
            assert err <= tol + drift
        else:
            assert err <= tol
        assert abs(gt.robot.yaw_rad) < 0.05  # the heading is held (start yaw 0)
        cell = gt.robot_cell
