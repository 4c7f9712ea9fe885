"""Synthetic camera frames and laser scans with known ground truth.

For tests and benchmarks of the pure perception code without the MuJoCo twin:

- :class:`PinholeCamera` projects floor points and people into an image from a
  mount like the twin's (FEASIBILITY mount "A": behind the region's west end,
  2.75 m high, 25 deg tilt, 40 deg vertical field of view);
- :func:`render_person_frame` draws a person silhouette whose feet stand at a map
  point (OpenCV's HOG people detector finds it);
- :func:`simulate_scan` ray-casts a planar laser against circles (legs, chair legs)
  and wall segments;
- :func:`walking_legs` places a walking person's two legs.

Randomness is always passed in as a ``numpy.random.Generator``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from stack.cells import CellGrid
from stack.perception.legs import Pose2D, Scan


@dataclass(frozen=True)
class PinholeCamera:
    """An ideal pinhole camera above the floor.

    Attributes:
        width_px, height_px: image size [px].
        fovy_deg: vertical field of view [deg].
        position_m: (x, y, z) of the optical centre in the map frame [m].
        yaw_deg: heading of the optical axis on the floor, counter-clockwise from
            east [deg].
        tilt_deg: angle of the optical axis below horizontal [deg].
    """

    width_px: int = 640
    height_px: int = 400
    fovy_deg: float = 40.0
    position_m: tuple[float, float, float] = (-3.3, 1.5, 2.75)
    yaw_deg: float = 0.0
    tilt_deg: float = 25.0

    @classmethod
    def mount_a(
        cls, grid: CellGrid, width_px: int = 640, height_px: int = 400, distance_behind_m=3.3
    ) -> PinholeCamera:
        """The twin's default mount: on the region's long axis, behind its west edge."""
        x0, y0 = grid.origin_m
        return cls(
            width_px=width_px,
            height_px=height_px,
            position_m=(x0 - distance_behind_m, y0 + grid.size_m[1] / 2.0, 2.75),
        )

    def _axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        yaw, tilt = math.radians(self.yaw_deg), math.radians(self.tilt_deg)
        forward = np.array(
            [math.cos(tilt) * math.cos(yaw), math.cos(tilt) * math.sin(yaw), -math.sin(tilt)]
        )
        right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
        down = np.cross(forward, right)
        return right, down, forward

    @property
    def focal_px(self) -> float:
        return (self.height_px / 2.0) / math.tan(math.radians(self.fovy_deg) / 2.0)

    def project(self, points_m: np.ndarray) -> np.ndarray:
        """(N, 3) map points to (N, 2) pixels (u, v); NaN for points behind the camera."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 3) - np.asarray(self.position_m)
        right, down, forward = self._axes()
        z = p @ forward
        f = self.focal_px
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.width_px / 2.0 + f * (p @ right) / z
            v = self.height_px / 2.0 + f * (p @ down) / z
        out = np.c_[u, v]
        out[z <= 1e-6] = np.nan
        return out


def floor_calibration_points(
    camera: PinholeCamera, grid: CellGrid
) -> tuple[np.ndarray, np.ndarray]:
    """The region's cell corners on the floor and their pixels, as a twin would report.

    Returns:
        (image_px (N, 2), map_m (N, 2)) for the corners inside the image.
    """
    w, h = grid.cell_size_m
    xs = grid.origin_m[0] + w * np.arange(grid.columns + 1)
    ys = grid.origin_m[1] + h * np.arange(grid.rows + 1)
    floor = np.array([(x, y) for x in xs for y in ys])
    px = camera.project(np.c_[floor, np.zeros(len(floor))])
    inside = (
        np.isfinite(px).all(axis=1)
        & (px[:, 0] >= 0)
        & (px[:, 0] < camera.width_px)
        & (px[:, 1] >= 0)
        & (px[:, 1] < camera.height_px)
    )
    return px[inside], floor[inside]


def background_frame(camera: PinholeCamera, rng: np.random.Generator) -> np.ndarray:
    """An empty room: a wall above a floor with mild sensor noise (BGR, uint8)."""
    img = np.empty((camera.height_px, camera.width_px, 3), np.uint8)
    horizon = camera.height_px // 3
    img[:horizon] = (200, 190, 180)
    img[horizon:] = (150, 160, 165)
    noise = rng.normal(0.0, 5.0, img.shape)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def draw_person(image: np.ndarray, foot_px: tuple[float, float], height_px: float) -> None:
    """Draw an upright person silhouette standing on ``foot_px`` (in place)."""
    u, v, h = float(foot_px[0]), float(foot_px[1]), float(height_px)

    def pt(du: float, dv: float) -> tuple[int, int]:
        return (round(u + du * h), round(v - dv * h))

    legs, shirt, skin = (35, 35, 40), (40, 40, 110), (80, 120, 170)
    thick_leg, thick_arm = max(2, round(0.07 * h)), max(2, round(0.05 * h))
    cv2.line(image, pt(-0.05, 0.0), pt(-0.03, 0.47), legs, thick_leg)
    cv2.line(image, pt(0.05, 0.0), pt(0.03, 0.47), legs, thick_leg)
    cv2.rectangle(image, pt(-0.1, 0.8), pt(0.1, 0.45), shirt, -1)
    cv2.line(image, pt(-0.11, 0.78), pt(-0.14, 0.5), shirt, thick_arm)
    cv2.line(image, pt(0.11, 0.78), pt(0.14, 0.5), shirt, thick_arm)
    r = max(2, round(0.065 * h))
    cv2.circle(image, pt(0.0, 1.0 - 0.065), r, skin, -1)


def render_person_frame(
    camera: PinholeCamera,
    person_xy_m: tuple[float, float] | None,
    rng: np.random.Generator,
    person_height_m: float = 1.75,
    background: np.ndarray | None = None,
) -> np.ndarray:
    """A frame with a person standing at a map point (or an empty frame).

    Args:
        camera: the camera.
        person_xy_m: where the person's feet are on the map [m]; None: no person.
        rng: noise source.
        person_height_m: the person's height [m].
        background: the empty frame to draw on (a fresh one when None).

    Returns:
        A BGR uint8 frame.
    """
    img = background_frame(camera, rng) if background is None else background.copy()
    if person_xy_m is not None:
        x, y = person_xy_m
        foot, head = camera.project(np.array([[x, y, 0.0], [x, y, person_height_m]]))
        if np.all(np.isfinite(foot)) and np.all(np.isfinite(head)):
            draw_person(img, (foot[0], foot[1]), foot[1] - head[1])
    return cv2.GaussianBlur(img, (3, 3), 0)


def render_people_frame(
    camera: PinholeCamera,
    people_xy_m: Sequence[tuple[float, float]],
    rng: np.random.Generator,
    person_height_m: float = 1.75,
    background: np.ndarray | None = None,
) -> np.ndarray:
    """A frame with several people standing at map points (issue 16).

    People are drawn farthest first, so a nearer person hides a farther one as in
    a real image.

    Args:
        camera: the camera.
        people_xy_m: where each person's feet are on the map [m].
        rng: noise source.
        person_height_m: everyone's height [m].
        background: the empty frame to draw on (a fresh one when None).

    Returns:
        A BGR uint8 frame.
    """
    img = background_frame(camera, rng) if background is None else background.copy()
    cam = np.asarray(camera.position_m[:2])
    order = sorted(people_xy_m, key=lambda p: -float(np.hypot(*(np.asarray(p) - cam))))
    for x, y in order:
        foot, head = camera.project(np.array([[x, y, 0.0], [x, y, person_height_m]]))
        if np.all(np.isfinite(foot)) and np.all(np.isfinite(head)):
            draw_person(img, (foot[0], foot[1]), foot[1] - head[1])
    return cv2.GaussianBlur(img, (3, 3), 0)


def crossing_paths(
    t_s: float,
    center_m: tuple[float, float] = (1.5, 1.5),
    half_length_m: float = 1.2,
    speed_mps: float = 0.8,
    lateral_m: float = 0.0,
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Two people crossing: one walks north, the other south, along x = centre.

    At ``t_s = 0`` they are ``half_length_m`` either side of ``center_m``; they meet
    there at ``half_length_m / speed_mps`` and walk on. ``lateral_m`` puts them that
    far apart across the walk (0: straight through each other).

    Returns:
        ((x, y) of the north-walker, (x, y) of the south-walker) [m].
    """
    cx, cy = center_m
    d = speed_mps * t_s - half_length_m
    return (cx - lateral_m / 2.0, cy + d), (cx + lateral_m / 2.0, cy - d)


def walking_legs(
    center_m: tuple[float, float],
    heading_rad: float,
    t_s: float,
    speed_mps: float,
    stride_m: float = 0.6,
    hip_width_m: float = 0.2,
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Both leg positions of a person walking at ``speed_mps`` (symmetric swing).

    The legs swing in antiphase along the heading with an amplitude of a quarter
    stride at a cadence of speed / stride, so their midpoint is ``center_m``.
    """
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    phase = 2.0 * math.pi * (speed_mps / stride_m) * t_s
    swing = (stride_m / 4.0) * math.sin(phase) if speed_mps > 0 else 0.0
    side = hip_width_m / 2.0
    legs = []
    for sign in (1.0, -1.0):
        along, across = sign * swing, sign * side
        legs.append((center_m[0] + c * along - s * across, center_m[1] + s * along + c * across))
    return legs[0], legs[1]


def simulate_scan(
    laser_pose: Pose2D,
    circles: Sequence[tuple[float, float, float]],
    rng: np.random.Generator,
    walls: Sequence[tuple[tuple[float, float], tuple[float, float]]] = (),
    n_beams: int = 720,
    fov_deg: float = 270.0,
    range_min_m: float = 0.05,
    range_max_m: float = 10.0,
    noise_sigma_m: float = 0.01,
    stamp_s: float = 0.0,
) -> Scan:
    """Ray-cast a planar laser against circles and wall segments in the map frame.

    Args:
        laser_pose: the laser's pose in the map frame.
        circles: (x, y, radius) of legs, chair legs, poles [m].
        rng: range noise source.
        walls: ((x0, y0), (x1, y1)) line segments [m].
        n_beams: beams, spread evenly over ``fov_deg`` centred on the laser's x axis.
        fov_deg: field of view [deg].
        range_min_m, range_max_m: valid range; no hit gives inf.
        noise_sigma_m: Gaussian range noise [m].
        stamp_s: the scan's time [s].

    Returns:
        The scan, in the laser frame.
    """
    fov = math.radians(fov_deg)
    inc = fov / n_beams
    angle_min = -fov / 2.0 + inc / 2.0
    angles = angle_min + inc * np.arange(n_beams)
    world = angles + laser_pose.yaw_rad
    d = np.c_[np.cos(world), np.sin(world)]
    o = np.array([laser_pose.x_m, laser_pose.y_m])
    best = np.full(n_beams, np.inf)
    for cx, cy, r in circles:
        oc = o - (cx, cy)
        b = d @ oc
        disc = b * b - (oc @ oc - r * r)
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(disc)
        t[(disc < 0) | (t <= 0)] = np.inf
        best = np.minimum(best, t)
    for (x0, y0), (x1, y1) in walls:
        e = np.array([x1 - x0, y1 - y0])
        denom = d[:, 0] * e[1] - d[:, 1] * e[0]
        w = np.array([x0, y0]) - o
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[0] * e[1] - w[1] * e[0]) / denom
            s = (w[0] * d[:, 1] - w[1] * d[:, 0]) / denom
        hit = (np.abs(denom) > 1e-12) & (t > 0) & (s >= 0) & (s <= 1)
        best = np.where(hit, np.minimum(best, t), best)
    ranges = best + rng.normal(0.0, noise_sigma_m, n_beams)
    ranges[~np.isfinite(best) | (best > range_max_m)] = np.inf
    return Scan(ranges, angle_min, inc, range_min_m, range_max_m, stamp_s)
