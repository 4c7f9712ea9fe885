"""OpenCV's default HOG people detector finds the rendered person across the region."""

import cv2
import numpy as np
import pytest

from twin.config import TwinConfig
from twin.sensors import project
from twin.twin import Pose2D, Twin


@pytest.fixture(scope="module")
def hog():
    cv2.setNumThreads(2)
    h = cv2.HOGDescriptor()
    h.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
    return h


def _frame(waypoints, t_s: float = 0.0):
    twin = Twin(TwinConfig.from_dict({"person": {"waypoints": waypoints}}), seed=0)
    twin.set_robot_pose(Pose2D(-2.5, -1.6, 0.0))  # behind the camera's view
    twin.run(t_s)
    image = twin.render_camera()
    twin.close()
    p = twin.person.pose(twin.time_s)
    x, y = p.position_m
    h = twin.config.person.height_m
    feet, head = project(twin.camera_info, twin.camera_pose(), np.array([[x, y, 0], [x, y, h]]))
    return image, feet, head


def _detected(hog, image, feet, head) -> bool:
    rects, _ = hog.detectMultiScale(
        np.ascontiguousarray(image[..., ::-1]), winStride=(8, 8), padding=(8, 8), scale=1.05
    )
    u, v_mid = feet[0], (feet[1] + head[1]) / 2
    # a box counts if it holds the person's centre and is about the person's height
    return any(
        x <= u <= x + w and y <= v_mid <= y + h and 0.8 < h / (feet[1] - head[1]) < 2.0
        for x, y, w, h in rects
    )


@pytest.mark.parametrize(
    ("cell_xy", "heading"),
    [((0.5, 0.75), 0.0), ((2.5, 2.25), np.pi / 2), ((5.5, 0.75), np.pi), ((5.5, 2.25), -1.0)],
)
def test_standing_person_is_detected(hog, cell_xy, heading):
    x, y = cell_xy
    wps = [
        {"x_m": x, "y_m": y},
        {"x_m": x + 0.01 * np.cos(heading), "y_m": y + 0.01 * np.sin(heading), "speed_mps": 0.1},
    ]
    image, feet, head = _frame(wps)
    assert _detected(hog, image, feet, head)


def test_walking_person_is_detected_in_most_frames(hog):
    # walking east along the middle of the region at 1.2 m/s, side-on and mid-stride
    wps = [{"x_m": 0.3, "y_m": 1.5}, {"x_m": 5.8, "y_m": 2.2, "speed_mps": 1.2}]
    hits = [_detected(hog, *_frame(wps, t)) for t in (0.7, 2.3, 3.9)]
    assert sum(hits) >= 2
