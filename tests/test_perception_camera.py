"""Camera side of perception: homography, HOG pipeline, direction, two-missed-frames rule.

Frames come from :mod:`stack.perception.synthetic` (a pinhole camera at the twin's
mount "A" and a drawn person silhouette), not from the MuJoCo twin.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import yaml

from stack.cells import CellGrid, ConfigError, Direction
from stack.perception.camera import CameraConfig, CameraPeopleTracker, PersonStatus
from stack.perception.direction import DirectionConfig, DirectionEstimator, classify_displacement
from stack.perception.errors import BadFrameError, CalibrationError
from stack.perception.hog import (
    FootConfig,
    HogConfig,
    HogPeopleDetector,
    PersonBox,
    foot_point,
    validate_frame,
)
from stack.perception.homography import calibrate, load_calibration, save_calibration
from stack.perception.synthetic import (
    PinholeCamera,
    background_frame,
    floor_calibration_points,
    render_person_frame,
)

GRID = CellGrid()
CAMERA = PinholeCamera.mount_a(GRID)


@pytest.fixture(scope="module")
def calibration():
    image_px, map_m = floor_calibration_points(CAMERA, GRID)
    return calibrate(image_px, map_m, image_size_px=(CAMERA.width_px, CAMERA.height_px))


@pytest.fixture(scope="module")
def detector():
    return HogPeopleDetector(HogConfig())


SHRINK = FootConfig().bottom_shrink_frac


def box_with_foot_at(xy_m, height_px=120.0, shrink=SHRINK):
    """A HOG-like box whose shrunk bottom-middle pixel is the projection of map point xy_m."""
    u, v = CAMERA.project(np.array([[xy_m[0], xy_m[1], 0.0]]))[0]
    h = height_px
    w = h / 2
    return PersonBox(x=round(u - w / 2), y=round(v - h * (1 - shrink)), width=round(w),
                     height=round(h), weight=1.0)  # fmt: skip


# -- homography --------------------------------------------------------------------
def test_homography_maps_known_floor_points_exactly(calibration):
    assert len(calibration.image_px) >= 4
    assert calibration.max_error_m < 1e-6
    # Points not used in the fit: the cell centres.
    for cell in GRID.cells:
        x, y = GRID.center(cell)
        u, v = CAMERA.project(np.array([[x, y, 0.0]]))[0]
        mx, my = calibration.homography.image_to_map(u, v)
        assert math.hypot(mx - x, my - y) < 1e-4
        assert GRID.cell_at(mx, my) == cell


def test_homography_error_with_clicked_points_is_centimetres():
    rng = np.random.default_rng(3)
    image_px, map_m = floor_calibration_points(CAMERA, GRID)
    noisy = image_px + rng.normal(0.0, 1.0, image_px.shape)  # clicked to about 1 px
    cal = calibrate(noisy, map_m)
    assert 0.0 < cal.mean_error_m < 0.05
    # Four points only still give a usable mapping.
    corners = [0, 2, len(map_m) - 3, len(map_m) - 1]
    cal4 = calibrate(image_px[corners], map_m[corners])
    assert cal4.max_error_m < 1e-6


def test_homography_rejects_bad_points_and_the_horizon(calibration):
    with pytest.raises(CalibrationError, match="at least 4"):
        calibrate([[0, 0], [1, 0], [0, 1]], [[0, 0], [1, 0], [0, 1]])
    line = [[i, 2 * i] for i in range(5)]
    with pytest.raises(CalibrationError):
        calibrate(line, line)
    with pytest.raises(CalibrationError, match="finite"):
        calibrate([[0, 0], [1, 0], [0, 1], [np.nan, 1]], [[0, 0], [1, 0], [0, 1], [1, 1]])
    # A pixel high above the horizon maps to no floor point, not to one behind the camera.
    assert calibration.homography.image_to_map(320.0, -2000.0) is None


def test_calibration_file_round_trip_and_errors(tmp_path, calibration):
    path = tmp_path / "calib" / "camera.yaml"
    save_calibration(path, calibration)
    loaded = load_calibration(path)
    np.testing.assert_allclose(loaded.homography.matrix, calibration.homography.matrix, atol=1e-9)
    assert loaded.homography.image_size_px == (640, 400)
    assert "reprojection_error_m" in path.read_text()
    with pytest.raises(CalibrationError, match="does not exist"):
        load_calibration(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("points: [{image_px: [1, 2]}]\n")
    with pytest.raises(CalibrationError, match="malformed"):
        load_calibration(bad)
    tampered = tmp_path / "tampered.yaml"
    data = yaml.safe_load(path.read_text())
    data["homography"][0][2] += 0.5
    tampered.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError, match="disagrees"):
        load_calibration(tampered)


# -- HOG on synthetic frames -------------------------------------------------------------
@pytest.mark.parametrize("cell", [2, 7, 11])
def test_hog_detects_person_and_places_it_in_the_right_cell(cell, calibration, detector):
    rng = np.random.default_rng(cell)
    background = background_frame(CAMERA, rng)
    xy = GRID.center(cell)
    frame = render_person_frame(CAMERA, xy, rng, background=background)
    foreground = np.abs(frame.astype(int) - cv2.GaussianBlur(background, (3, 3), 0)).max(2) > 25
    tracker = CameraPeopleTracker(CameraConfig(), GRID, calibration.homography, detector)
    state = tracker.update(detector.detect(frame), 1.0, foreground=foreground)
    assert state.status is PersonStatus.PERSON
    assert state.cell == cell
    assert math.dist(state.position_m, xy) < 0.3


def test_hog_finds_nobody_in_an_empty_frame_and_respects_roi(detector):
    rng = np.random.default_rng(5)
    assert detector.detect(render_person_frame(CAMERA, None, rng)) == ()
    frame = render_person_frame(CAMERA, GRID.center(7), rng)
    (box,) = detector.detect(frame)
    # An ROI that leaves the person out finds nothing; one around them finds them.
    left = HogPeopleDetector(HogConfig(roi_px=(0, 0, box.x - 20, 400)))
    assert left.detect(frame) == ()
    around = (box.x - 40, box.y - 40, box.width + 80, box.height + 80)
    (found,) = detector.detect(frame, roi_px=around)
    assert abs(found.x - box.x) <= 8 and abs(found.y - box.y) <= 16


def test_hog_downscaled_large_frame_detects_in_full_resolution_pixels():
    rng = np.random.default_rng(6)
    big = PinholeCamera.mount_a(GRID, width_px=1280, height_px=800)
    xy = GRID.center(5)
    frame = render_person_frame(big, xy, rng)
    (box,) = HogPeopleDetector(HogConfig(downscale=0.5)).detect(frame)
    u, v = big.project(np.array([[xy[0], xy[1], 0.0]]))[0]
    assert abs(box.x + box.width / 2 - u) < 15  # centred on the person in 1280 x 800 pixels
    assert box.y < v < box.y + box.height + 10


def test_foot_point_shrinks_the_box_and_uses_the_lowest_foreground():
    box = PersonBox(x=100, y=50, width=64, height=128, weight=1.0)
    assert foot_point(box, FootConfig(bottom_shrink_frac=0.0)) == (132.0, 178.0)
    assert foot_point(box, FootConfig(bottom_shrink_frac=0.125)) == (132.0, 162.0)
    mask = np.zeros((300, 300), bool)
    mask[70:158, 125:135] = True  # the person's pixels end at row 157
    u, v = foot_point(box, FootConfig(), mask)
    assert v == pytest.approx(157.5) and u == pytest.approx(129.5)
    # A mask far from the box's bottom (a shadow, a second person) is not trusted.
    mask[:] = False
    mask[60:70, 125:135] = True
    assert foot_point(box, FootConfig(), mask) == foot_point(box, FootConfig())


# -- direction -------------------------------------------------------------------------------
def test_classify_displacement():
    assert classify_displacement(0.3, 0.1, 0.1) is Direction.EAST
    assert classify_displacement(-0.3, 0.1, 0.1) is Direction.WEST
    assert classify_displacement(0.1, 0.3, 0.1) is Direction.NORTH
    assert classify_displacement(0.1, -0.3, 0.1) is Direction.SOUTH
    assert classify_displacement(0.1, -0.1, 0.1) is Direction.NOT_MOVING


def test_direction_of_a_walk_with_jitter_and_a_turn():
    rng = np.random.default_rng(1)
    est = DirectionEstimator(DirectionConfig(jitter_threshold_m=0.1, window_s=0.5))
    dirs = []
    for k in range(40):  # 4 s at 10 fps: 2 s east at 1 m/s, then 2 s west
        t = 0.1 * k
        x = t if t <= 2.0 else 4.0 - t
        dirs.append(est.update(t, (x + rng.normal(0, 0.02), 1.0 + rng.normal(0, 0.02))))
    assert all(d is Direction.EAST for d in dirs[5:20])
    assert all(d is Direction.WEST for d in dirs[27:])


def test_standing_jitter_reads_as_not_moving():
    rng = np.random.default_rng(2)
    est = DirectionEstimator(DirectionConfig(jitter_threshold_m=0.1, window_s=0.5))
    dirs = [est.update(0.1 * k, tuple(rng.normal(0, 0.02, 2) + (3.0, 1.5))) for k in range(50)]
    assert set(dirs) == {Direction.NOT_MOVING}
    # Consecutive-frame mode (the thesis's literal rule) also flags a real step.
    est0 = DirectionEstimator(DirectionConfig(jitter_threshold_m=0.05, window_s=0.0))
    est0.update(0.0, (1.0, 1.0))
    assert est0.update(0.1, (1.02, 1.0)) is Direction.NOT_MOVING
    assert est0.update(0.2, (1.02, 0.9)) is Direction.SOUTH
    with pytest.raises(ValueError, match="not after"):
        est0.update(0.2, (1.0, 1.0))


# -- camera tracker: two-missed-frames rule and bad input -------------------------------------
def test_two_missed_frames_mean_no_person(calibration):
    tracker = CameraPeopleTracker(CameraConfig(), GRID, calibration.homography)
    xy = GRID.center(5)
    for k in range(6):  # walking north at 1 m/s
        state = tracker.update((box_with_foot_at((xy[0], xy[1] + 0.1 * k)),), 0.1 * k)
    assert state.status is PersonStatus.PERSON and state.direction is Direction.NORTH
    one_miss = tracker.update((), 0.6)
    assert one_miss.status is PersonStatus.PERSON
    assert one_miss.position_m == state.position_m and one_miss.direction is Direction.NORTH
    assert one_miss.missed_frames == 1
    two_misses = tracker.update((), 0.7)
    assert two_misses.status is PersonStatus.NO_PERSON
    assert two_misses.position_m is None and two_misses.cell is None
    assert two_misses.direction is Direction.NOT_MOVING
    back = tracker.update((box_with_foot_at(xy),), 0.8)
    assert back.status is PersonStatus.PERSON and back.direction is Direction.NOT_MOVING


def test_tracker_follows_the_person_not_a_far_false_positive(calibration):
    tracker = CameraPeopleTracker(CameraConfig(), GRID, calibration.homography)
    tracker.update((box_with_foot_at(GRID.center(3)),), 0.0)
    far = PersonBox(**{**box_with_foot_at(GRID.center(12)).__dict__, "weight": 5.0})
    near = box_with_foot_at((GRID.center(3)[0] + 0.1, GRID.center(3)[1]))
    state = tracker.update((far, near), 0.1)
    assert state.cell == 3 and state.box == near


def test_bad_frames_never_invent_a_position(calibration):
    tracker = CameraPeopleTracker(CameraConfig(), GRID, calibration.homography)
    rng = np.random.default_rng(9)
    frame = render_person_frame(CAMERA, GRID.center(7), rng)
    good = tracker.process_frame(frame, 1.0)
    assert good.status is PersonStatus.PERSON and good.cell == 7
    frozen = tracker.process_frame(frame, 1.0)  # same stamp again
    assert "frozen" in frozen.warning and frozen.cell == 7
    black = tracker.process_frame(np.zeros((400, 640, 3), np.uint8), 1.1)
    assert "black" in black.warning and black.missed_frames == 1
    empty = tracker.process_frame(np.zeros((0, 0, 3), np.uint8), 1.2)
    assert "empty" in empty.warning
    assert empty.status is PersonStatus.UNKNOWN and empty.position_m is None
    assert empty.cell is None and empty.direction is Direction.NOT_MOVING
    assert tracker.process_frame(None, 1.3).status is PersonStatus.UNKNOWN
    with pytest.raises(BadFrameError, match="8-bit"):
        validate_frame(np.zeros((10, 10), np.float32) + 1)


def test_missing_calibration_reports_boxes_but_no_position(detector):
    tracker = CameraPeopleTracker(CameraConfig(), GRID, None, detector)
    frame = render_person_frame(CAMERA, GRID.center(7), np.random.default_rng(4))
    state = tracker.process_frame(frame, 1.0)
    assert state.status is PersonStatus.UNKNOWN and "calibration" in state.warning
    assert len(state.boxes) == 1 and state.position_m is None and state.cell is None


def test_configs_validate_with_key_and_value():
    cfg = CameraConfig.from_dict(
        {"hog": {"scale_step": 1.1, "downscale": 0.5}, "direction": {"jitter_threshold_m": 0.05}}
    )
    assert cfg.hog.scale_step == 1.1 and cfg.direction.jitter_threshold_m == 0.05
    with pytest.raises(ConfigError, match=r"camera\.hog\.scale_step"):
        CameraConfig.from_dict({"hog": {"scale_step": 1.0}})
    with pytest.raises(ConfigError, match=r"camera\.hog\.win_stride_px"):
        CameraConfig.from_dict({"hog": {"win_stride_px": [4, 8]}})
    with pytest.raises(ConfigError, match="unknown key"):
        CameraConfig.from_dict({"hogg": {}})
    with pytest.raises(ConfigError, match="must be a number"):
        DirectionConfig.from_dict({"window_s": "fast"})


def test_tracking_window_follows_the_person_and_falls_back_to_a_full_search(calibration):
    rng = np.random.default_rng(11)
    background = background_frame(CAMERA, rng)
    tracker = CameraPeopleTracker(CameraConfig(), GRID, calibration.homography)
    calls = []
    detect = tracker.detector.detect
    tracker.detector.detect = lambda image, roi_px=None: (
        calls.append(roi_px) or detect(image, roi_px)
    )
    first = tracker.process_frame(
        render_person_frame(CAMERA, (2.4, 0.8), rng, background=background), 0.0
    )
    near = tracker.process_frame(
        render_person_frame(CAMERA, (2.6, 0.8), rng, background=background), 0.1
    )
    assert first.cell == 7 and near.cell == 7
    assert calls[0] is None and calls[1] is not None and len(calls) == 2  # window sufficed
    # The person jumps out of the window: the same frame is searched in full.
    jumped = tracker.process_frame(
        render_person_frame(CAMERA, (5.5, 2.2), rng, background=background), 0.2
    )
    assert jumped.cell == 2 and jumped.missed_frames == 0
    assert calls[2] is not None and calls[3] is None


def test_a_silent_camera_record_says_unknown_and_why_and_keeps_nothing_of_the_last_person():
    from stack.perception.camera import CameraPersonState, PersonStatus

    seen = CameraPersonState(
        stamp_s=3.0, status=PersonStatus.PERSON, position_m=(2.0, 0.5), cell=9,
        direction=Direction.EAST,
    )  # fmt: skip
    out = seen.silent_dict(2.5)
    assert out["status"] == PersonStatus.UNKNOWN.value and out["stamp_s"] == 3.0
    assert out["position_m"] is None and out["cell"] is None and out["boxes"] == []
    assert out["direction"] == "Not moving" and out["warning"] == "no camera frame for 2.5 s"
