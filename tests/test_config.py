"""One validation path: every configuration dataclass is checked however it is built."""

from __future__ import annotations

import dataclasses
import typing

import pytest

from stack.cells import ConfigError
from stack.config import Config
from stack.nav.config import FollowerConfig, SpeechConfig
from stack.perception.camera import CameraConfig
from stack.perception.direction import DirectionConfig
from stack.perception.hog import FootConfig, HogConfig
from stack.perception.legs import LegConfig
from stack.perception.observation import CombinerConfig
from stack.perception.tracker import TrackerConfig
from stack.perception.visibility import VisibilityConfig
from twin import config as twin_config

CLASSES = [
    FollowerConfig, SpeechConfig, CameraConfig, DirectionConfig, FootConfig, HogConfig,
    LegConfig, CombinerConfig, TrackerConfig, VisibilityConfig,
    twin_config.RoomConfig, twin_config.CameraConfig, twin_config.LidarConfig,
    twin_config.RobotConfig, twin_config.OdometryConfig, twin_config.PersonConfig,
    twin_config.MapConfig,
]  # fmt: skip


def float_fields(cls):
    hints = typing.get_type_hints(cls)
    return [f.name for f in dataclasses.fields(cls) if hints.get(f.name) is float]


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: f"{c.__module__}.{c.__name__}")
def test_every_config_rejects_nan_and_unknown_keys_from_code_and_yaml(cls):
    assert issubclass(cls, Config)
    cls()  # the defaults are valid
    names = float_fields(cls)
    assert names, f"{cls.__name__} has no float field to check"
    for name in names:
        for bad in (float("nan"), float("inf")):
            with pytest.raises(ConfigError) as err:
                cls(**{name: bad})  # in code
            assert name in err.value.key
            with pytest.raises(ConfigError) as err:
                cls.from_dict({name: bad})  # from YAML
            assert name in err.value.key
    with pytest.raises(ConfigError, match="unknown key"):
        cls.from_dict({"no_such_key": 1})
    with pytest.raises(ConfigError, match="must be a number"):
        cls(**{names[0]: "fast"})


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
