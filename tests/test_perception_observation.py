"""The planner's observation: labels, and the combination rules of thesis 4.5."""

from __future__ import annotations

import json

import pytest

from stack.cells import CellGrid, ConfigError, Direction
from stack.perception.camera import CameraPersonState, PersonStatus
from stack.perception.legs import Pose2D
from stack.perception.observation import (
    CombinerConfig,
    Observation,
    ObservationCombiner,
    SpeedClass,
)
from stack.perception.tracker import TrackEstimate

GRID = CellGrid()


def person(xy, direction, stamp_s=10.0, status=PersonStatus.PERSON):
    return CameraPersonState(
        stamp_s=stamp_s, status=status, position_m=xy, cell=GRID.cell_at(*xy), direction=direction
    )


def track(xy, speed_mps, last_update_s=10.0, confirmed=True):
    return TrackEstimate(1, xy, (speed_mps, 0.0), speed_mps, 5, last_update_s, confirmed)


@pytest.mark.parametrize(
    ("direction", "speed", "label"),
    [
        (Direction.EAST, SpeedClass.FAST, "East higher"),
        (Direction.WEST, SpeedClass.MEDIUM, "West 0.2-0.7"),
        (Direction.SOUTH, SpeedClass.SLOW, "South 0-0.2"),
        (Direction.NORTH, SpeedClass.SLOW, "North 0-0.2"),
        (Direction.NOT_MOVING, None, "Not moving"),
    ],
)
def test_velocity_labels_are_the_thesis_alphabet(direction, speed, label):
    obs = Observation(1.0, 7, direction, speed, 5)
    assert obs.velocity_label == label
    assert obs.person_label == "7" and obs.robot_label == "5"
    back = Observation.from_labels(1.0, "5", "7", label)
    assert back == obs
    assert Observation.from_dict(json.loads(obs.to_json())) == obs


def test_no_person_and_out_of_map_labels_and_invariants():
    obs = Observation(1.0, None, Direction.NOT_MOVING, None, None)
    assert (obs.person_label, obs.velocity_label, obs.robot_label) == (
        "No person", "Not moving", "Out of the map",
    )  # fmt: skip
    with pytest.raises(ValueError, match="no person"):
        Observation(1.0, None, Direction.EAST, SpeedClass.FAST, 3)
    with pytest.raises(ValueError, match="speed"):
        Observation(1.0, 4, Direction.EAST, None, 3)
    with pytest.raises(ValueError, match="speed"):
        Observation(1.0, 4, Direction.NOT_MOVING, SpeedClass.SLOW, 3)
    with pytest.raises(ValueError):
        Observation.from_labels(1.0, "3", "4", "Eastward fast")
    with pytest.raises(ValueError):
        Observation.from_labels(1.0, "3", "somewhere", "Not moving")


def test_a_robot_just_past_the_edge_is_in_the_edge_cell_further_out_of_the_map():
    """An overshoot 0.23 m past cell 1's south edge once labelled the robot "Out of the
    map", which the task model cannot reach: the planner ignored every observation."""
    comb = ObservationCombiner(GRID)
    x0, y0 = GRID.origin_m
    w, _ = GRID.size_m
    just_out = Pose2D(x0 + w - 0.5, y0 - 0.23, 0.0)
    edge = GRID.cell_at(x0 + w - 0.5, y0 + 0.01)
    assert comb.combine(10.0, None, (), just_out).robot_label == str(edge)
    far = Pose2D(x0 + w - 0.5, y0 - 0.5, 0.0)
    assert comb.combine(10.1, None, (), far).robot_label == "Out of the map"


def test_no_person_from_a_camera_that_sees_the_cell_ignores_the_laser():
    comb = ObservationCombiner(GRID)
    fast_leg = track(GRID.center(4), 1.5)
    cam = CameraPersonState(stamp_s=10.0, status=PersonStatus.NO_PERSON)
    obs = comb.combine(10.0, cam, [fast_leg], Pose2D(*GRID.center(7)))
    assert obs.person_label == "No person" and obs.velocity_label == "Not moving"
    assert obs.robot_cell == 7 and obs.hidden == () and obs.source == "none"


@pytest.mark.parametrize("camera", ["unknown", "none", "stale"])
def test_a_camera_that_cannot_see_gives_unseen_never_no_person(camera):
    comb = ObservationCombiner(GRID)
    cam = {
        "unknown": CameraPersonState(stamp_s=10.0, status=PersonStatus.UNKNOWN),
        "none": None,
        "stale": CameraPersonState(stamp_s=5.0, status=PersonStatus.NO_PERSON),  # frozen
    }[camera]
    obs = comb.combine(10.0, cam, [], Pose2D(*GRID.center(7)))
    assert obs.person_label == "Unseen" and obs.person_cell is None
    assert dict(obs.hidden) == {c: 1.0 for c in GRID.cells}
    back = Observation.from_dict(json.loads(obs.to_json()))
    assert back.person_label == "Unseen" and back.hidden == obs.hidden


def test_laser_alone_gives_the_cell_and_velocity_when_the_camera_cannot_see():
    comb = ObservationCombiner(GRID)
    fast_leg = TrackEstimate(1, GRID.center(4), (-1.3, 0.1), 1.3, 9, 10.0, True)
    obs = comb.combine(10.0, None, [fast_leg], Pose2D(*GRID.center(7)))
    assert obs.person_cell == 4 and obs.velocity_label == "West higher"
    assert obs.source == "laser"
    still = TrackEstimate(2, GRID.center(3), (0.05, 0.0), 0.05, 9, 10.0, True)
    obs = comb.combine(10.0, None, [still], Pose2D(*GRID.center(7)))
    assert obs.person_cell == 3 and obs.velocity_label == "Not moving"
    # an unconfirmed or NaN track is not a person
    bad = TrackEstimate(3, (float("nan"), 1.0), (0.0, 0.0), float("nan"), 9, 10.0, True)
    young = TrackEstimate(4, GRID.center(3), (0.5, 0.0), 0.5, 1, 10.0, False)
    assert comb.combine(10.0, None, [bad, young]).person_label == "Unseen"


def test_camera_foot_point_the_laser_contradicts_is_fused_not_dropped():
    comb = ObservationCombiner(GRID)
    # the case: the camera puts a half-hidden person at x = 6.1 (past the grid's
    # east edge), the laser at 5.43 in cell 1
    cam = person((6.1, 0.7), Direction.NOT_MOVING)
    obs = comb.combine(10.0, cam, [track((5.43, 0.7), 0.0)], Pose2D(*GRID.center(5)))
    assert obs.person_cell == 1 and obs.source == "fused"
    assert 5.43 < obs.person_position_m[0] < 5.6
    # just past the edge without the laser: the nearest cell (foot-point error)
    assert comb.combine(10.0, person((6.2, 0.7), Direction.NOT_MOVING), []).person_cell == 1
    # well outside: not in the environment
    assert comb.combine(10.0, person((6.8, 0.7), Direction.NOT_MOVING), []).person_cell is None


def test_speed_comes_from_the_track_at_the_camera_person():
    comb = ObservationCombiner(GRID)
    xy = GRID.center(4)
    cam = person(xy, Direction.EAST)
    near_fast = track((xy[0] + 0.3, xy[1]), 1.1)
    far_slow = track(GRID.center(11), 0.4)
    obs = comb.combine(10.2, cam, [far_slow, near_fast], Pose2D(*GRID.center(3)))
    assert obs.velocity_label == "East higher" and obs.person_cell == 4 and obs.robot_cell == 3
    assert obs.speed_mps == pytest.approx(1.1)
    medium = comb.combine(10.2, cam, [track(xy, 0.5)])
    assert medium.velocity_label == "East 0.2-0.7"
    assert medium.robot_cell == 3  # no new pose: the robot stayed where it was


def test_camera_person_without_laser_data_is_slow():
    comb = ObservationCombiner(GRID)
    xy = GRID.center(9)
    cam = person(xy, Direction.WEST)
    assert comb.combine(10.0, cam, []).velocity_label == "West 0-0.2"
    far = track(GRID.center(2), 1.5)  # someone (something) else
    assert comb.combine(10.0, cam, [far]).velocity_label == "West 0-0.2"
    stale = track(xy, 1.5, last_update_s=5.0)
    assert comb.combine(10.0, cam, [stale]).velocity_label == "West 0-0.2"
    unconfirmed = track(xy, 1.5, confirmed=False)
    assert comb.combine(10.0, cam, [unconfirmed]).velocity_label == "West 0-0.2"


def test_not_moving_camera_wins_over_laser_speed_and_outside_is_no_person():
    comb = ObservationCombiner(GRID)
    xy = GRID.center(6)
    obs = comb.combine(10.0, person(xy, Direction.NOT_MOVING), [track(xy, 0.9)])
    assert obs.velocity_label == "Not moving" and obs.person_cell == 6
    outside = comb.combine(10.0, person((-1.0, 1.0), Direction.EAST), [track((-1.0, 1.0), 1.0)])
    assert outside.person_label == "No person" and outside.velocity_label == "Not moving"
    # the floor point still travels with it, for the goal inference (person_model: goal)
    assert outside.person_position_m == pytest.approx((-1.0, 1.0))
    assert outside.to_dict()["person_position_m"] == pytest.approx([-1.0, 1.0])
    old = comb.combine(20.0, person(xy, Direction.EAST, stamp_s=10.0), [])
    assert old.person_label == "Unseen"


def test_combiner_config_validation():
    assert CombinerConfig.from_dict({"speed_thresholds_mps": [0.3, 0.8]}).speed_thresholds_mps == (
        0.3, 0.8,
    )  # fmt: skip
    with pytest.raises(ConfigError, match=r"observations\.speed_thresholds_mps"):
        CombinerConfig.from_dict({"speed_thresholds_mps": [0.8, 0.3]})
    with pytest.raises(ConfigError, match="list of 2"):
        CombinerConfig.from_dict({"speed_thresholds_mps": [0.8]})


class _RobotHidesCell1:
    """A stand-in for CameraVisibility: the robot in cell 3 hides cell 1 wholly."""

    def hidden_fractions(self, pose):
        return {c: (1.0 if c == 1 else 0.0) for c in GRID.cells}

    def point_hidden(self, x, y, pose):
        return GRID.cell_at(x, y) == 1


def test_a_cell_hidden_behind_the_robot_is_no_person_with_the_cell_hidden_not_unseen():
    # the camera sees the rest of the grid: "No person" there is information the
    # planner must keep (before: every listed hidden cell at 1.0 read as "Unseen")
    comb = ObservationCombiner(GRID, visibility=_RobotHidesCell1())
    robot = Pose2D(*GRID.center(3))
    seen = comb.combine(9.0, person(GRID.center(1), Direction.EAST, stamp_s=9.0), [], robot)
    assert seen.person_cell == 1
    lost = comb.combine(10.0, CameraPersonState(stamp_s=10.0, status=PersonStatus.NO_PERSON),
                        [], robot)  # fmt: skip
    assert lost.person_label == "No person" and not lost.blind
    assert dict(lost.hidden) == {1: 1.0}
    back = Observation.from_dict(json.loads(lost.to_json()))
    assert back.person_label == "No person" and back.hidden == lost.hidden
    # the same with the camera out: blind, "Unseen"
    out = comb.combine(20.0, None, [], robot)
    assert out.blind and out.person_label == "Unseen"
    assert Observation.from_labels(20.0, "3", "Unseen", "Not moving").person_label == "Unseen"
