"""The ceiling camera rendered on a thread of its own, for the real-time twin.

Rendering a frame on the CPU (Mesa's rasteriser) takes 35-100 ms, two to five control
periods. Rendered on the bridge's thread it holds the physics back; here the bridge
only *captures* the scene at a camera time (:meth:`AsyncCamera.capture`: MuJoCo's
``mjv_updateScene``, CPU only, well under a millisecond) and goes on stepping while this
thread rasterises it (the rasteriser runs without Python's lock); the finished frame is
collected later (:meth:`AsyncCamera.collect`) and published stamped with the time it was
captured at, as a real camera stamps its exposure. A frame due while the last one is
still being rendered is not captured: the camera drops it, as a real camera's driver
drops what it cannot send, and the bridge counts it.

The renderer and its GL context belong to this thread (EGL binds a context to the thread
that made it current): it is made, used and closed here. Pure code, no rclpy.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

Frame = tuple[float, np.ndarray]  # (capture time [s], (H, W, 3) uint8 RGB)


class AsyncCamera:
    """One renderer on a worker thread; one frame in flight at most.

    Args:
        make_renderer: called on the worker thread, returns an object with
            ``update_scene(data, camera=...)``, ``render()`` and ``close()``
            (``mujoco.Renderer``).
        camera: the camera's id or name for ``update_scene``.
    """

    def __init__(self, make_renderer: Callable[[], Any], camera: Any):
        self._camera = camera
        self._jobs: queue.Queue[float | None] = queue.Queue()
        self._done: queue.Queue[Frame | BaseException] = queue.Queue()
        self._ready = threading.Event()
        self._busy = False
        self._renderer: Any = None
        self._error: BaseException | None = None
        # the render times (wall clock) in 0.1 ms bins, and the longest: a run of hours
        # keeps a few thousand counts, not a list it must sort
        self._render_bins: Counter[int] = Counter()
        self._render_max_s = 0.0
        self._stats_lock = threading.Lock()
        self._thread = threading.Thread(
            target=self._run, args=(make_renderer,), name="camera-render", daemon=True
        )
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            raise self._error

    def render_ms(self) -> tuple[float, float] | None:
        """The median render time (to 0.1 ms) and the longest, in milliseconds; None
        before the first frame."""
        with self._stats_lock:
            bins, longest = sorted(self._render_bins.items()), self._render_max_s
        n = sum(c for _, c in bins)
        if not n:
            return None
        seen = 0
        for b, c in bins:  # the bin of the (n // 2)-th time, as sorted(times)[n // 2]
            seen += c
            if seen > n // 2:
                return b / 10.0, longest * 1e3
        raise AssertionError("unreachable")

    @property
    def busy(self) -> bool:
        """A frame is being rendered (or waits to be collected)."""
        return self._busy

    def capture(self, data: Any, t_s: float) -> bool:
        """Take the scene of ``data`` (the caller's thread, which owns it) at time
        ``t_s`` and render it on the worker; False (nothing taken) while busy."""
        if self._busy:
            return False
        self._renderer.update_scene(data, camera=self._camera)
        self._busy = True
        self._jobs.put(t_s)
        return True

    def collect(self, wait: bool = False) -> Frame | None:
        """The finished frame, or None (none in flight, or not finished and not
        ``wait``). Raises what the render raised."""
        if not self._busy:
            return None
        try:
            item = self._done.get(block=wait)
        except queue.Empty:
            return None
        self._busy = False
        if isinstance(item, BaseException):
            raise item
        return item

    def close(self) -> None:
        """Finish the frame in flight, then close the renderer on its thread."""
        if self._thread.is_alive():
            self._jobs.put(None)
            self._thread.join(timeout=10.0)

    def _run(self, make_renderer: Callable[[], Any]) -> None:
        try:
            self._renderer = make_renderer()
        except BaseException as err:  # noqa: BLE001 - handed to the constructor
            self._error = err
            self._ready.set()
            return
        self._ready.set()
        try:
            while (t_s := self._jobs.get()) is not None:
                try:
                    t0 = time.monotonic()
                    rgb = self._renderer.render().copy()
                    took = time.monotonic() - t0
                    with self._stats_lock:
                        self._render_bins[round(took * 1e4)] += 1
                        self._render_max_s = max(self._render_max_s, took)
                    self._done.put((t_s, rgb))
                except BaseException as err:  # noqa: BLE001 - handed to collect()
                    self._done.put(err)
        finally:
            self._renderer.close()


class LensBlur:
    """A renderer whose images pass through the lens's blur: a Gaussian of ``sigma_px``
    pixels (OpenCV), as a real camera's optics soften edges. Wraps ``mujoco.Renderer``
    (``update_scene``, ``render``, ``close`` and the rest pass through)."""

    def __init__(self, renderer: Any, sigma_px: float):
        self._renderer = renderer
        self.sigma_px = float(sigma_px)

    def render(self, *args: Any, **kwargs: Any) -> np.ndarray:
        return cv2.GaussianBlur(self._renderer.render(*args, **kwargs), (0, 0), self.sigma_px)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._renderer, name)
