"""Laser side of perception: leg detection, static-map rejection, Kalman speed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stack.cells import ConfigError
from stack.perception.errors import BadScanError
from stack.perception.legs import (
    LegConfig,
    Pose2D,
    Scan,
    StaticMap,
    detect_legs,
    pair_legs,
    segment_scan,
)
from stack.perception.observation import SpeedClass, speed_class
from stack.perception.synthetic import simulate_scan, walking_legs
from stack.perception.tracker import LegTracker, TrackerConfig, nearest_track

LEG_RADIUS_M = 0.06
ROOM = [((-1.0, -1.0), (8.0, -1.0)), ((8.0, -1.0), (8.0, 5.0)), ((8.0, 5.0), (-1.0, 5.0))]
CHAIR_LEGS = [(5.0, 3.0), (5.4, 3.0), (5.0, 3.4), (5.4, 3.4)]  # 0.4 m apart: pair-able


def chair_map(resolution_m=0.05):
    """The robot's map: the chair's legs (and nothing else) occupied."""
    occ = np.zeros((120, 180), bool)  # 9 m x 6 m from (-1, -1)
    for x, y in CHAIR_LEGS:
        occ[int((y + 1.0) / resolution_m), int((x + 1.0) / resolution_m)] = True
    return StaticMap(occ, resolution_m, (-1.0, -1.0))


@pytest.mark.parametrize("distance_m", [1.0, 2.0, 3.0])
def test_two_legs_at_1_to_3_m_are_one_person(distance_m):
    rng = np.random.default_rng(int(distance_m * 10))
    robot = Pose2D(1.0, 1.0, math.radians(30))
    heading = robot.yaw_rad + 0.2
    center = (1.0 + distance_m * math.cos(heading), 1.0 + distance_m * math.sin(heading))
    legs = walking_legs(center, heading + 1.0, 0.3, 1.0)
    scan = simulate_scan(robot, [(*p, LEG_RADIUS_M) for p in legs], rng, walls=ROOM)
    det = detect_legs(scan, LegConfig(expected_beams=720), robot)
    paired = [p for p in det.people if len(p.legs) == 2]
    assert len(paired) == 1
    # The leg centres lie on the surfaces facing the laser: within a leg radius.
    assert math.dist(paired[0].position_m, center) < LEG_RADIUS_M + 0.03
    for leg in paired[0].legs:
        assert 0.05 < leg.width_m < 0.15 and leg.n_points >= 3 and leg.bulge_m > 0


def test_chair_legs_on_the_map_are_not_a_person_but_the_person_is():
    rng = np.random.default_rng(7)
    robot = Pose2D(3.0, 1.0, math.radians(60))
    person = [(3.6, 2.6), (3.85, 2.55)]
    circles = [(x, y, 0.04) for x, y in CHAIR_LEGS] + [(x, y, LEG_RADIUS_M) for x, y in person]
    scan = simulate_scan(robot, circles, rng, walls=ROOM)
    without_map = detect_legs(scan, LegConfig(), robot)
    near_chair = [p for p in without_map.people if math.dist(p.position_m, (5.2, 3.2)) < 0.5]
    assert near_chair, "the chair's legs look like legs when the map is not used"
    det = detect_legs(scan, LegConfig(), robot, chair_map())
    assert det.on_obstacles >= 2
    assert all(math.dist(p.position_m, (5.2, 3.2)) > 0.5 for p in det.people)
    assert len(det.people) == 1 and len(det.people[0].legs) == 2
    assert math.dist(det.people[0].position_m, (3.725, 2.575)) < 0.1


def test_walls_and_empty_scans_give_no_legs():
    rng = np.random.default_rng(8)
    robot = Pose2D(2.0, 2.0, 0.0)
    scan = simulate_scan(robot, [], rng, walls=ROOM)
    assert detect_legs(scan, LegConfig(), robot).legs == ()
    nothing = Scan(np.full(360, np.inf), -math.pi, 2 * math.pi / 360)
    det = detect_legs(nothing, LegConfig(), robot)
    assert det.legs == () and det.people == () and det.valid_beams == 0


def test_nan_inf_and_out_of_range_returns_split_segments():
    r = np.array([2.0, 2.0, 2.0, np.nan, 2.0, 2.0, np.inf, 2.0, 0.01, 2.0, 2.0, 50.0])
    scan = Scan(r, 0.0, math.radians(0.5), range_min_m=0.05, range_max_m=10.0)
    segs = segment_scan(scan, LegConfig())
    assert [s.tolist() for s in segs] == [[0, 1, 2], [4, 5], [7], [9, 10]]
    assert scan.valid.sum() == 8


def test_bad_scans_raise_clear_errors():
    with pytest.raises(BadScanError, match="720"):
        detect_legs(Scan(np.ones(700), 0.0, 0.01), LegConfig(expected_beams=720))
    with pytest.raises(BadScanError, match="non-zero"):
        Scan(np.ones(10), 0.0, 0.0)
    with pytest.raises(BadScanError, match="1-D"):
        Scan(np.ones((2, 5)), 0.0, 0.01)
    with pytest.raises(BadScanError, match="finite"):
        Scan(np.ones(10), math.nan, 0.01)
    with pytest.raises(ConfigError, match=r"legs\.min_points"):
        LegConfig.from_dict({"min_points": 50})


def test_pairing_takes_closest_legs_first_and_respects_the_limit():
    from stack.perception.legs import Leg

    legs = [Leg((0.0, 0.0), 0.1, 5, 0.02), Leg((0.3, 0.0), 0.1, 5, 0.02),
            Leg((0.9, 0.0), 0.1, 5, 0.02), Leg((3.0, 0.0), 0.1, 5, 0.02)]  # fmt: skip
    people = pair_legs(legs, 0.8, allow_single=False)
    assert [p.position_m for p in people] == [(0.15, 0.0)]
    people = pair_legs(legs, 0.8, allow_single=True)
    assert len(people) == 3 and sum(len(p.legs) for p in people) == 4


def track_walk(speed_mps, robot_moves, seed, duration_s=3.0, rate_hz=10.0):
    """Walk a person north-east at a known speed past a (possibly moving) robot."""
    rng = np.random.default_rng(seed)
    tracker = LegTracker(TrackerConfig())
    heading = math.radians(40)
    start = (1.5, 1.0)
    for k in range(int(duration_s * rate_hz)):
        t = k / rate_hz
        center = (start[0] + speed_mps * t * math.cos(heading),
                  start[1] + speed_mps * t * math.sin(heading))  # fmt: skip
        # The robot drives east at 0.4 m/s while turning: its motion must not leak in.
        robot = Pose2D(0.4 * t, 0.0, 0.3 * t) if robot_moves else Pose2D(0.0, 0.0, 0.5)
        legs = walking_legs(center, heading, t, speed_mps)
        scan = simulate_scan(robot, [(*p, LEG_RADIUS_M) for p in legs], rng, walls=ROOM,
                             stamp_s=t)  # fmt: skip
        det = detect_legs(scan, LegConfig(), robot)
        tracks = tracker.update(t, [p.position_m for p in det.people])
    track = nearest_track(tracks, center, gate_m=0.5)
    assert track is not None
    return track


@pytest.mark.parametrize(
    ("speed_mps", "expected"),
    [(0.0, SpeedClass.SLOW), (0.45, SpeedClass.MEDIUM), (1.2, SpeedClass.FAST)],
)
def test_speed_class_of_a_walk_at_known_speed_from_a_moving_robot(speed_mps, expected):
    track = track_walk(speed_mps, robot_moves=True, seed=int(speed_mps * 100))
    assert abs(track.speed_mps - speed_mps) < 0.12
    assert speed_class(track.speed_mps) is expected
    if speed_mps > 0:
        heading = math.atan2(track.velocity_mps[1], track.velocity_mps[0])
        assert abs(heading - math.radians(40)) < math.radians(15)


def test_tracker_confirms_tracks_drops_stale_ones_and_rejects_old_scans():
    tracker = LegTracker(TrackerConfig(min_hits=3, max_coast_s=0.5))
    for k in range(3):
        tracks = tracker.update(0.1 * k, [(1.0, 1.0)])
        assert len(tracks) == 1 and tracks[0].confirmed is (k == 2)
    assert nearest_track(tracks, (1.2, 1.0), gate_m=0.5).track_id == tracks[0].track_id
    assert nearest_track(tracks, (3.0, 1.0), gate_m=0.5) is None
    assert tracker.update(0.5, []) != ()
    assert tracker.update(0.9, []) == ()
    with pytest.raises(BadScanError, match="not after"):
        tracker.update(0.9, [])


def test_speed_class_boundaries():
    assert speed_class(0.0) is SpeedClass.SLOW
    assert speed_class(0.1999) is SpeedClass.SLOW
    assert speed_class(0.2) is SpeedClass.MEDIUM
    assert speed_class(0.7) is SpeedClass.FAST
    with pytest.raises(ValueError):
        speed_class(float("nan"))
    with pytest.raises(ValueError):
        speed_class(-0.1)
