"""One validation mechanism for every configuration: :class:`Config`.

Every component's configuration is a frozen dataclass deriving from :class:`Config`.
Whether it is built from YAML (``Cls.from_dict(mapping, key)``) or in code
(``Cls(x=...)``), the constructor checks each field against its type hint (numbers
finite, integers integral, booleans boolean, tuples of the right length, nested
configurations of their class) and then the class's own rules: ``_rules`` (field ->
(predicate, rule text)) and ``check()`` (cross-field rules, raising through
:func:`require`). Unknown keys are refused by ``from_dict``. An error is always
:class:`stack.cells.ConfigError` with the dotted key, the value and the rule.
"""

from __future__ import annotations

import dataclasses
import errno
import math
import os
import stat
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any, BinaryIO, ClassVar, TypeVar

from stack.cells import ConfigError

T = TypeVar("T")
Rule = tuple[Any, str]  # (predicate on the value, rule text)


class Config:
    """Base of every configuration dataclass: checked whenever it is built.

    Subclasses are ``@dataclass(frozen=True)``; they may define ``_rules`` and
    ``check()``; their own ``__post_init__`` (if any) runs after the field checks.
    """

    _rules: ClassVar[dict[str, Rule]] = {}
    section: ClassVar[str] = ""  # the YAML section's name: the default key of errors

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("__post_init__")

        def __post_init__(self: Any) -> None:
            check_fields(self)
            for name, (predicate, rule) in type(self)._rules.items():
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


MAX_FILE_BYTES = 16 * 2**20  # no configuration, task, map or state file is near this


def open_regular(
    path: str | os.PathLike, max_bytes: int = MAX_FILE_BYTES, follow_links: bool = True
) -> BinaryIO:
    """Open a file for reading only if it is a regular file of at most ``max_bytes``.

    A device (``/dev/zero``, ``/dev/random``), a named pipe (which would block the
    reader for ever), a socket or a folder is refused before a byte is read; so is a
    regular file larger than ``max_bytes`` (by its size). The file is opened first and
    checked through its descriptor, so it cannot be swapped between check and read.
    ``follow_links=False``: a symbolic link at ``path`` is refused too (``O_NOFOLLOW``),
    for a file the program wrote itself and that should never be a link (a bag's MCAP).

    Raises:
        IsADirectoryError: a folder; FileNotFoundError and other OSError: unreadable, or
            (``follow_links=False``) a symbolic link (ELOOP, naming it).
        ValueError: not a regular file, or larger than ``max_bytes``.
    """
    flags = os.O_RDONLY | os.O_NONBLOCK  # a FIFO must not block the open
    if not follow_links:
        flags |= os.O_NOFOLLOW
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        if exc.errno == errno.ELOOP and not follow_links:
            raise OSError(errno.ELOOP, "is a symbolic link: not read", str(path)) from None
        raise
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(errno.EISDIR, "is a folder, not a file", str(path))
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"{path}: not a regular file (a device, a pipe or a socket)")
        if st.st_size > max_bytes:
            raise ValueError(
                f"{path}: {st.st_size} bytes, longer than {max_bytes} bytes, not a file vigil reads"
            )
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def open_write(path: str | os.PathLike, mode: str = "w", encoding: str | None = None) -> IO[Any]:
    """Open a file the program writes: ``"w"``/``"wb"`` create or truncate it,
    ``"a"``/``"ab"`` create or append; never through a symbolic link (a link at
    ``path``, left there by mistake or by someone else, is an OSError naming it, not a
    write to wherever it points). Text modes default to UTF-8.

    Raises:
        OSError: ``path`` is a symbolic link (ELOOP), a folder, or cannot be written.
        ValueError: a mode other than these four.
    """
    if mode not in ("w", "wb", "a", "ab"):
        raise ValueError(f"open_write mode {mode!r}: one of w, wb, a, ab")
    flags = os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC
    flags |= os.O_APPEND if mode.startswith("a") else os.O_TRUNC
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OSError(
                errno.ELOOP, "is a symbolic link: not written through", str(path)
            ) from None
        raise
    try:
        if "b" in mode:
            return os.fdopen(fd, mode)
        return os.fdopen(fd, mode, encoding=encoding or "utf-8")
    except BaseException:
        os.close(fd)
        raise


def write_text(path: str | os.PathLike, text: str, encoding: str | None = None) -> None:
    """``Path.write_text`` through :func:`open_write` (no symbolic link followed)."""
    with open_write(path, "w", encoding) as f:
        f.write(text)


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """``Path.write_bytes`` through :func:`open_write` (no symbolic link followed)."""
    with open_write(path, "wb") as f:
        f.write(data)


def read_bytes_capped(path: str | os.PathLike, max_bytes: int = MAX_FILE_BYTES) -> bytes:
    """A regular file's bytes, at most ``max_bytes`` (see :func:`open_regular`); a file
    that grows past the cap while read is refused too.

    Raises:
        OSError: unreadable, or a folder.
        ValueError: not a regular file, or longer than ``max_bytes``.
    """
    with open_regular(path, max_bytes) as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise ValueError(f"{path}: longer than {max_bytes} bytes, not a file vigil reads")
    return data


def read_text_capped(path: str | Path, max_bytes: int = MAX_FILE_BYTES) -> str:
    """A text file's content, refusing one longer than ``max_bytes`` before reading it all
    (``/dev/zero``, a log passed by mistake) and anything but a regular file (a device,
    a named pipe): never an unbounded allocation, never a read that blocks for ever.

    Raises:
        OSError: unreadable, or a directory.
        ValueError: not a regular file, longer than ``max_bytes``, or not UTF-8 text.
    """
    data = read_bytes_capped(path, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


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
