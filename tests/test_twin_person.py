"""The scripted person: timeline, speeds and pauses, a gait whose planted feet stay put."""

import math

import numpy as np
import pytest

from twin.config import PersonConfig, TwinConfig, Waypoint
from twin.person import PersonScript
from twin.twin import Twin

SCRIPT = PersonConfig(
    waypoints=(
        Waypoint(x_m=0.0, y_m=0.0, pause_s=0.5),
        Waypoint(x_m=4.0, y_m=0.0, speed_mps=1.4, pause_s=1.0),
        Waypoint(x_m=4.0, y_m=2.0, speed_mps=0.1),
        Waypoint(x_m=1.0, y_m=2.0, speed_mps=0.7),
    )
)


def test_timeline_follows_speeds_and_pauses():
    s = PersonScript(SCRIPT)
    assert s.end_time_s == pytest.approx(0.5 + 4 / 1.4 + 1.0 + 2 / 0.1 + 3 / 0.7)
    assert s.pose(0.2).position_m == pytest.approx((0.0, 0.0))
    assert not s.pose(0.2).walking
    mid = s.pose(0.5 + 2.0 / 1.4)
    assert mid.position_m == pytest.approx((2.0, 0.0))
    assert mid.velocity_mps == pytest.approx((1.4, 0.0))
    paused = s.pose(0.5 + 4 / 1.4 + 0.5)
    assert paused.position_m == pytest.approx((4.0, 0.0)) and not paused.walking
    slow = s.pose(0.5 + 4 / 1.4 + 1.0 + 10.0)
    assert slow.position_m == pytest.approx((4.0, 1.0))
    assert slow.heading_rad == pytest.approx(math.pi / 2)
    assert s.pose(1e6).position_m == pytest.approx((1.0, 2.0))


def test_planted_feet_do_not_slide_and_legs_keep_their_length():
    s = PersonScript(SCRIPT)
    ground = s.dims.ankle_height_m + 1e-9
    prev = s.pose(0.0)
    slides = []
    for t in np.arange(0.0, s.end_time_s + 0.5, 0.01):
        p = s.pose(t)
        for k in range(2):
            assert np.linalg.norm(p.knees_m[k] - p.hips_m[k]) == pytest.approx(s.dims.thigh_m)
            assert np.linalg.norm(p.ankles_m[k] - p.knees_m[k]) == pytest.approx(s.dims.shin_m)
            if p.ankles_m[k, 2] <= ground and prev.ankles_m[k, 2] <= ground:
                slides.append(np.linalg.norm(p.ankles_m[k, :2] - prev.ankles_m[k, :2]))
        prev = p
    slides = np.array(slides)
    # feet only shift at the two corners, where the body turns on the spot
    assert np.count_nonzero(slides > 1e-9) <= 2 * 2
    assert np.median(slides) == 0.0


def test_legs_swing_while_walking_and_stand_together_when_paused():
    s = PersonScript(SCRIPT)
    t0 = 0.5
    ankles = np.array([s.pose(t0 + dt).ankles_m[:, 0] for dt in np.arange(0, 4 / 1.4, 0.02)])
    # each foot spends time planted and time moving forward faster than the body
    for k in range(2):
        v = np.diff(ankles[:, k]) / 0.02
        assert (v == 0).mean() > 0.3
        assert v.max() > 1.4 * 1.5
    still = s.pose(0.5 + 4 / 1.4 + 0.5)
    assert still.ankles_m[0, 0] == pytest.approx(still.ankles_m[1, 0])
    assert still.ankles_m[:, 2] == pytest.approx([s.dims.ankle_height_m] * 2)
    lo = min(np.min(s.pose(t).ankles_m[:, 2]) for t in np.arange(0.5, 3.0, 0.05))
    assert lo == pytest.approx(s.dims.ankle_height_m)


def test_default_script_enters_tours_the_region_and_leaves():
    twin = Twin(TwinConfig.from_dict({"room": {"furniture": False}}), seed=0)
    assert not twin.ground_truth().person.in_room
    cells, in_room = set(), []
    end = twin.person.end_time_s
    for t in np.arange(0.0, end + 1.0, 0.5):
        gt_pose = twin.person.pose(t)
        x, y = gt_pose.position_m
        cells.add(twin.config.grid.cell_at(x, y))
        in_room.append(twin.layout.in_room(x, y))
    assert {12, 7, 1} <= cells
    assert in_room[0] is False and any(in_room) and in_room[-1] is False
    # the mocap bodies follow the script
    twin.run(8.0)
    gt = twin.ground_truth()
    torso = twin.data.xpos[twin.model.body("person/torso").id]
    assert torso[:2] == pytest.approx([gt.person.pose.x_m, gt.person.pose.y_m], abs=0.03)
    assert gt.person.cell == twin.config.grid.cell_at(gt.person.pose.x_m, gt.person.pose.y_m)
    shin = twin.data.geom_xpos[twin.model.geom("person/shin_l_geom").id]
    knee, ankle = (
        twin.person.pose(twin.time_s).knees_m[0],
        twin.person.pose(twin.time_s).ankles_m[0],
    )
    assert shin == pytest.approx((knee + ankle) / 2, abs=0.03)


def test_a_walker_at_2_m_per_s_validates_and_moves_at_that_speed_in_the_twin():
    """Issue 26: walkers up to 2.0 m/s (ISO 13855 designs for 1.6 m/s); faster is refused."""
    from stack.cells import ConfigError
    from twin.config import MAX_WALK_SPEED_MPS
    from twin.person import max_step_length_m

    assert MAX_WALK_SPEED_MPS == 2.0
    with pytest.raises(ConfigError) as err:
        TwinConfig.from_dict({"person": {"waypoints": [{}, {"x_m": 1, "speed_mps": 2.1}]}})
    assert err.value.key == "person.waypoints[1].speed_mps"
    # the step lengthens past the brisk walk's 0.72 m: 0.78 m at 1.6 m/s, 0.90 m at 2.0
    assert max_step_length_m(1.4) == pytest.approx(0.72)
    assert max_step_length_m(1.6) == pytest.approx(0.78)
    assert max_step_length_m(2.0) == pytest.approx(0.90)
    cfg = TwinConfig.from_dict(
        {
            "room": {"furniture": False},
            "person": {
                "waypoints": [
                    {"x_m": -1.0, "y_m": 0.75, "pause_s": 0.5},
                    {"x_m": 6.5, "y_m": 0.75, "speed_mps": 2.0},
                ]
            },
        }
    )
    script = PersonScript(cfg.person)
    assert script.end_time_s == pytest.approx(0.5 + 7.5 / 2.0)
    # the gait at a jog: planted feet stay put, legs keep their length, the pelvis dips
    # but the person stays upright
    ground = script.dims.ankle_height_m + 1e-9
    prev, slides, drops = script.pose(0.5), [], []
    for t in np.arange(0.5, script.end_time_s, 0.01):
        p = script.pose(t)
        drops.append(p.pelvis_drop_m)
        for k in range(2):
            assert np.linalg.norm(p.knees_m[k] - p.hips_m[k]) == pytest.approx(script.dims.thigh_m)
            if p.ankles_m[k, 2] <= ground and prev.ankles_m[k, 2] <= ground:
                slides.append(np.linalg.norm(p.ankles_m[k, :2] - prev.ankles_m[k, :2]))
        prev = p
    assert max(slides) < 1e-9 and max(drops) < 0.15
    # in the twin: the mocap person covers 2.0 m per second
    twin = Twin(cfg, seed=0)
    twin.run(1.0)
    a = twin.ground_truth()
    twin.run(1.0)
    b = twin.ground_truth()
    dt = b.time_s - a.time_s
    dist = math.hypot(b.person.pose.x_m - a.person.pose.x_m, b.person.pose.y_m - a.person.pose.y_m)
    assert dist / dt == pytest.approx(2.0, rel=0.01)
    assert b.person.velocity_mps == pytest.approx((2.0, 0.0), abs=1e-6)
    torso = twin.data.xpos[twin.model.body("person/torso").id]
    assert torso[:2] == pytest.approx([b.person.pose.x_m, b.person.pose.y_m], abs=0.03)
