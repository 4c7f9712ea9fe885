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


def _point_on_the_whole_raster(vis, x, y, robot):
    """point()'s fractions as rasterised on the whole image (no window)."""
    import cv2

    whole, legs = vis._person_quads(x, y)

    def fill(px):
        mask = np.zeros(vis.shape, np.uint8)
        hull = cv2.convexHull(np.round(px * 16).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 1, lineType=cv2.LINE_8, shift=4)
        return mask

    m, lm = fill(whole), fill(legs)
    inside, n_legs = int(m.sum()), int(lm.sum())
    area = abs(cv2.contourArea(whole.astype(np.float32)))
    covered = float((m & robot).sum()) / inside if inside else 0.0
    legs_covered = float((lm & robot).sum()) / n_legs if n_legs and inside else 0.0
    return covered, legs_covered, (min(1.0, inside / area) if area > 1e-9 else 0.0)


def test_a_silhouettes_window_counts_the_same_pixels_as_the_whole_image(vis):
    # the robot's own silhouette and people all over the floor, in and off the image
    rng = np.random.default_rng(3)
    for _ in range(60):
        pose = Pose2D(rng.uniform(0, 6), rng.uniform(0, 3), rng.uniform(-3, 3))
        robot = vis.robot_mask(pose)
        for _ in range(10):
            x, y = rng.uniform(-1, 7.5), rng.uniform(-1.5, 4.5)
            p = vis.point(x, y, robot)
            assert (p.covered_frac, p.legs_covered_frac, p.in_image_frac) == (
                _point_on_the_whole_raster(vis, x, y, robot)
            ), (pose, x, y)


def test_instances_of_one_camera_share_their_tables_and_agree():
    a = CameraVisibility(camera_homography(), GRID)
    b = CameraVisibility(camera_homography(), GRID)
    other = CameraVisibility(camera_homography(tilt_deg=30.0), GRID)
    pose = Pose2D(*GRID.center(3), 0.0)
    assert a.hidden_fractions(pose) == b.hidden_fractions(pose)
    assert a._sample_table() is b._sample_table()  # made once
    assert other._sample_table() is not a._sample_table()
    assert other.hidden_fractions(pose) != a.hidden_fractions(pose)
