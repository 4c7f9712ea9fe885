"""Fixes from the twin walk benchmark (bench/bench_perception_walks.py), one test each."""

from __future__ import annotations

import math

import numpy as np

from stack.cells import CellGrid
from stack.perception.camera import CameraConfig, CameraPeopleTracker, PersonStatus, _drop_nested
from stack.perception.hog import FootConfig, PersonBox
from stack.perception.homography import calibrate
from stack.perception.legs import Leg, PersonCandidate
from stack.perception.observation import SpeedClass, speed_class
from stack.perception.synthetic import PinholeCamera, floor_calibration_points
from stack.perception.tracker import LegTracker, TrackerConfig

GRID = CellGrid()
CAMERA = PinholeCamera.mount_a(GRID)


def gait_midpoint(t: float, speed: float, step_m: float) -> float:
    """Legs' midpoint along a walk: a smoothstep surge per step, stalling between steps."""
    period = step_m / speed
    k, tau = divmod(t / period, 1.0)
    return step_m * (k + tau * tau * (3.0 - 2.0 * tau))


def class_share(config: TrackerConfig, speed: float, step_m: float, want: SpeedClass) -> float:
    tracker = LegTracker(config)
    right = []
    for k in range(120):  # 12 s of scans at 10 Hz
        t = 0.1 * k
        tracks = tracker.update(t, [(gait_midpoint(t, speed, step_m), 1.0)])
        if t >= 3.0:
            right.append(speed_class(tracks[0].speed_mps) is want)
    return float(np.mean(right))


def test_speed_class_is_steady_through_the_gait_surges():
    # 0.6 m/s with 0.48 m steps (the twin's gait): the midpoint runs 0-0.9 m/s per step.
    assert class_share(TrackerConfig(), 0.6, 0.48, SpeedClass.MEDIUM) >= 0.9
    # the old process noise (1.0 m/s^2) followed the surges into the wrong classes
    assert class_share(TrackerConfig(accel_noise_mps2=1.0), 0.6, 0.48, SpeedClass.MEDIUM) < 0.8


def test_lone_legs_move_the_track_less_than_pairs():
    def leg(x, y):
        return Leg((x, y), 0.1, 8, 0.02)

    pair = PersonCandidate((0.0, 0.0), (leg(0.0, 0.1), leg(0.0, -0.1)))
    lone = PersonCandidate((0.3, 0.0), (leg(0.3, 0.0),))
    moved = []
    for second in (PersonCandidate((0.3, 0.0), lone.legs * 2), lone):
        tracker = LegTracker(TrackerConfig())
        for k in range(5):
            tracker.update(0.1 * k, [pair])
        (track,) = tracker.update(0.5, [second])
        moved.append(track.position_m[0])
    assert moved[1] < 0.7 * moved[0]
    # plain (x, y) pairs are still accepted
    tracker = LegTracker(TrackerConfig())
    assert tracker.update(0.0, [(1.0, 2.0)])[0].position_m == (1.0, 2.0)


def test_upper_body_box_inside_a_taller_box_is_dropped():
    person = PersonBox(300, 60, 120, 240, 0.8)
    upper = PersonBox(315, 62, 80, 160, 1.2)  # stronger, but ends at the knees
    other = PersonBox(100, 80, 60, 120, 0.5)
    assert _drop_nested((upper, person, other), 0.8) == (person, other)
    cal = calibrate(*floor_calibration_points(CAMERA, GRID), (CAMERA.width_px, CAMERA.height_px))
    tracker = CameraPeopleTracker(CameraConfig(), GRID, cal.homography)
    state = tracker.update((upper, person), 1.0)
    assert state.status is PersonStatus.PERSON and state.box == person


def test_camera_matrix_from_the_homography_gives_heights():
    cal = calibrate(*floor_calibration_points(CAMERA, GRID), (CAMERA.width_px, CAMERA.height_px))
    hom = cal.homography
    for x, y, z in ((0.5, 0.5, 1.75), (5.5, 2.5, 2.0), (3.0, 1.5, 0.9)):
        _, v = CAMERA.project(np.array([[x, y, z]]))[0]
        assert math.isclose(hom.height_at_row_m(x, y, v), z, abs_tol=0.02)
    assert calibrate(*floor_calibration_points(CAMERA, GRID)).homography.camera_matrix() is None


def _person_rows(x: float, y: float, height_m: float = 1.75) -> tuple[float, float, float]:
    """(u, foot row, head row) of a person standing at (x, y) in CAMERA's image."""
    (u, v_foot), (_, v_head) = CAMERA.project(np.array([[x, y, 0.0], [x, y, height_m]]))
    return float(u), float(v_foot), float(v_head)


def test_row_of_point_from_the_homography_matches_the_camera():
    cal = calibrate(*floor_calibration_points(CAMERA, GRID), (CAMERA.width_px, CAMERA.height_px))
    for x, y in ((0.5, 0.5), (3.0, 1.5), (5.5, 2.5)):
        _, v_foot, v_head = _person_rows(x, y)
        assert math.isclose(cal.homography.row_of_point_px(x, y, 0.0), v_foot, abs_tol=0.5)
        assert math.isclose(cal.homography.row_of_point_px(x, y, 1.75), v_head, abs_tol=0.5)
    assert (
        calibrate(*floor_calibration_points(CAMERA, GRID)).homography.row_of_point_px(1.0, 1.0, 0.0)
        is None
    )


def test_short_knee_high_box_takes_its_feet_from_the_foreground():
    # HOG's window fitted tightly around a side-on person: its shrunk bottom is at the
    # knees, which alone puts the person far beyond where they stand (twin walks).
    cal = calibrate(*floor_calibration_points(CAMERA, GRID), (CAMERA.width_px, CAMERA.height_px))
    x, y = 2.5, 1.5
    u, v_foot, v_head = _person_rows(x, y)
    hp = v_foot - v_head
    tight = PersonBox(
        round(u - 0.25 * hp), round(v_head - 0.1 * hp), round(0.5 * hp), round(hp), 1.0
    )
    full = PersonBox(round(u - 0.35 * hp), round(v_head - 0.17 * hp), round(0.7 * hp),
                     round(1.39 * hp), 1.0)  # fmt: skip
    mask = np.zeros((CAMERA.height_px, CAMERA.width_px), bool)
    cols = slice(round(u - 0.1 * hp), round(u + 0.1 * hp))
    mask[round(v_head) : round(v_foot), cols] = True

    def place(config, box, foreground):
        tracker = CameraPeopleTracker(config, GRID, cal.homography)
        state = tracker.update((box,), 1.0, foreground=foreground)
        assert state.status is PersonStatus.PERSON
        return math.dist(state.position_m, (x, y))

    assert place(CameraConfig(), tight, mask) < 0.1
    # before: the knee row, over half a metre off; and without a mask nothing changes
    assert place(CameraConfig(short_box_ratio=None), tight, mask) > 0.5
    assert place(CameraConfig(), tight, None) > 0.5
    # a full-size box is not refined (the foreground put east-west walkers' feet too low)
    low_mask = mask.copy()
    low_mask[
        round(v_foot) : round(v_foot + 0.2 * hp), round(u - 0.1 * hp) : round(u + 0.1 * hp)
    ] = True
    no_fg = CameraConfig(foot=FootConfig(use_foreground=False))  # what process_frame does
    assert place(no_fg, tight, mask) < 0.1
    assert place(no_fg, full, low_mask) == place(no_fg, full, None) < 0.2


def test_foreground_model_at_half_resolution_gives_a_full_size_mask():
    from stack.perception.hog import Foreground

    fg = Foreground(downscale=0.5)
    frame = np.full((400, 640, 3), 90, np.uint8)
    for _ in range(5):
        fg.apply(frame)
    frame[100:300, 200:260] = 250
    mask = fg.apply(frame)
    assert mask.shape == (400, 640) and mask.dtype == bool
    assert mask[120:280, 210:250].all() and not mask[:, :150].any()
