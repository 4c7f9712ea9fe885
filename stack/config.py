"""One validation mechanism for every configuration: :class:`Config`.

Every component's configuration is a frozen dataclass deriving from :class:`Config`.
Whether it is built from YAML (``Cls.from_dict(mapping, key)``) or in code
(``Cls(x=...)``), the constructor checks each field against its type hint (numbers
finite, integers integral, booleans boolean, tuples of the right length, nested
configurations of their class) and then the class's own rules: each field's range
declared beside its default with :func:`setting`, ``_rules`` (field -> (predicate, rule
text)) and ``check()`` (cross-field rules, raising through :func:`require`). Unknown keys
are refused by ``from_dict``. An error is always :class:`stack.cells.ConfigError` with
the dotted key, the value and the rule.
"""

from __future__ import annotations

import dataclasses
import math
import operator
import re
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from stack.cells import ConfigError
from stack.files import MAX_FILE_BYTES as MAX_FILE_BYTES  # re-exported: the file
from stack.files import open_regular as open_regular  # helpers lived here first
from stack.files import open_write as open_write
from stack.files import read_bytes_capped as read_bytes_capped
from stack.files import read_text_capped as read_text_capped
from stack.files import write_bytes as write_bytes
from stack.files import write_text as write_text

T = TypeVar("T")
Rule = tuple[Any, str]  # (predicate on the value, rule text)


class Config:
    """Base of every configuration dataclass: checked whenever it is built.

    Subclasses are ``@dataclass(frozen=True)``; they may declare fields with
    :func:`setting`, define ``_rules`` and ``check()``; their own ``__post_init__`` (if
    any) runs after the field checks.
    """

    _rules: ClassVar[dict[str, Rule]] = {}
    section: ClassVar[str] = ""  # the YAML section's name: the default key of errors

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("__post_init__")

        def __post_init__(self: Any) -> None:
            check_fields(self)
            for name, (predicate, rule) in _class_rules(type(self)).items():
                value = getattr(self, name)
                if value is not None and not predicate(value):
                    raise ConfigError(name, value, rule)
            if own is not None:
                own(self)
            self.check()

        cls.__post_init__ = __post_init__  # type: ignore[attr-defined]

    def check(self) -> None:
        """Cross-field rules; override (raise with :func:`require`)."""

    @classmethod
    def from_dict(cls: type[T], data: Mapping[str, Any] | None, key: str | None = None) -> T:
        """Build from a mapping (a YAML section); missing keys keep their defaults.

        ``key`` names the section in errors (default: the class's ``section``).

        Raises:
            ConfigError: an unknown key, a value of the wrong type, or a broken rule.
        """
        return from_mapping(cls, data, cls.section if key is None else key)  # type: ignore[attr-defined]


_NUMBER = r"-?\d+(?:\.\d+)?"
_INTERVAL = re.compile(rf"([\[(])\s*({_NUMBER})\s*,\s*({_NUMBER})\s*([\])])")
_BOUND = re.compile(rf"(>=|<=|>|<)\s*({_NUMBER})")
_OPS = {"[": operator.le, "]": operator.le, "(": operator.lt, ")": operator.lt}
_BOUND_OPS = {">=": operator.ge, "<=": operator.le, ">": operator.gt, "<": operator.lt}


def setting(default: T, rule: str) -> T:
    """A Config field's default with its rule beside it, e.g.
    ``lapse: float = setting(0.05, "a probability in [0, 1)")``.

    ``rule`` is what the error says after "must be", and the check is read from it: one
    interval (``[a, b]``, ``(a, b]``, ...: round brackets for open ends) or one bound
    (``> a``, ``>= a``, ``< b``, ``<= b``); the words around it are for the reader. It is
    checked as one of ``_rules`` would be (a None value passes), before them.

    Raises:
        ValueError: the rule holds no interval or bound (when the class is defined).
    """
    if m := _INTERVAL.search(rule):
        below, above = _OPS[m[1]], _OPS[m[4]]
        low, high = float(m[2]), float(m[3])

        def predicate(v: Any) -> bool:
            return bool(below(low, v) and above(v, high))

    elif m := _BOUND.search(rule):
        op, bound = _BOUND_OPS[m[1]], float(m[2])

        def predicate(v: Any) -> bool:
            return bool(op(v, bound))

    else:
        raise ValueError(f"setting: no interval or bound in the rule {rule!r}")
    return dataclasses.field(default=default, metadata={"rule": (predicate, f"must be {rule}")})


_RULES: dict[type, dict[str, Rule]] = {}


def _class_rules(cls: type) -> dict[str, Rule]:
    """A Config class's rules, once per class: its settings' in field order, then ``_rules``."""
    rules = _RULES.get(cls)
    if rules is None:
        fields = dataclasses.fields(cls)  # type: ignore[arg-type]
        own = {f.name: f.metadata["rule"] for f in fields if "rule" in f.metadata}
        rules = _RULES[cls] = own | cls._rules  # type: ignore[attr-defined]
    return rules


_HINTS: dict[type, dict[str, Any]] = {}


def _type_hints(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints`` once per class (it evaluates every annotation's string)."""
    hints = _HINTS.get(cls)
    if hints is None:
        hints = _HINTS[cls] = typing.get_type_hints(cls)
    return hints


def check_fields(obj: Any) -> None:
    """Check each field of a dataclass instance against its type hint.

    Raises:
        ConfigError: the first field whose value does not fit (key: the field's name).
    """
    hints = _type_hints(type(obj))
    for f in dataclasses.fields(obj):
        if f.name.startswith("_") or f.name not in hints:
            continue
        _check_value(f.name, getattr(obj, f.name), hints[f.name])


def _check_value(key: str, value: Any, hint: Any) -> None:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            _check_value(key, value, inner[0])
        return
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(key, value, "must be a number")
        if not math.isfinite(value):
            raise ConfigError(key, value, "must be finite")
    elif hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(key, value, "must be an integer")
    elif hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, value, "must be true or false")
    elif hint is str:
        if not isinstance(value, str):
            raise ConfigError(key, value, "must be a string")
    elif origin is tuple:
        if not isinstance(value, tuple):
            raise ConfigError(key, value, "must be a tuple")
        if len(args) == 2 and args[1] is Ellipsis:
            for i, v in enumerate(value):
                _check_value(f"{key}[{i}]", v, args[0])
        elif args:
            if len(value) != len(args):
                raise ConfigError(key, value, f"must have {len(args)} elements")
            for i, (v, a) in enumerate(zip(value, args, strict=True)):
                _check_value(f"{key}[{i}]", v, a)
    elif isinstance(hint, type) and dataclasses.is_dataclass(hint):
        if not isinstance(value, hint):
            raise ConfigError(key, value, f"must be a {hint.__name__}")


def load_yaml(text: str) -> Any:
    """``yaml.safe_load`` through libyaml when PyYAML has it (the same safe schema, about
    ten times faster: a run reads a dozen configuration files)."""
    import yaml

    return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def dump_yaml(data: Any, **kwargs: Any) -> str:
    """``yaml.safe_dump`` through libyaml when PyYAML has it (the same representation;
    a run writes its parameters and calibration files, a study does so per episode)."""
    import yaml

    return yaml.dump(data, Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper), **kwargs)


def read_yaml(path: str | Path) -> dict[str, Any]:
    """A YAML file holding a mapping (an empty file is an empty mapping).

    Raises:
        ConfigError: the file cannot be read or parsed, or is not a mapping
            (key ``config_file``).
    """
    import yaml

    try:
        data = load_yaml(read_text_capped(path)) or {}
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise ConfigError("config_file", str(path), f"cannot be read: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError("config_file", str(path), "must hold a mapping")
    return data


def read_section(
    path: str | Path | None, section: str, parent: str | None = None
) -> Mapping[str, Any]:
    """The raw ``section`` mapping of a YAML file ({} when the path is empty or the
    section absent), for a node that validates it with its Config class. With
    ``parent``, a file that has a ``parent`` mapping (a deployment file, whose
    ``hardware:`` holds the hardware nodes' sections) is read there, so a node started
    on its own reads the same section as the launcher gives it; other files at the top.

    Raises:
        ConfigError: unreadable file, not a mapping, or the section not a mapping.
    """
    if not path:
        return {}
    data: Mapping[str, Any] = read_yaml(path)
    key = section
    if parent is not None and parent in data:
        holder = data[parent]
        if not isinstance(holder, Mapping):
            raise ConfigError(parent, holder, "must be a mapping")
        data, key = holder, f"{parent}.{section}"
    sect = data.get(section) or {}
    if not isinstance(sect, Mapping):
        raise ConfigError(key, sect, "must be a mapping")
    return sect


def from_mapping(cls: type[T], data: Mapping[str, Any] | None, key: str) -> T:
    """Build the frozen dataclass ``cls`` from a mapping, validating every field.

    Args:
        cls: a dataclass whose fields are bool, int, float, str, fixed-length tuples
            of numbers, nested dataclasses, or ``X | None`` of those.
        data: the mapping (e.g. one YAML section); None or empty gives the defaults.
        key: the dotted name of the section, used in error messages.

    Returns:
        The validated instance.

    Raises:
        ConfigError: unknown key, wrong type, or a rule of ``cls.__post_init__`` broken.
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(key, data, "must be a mapping")
    hints = _type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]

    def path(name: str) -> str:
        return f"{key}.{name}" if key else str(name)

    for k in data:
        if k not in fields:
            raise ConfigError(path(k), data[k], f"unknown key (known: {sorted(fields)})")
    kwargs = {}
    for name, value in data.items():
        kwargs[name] = _coerce(hints[name], value, path(name))
    try:
        return cls(**kwargs)
    except ConfigError as err:
        # Rules raised in __post_init__ name the bare field: prefix the section.
        if key and not err.key.startswith(key + "."):
            raise ConfigError(path(err.key), err.value, err.rule) from None
        raise


def _coerce(hint: Any, value: Any, key: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _coerce(inner[0], value, key)
        raise ConfigError(key, value, f"unsupported type {hint}")
    if isinstance(hint, type) and hasattr(hint, "from_mapping"):  # e.g. CellGrid
        return hint.from_mapping(value, key)
    if dataclasses.is_dataclass(hint):
        return from_mapping(hint, value, key)  # type: ignore[arg-type]
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, value, "must be true or false")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(key, value, "must be an integer")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(key, value, "must be a number")
        if not math.isfinite(value):
            raise ConfigError(key, value, "must be finite")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(key, value, "must be a string")
        return value
    if origin is tuple:
        if isinstance(value, str | bytes) or not isinstance(value, list | tuple):
            raise ConfigError(key, value, f"must be a list of {len(args)} numbers")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v, f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(key, value, f"must be a list of {len(args)} elements")
        return tuple(
            _coerce(a, v, f"{key}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    raise ConfigError(key, value, f"unsupported type {hint}")


def require(condition: bool, key: str, value: Any, rule: str) -> None:
    """Raise ConfigError(key, value, rule) unless ``condition`` holds."""
    if not condition:
        raise ConfigError(key, value, rule)
