"""The occupancy map: map_server files that load back and match the room's geometry."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from stack.nav.occupancy import FREE, OCCUPIED, UNKNOWN
from stack.nav.occupancy import load_map_yaml as load_map
from twin.twin import Twin


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    twin = Twin(seed=0)
    directory = tmp_path_factory.mktemp("map")
    pgm, yml = twin.save_map(directory, "lrm")
    return twin, pgm, yml


def test_files_are_in_map_server_format(saved):
    twin, pgm, yml = saved
    meta = yaml.safe_load(Path(yml).read_text())
    assert set(meta) >= {
        "image",
        "resolution",
        "origin",
        "negate",
        "occupied_thresh",
        "free_thresh",
    }
    assert meta["image"] == "lrm.pgm" and (Path(yml).parent / meta["image"]).exists()
    assert meta["resolution"] == twin.config.map.resolution_m
    assert len(meta["origin"]) == 3 and meta["negate"] == 0
    assert 0 < meta["free_thresh"] < meta["occupied_thresh"] < 1
    raw = Path(pgm).read_bytes()
    assert raw.startswith(b"P5\n")
    header = [line for line in raw.split(b"\n")[:4] if not line.startswith(b"#")]
    w, h = map(int, header[1].split())
    grid = twin.occupancy_map()
    assert (h, w) == grid.shape
    assert set(np.unique(np.frombuffer(raw[-w * h :], np.uint8))) <= {0, 205, 254}


def test_loaded_map_equals_the_built_one_and_matches_the_walls(saved):
    twin, _, yml = saved
    built = twin.occupancy_map()
    loaded = load_map(yml)
    assert loaded.origin_m == pytest.approx(built.origin_m)
    assert np.array_equal(loaded.data, built.data)
    x0, y0, x1, y1 = twin.layout.room
    t = twin.config.room.wall_thickness_m
    res = built.resolution_m
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    # wall cells just outside each inner face are occupied; just inside is free
    assert loaded.value_at(x1 + t / 2, cy) == OCCUPIED
    assert loaded.value_at(x0 - t / 2, cy) == OCCUPIED
    assert loaded.value_at(cx - 2.0, y0 - t / 2) == OCCUPIED
    assert loaded.value_at(x0 + 0.5, y1 + t / 2) == OCCUPIED
    assert loaded.value_at(x1 - 1.5 * res, cy + 1.5) == FREE
    # the region is free everywhere, the doorway is open, beyond the walls is unknown
    rx0, ry0, rx1, ry1 = twin.layout.region
    for x in np.arange(rx0 + 0.05, rx1, 0.25):
        for y in np.arange(ry0 + 0.05, ry1, 0.25):
            assert loaded.value_at(x, y) == FREE, (x, y)
    d0, d1 = twin.layout.door_x_m
    assert loaded.value_at((d0 + d1) / 2, y1 + t / 2) != OCCUPIED
    assert loaded.value_at(x0 - 0.45, y0 - 0.45) == UNKNOWN


def test_furniture_legs_are_obstacles(saved):
    twin, _, yml = saved
    loaded = load_map(yml)
    m, d = twin.model, twin.data
    for name in ("chair_s0/leg_1", "chair_w/leg_3", "desk_n1/leg_2", "pole"):
        x, y, _ = d.geom_xpos[m.geom(name).id]
        assert loaded.value_at(x, y) == OCCUPIED, name
    # a person and the robot are not part of the map
    gt = twin.ground_truth()
    assert loaded.value_at(gt.robot.x_m, gt.robot.y_m) == FREE
