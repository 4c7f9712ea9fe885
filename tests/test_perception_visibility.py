"""Which floor the ceiling camera sees given the robot's pose (stack.perception.visibility)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError
from stack.perception.homography import FloorHomography
from stack.perception.legs import Pose2D
from stack.perception.visibility import CameraVisibility, VisibilityConfig

GRID = CellGrid()  # 12 10 8 6 4 2 / 11 9 7 5 3 1, 1 m x 1.5 m cells, origin (0, 0)


def camera_homography(pos=(-3.3, 1.5, 2.75), tilt_deg=22.0, size=(640, 400), fovy_deg=40.0):
    """Image -> floor homography of a pinhole camera at ``pos`` looking east, tilted down."""
    w, h = size
    f = (h / 2) / math.tan(math.radians(fovy_deg) / 2)
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    t = math.radians(tilt_deg)
    forward = np.array([math.cos(t), 0.0, -math.sin(t)])
    right = np.array([0.0, -1.0, 0.0])  # looking east, image x points south
    down = np.cross(forward, right)
    r = np.array([right, down, forward])  # rows: camera axes in the map frame
    p = k @ np.c_[r, -r @ np.asarray(pos)]
    floor_to_image = p[:, [0, 1, 3]]
    return FloorHomography(np.linalg.inv(floor_to_image), 1.0, size)


@pytest.fixture(scope="module")
def vis():
    return CameraVisibility(camera_homography(), GRID)


def test_the_camera_position_is_recovered_from_the_homography(vis):
    np.testing.assert_allclose(vis.centre_m, (-3.3, 1.5, 2.75), atol=1e-3)


def test_without_the_robot_in_view_every_cell_is_visible(vis):
    assert all(f == 0.0 for f in vis.hidden_fractions(None).values())
    # the robot behind the camera's line of sight to the region hides nothing
    far = vis.hidden_fractions(Pose2D(-3.0, -1.5, 0.0))
    assert all(f == 0.0 for f in far.values())


def test_a_robot_between_the_camera_and_a_cell_hides_it(vis):
    # the robot in cell 3 stands between the camera (west) and cell 1 (east)
    h = vis.hidden_fractions(Pose2D(*GRID.center(3), 0.0))
    assert h[1] > 0.0
    assert vis.point_hidden(*GRID.center(1), Pose2D(*GRID.center(3), 0.0))
    # cells west of the robot (nearer the camera) and in the other row are not hidden
    for cell in (11, 9, 7, 5, 12, 10, 8):
        assert h[cell] == 0.0, cell
    # the same person with the robot in the north row: seen
    assert not vis.point_hidden(*GRID.center(1), Pose2D(*GRID.center(4), 0.0))


def test_a_person_nearer_the_camera_than_the_robot_is_never_hidden_by_it(vis):
    robot = Pose2D(*GRID.center(1), 0.0)
    assert not vis.point_hidden(*GRID.center(3), robot)


def test_floor_outside_the_image_is_hidden():
    narrow = CameraVisibility(camera_homography(fovy_deg=20.0), GRID)
    static = narrow.hidden_fractions(None)
    # a 20 degree camera sees a strip around the image centre only
    assert static[11] > 0.5 or static[12] > 0.5
    assert min(static.values()) < max(static.values())


def test_config_is_validated():
    with pytest.raises(ConfigError, match="max_covered_frac"):
        VisibilityConfig(max_covered_frac=0.0)
    with pytest.raises(ConfigError, match="robot_boxes"):
        VisibilityConfig(robot_boxes=((0.3, -0.3, 0, 1, 0, 1),))
    with pytest.raises(ValueError, match="image size"):
        CameraVisibility(FloorHomography(np.eye(3)), GRID)
