"""Reading and writing files safely, whoever names them (issues 13 and 23).

Reading: :func:`open_regular`, :func:`read_bytes_capped`, :func:`read_text_capped` take a
regular file only (checked on the open descriptor: a device, a pipe, a socket or a
folder is refused before a byte is read) and only up to a size cap.

Writing: every file the program creates or truncates is opened without following a
symbolic link. :func:`open_write` (and :func:`write_text`, :func:`write_bytes`,
:func:`save_figure` for matplotlib) opens with ``O_NOFOLLOW``; a file a library or a
process writes by name (ffmpeg, espeak-ng, openssl) goes through
:class:`PrivateOutput`: written in a fresh folder of its own, then renamed into place
(:func:`replace_into`). Either way a link at the file's name is an OSError naming it,
never a write to wherever it points. :func:`make_dir` makes a subfolder, refusing a
link under its name.
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
import stat
from pathlib import Path
from typing import IO, Any, BinaryIO

MAX_FILE_BYTES = 16 * 2**20  # no configuration, task, map or state file is near this
# a run's own records (trace, steps, speech log, detections): hours of a run at 25 Hz
MAX_RECORD_BYTES = 1024 * 2**20


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


def _link_error(path: str | os.PathLike, what: str) -> OSError:
    return OSError(errno.ELOOP, f"is a symbolic link: {what}", str(path))


def refuse_link(path: str | os.PathLike, what: str = "not written through") -> None:
    """Raise OSError (ELOOP, naming ``path``) if ``path`` itself is a symbolic link."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        raise _link_error(path, what)


def make_dir(path: str | os.PathLike, mode: int = 0o755) -> Path:
    """A folder the program makes inside one it made (``logs/``, ``speech/``): created if
    absent (its parent must exist: no chain of folders is made through a link), used
    if it is a folder already; a symbolic link under the name is refused, so that what
    is written "into" it never lands wherever the link points.

    Raises:
        OSError: ``path`` is a symbolic link (ELOOP, naming it), a file (ENOTDIR), or
            its parent does not exist.
    """
    path = Path(path)
    try:
        os.mkdir(path, mode)
    except FileExistsError:
        st = os.lstat(path)
        if stat.S_ISLNK(st.st_mode):
            raise _link_error(path, "not used as a folder") from None
        if not stat.S_ISDIR(st.st_mode):
            raise NotADirectoryError(errno.ENOTDIR, "is not a folder", str(path)) from None
    return path


def replace_into(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Move the file ``src`` to ``dst`` (same file system) with rename(2), which replaces
    the directory entry ``dst`` and never writes through it; a symbolic link already at
    ``dst`` is refused (OSError ELOOP naming it) rather than replaced, as
    :func:`open_write` refuses one. (A link planted between the check and the rename
    is replaced by the file, its target still untouched.)"""
    refuse_link(dst)
    os.replace(src, dst)


def write_atomic(path: str | os.PathLike, text: str) -> None:
    """Replace the text file ``path`` whole: written beside it as ``<name>.tmp``
    (:func:`write_text`), then renamed over it (:func:`replace_into`), so a crash
    mid-write leaves the old file intact and a reader never sees half of one."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    write_text(tmp, text)
    replace_into(tmp, path)


class PrivateOutput:
    """A file written by name by a library or a process that would follow a link there
    (ffmpeg, espeak-ng, openssl), then moved into place.

    :attr:`path` (named as the target, so a suffix still picks the format) lies in a
    folder made here beside the target, mode 0700, under a random name: ``mkdir`` fails
    on any existing entry, link or not, so nothing can have been planted in it.
    :meth:`commit` moves the file to the target with :func:`replace_into` (rename(2):
    never through a link; a link already at the target is refused); :meth:`discard`
    drops it. Either removes the folder and whatever is in it (``shutil.rmtree``
    works through descriptors and never follows a link). As a context manager: commit
    on a clean exit, discard on an exception (nothing then reaches the target). A
    process killed meanwhile leaves the hidden folder ``.<name>.<random>.part``.

    Raises:
        OSError: the target is a symbolic link (ELOOP, naming it; checked here, before
            the work, and again by :meth:`commit`), or the folder cannot be made.
    """

    def __init__(self, target: str | os.PathLike):
        self.target = Path(target)
        refuse_link(self.target)
        self._folder = self.target.with_name(f".{self.target.name}.{secrets.token_hex(6)}.part")
        os.mkdir(self._folder, 0o700)
        self.path = self._folder / self.target.name
        self.done = False

    def commit(self) -> Path:
        """Move the written file to the target (FileNotFoundError if none was written)."""
        if not self.done:
            self.done = True
            try:
                replace_into(self.path, self.target)
            finally:
                shutil.rmtree(self._folder, ignore_errors=True)
        return self.target

    def discard(self) -> None:
        if not self.done:
            self.done = True
            shutil.rmtree(self._folder, ignore_errors=True)

    def __enter__(self) -> PrivateOutput:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


def save_figure(fig: Any, path: str | os.PathLike, **kwargs: Any) -> Path:
    """``fig.savefig(path, **kwargs)`` into a file opened by :func:`open_write` (matplotlib
    itself opens the name and follows a link there); the format is the suffix's."""
    path = Path(path)
    kwargs.setdefault("format", path.suffix.lstrip(".").lower() or "png")
    with open_write(path, "wb") as f:
        fig.savefig(f, **kwargs)
    return path


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
