"""HOG on frames rendered by the MuJoCo twin: the person detected and placed in the right cell.

The calibration uses floor points the twin reports (the cells' corners projected
with the twin's own camera pose and intrinsics), as a calibration in the twin would.
"""

from __future__ import annotations

import math

import cv2
import pytest

twin_mod = pytest.importorskip("twin.twin")
from stack.perception.camera import CameraConfig, CameraPeopleTracker, PersonStatus  # noqa: E402
from twin.calibration import calibrate_twin  # noqa: E402
from twin.config import TwinConfig  # noqa: E402

pytestmark = pytest.mark.slow


# Off-centre spots (0.25-0.35 m from the centre) in near, middle and far cells.
@pytest.mark.parametrize(
    ("cell", "offset_m"), [(11, (0.25, -0.3)), (6, (-0.3, 0.35)), (1, (0.2, 0.3))]
)
def test_twin_person_is_detected_in_the_right_cell(cell, offset_m):
    grid = TwinConfig().grid
    cx, cy = grid.center(cell)
    x, y = cx + offset_m[0], cy + offset_m[1]
    cfg = TwinConfig.from_dict({"person": {"waypoints": [{"x_m": x, "y_m": y, "pause_s": 60.0}]}})
    tw = twin_mod.Twin(cfg, seed=cell)
    try:
        cal = calibrate_twin(tw, grid)
        assert cal.max_error_m < 1e-3
        frame = cv2.cvtColor(tw.render_camera(), cv2.COLOR_RGB2BGR)
        truth = tw.ground_truth().person
    finally:
        tw.close()
    tracker = CameraPeopleTracker(CameraConfig(), grid, cal.homography)
    state = tracker.process_frame(frame, 0.0)
    assert state.status is PersonStatus.PERSON
    assert truth.cell == cell
    assert state.cell == cell
    assert math.dist(state.position_m, (truth.pose.x_m, truth.pose.y_m)) < 0.35
