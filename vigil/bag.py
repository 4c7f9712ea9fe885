"""A run's rosbag2 bag (MCAP storage), written with the ``rosbags`` library: no rclpy here.

:class:`BagWriter` takes messages as CDR bytes (as a raw ROS subscription hands them
over) with the ROS type name and a log time, and writes a rosbag2 folder (``metadata.yaml``
+ ``<name>.mcap``) that ``rosbags`` and Foxglove read. The message definitions come
from the ``rosbags`` typestore of ROS 2 Jazzy (standard types) and from the ``.msg`` files
under ``interfaces/`` (vigil_interfaces, and tf2_msgs where the store lacks one), so each
connection carries its schema.

:class:`RateLimit` keeps a topic to at most one message per period of log time (the
camera's frames: about 900 kB each at full rate would make the bag the run's largest file
by far).

The writer never touches a path it did not create: an existing bag folder (or a symbolic
link under its name, dangling or not) is an error (``mkdir`` makes the bag's folder,
and fails on any entry under the name), and ``metadata.yaml`` is written at the close
only into the very folder it made (not one swapped in under the name since, nor
through a link planted inside it). The folder a bag goes in is the run folder, which
:func:`vigil.run_folder.fresh_run_dir` checks is the user's and not writable by others.
A bag left unclosed (its writer killed) is salvaged by :mod:`vigil.bag_salvage`.

:func:`read_recording` reads a lock-step run's bag back split by ``/lockstep/tick`` (the
bag node writes one before each tick's messages), for ``vigil replay-bag``.
"""

from __future__ import annotations

import errno
import importlib
import os
import shutil
import stat
from dataclasses import dataclass, field
from pathlib import Path

from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

import stack.topics as topic
from stack.files import refuse_link
from vigil.ending import allocate

REPO = Path(__file__).resolve().parents[1]
INTERFACES = REPO / "interfaces"
BAG_DIR = "bag"  # the bag's folder inside a run folder


class BagError(ValueError):
    """A message the bag cannot take (unknown type, undeclared topic)."""


def fresh_path(folder: Path, name: str = BAG_DIR) -> Path:
    """``folder/name``, or ``name_1``, ``name_2``... if taken (a restarted recorder; a
    symbolic link under the name, even a dangling one, takes it too)."""
    path, n = Path(folder) / name, 0
    while os.path.lexists(path):
        n += 1
        path = Path(folder) / f"{name}_{n}"
    return path


def message_class(type_name: str):
    """``pkg/msg/Name`` -> the generated Python class (ImportError, AttributeError or
    ValueError when there is none)."""
    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def typestore(interfaces: Path = INTERFACES) -> Typestore:
    """Jazzy's standard types plus every ``<pkg>/msg/<Name>.msg`` under ``interfaces``
    that the store does not already hold."""
    store = get_typestore(Stores.ROS2_JAZZY)
    extra: dict = {}
    for path in sorted(interfaces.glob("*/msg/*.msg")):
        name = f"{path.parents[1].name}/msg/{path.stem}"
        if name not in store.fielddefs:
            extra.update(get_types_from_msg(path.read_text(), name))
    if extra:
        store.register(extra)
    return store


class RateLimit:
    """At most one message per ``period_ns`` of log time (0: every message)."""

    def __init__(self, period_ns: int):
        if period_ns < 0:
            raise ValueError(f"rate limit period must be >= 0, got {period_ns} ns")
        self.period_ns = period_ns
        self.last_ns: int | None = None

    def admit(self, t_ns: int) -> bool:
        if self.last_ns is not None and 0 <= t_ns - self.last_ns < self.period_ns:
            return False
        self.last_ns = t_ns
        return True


class BagWriter:
    """One rosbag2 bag (MCAP) at ``path``, which must not exist yet (FileExistsError).

    Args:
        path: the bag's folder (created here).
        store: the typestore holding every type to be written (:func:`typestore`).
        compress: zstd-compress the MCAP's chunks (MCAP's own chunk compression, which
            Foxglove, ``rosbags`` and ``ros2 bag`` read; the messages stay CDR).
    """

    def __init__(
        self,
        path: Path,
        store: Typestore | None = None,
        compress: bool = True,
        reserve_bytes: int = 0,
    ):
        path = Path(path)
        if os.path.islink(path):
            raise FileExistsError(f"bag {path} is a symbolic link: not writing through it")
        if os.path.lexists(path):
            raise FileExistsError(f"bag {path} already exists: not overwriting it")
        self.path = path
        # room for the summary and metadata.yaml on a disk that fills up (freed by close)
        reserve = path.with_name(f".{path.name}.reserve")
        # only a reserve this writer made is removed by close (never a file it found)
        self.reserve = reserve if reserve_bytes > 0 and allocate(reserve, reserve_bytes) else None
        self.store = store if store is not None else typestore()
        self.writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        if compress:
            self.writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self.writer.open()  # mkdir: fails on any entry under the name, a link too
        made = os.lstat(path)
        self._made = (made.st_dev, made.st_ino)  # the folder this writer made
        self.connections: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self.closed = False

    def add_topic(self, topic: str, msgtype: str) -> None:
        """Declare a topic with its ROS type (``pkg/msg/Name``)."""
        if topic in self.connections:
            return
        if msgtype not in self.store.fielddefs:
            raise BagError(f"topic {topic}: no message definition for type {msgtype!r}")
        self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        self.counts[topic] = 0

    def write(self, topic: str, t_ns: int, cdr: bytes) -> None:
        """One message (CDR bytes) at log time ``t_ns``; the topic must be declared."""
        if self.closed:
            return
        conn = self.connections.get(topic)
        if conn is None:
            raise BagError(f"topic {topic} was not declared with add_topic")
        self.writer.write(conn, int(t_ns), bytes(cdr))
        self.counts[topic] += 1

    def close(self) -> None:
        """Write the MCAP summary and metadata.yaml; safe to call twice. The reserve (if
        any) is freed first: a bag whose disk filled up still gets its index.

        Raises:
            OSError: the bag's folder is no longer the one this writer made (replaced by
                another folder or a symbolic link), or ``metadata.yaml`` (or rosbags'
                ``metadata.yaml.tmp``) in it is a symbolic link: ``rosbags`` writes
                those by name and would follow the link. The MCAP, written through its
                open descriptor, is then closed without its summary (``vigil
                bag-reindex`` salvages it) and nothing more is written.
        """
        if not self.closed:
            self.closed = True
            if self.reserve is not None:
                self.reserve.unlink(missing_ok=True)
            try:
                self._check_folder()
            except OSError:
                self.writer.abort()
                raise
            self.writer.close()

    def discard(self) -> None:
        """Drop a bag that must not be kept (a failed salvage): the writer is aborted,
        and the reserve and the bag's folder are removed, the folder only while it is
        still the one this writer made (never one swapped in under its name)."""
        if not self.closed:
            self.closed = True
            if self.reserve is not None:
                self.reserve.unlink(missing_ok=True)
            self.writer.abort()
        if self._own_folder():
            shutil.rmtree(self.path, ignore_errors=True)

    def _own_folder(self) -> bool:
        try:
            st = os.lstat(self.path)
        except FileNotFoundError:
            return False
        return stat.S_ISDIR(st.st_mode) and (st.st_dev, st.st_ino) == self._made

    def _check_folder(self) -> None:
        if not self._own_folder():
            raise OSError(
                errno.ELOOP,
                "is no longer the folder this bag writer made (moved, or replaced by another"
                " folder or a symbolic link): metadata.yaml not written",
                str(self.path),
            )
        for name in ("metadata.yaml", "metadata.yaml.tmp"):
            refuse_link(self.path / name, "metadata.yaml not written through it")


# -- reading a run's bag for a replay (vigil replay-bag) ----------------------------
class ReplayError(RuntimeError):
    """The run folder or its bag cannot be replayed (names the file and the reason)."""


@dataclass
class Tick:
    """One recorded lock-step tick: its time and the messages the bag got in it."""

    t_ns: int
    messages: list[tuple[str, bytes]] = field(default_factory=list)  # (topic, CDR)


@dataclass
class Recording:
    """A bag read for a replay.

    Attributes:
        before: messages received before the first tick (latched ones: /map, /tf_static).
        ticks: the ticks in order.
        types: topic -> its recorded ROS type (``pkg/msg/Name``).
    """

    before: list[tuple[str, bytes]]
    ticks: list[Tick]
    types: dict[str, str]

    def count(self, name: str) -> int:
        return sum(t == name for t, _ in self.before) + sum(
            t == name for tick in self.ticks for t, _ in tick.messages
        )


def _clock_ns(cdr: bytes) -> int:
    """A rosgraph_msgs/Clock's time from its CDR bytes (4-byte header, sec, nanosec)."""
    if len(cdr) < 12:
        raise ValueError(f"a /lockstep/tick record of {len(cdr)} bytes")
    order = "little" if cdr[1] in (1, 3) else "big"
    sec = int.from_bytes(cdr[4:8], order, signed=True)
    nsec = int.from_bytes(cdr[8:12], order)
    return sec * 1_000_000_000 + nsec


def read_recording(bag: Path) -> Recording:
    """Every message of the bag, split by lock-step tick.

    Raises:
        ReplayError: the bag cannot be read, or it has no lock-step ticks (it was
            recorded without lock-step, e.g. on a robot: no deterministic replay then).
    """
    from rosbags.rosbag2 import Reader

    before: list[tuple[str, bytes]] = []
    ticks: list[Tick] = []
    types: dict[str, str] = {}
    try:
        with Reader(bag) as reader:
            for conn in reader.connections:
                types[conn.topic] = conn.msgtype
            for conn, _t, raw in reader.messages():
                if conn.topic == topic.LOCKSTEP_TICK:
                    ticks.append(Tick(_clock_ns(bytes(raw))))
                elif ticks:
                    ticks[-1].messages.append((conn.topic, bytes(raw)))
                else:
                    before.append((conn.topic, bytes(raw)))
    except ReplayError:
        raise
    except Exception as err:  # rosbags' ReaderError, a truncated MCAP, bad YAML...
        raise ReplayError(f"{bag}: the bag cannot be read: {type(err).__name__}: {err}") from err
    if not ticks:
        raise ReplayError(
            f"{bag} has no {topic.LOCKSTEP_TICK} records: it was recorded without lock-step "
            "(or by an older vigil), so it cannot be replayed deterministically"
        )
    return Recording(before, ticks, types)
