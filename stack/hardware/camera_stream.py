"""Frames from the real ceiling camera (AXIS P1344) through OpenCV (pure, no rclpy).

:class:`CameraStream` opens an RTSP or HTTP MJPEG URL, a local device index (``"0"``) or a
video file with ``cv2.VideoCapture`` and hands out RGB frames. Stream trouble never
raises: :meth:`CameraStream.read` returns a :class:`StreamProblem` that says what is
wrong, and the stream reopens itself ``reconnect_s`` after a failure. A stream that
keeps delivering byte-identical frames (a stalled encoder or proxy re-sending its last
buffer) counts as frozen and is reopened too.

YAML section ``camera_stream:`` (``url`` is required, the rest optional)::

    camera_stream:
      url: "rtsp://user:pass@192.168.0.90/axis-media/media.amp?fps=10&resolution=640x480"
      rate_hz: 10.0             # frames read per second by the node
      width_px: 0               # 0 and 0: as delivered; both > 0: resized to this size
      height_px: 0
      reconnect_s: 2.0          # wait after a failure before reopening [s]
      frozen_after_frames: 20   # this many byte-identical consecutive frames = frozen; 0: off
      open_timeout_s: 5.0       # bound on opening (and on one read, FFmpeg backend) [s]

User names and passwords in a URL never appear in messages (:func:`redact_url`).

Camera calibration (:func:`load_calibration`): a YAML file with ``width``, ``height``,
``K`` (9 numbers, row-major), ``D``, ``distortion_model`` and optionally ``R`` (9) and
``P`` (12); the files written by ROS ``camera_calibration`` (``image_width``,
``camera_matrix: {data: [...]}``, ...) are read too.
"""

from __future__ import annotations

import hashlib
import math
import re
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from stack.cells import ConfigError
from stack.config import Config, load_yaml


@dataclass(frozen=True)
class StreamConfig(Config):
    """Where the frames come from and how they are read (see the module docstring)."""

    section = "camera_stream"  # errors name keys "camera_stream.<field>"

    url: str = ""  # required: a URL, a device index ("0") or a file
    rate_hz: float = 10.0
    width_px: int = 0
    height_px: int = 0
    reconnect_s: float = 2.0
    frozen_after_frames: int = 20
    open_timeout_s: float = 5.0

    _rules = {
        "url": (lambda u: bool(u.strip()), "must name a URL, a device index or a file"),
        "rate_hz": (lambda v: v > 0, "must be > 0"),
        "reconnect_s": (lambda v: v > 0, "must be > 0"),
        "open_timeout_s": (lambda v: v > 0, "must be > 0"),
        "width_px": (lambda v: v >= 0, "must be >= 0"),
        "height_px": (lambda v: v >= 0, "must be >= 0"),
        "frozen_after_frames": (lambda v: v == 0 or v >= 2, "must be 0 (off) or >= 2"),
    }

    def check(self) -> None:
        if (self.width_px == 0) != (self.height_px == 0):
            raise ConfigError(
                "width_px",
                (self.width_px, self.height_px),
                "width_px and height_px are both 0 (as delivered) or both > 0",
            )

    @property
    def source(self) -> str | int:
        """What VideoCapture opens: an int for a device index, else the URL or path."""
        u = self.url.strip()
        return int(u) if u.isdigit() else u


@dataclass(frozen=True)
class StreamFrame:
    """One frame: ``rgb`` is (H, W, 3) uint8; ``seq`` counts delivered frames from 1."""

    rgb: np.ndarray = field(repr=False)
    seq: int
    stamp_s: float  # the stream's clock when it was read [s]


@dataclass(frozen=True)
class StreamProblem:
    """Why there is no frame. ``kind``: cannot_open, read_failed or frozen."""

    kind: str
    message: str
    since_s: float  # when it began (the stream's clock) [s]
    retry_at_s: float  # when the stream is reopened [s]


Capture = Any  # a cv2.VideoCapture or anything with isOpened(), read(), release()


def redact_url(url: str) -> str:
    """``rtsp://user:pass@host/x`` -> ``rtsp://***@host/x``: no secrets in logs."""
    return re.sub(r"(?<=://)[^/@]*@", "***@", url)


class CameraStream:
    """Reads frames, reports problems, reopens after ``reconnect_s``; never raises on the stream.

    Args:
        config: the stream.
        capture_factory: called as ``capture_factory(source, cv2.CAP_ANY, params)``, like
            the ``cv2.VideoCapture`` constructor (params carry the open/read timeouts).
        clock: monotonic seconds (injectable for tests).
    """

    def __init__(
        self,
        config: StreamConfig,
        capture_factory: Callable[..., Capture] = cv2.VideoCapture,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.config = config
        self._factory = capture_factory
        self._clock = clock
        self._cap: Capture | None = None
        self._next_open_s = -math.inf
        self._problem: StreamProblem | None = None
        self._seq = 0
        self._last_digest: bytes | None = None
        self._same = 0
        self.opens = 0  # successful opens so far

    @property
    def problem(self) -> StreamProblem | None:
        """The current problem (None while frames arrive)."""
        return self._problem

    @property
    def is_open(self) -> bool:
        return self._cap is not None

    @property
    def frames(self) -> int:
        """Frames delivered so far."""
        return self._seq

    def read(self) -> StreamFrame | StreamProblem:
        """The next frame, or the problem in force (opening or reopening when it is time)."""
        now = self._clock()
        if self._cap is None:
            if now < self._next_open_s and self._problem is not None:
                return self._problem
            failed = self._open()
            if failed is not None:
                return self._fail("cannot_open", failed, now)
        assert self._cap is not None  # opened above
        try:
            ok, frame = self._cap.read()
        except Exception as exc:  # a backend error is stream trouble
            ok, frame = False, exc
        if not ok or not isinstance(frame, np.ndarray) or frame.size == 0:
            detail = f" ({frame})" if isinstance(frame, Exception) else ""
            return self._fail(
                "read_failed",
                f"read failed{detail}, reconnecting in {self.config.reconnect_s:.1f} s",
                now,
            )
        n = self.config.frozen_after_frames
        if n:
            digest = hashlib.blake2b(frame.tobytes(), digest_size=16).digest()
            digest += repr(frame.shape).encode()
            self._same = self._same + 1 if digest == self._last_digest else 1
            self._last_digest = digest
            if self._same >= n:
                return self._fail("frozen", f"frozen: {n} identical frames", now)
        try:
            rgb = self._to_rgb(frame)
        except (cv2.error, ValueError) as exc:
            return self._fail("read_failed", f"bad frame {frame.shape}: {exc}", now)
        self._problem = None
        self._seq += 1
        return StreamFrame(rgb=rgb, seq=self._seq, stamp_s=now)

    def close(self) -> None:
        """Release the capture (the next read reopens it)."""
        if self._cap is not None:
            try:
                self._cap.release()
            except Exception:  # releasing a broken capture
                pass
        self._cap = None
        self._last_digest, self._same = None, 0

    # -- internals --------------------------------------------------------------
    def _open(self) -> str | None:
        """Open the capture; the failure message, or None when open."""
        ms = int(self.config.open_timeout_s * 1000)
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms]
        name = redact_url(self.config.url)
        try:
            cap = self._factory(self.config.source, cv2.CAP_ANY, params)
        except Exception as exc:  # never raise on stream trouble
            return f"cannot open {name}: {exc}"
        try:
            opened = bool(cap.isOpened())
        except Exception:  # a broken capture
            opened = False
        if not opened:
            try:
                cap.release()
            except Exception:  # already broken
                pass
            return f"cannot open {name}"
        self._cap = cap
        self.opens += 1
        return None

    def _fail(self, kind: str, message: str, now: float) -> StreamProblem:
        self.close()
        self._next_open_s = now + self.config.reconnect_s
        since = self._problem.since_s if self._problem is not None else now
        self._problem = StreamProblem(kind, message, since, self._next_open_s)
        return self._problem

    def _to_rgb(self, frame: np.ndarray) -> np.ndarray:
        if frame.dtype != np.uint8:
            raise ValueError(f"dtype {frame.dtype}, need uint8")
        if frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 1):
            rgb = cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
        elif frame.ndim == 3 and frame.shape[2] == 3:
            rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
        elif frame.ndim == 3 and frame.shape[2] == 4:
            rgb = cv2.cvtColor(frame, cv2.COLOR_BGRA2RGB)
        else:
            raise ValueError("not a grey, BGR or BGRA image")
        w, h = self.config.width_px, self.config.height_px
        if w and (rgb.shape[1], rgb.shape[0]) != (w, h):
            rgb = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(rgb)


# -- camera calibration ----------------------------------------------------------------
@dataclass(frozen=True)
class CameraCalibration:
    """Intrinsics for sensor_msgs/CameraInfo (row-major K 3x3, R 3x3, P 3x4)."""

    width: int
    height: int
    K: tuple[float, ...]
    D: tuple[float, ...] = ()
    distortion_model: str = "plumb_bob"
    R: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    P: tuple[float, ...] = ()  # empty: [K | 0]

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ConfigError("calibration.width", (self.width, self.height), "must be >= 1")
        for name, n in (("K", 9), ("R", 9)):
            if len(getattr(self, name)) != n:
                raise ConfigError(f"calibration.{name}", getattr(self, name), f"needs {n} numbers")
        if self.P and len(self.P) != 12:
            raise ConfigError("calibration.P", self.P, "needs 12 numbers")
        if not self.P:
            k = self.K
            object.__setattr__(self, "P", (*k[0:3], 0.0, *k[3:6], 0.0, *k[6:9], 0.0))

    def scaled(self, width: int, height: int) -> CameraCalibration:
        """The calibration of the same camera delivering ``width`` x ``height`` images."""
        if (width, height) == (self.width, self.height):
            return self
        sx, sy = width / self.width, height / self.height
        k, p = list(self.K), list(self.P)
        # focal lengths (and P's Tx, Ty) scale; centres follow cv2.resize's pixel centres
        for m, fx_i, fy_i, cx_i, cy_i in ((k, (0, 1), (4,), 2, 5), (p, (0, 1, 3), (5, 7), 2, 6)):
            for i in fx_i:
                m[i] *= sx
            for i in fy_i:
                m[i] *= sy
            m[cx_i] = (m[cx_i] + 0.5) * sx - 0.5
            m[cy_i] = (m[cy_i] + 0.5) * sy - 0.5
        return CameraCalibration(
            width, height, tuple(k), self.D, self.distortion_model, self.R, tuple(p)
        )


def _numbers(key: str, value: Any) -> tuple[float, ...]:
    if isinstance(value, Mapping):  # camera_calibration: {rows, cols, data}
        value = value.get("data")
    if isinstance(value, str | bytes) or not isinstance(value, list | tuple):
        raise ConfigError(key, value, "must be a list of numbers")
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
        raise ConfigError(key, value, "must be a list of numbers")
    out = tuple(float(v) for v in value)
    if not all(math.isfinite(v) for v in out):
        raise ConfigError(key, value, "must be finite")
    return out


def calibration_from_dict(data: Mapping[str, Any], key: str = "calibration") -> CameraCalibration:
    """Read our keys (width, height, K, D, distortion_model, R, P) or camera_calibration's.

    Raises:
        stack.cells.ConfigError: a missing or malformed value.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(key, data, "must be a mapping")
    aliases = {
        "width": ("width", "image_width"),
        "height": ("height", "image_height"),
        "K": ("K", "k", "camera_matrix"),
        "D": ("D", "d", "distortion_coefficients"),
        "R": ("R", "r", "rectification_matrix"),
        "P": ("P", "p", "projection_matrix"),
    }
    got: dict[str, Any] = {}
    for name, keys in aliases.items():
        for k in keys:
            if k in data:
                got[name] = data[k]
                break
    for name in ("width", "height", "K"):
        if name not in got:
            raise ConfigError(f"{key}.{name}", None, "is required")
    for name in ("width", "height"):
        v = got[name]
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"{key}.{name}", v, "must be an integer")
    kwargs: dict[str, Any] = {"width": got["width"], "height": got["height"]}
    for name in ("K", "D", "R", "P"):
        if name in got:
            kwargs[name] = _numbers(f"{key}.{name}", got[name])
    model = data.get("distortion_model", "plumb_bob")
    if not isinstance(model, str):
        raise ConfigError(f"{key}.distortion_model", model, "must be a string")
    kwargs["distortion_model"] = model
    return CameraCalibration(**kwargs)


def load_calibration(path: str | Path) -> CameraCalibration:
    """Read a calibration YAML file (see the module docstring).

    Raises:
        stack.cells.ConfigError: unreadable file or a bad value.
    """
    import yaml

    from stack.config import read_text_capped

    try:  # a regular file of at most 16 MB: /dev/zero grew the node to 3.6 GB
        data = load_yaml(read_text_capped(path))
    except (OSError, ValueError, yaml.YAMLError) as exc:
        text = " ".join(str(exc).split())
        raise ConfigError("camera_info_file", str(path), f"cannot be read: {text}") from None
    return calibration_from_dict(data, "camera_info_file")
