"""The camera pipeline's model (stack.perception.model): drawing, fitting, the file, and
the tracker it feeds (CameraPeopleTracker.update_points)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError, Direction
from stack.perception.camera import CameraConfig, CameraPeopleTracker, PersonStatus
from stack.perception.legs import Pose2D
from stack.perception.model import (
    FEATURES,
    FrameRecord,
    ModelCamera,
    PerceptionModel,
    PersonFrame,
    features_of,
    fit,
)
from stack.perception.visibility import CameraVisibility
from tests.test_perception_visibility import camera_homography

GRID = CellGrid()


@pytest.fixture(scope="module")
def vis():
    return CameraVisibility(camera_homography(), GRID)


def truth_model(**kw) -> PerceptionModel:
    base = dict(
        # bias, in_image, covered, legs_covered, speed, out_of_room, seen_before
        detect_w=(-1.0, 2.5, -3.0, -2.0, -0.8, -6.0, 2.0),
        bias_w=((0.05, 0.0, 0.0, 0.1, 0.0), (-0.02, 0.0, 0.01, 0.0, 0.0)),
        error_sd_m=(0.12, 0.08),
        error_rho=0.6,
        false_rate=0.05,
        false_points_m=((2.5, 1.0), (4.0, 2.0)),
    )
    base.update(kw)
    return PerceptionModel(**base)


def synthetic_frames(model: PerceptionModel, vis, n_walks: int = 30, seed: int = 0):
    """Walks across the region with the robot at changing places, drawn from ``model``."""
    rng = np.random.default_rng(seed)
    frames = []
    for w in range(n_walks):
        cam = ModelCamera(model, vis, np.random.default_rng([seed, w]))
        a = np.array([rng.uniform(0.2, 5.8), rng.uniform(0.2, 2.8)])
        b = np.array([rng.uniform(0.2, 5.8), rng.uniform(0.2, 2.8)])
        speed = rng.uniform(0.0, 1.4)
        robot = Pose2D(float(rng.uniform(0.5, 5.5)), float(rng.uniform(0.3, 2.7)), 0.0)
        n = 60
        v = (b - a) / max(np.linalg.norm(b - a), 1e-9) * speed
        for k in range(n):
            p = a + v * 0.1 * k
            person = PersonFrame(float(p[0]), float(p[1]), float(v[0]), float(v[1]), k < 55)
            det = cam.frame([person], robot)
            frames.append(FrameRecord(0.1 * k, robot, (person,), tuple(det), f"walk{w}"))
    return frames


def test_the_fit_recovers_the_model_that_drew_the_data(vis):
    true = truth_model()
    frames = synthetic_frames(true, vis)
    model, report = fit(frames, vis)
    # the detection probability agrees on the data's own features (covered and
    # legs_covered move together, so single weights are not identifiable, only this)
    diffs = []
    for fr in frames[::7]:
        for seen_before in (False, True):
            mask = vis.robot_mask(fr.robot)
            f = features_of(fr.people[0], vis, mask, (fr.robot.x_m, fr.robot.y_m), seen_before)
            diffs.append(abs(model.p_detect(f) - true.p_detect(f)))
    assert np.mean(diffs) < 0.05 and np.percentile(diffs, 90) < 0.12
    assert model.error_sd_m == pytest.approx(true.error_sd_m, rel=0.15)
    assert model.error_rho == pytest.approx(true.error_rho, abs=0.1)
    assert model.false_rate == pytest.approx(true.false_rate, rel=0.3)
    np.testing.assert_allclose(model.bias_w[0][0] + 0.1 * 0.7, 0.05 + 0.07, atol=0.05)
    assert report["person_frames"] == 30 * 60
    assert all(abs(row["mean_model"] - row["rate_data"]) < 0.1 for row in report["calibration"])


def test_the_same_seed_draws_the_same_detections(vis):
    model = truth_model()
    a = synthetic_frames(model, vis, n_walks=3, seed=4)
    b = synthetic_frames(model, vis, n_walks=3, seed=4)
    c = synthetic_frames(model, vis, n_walks=3, seed=5)
    assert [f.detections for f in a] == [f.detections for f in b]
    assert [f.detections for f in a] != [f.detections for f in c]


def test_a_person_out_of_the_room_or_behind_the_robot_is_rarely_seen(vis):
    model = truth_model(false_rate=0.0, false_points_m=())
    cam = ModelCamera(model, vis, np.random.default_rng(0))
    outside = PersonFrame(5.5, 0.75, 0.0, 0.0, False)
    seen_out = sum(bool(cam.frame([outside], Pose2D(-3.0, -1.5, 0.0))) for _ in range(200))
    # the robot in cell 3 between the camera (west) and a person in cell 1
    hidden = PersonFrame(5.5, 0.75, 0.0, 0.0, True)
    robot = Pose2D(4.2, 0.75, 0.0)
    seen_hidden = sum(bool(cam.frame([hidden], robot)) for _ in range(200))
    seen_clear = sum(bool(cam.frame([hidden], Pose2D(1.0, 2.5, 0.0))) for _ in range(200))
    assert seen_out < 10
    assert seen_hidden < seen_clear - 40


def test_the_model_file_round_trips_and_a_bad_one_is_refused(tmp_path, vis):
    model = truth_model(meta={"date": "2026-11-26"})
    path = model.save(tmp_path / "m.yaml")
    assert PerceptionModel.load(path) == PerceptionModel.from_dict(model.to_dict())
    text = path.read_text()
    (tmp_path / "bad.yaml").write_text(text.replace("error_rho: 0.6", "error_rho: 1.5"))
    with pytest.raises(ConfigError, match="error_rho"):
        PerceptionModel.load(tmp_path / "bad.yaml")
    (tmp_path / "short.yaml").write_text(text.replace("- -1.0\n", "", 1))
    with pytest.raises(ConfigError, match="detect_w"):
        PerceptionModel.load(tmp_path / "short.yaml")
    (tmp_path / "other.yaml").write_text("format: something-else\n")
    with pytest.raises(ConfigError, match="format"):
        PerceptionModel.load(tmp_path / "other.yaml")
    assert len(FEATURES) == len(model.detect_w)


def test_floor_points_go_through_the_camera_trackers_rules():
    tracker = CameraPeopleTracker(CameraConfig(), GRID, homography=None)
    s = tracker.update_points(((5.5, 0.75),), 0.1)
    assert s.status is PersonStatus.PERSON and s.cell == 1 and s.box is None
    # walking west along the row: the direction window sees it
    for k in range(2, 8):
        s = tracker.update_points(((5.5 - 0.1 * k, 0.75),), 0.1 * k)
    assert s.direction is Direction.WEST
    # one missed frame keeps the person, two mean nobody (thesis 4.5)
    s = tracker.update_points((), 0.8)
    assert s.status is PersonStatus.PERSON and s.position_m == pytest.approx((4.8, 0.75))
    s = tracker.update_points((), 0.9)
    assert s.status is PersonStatus.NO_PERSON and s.cell is None
    # a repeated stamp is a frozen frame, not a new one
    assert tracker.update_points(((1.0, 1.0),), 0.9).warning.startswith("frozen")


def test_vectorised_hidden_fractions_equal_the_per_point_rule(vis):
    rng = np.random.default_rng(1)
    for _ in range(40):
        pose = Pose2D(
            float(rng.uniform(-0.5, 6.0)), float(rng.uniform(-0.5, 3.5)), float(rng.uniform(-3, 3))
        )
        robot = vis.robot_mask(pose)
        rxy = (pose.x_m, pose.y_m)
        expect = {
            c: sum(vis.point(x, y, robot, rxy).hidden for x, y in vis._samples(c))
            / len(vis._samples(c))
            for c in GRID.cells
        }
        if not robot.any():
            expect = vis.hidden_fractions(None)
        assert vis.hidden_fractions(pose) == expect
    assert math.isfinite(sum(vis.hidden_fractions(Pose2D(2.0, 1.0, 0.0)).values()))
