"""The holonomic path follower against a kinematic model of the mecanum base."""

import math

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError
from stack.nav.base_model import KinematicBase
from stack.nav.config import FollowerConfig
from stack.nav.follower import (
    FollowerState,
    NavErrorCode,
    NavResult,
    PathFollower,
    Pose2D,
    Twist2D,
    cap_twist,
)
from stack.nav.occupancy import OCCUPIED, OccupancyMap
from stack.nav.waypoints import ActionOutcome, CellWaypoints

GRID = CellGrid()  # 6 m x 3 m of cells from (0, 0)
CFG = FollowerConfig()
DT = 0.05


def room(wall_x_m: float | None = None, door_y_m: tuple[float, float] | None = None):
    """An 8 m x 5 m room around the cells, walls one cell thick; optional inner wall."""
    m = OccupancyMap.empty(8.0, 5.0, 0.05, (-1.0, -1.0))
    data = m.data.copy()
    data[[0, -1], :] = OCCUPIED
    data[:, [0, -1]] = OCCUPIED
    if wall_x_m is not None:
        _, col = m.world_to_cell(wall_x_m, 0.0)
        data[:, col] = OCCUPIED
        if door_y_m is not None:
            r0, _ = m.world_to_cell(0.0, door_y_m[0])
            r1, _ = m.world_to_cell(0.0, door_y_m[1])
            data[r0:r1, col] = 0
    return m.with_data(data)


def drive(follower, base, goal, t0=0.0, people=(), max_s=40.0, region=None):
    """Run the loop until the task ends; returns (final status, commands, poses, t)."""
    follower.start(goal, t0, region)
    t, cmds, poses = t0, [], [base.pose]
    while t - t0 < max_s:
        status = follower.step(base.pose, t, t, people)
        cmds.append(status.cmd)
        if status.result is not None:
            break
        base.step(status.cmd, DT)
        poses.append(base.pose)
        t += DT
    for _ in range(20):  # let the first-order lag settle after the last command
        base.step(Twist2D(), DT)
    return status, cmds, poses, t


def test_reaches_every_cells_waypoint_within_tolerance_respecting_limits():
    follower = PathFollower(CFG, room())
    waypoints = CellWaypoints(GRID)
    base = KinematicBase(Pose2D(*GRID.center(7), yaw_rad=0.9))
    tour = ["East", "East", "East", "North", "West", "West", "West", "West", "West", "South"]
    tour += ["East", "East"]
    visited = set()
    t = 0.0
    all_cmds = []
    for action in tour:
        cell = waypoints.cell_of(base.pose.x_m, base.pose.y_m)
        target = waypoints.target(cell, action)
        assert target.outcome is ActionOutcome.MOVE
        status, cmds, _, t = drive(follower, base, target.waypoint_m, t0=t)
        assert status.result is NavResult.SUCCEEDED, status
        assert status.error_code is NavErrorCode.NONE
        assert math.dist((base.pose.x_m, base.pose.y_m), target.waypoint_m) <= CFG.goal_tolerance_m
        assert waypoints.cell_of(base.pose.x_m, base.pose.y_m) == target.cell
        visited.add(target.cell)
        all_cmds.append(cmds)
        t += 1.0
    assert visited == set(GRID.cells)
    v = np.array([[c.vx_mps, c.vy_mps, c.wz_radps] for cmds in all_cmds for c in cmds])
    assert (np.abs(v[:, 0]) <= CFG.max_vx_mps + 1e-9).all()
    assert (np.abs(v[:, 1]) <= CFG.max_vy_mps + 1e-9).all()
    assert (np.hypot(v[:, 0], v[:, 1]) <= CFG.max_speed_mps + 1e-9).all()
    assert (np.abs(v[:, 2]) <= CFG.max_wz_radps + 1e-9).all()
    # the base is holonomic and turned 0.9 rad off the map axes: it uses its lateral axis
    assert np.abs(v[:, 1]).max() > 0.1
    # acceleration limits hold while moving; the stop at the goal is a (small) step to zero
    limits = np.array([CFG.max_accel_x_mps2, CFG.max_accel_y_mps2, CFG.max_accel_wz_radps2])
    for cmds in all_cmds:
        v = np.array([[0.0, 0.0, 0.0]] + [[c.vx_mps, c.vy_mps, c.wz_radps] for c in cmds[:-1]])
        assert (np.abs(np.diff(v, axis=0)) <= limits * DT + 1e-9).all()
        assert cmds[-1].is_zero() and np.hypot(*v[-1, :2]) < 0.2


def test_a_differential_drive_tours_every_cell_forward_only_turning_on_the_spot():
    cfg = FollowerConfig(drive="diff")
    follower = PathFollower(cfg, room())
    waypoints = CellWaypoints(GRID)
    base = KinematicBase(Pose2D(*GRID.center(7), yaw_rad=math.pi))  # facing away from 5
    tour = ["East", "East", "East", "North", "West", "West", "West", "West", "West", "South"]
    visited, t, all_cmds = set(), 0.0, []
    for action in tour:
        cell = waypoints.cell_of(base.pose.x_m, base.pose.y_m)
        target = waypoints.target(cell, action)
        status, cmds, _, t = drive(follower, base, target.waypoint_m, t0=t)
        assert status.result is NavResult.SUCCEEDED, (action, status)
        assert waypoints.cell_of(base.pose.x_m, base.pose.y_m) == target.cell
        visited.add(target.cell)
        all_cmds += cmds
        t += 1.0
    assert len(visited) == len(tour)
    v = np.array([[c.vx_mps, c.vy_mps, c.wz_radps] for c in all_cmds])
    assert (v[:, 1] == 0.0).all()  # never sideways
    assert (v[:, 0] >= 0.0).all()  # never backwards
    assert (np.abs(v[:, 2]) <= cfg.max_wz_radps + 1e-9).all()
    # the first move starts facing away: it turns on the spot before driving
    first = v[: int(1.0 / DT)]
    assert (first[:, 0] == 0.0).all() and np.abs(first[:, 2]).max() > 0.5


def test_holonomic_and_diff_are_the_only_drives():
    with pytest.raises(ConfigError, match="follower.drive"):
        FollowerConfig.from_dict({"drive": "ackermann"})


def test_orientation_is_ignored_at_the_goal():
    follower = PathFollower(CFG, room())
    base = KinematicBase(Pose2D(*GRID.center(5), yaw_rad=-2.5))
    status, *_ = drive(follower, base, GRID.center(3))
    assert status.result is NavResult.SUCCEEDED
    assert base.pose.yaw_rad == pytest.approx(-2.5, abs=0.05)  # held, never turned to 0


def test_stale_pose_gives_zero_velocity_at_once_and_resumes():
    follower = PathFollower(CFG, room())
    base = KinematicBase(Pose2D(*GRID.center(7)))
    follower.start(GRID.center(1), 0.0)
    t = 0.0
    for _ in range(30):
        status = follower.step(base.pose, t, t)
        base.step(status.cmd, DT)
        t += DT
    assert not status.cmd.is_zero()
    stale = follower.step(base.pose, t - CFG.stale_pose_s - 0.1, t)
    assert stale.cmd.is_zero() and stale.state is FollowerState.STALE_POSE
    assert stale.result is None and follower.active
    assert follower.step(None, 0.0, t + DT).cmd.is_zero()
    fresh = follower.step(base.pose, t + 2 * DT, t + 2 * DT)
    assert fresh.state is FollowerState.ACTIVE and not fresh.cmd.is_zero()
    # it ramps up again from zero under the acceleration limit
    assert abs(fresh.cmd.vx_mps) <= CFG.max_accel_x_mps2 * DT + 1e-9


def test_person_standing_on_the_waypoint_blocks():
    cfg = FollowerConfig(blocked_timeout_s=2.0)
    follower = PathFollower(cfg, room())
    base = KinematicBase(Pose2D(*GRID.center(7)))
    person = GRID.center(5)
    status, cmds, poses, t = drive(follower, base, GRID.center(5), people=[person])
    assert status.result is NavResult.BLOCKED
    assert status.error_code is NavErrorCode.PATH_BLOCKED_BY_PERSON
    assert t == pytest.approx(cfg.blocked_timeout_s, abs=2 * DT)
    assert all(c.is_zero() for c in cmds)
    assert math.dist((base.pose.x_m, base.pose.y_m), GRID.center(7)) < 1e-9


def test_person_on_the_waypoint_the_robot_still_enters_the_cell():
    # the action is "go to cell 5": with the cell as the region the robot stops inside
    # it, beside the person, instead of waiting for the person to leave the waypoint
    follower = PathFollower(CFG, room())
    base = KinematicBase(Pose2D(*GRID.center(7)))
    person = GRID.center(5)
    status, _, poses, _ = drive(
        follower, base, GRID.center(5), people=[person], region=GRID.bounds(5)
    )
    assert status.result is NavResult.SUCCEEDED
    assert GRID.cell_at(base.pose.x_m, base.pose.y_m) == 5
    clearance = min(math.dist((p.x_m, p.y_m), person) for p in poses)
    assert clearance >= CFG.person_radius_m + CFG.robot_radius_m - 0.05


def test_a_person_who_stepped_up_to_the_robot_at_the_cells_border_is_walked_round():
    # the person stopped at cell 1's border right in front of the robot, nearer than
    # the gap it keeps (robot radius + 0.15 m): it steps back to that gap, goes round
    # them and enters the cell where they are not, never closer than it started
    follower = PathFollower(CFG, room())
    start = (4.75, 0.64)
    base = KinematicBase(Pose2D(*start))
    person = (5.1, 0.5)
    gap = math.dist(start, person)
    assert gap < CFG.robot_radius_m + 0.15
    status, _, poses, _ = drive(
        follower, base, (5.35, 0.6), people=[person], region=GRID.bounds(1), max_s=15
    )
    assert status.result is NavResult.SUCCEEDED
    assert GRID.cell_at(base.pose.x_m, base.pose.y_m) == 1
    assert min(math.dist((p.x_m, p.y_m), person) for p in poses) >= gap - 0.03


def test_a_robot_already_in_the_cell_does_not_step_out_of_it_for_a_person_who_comes_close():
    # in cell 12 by its corner, short of its waypoint; the visitor steps up to it: it
    # keeps still in the cell (stepping back would take it out of what it guards)
    follower = PathFollower(FollowerConfig(blocked_timeout_s=2.0), room())
    base = KinematicBase(Pose2D(0.95, 1.56))
    person = (0.9, 1.95)
    assert math.dist((0.95, 1.56), person) < CFG.robot_radius_m + 0.15
    status, cmds, poses, _ = drive(
        follower, base, (0.65, 1.85), people=[person], region=GRID.bounds(12), max_s=3
    )
    assert all(GRID.cell_at(p.x_m, p.y_m) == 12 for p in poses)
    assert all(c.is_zero() for c in cmds)


def test_the_cell_is_entered_on_the_far_side_of_a_person_when_the_near_one_is_closed():
    # a person in the south-west of cell 1, 0.6 m from the robot: the nearest free
    # points of the cell are behind them or across; the robot goes round, keeping
    # contact clearance
    follower = PathFollower(CFG, room())
    base = KinematicBase(Pose2D(4.5, 0.4))
    person = (5.15, 0.35)
    status, _, poses, _ = drive(
        follower, base, (5.35, 0.4), people=[person], region=GRID.bounds(1), max_s=15
    )
    assert status.result is NavResult.SUCCEEDED
    assert GRID.cell_at(base.pose.x_m, base.pose.y_m) == 1
    clearance = min(math.dist((p.x_m, p.y_m), person) for p in poses)
    assert clearance >= CFG.person_radius_m + CFG.robot_radius_m - 0.05


@pytest.mark.parametrize("slack", [None, 0.0])
def test_a_jittering_track_on_the_path_does_not_flip_the_way_round(slack, monkeypatch):
    # a person standing on the way from cell 9 to cell 3, their track jumping 8 cm
    # north and south: the way round them planned first stays (with no slack each jump
    # voids it, the robot swings from one side to the other and never gets past)
    from stack.nav import follower as follower_module

    if slack is not None:
        monkeypatch.setattr(follower_module, "REPLAN_SLACK_M", slack)
    follower = PathFollower(CFG, room())
    base = KinematicBase(Pose2D(*GRID.center(9)))
    follower.start(GRID.center(3), 0.0)
    t = 0.0
    for k in range(400):
        person = (3.0, 0.71 + (0.08 if k % 2 else 0.0))
        status = follower.step(base.pose, t, t, [person])
        if status.result is not None:
            break
        base.step(status.cmd, DT)
        t += DT
    if slack is None:
        assert status.result is NavResult.SUCCEEDED and status.replans <= 1
    else:
        assert status.result is not NavResult.SUCCEEDED and status.replans > 5


def test_person_in_a_doorway_blocks_after_the_robot_stops_short():
    # a wall between cells 7 and 5 with a 0.9 m door: a person in it closes the only way
    cfg = FollowerConfig(blocked_timeout_s=1.5)
    m = room(wall_x_m=3.0, door_y_m=(1.0, 1.9))
    follower = PathFollower(cfg, m)
    base = KinematicBase(Pose2D(*GRID.center(9)))
    person = (3.0, 1.45)
    status, cmds, poses, _ = drive(follower, base, GRID.center(3), people=[person], max_s=20)
    assert status.result is NavResult.BLOCKED
    clearance = min(math.dist((p.x_m, p.y_m), person) for p in poses)
    assert clearance >= cfg.person_radius_m + cfg.robot_radius_m


def test_person_in_open_floor_is_passed_by_replanning():
    follower = PathFollower(CFG, room())
    base = KinematicBase(Pose2D(*GRID.center(9)))
    person = GRID.center(7)
    # the person steps into the way once the robot is moving
    follower.start(GRID.center(5), 0.0)
    t, people, replans, poses = 0.0, [], 0, []
    for k in range(800):
        if k == 10:
            people = [person]
        status = follower.step(base.pose, t, t, people)
        if status.result is not None:
            break
        replans = status.replans
        base.step(status.cmd, DT)
        poses.append(base.pose)
        t += DT
    assert status.result is NavResult.SUCCEEDED
    assert replans >= 1
    clearance = min(math.dist((p.x_m, p.y_m), person) for p in poses[10:])
    assert clearance >= CFG.person_radius_m + CFG.robot_radius_m - 0.1


def test_goal_in_a_wall_is_no_path():
    follower = PathFollower(CFG, room(wall_x_m=3.0))
    base = KinematicBase(Pose2D(*GRID.center(9)))
    status, *_ = drive(follower, base, (3.0, 1.0))
    assert status.result is NavResult.NO_PATH
    assert status.error_code is NavErrorCode.GOAL_OCCUPIED
    status, *_ = drive(follower, base, GRID.center(3))  # the wall has no door
    assert status.result is NavResult.NO_PATH
    assert status.error_code is NavErrorCode.NO_CONNECTION


def test_timeout_and_cancel():
    follower = PathFollower(FollowerConfig(timeout_s=1.0), room())
    base = KinematicBase(Pose2D(*GRID.center(12)))
    status, *_ = drive(follower, base, GRID.center(1))
    assert status.result is NavResult.TIMED_OUT and status.cmd.is_zero()
    assert status.error_code is NavErrorCode.TIMEOUT
    follower.start(GRID.center(1), 10.0)
    assert follower.active
    status = follower.cancel()
    assert status.result is NavResult.CANCELED and not follower.active
    assert follower.step(base.pose, 10.1, 10.1).cmd.is_zero()


@pytest.mark.parametrize("seed", range(3))
def test_cap_twist_keeps_direction_within_limits(seed):
    rng = np.random.default_rng(seed)
    for vx, vy, wz in rng.normal(0.0, 2.0, size=(50, 3)):
        c = cap_twist(Twist2D(vx, vy, wz), CFG)
        assert abs(c.vx_mps) <= CFG.max_vx_mps + 1e-12
        assert abs(c.vy_mps) <= CFG.max_vy_mps + 1e-12
        assert abs(c.wz_radps) <= CFG.max_wz_radps + 1e-12
        assert c.vx_mps * vy == pytest.approx(c.vy_mps * vx)  # same direction
    assert cap_twist(Twist2D(math.nan, 0.1, math.inf), CFG) == Twist2D(0.0, 0.0, 0.0)


def test_config_from_dict_validates():
    cfg = FollowerConfig.from_dict({"max_vy_mps": 0.3, "goal_tolerance_m": 0.1})
    assert cfg.max_vy_mps == 0.3 and cfg.max_vx_mps == CFG.max_vx_mps
    with pytest.raises(ConfigError, match="follower.max_vy_mps: 0.0 is invalid: must be"):
        FollowerConfig.from_dict({"max_vy_mps": 0})
    with pytest.raises(ConfigError, match="nav.speed: .* unknown key"):
        FollowerConfig.from_dict({"speed": 1.0}, "nav")
    with pytest.raises(ConfigError, match="follower.timeout_s: 'long' is invalid: must be a num"):
        FollowerConfig.from_dict({"timeout_s": "long"})
