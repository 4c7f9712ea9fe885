"""One validation path: every configuration dataclass is checked however it is built."""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
import typing

import pytest

from stack.cells import ConfigError
from stack.config import Config
from stack.nav.config import FollowerConfig
from twin import config as twin_config

# every Config subclass of the packages, found by importing them (a new config class is
# covered without being listed); node modules are left out (they import rclpy)
for _pkg in ("stack", "twin", "vigil"):
    for _m in pkgutil.walk_packages(importlib.import_module(_pkg).__path__, f"{_pkg}."):
        if ".node_" not in _m.name and not _m.name.endswith(("bridge_node", "ros_main")):
            importlib.import_module(_m.name)


def _all_subclasses(cls):
    for sub in cls.__subclasses__():
        yield sub
        yield from _all_subclasses(sub)


# the fields a class needs besides its defaults to be valid
REQUIRED = {"StreamConfig": {"url": "rtsp://camera/stream"}}
CLASSES = sorted(
    {c for c in _all_subclasses(Config) if dataclasses.is_dataclass(c)},
    key=lambda c: (c.__module__, c.__name__),
)


def test_the_config_classes_are_found():
    names = {c.__name__ for c in CLASSES}
    assert {"FollowerConfig", "GateConfig", "StreamConfig", "Task", "Rewards", "RosSection",
            "PlannerSection", "TwinConfig", "CombinerConfig"} <= names  # fmt: skip
    assert len(CLASSES) >= 35


def float_fields(cls):
    hints = typing.get_type_hints(cls)
    return [f.name for f in dataclasses.fields(cls) if hints.get(f.name) is float]


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: f"{c.__module__}.{c.__name__}")
def test_every_config_rejects_nan_and_unknown_keys_from_code_and_yaml(cls):
    assert issubclass(cls, Config)
    need = REQUIRED.get(cls.__name__, {})
    cls(**need)  # the defaults are valid
    for name in float_fields(cls):
        for bad in (float("nan"), float("inf")):
            with pytest.raises(ConfigError) as err:
                cls(**{**need, name: bad})  # in code
            assert name in err.value.key
            with pytest.raises(ConfigError) as err:
                cls.from_dict({**need, name: bad})  # from YAML
            assert name in err.value.key
        with pytest.raises(ConfigError, match="must be a number"):
            cls(**{**need, name: "fast"})
    with pytest.raises(ConfigError, match="unknown key"):
        cls.from_dict({**need, "no_such_key": 1})


def test_out_of_range_is_refused_in_code_as_from_yaml():
    with pytest.raises(ConfigError, match="max_vx_mps"):
        FollowerConfig(max_vx_mps=-1.0)
    with pytest.raises(ConfigError, match="follower.max_vx_mps"):
        FollowerConfig.from_dict({"max_vx_mps": -1.0})
    with pytest.raises(ConfigError, match="camera.width_px"):
        twin_config.TwinConfig.from_dict({"camera": {"width_px": 4}})
    with pytest.raises(ConfigError, match="width_px"):
        twin_config.CameraConfig(width_px=4)
    with pytest.raises(ConfigError, match="must be an integer"):
        twin_config.CameraConfig(width_px=640.5)


# numeric fields where any finite value is meaningful (NaN and infinity are still refused)
ANY_FINITE = {
    "Rewards": {"move", "rest_cell", "restricted_guarded", "restricted_idle", "out_of_map",
                "other_cell"},  # rewards and costs: any real number
    "HogConfig": {"hit_threshold", "min_weight"},  # SVM margins: negative is meaningful
    "CameraConfig": {"lateral_offset_m"},  # a signed offset (left or right)
    "Obstacle": {"x_m", "y_m"},  # positions in the room's frame (signed)
    "Waypoint": {"x_m", "y_m"},
    "RobotConfig": {"start_yaw_rad"},  # any angle
    "RoomConfig": {"door_offset_east_m"},  # signed: east or west of the region's edge
}  # fmt: skip


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: f"{c.__module__}.{c.__name__}")
def test_every_numeric_field_has_a_range_in_code_as_from_yaml(cls):
    """Each int/float field refuses an absurd value (-1e9 or 1e9) built in code and read
    from YAML alike, unless listed in ANY_FINITE with the reason."""
    need = REQUIRED.get(cls.__name__, {})
    hints = typing.get_type_hints(cls)
    loose = []
    for f in dataclasses.fields(cls):
        kind = hints.get(f.name)
        if kind not in (int, float) or f.name in ANY_FINITE.get(cls.__name__, ()):
            continue
        refused = False
        for bad in (kind(-(10**9)), kind(10**9)):
            try:
                cls(**{**need, f.name: bad})
            except ConfigError:  # its own rule or a cross-field one (min < max)
                refused = True
                with pytest.raises(ConfigError):
                    cls.from_dict({**need, f.name: bad})
        if not refused:
            loose.append(f.name)
    assert not loose, f"{cls.__name__}: fields with no range: {loose}"


def test_a_setting_checks_the_range_its_rule_names_with_open_and_closed_ends():
    from stack.config import setting

    @dataclasses.dataclass(frozen=True)
    class Limits(Config):
        p: float = setting(0.5, "a probability in [0, 1)")
        gain: float = setting(1.0, "in (0, 10] per second")
        gap_s: float = setting(2.0, "> 0 s")
        count: int = setting(3, ">= 1")

    assert Limits().p == 0.5 and Limits(p=0.0).p == 0.0 and Limits(gain=10.0).gain == 10.0
    for bad, rule in (
        ({"p": 1.0}, "must be a probability in \\[0, 1\\)"),
        ({"p": -0.1}, "p"),
        ({"gain": 0.0}, "must be in \\(0, 10\\] per second"),
        ({"gain": 10.5}, "gain"),
        ({"gap_s": 0.0}, "must be > 0 s"),
        ({"count": 0}, "must be >= 1"),
    ):
        with pytest.raises(ConfigError, match=rule):
            Limits(**bad)
    with pytest.raises(ConfigError, match="gap_s"):
        Limits.from_dict({"gap_s": -1.0}, "limits")
    with pytest.raises(ValueError, match="no interval or bound"):
        setting(1.0, "positive")
