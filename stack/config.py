"""What every component's config validation shares: typed values and YAML files.

Each component keeps its own frozen dataclasses and rules; this module holds the two
pieces they all need, so that an error reads the same everywhere:
:class:`stack.cells.ConfigError` with the dotted key, the value and the rule.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from stack.cells import ConfigError


def coerce_like(key: str, value: Any, default: Any) -> Any:
    """``value`` checked against the type of ``default`` (a field's default value).

    bool needs a bool; float takes any number; int needs an integer; str takes a string
    (or an integer, e.g. a device index written as a number); tuple takes a list.

    Raises:
        ConfigError: the value has the wrong type.
    """
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(key, value, "must be true or false")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(key, value, "must be a number")
        return float(value)
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(key, value, "must be an integer")
        return value
    if isinstance(default, str):
        if isinstance(value, bool) or not isinstance(value, str | int):
            raise ConfigError(key, value, "must be a string")
        return str(value)
    if isinstance(default, tuple):
        if isinstance(value, str) or not isinstance(value, list | tuple):
            raise ConfigError(key, value, "must be a list")
        return tuple(value)
    return value


def read_yaml(path: str | Path) -> dict[str, Any]:
    """A YAML file holding a mapping (an empty file is an empty mapping).

    Raises:
        ConfigError: the file cannot be read or parsed, or is not a mapping
            (key ``config_file``).
    """
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError("config_file", str(path), f"cannot be read: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError("config_file", str(path), "must hold a mapping")
    return data
