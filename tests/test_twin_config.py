"""Twin configuration: defaults build, bad values fail naming key, value and rule."""

from pathlib import Path

import pytest

from stack.cells import CellGrid, ConfigError
from twin.config import TwinConfig, load_twin_config


def test_defaults_are_valid_and_use_the_shared_grid():
    cfg = TwinConfig.from_dict({})
    assert cfg == TwinConfig()
    assert cfg.grid == CellGrid()
    assert cfg.camera.width_px <= 1280 and cfg.camera.height_px <= 800


def test_sections_are_parsed_into_frozen_dataclasses():
    cfg = TwinConfig.from_dict(
        {
            "camera": {"width_px": 1280, "height_px": 800, "fovy_deg": 38},
            "lidar": {"beams": 360, "fov_deg": 360},
            "person": {"waypoints": [{"x_m": 1, "y_m": 2, "speed_mps": 0.5, "pause_s": 2}]},
            "grid": {"cell_size_m": [1.0, 1.5], "origin_m": [2.0, 1.0]},
        }
    )
    assert cfg.camera.fovy_deg == 38.0 and isinstance(cfg.camera.fovy_deg, float)
    assert cfg.lidar.beams == 360
    assert cfg.person.waypoints[0].pause_s == 2.0
    assert cfg.grid.origin_m == (2.0, 1.0)
    with pytest.raises(AttributeError):
        cfg.camera.fovy_deg = 10.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("data", "key", "rule"),
    [
        ({"camera": {"fovy_deg": 100}}, "camera.fovy_deg", "3-8 mm lens"),
        ({"camera": {"width_px": 1920}}, "camera.width_px", "P1344"),
        ({"camera": {"zoom": 2}}, "camera.zoom", "unknown key"),
        ({"lidar": {"beams": True}}, "lidar.beams", "integer"),
        ({"lidar": {"range_min_m": 5, "range_max_m": 4}}, "lidar.range_max_m", "exceed"),
        (
            {"person": {"waypoints": [{"x_m": 0, "y_m": 0}, {"x_m": 1, "y_m": 0, "speed_mps": 3}]}},
            "person.waypoints[1].speed_mps",
            "walking speeds",
        ),
        ({"person": {"shirt_rgb": [1, 0]}}, "person.shirt_rgb", "3 elements"),
        ({"robot": {"start_cell": 13}}, "robot.start_cell", "not a cell"),
        ({"timestep_s": 0.002, "control_period_s": 0.003}, "control_period_s", "multiple"),
        ({"camera": {"distance_behind_m": 4.0}}, "camera.distance_behind_m", "margin_west_m"),
        ({"grid": {"cell_size_m": [0, 1]}}, "grid.cell_size_m[0]", "> 0"),
        ({"map": {"free_thresh": 0.9}}, "map.free_thresh", "occupied_thresh"),
        ({"room": "big"}, "room", "mapping"),
    ],
)
def test_bad_values_name_key_value_and_rule(data, key, rule):
    with pytest.raises(ConfigError) as err:
        TwinConfig.from_dict(data)
    assert err.value.key == key
    assert rule in err.value.rule
    assert key in str(err.value)


def test_load_takes_the_grid_from_the_task_file(tmp_path: Path):
    twin_yaml = tmp_path / "twin.yaml"
    twin_yaml.write_text("twin:\n  camera:\n    fovy_deg: 42\n")
    task = tmp_path / "task.yaml"
    task.write_text("grid:\n  rows: 2\n  columns: 4\n  origin_m: [1.0, 0.5]\n")
    cfg = load_twin_config(twin_yaml, task)
    assert cfg.camera.fovy_deg == 42.0
    assert cfg.grid.n_cells == 8 and cfg.grid.origin_m == (1.0, 0.5)
    # a task file that does not exist yet leaves the default grid
    assert load_twin_config(twin_yaml, tmp_path / "absent.yaml").grid == CellGrid()


def test_sample_config_file_loads():
    root = Path(__file__).resolve().parents[1]
    cfg = load_twin_config(root / "config" / "twin-scene.yaml", root / "config" / "task-r1.yaml")
    assert cfg.camera.width_px > 0
