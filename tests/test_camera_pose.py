"""The camera's pose from its floor calibration (stack/perception/camera_pose.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stack.perception.camera_pose import (
    OPTICAL_IN_LINK,
    camera_pose_from_homography,
    camera_transforms,
)
from stack.perception.errors import CalibrationError
from stack.tf import Transform, quaternion_from_rpy


def synthetic_camera(position, roll, pitch, yaw):
    """A camera looking at the floor: K, R (optical axes in the map) and H (image -> map)."""
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 200.0], [0.0, 0.0, 1.0]])
    # camera_link orientation from rpy, then the optical frame's axes
    link = Transform(tuple(position), quaternion_from_rpy(roll, pitch, yaw))
    opt = link.compose(OPTICAL_IN_LINK)
    R = np.array([opt.apply(e) for e in np.eye(3)]).T - np.array(position)[:, None]
    t = -R.T @ np.array(position)
    G = K @ np.c_[R.T[:, 0], R.T[:, 1], t]  # floor -> image
    return K, R, np.linalg.inv(G) / np.linalg.inv(G)[2, 2]


@pytest.mark.parametrize("yaw", [0.0, 0.8, -2.5])
def test_pose_is_recovered_from_a_synthetic_homography(yaw):
    pos = np.array([-3.3, 0.4, 2.75])
    K, R, H = synthetic_camera(pos, 0.0, math.radians(22), yaw)
    ahead = pos[:2] + 4.0 * np.array([math.cos(yaw), math.sin(yaw)])
    floor = ahead + np.array([[0, 0], [1, 0], [0, 1], [1, 1]])
    p, rot = camera_pose_from_homography(H, K, floor)
    assert np.allclose(p, pos, atol=1e-9)
    assert np.allclose(rot, R, atol=1e-9)
    map_link, link_opt = camera_transforms(H, K, floor)
    assert np.allclose(map_link.translation, pos, atol=1e-9)
    assert math.isclose(map_link.to_pose2d().yaw_rad, yaw, abs_tol=1e-9)


def test_points_on_both_sides_of_the_camera_are_refused():
    K, _, H = synthetic_camera([0.0, 0.0, 2.0], 0.0, math.radians(30), 0.0)
    with pytest.raises(CalibrationError, match="in front"):
        camera_pose_from_homography(H, K, np.array([[4.0, 0.0], [-4.0, 0.0]]))
    with pytest.raises(CalibrationError, match="3 x 3"):
        camera_pose_from_homography(np.eye(2), K, np.zeros((1, 2)))


def test_twin_camera_pose_from_its_calibration():
    twin_mod = pytest.importorskip("twin.twin")
    from twin.calibration import calibrate_twin
    from twin.config import TwinConfig

    tw = twin_mod.Twin(TwinConfig(), seed=0)
    try:
        cal = calibrate_twin(tw)
        truth = tw.camera_pose()
        K = tw.camera_info.K
    finally:
        tw.close()
    p, rot = camera_pose_from_homography(cal.homography.matrix, K, cal.map_m)
    assert np.linalg.norm(p - truth.position_m) < 1e-3
    assert np.allclose(rot, truth.rotation, atol=1e-4)
