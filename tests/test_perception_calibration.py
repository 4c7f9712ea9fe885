"""Floor calibration inputs: the robot's points file and the twin's reported points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stack.perception.errors import CalibrationError
from stack.perception.homography import (
    FloorPoints,
    calibrate,
    load_calibration,
    load_points_file,
    save_calibration,
    save_points_file,
)

SQUARE = [
    {"pixel": [100, 300], "map": [0.0, 0.0]},
    {"pixel": [500, 300], "map": [6.0, 0.0]},
    {"pixel": [420, 120], "map": [6.0, 3.0]},
    {"pixel": [180, 120], "map": [0.0, 3.0]},
]


def write(tmp_path, text):
    path = tmp_path / "points.yaml"
    path.write_text(text)
    return path


def test_points_file_list_and_mapping_forms(tmp_path):
    import yaml

    pts = load_points_file(write(tmp_path, yaml.safe_dump(SQUARE)))
    assert pts.image_px.shape == (4, 2) and pts.image_size_px is None
    assert pts.map_m[2].tolist() == [6.0, 3.0]
    pts = load_points_file(
        write(tmp_path, yaml.safe_dump({"image_size_px": [640, 400], "points": SQUARE}))
    )
    assert pts.image_size_px == (640, 400)
    cal = calibrate(pts.image_px, pts.map_m, image_size_px=pts.image_size_px)
    assert cal.max_error_m < 1e-6


def test_points_file_round_trip_and_calibration_file(tmp_path):
    pts = FloorPoints(
        np.array([e["pixel"] for e in SQUARE], float),
        np.array([e["map"] for e in SQUARE], float),
        (640, 400),
    )
    save_points_file(tmp_path / "p.yaml", pts)
    back = load_points_file(tmp_path / "p.yaml")
    assert np.array_equal(back.image_px, pts.image_px) and back.image_size_px == (640, 400)
    save_calibration(tmp_path / "cal.yaml", calibrate(back.image_px, back.map_m, (640, 400)))
    assert load_calibration(tmp_path / "cal.yaml").max_error_m < 1e-6


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[", "cannot read points file"),
        ("42", "needs a list"),
        ("{pointz: []}", "unknown key(s) ['pointz']"),
        ("[{pixel: [1, 2], map: [0, 0]}, 7]", "entry 1 (7): must be a mapping"),
        ("[{pixel: [1, 2]}]", "entry 0 ({'pixel': [1, 2]}): missing 'map'"),
        (
            "[{pixel: [1, 2, 3], map: [0, 0]}]",
            "entry 0 ({'pixel': [1, 2, 3], 'map': [0, 0]}): 'pixel' must be [u, v] in pixels",
        ),  # fmt: skip
        ("[{pixel: [1, 2], map: [x, 0]}]", "'map' must be [x, y] in metres"),
        ("[{pixel: [1, .nan], map: [0, 0]}]", "two finite numbers"),
        (
            "[{pixel: [1, 2], map: [0, 0], z: 1}]",
            "entry 0 ({'pixel': [1, 2], 'map': [0, 0], 'z': 1}): unknown key(s) ['z']",
        ),  # fmt: skip
        ("[{pixel: [-1, 2], map: [0, 0]}]", "pixel [-1.0, 2.0] must be >= 0"),
        (
            "{image_size_px: [640, 400], points: [{pixel: [700, 2], map: [0, 0]}]}",
            "inside the 640 x 400 image",
        ),  # fmt: skip
        ("{image_size_px: [640], points: []}", "image_size_px [640] must be [width, height]"),
        (
            "[{pixel: [1, 2], map: [0, 0]}, {pixel: [1, 2], map: [1, 0]}]",
            "entry 1 ({'pixel': [1, 2], 'map': [1, 0]}): repeats entry 0's pixel",
        ),  # fmt: skip
        (
            "[{pixel: [1, 2], map: [0, 0]}, {pixel: [3, 4], map: [1, 0]}]",
            "needs at least 4 points, got 2",
        ),  # fmt: skip
    ],
)
def test_points_file_errors_name_the_bad_entry(tmp_path, text, message):
    with pytest.raises(CalibrationError) as err:
        load_points_file(write(tmp_path, text))
    assert message in str(err.value)
    assert "points.yaml" in str(err.value)


def test_missing_points_file(tmp_path):
    with pytest.raises(CalibrationError, match="does not exist"):
        load_points_file(tmp_path / "nope.yaml")


def test_twin_calibration_is_exact_on_corners_and_places_cell_centres():
    twin_mod = pytest.importorskip("twin.twin")
    from twin.calibration import calibrate_twin, twin_floor_points
    from twin.config import TwinConfig

    tw = twin_mod.Twin(TwinConfig(), seed=0)
    try:
        cal = calibrate_twin(tw)
        grid = tw.config.grid
        centres = np.array([grid.center(c) for c in grid.cells])
        held_out = twin_floor_points(tw, floor_m=centres)
    finally:
        tw.close()
    assert len(cal.errors_m) == (grid.rows + 1) * (grid.columns + 1)
    assert cal.max_error_m < 1e-4
    assert cal.homography.image_size_px == (tw.camera_info.width, tw.camera_info.height)
    mapped = cal.homography.image_to_map_many(held_out.image_px)
    assert np.max(np.linalg.norm(mapped - held_out.map_m, axis=1)) < 1e-4
    for c, (x, y) in zip(grid.cells, mapped, strict=True):
        assert grid.cell_at(x, y) == c and math.isfinite(x)
