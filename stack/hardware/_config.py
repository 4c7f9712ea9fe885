"""Validation of the hardware sections (``camera_stream``, ``velocity_gate``) of a YAML file."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from stack.cells import ConfigError
from stack.config import coerce_like, read_yaml

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


coerce = coerce_like  # the shared rules (stack.config)


def positive(key: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(key, value, "must be a finite number > 0")


def read_section(path: str | Path | None, section: str) -> Mapping[str, Any]:
    """The raw ``section`` mapping of a YAML file ({} when the path is empty or it is absent).

    Raises:
        ConfigError: unreadable file, not a mapping, or the section not a mapping.
    """
    if not path:
        return {}
    data = read_yaml(path)
    sect = data.get(section) or {}
    if not isinstance(sect, Mapping):
        raise ConfigError(section, sect, "must be a mapping")
    return sect
