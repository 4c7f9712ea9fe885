"""The run's video, composed after the run from what the recorder stored.

The recorder node writes the camera frames as JPEG into ``camera_frames.bin``
(:mod:`vigil.frames`) beside ``trace.jsonl``; :func:`write_video` reads both once the
nodes have stopped and writes ``camera.mp4`` (H.264): on the left the camera frame
with the HOG boxes and the foot point, on the right the grid from above with the
belief (from ``steps.jsonl``: the belief after the last step before each frame), the
robot and its path, the true person, the camera's person and the leg tracks.
"""

from __future__ import annotations

import bisect
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from stack.cells import CellGrid
from stack.files import PrivateOutput
from stack.vocabulary import NO_PERSON
from vigil.frames import FRAMES_FILE, decode, read_frames
from vigil.report.records import since

VIDEO_FILE = "camera.mp4"


def _h264_writer(path: Path, size: tuple[int, int], fps: float):
    """An started imageio-ffmpeg writer generator (send RGB frames, then close)."""
    import imageio_ffmpeg

    try:
        gen = imageio_ffmpeg.write_frames(
            str(path),
            size,
            fps=float(fps),
            codec="libx264",
            pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p",
            macro_block_size=2,
            quality=None,
            output_params=["-crf", "23", "-preset", "veryfast", "-movflags", "+faststart"],
            ffmpeg_log_level="error",
        )
        gen.send(None)
    except (OSError, RuntimeError) as exc:
        raise RuntimeError(f"cannot open an H.264 video writer for {path}: {exc}") from exc
    return gen


def video_codec(path: str | Path) -> str:
    """The codec of a video file's video stream as ffmpeg names it ("h264", ...)."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    try:
        meta = next(reader)
    finally:
        reader.close()
    return str(meta.get("codec", "")).split()[0]


_WHITE = (255, 255, 255)
_BLACK = (0, 0, 0)
_BELIEF_RGB = np.array((40, 90, 230), float)


class VideoComposer:
    """The run's video: the camera frame beside a top view of the grid, as H.264 MP4.

    Each :meth:`add` writes one output frame (``size`` pixels, fixed): on the left the
    camera frame letterboxed into the panel (a grey "no frame" panel when None) with
    the HOG boxes, the foot point and the camera's status; on the right the grid seen
    from above (north up, east right): cell numbers, restricted cells red, the rest
    cell green, the person belief as blue shading, the robot with its heading and its
    path so far, the true person (green), the camera's person position (magenta ring)
    and the leg tracks (orange crosses). Colours in RGB; frames are RGB uint8.

    The file is H.264 (libx264 through the ffmpeg that ``imageio-ffmpeg`` ships,
    yuv420p, ``+faststart``): browsers play it. ffmpeg writes it by name, and would
    follow a link there: it writes into a fresh folder of its own beside ``path``
    (:class:`stack.config.PrivateOutput`), and :meth:`close` moves the finished file
    to ``path``, never through a link (a link at ``path`` is refused, naming it). Left
    by an exception (``with``), nothing reaches ``path``.

    Raises:
        RuntimeError: the MP4 writer cannot be opened (at the first :meth:`add`).
        OSError: ``path`` is a symbolic link (at the first :meth:`add` and at
            :meth:`close`).
    """

    def __init__(
        self,
        path: str | Path,
        grid: CellGrid,
        restricted: tuple[int, ...],
        room_bounds_m: tuple[float, float, float, float] | None = None,
        fps: float = 10.0,
        *,
        rest_cell: int | None = 7,
        size: tuple[int, int] = (960, 360),
        camera_width: int = 576,
    ):
        import cv2

        self._cv2 = cv2
        self.path = Path(path)
        self.grid = grid
        self.restricted = tuple(restricted)
        self.width, self.height = (int(size[0]) // 2 * 2, int(size[1]) // 2 * 2)
        self.cam_w = int(camera_width)
        self.map_w = self.width - self.cam_w
        if self.map_w < 64:
            raise ValueError(f"size {size} leaves no room for the map beside the camera")
        self.frames = 0
        self._path_px: list[tuple[int, int]] = []
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.fps = float(fps)
        self._writer = None  # opened by the first add(): no empty, invalid file
        self._out: PrivateOutput | None = None  # where ffmpeg writes until close()
        self._closed = False
        self._setup_map(room_bounds_m, rest_cell)
        self._no_frame = np.full((self.height, self.cam_w, 3), 90, np.uint8)
        cv2.putText(
            self._no_frame,
            "no frame",
            (self.cam_w // 2 - 50, self.height // 2),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.7,
            (200, 200, 200),
            2,
            cv2.LINE_AA,
        )

    # -- geometry ----------------------------------------------------------------------
    def _setup_map(self, room: tuple[float, float, float, float] | None, rest: int | None):
        cv2 = self._cv2
        g = self.grid
        gx0, gy0 = g.origin_m
        gw, gh = g.size_m
        x0, y0, x1, y1 = (gx0, gy0, gx0 + gw, gy0 + gh)
        if room is not None:
            x0, y0, x1, y1 = (
                min(x0, room[0]),
                min(y0, room[1]),
                max(x1, room[2]),
                max(y1, room[3]),
            )
        margin, top = 10, 24
        scale = min(
            (self.map_w - 2 * margin) / max(x1 - x0, 1e-6),
            (self.height - top - 2 * margin) / max(y1 - y0, 1e-6),
        )
        self._scale = scale
        used_w, used_h = (x1 - x0) * scale, (y1 - y0) * scale
        self._ox = margin + (self.map_w - 2 * margin - used_w) / 2
        self._oy = top + margin + (self.height - top - 2 * margin - used_h) / 2
        self._x0, self._y1 = x0, y1
        bg = np.full((self.height, self.map_w, 3), 245, np.uint8)
        fg = bg.copy()
        mask = np.zeros((self.height, self.map_w), np.uint8)
        if room is not None:
            cv2.rectangle(bg, self.px(room[0], room[3]), self.px(room[2], room[1]), _WHITE, -1)
        self._cell_px: dict[int, tuple[int, int, int, int]] = {}
        self._cell_colour: dict[int, np.ndarray] = {}
        for cell in g.cells:
            bx0, by0, bx1, by1 = g.bounds(cell)
            u0, v0 = self.px(bx0, by1)
            u1, v1 = self.px(bx1, by0)
            self._cell_px[cell] = (u0, v0, u1, v1)
            colour = _WHITE
            if cell in self.restricted:
                colour = (255, 200, 200)
            elif cell == rest:
                colour = (210, 245, 210)
            self._cell_colour[cell] = np.asarray(colour, float)
            cv2.rectangle(bg, (u0, v0), (u1, v1), colour, -1)
        for cell, (u0, v0, u1, v1) in self._cell_px.items():
            for img, val in ((fg, (120, 120, 120)), (mask, 255)):
                cv2.rectangle(img, (u0, v0), (u1, v1), val, 1)
            edge = (200, 0, 0) if cell in self.restricted else (60, 60, 60)
            for img, val in ((fg, edge), (mask, 255)):
                cv2.putText(
                    img, str(cell), (u0 + 3, v0 + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, val, 1
                )
            if cell in self.restricted:
                for img, val in ((fg, (220, 0, 0)), (mask, 255)):
                    cv2.rectangle(img, (u0 + 1, v0 + 1), (u1 - 1, v1 - 1), val, 2)
        if room is not None:
            for img, val in ((fg, (80, 80, 80)), (mask, 255)):
                cv2.rectangle(img, self.px(room[0], room[3]), self.px(room[2], room[1]), val, 1)
        self._bg = bg
        self._fg_idx = np.nonzero(mask)
        self._fg_val = fg[self._fg_idx]

    def px(self, x: float, y: float) -> tuple[int, int]:
        """Pixel (u, v) in the map panel of map point (x, y) [m]."""
        return (
            int(round(self._ox + (x - self._x0) * self._scale)),
            int(round(self._oy + (self._y1 - y) * self._scale)),
        )

    # -- drawing -----------------------------------------------------------------------
    def _camera_panel(self, frame: np.ndarray | None, camera: Mapping | None) -> np.ndarray:
        cv2 = self._cv2
        if frame is None:
            panel = self._no_frame.copy()
            sx = sy = 1.0
            du = dv = 0
        else:
            frame = np.asarray(frame)
            if frame.dtype != np.uint8:
                frame = np.clip(frame, 0, 255).astype(np.uint8)
            if frame.ndim == 2:
                frame = np.repeat(frame[:, :, None], 3, axis=2)
            frame = frame[:, :, :3]
            fh, fw = frame.shape[:2]
            s = min(self.cam_w / fw, self.height / fh)
            nw, nh = max(1, int(round(fw * s))), max(1, int(round(fh * s)))
            panel = np.zeros((self.height, self.cam_w, 3), np.uint8)
            du, dv = (self.cam_w - nw) // 2, (self.height - nh) // 2
            interp = cv2.INTER_AREA if s < 0.5 else cv2.INTER_LINEAR  # AREA: slow, for big cuts
            panel[dv : dv + nh, du : du + nw] = cv2.resize(frame, (nw, nh), interpolation=interp)
            sx, sy = nw / fw, nh / fh
        status = "camera: -"
        if camera:
            for box in camera.get("boxes") or []:
                x, y, w, h = box[:4]
                p0 = (int(du + x * sx), int(dv + y * sy))
                p1 = (int(du + (x + w) * sx), int(dv + (y + h) * sy))
                cv2.rectangle(panel, p0, p1, (0, 255, 0), 2)
                if len(box) > 4:
                    cv2.putText(
                        panel,
                        f"{box[4]:.2f}",
                        (p0[0], max(p0[1] - 3, 10)),
                        cv2.FONT_HERSHEY_SIMPLEX,
                        0.4,
                        (0, 255, 0),
                        1,
                    )
            foot = camera.get("foot_px")
            if foot is not None:
                cv2.circle(
                    panel, (int(du + foot[0] * sx), int(dv + foot[1] * sy)), 5, (255, 0, 255), -1
                )
            status = f"camera: {camera.get('status', '?')}"
            if camera.get("cell") is not None:
                status += f"  cell {camera['cell']}"
            if camera.get("direction"):
                status += f"  {camera['direction']}"
        cv2.rectangle(panel, (0, 0), (self.cam_w, 20), _BLACK, -1)
        cv2.putText(panel, status, (5, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _WHITE, 1, cv2.LINE_AA)
        return panel

    def _map_panel(
        self,
        t_s: float,
        camera: Mapping | None,
        legs: Sequence,
        robot: Sequence[float] | None,
        person: Sequence[float] | None,
        belief: Mapping | None,
    ) -> np.ndarray:
        cv2 = self._cv2
        img = self._bg.copy()
        if belief:
            for cell, (u0, v0, u1, v1) in self._cell_px.items():
                p = belief.get(str(cell), belief.get(cell))
                if p is None:
                    continue
                a = 0.75 * min(max(float(p), 0.0), 1.0)
                # cells are flat colours: blend the colour, fill (lines come back below)
                c = self._cell_colour[cell] * (1.0 - a) + _BELIEF_RGB * a
                cv2.rectangle(img, (u0, v0), (u1, v1), tuple(int(x) for x in c), -1)
        img[self._fg_idx] = self._fg_val
        if robot is not None:
            u, v = self.px(robot[0], robot[1])
            if (
                not self._path_px
                or abs(self._path_px[-1][0] - u) + abs(self._path_px[-1][1] - v) > 1
            ):
                self._path_px.append((u, v))
        if len(self._path_px) > 1:
            pts = np.asarray(self._path_px, np.int32).reshape(-1, 1, 2)
            cv2.polylines(img, [pts], False, (80, 80, 255), 1, cv2.LINE_AA)
        r_px = max(3, int(0.2 * self._scale))
        for leg in legs or []:
            u, v = self.px(leg[0], leg[1])
            cv2.drawMarker(img, (u, v), (255, 140, 0), cv2.MARKER_TILTED_CROSS, 8, 2)
        if camera and camera.get("position_m") is not None:
            u, v = self.px(*camera["position_m"][:2])
            cv2.circle(img, (u, v), r_px + 3, (220, 0, 220), 2, cv2.LINE_AA)
        if person is not None:
            u, v = self.px(person[0], person[1])
            cv2.circle(img, (u, v), r_px, (0, 170, 0), -1, cv2.LINE_AA)
        if robot is not None:
            u, v = self.px(robot[0], robot[1])
            cv2.circle(img, (u, v), r_px, (0, 0, 200), -1, cv2.LINE_AA)
            if len(robot) > 2 and robot[2] is not None:
                yaw = float(robot[2])
                tip = (int(u + 2 * r_px * math.cos(yaw)), int(v - 2 * r_px * math.sin(yaw)))
                cv2.line(img, (u, v), tip, (0, 0, 120), 2, cv2.LINE_AA)
        text = f"t = {t_s:7.1f} s"
        if belief and NO_PERSON in belief:
            text += f"   P(no person) {float(belief[NO_PERSON]):.2f}"
        cv2.putText(img, text, (8, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _BLACK, 1, cv2.LINE_AA)
        return img

    def render(
        self,
        t_s: float,
        frame_rgb: np.ndarray | None,
        camera: Mapping | None,
        legs: Sequence,
        robot_xy_yaw: Sequence[float] | None,
        person_xy: Sequence[float] | None,
        belief_person: Mapping | None = None,
    ) -> np.ndarray:
        """One output frame (RGB, height x width x 3) without writing it."""
        out = np.empty((self.height, self.width, 3), np.uint8)
        out[:, : self.cam_w] = self._camera_panel(frame_rgb, camera)
        out[:, self.cam_w :] = self._map_panel(
            t_s, camera, legs, robot_xy_yaw, person_xy, belief_person
        )
        return out

    def add(
        self,
        t_s: float,
        frame_rgb: np.ndarray | None,
        camera: Mapping | None,
        legs: Sequence,
        robot_xy_yaw: Sequence[float] | None,
        person_xy: Sequence[float] | None,
        belief_person: Mapping | None = None,
    ) -> None:
        """Compose and write one frame (``belief_person``: {"1": p, ..., "No person": p})."""
        if self._closed:
            raise RuntimeError(f"{self.path} is closed")
        if self._writer is None:
            self._out = PrivateOutput(self.path)
            self._writer = _h264_writer(self._out.path, (self.width, self.height), self.fps)
        img = self.render(t_s, frame_rgb, camera, legs, robot_xy_yaw, person_xy, belief_person)
        self._writer.send(np.ascontiguousarray(img))
        self.frames += 1

    def close(self) -> None:
        """Finish the file and move it to ``path`` (safe to call twice)."""
        self._end(keep=True)

    def _end(self, keep: bool) -> None:
        self._closed = True
        writer, self._writer = self._writer, None
        out, self._out = self._out, None
        try:
            if writer is not None:
                writer.close()
        except BaseException:
            if out is not None:
                out.discard()
            raise
        if out is not None:
            if keep:
                out.commit()
            else:
                out.discard()

    def __enter__(self) -> VideoComposer:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._end(keep=exc_type is None)


def write_video(
    run_dir: str | Path,
    grid: CellGrid,
    restricted: Sequence[int],
    trace: Sequence[dict],
    steps: Sequence[dict],
    *,
    rest_cell: int | None = 7,
    room_m: tuple[float, float, float, float] | None = None,
    fps: float = 10.0,
    say: Callable[[str], None] | None = None,
    origin_s: float = 0.0,
) -> Path | None:
    """``camera.mp4`` from ``camera_frames.bin`` and the trace: one video frame per
    trace record. Returns the file, or None when the run stored no frames (then an
    existing ``camera.mp4``, e.g. from an older recorder, is left as it is).

    ``say`` gets about one progress line a second. ``origin_s``: what was subtracted
    from the times of ``trace`` and ``steps`` (:func:`vigil.report.records.load_run`);
    the frames file holds the recorded times, and a frame goes with the record whose
    recorded time it has.
    """
    run_dir = Path(run_dir)
    frames_path = run_dir / FRAMES_FILE
    if not frames_path.exists():
        return None
    jpegs: dict[float, bytes] = {}
    for t, data in read_frames(frames_path):
        jpegs[since(t, origin_s)] = data  # round(t, 6) for a simulated clock's origin 0
    stamps = [float(s["stamp_s"]) for s in steps]
    beliefs = [((s.get("belief") or {}).get("person")) for s in steps]
    out = run_dir / VIDEO_FILE
    last = time.monotonic()
    with VideoComposer(out, grid, tuple(restricted), room_m, fps, rest_cell=rest_cell) as video:
        for k, rec in enumerate(trace):
            t = float(rec["t"])
            i = bisect.bisect_right(stamps, t + 1e-9) - 1
            belief = beliefs[i] if i >= 0 else None
            robot = rec.get("robot") or rec.get("odom")
            video.add(
                t,
                decode(jpegs.get(round(t, 6), b"")),
                rec.get("camera"),
                rec.get("legs") or [],
                robot,
                rec.get("person"),
                belief,
            )
            if say is not None and time.monotonic() - last >= 1.0:
                last = time.monotonic()
                say(f"[report] video: frame {k + 1}/{len(trace)} (t = {t:.1f} s)")
    if video.frames == 0:
        return None
    return out
