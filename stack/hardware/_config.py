"""Validation of the hardware sections (``camera_stream``, ``velocity_gate``) of a YAML file."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from stack.cells import ConfigError

T = TypeVar("T")


def from_dict(cls: type[T], data: Mapping[str, Any] | None, prefix: str) -> T:
    """Build the frozen dataclass ``cls`` from a mapping; unknown keys and wrong types are errors.

    A field's type is read from its default (bool, int, float, str); a field without a
    default is required and takes a string.

    Raises:
        ConfigError: unknown or missing key, wrong type, or a rule of ``__post_init__`` broken
            (re-raised with the key prefixed by ``prefix``).
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(prefix, data, "must be a mapping")
    known = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key not in known:
            raise ConfigError(f"{prefix}.{key}", value, f"unknown key (known: {sorted(known)})")
        f = known[key]
        default = f.default if f.default is not dataclasses.MISSING else ""
        kwargs[key] = coerce(f"{prefix}.{key}", value, default)
    for name, f in known.items():
        if name not in kwargs and f.default is dataclasses.MISSING:
            raise ConfigError(f"{prefix}.{name}", None, "is required")
    try:
        return cls(**kwargs)
    except ConfigError as exc:  # __post_init__ names the bare field
        key = exc.key if exc.key.startswith(prefix + ".") else f"{prefix}.{exc.key}"
        raise ConfigError(key, exc.value, exc.rule) from None


def coerce(key: str, value: Any, default: Any) -> Any:
    """``value`` checked against the type of ``default`` (ints are accepted for floats)."""
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
        return str(value)  # a device index written as a number in YAML
    return value


def positive(key: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(key, value, "must be a finite number > 0")


def read_section(path: str | Path | None, section: str) -> Mapping[str, Any]:
    """The raw ``section`` mapping of a YAML file ({} when the path is empty or it is absent).

    Raises:
        ConfigError: unreadable file, not a mapping, or the section not a mapping.
    """
    import yaml

    if not path:
        return {}
    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError("config_file", str(path), f"cannot be read: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError("config_file", str(path), "must hold a mapping")
    sect = data.get(section) or {}
    if not isinstance(sect, Mapping):
        raise ConfigError(section, sect, "must be a mapping")
    return sect
