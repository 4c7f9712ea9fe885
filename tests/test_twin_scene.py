"""Scenes compile and step headless with no MuJoCo warnings; camera properties hold."""

import math

import mujoco
import numpy as np
import pytest

from twin.config import TwinConfig
from twin.sensors import project
from twin.twin import Pose2D, Twin, VelocityCommand

SCENES = {
    "default": {},
    "bare_room": {"room": {"furniture": False}, "person": {"present": False}},
    "shifted_grid_3x4": {
        "grid": {"rows": 3, "columns": 4, "origin_m": [10.0, -4.0]},
        "robot": {"start_cell": 5},
    },
    "hd_camera_wide_lidar": {
        "camera": {"width_px": 1280, "height_px": 800, "shadows": False},
        "lidar": {"beams": 1080, "fov_deg": 360},
    },
}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_scene_compiles_and_steps_without_warnings(name):
    twin = Twin(TwinConfig.from_dict(SCENES[name]), seed=0)
    cmds = [VelocityCommand(0.3, 0.1, 0.4), VelocityCommand(-0.2, 0.2, -0.5), VelocityCommand()]
    for cmd in cmds:
        twin.run(1.0, cmd)
    assert twin.data.warning.number.sum() == 0, [
        (mujoco.mjtWarning(i).name, n) for i, n in enumerate(twin.data.warning.number) if n
    ]
    assert np.all(np.isfinite(twin.data.qpos))
    assert twin.time_s == pytest.approx(3.0)


def test_scene_has_its_parts():
    twin = Twin(seed=0)
    m = twin.model
    names = {m.geom(i).name for i in range(m.ngeom)}
    for part in ("floor", "wall_north_lintel", "door_leaf", "desk_n0/top", "chair_s0/leg_1"):
        assert part in names
    assert sum(n.startswith("mbot/wheel_") for n in names) == 4
    assert {"person/shin_l_geom", "person/shin_r_geom", "person/head"} <= names
    # no light casts shadows by default (the render's cost); camera.shadows: the key light
    assert m.nlight >= 4 and not any(m.light_castshadow)
    lit = Twin(TwinConfig.from_dict({"camera": {"shadows": True}}), seed=0).model
    assert sum(bool(c) for c in lit.light_castshadow) == 1
    # the robot is about 0.6 m wide and 1.2-1.3 m tall
    twin.data.qpos[:] = 0
    mujoco.mj_forward(m, twin.data)
    body = m.body("mbot/base").id
    tops = [
        twin.data.geom_xpos[g][2] + m.geom_rbound[g]
        for g in range(m.ngeom)
        if m.geom_bodyid[g] == body
    ]
    assert 1.15 < max(tops) < 1.35


def test_camera_matches_its_configuration():
    cfg = TwinConfig.from_dict({"camera": {"width_px": 320, "height_px": 200, "fovy_deg": 38}})
    twin = Twin(cfg, seed=0)
    cam = twin.model.camera("ceiling")
    assert cam.fovy[0] == pytest.approx(38.0)
    info = twin.camera_info
    assert (info.width, info.height) == (320, 200)
    assert info.fovy_deg == pytest.approx(38.0)
    assert 34.0 <= info.fovx_deg <= 80.0  # the P1344's 3-8 mm lens
    img = twin.render_camera()
    twin.close()
    assert img.shape == (200, 320, 3) and img.dtype == np.uint8
    assert img.std() > 10  # a scene, not a blank frame
    pose = twin.camera_pose()
    forward = pose.rotation[:, 2]
    assert math.degrees(math.asin(-forward[2])) == pytest.approx(cfg.camera.tilt_deg)
    assert forward[0] > 0.9  # looking east, along the region's long axis
    assert pose.position_m[2] == pytest.approx(cfg.camera.height_m)


def test_intrinsics_and_pose_project_points_onto_what_is_rendered():
    cfg = TwinConfig.from_dict({"person": {"waypoints": [{"x_m": 2.0, "y_m": 1.0}]}})
    twin = Twin(cfg, seed=0)
    twin.set_robot_pose(Pose2D(-2.0, -1.5, 0.0))  # out of the way
    seg = twin.render_segmentation()
    twin.close()
    m = twin.model
    for names in (("person/chest",), ("person/shin_l_geom",), ("person/head", "person/hair")):
        gid = m.geom(names[0]).id
        uv = project(twin.camera_info, twin.camera_pose(), twin.data.geom_xpos[gid][None])[0]
        u, v = int(round(uv[0])), int(round(uv[1]))
        assert m.geom(seg[v, u]).name in names, names
    # the projected centre of the chest sits at the centroid of its silhouette
    chest = m.geom("person/chest").id
    vs, us = np.nonzero(seg == chest)
    uv = project(twin.camera_info, twin.camera_pose(), twin.data.geom_xpos[chest][None])[0]
    assert abs(us.mean() - uv[0]) < 1.5


def test_person_is_in_view_everywhere_in_the_region_tall_enough_for_hog():
    twin = Twin(seed=0)
    info, pose = twin.camera_info, twin.camera_pose()
    x0, y0, x1, y1 = twin.layout.region
    h = twin.config.person.height_m
    for x in np.linspace(x0, x1, 7):
        for y in np.linspace(y0, y1, 4):
            feet, head = project(info, pose, np.array([[x, y, 0.0], [x, y, h]]))
            for u, v in (feet, head):
                assert 0 <= u < info.width and 0 <= v < info.height, (x, y)
            # the default people detector wants about 100 px of person
            assert feet[1] - head[1] > 95, (x, y)
