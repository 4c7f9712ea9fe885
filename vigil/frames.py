"""The run's camera frames as the recorder stores them: JPEG images in one file.

The recorder node writes one entry per trace record (``trace.jsonl``) while the run
goes on; the report (:mod:`vigil.report.video`) reads the file after the nodes have
stopped and composes the video from it. Encoding a JPEG costs about 2 ms a frame;
composing and encoding the video took the recorder about 10 ms a frame inside the
lock-step, and now happens after the run.

Format: the 8 bytes ``VGLFRM1\\n``, then per entry a little-endian header
(``t`` float64: the trace record's time [s]; ``n`` uint32: the JPEG's length, 0 for
"no frame at this record") followed by ``n`` bytes of JPEG (BGR order as OpenCV
writes it). A truncated last entry (a node killed mid-write) is ignored on reading.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np

from stack.config import open_write
from stack.files import open_regular

FRAMES_FILE = "camera_frames.bin"
MAGIC = b"VGLFRM1\n"
_HEADER = struct.Struct("<dI")


class FrameFileError(ValueError):
    """A frames file that is not one (the message names the file and the offset)."""


class FrameWriter:
    """Appends frames to a frames file (created with its magic if new).

    Args:
        path: the file.
        quality: JPEG quality 1-100.

    Raises:
        ValueError: a quality outside 1-100.
    """

    def __init__(self, path: str | Path, quality: int = 90):
        import cv2

        if not 1 <= int(quality) <= 100:
            raise ValueError(f"JPEG quality {quality!r} is not in 1..100")
        self._cv2 = cv2
        self._params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
        self.path = Path(path)
        new = not self.path.exists() or self.path.stat().st_size == 0
        self._f: BinaryIO | None = open_write(self.path, "ab")
        if new:
            self._f.write(MAGIC)
        self.frames = 0

    def add(self, t_s: float, frame_bgr: np.ndarray | None) -> None:
        """One entry: the frame (BGR uint8, as OpenCV holds images) or None."""
        if self._f is None:
            raise RuntimeError(f"{self.path} is closed")
        data = b""
        if frame_bgr is not None:
            ok, buf = self._cv2.imencode(".jpg", np.ascontiguousarray(frame_bgr), self._params)
            if ok:
                data = buf.tobytes()
        self._f.write(_HEADER.pack(float(t_s), len(data)) + data)
        self.frames += 1

    def flush(self) -> None:
        if self._f is not None:
            self._f.flush()

    def close(self) -> None:
        """Finish the file (safe to call twice)."""
        f, self._f = self._f, None
        if f is not None:
            f.close()


def read_frames(path: str | Path) -> Iterator[tuple[float, bytes]]:
    """(t, JPEG bytes or b"") per entry, in order; a truncated last entry is skipped.

    Raises:
        FrameFileError: the file does not start with the magic.
    """
    path = Path(path)
    with open_regular(path, max_bytes=2**50) as f:  # a device or a pipe never: streamed
        if f.read(len(MAGIC)) != MAGIC:
            raise FrameFileError(f"{path}: not a frames file (no {MAGIC!r} at offset 0)")
        while True:
            head = f.read(_HEADER.size)
            if len(head) < _HEADER.size:
                return
            t, n = _HEADER.unpack(head)
            data = f.read(n)
            if len(data) < n:
                return
            yield t, data


def decode(data: bytes) -> np.ndarray | None:
    """A frame's JPEG bytes as an RGB uint8 image (None for an empty entry)."""
    if not data:
        return None
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return None if img is None else img[:, :, ::-1]
