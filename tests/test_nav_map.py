"""Map loading (map_server YAML + PGM, OccupancyGrid arrays) and obstacle inflation."""

import math

import numpy as np
import pytest
import yaml

from stack.nav.occupancy import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    MapError,
    OccupancyMap,
    disc_mask,
    from_occupancy_grid,
    inflate,
    load_map_yaml,
    save_map_yaml,
)


def write_map(tmp_path, pixels, meta_overrides=None, magic="P5", name="room"):
    """A map_server map with the given image rows (top row first)."""
    pixels = np.asarray(pixels, dtype=np.uint8)
    h, w = pixels.shape
    pgm = tmp_path / f"{name}.pgm"
    if magic == "P5":
        pgm.write_bytes(f"P5\n# made by a test\n{w} {h}\n255\n".encode() + pixels.tobytes())
    else:
        body = "\n".join(" ".join(str(v) for v in row) for row in pixels)
        pgm.write_text(f"P2\n{w} {h}\n255\n{body}\n")
    meta = {
        "image": pgm.name,
        "resolution": 0.1,
        "origin": [-1.0, -2.0, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.25,
    }
    meta.update(meta_overrides or {})
    meta = {k: v for k, v in meta.items() if v is not None}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(meta))
    return path


# image rows top first: black (occupied) top-left, grey (unknown) bottom-right
IMAGE = [[0, 254, 254], [254, 254, 254], [254, 254, 128]]


@pytest.mark.parametrize("magic", ["P5", "P2"])
def test_loader_reads_values_placement_and_flips_rows(tmp_path, magic):
    m = load_map_yaml(write_map(tmp_path, IMAGE, magic=magic))
    assert m.shape == (3, 3)
    assert m.resolution_m == pytest.approx(0.1)
    assert m.origin_m == (-1.0, -2.0)
    # the image's top row is the map's northmost row (last row in OccupancyGrid order)
    assert m.data[2, 0] == OCCUPIED
    assert m.data[0, 2] == UNKNOWN
    assert (m.data == FREE).sum() == 7
    # cell (2, 0) is the north-west cell: its centre is half a cell in from the corner
    assert m.cell_to_world(2, 0) == pytest.approx((-0.95, -1.75))
    assert m.world_to_cell(-0.95, -1.75) == (2, 0)


def test_a_png_map_reads_as_its_pgm(tmp_path):
    """A non-PGM image is decoded by OpenCV from the bytes read once (capped)."""
    import cv2

    pgm = load_map_yaml(write_map(tmp_path, IMAGE))
    ok, png = cv2.imencode(".png", np.asarray(IMAGE, np.uint8))
    assert ok
    (tmp_path / "map.png").write_bytes(png.tobytes())
    meta = yaml.safe_load((tmp_path / "room.yaml").read_text())
    meta["image"] = "map.png"
    (tmp_path / "png.yaml").write_text(yaml.safe_dump(meta))
    m = load_map_yaml(tmp_path / "png.yaml")
    assert np.array_equal(m.data, pgm.data) and m.origin_m == pgm.origin_m


def test_negate_and_thresholds(tmp_path):
    m = load_map_yaml(write_map(tmp_path, [[0, 255, 128]], {"negate": 1}))
    # negate: white is occupied, black free; 128/255 = 0.50 lies between the thresholds
    assert list(m.data[0]) == [FREE, OCCUPIED, UNKNOWN]


def test_scale_and_raw_modes(tmp_path):
    m = load_map_yaml(write_map(tmp_path, [[0, 254, 128]], {"mode": "scale"}))
    assert m.data[0, 0] == OCCUPIED and m.data[0, 1] == FREE
    assert 1 <= m.data[0, 2] <= 99
    m = load_map_yaml(write_map(tmp_path, [[0, 100, 101]], {"mode": "raw"}))
    assert list(m.data[0]) == [0, 100, UNKNOWN]


def test_save_load_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    data = rng.choice([FREE, OCCUPIED, UNKNOWN], size=(7, 5)).astype(np.int8)
    m = OccupancyMap(data, 0.05, (1.5, -0.5))
    back = load_map_yaml(save_map_yaml(m, tmp_path / "saved.yaml"))
    np.testing.assert_array_equal(back.data, data)
    assert back.origin_m == (1.5, -0.5) and back.resolution_m == pytest.approx(0.05)


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"resolution": None}, "missing required field(s) ['resolution']"),
        ({"resolution": -0.05}, "resolution: -0.05 must be > 0"),
        ({"resolution": "fine"}, "resolution: 'fine' must be a finite number"),
        ({"origin": [0.0, 0.0]}, "origin: [0.0, 0.0] must be [x, y, yaw]"),
        ({"origin": [0.0, 0.0, 0.5]}, "yaw 0.5 is not supported"),
        ({"occupied_thresh": 1.5}, "occupied_thresh: 1.5 must lie in [0, 1]"),
        ({"free_thresh": 0.7}, "free_thresh 0.7 must be below occupied_thresh 0.65"),
        ({"negate": 2}, "negate: 2 must be 0 or 1"),
        ({"mode": "fancy"}, "mode: 'fancy' must be one of"),
        ({"colour": "red"}, "unknown field(s) ['colour']"),
        ({"image": "absent.pgm"}, "absent.pgm: image file not found"),
    ],
)
def test_malformed_yaml_rejected_with_message(tmp_path, overrides, message):
    with pytest.raises(MapError) as err:
        load_map_yaml(write_map(tmp_path, IMAGE, overrides))
    assert message in str(err.value)


def test_malformed_files_rejected_with_message(tmp_path):
    with pytest.raises(MapError, match="cannot read map YAML"):
        load_map_yaml(tmp_path / "nothing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("image: [unclosed")
    with pytest.raises(MapError, match="not valid YAML"):
        load_map_yaml(bad)
    bad.write_text("- just\n- a list\n")
    with pytest.raises(MapError, match="must be a mapping"):
        load_map_yaml(bad)
    path = write_map(tmp_path, IMAGE)
    pgm = tmp_path / "room.pgm"
    pgm.write_bytes(pgm.read_bytes()[:-2])
    with pytest.raises(MapError, match="PGM raster truncated: 7 of 9 bytes"):
        load_map_yaml(path)
    pgm.write_bytes(b"P7\n3 3\n255\n" + bytes(9))
    with pytest.raises(MapError, match="not a PGM image"):
        load_map_yaml(path)
    pgm.write_bytes(b"P5\n3 x\n255\n" + bytes(9))
    with pytest.raises(MapError, match="malformed PGM header"):
        load_map_yaml(path)


def test_from_occupancy_grid_and_its_errors():
    m = from_occupancy_grid([0, 100, -1, 0, 0, 0], width=3, height=2, resolution_m=0.5)
    assert m.shape == (2, 3) and m.data[0, 1] == OCCUPIED and m.data[0, 2] == UNKNOWN
    with pytest.raises(MapError, match="data has 5 values, width\\*height is 6"):
        from_occupancy_grid([0] * 5, 3, 2, 0.5)
    with pytest.raises(MapError, match="value 101 at index 2 is outside -1..100"):
        from_occupancy_grid([0, 0, 101, 0], 2, 2, 0.5)
    with pytest.raises(MapError, match="resolution"):
        from_occupancy_grid([0] * 4, 2, 2, 0.0)
    with pytest.raises(MapError, match="yaw"):
        from_occupancy_grid([0] * 4, 2, 2, 0.5, origin_yaw_rad=1.0)


def _min_distance_to_obstacles(m: OccupancyMap, x: float, y: float) -> float:
    """Exact distance from (x, y) to the nearest point of any occupied square."""
    res = m.resolution_m
    rows, cols = np.nonzero(m.occupied())
    cx, cy = m.cells_to_world(np.column_stack((rows, cols))).T
    dx = np.maximum(np.abs(cx - x) - res / 2, 0.0)
    dy = np.maximum(np.abs(cy - y) - res / 2, 0.0)
    return float(np.hypot(dx, dy).min())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_inflation_keeps_the_footprint_off_obstacles(seed):
    rng = np.random.default_rng(seed)
    data = np.zeros((40, 40), dtype=np.int8)
    data[tuple(rng.integers(0, 40, size=(2, 4)))] = OCCUPIED
    m = OccupancyMap(data, 0.05, (0.0, 0.0))
    radius = 0.3 + 0.05
    blocked = inflate(m, radius)
    assert blocked[m.occupied()].all()
    free_cells = np.argwhere(~blocked)
    assert len(free_cells) > 0
    for r, c in free_cells[rng.choice(len(free_cells), size=min(200, len(free_cells)))]:
        x, y = m.cell_to_world(r, c)
        assert _min_distance_to_obstacles(m, x, y) >= radius
    # and not wildly conservative: every cell a cell diagonal beyond the radius is free
    for r, c in np.argwhere(blocked):
        x, y = m.cell_to_world(r, c)
        assert _min_distance_to_obstacles(m, x, y) < radius + 2 * m.resolution_m


def test_inflation_radius_zero_and_unknown():
    data = np.zeros((9, 9), dtype=np.int8)
    data[4, 4] = UNKNOWN
    m = OccupancyMap(data, 0.1)
    assert inflate(m, 0.0).sum() == 1
    assert inflate(m, 0.0, unknown_is_occupied=False).sum() == 0
    # radius 0.1 + half diagonal 0.0707: the 4 side neighbours (0.1) and diagonals (0.141)
    assert inflate(m, 0.1).sum() == 9
    with pytest.raises(ValueError, match="must be >= 0"):
        inflate(m, -1.0)


def test_disc_mask_marks_cells_within_radius():
    m = OccupancyMap.empty(2.0, 2.0, 0.1)
    mask = disc_mask(m, [(1.0, 1.0)], 0.3)
    rows, cols = np.nonzero(mask)
    centres = m.cells_to_world(np.column_stack((rows, cols)))
    assert np.hypot(*(centres - (1.0, 1.0)).T).max() <= 0.3
    assert mask.sum() == pytest.approx(math.pi * 0.3**2 / 0.01, rel=0.25)
    assert not disc_mask(m, [], 0.3).any()
