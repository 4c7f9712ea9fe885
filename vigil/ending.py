"""How a ``vigil run`` or ``vigil launch`` ended: the first cause in one line, an exit
code per cause, and ``run.json`` written whatever happened (docs/SAFETY.md, "Endings").

The first cause wins: a node that dies while the others are being stopped after a
SIGTERM does not hide the SIGTERM, and a report that cannot be written after the disk
filled up does not hide the disk.

A full disk: the run folder holds :data:`RESERVE_FILE` (:data:`RESERVE_BYTES`, allocated
when the run starts) which is deleted once the nodes have stopped, so that ``run.json``
(written in place, never through a link) and what report fits can still be written.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# exit codes of `vigil run` and `vigil launch` (docs/SAFETY.md, "Endings")
EXIT_OK = 0
EXIT_INTERNAL = 1  # vigil itself failed (a traceback): a bug
EXIT_BAD_INPUT = 2  # refused before any process started (one line naming the key)
EXIT_NODE = 3  # a node died, was killed or failed (its name in the cause)
EXIT_STALLED = 4  # the lock-step stalled for good (what it waited for in the cause)
EXIT_TIMEOUT = 5  # vigil run's --timeout passed before the last step
EXIT_DISK_FULL = 6  # no space left on the run folder's disk (a node's or vigil's write)
EXIT_REPORT = 7  # the run finished but its report could not be written
EXIT_SIGHUP = 128 + signal.SIGHUP  # 129: the terminal went away
EXIT_SIGINT = 128 + signal.SIGINT  # 130: Ctrl-C
EXIT_SIGTERM = 128 + signal.SIGTERM  # 143: kill, systemd, a CI job's cancel

KINDS = {
    "finished": EXIT_OK,
    "stopped": EXIT_OK,  # vigil launch stopped by SIGINT or SIGTERM, every node clean
    "internal": EXIT_INTERNAL,
    "bad input": EXIT_BAD_INPUT,
    "node": EXIT_NODE,
    "stalled": EXIT_STALLED,
    "timeout": EXIT_TIMEOUT,
    "disk full": EXIT_DISK_FULL,
    "report": EXIT_REPORT,
    "SIGHUP": EXIT_SIGHUP,
    "SIGINT": EXIT_SIGINT,
    "SIGTERM": EXIT_SIGTERM,
}
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)

RUN_FILE = "run.json"
RESERVE_FILE = ".vigil-reserve"
RESERVE_BYTES = 4 << 20  # run.json, the report's tables and a bag's index fit in it


@dataclass
class Ending:
    """The first cause of a run's end: its kind (a key of :data:`KINDS`) and one line."""

    kind: str
    cause: str

    @property
    def code(self) -> int:
        return KINDS[self.kind]


def is_disk_full(err: BaseException) -> bool:
    return isinstance(err, OSError) and err.errno in DISK_FULL_ERRNOS


def one_line(text: str, limit: int = 400) -> str:
    return " ".join(str(text).split())[:limit]


class Signals:
    """SIGINT, SIGTERM and SIGHUP while a run is under way (main thread only).

    Before :meth:`watching` a signal raises :class:`Interrupted` (the run is being
    prepared: nothing to stop yet but the preparation); while watching it only sets
    :attr:`first` (the watch loop sees it between two polls, so the launcher is never
    cut in the middle of starting or stopping a process); after :meth:`cleaning` it is
    noted and ignored, so that the nodes are stopped, the bag closed and ``run.json``
    written. :meth:`restore` puts the previous handlers back.
    """

    def __init__(self) -> None:
        self.first: str | None = None
        self.raising = True
        self._old: dict[int, Any] = {}
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._old[sig] = signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:
        name = signal.Signals(signum).name
        if self.first is None:
            self.first = name
            if self.raising:
                raise Interrupted(name)

    def watching(self) -> None:
        self.raising = False

    def cleaning(self) -> None:
        self.raising = False

    def restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()


class Interrupted(Exception):  # noqa: N818 (a signal, not an error)
    """A signal arrived while the run was being prepared."""

    def __init__(self, name: str):
        super().__init__(name)
        self.name = name


def from_launcher(launcher) -> Ending | None:
    """The ending a :class:`vigil.launch.Launcher`'s first failure stands for (None if no
    node failed): a full disk, a stalled lock-step or a node's death."""
    first = launcher.first_failure
    if first is None:
        return None
    name, rc, line = first
    from stack.exits import EXIT_DISK_FULL as NODE_DISK_FULL
    from stack.exits import EXIT_STALLED as BRIDGE_STALLED

    if rc == NODE_DISK_FULL:
        return Ending("disk full", f"disk full: {line}")
    if name in ("twin_bridge", "container") and rc == BRIDGE_STALLED:  # vigil.container
        return Ending("stalled", line)
    return Ending("node", line)


def allocate(path: Path, size: int) -> bool:
    """A new file of ``size`` allocated bytes, never through a link (best effort: a
    disk already full leaves it short); False when it could not be created."""
    try:
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW
        fd = os.open(path, flags, 0o600)
    except OSError:
        return False
    try:
        os.posix_fallocate(fd, 0, size)
    except OSError:
        pass
    finally:
        os.close(fd)
    return True


_RESERVED: set[Path] = set()  # reserve files this process made (release removes only those)


def reserve(run_dir: Path, size: int = RESERVE_BYTES) -> None:
    """Allocate :data:`RESERVE_FILE` in the run folder (best effort: a disk already
    full has nothing to reserve)."""
    path = run_dir / RESERVE_FILE
    if allocate(path, size):
        _RESERVED.add(path)


def release(run_dir: Path) -> None:
    """Free the run folder's reserve, if :func:`reserve` made it (a file of that name
    vigil did not create is never removed)."""
    path = run_dir / RESERVE_FILE
    if path not in _RESERVED:
        return
    _RESERVED.discard(path)
    try:
        os.unlink(path)
    except OSError:
        pass


def write_in_place(path: Path, text: str) -> None:
    """Write ``path`` without following a link and, when it exists, over its own blocks
    (no truncation first: on a full disk the new text fits where the old one was)."""
    data = text.encode()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        os.ftruncate(fd, len(data))
        os.fsync(fd)
    finally:
        os.close(fd)


def write_run_json(run_dir: Path, record: dict, say: Callable[[str], None]) -> bool:
    """``run.json``; False (and one line said) when even that cannot be written."""
    try:
        write_in_place(run_dir / RUN_FILE, json.dumps(record, indent=2, sort_keys=True) + "\n")
        return True
    except OSError as err:
        say(f"[run] {RUN_FILE} not written: {one_line(str(err))}")
        return False


def operator_stop(name: str) -> Ending:
    """``vigil launch``: SIGINT and SIGTERM are an operator's stop (exit 0 when the nodes
    leave cleanly); SIGHUP (the terminal went away) is not."""
    if name == "SIGHUP":
        return Ending(name, f"{name}: the terminal went away")
    return Ending("stopped", f"{name}: stopped by the operator")
